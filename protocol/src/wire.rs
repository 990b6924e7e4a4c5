//! Direct MessagePack writing of the batch-step reply, the largest and most frequent message.
//!
//! [`encode`](crate::encode) of a `Reply<BatchStepResult>` needs the arrays as owned
//! [`NdArray`](crate::NdArray)s (one copy of every element into little-endian bytes) and the
//! per-env parts as owned [`BatchEnvInfo`](crate::BatchEnvInfo)s, and then copies everything
//! once more into the output. The writers here take borrowed slices and write the same bytes
//! straight into the output buffer: every function produces exactly what `rmp_serde`'s named
//! encoding of the corresponding message produces (the tests compare the two byte for byte).

use serde::Serialize;

use crate::array::{shape_len, ArrayError, Element};
use crate::messages::{AgentKind, EpisodeMetrics, Event};

fn put_u8s(out: &mut Vec<u8>, marker: u8, bytes: &[u8]) {
    out.push(marker);
    out.extend_from_slice(bytes);
}

/// A MessagePack unsigned integer in its shortest form (as `rmp::encode::write_uint`).
pub fn write_uint(out: &mut Vec<u8>, v: u64) {
    if v < 128 {
        out.push(v as u8);
    } else if v <= u64::from(u8::MAX) {
        put_u8s(out, 0xcc, &[v as u8]);
    } else if v <= u64::from(u16::MAX) {
        put_u8s(out, 0xcd, &(v as u16).to_be_bytes());
    } else if v <= u64::from(u32::MAX) {
        put_u8s(out, 0xce, &(v as u32).to_be_bytes());
    } else {
        put_u8s(out, 0xcf, &v.to_be_bytes());
    }
}

/// A MessagePack float 64.
pub fn write_f64(out: &mut Vec<u8>, v: f64) {
    put_u8s(out, 0xcb, &v.to_be_bytes());
}

/// A MessagePack boolean.
pub fn write_bool(out: &mut Vec<u8>, v: bool) {
    out.push(if v { 0xc3 } else { 0xc2 });
}

/// A MessagePack string.
pub fn write_str(out: &mut Vec<u8>, s: &str) {
    let n = s.len();
    if n < 32 {
        out.push(0xa0 | n as u8);
    } else if n <= usize::from(u8::MAX) {
        put_u8s(out, 0xd9, &[n as u8]);
    } else if n <= usize::from(u16::MAX) {
        put_u8s(out, 0xda, &(n as u16).to_be_bytes());
    } else {
        put_u8s(out, 0xdb, &(n as u32).to_be_bytes());
    }
    out.extend_from_slice(s.as_bytes());
}

/// A MessagePack array header of `n` elements.
pub fn write_array_len(out: &mut Vec<u8>, n: usize) {
    if n < 16 {
        out.push(0x90 | n as u8);
    } else if n <= usize::from(u16::MAX) {
        put_u8s(out, 0xdc, &(n as u16).to_be_bytes());
    } else {
        put_u8s(out, 0xdd, &(n as u32).to_be_bytes());
    }
}

/// A MessagePack map header of `n` entries.
pub fn write_map_len(out: &mut Vec<u8>, n: usize) {
    if n < 16 {
        out.push(0x80 | n as u8);
    } else if n <= usize::from(u16::MAX) {
        put_u8s(out, 0xde, &(n as u16).to_be_bytes());
    } else {
        put_u8s(out, 0xdf, &(n as u32).to_be_bytes());
    }
}

fn write_bin_len(out: &mut Vec<u8>, n: usize) {
    if n <= usize::from(u8::MAX) {
        put_u8s(out, 0xc4, &[n as u8]);
    } else if n <= usize::from(u16::MAX) {
        put_u8s(out, 0xc5, &(n as u16).to_be_bytes());
    } else {
        put_u8s(out, 0xc6, &(n as u32).to_be_bytes());
    }
}

/// Appends `value` with the named encoding of [`encode`](crate::encode).
fn write_named<T: Serialize + ?Sized>(out: &mut Vec<u8>, value: &T) {
    if let Err(e) = rmp_serde::encode::write_named(out, value) {
        // Writing into a Vec cannot fail, and the message types serialize infallibly.
        unreachable!("encoding into a Vec failed: {e}");
    }
}

/// An array in the wire layout of [`NdArray`](crate::NdArray) (`{dtype, shape, data}`), written
/// from row-major `values` of `shape`.
pub fn write_array<T: Element>(
    out: &mut Vec<u8>,
    shape: &[u32],
    values: &[T],
) -> Result<(), ArrayError> {
    let n = shape_len(shape)?;
    if values.len() != n {
        return Err(ArrayError::LengthMismatch {
            dtype: T::DTYPE,
            shape: shape.to_vec(),
            expected: n,
            expected_bytes: n.saturating_mul(T::SIZE),
            actual_bytes: values.len().saturating_mul(T::SIZE),
        });
    }
    let bytes = n
        .checked_mul(T::SIZE)
        .filter(|&b| u32::try_from(b).is_ok())
        .ok_or_else(|| ArrayError::ShapeOverflow {
            shape: shape.to_vec(),
        })?;
    write_map_len(out, 3);
    write_str(out, "dtype");
    write_str(out, T::DTYPE);
    write_str(out, "shape");
    write_array_len(out, shape.len());
    for &d in shape {
        write_uint(out, u64::from(d));
    }
    write_str(out, "data");
    write_bin_len(out, bytes);
    // Through a small stack buffer rather than `resize` + overwrite, so the output is written
    // once instead of zeroed first.
    out.reserve(bytes);
    const CHUNK: usize = 1024;
    let mut tmp = [0u8; CHUNK];
    for part in values.chunks(CHUNK / T::SIZE) {
        let n = part.len() * T::SIZE;
        T::write_all_le(part, &mut tmp[..n]);
        out.extend_from_slice(&tmp[..n]);
    }
    Ok(())
}

/// The stacked arrays of a batch step result: `k` envs of `n_ext` agents with `m` nodes each,
/// row-major with the env axis first.
#[derive(Debug, Clone, Copy)]
pub struct BatchArrays<'a> {
    pub k: u32,
    /// The `k` envs' observations, stacked (each array has a leading `k` axis).
    pub obs: ObsRef<'a>,
    pub reward: &'a [f32],
    /// progress, success, collision, danger, comfort.
    pub terms: [&'a [f32]; 5],
    pub terminated: &'a [u8],
    pub truncated: &'a [u8],
}

impl BatchArrays<'_> {
    /// Bytes of array data (a lower bound of the encoded size).
    pub fn data_bytes(&self) -> usize {
        let o = &self.obs;
        4 * (o.features.len() + o.adjacency.len() + o.node_ids.len())
            + o.mask.len()
            + 4 * 6 * self.reward.len()
            + 2 * self.terminated.len()
    }
}

/// Writes a whole `Reply::Ok(BatchStepResult)`: `env_ids`, the arrays, and `envs`, which must be
/// `env_ids.len()` entries already written with [`write_batch_env_info_head`] and their
/// `reset`, concatenated.
/// Byte-identical to `encode(&Reply::Ok(result))` of the equivalent owned result.
pub fn write_batch_step_ok(
    out: &mut Vec<u8>,
    env_ids: &[String],
    a: &BatchArrays<'_>,
    envs: &[u8],
) -> Result<(), ArrayError> {
    let (k, n) = (a.k, a.obs.n_ext);
    write_map_len(out, 1);
    write_str(out, "ok");
    write_map_len(out, 7);
    write_str(out, "env_ids");
    write_array_len(out, env_ids.len());
    for id in env_ids {
        write_str(out, id);
    }
    write_str(out, "obs");
    write_obs(out, Some(k), &a.obs)?;
    write_str(out, "reward");
    write_array(out, &[k, n], a.reward)?;
    write_str(out, "reward_terms");
    write_map_len(out, 5);
    for (name, t) in ["progress", "success", "collision", "danger", "comfort"]
        .iter()
        .zip(a.terms)
    {
        write_str(out, name);
        write_array(out, &[k, n], t)?;
    }
    write_str(out, "terminated");
    write_array(out, &[k, n], a.terminated)?;
    write_str(out, "truncated");
    write_array(out, &[k, n], a.truncated)?;
    write_str(out, "envs");
    write_array_len(out, env_ids.len());
    out.extend_from_slice(envs);
    Ok(())
}

/// The fields of one [`BatchEnvInfo`](crate::BatchEnvInfo), borrowed, but for `reset`.
#[derive(Debug, Clone, Copy)]
pub struct BatchEnvInfoRef<'a> {
    pub episode: u64,
    pub scenario: &'a str,
    pub step: u32,
    pub t: f64,
    pub action_clipped: &'a [bool],
    pub events: &'a [Event],
    pub metrics: &'a [EpisodeMetrics],
}

/// One `BatchEnvInfo` map (an element of `BatchStepResult::envs`) up to the value of its last
/// field, `reset`, which the caller writes next: [`write_nil`], or a `ResetResult` (e.g. with
/// [`write_reset_result`]).
pub fn write_batch_env_info_head(out: &mut Vec<u8>, e: &BatchEnvInfoRef<'_>) {
    // The constant runs of map headers and keys are pre-encoded (this runs once per env and
    // step); the tests check them against the serde encoding.
    out.extend_from_slice(b"\x86\xa7episode");
    write_uint(out, e.episode);
    out.extend_from_slice(b"\xa8scenario");
    write_str(out, e.scenario);
    out.extend_from_slice(b"\xa4step");
    write_uint(out, u64::from(e.step));
    out.extend_from_slice(b"\xa1t");
    write_f64(out, e.t);
    out.extend_from_slice(b"\xa4info\x83\xaeaction_clipped");
    write_array_len(out, e.action_clipped.len());
    for &c in e.action_clipped {
        write_bool(out, c);
    }
    out.extend_from_slice(b"\xa6events");
    if e.events.is_empty() {
        write_array_len(out, 0);
    } else {
        write_named(out, e.events);
    }
    out.extend_from_slice(b"\xa7metrics");
    if e.metrics.is_empty() {
        write_array_len(out, 0);
    } else {
        write_named(out, e.metrics);
    }
    out.extend_from_slice(b"\xa5reset");
}

/// MessagePack nil (an absent optional value).
pub fn write_nil(out: &mut Vec<u8>) {
    out.push(0xc0);
}

fn write_opt_f64(out: &mut Vec<u8>, v: Option<f64>) {
    match v {
        None => write_nil(out),
        Some(v) => write_f64(out, v),
    }
}

/// The fields of one [`AgentDesc`](crate::AgentDesc), borrowed.
#[derive(Debug, Clone, Copy)]
pub struct AgentDescRef<'a> {
    pub id: u32,
    pub name: &'a str,
    pub kind: AgentKind,
    pub external: bool,
    pub radius: f64,
    pub length: Option<f64>,
    pub width: Option<f64>,
}

/// One env's observation arrays (`[n_ext, m, F]`, `[n_ext, m, m]`, `[n_ext, m]`, `[n_ext, m]`).
#[derive(Debug, Clone, Copy)]
pub struct ObsRef<'a> {
    pub n_ext: u32,
    pub m: u32,
    pub features: &'a [f32],
    pub adjacency: &'a [f32],
    pub mask: &'a [u8],
    pub node_ids: &'a [u32],
}

/// The fields of a [`ResetResult`](crate::ResetResult), borrowed (`step` and `t` are always 0).
#[derive(Debug, Clone, Copy)]
pub struct ResetResultRef<'a> {
    pub env_id: &'a str,
    pub episode: u64,
    pub scenario: &'a str,
    pub horizon_steps: u32,
    /// In id order, as in `ResetResult::agents`.
    pub agents: &'a [AgentDescRef<'a>],
    pub obs: ObsRef<'a>,
}

/// Writes a `ResetResult` map, byte-identical to its serde encoding.
pub fn write_reset_result(out: &mut Vec<u8>, r: &ResetResultRef<'_>) -> Result<(), ArrayError> {
    out.extend_from_slice(b"\x88\xa6env_id");
    write_str(out, r.env_id);
    out.extend_from_slice(b"\xa7episode");
    write_uint(out, r.episode);
    out.extend_from_slice(b"\xa8scenario");
    write_str(out, r.scenario);
    // "step": 0, "t": 0.0
    out.extend_from_slice(b"\xa4step\x00\xa1t");
    write_f64(out, 0.0);
    out.extend_from_slice(b"\xadhorizon_steps");
    write_uint(out, u64::from(r.horizon_steps));
    out.extend_from_slice(b"\xa6agents");
    write_array_len(out, r.agents.len());
    for a in r.agents {
        out.extend_from_slice(b"\x87\xa2id");
        write_uint(out, u64::from(a.id));
        out.extend_from_slice(b"\xa4name");
        write_str(out, a.name);
        out.extend_from_slice(b"\xa4kind");
        write_str(
            out,
            match a.kind {
                AgentKind::Vehicle => "vehicle",
                AgentKind::Pedestrian => "pedestrian",
            },
        );
        out.extend_from_slice(b"\xa8external");
        write_bool(out, a.external);
        out.extend_from_slice(b"\xa6radius");
        write_f64(out, a.radius);
        out.extend_from_slice(b"\xa6length");
        write_opt_f64(out, a.length);
        out.extend_from_slice(b"\xa5width");
        write_opt_f64(out, a.width);
    }
    out.extend_from_slice(b"\xa3obs");
    write_obs(out, None, &r.obs)
}

/// Writes an observation map (`features`, `adjacency`, `mask`, `node_ids`), each array with a
/// leading axis of `k` envs when given (a batch), else of one env's shape.
fn write_obs(out: &mut Vec<u8>, k: Option<u32>, o: &ObsRef<'_>) -> Result<(), ArrayError> {
    let (n, m) = (o.n_ext, o.m);
    // Room for the longest shape, [k, n, m, F]; `lead` skips the k axis of a single env.
    let lead = usize::from(k.is_none());
    let k = k.unwrap_or(0);
    out.extend_from_slice(b"\x84\xa8features");
    write_array(out, &[k, n, m, crate::N_FEATURES][lead..], o.features)?;
    out.extend_from_slice(b"\xa9adjacency");
    write_array(out, &[k, n, m, m][lead..], o.adjacency)?;
    out.extend_from_slice(b"\xa4mask");
    write_array(out, &[k, n, m][lead..], o.mask)?;
    out.extend_from_slice(b"\xa8node_ids");
    write_array(out, &[k, n, m][lead..], o.node_ids)
}

/// [`decode`](crate::decode) of a [`BatchStep`](crate::BatchStep), with a direct reading of the
/// env ids in the usual layout (a map of `env_ids` then `actions`, ids as MessagePack strings):
/// through serde each id costs a copy into a staging buffer besides its allocation. Anything
/// else (other layouts, malformed input) goes through `decode`, so results and errors are
/// always those of `decode`.
pub fn decode_batch_step(bytes: &[u8]) -> Result<crate::BatchStep, crate::ProtocolError> {
    match fast_batch_step(bytes) {
        Some(req) => Ok(req),
        None => crate::decode(bytes),
    }
}

/// Reads `n` big-endian bytes as a length.
fn take_len(b: &mut &[u8], n: usize) -> Option<usize> {
    if b.len() < n {
        return None;
    }
    let (head, rest) = b.split_at(n);
    *b = rest;
    Some(
        head.iter()
            .fold(0usize, |acc, &x| (acc << 8) | usize::from(x)),
    )
}

fn take_str<'a>(b: &mut &'a [u8]) -> Option<&'a str> {
    let (&marker, mut rest) = b.split_first()?;
    let len = match marker {
        0xa0..=0xbf => usize::from(marker & 0x1f),
        0xd9 => take_len(&mut rest, 1)?,
        0xda => take_len(&mut rest, 2)?,
        0xdb => take_len(&mut rest, 4)?,
        _ => return None,
    };
    if rest.len() < len {
        return None;
    }
    let (s, tail) = rest.split_at(len);
    *b = tail;
    std::str::from_utf8(s).ok()
}

fn fast_batch_step(bytes: &[u8]) -> Option<crate::BatchStep> {
    let mut b = bytes.strip_prefix(b"\x82\xa7env_ids")?;
    let (&marker, mut rest) = b.split_first()?;
    let n = match marker {
        0x90..=0x9f => usize::from(marker & 0x0f),
        0xdc => take_len(&mut rest, 2)?,
        0xdd => take_len(&mut rest, 4)?,
        _ => return None,
    };
    b = rest;
    // Each id takes at least one byte: a count beyond that is malformed (and must not size an
    // allocation).
    if n > b.len() {
        return None;
    }
    let mut env_ids = Vec::with_capacity(n);
    for _ in 0..n {
        env_ids.push(take_str(&mut b)?.to_owned());
    }
    let b = b.strip_prefix(b"\xa7actions")?;
    let actions = crate::decode(b).ok()?;
    Some(crate::BatchStep { env_ids, actions })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::messages::*;
    use crate::{encode, F32Array, U32Array, U8Array};

    /// One whole `BatchEnvInfo` map, `reset` through serde (the reference the direct writers
    /// are checked against).
    fn write_batch_env_info(
        out: &mut Vec<u8>,
        e: &BatchEnvInfoRef<'_>,
        reset: Option<&ResetResult>,
    ) {
        write_batch_env_info_head(out, e);
        match reset {
            None => write_nil(out),
            Some(r) => write_named(out, r),
        }
    }

    fn sample_result(k: usize, n: usize, m: usize, with_extras: bool) -> BatchStepResult {
        let f = N_FEATURES as usize;
        let e = k * n;
        let fl = |len: usize, s: f32| -> Vec<f32> {
            (0..len).map(|i| (i as f32 * 0.37 + s).sin()).collect()
        };
        let sh = |rest: &[usize]| -> Vec<u32> {
            std::iter::once(k as u32)
                .chain(rest.iter().map(|&d| d as u32))
                .collect()
        };
        let reset = crate::samples::reset_result();
        BatchStepResult {
            env_ids: (0..k)
                .map(|i| format!("srv-{}", i * 1000 + i * 7))
                .collect(),
            obs: ObsBatch {
                features: F32Array::new(sh(&[n, m, f]), &fl(e * m * f, 0.1)).unwrap(),
                adjacency: F32Array::new(sh(&[n, m, m]), &fl(e * m * m, 0.2)).unwrap(),
                mask: U8Array::new(sh(&[n, m]), &vec![1; e * m]).unwrap(),
                node_ids: U32Array::new(
                    sh(&[n, m]),
                    &(0..e * m)
                        .map(|i| {
                            if i % 3 == 0 {
                                PAD_NODE_ID
                            } else {
                                i as u32 * 977
                            }
                        })
                        .collect::<Vec<_>>(),
                )
                .unwrap(),
            },
            reward: F32Array::new(sh(&[n]), &fl(e, 0.3)).unwrap(),
            reward_terms: RewardTerms {
                progress: F32Array::new(sh(&[n]), &fl(e, 0.4)).unwrap(),
                success: F32Array::new(sh(&[n]), &fl(e, 0.5)).unwrap(),
                collision: F32Array::new(sh(&[n]), &fl(e, 0.6)).unwrap(),
                danger: F32Array::new(sh(&[n]), &fl(e, 0.7)).unwrap(),
                comfort: F32Array::new(sh(&[n]), &fl(e, 0.8)).unwrap(),
            },
            terminated: U8Array::new(sh(&[n]), &vec![0; e]).unwrap(),
            truncated: U8Array::new(sh(&[n]), &vec![1; e]).unwrap(),
            envs: (0..k)
                .map(|i| BatchEnvInfo {
                    episode: (i as u64) << (i % 40),
                    scenario: "s".repeat(i % 300),
                    step: (i as u32).wrapping_mul(2_654_435_761),
                    t: i as f64 * 0.1,
                    info: StepInfo {
                        action_clipped: (0..n).map(|a| (a + i) % 2 == 0).collect(),
                        events: if with_extras && i % 2 == 0 {
                            vec![Event {
                                kind: EventKind::EpisodeEnd,
                                step: 3,
                                t: 0.3,
                                agents: vec![1, 2],
                                outcome: Some(Outcome::Collision),
                            }]
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
                    reset: (with_extras && i % 4 == 1).then(|| reset.clone()),
                })
                .collect(),
        }
    }

    fn direct(r: &BatchStepResult) -> Vec<u8> {
        let mut envs = Vec::new();
        for e in &r.envs {
            let info = BatchEnvInfoRef {
                episode: e.episode,
                scenario: &e.scenario,
                step: e.step,
                t: e.t,
                action_clipped: &e.info.action_clipped,
                events: &e.info.events,
                metrics: &e.info.metrics,
            };
            match &e.reset {
                // Both ways of writing the reset result.
                Some(r) if e.step % 2 == 0 => {
                    write_batch_env_info_head(&mut envs, &info);
                    write_reset_result(&mut envs, &reset_ref(r).as_ref()).unwrap();
                }
                r => write_batch_env_info(&mut envs, &info, r.as_ref()),
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
        write_batch_step_ok(&mut out, &r.env_ids, &a, &envs).unwrap();
        out
    }

    /// Owned parts of a [`ResetResultRef`].
    struct ResetParts {
        r: ResetResult,
        features: Vec<f32>,
        adjacency: Vec<f32>,
        mask: Vec<u8>,
        node_ids: Vec<u32>,
    }

    impl ResetParts {
        fn as_ref(&self) -> ResetResultRef<'_> {
            // Leaked: test-only, keeps the borrow simple.
            let agents: &'static [AgentDescRef<'static>] = Box::leak(
                self.r
                    .agents
                    .iter()
                    .map(|a| AgentDescRef {
                        id: a.id,
                        name: Box::leak(a.name.clone().into_boxed_str()),
                        kind: a.kind,
                        external: a.external,
                        radius: a.radius,
                        length: a.length,
                        width: a.width,
                    })
                    .collect::<Vec<_>>()
                    .into_boxed_slice(),
            );
            let shape = self.r.obs.features.shape();
            ResetResultRef {
                env_id: &self.r.env_id,
                episode: self.r.episode,
                scenario: &self.r.scenario,
                horizon_steps: self.r.horizon_steps,
                agents,
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

    fn reset_ref(r: &ResetResult) -> ResetParts {
        ResetParts {
            r: r.clone(),
            features: r.obs.features.to_vec(),
            adjacency: r.obs.adjacency.to_vec(),
            mask: r.obs.mask.to_vec(),
            node_ids: r.obs.node_ids.to_vec(),
        }
    }

    #[test]
    fn reset_result_is_byte_identical_to_the_serde_encoding() {
        let mut r = crate::samples::reset_result();
        for round in 0..3 {
            let mut out = Vec::new();
            write_reset_result(&mut out, &reset_ref(&r).as_ref()).unwrap();
            assert_eq!(out, encode(&r), "round {round}");
            // Longer names, more agents, large numbers.
            r.env_id = format!("{}-{}", r.env_id, "x".repeat(40));
            r.episode = r.episode * 1000 + 77_777;
            r.horizon_steps = r.horizon_steps * 300 + 1;
            let mut more = r.agents.clone();
            for a in &mut more {
                a.id += 1000 * (round + 1);
                a.name = format!("{}_{}", a.name, "n".repeat(30));
                a.length = a.length.or(Some(4.5));
            }
            r.agents.extend(more);
        }
    }

    #[test]
    fn batch_reply_is_byte_identical_to_the_serde_encoding() {
        // Sizes that cross every MessagePack length class used: fix/8/16/32-bit bin and
        // array lengths, long scenario names, large episode and step numbers.
        for (k, n, m, extras) in [
            (1, 1, 1, false),
            (1, 1, 8, true),
            (3, 2, 8, true),
            (17, 1, 8, true),
            (300, 1, 8, true),
            (64, 3, 20, false),
        ] {
            let r = sample_result(k, n, m, extras);
            let want = encode(&Reply::Ok(r.clone()));
            assert_eq!(direct(&r), want, "k={k} n={n} m={m}");
        }
    }

    #[test]
    fn golden_batch_sample_is_reproduced() {
        let r = crate::samples::batch_step_result();
        assert_eq!(direct(&r), encode(&Reply::Ok(r.clone())));
    }

    #[test]
    fn integers_and_strings_match_rmp() {
        for v in [
            0u64,
            1,
            127,
            128,
            255,
            256,
            65535,
            65536,
            u64::from(u32::MAX),
            u64::from(u32::MAX) + 1,
            u64::MAX,
        ] {
            let mut out = Vec::new();
            write_uint(&mut out, v);
            assert_eq!(out, encode(&v), "{v}");
        }
        for len in [0, 31, 32, 255, 256, 65535, 65536] {
            let s = "x".repeat(len);
            let mut out = Vec::new();
            write_str(&mut out, &s);
            assert_eq!(out, encode(&s), "{len}");
        }
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
    fn wrong_lengths_are_errors() {
        let mut out = Vec::new();
        assert!(write_array::<f32>(&mut out, &[2, 2], &[1.0; 3]).is_err());
        assert!(write_array::<u8>(&mut out, &[u32::MAX, u32::MAX, u32::MAX], &[]).is_err());
    }
}
