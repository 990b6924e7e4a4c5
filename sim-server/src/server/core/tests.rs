use super::*;
use protocol::{decode, ComposedScenes, F64Array, Reply, ResetResult, StepResult};

fn core(limits: Limits) -> ServerCore {
    ServerCore::new(
        "s".into(),
        KeySpace::default(),
        limits,
        vec![ServedPool::new(scenarios::embedded::default_pool())],
        WorldParams::default(),
    )
}

fn err_of(bytes: &[u8]) -> ErrorReply {
    match decode::<Reply<serde::de::IgnoredAny>>(bytes).unwrap() {
        Reply::Err(e) => e,
        Reply::Ok(_) => panic!("expected an error reply"),
    }
}

fn create(c: &ServerCore, req: &CreateEnv) -> EnvCreated {
    let r = c.handle_create(&encode(req), Instant::now());
    decode::<Reply<EnvCreated>>(&r.reply)
        .unwrap()
        .into_result()
        .unwrap()
}

/// The `ResetResult` of resetting env `id` with no options.
fn reset(c: &ServerCore, id: &str) -> ResetResult {
    decode::<Reply<ResetResult>>(&c.handle_reset(id, &[], Gates::NONE).reply)
        .unwrap()
        .into_result()
        .unwrap()
}

/// The `StepResult` of stepping env `id` with `rows`.
fn step(c: &ServerCore, id: &str, rows: &[[f32; 2]]) -> StepResult {
    let payload = encode(&Step::from_rows(rows));
    decode::<Reply<StepResult>>(&c.handle_step(id, &payload, Gates::NONE).reply)
        .unwrap()
        .into_result()
        .unwrap()
}

#[test]
fn lifecycle_and_errors_without_zenoh() {
    let c = core(Limits::default());
    let mut req = CreateEnv::new("t");
    req.count = 2;
    let created = create(&c, &req);
    assert_eq!(created.env_ids, vec!["s-0", "s-1"]);
    let id = &created.env_ids[0];
    let step = encode(&Step::from_rows(&[[0.5, 0.0]]));
    assert_eq!(
        err_of(&c.handle_step(id, &step, Gates::NONE).reply).code,
        ErrorCode::NeedsReset
    );
    let r = c.handle_reset(id, &[], Gates::NONE);
    assert!(r.pubs.is_empty());
    let reset: ResetResult = decode::<Reply<ResetResult>>(&r.reply)
        .unwrap()
        .into_result()
        .unwrap();
    assert_eq!(reset.episode, 1);
    assert_eq!(
        reset.obs.node_ids.get(&[0, 0]),
        Some(reset.agents.iter().find(|a| a.external).unwrap().id)
    );
    // NaN leaves the env untouched.
    let nan = encode(&Step {
        actions: F64Array::new(vec![1, 2], &[f64::NAN, 0.0]).unwrap().into(),
    });
    let e = err_of(&c.handle_step(id, &nan, Gates::NONE).reply);
    assert_eq!(e.code, ErrorCode::NonFiniteAction);
    assert_eq!(e.env_id.as_deref(), Some(id.as_str()));
    let r = c.handle_step(id, &step, Gates::ALL);
    let s: StepResult = decode::<Reply<StepResult>>(&r.reply)
        .unwrap()
        .into_result()
        .unwrap();
    assert_eq!(s.step, 1);
    // With every gate open the three state topics are published.
    let topics: Vec<_> = r.pubs.iter().map(|p| p.topic).collect();
    assert!(topics.contains(&protocol::EnvTopic::States));
    assert!(topics.contains(&protocol::EnvTopic::RiskGraph));
    assert!(topics.contains(&protocol::EnvTopic::Uncertainty));
    // Codes for unknown / closed envs.
    assert_eq!(
        err_of(&c.handle_step("s-9", &step, Gates::NONE).reply).code,
        ErrorCode::UnknownEnv
    );
    assert_eq!(
        err_of(&c.handle_step("other-0", &step, Gates::NONE).reply).code,
        ErrorCode::UnknownEnv
    );
    assert!(decode::<Reply<Closed>>(&c.handle_close(id, &[]).reply)
        .unwrap()
        .into_result()
        .is_ok());
    assert_eq!(
        err_of(&c.handle_close(id, &[]).reply).code,
        ErrorCode::EnvClosed
    );
    assert_eq!(c.load(), 1);
}

#[test]
fn reaping_by_token_and_grace() {
    let c = core(Limits {
        trainer_grace: Duration::from_secs(10),
        ..Limits::default()
    });
    let t0 = Instant::now();
    c.trainer_alive("a");
    create(&c, &CreateEnv::new("a"));
    create(&c, &CreateEnv::new("b"));
    assert_eq!(c.load(), 2);
    assert!(c.sweep(t0 + Duration::from_secs(5)).is_empty());
    assert_eq!(
        c.sweep(t0 + Duration::from_secs(11)),
        vec!["s-1".to_string()]
    );
    assert_eq!(c.trainer_gone("a"), vec!["s-0".to_string()]);
    assert_eq!(c.load(), 0);
}

#[test]
fn limits() {
    let c = core(Limits {
        capacity: 3,
        max_batch: 2,
        max_agents: 8,
        ..Limits::default()
    });
    let mut req = CreateEnv::new("a");
    req.count = 3;
    let e = err_of(&c.handle_create(&encode(&req), Instant::now()).reply);
    assert_eq!(e.code, ErrorCode::LimitExceeded);
    req.count = 2;
    create(&c, &req);
    let e = err_of(&c.handle_create(&encode(&req), Instant::now()).reply);
    assert_eq!(e.code, ErrorCode::LimitExceeded, "{e}");
    assert!(e.message.contains("capacity"), "{e}");
    req.count = 1;
    req.max_agents = 9;
    let e = err_of(&c.handle_create(&encode(&req), Instant::now()).reply);
    assert_eq!(e.code, ErrorCode::LimitExceeded);
}

#[test]
fn a_lost_trainer_that_reconnects_within_the_grace_keeps_its_envs() {
    let c = core(Limits {
        reconnect_grace: Duration::from_secs(5),
        ..Limits::default()
    });
    let t0 = Instant::now();
    c.trainer_alive("a");
    c.trainer_alive("b");
    create(&c, &CreateEnv::new("a"));
    create(&c, &CreateEnv::new("b"));
    assert!(c.trainer_lost("a", t0).is_empty());
    assert!(c.trainer_lost("b", t0).is_empty());
    c.trainer_alive("a"); // a's token is back within the grace
    assert!(c.sweep(t0 + Duration::from_secs(4)).is_empty());
    assert_eq!(
        c.sweep(t0 + Duration::from_secs(6)),
        vec!["s-1".to_string()]
    );
    assert_eq!(c.load(), 1);
    // without a reconnect grace a lost trainer is reaped at once
    let now = core(Limits::default());
    create(&now, &CreateEnv::new("a"));
    assert_eq!(now.trainer_lost("a", t0), vec!["s-0".to_string()]);
}

#[test]
fn a_trainer_at_its_quota_leaves_room_for_another() {
    let c = core(Limits {
        capacity: 8,
        max_envs_per_trainer: 3,
        ..Limits::default()
    });
    let mut req = CreateEnv::new("greedy");
    req.count = 3;
    create(&c, &req);
    req.count = 1;
    let e = err_of(&c.handle_create(&encode(&req), Instant::now()).reply);
    assert_eq!(e.code, ErrorCode::LimitExceeded);
    assert!(e.message.contains("max_envs_per_trainer"), "{e}");
    assert!(e.message.contains("greedy"), "{e}");
    let mut other = CreateEnv::new("modest");
    other.count = 2;
    let created = create(&c, &other);
    let id = &created.env_ids[0];
    assert!(c.handle_reset(id, &[], Gates::NONE).reply.len() > 16);
    let step = encode(&Step::from_rows(&[[0.5, 0.0]]));
    let r = c.handle_step(id, &step, Gates::NONE);
    assert!(decode::<Reply<StepResult>>(&r.reply)
        .unwrap()
        .into_result()
        .is_ok());
    // closing frees the quota
    decode::<Reply<Closed>>(&c.handle_close(&created.env_ids[1], &[]).reply)
        .unwrap()
        .into_result()
        .unwrap();
    assert_eq!(c.load(), 4);
}

#[test]
fn synthetic_scenes_with_two_controlled_vehicles_are_created_and_stepped() {
    let c = core(Limits::default());
    let mut req = CreateEnv::new("syn");
    req.external_agents = vec!["vehicle_0".into(), "vehicle_1".into()];
    req.max_agents = 16;
    req.synthetic = Some(SyntheticScenes {
        layout: "counter_flow".into(),
        pedestrians: 60,
        vehicles: 2,
        seed: 7,
        scenes: 3,
        ..SyntheticScenes::default()
    });
    let created = create(&c, &req);
    let id = &created.env_ids[0];
    let reset = reset(&c, id);
    assert!(reset
        .scenario
        .starts_with("synthetic-counter_flow-n60-v2-seed"));
    assert_eq!(reset.agents.len(), 62);
    let r = step(&c, id, &[[0.5, 0.0], [0.0, 0.1]]);
    assert_eq!(r.reward.len(), 2);
    // Refused with a message that names the problem, and nothing is created.
    let load = c.load();
    for (change, needle) in [
        (
            Box::new(|r: &mut CreateEnv| r.pool = Some("hbs-paper".into()))
                as Box<dyn Fn(&mut CreateEnv)>,
            "exclude each other",
        ),
        (
            Box::new(|r: &mut CreateEnv| r.synthetic.as_mut().unwrap().layout = "spiral".into()),
            "synthetic.layout",
        ),
        (
            Box::new(|r: &mut CreateEnv| r.synthetic.as_mut().unwrap().pedestrians = 5_000),
            "synthetic.pedestrians",
        ),
        (
            Box::new(|r: &mut CreateEnv| r.synthetic.as_mut().unwrap().vehicles = 1),
            "2 vehicle",
        ),
        (
            Box::new(|r: &mut CreateEnv| r.synthetic.as_mut().unwrap().scenes = 0),
            "synthetic.scenes",
        ),
        (
            Box::new(|r: &mut CreateEnv| r.synthetic.as_mut().unwrap().density = -1.0),
            "density",
        ),
        (
            Box::new(|r: &mut CreateEnv| r.synthetic.as_mut().unwrap().vehicles = 0),
            "vehicles",
        ),
        (
            Box::new(|r: &mut CreateEnv| r.synthetic.as_mut().unwrap().routes = "ring".into()),
            "synthetic.routes",
        ),
        (
            Box::new(|r: &mut CreateEnv| {
                let s = r.synthetic.as_mut().unwrap();
                (s.routes, s.vehicles) = ("intersection".into(), 5);
            }),
            "4 arms",
        ),
    ] {
        let mut bad_req = req.clone();
        change(&mut bad_req);
        let e = err_of(&c.handle_create(&encode(&bad_req), Instant::now()).reply);
        assert!(e.message.contains(needle), "{needle}: {e}");
    }
    assert_eq!(c.load(), load);
}

#[test]
fn pedestrians_are_external_agents_beside_the_car_and_bad_names_are_refused() {
    let c = core(Limits::default());
    let mut req = CreateEnv::new("peds");
    req.external_agents = vec!["vehicle_0".into(), "pedestrian_1".into()];
    req.scenario = Some("hbs-car1116".into());
    let created = create(&c, &req);
    assert_eq!(created.external_agents, req.external_agents);
    let id = &created.env_ids[0];
    let reset = reset(&c, id);
    let ped = reset
        .agents
        .iter()
        .find(|a| a.name == "pedestrian_1")
        .expect("pedestrian_1 is present at the start of hbs-car1116");
    assert!(ped.external && ped.kind == protocol::AgentKind::Pedestrian);
    // its observation row: node 0 is itself
    assert_eq!(reset.obs.node_ids.get(&[1, 0]), Some(ped.id));
    assert_eq!(step(&c, id, &[[0.5, 0.0], [1.0, 0.5]]).reward.len(), 2);
    // A non-finite pedestrian action is refused by name and leaves the env as it was.
    let nan = encode(&Step::from_rows(&[[0.0, 0.0], [f32::NAN, 0.0]]));
    let e = err_of(&c.handle_step(id, &nan, Gates::NONE).reply);
    assert_eq!(e.code, ErrorCode::NonFiniteAction);
    assert!(e.message.starts_with("pedestrian_1: "), "{}", e.message);
    // Refused with a message that names the problem, and nothing is created.
    let load = c.load();
    for (names, scenario, needle) in [
        (
            vec!["pedestrian_01"],
            None,
            "\"pedestrian_01\": expected vehicle_{k}",
        ),
        (vec!["walker_0"], None, "\"walker_0\""),
        (
            vec!["vehicle_0", "pedestrian_3"],
            None,
            "no scenario with 1 vehicle(s) and 4 pedestrian(s)",
        ),
        (
            vec!["pedestrian_3"],
            Some("hbs-car1116"),
            "has fewer than 4 pedestrian(s)",
        ),
    ] {
        let mut bad_req = CreateEnv::new("peds");
        bad_req.external_agents = names.iter().map(|n| n.to_string()).collect();
        bad_req.scenario = scenario.map(String::from);
        let r = c.handle_create(&encode(&bad_req), Instant::now());
        let e = err_of(&r.reply);
        assert_eq!(e.code, ErrorCode::BadRequest, "{names:?}");
        assert!(e.message.contains(needle), "{names:?}: {}", e.message);
    }
    assert_eq!(c.load(), load);
}

#[test]
fn an_oversized_request_is_refused_before_decoding() {
    let c = core(Limits {
        max_request_bytes: 64,
        ..Limits::default()
    });
    assert!(c.refuse_oversized(64).is_none());
    let refused = c.refuse_oversized(65).expect("refused");
    let e = err_of(&refused.reply);
    assert_eq!(e.code, ErrorCode::LimitExceeded);
    assert!(
        e.message.contains("65 bytes") && e.message.contains("not decoded"),
        "{e}"
    );
    assert!(refused.pubs.is_empty() && refused.realtime_envs.is_empty());
    assert_eq!(c.load(), 0);
}

#[test]
fn threaded_batch_equals_single_steps() {
    let mut c = core(Limits::default());
    c.set_batch_threads(3);
    let k = 2 * PARALLEL_MIN_BATCH + 3;
    let mut req = CreateEnv::new("a");
    req.count = k as u32;
    req.autoreset = true;
    let a = create(&c, &req).env_ids;
    let b = create(&c, &req).env_ids;
    for id in a.iter().chain(&b) {
        c.handle_reset(id, &[], Gates::NONE);
    }
    let (mut resets, mut events) = (0, 0);
    // Enough rounds for episodes to end (collisions, arrivals) and restart.
    for round in 0..40 {
        let vals: Vec<f32> = (0..k)
            .flat_map(|i| [((i + round) as f32 * 0.1).sin(), 0.05])
            .collect();
        let batch = encode(&BatchStep {
            env_ids: a.clone(),
            actions: protocol::F32Array::new(vec![k as u32, 1, 2], &vals)
                .unwrap()
                .into(),
        });
        let r: BatchStepResult =
            decode::<Reply<BatchStepResult>>(&c.handle_batch(&batch, &Gates::NONE).reply)
                .unwrap()
                .into_result()
                .unwrap();
        let singles: Vec<StepResult> = b
            .iter()
            .enumerate()
            .map(|(i, id)| {
                let step = encode(&Step::from_rows(&[[vals[2 * i], vals[2 * i + 1]]]));
                decode::<Reply<StepResult>>(&c.handle_step(id, &step, Gates::NONE).reply)
                    .unwrap()
                    .into_result()
                    .unwrap()
            })
            .collect();
        // The same transitions stacked (the reply names envs by position, so only the
        // ids differ).
        let mut want = BatchStepResult::from_results(singles).unwrap();
        want.env_ids = a.clone();
        assert_eq!(r, want, "round {round}");
        resets += r.resets.index.len();
        events += r.events.len();
    }
    assert!(resets > 0 && events > 0, "{resets} resets, {events} events");
}

/// The `ResetResult` of resetting env `id` to scenario `name`.
fn reset_to(c: &ServerCore, id: &str, name: &str) -> Result<ResetResult, ErrorReply> {
    let req = Reset {
        scenario: Some(name.into()),
        ..Reset::default()
    };
    decode::<Reply<ResetResult>>(&c.handle_reset(id, &encode(&req), Gates::NONE).reply)
        .unwrap()
        .into_result()
}

#[test]
fn composed_scenes_are_drawn_beside_the_recorded_ones_and_named_by_seed_and_index() {
    let c = core(Limits::default());
    let mut req = CreateEnv::new("composed");
    req.count = 1;
    req.composed = Some(ComposedScenes {
        scenes: Some(1000),
        seed: 5,
        hold_out: vec!["hbs-car1116".into()],
        ..ComposedScenes::default()
    });
    let id = &create(&c, &req).env_ids[0];
    let names: Vec<String> = (0..60).map(|_| reset(&c, id).scenario).collect();
    let composed = names
        .iter()
        .filter(|n| n.starts_with("composed-s5-"))
        .count();
    // 59 recorded train scenes beside 1 000 composed ones: nearly every draw is composed.
    assert!(composed >= 50, "{names:?}");
    assert!(names.iter().any(|n| n.starts_with("hbs-car")) || composed == 60);
    // A composed scene by name is the same scene every time; one past `scenes` is not there.
    let a = reset_to(&c, id, "composed-s5-17").unwrap();
    let b = reset_to(&c, id, "composed-s5-17").unwrap();
    assert_eq!((a.scenario.as_str(), a.agents.len()), ("composed-s5-17", 4));
    assert_eq!(a.obs, b.obs);
    let r = step(&c, id, &[[0.5, 0.0]]);
    assert_eq!(r.scenario, "composed-s5-17");
    let e = reset_to(&c, id, "composed-s5-1000").unwrap_err();
    assert!(e.message.contains("no scenario"), "{e}");
    // Unlimited: a fresh scene every episode, none recorded.
    req.composed.as_mut().unwrap().scenes = None;
    let id = &create(&c, &req).env_ids[0];
    let names: BTreeSet<String> = (0..40).map(|_| reset(&c, id).scenario).collect();
    assert_eq!(names.len(), 40);
    assert!(names.iter().all(|n| n.starts_with("composed-s5-")));
}

#[test]
fn a_composed_request_that_cannot_be_served_is_refused_by_name() {
    let c = core(Limits::default());
    let mut req = CreateEnv::new("composed");
    req.composed = Some(ComposedScenes::default());
    create(&c, &req);
    let load = c.load();
    type Change = Box<dyn Fn(&mut CreateEnv)>;
    let cases: Vec<(Change, &str)> = vec![
        (Box::new(|r| r.split = WireSplit::Test), "split train"),
        (
            Box::new(|r| r.external_agents = vec!["vehicle_0".into(), "vehicle_1".into()]),
            "vehicle_0",
        ),
        (
            Box::new(|r| r.composed.as_mut().unwrap().scenes = Some(0)),
            "composed.scenes",
        ),
        (
            Box::new(|r| r.composed.as_mut().unwrap().source = Some("hbs-papr".into())),
            "composed.source \"hbs-papr\"",
        ),
        (
            Box::new(|r| r.composed.as_mut().unwrap().hold_out = vec!["hbs-car0".into()]),
            "hbs-car0",
        ),
        (
            Box::new(|r| {
                r.composed
                    .as_mut()
                    .unwrap()
                    .shares
                    .insert("crosing".into(), 1.0);
            }),
            "crosing",
        ),
        (
            Box::new(|r| {
                r.composed
                    .as_mut()
                    .unwrap()
                    .shares
                    .insert("along".into(), -1.0);
            }),
            "along",
        ),
        (
            Box::new(|r| r.synthetic = Some(SyntheticScenes::default())),
            "exclude each other",
        ),
    ];
    for (change, needle) in cases {
        let mut bad_req = req.clone();
        change(&mut bad_req);
        let e = err_of(&c.handle_create(&encode(&bad_req), Instant::now()).reply);
        assert!(e.message.contains(needle), "{needle}: {e}");
    }
    assert_eq!(c.load(), load);
}

#[test]
fn excluded_scenarios_are_never_drawn_and_the_rest_keep_their_order() {
    let c = core(Limits::default());
    let held = ["hbs-car1116".to_string(), "hbs-car1130".to_string()];
    let mut req = CreateEnv::new("held");
    req.exclude = held.to_vec();
    let id = &create(&c, &req).env_ids[0];
    let drawn: BTreeSet<String> = (0..200).map(|_| reset(&c, id).scenario).collect();
    assert!(drawn.iter().all(|n| !held.contains(n)), "{drawn:?}");
    assert_eq!(drawn.len(), 59 - 2, "every other train scene is drawn");
    let e = reset_to(&c, id, "hbs-car1116").unwrap_err();
    assert!(e.message.contains("candidates"), "{e}");
    let mut unknown = req.clone();
    unknown.exclude = vec!["hbs-car0".into()];
    let e = err_of(&c.handle_create(&encode(&unknown), Instant::now()).reply);
    assert!(
        e.message.contains("exclude: no scenario \"hbs-car0\""),
        "{e}"
    );
    let mut pinned = req.clone();
    pinned.scenario = Some("hbs-car1130".into());
    let e = err_of(&c.handle_create(&encode(&pinned), Instant::now()).reply);
    assert!(e.message.contains("excluded"), "{e}");
}
