//! The batch-step reply written from borrowed data, the largest and most frequent message.
//!
//! [`BatchStepResult`](crate::BatchStepResult) owns its arrays as [`NdArray`](crate::NdArray)s:
//! building one copies every element out of the server's step buffers, and encoding it copies
//! them again. The views here are the same messages with their arrays borrowed
//! ([`ArrayView`]): serde writes them, field by field as the owned structs declare them, to the
//! same bytes (the tests compare the two), with each array's bytes copied once, into the output.
//! The per-env columns ([`BatchColumns`]) are gathered by the threads that step the envs.

use std::sync::Arc;

use serde::Serialize;

use crate::array::{ArrayError, ArrayView};
use crate::messages::{
    no_variation, AgentDesc, BatchEvent, BatchMetrics, EpisodeMetrics, Event, Reply,
};

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

/// One env's observation arrays (`[n_ext, m, F]`, `[n_ext, m, m]`, `[n_ext, m]`, `[n_ext, m]`),
/// or `k` envs' stacked along a leading axis.
#[derive(Debug, Clone, Copy)]
pub struct ObsRef<'a> {
    pub n_ext: u32,
    pub m: u32,
    pub features: &'a [f32],
    pub adjacency: &'a [f32],
    pub mask: &'a [u8],
    pub node_ids: &'a [u32],
}

/// [`ObsBatch`](crate::ObsBatch), borrowed.
#[derive(Serialize)]
struct ObsView<'a> {
    features: ArrayView<'a, f32>,
    adjacency: ArrayView<'a, f32>,
    mask: ArrayView<'a, u8>,
    node_ids: ArrayView<'a, u32>,
}

impl<'a> ObsView<'a> {
    /// The observations of `k` stacked envs.
    fn stacked(k: u32, o: &ObsRef<'a>) -> Result<Self, ArrayError> {
        let (n, m) = (o.n_ext, o.m);
        Ok(Self {
            features: ArrayView::new(vec![k, n, m, crate::N_FEATURES], o.features)?,
            adjacency: ArrayView::new(vec![k, n, m, m], o.adjacency)?,
            mask: ArrayView::new(vec![k, n, m], o.mask)?,
            node_ids: ArrayView::new(vec![k, n, m], o.node_ids)?,
        })
    }
}

/// [`RewardTerms`](crate::RewardTerms), borrowed.
#[derive(Serialize)]
struct RewardTermsView<'a> {
    progress: ArrayView<'a, f32>,
    success: ArrayView<'a, f32>,
    collision: ArrayView<'a, f32>,
    danger: ArrayView<'a, f32>,
    comfort: ArrayView<'a, f32>,
}

/// [`BatchResets`](crate::BatchResets), borrowed.
#[derive(Serialize)]
struct BatchResetsView<'a> {
    index: ArrayView<'a, u32>,
    episode: ArrayView<'a, u64>,
    scenario: &'a [String],
    horizon_steps: ArrayView<'a, u32>,
    agents: &'a [Vec<AgentDesc>],
    obs: ObsView<'a>,
    #[serde(skip_serializing_if = "no_variation_in")]
    variation: &'a [Option<u64>],
}

fn no_variation_in(seeds: &&[Option<u64>]) -> bool {
    no_variation(seeds)
}

/// [`BatchStepResult`](crate::BatchStepResult), borrowed.
#[derive(Serialize)]
struct BatchStepView<'a> {
    env_ids: &'a [String],
    obs: ObsView<'a>,
    reward: ArrayView<'a, f32>,
    reward_terms: RewardTermsView<'a>,
    terminated: ArrayView<'a, u8>,
    truncated: ArrayView<'a, u8>,
    episode: ArrayView<'a, u64>,
    scenario: SharedNames<'a>,
    step: ArrayView<'a, u32>,
    t: ArrayView<'a, f64>,
    action_clipped: ArrayView<'a, u8>,
    events: &'a [BatchEvent],
    metrics: &'a [BatchMetrics],
    resets: BatchResetsView<'a>,
}

/// A list of shared strings (the scenario names of a batch's envs: an `Arc` each, so naming an
/// env costs no copy), serialized as a list of strings.
struct SharedNames<'a>(&'a [Arc<str>]);

impl Serialize for SharedNames<'_> {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.collect_seq(self.0.iter().map(|name| &**name))
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
    let per_agent = |values| ArrayView::new(vec![k, n], values);
    let [progress, success, collision, danger, comfort] = a.terms;
    let r = &cols.resets;
    let resets = r.index.len() as u32;
    let view = BatchStepView {
        env_ids,
        obs: ObsView::stacked(k, &a.obs)?,
        reward: per_agent(a.reward)?,
        reward_terms: RewardTermsView {
            progress: per_agent(progress)?,
            success: per_agent(success)?,
            collision: per_agent(collision)?,
            danger: per_agent(danger)?,
            comfort: per_agent(comfort)?,
        },
        terminated: ArrayView::new(vec![k, n], a.terminated)?,
        truncated: ArrayView::new(vec![k, n], a.truncated)?,
        episode: ArrayView::new(vec![k], &cols.episode)?,
        scenario: SharedNames(&cols.scenario),
        step: ArrayView::new(vec![k], &cols.step)?,
        t: ArrayView::new(vec![k], &cols.t)?,
        action_clipped: ArrayView::new(vec![k, n], &cols.action_clipped)?,
        events: &cols.events,
        metrics: &cols.metrics,
        resets: BatchResetsView {
            index: ArrayView::new(vec![resets], &r.index)?,
            episode: ArrayView::new(vec![resets], &r.episode)?,
            scenario: &r.scenario,
            horizon_steps: ArrayView::new(vec![resets], &r.horizon_steps)?,
            agents: &r.agents,
            obs: ObsView::stacked(
                resets,
                &ObsRef {
                    n_ext: n,
                    m: a.obs.m,
                    features: &r.features,
                    adjacency: &r.adjacency,
                    mask: &r.mask,
                    node_ids: &r.node_ids,
                },
            )?,
            variation: &r.variation,
        },
    };
    if let Err(e) = crate::codec::try_encode_into(out, &Reply::Ok(view)) {
        // Writing into a Vec cannot fail, and the views serialize infallibly.
        unreachable!("{e}");
    }
    Ok(())
}

/// What a batch reply says of one env besides its stacked arrays, borrowed.
#[derive(Debug, Clone, Copy)]
pub struct BatchEnvRef<'a> {
    pub episode: u64,
    pub scenario: &'a Arc<str>,
    pub step: u32,
    pub t: f64,
    pub action_clipped: &'a [bool],
    pub events: &'a [Event],
    pub metrics: &'a [EpisodeMetrics],
}

/// What a batch reply says of one autoreset ([`BatchColumns::push_reset`]): the fields of its
/// [`ResetResult`](crate::ResetResult) but `env_id` (the reply names the env by position) and
/// `step`/`t` (always 0), with the observation borrowed.
#[derive(Debug, Clone)]
pub struct BatchReset<'a> {
    pub episode: u64,
    pub scenario: &'a str,
    pub horizon_steps: u32,
    /// In id order, as in `ResetResult::agents`.
    pub agents: Vec<AgentDesc>,
    pub obs: ObsRef<'a>,
    /// The episode's variation seed (`ResetResult::variation`'s), if the env has variations.
    pub variation: Option<u64>,
}

/// The per-env columns and the sparse lists (events, metrics, autoresets) of a batch reply
/// (`BatchStepResult`), gathered env by env in `env_ids` order with [`BatchColumns::push_env`]
/// and [`BatchColumns::push_reset`]. Envs stepped in chunks on several threads each fill a
/// `BatchColumns` made with the position of their first env, joined with
/// [`BatchColumns::append`].
#[derive(Debug, Clone, Default)]
pub struct BatchColumns {
    /// Position in `env_ids` of the first env pushed.
    base: u32,
    episode: Vec<u64>,
    scenario: Vec<Arc<str>>,
    step: Vec<u32>,
    t: Vec<f64>,
    action_clipped: Vec<u8>,
    events: Vec<BatchEvent>,
    metrics: Vec<BatchMetrics>,
    resets: ResetColumns,
}

/// The autoresets' columns (`BatchResets`).
#[derive(Debug, Clone, Default)]
struct ResetColumns {
    index: Vec<u32>,
    episode: Vec<u64>,
    scenario: Vec<String>,
    horizon_steps: Vec<u32>,
    agents: Vec<Vec<AgentDesc>>,
    features: Vec<f32>,
    adjacency: Vec<f32>,
    mask: Vec<u8>,
    node_ids: Vec<u32>,
    variation: Vec<Option<u64>>,
}

impl ResetColumns {
    fn append(&mut self, mut next: ResetColumns) {
        self.index.append(&mut next.index);
        self.episode.append(&mut next.episode);
        self.scenario.append(&mut next.scenario);
        self.horizon_steps.append(&mut next.horizon_steps);
        self.agents.append(&mut next.agents);
        self.features.append(&mut next.features);
        self.adjacency.append(&mut next.adjacency);
        self.mask.append(&mut next.mask);
        self.node_ids.append(&mut next.node_ids);
        self.variation.append(&mut next.variation);
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
            scenario: Vec::with_capacity(envs),
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
        self.scenario.push(Arc::clone(e.scenario));
        self.step.push(e.step);
        self.t.push(e.t);
        self.action_clipped
            .extend(e.action_clipped.iter().map(|&c| u8::from(c)));
        self.events.extend(e.events.iter().map(|event| BatchEvent {
            index,
            event: event.clone(),
        }));
        self.metrics
            .extend(e.metrics.iter().map(|metrics| BatchMetrics {
                index,
                metrics: metrics.clone(),
            }));
    }

    /// Records that the env pushed last restarted with `r`. The observation must have the
    /// batch's shapes.
    pub fn push_reset(&mut self, r: BatchReset<'_>) {
        debug_assert!(!self.is_empty(), "push_reset before push_env");
        let index = self.base + self.episode.len().saturating_sub(1) as u32;
        let c = &mut self.resets;
        c.index.push(index);
        c.episode.push(r.episode);
        c.scenario.push(r.scenario.to_owned());
        c.horizon_steps.push(r.horizon_steps);
        c.agents.push(r.agents);
        c.features.extend_from_slice(r.obs.features);
        c.adjacency.extend_from_slice(r.obs.adjacency);
        c.mask.extend_from_slice(r.obs.mask);
        c.node_ids.extend_from_slice(r.obs.node_ids);
        c.variation.push(r.variation);
    }

    /// Appends the envs of `next`, which must start where these end.
    pub fn append(&mut self, mut next: BatchColumns) {
        debug_assert_eq!(next.base as usize, self.base as usize + self.len());
        self.episode.append(&mut next.episode);
        self.scenario.append(&mut next.scenario);
        self.step.append(&mut next.step);
        self.t.append(&mut next.t);
        self.action_clipped.append(&mut next.action_clipped);
        self.events.append(&mut next.events);
        self.metrics.append(&mut next.metrics);
        self.resets.append(next.resets);
    }

    /// Bytes the columns add to a reply, roughly (for reserving the output).
    pub fn encoded_bytes(&self) -> usize {
        let r = &self.resets;
        let names = |v: &[String]| v.iter().map(|s| s.len() + 5).sum::<usize>();
        32 * self.len()
            + self.scenario.iter().map(|s| s.len() + 5).sum::<usize>()
            + 160 * (self.events.len() + self.metrics.len())
            + names(&r.scenario)
            + 96 * r.agents.iter().map(Vec::len).sum::<usize>()
            + 4 * (r.features.len() + r.adjacency.len() + r.node_ids.len())
            + r.mask.len()
            + 16 * r.index.len()
            + 1024
    }
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
