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
mod tests;
