//! Every writer against `rmp_serde`'s encoding of the same message, byte for byte.

use super::*;
use crate::messages::*;
use crate::{encode, F32Array, U32Array, U8Array};

/// The K step results a batch sample stacks (`with_extras`: events, metrics and autoresets
/// on some envs).
fn sample_steps(k: usize, n: usize, m: usize, with_extras: bool) -> Vec<StepResult> {
    let f = N_FEATURES as usize;
    let fl = |len: usize, s: f32| -> Vec<f32> {
        (0..len).map(|i| (i as f32 * 0.37 + s).sin()).collect()
    };
    let sh = |rest: &[usize]| -> Vec<u32> { rest.iter().map(|&d| d as u32).collect() };
    let reset = crate::samples::reset_result();
    let reset_obs = |i: usize| ObsBatch {
        features: F32Array::new(sh(&[n, m, f]), &fl(n * m * f, 0.9 + i as f32)).unwrap(),
        adjacency: F32Array::new(sh(&[n, m, m]), &fl(n * m * m, 1.1)).unwrap(),
        mask: U8Array::new(sh(&[n, m]), &vec![1; n * m]).unwrap(),
        node_ids: U32Array::new(sh(&[n, m]), &vec![7; n * m]).unwrap(),
    };
    (0..k)
        .map(|i| {
            let s = i as f32;
            StepResult {
                env_id: format!("srv-{}", i * 1000 + i * 7),
                episode: (i as u64) << (i % 40),
                scenario: "s".repeat(i % 300),
                step: (i as u32).wrapping_mul(2_654_435_761),
                t: i as f64 * 0.1,
                obs: ObsBatch {
                    features: F32Array::new(sh(&[n, m, f]), &fl(n * m * f, 0.1 + s)).unwrap(),
                    adjacency: F32Array::new(sh(&[n, m, m]), &fl(n * m * m, 0.2 + s)).unwrap(),
                    mask: U8Array::new(sh(&[n, m]), &vec![1; n * m]).unwrap(),
                    node_ids: U32Array::new(
                        sh(&[n, m]),
                        &(0..n * m)
                            .map(|j| {
                                if j % 3 == 0 {
                                    PAD_NODE_ID
                                } else {
                                    (i * 31 + j) as u32 * 977
                                }
                            })
                            .collect::<Vec<_>>(),
                    )
                    .unwrap(),
                },
                reward: F32Array::new(sh(&[n]), &fl(n, 0.3 + s)).unwrap(),
                reward_terms: RewardTerms {
                    progress: F32Array::new(sh(&[n]), &fl(n, 0.4 + s)).unwrap(),
                    success: F32Array::new(sh(&[n]), &fl(n, 0.5 + s)).unwrap(),
                    collision: F32Array::new(sh(&[n]), &fl(n, 0.6 + s)).unwrap(),
                    danger: F32Array::new(sh(&[n]), &fl(n, 0.7 + s)).unwrap(),
                    comfort: F32Array::new(sh(&[n]), &fl(n, 0.8 + s)).unwrap(),
                },
                terminated: U8Array::new(sh(&[n]), &vec![(i % 2) as u8; n]).unwrap(),
                truncated: U8Array::new(sh(&[n]), &vec![1; n]).unwrap(),
                info: StepInfo {
                    action_clipped: (0..n).map(|a| (a + i) % 2 == 0).collect(),
                    events: if with_extras && i % 2 == 0 {
                        vec![
                            Event {
                                kind: EventKind::EpisodeEnd,
                                step: 3,
                                t: 0.3,
                                agents: vec![1, 2],
                                outcome: Some(Outcome::Collision),
                            };
                            1 + i % 3
                        ]
                    } else {
                        Vec::new()
                    },
                    metrics: if with_extras && i % 3 == 0 {
                        vec![EpisodeMetrics {
                            agent: "vehicle_0".into(),
                            outcome: Outcome::Timeout,
                            steps: 40,
                            duration: 4.0,
                            episode_return: -1.5,
                            avg_speed: 3.0,
                            avg_abs_jerk: 0.2,
                            max_abs_acc: 1.1,
                        }]
                    } else {
                        Vec::new()
                    },
                },
                reset: (with_extras && i % 4 == 1).then(|| ResetResult {
                    env_id: format!("srv-{}", i * 1000 + i * 7),
                    episode: (i as u64) << (i % 40) | 1,
                    scenario: "r".repeat(i % 40),
                    obs: reset_obs(i),
                    variation: (i % 8 == 1).then(|| Variation {
                        seed: i as u64 * 31,
                        mirrored: false,
                        rotation_deg: 0.0,
                        param_scales: Default::default(),
                        pedestrians: Vec::new(),
                    }),
                    ..reset.clone()
                }),
            }
        })
        .collect()
}

/// The reply written directly from `steps`, in `chunks` envs at a time joined with
/// `BatchColumns::append` (as the server's batch threads do).
fn direct(steps: &[StepResult], chunk: usize) -> Vec<u8> {
    let r = BatchStepResult::from_results(steps.to_vec()).unwrap();
    let mut cols = BatchColumns::starting_at(0);
    for (c, part) in steps.chunks(chunk).enumerate() {
        let mut next = BatchColumns::starting_at((c * chunk) as u32);
        for s in part {
            next.push_env(&BatchEnvRef {
                episode: s.episode,
                scenario: &std::sync::Arc::from(s.scenario.as_str()),
                step: s.step,
                t: s.t,
                action_clipped: &s.info.action_clipped,
                events: &s.info.events,
                metrics: &s.info.metrics,
            });
            if let Some(reset) = &s.reset {
                next.push_reset(reset_parts(reset).as_batch_reset());
            }
        }
        if c == 0 {
            cols = next;
        } else {
            cols.append(next);
        }
    }
    let (o, t) = (&r.obs, &r.reward_terms);
    let shape = o.features.shape();
    let (features, adjacency, mask, node_ids) = (
        o.features.to_vec(),
        o.adjacency.to_vec(),
        o.mask.to_vec(),
        o.node_ids.to_vec(),
    );
    let terms: Vec<Vec<f32>> = [&t.progress, &t.success, &t.collision, &t.danger, &t.comfort]
        .iter()
        .map(|a| a.to_vec())
        .collect();
    let (reward, terminated, truncated) = (
        r.reward.to_vec(),
        r.terminated.to_vec(),
        r.truncated.to_vec(),
    );
    let a = BatchArrays {
        k: shape[0],
        obs: ObsRef {
            n_ext: shape[1],
            m: shape[2],
            features: &features,
            adjacency: &adjacency,
            mask: &mask,
            node_ids: &node_ids,
        },
        reward: &reward,
        terms: [&terms[0], &terms[1], &terms[2], &terms[3], &terms[4]],
        terminated: &terminated,
        truncated: &truncated,
    };
    let mut out = Vec::new();
    write_batch_step_ok(&mut out, &r.env_ids, &a, &cols).unwrap();
    out
}

/// Owned parts of a [`BatchReset`].
struct ResetParts {
    r: ResetResult,
    features: Vec<f32>,
    adjacency: Vec<f32>,
    mask: Vec<u8>,
    node_ids: Vec<u32>,
}

impl ResetParts {
    fn as_batch_reset(&self) -> BatchReset<'_> {
        let shape = self.r.obs.features.shape();
        BatchReset {
            episode: self.r.episode,
            scenario: &self.r.scenario,
            horizon_steps: self.r.horizon_steps,
            agents: self.r.agents.clone(),
            variation: self.r.variation.as_ref().map(|v| v.seed),
            obs: ObsRef {
                n_ext: shape[0],
                m: shape[1],
                features: &self.features,
                adjacency: &self.adjacency,
                mask: &self.mask,
                node_ids: &self.node_ids,
            },
        }
    }
}

fn reset_parts(r: &ResetResult) -> ResetParts {
    ResetParts {
        r: r.clone(),
        features: r.obs.features.to_vec(),
        adjacency: r.obs.adjacency.to_vec(),
        mask: r.obs.mask.to_vec(),
        node_ids: r.obs.node_ids.to_vec(),
    }
}

#[test]
fn batch_reply_is_byte_identical_to_the_serde_encoding() {
    // Sizes that cross every MessagePack length class used: fix/8/16/32-bit bin and
    // array lengths, long scenario names, large episode and step numbers; written whole
    // and in chunks.
    for (k, n, m, extras) in [
        (1, 1, 1, false),
        (1, 1, 8, true),
        (3, 2, 8, true),
        (17, 1, 8, true),
        (300, 1, 8, true),
        (64, 3, 20, false),
    ] {
        let steps = sample_steps(k, n, m, extras);
        let want = encode(&Reply::Ok(
            BatchStepResult::from_results(steps.clone()).unwrap(),
        ));
        for chunk in [k, k.div_ceil(2), 7] {
            assert_eq!(
                direct(&steps, chunk),
                want,
                "k={k} n={n} m={m} chunk={chunk}"
            );
        }
    }
}

#[test]
fn batch_columns_name_each_env_by_position() {
    let steps = sample_steps(9, 2, 4, true);
    let r = BatchStepResult::from_results(steps.clone()).unwrap();
    assert_eq!(
        r.episode.to_vec(),
        steps.iter().map(|s| s.episode).collect::<Vec<_>>()
    );
    let events: Vec<u32> = r.events.iter().map(|e| e.index).collect();
    // Envs 0, 2, 4, 6, 8 have 1 + i % 3 events each.
    assert_eq!(events, [0, 2, 2, 2, 4, 4, 6, 8, 8, 8]);
    let metrics: Vec<u32> = r.metrics.iter().map(|m| m.index).collect();
    assert_eq!(metrics, [0, 3, 6]);
    assert_eq!(r.resets.index.to_vec(), [1, 5]);
    assert_eq!(r.resets.obs.features.shape(), [2, 2, 4, N_FEATURES]);
    let second = steps[5].reset.as_ref().unwrap().obs.features.to_vec();
    assert_eq!(r.resets.obs.features.to_vec()[second.len()..], second[..]);
    assert_eq!(r.action_clipped.shape(), [9, 2]);
    assert_eq!(r.action_clipped.to_vec()[..4], [1, 0, 0, 1]);
}

#[test]
fn columns_of_the_wrong_length_are_refused() {
    let steps = sample_steps(3, 1, 4, false);
    let mut full = direct(&steps, 3);
    full.clear();
    let r = BatchStepResult::from_results(steps).unwrap();
    let empty = BatchColumns::starting_at(0);
    let (f, a, mk, ids) = (
        r.obs.features.to_vec(),
        r.obs.adjacency.to_vec(),
        r.obs.mask.to_vec(),
        r.obs.node_ids.to_vec(),
    );
    let (rw, tm, tr) = (
        r.reward.to_vec(),
        r.terminated.to_vec(),
        r.truncated.to_vec(),
    );
    let arrays = BatchArrays {
        k: 3,
        obs: ObsRef {
            n_ext: 1,
            m: 4,
            features: &f,
            adjacency: &a,
            mask: &mk,
            node_ids: &ids,
        },
        reward: &rw,
        terms: [&rw, &rw, &rw, &rw, &rw],
        terminated: &tm,
        truncated: &tr,
    };
    assert!(write_batch_step_ok(&mut full, &r.env_ids, &arrays, &empty).is_err());
}

#[test]
fn golden_batch_sample_is_reproduced() {
    let steps = crate::samples::batch_steps();
    let r = crate::samples::batch_step_result();
    assert_eq!(direct(&steps, 1), encode(&Reply::Ok(r)));
}

#[test]
fn batch_step_decoding_equals_serde() {
    use crate::{decode, BatchStep, F32Array, F64Array};
    let mut cases = Vec::new();
    for (k, id_len) in [
        (1usize, 3usize),
        (15, 31),
        (16, 32),
        (300, 40),
        (3, 300),
        (2, 70_000),
    ] {
        let ids: Vec<String> = (0..k)
            .map(|i| format!("{i}{}", "é".repeat(id_len / 2)))
            .collect();
        let vals: Vec<f32> = (0..2 * k).map(|i| i as f32 * 0.25 - 1.0).collect();
        let f32req = BatchStep {
            env_ids: ids.clone(),
            actions: F32Array::new(vec![k as u32, 1, 2], &vals).unwrap().into(),
        };
        let vals64: Vec<f64> = vals.iter().map(|&v| f64::from(v)).collect();
        let f64req = BatchStep {
            env_ids: ids,
            actions: F64Array::new(vec![k as u32, 2], &vals64).unwrap().into(),
        };
        cases.push(encode(&f32req));
        cases.push(encode(&f64req));
    }
    for (i, c) in cases.iter().enumerate() {
        assert!(
            fast_batch_step(c).is_some(),
            "usual layout {i} read directly"
        );
    }
    // Malformed and unusual inputs: every prefix of a valid request, trailing bytes,
    // invalid UTF-8 in an id, an id as bin, fields in the other order, a struct as array.
    let valid = cases[2].clone();
    for cut in 0..valid.len() {
        cases.push(valid[..cut].to_vec());
    }
    let mut trailing = valid.clone();
    trailing.push(0xc0);
    cases.push(trailing);
    let mut bad_utf8 = valid.clone();
    let at = valid.iter().position(|&c| c == b'0').unwrap();
    bad_utf8[at] = 0xff;
    cases.push(bad_utf8);
    let mut as_bin = valid.clone();
    as_bin[at - 1] = 0xc4;
    cases.push(as_bin);
    cases.push(b"\x82\xa7actions\xc0\xa7env_ids\x90".to_vec());
    cases.push(b"\x82\xa7env_ids\xdd\xff\xff\xff\xff".to_vec());
    cases.push(b"\x92\x90\xc0".to_vec());
    for (i, c) in cases.iter().enumerate() {
        let want = decode::<BatchStep>(c).map_err(|e| e.to_string());
        let got = decode_batch_step(c).map_err(|e| e.to_string());
        assert_eq!(got, want, "case {i}");
    }
}

#[test]
fn array_views_are_byte_identical_to_their_arrays() {
    let values: Vec<f32> = (0..70_000).map(|i| i as f32 * 0.5 - 3.0).collect();
    for shape in [
        vec![],
        vec![0],
        vec![1],
        vec![3, 5],
        vec![70_000],
        vec![7, 10_000],
    ] {
        let n = crate::array::shape_len(&shape).unwrap();
        let view = ArrayView::new(shape.clone(), &values[..n]).unwrap();
        let owned = F32Array::new(shape, &values[..n]).unwrap();
        assert_eq!(encode(&view), encode(&owned), "shape {:?}", owned.shape());
    }
    let ids: Vec<u64> = vec![0, 1, u64::MAX];
    assert_eq!(
        encode(&ArrayView::new(vec![3], &ids).unwrap()),
        encode(&crate::U64Array::new(vec![3], &ids).unwrap())
    );
}

#[test]
fn array_views_of_the_wrong_length_are_refused() {
    assert!(ArrayView::<f32>::new(vec![2, 2], &[1.0; 3]).is_err());
    assert!(ArrayView::<u8>::new(vec![u32::MAX, u32::MAX, u32::MAX], &[]).is_err());
}
