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

#[test]
fn rollout_writes_header_steps_and_end() {
    let out = rollout(&["--scenario", "0", "--model", "cr_sfm", "--av", "0.3,0.1"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).unwrap();
    let lines: Vec<serde_json::Value> = text
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
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
