//! Scenario pools as the server serves them, and the per-env scenario sequence.
//!
//! **Agent names.** In every scenario the vehicles are named `vehicle_0`, `vehicle_1`, ... with
//! `vehicle_0` the scenario's ego (`Scenario::ego`) and the other vehicles following in the
//! scenario's agent order; pedestrians are `pedestrian_0`, `pedestrian_1`, ... in agent order.
//! Either may be external ([`ExternalAgent`]).
//!
//! **Scenario sequence.** An env draws its episodes from the candidate scenarios of its pool
//! split (those with enough vehicles and pedestrians for its external agents), in pool order. The sequence is a
//! series of random permutations of the candidates: the first is drawn by a SplitMix64 generator
//! seeded with the env's seed (`CreateEnv.seed + k` for the k-th env of a request), and each
//! time a permutation is used up the next one is drawn from the same generator. `Reset.seed`
//! re-seeds the generator and starts a fresh permutation. So a trainer's sequence of scenarios
//! depends only on (pool, split, external agents, seed, env index, resets with seeds), never on
//! other trainers or on timing.
//!
//! **Composed scenes** (`CreateEnv.composed`, [`Composed`]): each episode is one of the
//! candidates and the `scenes` composed scenes uniformly (drawn from a stream of the env's seed
//! apart from the permutations), or a fresh composed scene (unlimited `scenes`).

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::Arc;

use protocol::{PoolSummary, ScenarioSummary};
use scenarios::composed::{ComposeConfig, Parts};
use scenarios::synthetic::SplitMix64;
use serde::{Deserialize, Serialize};
use sim_core::params::{VehicleModel, WorldParams};
use sim_core::scenario::{AgentKind, Scenario, ScenarioPool, Split};
use sim_core::variation::VariationSpec;
use sim_core::world::AgentId;

/// One entry of `pools`: a path, or a path with the pool's default scene variations and vehicle
/// model.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum PoolEntry {
    Path(PathBuf),
    WithVariations {
        path: PathBuf,
        #[serde(default)]
        variations: Option<VariationSpec>,
        /// How the pool's vehicles nobody controls move (`replay` | `idm`); absent: as the pool
        /// file says.
        #[serde(default)]
        vehicle_model: Option<VehicleModel>,
    },
}

/// The map form of a [`PoolEntry`], read field by field so that a bad field is named (an
/// untagged enum would only say that no variant matched).
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct PoolEntryFields {
    path: PathBuf,
    #[serde(default)]
    variations: Option<VariationSpec>,
    #[serde(default)]
    vehicle_model: Option<VehicleModel>,
}

impl<'de> Deserialize<'de> for PoolEntry {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Entry;
        impl<'de> serde::de::Visitor<'de> for Entry {
            type Value = PoolEntry;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a pool path, or {path, variations, vehicle_model}")
            }
            fn visit_str<E: serde::de::Error>(self, s: &str) -> Result<PoolEntry, E> {
                Ok(PoolEntry::Path(PathBuf::from(s)))
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(
                self,
                map: A,
            ) -> Result<PoolEntry, A::Error> {
                let f = PoolEntryFields::deserialize(
                    serde::de::value::MapAccessDeserializer::new(map),
                )?;
                Ok(PoolEntry::WithVariations {
                    path: f.path,
                    variations: f.variations,
                    vehicle_model: f.vehicle_model,
                })
            }
        }
        d.deserialize_any(Entry)
    }
}

impl PoolEntry {
    pub fn path(&self) -> &PathBuf {
        match self {
            PoolEntry::Path(p) | PoolEntry::WithVariations { path: p, .. } => p,
        }
    }

    pub fn vehicle_model(&self) -> Option<VehicleModel> {
        match self {
            PoolEntry::Path(_) => None,
            PoolEntry::WithVariations { vehicle_model, .. } => *vehicle_model,
        }
    }

    pub fn variations(&self) -> Option<&VariationSpec> {
        match self {
            PoolEntry::Path(_) => None,
            PoolEntry::WithVariations { variations, .. } => variations.as_ref(),
        }
    }
}

impl From<PathBuf> for PoolEntry {
    fn from(p: PathBuf) -> Self {
        PoolEntry::Path(p)
    }
}

/// One scenario with the server's naming of its agents.
#[derive(Debug)]
pub struct ServedScenario {
    pub scenario: Arc<Scenario>,
    /// Agent ids of the vehicles: index k is `vehicle_k` (the ego first).
    pub vehicles: Vec<AgentId>,
    /// Agent ids of the pedestrians: index k is `pedestrian_k` (agent order).
    pub pedestrians: Vec<AgentId>,
    /// Name of every agent, indexed by agent id.
    pub names: Vec<String>,
    /// The scenario's name, shared by the batch replies that name it (no copy per env step).
    pub name: Arc<str>,
}

impl ServedScenario {
    pub fn new(scenario: Scenario) -> Self {
        let mut vehicles: Vec<AgentId> = Vec::new();
        if scenario
            .agents
            .get(scenario.ego)
            .is_some_and(|a| a.kind == AgentKind::Vehicle)
        {
            vehicles.push(scenario.ego as AgentId);
        }
        for (k, a) in scenario.agents.iter().enumerate() {
            if a.kind == AgentKind::Vehicle && k != scenario.ego {
                vehicles.push(k as AgentId);
            }
        }
        let mut names = vec![String::new(); scenario.agents.len()];
        for (k, &id) in vehicles.iter().enumerate() {
            names[id as usize] = format!("vehicle_{k}");
        }
        let mut pedestrians: Vec<AgentId> = Vec::new();
        for (k, a) in scenario.agents.iter().enumerate() {
            if a.kind == AgentKind::Pedestrian {
                names[k] = format!("pedestrian_{}", pedestrians.len());
                pedestrians.push(k as AgentId);
            }
        }
        Self {
            name: Arc::from(scenario.name.as_str()),
            scenario: Arc::new(scenario),
            vehicles,
            pedestrians,
            names,
        }
    }

    /// The agent id of an external agent, if the scenario has it.
    pub fn agent_id(&self, agent: ExternalAgent) -> Option<AgentId> {
        match agent {
            ExternalAgent::Vehicle(k) => self.vehicles.get(k).copied(),
            ExternalAgent::Pedestrian(k) => self.pedestrians.get(k).copied(),
        }
    }
}

/// An agent a client drives: `vehicle_{k}` or `pedestrian_{k}` (the module doc says which).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ExternalAgent {
    Vehicle(usize),
    Pedestrian(usize),
}

impl ExternalAgent {
    /// `vehicle_{k}` or `pedestrian_{k}` with `k` a decimal number without leading zeros.
    pub fn parse(name: &str) -> Option<Self> {
        let (kind, k): (fn(usize) -> Self, &str) = if let Some(k) = name.strip_prefix("vehicle_") {
            (Self::Vehicle, k)
        } else {
            (Self::Pedestrian, name.strip_prefix("pedestrian_")?)
        };
        if k.is_empty()
            || (k.len() > 1 && k.starts_with('0'))
            || !k.bytes().all(|b| b.is_ascii_digit())
        {
            return None;
        }
        k.parse().ok().map(kind)
    }
}

/// What a scenario must have to serve a list of external agents: this many vehicles and
/// pedestrians.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct AgentsNeeded {
    pub vehicles: usize,
    pub pedestrians: usize,
}

impl AgentsNeeded {
    pub fn of(agents: &[ExternalAgent]) -> Self {
        let mut need = Self::default();
        for a in agents {
            match *a {
                ExternalAgent::Vehicle(k) => need.vehicles = need.vehicles.max(k + 1),
                ExternalAgent::Pedestrian(k) => need.pedestrians = need.pedestrians.max(k + 1),
            }
        }
        need
    }

    fn met_by(&self, s: &ServedScenario) -> bool {
        s.vehicles.len() >= self.vehicles && s.pedestrians.len() >= self.pedestrians
    }
}

impl std::fmt::Display for AgentsNeeded {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match (self.vehicles, self.pedestrians) {
            (v, 0) => write!(f, "{v} vehicle(s)"),
            (0, p) => write!(f, "{p} pedestrian(s)"),
            (v, p) => write!(f, "{v} vehicle(s) and {p} pedestrian(s)"),
        }
    }
}

/// A pool as served: scenarios by split and by name.
#[derive(Debug)]
pub struct ServedPool {
    pub name: String,
    pub scenarios: Vec<Arc<ServedScenario>>,
    /// Scene variations of the envs on this pool that send none of their own.
    pub variations: Option<VariationSpec>,
    /// How the vehicles nobody controls move in the envs on this pool that do not say (the pool
    /// file's `vehicle_model`, or the server configuration's pool entry's).
    pub vehicle_model: VehicleModel,
    by_name: HashMap<String, usize>,
}

impl ServedPool {
    pub fn new(pool: ScenarioPool) -> Self {
        let vehicle_model = pool.vehicle_model;
        let scenarios: Vec<Arc<ServedScenario>> = pool
            .scenarios
            .into_iter()
            .map(|s| Arc::new(ServedScenario::new(s)))
            .collect();
        let by_name = scenarios
            .iter()
            .enumerate()
            .map(|(i, s)| (s.scenario.name.clone(), i))
            .collect();
        Self {
            name: pool.name,
            scenarios,
            variations: None,
            vehicle_model,
            by_name,
        }
    }

    /// This pool with default scene variations.
    pub fn with_variations(mut self, variations: Option<VariationSpec>) -> Self {
        self.variations = variations;
        self
    }

    /// This pool with its vehicles moved by `model` unless an env says otherwise (`None`: as the
    /// pool file says).
    pub fn with_vehicle_model(mut self, model: Option<VehicleModel>) -> Self {
        if let Some(m) = model {
            self.vehicle_model = m;
        }
        self
    }

    /// Index of the scenario called `name`.
    pub fn find(&self, name: &str) -> Option<usize> {
        self.by_name.get(name).copied()
    }

    /// Indices of the scenarios of `split` with at least `vehicles` vehicles, in pool order.
    pub fn candidates(&self, split: Split, need: AgentsNeeded) -> Vec<usize> {
        self.scenarios
            .iter()
            .enumerate()
            .filter(|(_, s)| s.scenario.split == split && need.met_by(s))
            .map(|(i, _)| i)
            .collect()
    }

    pub fn summary(&self) -> PoolSummary {
        let count = |split| {
            self.scenarios
                .iter()
                .filter(|s| s.scenario.split == split)
                .count() as u32
        };
        PoolSummary {
            name: self.name.clone(),
            train: count(Split::Train),
            test: count(Split::Test),
            scenarios: self
                .scenarios
                .iter()
                .map(|s| ScenarioSummary {
                    name: s.scenario.name.clone(),
                    split: match s.scenario.split {
                        Split::Train => protocol::Split::Train,
                        Split::Test => protocol::Split::Test,
                    },
                })
                .collect(),
        }
    }
}

/// What an episode plays: a pool's scenario (its index) or a composed scene (its index).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EpisodeDraw {
    Recorded(usize),
    Composed(u64),
}

/// The composed scenes of the envs of one `CreateEnv` (`CreateEnv.composed`): the parts, the
/// generator's configuration and how many scenes.
#[derive(Debug)]
pub struct Composed {
    pub parts: Arc<Parts>,
    pub config: ComposeConfig,
    /// Scenes `0..n` beside the recorded candidates; `None`: a fresh one every episode.
    pub scenes: Option<u64>,
}

impl Composed {
    /// Composed scene `index`.
    pub fn scene(&self, index: u64) -> Scenario {
        self.parts.compose(&self.config, index)
    }

    /// The index of the composed scene called `name`, if it is one of these.
    pub fn index_of(&self, name: &str) -> Option<u64> {
        let (seed, index) = Parts::parse_scene_name(name)?;
        (seed == self.config.seed && self.scenes.is_none_or(|n| index < n)).then_some(index)
    }

    /// The next episode's scene: uniformly one of the `recorded` candidates and the `scenes`
    /// composed ones, or a fresh composed one (an index drawn from all of `u64`).
    pub fn draw(&self, recorded: &[usize], rng: &mut SplitMix64) -> EpisodeDraw {
        let Some(n) = self.scenes else {
            return EpisodeDraw::Composed(rng.next_u64());
        };
        let r = recorded.len() as u64;
        let k = rng.next_u64() % (r + n);
        if k < r {
            EpisodeDraw::Recorded(recorded[k as usize])
        } else {
            EpisodeDraw::Composed(k - r)
        }
    }
}

/// The seeded scenario sequence of one env (see the module docs).
#[derive(Debug, Clone)]
pub struct ScenarioSequence {
    candidates: Arc<Vec<usize>>,
    rng: SplitMix64,
    order: Vec<usize>,
    next: usize,
}

impl ScenarioSequence {
    /// A sequence over `candidates` (must be non-empty) seeded with `seed`.
    pub fn new(candidates: Arc<Vec<usize>>, seed: u64) -> Self {
        let mut s = Self {
            candidates,
            rng: SplitMix64::new(seed),
            order: Vec::new(),
            next: 0,
        };
        s.reseed(seed);
        s
    }

    /// Re-seeds the generator and starts a fresh permutation.
    pub fn reseed(&mut self, seed: u64) {
        self.rng = SplitMix64::new(seed);
        self.order.clear();
        self.next = 0;
    }

    fn shuffle(&mut self) {
        self.order.clear();
        self.order.extend(self.candidates.iter().copied());
        // Fisher–Yates.
        for i in (1..self.order.len()).rev() {
            let j = (self.rng.next_u64() % (i as u64 + 1)) as usize;
            self.order.swap(i, j);
        }
        self.next = 0;
    }

    /// The next scenario index.
    pub fn next_scenario(&mut self) -> usize {
        if self.next >= self.order.len() {
            self.shuffle();
        }
        let s = self.order[self.next];
        self.next += 1;
        s
    }
}

/// A pool entry's defaults: its scene variations and its vehicle model.
type PoolDefaults = (Option<VariationSpec>, Option<VehicleModel>);

/// The pools a server configuration names (`pools`; empty: both embedded pools), each checked
/// (scenes, their step, unique names, valid variations), with their entry's defaults. The error
/// says which pool and what is wrong.
pub fn load_pools(entries: &[PoolEntry], params: &WorldParams) -> Result<Vec<ServedPool>, String> {
    let pools: Vec<(ScenarioPool, PoolDefaults, String)> = if entries.is_empty() {
        scenarios::embedded::EMBEDDED_POOLS
            .iter()
            .filter_map(|name| scenarios::embedded::pool(name))
            .map(|p| {
                let arg = format!("embedded:{}", p.name);
                (p, (None, None), arg)
            })
            .collect()
    } else {
        entries
            .iter()
            .map(|entry| {
                let arg = entry.path().display().to_string();
                let pool = scenarios::embedded::pool_from_arg(entry.path())?;
                if let Some(v) = entry.variations() {
                    v.validate().map_err(|e| format!("pool {arg}: {e}"))?;
                }
                Ok((
                    pool,
                    (entry.variations().cloned(), entry.vehicle_model()),
                    arg,
                ))
            })
            .collect::<Result<Vec<_>, String>>()?
    };
    for (i, (pool, _, arg)) in pools.iter().enumerate() {
        if let Some((_, _, first)) = pools[..i].iter().find(|(p, _, _)| p.name == pool.name) {
            return Err(format!(
                "pools {first} and {arg} are both named {:?}: a pool is chosen by name, so the second could never be reached",
                pool.name
            ));
        }
    }
    for (pool, _, _) in &pools {
        if pool.scenarios.is_empty() {
            return Err(format!(
                "pool {:?} has no scenarios ({})",
                pool.name, pool.provenance
            ));
        }
        if let Some(s) = pool
            .scenarios
            .iter()
            .find(|s| (s.dt - params.dt).abs() > 1e-9)
        {
            return Err(format!(
                "pool {:?}: scenario {:?} is sampled every {} s but the world steps {} s",
                pool.name, s.name, s.dt, params.dt
            ));
        }
    }
    Ok(pools
        .into_iter()
        .map(|(pool, (variations, vehicles), _)| {
            ServedPool::new(pool)
                .with_variations(variations)
                .with_vehicle_model(vehicles)
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sequence_is_a_series_of_permutations() {
        let c = Arc::new((10..17).collect::<Vec<_>>());
        let mut s = ScenarioSequence::new(c.clone(), 42);
        let first: Vec<usize> = (0..7).map(|_| s.next_scenario()).collect();
        let mut sorted = first.clone();
        sorted.sort();
        assert_eq!(sorted, *c);
        let second: Vec<usize> = (0..7).map(|_| s.next_scenario()).collect();
        let mut sorted2 = second.clone();
        sorted2.sort();
        assert_eq!(sorted2, *c);
        // Reproducible.
        let mut t = ScenarioSequence::new(c.clone(), 42);
        let again: Vec<usize> = (0..7).map(|_| t.next_scenario()).collect();
        assert_eq!(first, again);
        // Another seed gives another order (for this seed pair).
        let mut u = ScenarioSequence::new(c, 43);
        let other: Vec<usize> = (0..7).map(|_| u.next_scenario()).collect();
        assert_ne!(first, other);
        // Reseeding restarts.
        t.reseed(42);
        assert_eq!(t.next_scenario(), first[0]);
    }

    #[test]
    fn ego_is_vehicle_0() {
        let pool = scenarios::embedded::default_pool();
        let served = ServedPool::new(pool);
        for s in &served.scenarios {
            assert_eq!(s.vehicles.first().copied(), Some(s.scenario.ego as AgentId));
            assert_eq!(s.names[s.scenario.ego], "vehicle_0");
        }
    }
}
