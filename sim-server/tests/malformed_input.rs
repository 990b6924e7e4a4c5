//! Contract: every malformed or out-of-protocol request to every queryable (garbage bytes, wrong
//! types, unknown or closed env ids, NaN and infinite actions, wrong shapes and dtypes, oversized
//! batches and counts, limits) gets exactly one error reply with the documented code, changes no
//! env, and the server keeps serving every trainer afterwards.

mod common;

use common::{client, config, free_port, one_env, start, t};
use protocol::{
    encode, BatchStep, CreateEnv, ErrorCode, F32Array, F64Array, Mode, Reply, Reset, Step, U32Array,
};
use serde::Serialize;
use serde_json::json;
use sim_server::server::client::Client;

/// Sends raw bytes and returns the error code of the reply (panics on a success reply).
async fn code(c: &Client, key: &str, payload: Vec<u8>) -> ErrorCode {
    let bytes = t(c.raw(key, payload)).await.expect("a reply");
    match protocol::decode::<Reply<serde::de::IgnoredAny>>(&bytes).expect("a reply envelope") {
        Reply::Err(e) => {
            assert!(!e.message.is_empty());
            e.code
        }
        Reply::Ok(_) => panic!("expected an error reply on {key}"),
    }
}

fn json_msgpack(v: serde_json::Value) -> Vec<u8> {
    rmp_serde::to_vec_named(&v).unwrap()
}

#[derive(Serialize)]
struct IntStep {
    actions: U32Array,
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_queryable_answers_bad_input_with_an_error_code() {
    let mut cfg = config(free_port(), "srv-bad");
    cfg.capacity = 7;
    cfg.max_batch = 4;
    cfg.max_agents = 16;
    let server = start(cfg).await;
    let c = client(&server, "bad-trainer").await;
    let keys = c.keys().clone();
    let sid = "srv-bad";
    let garbage = vec![0xc1, 0xff, 0x00, 0x13, 0x37];

    // A healthy env of another trainer that must not be disturbed.
    let other = client(&server, "good-trainer").await;
    let good = one_env(&other).await;
    t(other.reset(
        &good,
        &Reset {
            seed: Some(5),
            scenario: None,
            variation: None,
        },
    ))
    .await
    .unwrap();

    // --- info
    let info = keys.server_info(sid).unwrap();
    for payload in [
        garbage.clone(),
        json_msgpack(json!({"protocol_version": "one"})),
    ] {
        assert_eq!(code(&c, &info, payload).await, ErrorCode::BadRequest);
    }

    // --- create
    let create = keys.env_create(sid).unwrap();
    let base = |f: &dyn Fn(&mut CreateEnv)| {
        let mut r = CreateEnv::new("bad-trainer");
        f(&mut r);
        encode(&r)
    };
    let cases: Vec<(Vec<u8>, ErrorCode)> = vec![
        (garbage.clone(), ErrorCode::BadRequest),
        (Vec::new(), ErrorCode::BadRequest),
        (
            json_msgpack(json!({"protocol_version": protocol::PROTOCOL_VERSION})),
            ErrorCode::BadRequest,
        ), // no client_id
        (
            json_msgpack(json!({"protocol_version": protocol::PROTOCOL_VERSION, "client_id": 5})),
            ErrorCode::BadRequest,
        ),
        (
            json_msgpack(
                json!({"protocol_version": protocol::PROTOCOL_VERSION, "client_id": "a", "count": -1}),
            ),
            ErrorCode::BadRequest,
        ),
        (
            json_msgpack(
                json!({"protocol_version": protocol::PROTOCOL_VERSION, "client_id": "a", "split": "dev"}),
            ),
            ErrorCode::BadRequest,
        ),
        (json_msgpack(json!([1, 2, 3])), ErrorCode::BadRequest),
        (
            base(&|r| r.protocol_version = protocol::PROTOCOL_VERSION + 1),
            ErrorCode::VersionMismatch,
        ),
        (base(&|r| r.count = 0), ErrorCode::BadRequest),
        (base(&|r| r.count = 5), ErrorCode::LimitExceeded),
        (base(&|r| r.max_agents = 17), ErrorCode::LimitExceeded),
        (base(&|r| r.max_agents = 0), ErrorCode::BadRequest),
        (base(&|r| r.client_id = "a/b".into()), ErrorCode::BadRequest),
        (
            base(&|r| r.pool = Some("nope".into())),
            ErrorCode::BadRequest,
        ),
        (
            base(&|r| r.scenario = Some("nope".into())),
            ErrorCode::BadRequest,
        ),
        (
            base(&|r| {
                r.reward_weights.insert("speed".into(), 1.0);
            }),
            ErrorCode::BadRequest,
        ),
        (
            base(&|r| {
                r.pedestrian_params.insert("nope".into(), 1.0);
            }),
            ErrorCode::BadRequest,
        ),
        (
            base(&|r| {
                r.pedestrian_params.insert("tau".into(), -1.0);
            }),
            ErrorCode::BadRequest,
        ),
        (
            base(&|r| {
                r.pedestrian_params.insert("tau".into(), f64::NAN);
            }),
            ErrorCode::BadRequest,
        ),
        (
            base(&|r| r.external_agents = vec!["pedestrian_3".into()]), // hbs-paper has 3
            ErrorCode::BadRequest,
        ),
        (
            base(&|r| r.external_agents = vec!["pedestrian_01".into()]),
            ErrorCode::BadRequest,
        ),
        (
            base(&|r| r.external_agents = vec!["vehicle_7".into()]),
            ErrorCode::BadRequest,
        ),
        (base(&|r| r.external_agents = vec![]), ErrorCode::BadRequest),
        (
            base(&|r| r.external_agents = vec!["vehicle_0".into(), "vehicle_0".into()]),
            ErrorCode::BadRequest,
        ),
        (
            base(&|r| r.realtime_factor = f64::INFINITY),
            ErrorCode::BadRequest,
        ),
    ];
    for (i, (payload, want)) in cases.into_iter().enumerate() {
        assert_eq!(code(&c, &create, payload).await, want, "create case {i}");
    }
    let mut four = CreateEnv::new("bad-trainer");
    four.count = 4;
    let envs = t(c.create(four.clone())).await.unwrap().env_ids;
    let mut small = CreateEnv::new("bad-trainer");
    small.max_agents = 4;
    let small_env = t(c.create(small)).await.unwrap().env_ids.remove(0);
    t(c.reset(&small_env, &Reset::default())).await.unwrap();
    let env = envs[0].clone();

    // --- reset
    let reset = keys.env_reset(sid, &env).unwrap();
    let unknown_scenario = Reset {
        scenario: Some("nope".into()),
        ..Reset::default()
    };
    let reset_cases = [
        (reset.clone(), garbage.clone(), ErrorCode::BadRequest),
        (
            reset.clone(),
            json_msgpack(json!({"seed": "x"})),
            ErrorCode::BadRequest,
        ),
        (
            reset.clone(),
            json_msgpack(json!({"seed": -3})),
            ErrorCode::BadRequest,
        ),
        (reset, encode(&unknown_scenario), ErrorCode::BadRequest),
        (
            keys.env_reset(sid, "srv-bad-999").unwrap(),
            Vec::new(),
            ErrorCode::UnknownEnv,
        ),
        (
            keys.env_reset(sid, "someone-else-0").unwrap(),
            Vec::new(),
            ErrorCode::UnknownEnv,
        ),
    ];
    for (i, (key, payload, want)) in reset_cases.into_iter().enumerate() {
        assert_eq!(code(&c, &key, payload).await, want, "reset case {i}");
    }

    // --- step
    let step = keys.env_step(sid, &env).unwrap();
    let ok_step = encode(&Step::from_rows(&[[0.1, 0.0]]));
    assert_eq!(
        code(&c, &step, ok_step.clone()).await,
        ErrorCode::NeedsReset
    );
    t(c.reset(&env, &Reset::default())).await.unwrap();
    let f64_step = |v: [f64; 2]| {
        encode(&Step {
            actions: F64Array::new(vec![1, 2], &v).unwrap().into(),
        })
    };
    let step_cases: Vec<(Vec<u8>, ErrorCode)> = vec![
        (garbage.clone(), ErrorCode::BadRequest),
        (Vec::new(), ErrorCode::BadRequest),
        (
            json_msgpack(json!({"actions": [0.1, 0.2]})),
            ErrorCode::BadRequest,
        ),
        (
            json_msgpack(json!({"actions": {"dtype": "<f4", "shape": [1, 2], "data": "abcdefgh"}})),
            ErrorCode::BadRequest,
        ),
        (
            encode(&IntStep {
                actions: U32Array::new(vec![1, 2], &[1, 2]).unwrap(),
            }),
            ErrorCode::BadRequest,
        ),
        (f64_step([f64::NAN, 0.0]), ErrorCode::NonFiniteAction),
        (f64_step([0.0, f64::INFINITY]), ErrorCode::NonFiniteAction),
        (
            f64_step([f64::NEG_INFINITY, 0.0]),
            ErrorCode::NonFiniteAction,
        ),
        (
            encode(&Step {
                actions: F32Array::new(vec![2, 2], &[0.0; 4]).unwrap().into(),
            }),
            ErrorCode::WrongShape,
        ),
        (
            encode(&Step {
                actions: F32Array::new(vec![2], &[0.0; 2]).unwrap().into(),
            }),
            ErrorCode::WrongShape,
        ),
        (
            encode(&Step {
                actions: F32Array::new(vec![1, 3], &[0.0; 3]).unwrap().into(),
            }),
            ErrorCode::WrongShape,
        ),
    ];
    for (i, (payload, want)) in step_cases.into_iter().enumerate() {
        assert_eq!(code(&c, &step, payload).await, want, "step case {i}");
    }
    assert_eq!(
        code(
            &c,
            &keys.env_step(sid, "srv-bad-999").unwrap(),
            ok_step.clone()
        )
        .await,
        ErrorCode::UnknownEnv
    );
    // A key whose env segment is not a valid env id ("create" is reserved).
    let weird = format!("{}/server/{sid}/env/create/step", keys.prefix());
    assert_eq!(
        code(&c, &weird, ok_step.clone()).await,
        ErrorCode::BadRequest
    );
    // None of the refused steps advanced the env.
    let s = t(c.step(&env, &[[0.1, 0.0]])).await.unwrap();
    assert_eq!(s.step, 1);

    // Realtime env: Step is wrong_mode.
    let mut rt = CreateEnv::new("bad-trainer");
    rt.mode = Mode::Realtime;
    let rt_env = t(c.create(rt)).await.unwrap().env_ids.remove(0);
    t(c.reset(&rt_env, &Reset::default())).await.unwrap();
    // Capacity: 7 envs, all open now (1 of the good trainer, 6 of this one).
    assert_eq!(
        code(&c, &create, encode(&CreateEnv::new("bad-trainer"))).await,
        ErrorCode::LimitExceeded
    );
    assert_eq!(
        code(&c, &keys.env_step(sid, &rt_env).unwrap(), ok_step.clone()).await,
        ErrorCode::WrongMode
    );

    // --- batch
    let batch = keys.batch_step(sid).unwrap();
    let b = |ids: &[&str], vals: &[f32]| {
        encode(&BatchStep {
            env_ids: ids.iter().map(|s| s.to_string()).collect(),
            actions: F32Array::new(vec![ids.len() as u32, 1, 2], vals)
                .unwrap()
                .into(),
        })
    };
    for e in &envs[1..] {
        t(c.reset(e, &Reset::default())).await.unwrap();
    }
    let ids: Vec<&str> = envs.iter().map(|s| s.as_str()).collect();
    let mut nan = vec![0.0f32; 8];
    nan[5] = f32::NAN;
    let batch_cases: Vec<(Vec<u8>, ErrorCode)> = vec![
        (garbage.clone(), ErrorCode::BadRequest),
        (json_msgpack(json!({"env_ids": "x"})), ErrorCode::BadRequest),
        (b(&[], &[]), ErrorCode::BadRequest),
        (
            b(&[ids[0], ids[1], ids[2], ids[3], ids[0]], &[0.0; 10]),
            ErrorCode::LimitExceeded,
        ),
        (b(&[ids[0], ids[0]], &[0.0; 4]), ErrorCode::BadRequest),
        (
            b(&[ids[0], "srv-bad-999"], &[0.0; 4]),
            ErrorCode::UnknownEnv,
        ),
        (b(&ids, &nan), ErrorCode::NonFiniteAction),
        (b(&[ids[0], &rt_env], &[0.0; 4]), ErrorCode::WrongMode),
        (b(&[ids[0], &small_env], &[0.0; 4]), ErrorCode::WrongShape),
        (
            encode(&BatchStep {
                env_ids: vec![ids[0].into(), ids[1].into()],
                actions: F32Array::new(vec![2, 2], &[0.0; 4]).unwrap().into(),
            }),
            ErrorCode::WrongShape,
        ),
    ];
    for (i, (payload, want)) in batch_cases.into_iter().enumerate() {
        assert_eq!(code(&c, &batch, payload).await, want, "batch case {i}");
    }
    // The NaN batch named env 2 and advanced nobody: env 0 is still at step 1.
    let s = t(c.step(&env, &[[0.1, 0.0]])).await.unwrap();
    assert_eq!(s.step, 2);

    // --- close
    let close = keys.env_close(sid, &envs[3]).unwrap();
    assert_eq!(
        code(&c, &close, garbage.clone()).await,
        ErrorCode::BadRequest
    );
    t(c.close(&envs[3])).await.unwrap();
    assert_eq!(code(&c, &close, Vec::new()).await, ErrorCode::EnvClosed);
    assert_eq!(
        code(&c, &keys.env_step(sid, &envs[3]).unwrap(), ok_step.clone()).await,
        ErrorCode::EnvClosed
    );
    assert_eq!(
        code(&c, &keys.env_reset(sid, &envs[3]).unwrap(), Vec::new()).await,
        ErrorCode::EnvClosed
    );
    assert_eq!(
        code(&c, &keys.env_close(sid, "srv-bad-999").unwrap(), Vec::new()).await,
        ErrorCode::UnknownEnv
    );
    assert_eq!(
        code(&c, &batch, b(&[ids[0], ids[3]], &[0.0; 4])).await,
        ErrorCode::EnvClosed
    );

    // --- the server still serves, and the other trainer's env was not disturbed.
    let info = t(other.info()).await.unwrap();
    assert_eq!(info.server_id, sid);
    let s = t(other.step(&good, &[[0.2, 0.0]])).await.unwrap();
    assert_eq!(s.step, 1);
    let r = t(c.batch_step(&BatchStep {
        env_ids: vec![envs[1].clone(), envs[2].clone()],
        actions: F32Array::new(vec![2, 1, 2], &[0.1, 0.0, -0.1, 0.0])
            .unwrap()
            .into(),
    }))
    .await
    .unwrap();
    assert_eq!(r.env_ids.len(), 2);
    assert_eq!(r.obs.features.shape(), &[2, 1, 8, 11]);
    server.stop().await;
}

/// Contract: 256 malformed steps of an env whose second external agent is a pedestrian (NaN and
/// infinite numbers in its row, wrong shapes and dtypes, garbage) are each answered with an
/// error code, the non-finite ones naming `pedestrian_0` (in a `BatchStep` too); none advances the env, and the server
/// goes on serving it and another trainer.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn malformed_pedestrian_actions_leave_the_server_serving() {
    let server = start(config(free_port(), "srv-ped")).await;
    let c = client(&server, "ped-trainer").await;
    let other = client(&server, "car-trainer").await;
    let car = one_env(&other).await;
    t(other.reset(&car, &Reset::default())).await.unwrap();
    let mut req = CreateEnv::new("ped-trainer");
    req.external_agents = vec!["vehicle_0".into(), "pedestrian_0".into()];
    let env = t(c.create(req)).await.unwrap().env_ids.remove(0);
    t(c.reset(&env, &Reset::default())).await.unwrap();
    let key = c.keys().env_step("srv-ped", &env).unwrap();
    let rows = |ped: [f32; 2]| {
        encode(&Step {
            actions: F32Array::new(vec![2, 2], &[0.1, 0.0, ped[0], ped[1]])
                .unwrap()
                .into(),
        })
    };
    for i in 0..256u32 {
        let x = i as f32 / 64.0 - 2.0;
        let (payload, want) = match i % 8 {
            0 => (rows([f32::NAN, x]), ErrorCode::NonFiniteAction),
            1 => (rows([x, f32::INFINITY]), ErrorCode::NonFiniteAction),
            2 => (
                rows([f32::NEG_INFINITY, f32::NAN]),
                ErrorCode::NonFiniteAction,
            ),
            3 => (
                encode(&Step {
                    actions: F32Array::new(vec![1, 2], &[x, x]).unwrap().into(),
                }),
                ErrorCode::WrongShape,
            ),
            4 => (
                encode(&Step {
                    actions: F32Array::new(vec![2, 3], &[x; 6]).unwrap().into(),
                }),
                ErrorCode::WrongShape,
            ),
            5 => (
                encode(&IntStep {
                    actions: U32Array::new(vec![2, 2], &[i, 1, 2, 3]).unwrap(),
                }),
                ErrorCode::BadRequest,
            ),
            6 => (
                (0..(i % 31))
                    .map(|k| (k * 37 + i) as u8)
                    .chain([0xc1])
                    .collect(),
                ErrorCode::BadRequest,
            ),
            _ => (
                json_msgpack(json!({"actions": [[0.1, 0.0], [x, "walk"]]})),
                ErrorCode::BadRequest,
            ),
        };
        let bytes = t(c.raw(&key, payload)).await.expect("a reply");
        match protocol::decode::<Reply<serde::de::IgnoredAny>>(&bytes).expect("an envelope") {
            Reply::Err(e) => {
                assert_eq!(e.code, want, "case {i}: {}", e.message);
                if want == ErrorCode::NonFiniteAction {
                    assert!(e.message.starts_with("pedestrian_0: "), "{}", e.message);
                }
            }
            Reply::Ok(_) => panic!("case {i}: a malformed step was accepted"),
        }
    }
    // In a batch too, the non-finite action is named by its agent and its env.
    let err = t(c.batch_step(&BatchStep {
        env_ids: vec![env.clone()],
        actions: F32Array::new(vec![1, 2, 2], &[0.1, 0.0, 0.2, f32::NAN])
            .unwrap()
            .into(),
    }))
    .await
    .expect_err("a NaN in a batch");
    let text = err.to_string();
    assert!(
        text.contains("pedestrian_0: ") && text.contains(&env),
        "{text}"
    );
    // None of them advanced the env; it and the other trainer's env step on.
    let s = t(c.step(&env, &[[0.1, 0.0], [0.5, 0.5]])).await.unwrap();
    assert_eq!((s.step, s.reward.len()), (1, 2));
    let s = t(other.step(&car, &[[0.2, 0.0]])).await.unwrap();
    assert_eq!(s.step, 1);
    server.stop().await;
}
