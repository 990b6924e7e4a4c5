//! Contract of `sim-server eval-peds`: on the embedded pool it reports, per requested model, finite
//! ADE/FDE/collision rate and episode counts plus per-scenario values; batch mode answers one JSON
//! line per input line (an `error` line for refused parameters, and goes on); malformed parameters
//! are refused with a message naming the offending field, and the command exits non-zero.

use std::process::Command;

use serde_json::Value;
use sim_server::pedeval_cmd::{run_batch, run_summary, EvalPedsArgs};

fn two_test_scenarios() -> EvalPedsArgs {
    EvalPedsArgs {
        split: "test".into(),
        models: "cv,sfm,ra_sfm,cr_sfm".into(),
        limit: Some(2),
        threads: Some(2),
        ..Default::default()
    }
}

fn finite(v: &Value, what: &str) -> f64 {
    let x = v
        .as_f64()
        .unwrap_or_else(|| panic!("{what} is not a number: {v}"));
    assert!(x.is_finite(), "{what} = {x}");
    x
}

#[test]
fn summary_has_every_model_with_finite_numbers() {
    let s = run_summary(&two_test_scenarios()).unwrap();
    assert_eq!(s["split"], "test");
    assert!(s["pool"]["name"].is_string());
    assert_eq!(
        s["models_order"],
        serde_json::json!(["cv", "sfm", "ra_sfm", "cr_sfm"])
    );
    for m in ["cv", "sfm", "ra_sfm", "cr_sfm"] {
        let r = &s["models"][m];
        assert_eq!(r["episodes"], 2, "{m}");
        let ade = finite(&r["ade"], "ade");
        let fde = finite(&r["fde"], "fde");
        assert!(ade >= 0.0 && fde >= 0.0);
        assert!((finite(&r["objective"], "objective") - (ade + fde)).abs() < 1e-12);
        let cr = finite(&r["collision_rate"], "collision_rate");
        assert!((0.0..=1.0).contains(&cr));
        let scen = r["scenarios"].as_array().expect("per-scenario values");
        assert_eq!(scen.len(), 2);
        let mean_ade = scen.iter().map(|e| finite(&e["ade"], "ade")).sum::<f64>() / 2.0;
        assert!((mean_ade - ade).abs() < 1e-12, "{m}: mean of scenarios");
        for e in scen {
            assert!(e["name"].is_string());
            assert!(e["collided"].is_boolean());
            assert_eq!(e["pedestrians"], 3, "paper pool: three pedestrians");
        }
    }
    // Deterministic: the same numbers on one thread.
    let mut one = two_test_scenarios();
    one.threads = Some(1);
    assert_eq!(run_summary(&one).unwrap()["models"], s["models"]);
}

#[test]
fn batch_answers_every_line_and_survives_bad_parameters() {
    let mut args = two_test_scenarios();
    args.models = "sfm,cr_sfm".into();
    args.batch = true;
    let input = "{pedestrians: {sfm: {tau: 0.8}}}\n\n{\"pedestrians\": {\"sfm\": {\"tau\": \"slow\"}}}\n{models: {cr_sfm: {risk: {gamma1: 1.2}}}}\n";
    let mut out = Vec::new();
    run_batch(&args, input.as_bytes(), &mut out).unwrap();
    let lines: Vec<Value> = String::from_utf8(out)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), 3, "one result per non-empty line");
    finite(&lines[0]["models"]["sfm"]["ade"], "ade");
    finite(&lines[0]["models"]["cr_sfm"]["fde"], "fde");
    let err = lines[1]["error"].as_str().expect("an error line");
    assert!(err.contains("pedestrians.sfm.tau"), "{err}");
    assert_eq!(lines[2]["index"], 3);
    finite(&lines[2]["models"]["cr_sfm"]["objective"], "objective");
}

#[test]
fn malformed_params_are_refused_naming_the_field() {
    let bin = env!("CARGO_BIN_EXE_sim-server");
    for (json, field) in [
        (
            r#"{"pedestrians": {"cr_sfm": {"lambda1": "big"}}}"#,
            "pedestrians.cr_sfm.lambda1",
        ),
        (r#"{"risk": {"gama2": 1.0}}"#, "gama2"),
        (
            r#"{"pedestrians": {"sfm": {"b_ped": 0}}}"#,
            "pedestrians.sfm.b_ped",
        ),
        (
            r#"{"models": {"ra_sfm": {"risk": {"gamma2": -1}}}}"#,
            "risk.gamma2",
        ),
    ] {
        let out = Command::new(bin)
            .args([
                "eval-peds",
                "--limit",
                "1",
                "--models",
                "sfm",
                "--params-json",
                json,
            ])
            .output()
            .unwrap();
        assert!(!out.status.success(), "{json} accepted");
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(stderr.contains(field), "{json}: {stderr}");
        assert!(out.stdout.is_empty(), "no result on refusal");
    }
}
