//! Round trips, named-map encoding, validation and robustness of the codec.

use std::collections::BTreeMap;

use proptest::prelude::*;
use protocol::samples;
use protocol::*;
use rmpv::Value;

fn value_of(bytes: &[u8]) -> Value {
    rmpv::decode::read_value(&mut &bytes[..]).expect("valid msgpack")
}

fn to_bytes(v: &Value) -> Vec<u8> {
    let mut out = Vec::new();
    rmpv::encode::write_value(&mut out, v).unwrap();
    out
}

fn map_get<'a>(v: &'a Value, key: &str) -> &'a Value {
    v.as_map()
        .unwrap_or_else(|| panic!("not a map: {v}"))
        .iter()
        .find(|(k, _)| k.as_str() == Some(key))
        .map(|(_, v)| v)
        .unwrap_or_else(|| panic!("no key {key} in {v}"))
}

fn roundtrip<T>(v: &T)
where
    T: serde::Serialize + serde::de::DeserializeOwned + PartialEq + std::fmt::Debug,
{
    let b = encode(v);
    assert!(
        matches!(b[0], 0x80..=0x8f | 0xde | 0xdf),
        "not a map: first byte {:#x}",
        b[0]
    );
    let back: T = decode(&b).unwrap();
    assert_eq!(&back, v);
    assert_eq!(encode(&back), b);
}

#[test]
fn every_message_round_trips() {
    roundtrip(&InfoRequest::default());
    roundtrip(&InfoRequest {
        protocol_version: Some(PROTOCOL_VERSION),
    });
    roundtrip(&samples::create_env());
    roundtrip(&CreateEnv::new("c"));
    roundtrip(&Reset::default());
    roundtrip(&Reset {
        seed: Some(1),
        scenario: Some("hbs_0001".into()),
        variation: Some(3),
    });
    roundtrip(&Step::from_rows(&[[0.5, -0.5], [1.0, 0.0]]));
    roundtrip(&BatchStep {
        env_ids: vec!["a".into()],
        actions: F64Array::new(vec![1, 1, 2], &[0.1, 0.2]).unwrap().into(),
    });
    roundtrip(&Close {});
    roundtrip(&ActionMsg {
        action: F64Array::from_slice(&[0.1, -0.1]).into(),
        seq: 3,
    });
    roundtrip(&Reply::Ok(samples::server_info()));
    roundtrip(&Reply::Ok(samples::reset_result()));
    roundtrip(&Reply::Ok(samples::step_result()));
    roundtrip(&Reply::Ok(samples::step_result_done()));
    roundtrip(&Reply::Ok(samples::batch_step_result()));
    roundtrip(&Reply::Ok(Closed {
        env_ids: vec!["x".into()],
    }));
    roundtrip(&Reply::<Closed>::error(ErrorCode::UnknownEnv, "no env x"));
    roundtrip(&samples::states());
    roundtrip(&samples::uncertainty());
    roundtrip(&samples::risk_graph());
    roundtrip(&samples::events());
    for s in samples::all() {
        s.verify(&s.bytes).unwrap();
    }
}

#[test]
fn structs_are_named_maps() {
    let v = value_of(&encode(&samples::create_env()));
    assert_eq!(map_get(&v, "client_id").as_str(), Some("trainer-a"));
    assert_eq!(map_get(&v, "pedestrian_model").as_str(), Some("cr_sfm"));
    assert_eq!(map_get(&v, "split").as_str(), Some("train"));
    assert_eq!(map_get(&v, "mode").as_str(), Some("lockstep"));
    assert_eq!(map_get(&v, "scenario"), &Value::Nil);
    let p = map_get(&v, "pedestrian_params");
    assert_eq!(map_get(p, "lambda1").as_f64(), Some(1.5));

    let v = value_of(&encode(&samples::states()));
    let pos = map_get(&v, "positions");
    assert_eq!(map_get(pos, "dtype").as_str(), Some("<f8"));
    assert_eq!(
        map_get(pos, "shape"),
        &Value::Array(vec![Value::from(3u32), Value::from(2u32)])
    );
    let Value::Binary(data) = map_get(pos, "data") else {
        panic!("data is not bin")
    };
    assert_eq!(data.len(), 6 * 8);
    assert_eq!(&data[..8], &10.0f64.to_le_bytes());
    assert_eq!(map_get(map_get(&v, "kinds"), "dtype").as_str(), Some("|u1"));
    assert_eq!(map_get(map_get(&v, "ids"), "dtype").as_str(), Some("<u4"));
}

#[test]
fn reply_envelope() {
    let ok = value_of(&encode(&Reply::Ok(Closed {
        env_ids: vec!["e".into()],
    })));
    let m = ok.as_map().unwrap();
    assert_eq!(m.len(), 1);
    assert_eq!(m[0].0.as_str(), Some("ok"));

    let err = value_of(&encode(&Reply::<Closed>::Err(
        ErrorReply::new(ErrorCode::WrongShape, "bad").with_env("e"),
    )));
    let e = map_get(&err, "error");
    assert_eq!(map_get(e, "code").as_str(), Some("wrong_shape"));
    assert_eq!(map_get(e, "message").as_str(), Some("bad"));
    assert_eq!(map_get(e, "env_id").as_str(), Some("e"));

    // Neither / both keys are errors; unknown extra keys are ignored.
    let neither = to_bytes(&Value::Map(vec![]));
    assert!(decode::<Reply<Closed>>(&neither).is_err());
    let closed = value_of(&encode(&Closed { env_ids: vec![] }));
    let both = to_bytes(&Value::Map(vec![
        ("ok".into(), closed.clone()),
        (
            "error".into(),
            value_of(&encode(&ErrorReply::new(ErrorCode::Internal, "x"))),
        ),
    ]));
    assert!(decode::<Reply<Closed>>(&both).is_err());
    let extra = to_bytes(&Value::Map(vec![
        ("trace".into(), Value::from(5)),
        ("ok".into(), closed),
    ]));
    assert!(matches!(
        decode::<Reply<Closed>>(&extra).unwrap(),
        Reply::Ok(_)
    ));
}

#[test]
fn error_codes_snake_case() {
    let all = [
        (ErrorCode::BadRequest, "bad_request"),
        (ErrorCode::VersionMismatch, "version_mismatch"),
        (ErrorCode::UnknownEnv, "unknown_env"),
        (ErrorCode::NonFiniteAction, "non_finite_action"),
        (ErrorCode::WrongShape, "wrong_shape"),
        (ErrorCode::LimitExceeded, "limit_exceeded"),
        (ErrorCode::EnvClosed, "env_closed"),
        (ErrorCode::NeedsReset, "needs_reset"),
        (ErrorCode::WrongMode, "wrong_mode"),
        (ErrorCode::Internal, "internal"),
    ];
    for (code, s) in all {
        assert_eq!(code.as_str(), s);
        assert_eq!(value_of(&encode(&code)).as_str(), Some(s));
        assert_eq!(decode::<ErrorCode>(&encode(&code)).unwrap(), code);
    }
    // Future codes decode as Unknown rather than failing.
    let future = to_bytes(&Value::from("too_many_pigeons"));
    assert_eq!(decode::<ErrorCode>(&future).unwrap(), ErrorCode::Unknown);
}

#[test]
fn create_env_defaults_from_minimal_map() {
    let minimal = to_bytes(&Value::Map(vec![
        ("protocol_version".into(), Value::from(PROTOCOL_VERSION)),
        ("client_id".into(), Value::from("c1")),
    ]));
    let c: CreateEnv = decode(&minimal).unwrap();
    assert_eq!(c, CreateEnv::new("c1"));
    assert_eq!(c.external_agents, vec!["vehicle_0".to_string()]);
    assert_eq!(c.max_agents, 8);
    assert_eq!(c.count, 1);
    c.validate().unwrap();

    // Unknown fields are ignored (forward compatibility).
    let extra = to_bytes(&Value::Map(vec![
        ("protocol_version".into(), Value::from(PROTOCOL_VERSION)),
        ("client_id".into(), Value::from("c1")),
        ("future_field".into(), Value::from(true)),
    ]));
    assert_eq!(decode::<CreateEnv>(&extra).unwrap(), CreateEnv::new("c1"));

    // Missing required field names it.
    let missing = to_bytes(&Value::Map(vec![("client_id".into(), Value::from("c1"))]));
    let e = decode::<CreateEnv>(&missing).unwrap_err().to_string();
    assert!(
        e.contains("CreateEnv") && e.contains("protocol_version"),
        "{e}"
    );
}

#[test]
fn create_env_validation() {
    let mut c = CreateEnv::new("c1");
    c.protocol_version = PROTOCOL_VERSION + 1;
    assert_eq!(c.validate().unwrap_err().code, ErrorCode::VersionMismatch);
    let mut c = CreateEnv::new("a/b");
    assert_eq!(c.validate().unwrap_err().code, ErrorCode::BadRequest);
    c.client_id = "ok".into();
    c.external_agents = vec!["vehicle_0".into(), "vehicle_0".into()];
    assert!(c.validate().is_err());
    c.external_agents = vec![];
    assert!(c.validate().is_err());
    c.external_agents = vec!["vehicle_0".into()];
    c.reward_weights.insert("colision".into(), 1.0);
    let e = c.validate().unwrap_err();
    assert!(e.message.contains("colision") && e.message.contains("collision"));
    c.reward_weights = BTreeMap::from([("collision".into(), f64::NAN)]);
    assert!(c.validate().is_err());
    c.reward_weights.clear();
    c.pedestrian_params.insert("tau".into(), f64::INFINITY);
    assert!(c.validate().is_err());
    c.pedestrian_params.clear();
    c.realtime_factor = 0.0;
    assert!(c.validate().is_err());
    c.realtime_factor = 2.0;
    c.count = 0;
    assert!(c.validate().is_err());
    c.count = 3;
    c.validate().unwrap();
    assert_eq!(c.effective_reward_weights()["success"], 10.0);
}

#[test]
fn action_checks() {
    let s = Step::from_rows(&[[0.5, -2.0]]);
    assert_eq!(s.checked_actions(1).unwrap(), vec![[0.5, -2.0]]);
    assert_eq!(
        s.checked_actions(2).unwrap_err().code,
        ErrorCode::WrongShape
    );
    let nan = Step {
        actions: F64Array::new(vec![1, 2], &[0.0, f64::NAN]).unwrap().into(),
    };
    assert_eq!(
        nan.checked_actions(1).unwrap_err().code,
        ErrorCode::NonFiniteAction
    );
    // NaN survives the wire and is still detected.
    let back: Step = decode(&encode(&nan)).unwrap();
    assert_eq!(
        back.checked_actions(1).unwrap_err().code,
        ErrorCode::NonFiniteAction
    );

    let b = BatchStep {
        env_ids: vec!["a".into(), "b".into()],
        actions: F32Array::new(vec![2, 1, 2], &[0.1, 0.2, f32::INFINITY, 0.0])
            .unwrap()
            .into(),
    };
    let e = b.checked_actions(1).unwrap_err();
    assert_eq!(e.code, ErrorCode::NonFiniteAction);
    assert_eq!(e.env_id.as_deref(), Some("b"));
    assert_eq!(
        b.checked_actions(2).unwrap_err().code,
        ErrorCode::WrongShape
    );
    let ok = BatchStep {
        env_ids: vec!["a".into(), "b".into()],
        actions: F32Array::new(vec![2, 1, 2], &[0.5, 0.25, -0.5, 0.0])
            .unwrap()
            .into(),
    };
    assert_eq!(
        ok.checked_actions(1).unwrap(),
        vec![vec![[0.5, 0.25]], vec![[-0.5, 0.0]]]
    );
    let dup = BatchStep {
        env_ids: vec!["a".into(), "a".into()],
        ..ok
    };
    assert_eq!(
        dup.checked_actions(1).unwrap_err().code,
        ErrorCode::BadRequest
    );

    let a = ActionMsg {
        action: F32Array::from_slice(&[0.25, 0.0]).into(),
        seq: 0,
    };
    assert_eq!(a.checked_action().unwrap(), [0.25, 0.0]);
}

fn array_map(dtype: &str, shape: &[u32], data: Vec<u8>) -> Value {
    Value::Map(vec![
        ("dtype".into(), Value::from(dtype)),
        (
            "shape".into(),
            Value::Array(shape.iter().map(|&d| Value::from(d)).collect()),
        ),
        ("data".into(), Value::Binary(data)),
    ])
}

#[test]
fn array_decode_validation() {
    // Length mismatch.
    let bad = to_bytes(&array_map("<f4", &[2, 3], vec![0; 20]));
    let e = decode::<F32Array>(&bad).unwrap_err().to_string();
    assert!(e.contains("F32") || e.contains("NdArray"), "{e}");
    assert!(
        e.contains("length mismatch") && e.contains("24 bytes"),
        "{e}"
    );
    // Dtype mismatch.
    let wrong = to_bytes(&array_map("<f8", &[2], vec![0; 16]));
    let e = decode::<F32Array>(&wrong).unwrap_err().to_string();
    assert!(e.contains("dtype mismatch"), "{e}");
    assert!(decode::<F64Array>(&wrong).is_ok());
    // FloatArray accepts both float dtypes, not ints.
    assert!(matches!(
        decode::<FloatArray>(&wrong).unwrap(),
        FloatArray::F64(_)
    ));
    let ints = to_bytes(&array_map("<u4", &[2], vec![0; 8]));
    assert!(decode::<FloatArray>(&ints).is_err());
    assert!(decode::<U32Array>(&ints).is_ok());
    // Missing field.
    let missing = to_bytes(&Value::Map(vec![("dtype".into(), Value::from("|u1"))]));
    assert!(decode::<U8Array>(&missing).is_err());
    // Overflowing shape.
    let huge = to_bytes(&array_map("|u1", &[u32::MAX, u32::MAX, u32::MAX], vec![]));
    assert!(decode::<U8Array>(&huge).is_err());
    // Data as a msgpack array instead of bin is rejected.
    let not_bin = to_bytes(&Value::Map(vec![
        ("dtype".into(), Value::from("|u1")),
        ("shape".into(), Value::Array(vec![Value::from(1)])),
        ("data".into(), Value::Array(vec![Value::from(1)])),
    ]));
    assert!(decode::<U8Array>(&not_bin).is_err());

    // A mismatch deep inside a message names the message type.
    let mut states = value_of(&encode(&samples::states()));
    if let Value::Map(entries) = &mut states {
        for (k, v) in entries.iter_mut() {
            if k.as_str() == Some("headings") {
                *v = array_map("<f8", &[3], vec![0; 16]);
            }
        }
    }
    let e = decode::<StatesMsg>(&to_bytes(&states)).unwrap_err();
    assert!(matches!(e, ProtocolError::Decode { .. }));
    let e = e.to_string();
    assert!(
        e.contains("StatesMsg") && e.contains("length mismatch"),
        "{e}"
    );
}

#[test]
fn obs_helpers() {
    let o = ObsBatch::empty(2, 4).unwrap();
    o.check(None, 2, 4).unwrap();
    assert!(o.check(None, 1, 4).is_err());
    assert_eq!(o.node_ids.to_vec(), vec![PAD_NODE_ID; 8]);
    let s = ObsBatch::stack(&[o.clone(), o]).unwrap();
    s.check(Some(2), 2, 4).unwrap();
    assert_eq!(s.features.shape(), &[2, 2, 4, 11]);

    let b = samples::batch_step_result();
    b.obs.check(Some(2), 1, samples::MAX_AGENTS).unwrap();
    assert_eq!(b.reward.shape(), &[2, 1]);
    assert_eq!(b.reward.to_vec(), vec![-1.125, 11.875]);
    assert_eq!(b.terminated.to_vec(), vec![0, 1]);
    assert_eq!(b.resets.index.to_vec(), vec![1]);
    assert_eq!(b.resets.episode.to_vec(), vec![4]);
    b.resets.obs.check(Some(1), 1, samples::MAX_AGENTS).unwrap();
}

#[test]
fn wrong_type_names_expected() {
    let e = decode::<StepResult>(&encode(&samples::states()))
        .unwrap_err()
        .to_string();
    assert!(e.starts_with("cannot decode StepResult"), "{e}");
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

    #[test]
    fn garbage_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..256)) {
        let _ = decode::<Reply<StepResult>>(&bytes);
        let _ = decode::<Reply<BatchStepResult>>(&bytes);
        let _ = decode::<CreateEnv>(&bytes);
        let _ = decode::<Step>(&bytes);
        let _ = decode::<BatchStep>(&bytes);
        let _ = decode::<StatesMsg>(&bytes);
        let _ = decode::<RiskGraphMsg>(&bytes);
        let _ = decode::<F32Array>(&bytes);
        let _ = decode::<FloatArray>(&bytes);
    }

    #[test]
    fn mutated_samples_never_panic(idx in 0usize..20, pos in any::<usize>(), byte in any::<u8>(), cut in any::<usize>()) {
        let all = samples::all();
        let s = &all[idx % all.len()];
        let mut b = s.bytes.clone();
        let p = pos % b.len();
        b[p] = byte;
        let _ = s.verify(&b);
        b.truncate(cut % (b.len() + 1));
        let _ = s.verify(&b);
    }

    #[test]
    fn f32_arrays_round_trip(values in proptest::collection::vec(any::<f32>(), 0..64)) {
        let a = F32Array::from_slice(&values);
        let back: F32Array = decode(&encode(&a)).unwrap();
        prop_assert_eq!(back.as_le_bytes(), a.as_le_bytes());
        prop_assert_eq!(back.shape(), a.shape());
    }
}
