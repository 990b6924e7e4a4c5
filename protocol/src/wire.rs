//! Direct MessagePack writing of the batch-step reply, the largest and most frequent message.
//!
//! [`encode`](crate::encode) of a `Reply<BatchStepResult>` needs the arrays as owned
//! [`NdArray`](crate::NdArray)s (one copy of every element into little-endian bytes) and the
//! per-env columns as owned arrays, and then copies everything once more into the output. The
//! writers here take borrowed slices and write the same bytes straight into the output buffer:
//! every function produces exactly what `rmp_serde`'s named encoding of the corresponding
//! message produces (the tests compare the two byte for byte).

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

/// Writes a whole `Reply::Ok(BatchStepResult)` from the stacked arrays and the per-env
/// columns (`cols` holds exactly `env_ids.len()` envs).
/// Byte-identical to `encode(&Reply::Ok(result))` of the equivalent owned result.
pub fn write_batch_step_ok(
    out: &mut Vec<u8>,
    env_ids: &[String],
    a: &BatchArrays<'_>,
    cols: &BatchColumns,
) -> Result<(), ArrayError> {
    let (k, n) = (a.k, a.obs.n_ext);
    if cols.len() != env_ids.len() || cols.action_clipped.len() != cols.len() * n as usize {
        return Err(ArrayError::WrongShape {
            expected: format!("columns of {} envs with {n} agents each", env_ids.len()),
            actual: vec![cols.len() as u32, cols.action_clipped.len() as u32],
        });
    }
    write_map_len(out, 1);
    write_str(out, "ok");
    write_map_len(out, 14);
    write_str(out, "env_ids");
    write_array_len(out, env_ids.len());
    for id in env_ids {
        write_str(out, id);
    }
    write_str(out, "obs");
    write_obs(out, k, &a.obs)?;
    write_str(out, "reward");
    write_array(out, &[k, n], a.reward)?;
    write_str(out, "reward_terms");
    write_map_len(out, 5);
    for (name, t) in crate::messages::REWARD_TERM_NAMES.iter().zip(a.terms) {
        write_str(out, name);
        write_array(out, &[k, n], t)?;
    }
    write_str(out, "terminated");
    write_array(out, &[k, n], a.terminated)?;
    write_str(out, "truncated");
    write_array(out, &[k, n], a.truncated)?;
    write_str(out, "episode");
    write_array(out, &[k], &cols.episode)?;
    write_str(out, "scenario");
    write_array_len(out, cols.len());
    out.extend_from_slice(&cols.scenarios);
    write_str(out, "step");
    write_array(out, &[k], &cols.step)?;
    write_str(out, "t");
    write_array(out, &[k], &cols.t)?;
    write_str(out, "action_clipped");
    write_array(out, &[k, n], &cols.action_clipped)?;
    write_str(out, "events");
    write_array_len(out, cols.n_events);
    out.extend_from_slice(&cols.events);
    write_str(out, "metrics");
    write_array_len(out, cols.n_metrics);
    out.extend_from_slice(&cols.metrics);
    write_str(out, "resets");
    let r = &cols.resets;
    let rn = r.index.len() as u32;
    // `variation` is left out when no reset env has variations (`messages::no_variation`).
    let with_variation = !crate::messages::no_variation(&r.variation);
    out.push(if with_variation { 0x87 } else { 0x86 });
    out.extend_from_slice(b"\xa5index");
    write_array(out, &[rn], &r.index)?;
    out.extend_from_slice(b"\xa7episode");
    write_array(out, &[rn], &r.episode)?;
    out.extend_from_slice(b"\xa8scenario");
    write_array_len(out, r.index.len());
    out.extend_from_slice(&r.scenarios);
    out.extend_from_slice(b"\xadhorizon_steps");
    write_array(out, &[rn], &r.horizon_steps)?;
    out.extend_from_slice(b"\xa6agents");
    write_array_len(out, r.index.len());
    out.extend_from_slice(&r.agents);
    out.extend_from_slice(b"\xa3obs");
    write_obs(
        out,
        rn,
        &ObsRef {
            n_ext: n,
            m: a.obs.m,
            features: &r.features,
            adjacency: &r.adjacency,
            mask: &r.mask,
            node_ids: &r.node_ids,
        },
    )?;
    if with_variation {
        out.extend_from_slice(b"\xa9variation");
        write_array_len(out, r.variation.len());
        for seed in &r.variation {
            match seed {
                Some(s) => write_uint(out, *s),
                None => write_nil(out),
            }
        }
    }
    Ok(())
}

/// What a batch reply says of one env besides its stacked arrays, borrowed.
#[derive(Debug, Clone, Copy)]
pub struct BatchEnvRef<'a> {
    pub episode: u64,
    pub scenario: &'a str,
    pub step: u32,
    pub t: f64,
    pub action_clipped: &'a [bool],
    pub events: &'a [Event],
    pub metrics: &'a [EpisodeMetrics],
}

/// The per-env columns and the sparse lists (events, metrics, autoresets) of a batch reply
/// (`BatchStepResult`), gathered env by env in `env_ids` order with [`BatchColumns::push_env`]
/// and [`BatchColumns::push_reset`]. Envs stepped in chunks on several threads each fill a
/// `BatchColumns` made with the position of their first env, joined with
/// [`BatchColumns::append`]. Strings and maps are kept already encoded.
#[derive(Debug, Clone, Default)]
pub struct BatchColumns {
    /// Position in `env_ids` of the first env pushed.
    base: u32,
    episode: Vec<u64>,
    scenarios: Vec<u8>,
    step: Vec<u32>,
    t: Vec<f64>,
    action_clipped: Vec<u8>,
    events: Vec<u8>,
    n_events: usize,
    metrics: Vec<u8>,
    n_metrics: usize,
    resets: ResetColumns,
}

#[derive(Debug, Clone, Default)]
struct ResetColumns {
    index: Vec<u32>,
    episode: Vec<u64>,
    scenarios: Vec<u8>,
    horizon_steps: Vec<u32>,
    agents: Vec<u8>,
    features: Vec<f32>,
    adjacency: Vec<f32>,
    mask: Vec<u8>,
    node_ids: Vec<u32>,
    variation: Vec<Option<u64>>,
}

impl ResetColumns {
    fn append(&mut self, next: &ResetColumns) {
        self.index.extend_from_slice(&next.index);
        self.episode.extend_from_slice(&next.episode);
        self.scenarios.extend_from_slice(&next.scenarios);
        self.horizon_steps.extend_from_slice(&next.horizon_steps);
        self.agents.extend_from_slice(&next.agents);
        self.features.extend_from_slice(&next.features);
        self.adjacency.extend_from_slice(&next.adjacency);
        self.mask.extend_from_slice(&next.mask);
        self.node_ids.extend_from_slice(&next.node_ids);
        self.variation.extend_from_slice(&next.variation);
    }
}

impl BatchColumns {
    /// Empty columns whose first env is `env_ids[base]`.
    pub fn starting_at(base: u32) -> Self {
        Self {
            base,
            ..Self::default()
        }
    }

    /// [`BatchColumns::starting_at`] with room for `envs` envs of `n_ext` agents (the per-env
    /// columns then never grow while they are filled).
    pub fn with_capacity(base: u32, envs: usize, n_ext: usize) -> Self {
        Self {
            base,
            episode: Vec::with_capacity(envs),
            scenarios: Vec::with_capacity(16 * envs),
            step: Vec::with_capacity(envs),
            t: Vec::with_capacity(envs),
            action_clipped: Vec::with_capacity(envs * n_ext),
            ..Self::default()
        }
    }

    /// Envs pushed so far.
    pub fn len(&self) -> usize {
        self.episode.len()
    }

    pub fn is_empty(&self) -> bool {
        self.episode.is_empty()
    }

    /// Appends the next env.
    pub fn push_env(&mut self, e: &BatchEnvRef<'_>) {
        let index = self.base + self.episode.len() as u32;
        self.episode.push(e.episode);
        write_str(&mut self.scenarios, e.scenario);
        self.step.push(e.step);
        self.t.push(e.t);
        self.action_clipped
            .extend(e.action_clipped.iter().map(|&c| u8::from(c)));
        /// `{index, <key>: value}` per value (`key` pre-encoded).
        fn indexed<T: Serialize>(out: &mut Vec<u8>, index: u32, key: &[u8], values: &[T]) {
            for v in values {
                out.extend_from_slice(b"\x82\xa5index");
                write_uint(out, u64::from(index));
                out.extend_from_slice(key);
                write_named(out, v);
            }
        }
        indexed(&mut self.events, index, b"\xa5event", e.events);
        self.n_events += e.events.len();
        indexed(&mut self.metrics, index, b"\xa7metrics", e.metrics);
        self.n_metrics += e.metrics.len();
    }

    /// Records that the env pushed last restarted with `r`. The observation must have the
    /// batch's shapes.
    pub fn push_reset(&mut self, r: &ResetResultRef<'_>) {
        debug_assert!(!self.is_empty(), "push_reset before push_env");
        let index = self.base + self.episode.len().saturating_sub(1) as u32;
        let c = &mut self.resets;
        c.index.push(index);
        c.episode.push(r.episode);
        write_str(&mut c.scenarios, r.scenario);
        c.horizon_steps.push(r.horizon_steps);
        write_agent_descs(&mut c.agents, r.agents);
        c.features.extend_from_slice(r.obs.features);
        c.adjacency.extend_from_slice(r.obs.adjacency);
        c.mask.extend_from_slice(r.obs.mask);
        c.node_ids.extend_from_slice(r.obs.node_ids);
        c.variation.push(r.variation);
    }

    /// Appends the envs of `next`, which must start where these end.
    pub fn append(&mut self, next: &BatchColumns) {
        debug_assert_eq!(next.base as usize, self.base as usize + self.len());
        self.episode.extend_from_slice(&next.episode);
        self.scenarios.extend_from_slice(&next.scenarios);
        self.step.extend_from_slice(&next.step);
        self.t.extend_from_slice(&next.t);
        self.action_clipped.extend_from_slice(&next.action_clipped);
        self.events.extend_from_slice(&next.events);
        self.n_events += next.n_events;
        self.metrics.extend_from_slice(&next.metrics);
        self.n_metrics += next.n_metrics;
        self.resets.append(&next.resets);
    }

    /// Bytes the columns add to a reply, roughly (for reserving the output).
    pub fn encoded_bytes(&self) -> usize {
        let r = &self.resets;
        32 * self.len()
            + self.scenarios.len()
            + self.events.len()
            + self.metrics.len()
            + r.scenarios.len()
            + r.agents.len()
            + 4 * (r.features.len() + r.adjacency.len() + r.node_ids.len())
            + r.mask.len()
            + 16 * r.index.len()
            + 1024
    }
}

/// MessagePack nil (an absent optional value).
fn write_nil(out: &mut Vec<u8>) {
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

/// What a batch reply says of one autoreset ([`BatchColumns::push_reset`]): the fields of its
/// [`ResetResult`](crate::ResetResult), borrowed, but `env_id` (the reply names the env by
/// position) and `step`/`t` (always 0).
#[derive(Debug, Clone, Copy)]
pub struct ResetResultRef<'a> {
    pub episode: u64,
    pub scenario: &'a str,
    pub horizon_steps: u32,
    /// In id order, as in `ResetResult::agents`.
    pub agents: &'a [AgentDescRef<'a>],
    pub obs: ObsRef<'a>,
    /// The episode's variation seed (`ResetResult::variation`'s), if the env has variations.
    pub variation: Option<u64>,
}

/// An array of `AgentDesc` maps.
fn write_agent_descs(out: &mut Vec<u8>, agents: &[AgentDescRef<'_>]) {
    write_array_len(out, agents.len());
    for a in agents {
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
}

/// Writes an observation map (`features`, `adjacency`, `mask`, `node_ids`) of `k` stacked envs
/// (each array has a leading `k` axis).
fn write_obs(out: &mut Vec<u8>, k: u32, o: &ObsRef<'_>) -> Result<(), ArrayError> {
    let (n, m) = (o.n_ext, o.m);
    out.extend_from_slice(b"\x84\xa8features");
    write_array(out, &[k, n, m, crate::N_FEATURES], o.features)?;
    out.extend_from_slice(b"\xa9adjacency");
    write_array(out, &[k, n, m, m], o.adjacency)?;
    out.extend_from_slice(b"\xa4mask");
    write_array(out, &[k, n, m], o.mask)?;
    out.extend_from_slice(b"\xa8node_ids");
    write_array(out, &[k, n, m], o.node_ids)
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
                    scenario: &s.scenario,
                    step: s.step,
                    t: s.t,
                    action_clipped: &s.info.action_clipped,
                    events: &s.info.events,
                    metrics: &s.info.metrics,
                });
                if let Some(reset) = &s.reset {
                    next.push_reset(&reset_ref(reset).as_ref());
                }
            }
            if c == 0 {
                cols = next;
            } else {
                cols.append(&next);
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
                episode: self.r.episode,
                scenario: &self.r.scenario,
                horizon_steps: self.r.horizon_steps,
                agents,
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
    fn agent_descs_are_byte_identical_to_the_serde_encoding() {
        let mut r = crate::samples::reset_result();
        for round in 0..3 {
            let mut out = Vec::new();
            write_agent_descs(&mut out, reset_ref(&r).as_ref().agents);
            assert_eq!(out, encode(&r.agents), "round {round}");
            // Longer names, more agents, large ids.
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
