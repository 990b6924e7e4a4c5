//! `sim-server rollout` writes header, step and end lines (docs/ROLLOUT.md) and refuses bad
//! arguments with an error naming what was wrong.

use std::process::Command;

fn rollout(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_sim-server"))
        .arg("rollout")
        .args(args)
        .output()
        .expect("run sim-server")
}

/// The JSON lines of a rollout that must succeed.
fn rollout_lines(args: &[&str]) -> Vec<serde_json::Value> {
    let out = rollout(args);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).unwrap();
    text.lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

#[test]
fn rollout_writes_header_steps_and_end() {
    let lines = rollout_lines(&["--scenario", "0", "--model", "cr_sfm", "--av", "0.3,0.1"]);
    assert_eq!(lines[0]["type"], "header");
    assert_eq!(lines[0]["format"], "sharedspace-rollout/1");
    assert_eq!(lines[1]["type"], "step");
    assert_eq!(lines[1]["step"], 0);
    assert!(lines[1]["edges"].as_array().is_some_and(|e| !e.is_empty()));
    assert_eq!(lines.last().unwrap()["type"], "end");
    assert!(lines[2..lines.len() - 1]
        .iter()
        .all(|l| l["type"] == "step"));
}

/// model.md 2b through the rollout: a driven pedestrian is listed as external, has rewards
/// every step and speeds up along its heading by `ped_acc_max * dt` per step.
#[test]
fn a_driven_pedestrian_is_recorded_as_an_external_agent() {
    let lines = rollout_lines(&["--scenario", "0", "--pedestrian", "0=1,0", "--av", "0,0"]);
    let driven = &lines[0]["pedestrians_driven"][0];
    assert_eq!(driven["name"], "pedestrian_0");
    let id = driven["agent"].as_u64().unwrap();
    let agent = lines[0]["agents"]
        .as_array()
        .unwrap()
        .iter()
        .find(|a| a["id"] == id)
        .unwrap();
    assert_eq!(agent["control"], "external");
    let speed = |l: &serde_json::Value| {
        l["agents"]
            .as_array()
            .unwrap()
            .iter()
            .find(|a| a["id"] == id)
            .map(|a| (a["vx"].as_f64().unwrap().powi(2) + a["vy"].as_f64().unwrap().powi(2)).sqrt())
    };
    let (s1, s2) = (speed(&lines[1]).unwrap(), speed(&lines[2]).unwrap());
    assert!((s2 - (s1 + 1.0).min(2.0)).abs() < 1e-9, "{s1} -> {s2}");
    assert!(lines[2]["rewards"]
        .as_array()
        .unwrap()
        .iter()
        .any(|r| r["agent"] == id));
}

#[test]
fn bad_arguments_are_refused_with_a_message_naming_them() {
    for (args, needle) in [
        (
            vec!["--model", "magic"],
            "invalid value 'magic' for '--model",
        ),
        (vec!["--av", "0.5"], "--av `0.5`"),
        (vec!["--av", "nan,0"], "--av `nan,0`"),
        (
            vec!["--scenario", "no-such-scenario"],
            "no scenario `no-such-scenario`",
        ),
        (
            vec!["--params", "/nonexistent/params.json5"],
            "/nonexistent/params.json5",
        ),
        (vec!["--threads", "0"], "--threads"),
        (vec!["--pedestrian", "0=1"], "--pedestrian `0=1`"),
        (
            vec!["--pedestrian", "99=0,0"],
            "--pedestrian 99: the scenario has",
        ),
    ] {
        let out = rollout(&args);
        assert!(!out.status.success(), "{args:?} should fail");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains(needle),
            "{args:?}: `{err}` should name `{needle}`"
        );
    }
}
