//! Contract: `load_pool` rejects every kind of malformed scenario file with an error naming the
//! file, the scenario, the agent and the field; valid pools round-trip exactly through
//! `save_pool`/`load_pool`.

use scenarios::pool::{load_pool, save_pool, validate_pool, OverlapCheck, Problem};
use serde_json::{json, Value};
use sim_core::scenario::{AgentKind, AgentRecord, Scenario, ScenarioPool, Split};

const ORIGIN: &str = "pools/bad.json";

fn agent(id: u64, kind: AgentKind, start: u32, p0: [f64; 2], v: [f64; 2], n: usize) -> AgentRecord {
    let positions = (0..n)
        .map(|k| [p0[0] + v[0] * 0.5 * k as f64, p0[1] + v[1] * 0.5 * k as f64])
        .collect();
    AgentRecord {
        record_id: id,
        kind,
        start_step: start,
        positions,
        velocities: vec![v; n],
        non_reactive: false,
        desired_speed: None,
    }
}

fn valid_pool() -> ScenarioPool {
    let s0 = Scenario {
        name: "s0".into(),
        split: Split::Train,
        dt: 0.5,
        ego: 0,
        agents: vec![
            agent(100, AgentKind::Vehicle, 0, [0.0, 0.0], [2.0, 0.0], 6),
            agent(7, AgentKind::Pedestrian, 0, [3.0, 5.0], [0.0, 1.0], 6),
            agent(8, AgentKind::Pedestrian, 2, [-3.0, 5.0], [0.0, 1.0], 4),
        ],
    };
    let mut s1 = s0.clone();
    s1.name = "s1".into();
    s1.split = Split::Test;
    ScenarioPool {
        version: 1,
        vehicle_model: sim_core::params::VehicleModel::Replay,
        name: "test-pool".into(),
        provenance: "hand-made".into(),
        scenarios: vec![s0, s1],
    }
}

fn as_value(pool: &ScenarioPool) -> Value {
    serde_json::to_value(pool).unwrap()
}

fn load_err(text: &str) -> (String, scenarios::PoolError) {
    let e = load_pool(text.as_bytes(), ORIGIN).expect_err("must be rejected");
    (e.to_string(), e)
}

/// Loads the valid pool after `edit` has changed its JSON document: the error (as message and
/// value) it must be rejected with.
fn rejected(edit: impl FnOnce(&mut Value)) -> (String, scenarios::PoolError) {
    let mut v = as_value(&valid_pool());
    edit(&mut v);
    load_err(&serde_json::to_string(&v).unwrap())
}

/// Asserts that the error message `msg` names the pool file and each `; `-separated part of
/// `parts` (scenario, agent, field, problem: one line per expectation).
#[track_caller]
fn names(msg: &str, parts: &str) {
    eprintln!("{msg}");
    for p in std::iter::once(ORIGIN).chain(parts.split("; ")) {
        assert!(msg.contains(p), "error `{msg}` does not name `{p}`");
    }
}

/// The other agent's index and the step of an overlap error; `None` for any other problem.
fn overlap(e: &scenarios::PoolError) -> Option<(usize, u32)> {
    match *e.problem {
        Problem::Overlap {
            other_index, step, ..
        } => Some((other_index, step)),
        _ => None,
    }
}

#[test]
fn valid_pool_round_trips_exactly() {
    let pool = valid_pool();
    let text = save_pool(&pool);
    let back = load_pool(text.as_bytes(), ORIGIN).unwrap();
    assert_eq!(back, pool);
    assert_eq!(save_pool(&back), text);
}

#[test]
fn malformed_json_names_file_and_position() {
    let text = save_pool(&valid_pool());
    // Truncated inside agent #1 of scenario #0.
    let cut = text.find("\"record_id\":7").unwrap() + 20;
    let (msg, e) = load_err(&text[..cut]);
    names(&msg, "scenario #0; agent #1; malformed JSON");
    assert!(matches!(*e.problem, Problem::Syntax(_)));
    // Not JSON at all.
    let (msg, _) = load_err("hello");
    names(&msg, "malformed JSON");
    // Trailing garbage after a valid pool.
    let (msg, _) = load_err(&format!("{text} x"));
    names(&msg, "malformed JSON");
    // Not UTF-8.
    let e = load_pool(&[0xff, 0xfe], ORIGIN).unwrap_err();
    names(&e.to_string(), "UTF-8");
}

#[test]
fn missing_field_is_named() {
    let (msg, e) = rejected(|v| {
        v["scenarios"][1]["agents"][2]
            .as_object_mut()
            .unwrap()
            .remove("velocities");
    });
    names(
        &msg,
        "scenario #1 `s1`; agent #2 (record_id 8); field `velocities`; missing field",
    );
    assert_eq!(e.field, "velocities");

    let (msg, _) = rejected(|v| {
        v["scenarios"][0].as_object_mut().unwrap().remove("ego");
    });
    names(&msg, "scenario #0 `s0`; field `ego`");
}

#[test]
fn wrong_types_and_unknown_variants_are_named() {
    let (msg, _) = rejected(|v| {
        v["scenarios"][0]["agents"][1]["kind"] = json!("bicycle");
    });
    names(
        &msg,
        "scenario #0 `s0`; agent #1 (record_id 7); field `kind`; bicycle",
    );

    let (msg, _) = rejected(|v| {
        v["scenarios"][0]["agents"][1]["start_step"] = json!(-1);
    });
    names(
        &msg,
        "scenario #0 `s0`; agent #1 (record_id 7); field `start_step`",
    );
}

#[test]
fn wrong_version_is_rejected() {
    let (msg, e) = rejected(|v| {
        v["version"] = json!(2);
    });
    names(&msg, "field `version`; unsupported format version 2");
    assert_eq!(
        *e.problem,
        Problem::Version {
            found: 2,
            expected: 1
        }
    );
}

#[test]
fn null_number_is_named() {
    let (msg, _) = rejected(|v| {
        v["scenarios"][0]["agents"][1]["positions"][2][0] = Value::Null;
    });
    names(
        &msg,
        "scenario #0 `s0`; agent #1 (record_id 7); field `positions[2][0]`",
    );
}

#[test]
fn out_of_range_literal_is_named() {
    let text = save_pool(&valid_pool());
    let text = text.replacen("[3.0,5.0]", "[1e400,5.0]", 1);
    let (msg, _) = load_err(&text);
    names(&msg, "scenario #0; agent #1; field `positions[0][0]`");
}

#[test]
fn nan_literal_is_rejected() {
    let text = save_pool(&valid_pool()).replacen("[3.0,5.0]", "[NaN,5.0]", 1);
    let (msg, _) = load_err(&text);
    names(&msg, "scenario #0; agent #1; field `positions[0][0]`");
}

#[test]
fn huge_finite_value_is_rejected() {
    let (msg, e) = rejected(|v| {
        v["scenarios"][1]["agents"][2]["velocities"][3][1] = json!(1e300);
    });
    names(
        &msg,
        "scenario #1 `s1`; agent #2 (record_id 8); field `velocities[3][1]`; plausibility",
    );
    assert!(matches!(*e.problem, Problem::TooLarge { .. }));
}

#[test]
fn a_bad_desired_speed_is_named() {
    for (bad, problem) in [
        (f64::NAN, "not a finite number"),
        (-0.5, "is negative"),
        (2e3, "plausibility"),
    ] {
        let mut pool = valid_pool();
        pool.scenarios[0].agents[2].desired_speed = Some(bad);
        let e = validate_pool(&pool, ORIGIN, OverlapCheck::Spawn).unwrap_err();
        let at = "scenario #0 `s0`; agent #2 (record_id 8); field `desired_speed`";
        names(&e.to_string(), &format!("{at}; {problem}"));
    }
    let mut pool = valid_pool();
    pool.scenarios[0].agents[2].desired_speed = Some(1.3);
    assert!(validate_pool(&pool, ORIGIN, OverlapCheck::Spawn).is_ok());
}

#[test]
fn non_finite_in_memory_is_rejected() {
    for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        let mut pool = valid_pool();
        pool.scenarios[0].agents[2].positions[1][1] = bad;
        let e = validate_pool(&pool, ORIGIN, OverlapCheck::Spawn).unwrap_err();
        let at = "scenario #0 `s0`; agent #2 (record_id 8); field `positions[1][1]`";
        names(&e.to_string(), &format!("{at}; not a finite number"));
    }
    let mut pool = valid_pool();
    pool.scenarios[1].dt = f64::NAN;
    let e = validate_pool(&pool, ORIGIN, OverlapCheck::Spawn).unwrap_err();
    names(&e.to_string(), "scenario #1 `s1`; field `dt`");
}

#[test]
fn empty_track_is_rejected() {
    let (msg, e) = rejected(|v| {
        v["scenarios"][0]["agents"][2]["positions"] = json!([]);
        v["scenarios"][0]["agents"][2]["velocities"] = json!([]);
    });
    names(
        &msg,
        "scenario #0 `s0`; agent #2 (record_id 8); field `positions`; empty track",
    );
    assert_eq!(*e.problem, Problem::EmptyTrack);
}

#[test]
fn length_mismatch_is_rejected() {
    let (msg, e) = rejected(|v| {
        v["scenarios"][1]["agents"][1]["velocities"]
            .as_array_mut()
            .unwrap()
            .pop();
    });
    let at = "scenario #1 `s1`; agent #1 (record_id 7); field `velocities`";
    names(&msg, &format!("{at}; 5 velocities for 6 positions"));
    assert!(matches!(
        *e.problem,
        Problem::LengthMismatch {
            positions: 6,
            velocities: 5
        }
    ));
}

#[test]
fn start_step_overflow_is_rejected() {
    let (msg, _) = rejected(|v| {
        v["scenarios"][0]["agents"][1]["start_step"] = json!(u32::MAX);
    });
    names(
        &msg,
        "scenario #0 `s0`; agent #1 (record_id 7); field `start_step`",
    );
}

#[test]
fn overlap_at_initial_frame_is_rejected() {
    // Pedestrian 7 placed 1 m ahead of the vehicle's centre: inside the 4.0 x 1.8 rectangle.
    let (msg, e) = rejected(|v| {
        v["scenarios"][0]["agents"][1]["positions"][0] = json!([1.0, 0.0]);
    });
    let at = "scenario #0 `s0`; agent #1 (record_id 7); field `positions[0]`";
    names(
        &msg,
        &format!("{at}; overlaps agent #0 (record_id 100) at step 0"),
    );
    assert_eq!(overlap(&e), Some((0, 0)));
}

#[test]
fn pedestrian_pair_touching_is_an_overlap() {
    // Two discs of radius 0.3 exactly 0.6 m apart: clearance 0 counts as a collision.
    let (msg, _) = rejected(|v| {
        v["scenarios"][0]["agents"][1]["start_step"] = json!(2);
        v["scenarios"][0]["agents"][1]["positions"][0] = json!([0.6, 5.0]);
        v["scenarios"][0]["agents"][2]["positions"][0] = json!([0.0, 5.0]);
    });
    names(
        &msg,
        "scenario #0 `s0`; field `positions[0]`; at step 2; overlaps agent",
    );
}

#[test]
fn overlap_when_an_agent_enters_is_rejected() {
    // Agent 8 enters at step 2 on top of the vehicle (at x = 2.0 then).
    let (msg, e) = rejected(|v| {
        v["scenarios"][1]["agents"][2]["positions"][0] = json!([2.5, 0.5]);
    });
    names(
        &msg,
        "scenario #1 `s1`; agent #2 (record_id 8); field `positions[0]`; at step 2",
    );
    assert_eq!(overlap(&e), Some((0, 2)));
}

#[test]
fn later_overlap_passes_spawn_check_but_fails_all_steps() {
    // Pedestrian 7 walks into the vehicle's path at step 3 (vehicle at x = 3.0).
    let mut pool = valid_pool();
    let a = &mut pool.scenarios[0].agents[1];
    a.positions[3] = [3.0, 0.0];
    let text = save_pool(&pool);
    load_pool(text.as_bytes(), ORIGIN).expect("spawn check passes");
    let e = validate_pool(&pool, ORIGIN, OverlapCheck::AllSteps).unwrap_err();
    names(
        &e.to_string(),
        "scenario #0 `s0`; agent #1 (record_id 7); field `positions[3]`; at step 3",
    );
}

#[test]
fn wrong_dt_is_rejected() {
    let (msg, e) = rejected(|v| {
        v["scenarios"][1]["dt"] = json!(0.25);
    });
    names(&msg, "scenario #1 `s1`; field `dt`; 0.25");
    assert_eq!(*e.problem, Problem::WrongDt(0.25));
}

#[test]
fn ego_out_of_range_is_rejected() {
    let (msg, _) = rejected(|v| {
        v["scenarios"][0]["ego"] = json!(3);
    });
    names(
        &msg,
        "scenario #0 `s0`; field `ego`; out of range (3 agents)",
    );
}

#[test]
fn ego_must_be_a_vehicle() {
    let (msg, e) = rejected(|v| {
        v["scenarios"][0]["ego"] = json!(1);
    });
    names(&msg, "scenario #0 `s0`; field `ego`; must be a vehicle");
    assert_eq!(*e.problem, Problem::EgoNotVehicle { ego: 1 });
}

#[test]
fn empty_scenario_is_rejected() {
    let (msg, _) = rejected(|v| {
        v["scenarios"][0]["agents"] = json!([]);
    });
    names(&msg, "scenario #0 `s0`; field `agents`; no agents");
}

#[test]
fn duplicate_scenario_names_are_rejected() {
    let (msg, e) = rejected(|v| {
        v["scenarios"][1]["name"] = json!("s0");
    });
    names(
        &msg,
        "scenario #1 `s0`; field `name`; duplicate scenario name; scenario #0",
    );
    assert_eq!(*e.problem, Problem::DuplicateName { first_index: 0 });

    let (msg, _) = rejected(|v| {
        v["scenarios"][1]["name"] = json!("");
    });
    names(&msg, "scenario #1; field `name`; empty name");
}

#[test]
fn duplicate_record_ids_are_rejected() {
    let (msg, _) = rejected(|v| {
        v["scenarios"][0]["agents"][2]["record_id"] = json!(7);
    });
    names(
        &msg,
        "scenario #0 `s0`; agent #2 (record_id 7); field `record_id`; duplicate",
    );
}

#[test]
fn load_pool_file_names_missing_file() {
    let e = scenarios::load_pool_file(std::path::Path::new("/nonexistent/pool.json")).unwrap_err();
    let msg = e.to_string();
    assert!(
        msg.contains("/nonexistent/pool.json") && msg.contains("cannot read"),
        "{msg}"
    );
}
