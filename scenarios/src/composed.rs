//! Composed scenes: new scenes put together from the recorded parts of a pool's train scenes
//! (`scenarios/EXTRACTION.md`, "Composed scenes").
//!
//! [`Parts::new`] takes apart the train scenes of a pool, less the scenes it is told to hold
//! out (a validation split):
//! - **routes**: each scene's ego car, with the scene's other cars and its pedestrian count;
//! - **tracks**: every recorded pedestrian (one per record id, its longest clip);
//! - **meetings**: where and when each recorded pedestrian met its scene's car, in the car's
//!   frame: the car's path sample (as a fraction of its route), the pedestrian's offset from
//!   it along and across the car's heading, its walking direction relative to that heading,
//!   and how many steps after the car it passed there. Each meeting has a [`Role`].
//!
//! No agent recorded in a test scene or a held-out scene enters a composed scene, even where
//! the same pedestrian was also recorded in a train scene: [`Parts::held_out`] lists them and
//! [`Parts::record_ids`] every id a composed scene may hold.
//!
//! [`Parts::compose`] builds scene `index` of a [`ComposeConfig`] from a generator seeded with
//! `(config.seed, index)` alone:
//! 1. **The ego**: one route's car, as recorded (its goal, and its speeds as the reference a
//!    recorded driver kept); its scene's other cars come along (`other_cars`), as recorded.
//! 2. **The pedestrians**: `pedestrians` of them (default: the route's scene's count). Each
//!    draws a role by `shares`, a recorded meeting of that role, and a recorded track of
//!    another pedestrian, which is mirrored about its own direction in half of the draws,
//!    rotated so that it walks in the meeting's direction relative to the new car, and moved
//!    and shifted in time so that it passes the meeting's point, relative to the new car's
//!    path, the meeting's number of steps after the car did. It starts at step 0 (its samples
//!    before are dropped) and is cut at the end of the car's window, so every goal is one its
//!    recording reached within the horizon.
//! 3. **Legal**: a draw whose pedestrian starts within [`PEDESTRIAN_GAP`] of another
//!    pedestrian or within [`VEHICLE_GAP`] of a car, or stands (as recorded) within those gaps
//!    where a later car enters, or whose recorded track touches the recorded car's at any step
//!    (in the recording nobody ever did), is redrawn (at most [`TRIES`] times; then the scene
//!    has one pedestrian fewer).
//!
//! Only `+ - * /` and `sqrt` touch the coordinates (rotations are unit vectors, never angles),
//! so a scene is the same bytes on every platform; the legality checks use the footprints'
//! headings (`atan2`), which can flip a draw only for a clearance within an ulp of its gap.

use std::collections::{BTreeMap, BTreeSet};
use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};
use sim_core::geometry::clearance;
use sim_core::scenario::{AgentKind, AgentRecord, Scenario, ScenarioPool, Split};
use sim_core::support::rng::{derive_seed, SplitMix64};

use crate::footprint::TrackFootprint;

/// Most draws of one pedestrian before it is left out of its scene.
pub const TRIES: usize = 64;
/// Least clearance (m) at step 0 between a composed pedestrian and any other pedestrian.
pub const PEDESTRIAN_GAP: f64 = 0.1;
/// Least clearance (m) at step 0 between a composed pedestrian and a car: no scene starts with
/// a collision the driver could not avoid.
pub const VEHICLE_GAP: f64 = 1.0;
/// A recorded pedestrian farther than this (m) from its car's path at its closest is
/// background.
pub const MEETING_DISTANCE: f64 = 5.0;
/// A recorded pedestrian whose whole track moves it less than this (m) stands.
pub const STANDING_DISPLACEMENT: f64 = 1.0;
/// Most pedestrians a composed scene may ask for.
pub const MAX_PEDESTRIANS: u32 = 500;
/// `cos 45°`: a meeting within 45° of the car's heading is `along`, of its reverse `oncoming`.
const COS_45: f64 = std::f64::consts::FRAC_1_SQRT_2;

/// How a composed pedestrian meets the ego's route.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Role {
    /// Walks across the car's path (more than 45° from its heading either way).
    Crossing,
    /// Walks within 45° of the car's heading.
    Along,
    /// Walks within 45° of the car's reverse heading.
    Oncoming,
    /// Never comes within [`MEETING_DISTANCE`] of the car's path, or stands.
    Background,
}

impl Role {
    pub const ALL: [Role; 4] = [
        Role::Crossing,
        Role::Along,
        Role::Oncoming,
        Role::Background,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            Role::Crossing => "crossing",
            Role::Along => "along",
            Role::Oncoming => "oncoming",
            Role::Background => "background",
        }
    }
}

impl fmt::Display for Role {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for Role {
    type Err = ComposeError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Role::ALL
            .into_iter()
            .find(|r| r.as_str() == s)
            .ok_or_else(|| ComposeError::UnknownRole(s.to_string()))
    }
}

/// The weights of the roles a composed pedestrian draws (normalised when drawn). The defaults
/// are the shares among the 177 pedestrians of hbs-paper's 59 train scenes (EXTRACTION.md);
/// the general pool's are within 0.07 of them.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RoleShares {
    pub crossing: f64,
    pub along: f64,
    pub oncoming: f64,
    pub background: f64,
}

impl Default for RoleShares {
    fn default() -> Self {
        Self {
            crossing: 0.74,
            along: 0.07,
            oncoming: 0.05,
            background: 0.14,
        }
    }
}

impl RoleShares {
    fn weight(&self, role: Role) -> f64 {
        match role {
            Role::Crossing => self.crossing,
            Role::Along => self.along,
            Role::Oncoming => self.oncoming,
            Role::Background => self.background,
        }
    }

    /// Every weight finite and non-negative, and their sum positive.
    pub fn validate(&self) -> Result<(), ComposeError> {
        for role in Role::ALL {
            let w = self.weight(role);
            if !(w.is_finite() && w >= 0.0) {
                return Err(ComposeError::Shares(format!(
                    "share {role} is {w}: a finite weight >= 0"
                )));
            }
        }
        if Role::ALL.iter().map(|&r| self.weight(r)).sum::<f64>() <= 0.0 {
            return Err(ComposeError::Shares("the shares sum to 0".into()));
        }
        Ok(())
    }
}

/// What a composed scene is made of (see the module docs).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ComposeConfig {
    /// The generator's seed: scene `index` depends on `(seed, index)` alone.
    pub seed: u64,
    /// Pedestrians per scene (`None`: as many as the route's recorded scene had).
    pub pedestrians: Option<u32>,
    /// The roles' weights.
    pub shares: RoleShares,
    /// Whether the route's recorded other cars come along (they move as the env's vehicle
    /// model says: `idm` reacts, `replay` replays).
    pub other_cars: bool,
}

impl Default for ComposeConfig {
    fn default() -> Self {
        Self {
            seed: 0,
            pedestrians: None,
            shares: RoleShares::default(),
            other_cars: true,
        }
    }
}

impl ComposeConfig {
    pub fn validate(&self) -> Result<(), ComposeError> {
        self.shares.validate()?;
        match self.pedestrians {
            Some(n) if n > MAX_PEDESTRIANS => Err(ComposeError::TooManyPedestrians(n)),
            _ => Ok(()),
        }
    }
}

/// Why a pool cannot give parts, or a configuration is unusable.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ComposeError {
    #[error("pool {pool:?} has no scene {name:?} to hold out")]
    UnknownScene { pool: String, name: String },
    #[error("pool {pool:?} has no train scene whose car may be used (all held out?)")]
    NoRoutes { pool: String },
    #[error("pool {pool:?} has no train-scene pedestrian that may be used (all held out?)")]
    NoTracks { pool: String },
    #[error("{0}")]
    Shares(String),
    #[error("unknown role `{0}` (expected crossing, along, oncoming or background)")]
    UnknownRole(String),
    #[error("pedestrians {0} exceeds {MAX_PEDESTRIANS}")]
    TooManyPedestrians(u32),
}

type V2 = [f64; 2];

fn sub(a: V2, b: V2) -> V2 {
    [a[0] - b[0], a[1] - b[1]]
}
fn add(a: V2, b: V2) -> V2 {
    [a[0] + b[0], a[1] + b[1]]
}
fn scale(a: V2, s: f64) -> V2 {
    [a[0] * s, a[1] * s]
}
fn dot(a: V2, b: V2) -> f64 {
    a[0] * b[0] + a[1] * b[1]
}
/// `a` turned left by 90°.
fn perp(a: V2) -> V2 {
    [-a[1], a[0]]
}
fn norm(a: V2) -> f64 {
    (a[0] * a[0] + a[1] * a[1]).sqrt()
}
fn unit(a: V2) -> Option<V2> {
    let n = norm(a);
    (n > 1e-9).then(|| scale(a, 1.0 / n))
}
/// `v` in the frame whose x axis is the unit vector `axis`.
fn to_frame(v: V2, axis: V2) -> V2 {
    [dot(v, axis), dot(v, perp(axis))]
}
/// `v` given in the frame whose x axis is `axis`, back in world coordinates.
fn from_frame(v: V2, axis: V2) -> V2 {
    add(scale(axis, v[0]), scale(perp(axis), v[1]))
}

/// The unit heading of a recorded car at sample `j`: along its path there, else from its first
/// to its last sample, else +x.
fn path_heading(positions: &[V2], j: usize) -> V2 {
    let n = positions.len();
    let (a, b) = (j.saturating_sub(1), (j + 1).min(n - 1));
    unit(sub(positions[b], positions[a]))
        .or_else(|| unit(sub(positions[n - 1], positions[0])))
        .unwrap_or([1.0, 0.0])
}

/// A recorded car's route: the ego of a composed scene.
#[derive(Debug, Clone)]
struct Route {
    ego: AgentRecord,
    others: Vec<AgentRecord>,
    pedestrians: usize,
}

/// A recorded pedestrian's track and the unit direction from its start to its goal (`None`
/// when it stands).
#[derive(Debug, Clone)]
struct Track {
    record: AgentRecord,
    direction: Option<V2>,
}

/// Where and when a recorded pedestrian met its scene's car (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Meeting {
    /// The car's path sample at the closest approach, as a fraction of its route's samples.
    fraction: f64,
    /// The pedestrian's offset from that sample in the car's frame (m): along, across (left).
    offset: V2,
    /// The pedestrian's walking direction in the car's frame (a unit vector; `None`: stands).
    direction: Option<V2>,
    /// Steps from the car's passing of that sample to the pedestrian's closest approach.
    delay: i64,
}

impl Meeting {
    /// The meeting of pedestrian `ped` with car `ego` (both of one scene).
    fn of(ped: &AgentRecord, ego: &AgentRecord) -> (Role, Meeting) {
        let (mut best, mut at) = (f64::INFINITY, (0, 0));
        for (i, p) in ped.positions.iter().enumerate() {
            for (j, e) in ego.positions.iter().enumerate() {
                let d = norm(sub(*p, *e));
                if d < best {
                    (best, at) = (d, (i, j));
                }
            }
        }
        let (i, j) = at;
        let heading = path_heading(&ego.positions, j);
        let displacement = sub(ped.goal(), ped.positions[0]);
        let direction = (norm(displacement) >= STANDING_DISPLACEMENT)
            .then(|| unit(to_frame(displacement, heading)))
            .flatten();
        let role = match direction {
            _ if best > MEETING_DISTANCE => Role::Background,
            None => Role::Background,
            Some(d) if d[0] > COS_45 => Role::Along,
            Some(d) if d[0] < -COS_45 => Role::Oncoming,
            Some(_) => Role::Crossing,
        };
        let last = ego.positions.len().saturating_sub(1).max(1) as f64;
        let meeting = Meeting {
            fraction: j as f64 / last,
            offset: to_frame(sub(ped.positions[i], ego.positions[j]), heading),
            direction,
            delay: (i64::from(ped.start_step) + i as i64) - (i64::from(ego.start_step) + j as i64),
        };
        (role, meeting)
    }
}

/// The parts of a pool's train scenes that composed scenes are made of (see the module docs).
#[derive(Debug, Clone)]
pub struct Parts {
    pool: String,
    dt: f64,
    routes: Vec<Route>,
    tracks: Vec<Track>,
    /// Indices into `tracks` of the moving ones and of the standing ones.
    moving: Vec<usize>,
    standing: Vec<usize>,
    meetings: BTreeMap<Role, Vec<Meeting>>,
    held_out: BTreeSet<(AgentKind, u64)>,
}

fn key(a: &AgentRecord) -> (AgentKind, u64) {
    (a.kind, a.record_id)
}

impl Parts {
    /// The parts of `pool`'s train scenes but those named in `hold_out`; no agent of a test
    /// scene or of a held-out scene is among them.
    pub fn new(pool: &ScenarioPool, hold_out: &[String]) -> Result<Self, ComposeError> {
        let scenes: Vec<&Scenario> = pool.scenarios.iter().collect();
        Self::of_scenes(&pool.name, &scenes, hold_out)
    }

    /// [`Parts::new`] of the pool called `pool` whose scenes are `scenes`.
    pub fn of_scenes(
        pool: &str,
        scenes: &[&Scenario],
        hold_out: &[String],
    ) -> Result<Self, ComposeError> {
        let held: BTreeSet<&str> = hold_out.iter().map(String::as_str).collect();
        for name in &held {
            if !scenes.iter().any(|s| s.name == *name) {
                return Err(ComposeError::UnknownScene {
                    pool: pool.to_string(),
                    name: name.to_string(),
                });
            }
        }
        let usable = |s: &Scenario| s.split == Split::Train && !held.contains(s.name.as_str());
        let held_out: BTreeSet<(AgentKind, u64)> = scenes
            .iter()
            .filter(|s| !usable(s))
            .flat_map(|s| s.agents.iter().map(key))
            .collect();
        let free = |a: &AgentRecord| !held_out.contains(&key(a));
        let mut routes = Vec::new();
        let mut longest: BTreeMap<u64, AgentRecord> = BTreeMap::new();
        let mut meetings: BTreeMap<Role, Vec<Meeting>> = BTreeMap::new();
        for scene in scenes.iter().filter(|s| usable(s)) {
            let Some(ego) = scene.agents.get(scene.ego).filter(|e| free(e)) else {
                continue;
            };
            let pedestrians: Vec<&AgentRecord> = scene
                .agents
                .iter()
                .filter(|a| a.kind == AgentKind::Pedestrian)
                .collect();
            routes.push(Route {
                ego: AgentRecord {
                    start_step: 0,
                    non_reactive: false,
                    desired_speed: None,
                    ..ego.clone()
                },
                others: scene
                    .agents
                    .iter()
                    .enumerate()
                    .filter(|&(k, a)| k != scene.ego && a.kind == AgentKind::Vehicle && free(a))
                    .map(|(_, a)| AgentRecord {
                        start_step: a.start_step.saturating_sub(ego.start_step),
                        ..a.clone()
                    })
                    .collect(),
                pedestrians: pedestrians.len(),
            });
            for ped in pedestrians.into_iter().filter(|p| free(p)) {
                let (role, meeting) = Meeting::of(ped, ego);
                meetings.entry(role).or_default().push(meeting);
                let kept = longest.entry(ped.record_id).or_insert_with(|| ped.clone());
                if ped.positions.len() > kept.positions.len() {
                    *kept = ped.clone();
                }
            }
        }
        let tracks: Vec<Track> = longest
            .into_values()
            .filter(|r| r.positions.len() >= 2)
            .map(|record| {
                let displacement = sub(record.goal(), record.positions[0]);
                Track {
                    direction: (norm(displacement) >= STANDING_DISPLACEMENT)
                        .then(|| unit(displacement))
                        .flatten(),
                    record: AgentRecord {
                        start_step: 0,
                        non_reactive: false,
                        desired_speed: None,
                        ..record
                    },
                }
            })
            .collect();
        if routes.is_empty() {
            return Err(ComposeError::NoRoutes {
                pool: pool.to_string(),
            });
        }
        if tracks.is_empty() || meetings.is_empty() {
            return Err(ComposeError::NoTracks {
                pool: pool.to_string(),
            });
        }
        let moving = (0..tracks.len())
            .filter(|&k| tracks[k].direction.is_some())
            .collect();
        let standing = (0..tracks.len())
            .filter(|&k| tracks[k].direction.is_none())
            .collect();
        Ok(Self {
            pool: pool.to_string(),
            dt: scenes.first().map_or(crate::pool::DT, |s| s.dt),
            routes,
            tracks,
            moving,
            standing,
            meetings,
            held_out,
        })
    }

    /// The pool the parts come from.
    pub fn pool(&self) -> &str {
        &self.pool
    }

    /// Routes, pedestrian tracks and recorded meetings.
    pub fn counts(&self) -> (usize, usize, usize) {
        let meetings = self.meetings.values().map(Vec::len).sum();
        (self.routes.len(), self.tracks.len(), meetings)
    }

    /// The recorded meetings of each role.
    pub fn role_counts(&self) -> BTreeMap<Role, usize> {
        self.meetings.iter().map(|(r, m)| (*r, m.len())).collect()
    }

    /// Agents (kind, record id) of the test and held-out scenes: none enters a composed scene.
    pub fn held_out(&self) -> &BTreeSet<(AgentKind, u64)> {
        &self.held_out
    }

    /// Every agent (kind, record id) a composed scene may hold.
    pub fn record_ids(&self) -> BTreeSet<(AgentKind, u64)> {
        let cars = self
            .routes
            .iter()
            .flat_map(|r| std::iter::once(&r.ego).chain(&r.others))
            .map(key);
        cars.chain(self.tracks.iter().map(|t| key(&t.record)))
            .collect()
    }

    /// The name of scene `index` of generator seed `seed`.
    pub fn scene_name(seed: u64, index: u64) -> String {
        format!("composed-s{seed}-{index}")
    }

    /// `(seed, index)` of a name written by [`Parts::scene_name`].
    pub fn parse_scene_name(name: &str) -> Option<(u64, u64)> {
        let (seed, index) = name.strip_prefix("composed-s")?.split_once('-')?;
        let number = |s: &str| {
            (!s.is_empty() && s.bytes().all(|b| b.is_ascii_digit()))
                .then(|| s.parse().ok())
                .flatten()
        };
        Some((number(seed)?, number(index)?))
    }

    /// Composed scene `index` of `config` (see the module docs).
    pub fn compose(&self, config: &ComposeConfig, index: u64) -> Scenario {
        let mut rng = SplitMix64::new(derive_seed(config.seed, index));
        let route = &self.routes[below(&mut rng, self.routes.len())];
        let mut agents = vec![route.ego.clone()];
        if config.other_cars {
            agents.extend(route.others.iter().cloned());
        }
        let count = config.pedestrians.map_or(route.pedestrians, |n| n as usize);
        let mut placed: Vec<TrackFootprint> = agents.iter().map(TrackFootprint::new).collect();
        let mut used: BTreeSet<(AgentKind, u64)> = agents.iter().map(key).collect();
        for _ in 0..count {
            for _ in 0..TRIES {
                let Some(ped) = self.draw_pedestrian(&config.shares, route, &mut rng) else {
                    continue;
                };
                let footprint = TrackFootprint::new(&ped);
                if used.contains(&key(&ped))
                    || !starts_clear(&footprint, &agents, &placed)
                    || meets_the_recorded_car(&footprint, &placed[0], ped.positions.len())
                {
                    continue;
                }
                used.insert(key(&ped));
                placed.push(footprint);
                agents.push(ped);
                break;
            }
        }
        Scenario {
            name: Self::scene_name(config.seed, index),
            split: Split::Train,
            dt: self.dt,
            ego: 0,
            agents,
        }
    }

    /// One pedestrian for `route`: a role, a recorded meeting of it and another pedestrian's
    /// track moved to keep that meeting with the new car (`None`: the draw does not fit).
    fn draw_pedestrian(
        &self,
        shares: &RoleShares,
        route: &Route,
        rng: &mut SplitMix64,
    ) -> Option<AgentRecord> {
        let role = draw_role(shares, &self.meetings, rng)?;
        let meetings = &self.meetings[&role];
        let meeting = meetings[below(rng, meetings.len())];
        let pick = match meeting.direction {
            Some(_) if !self.moving.is_empty() => &self.moving,
            _ if !self.standing.is_empty() => &self.standing,
            _ => &self.moving,
        };
        let track = &self.tracks[pick[below(rng, pick.len())]];
        let mirrored = rng.next_u64() & 1 == 1;
        // The car's frame at the meeting's sample of the new route.
        let car = &route.ego.positions;
        let n = car.len();
        let j = ((meeting.fraction * (n - 1) as f64) + 0.5).floor() as usize;
        let heading = path_heading(car, j.min(n - 1));
        let point = add(car[j.min(n - 1)], from_frame(meeting.offset, heading));
        // The track's own frame: its direction (any, for one that stands) and the rotation
        // that turns it to the meeting's direction in the car's frame.
        let own = track.direction.unwrap_or([1.0, 0.0]);
        let wanted = match meeting.direction {
            Some(d) => from_frame(d, heading),
            None => random_unit(rng),
        };
        // The step at which the pedestrian passes `point`, and its sample there.
        let at = j as i64 + meeting.delay;
        let len = track.record.positions.len() as i64;
        let (lo, hi) = (at.max(0), (len - 2 + at).min(len - 1));
        if lo > hi {
            return None;
        }
        let i = lo + below(rng, (hi - lo + 1) as usize) as i64;
        let first = (i - at) as usize;
        let last = (first + n).min(len as usize);
        let pivot = track.record.positions[i as usize];
        let turn = |v: V2| {
            let local = to_frame(v, own);
            let local = if mirrored {
                [local[0], -local[1]]
            } else {
                local
            };
            from_frame(local, wanted)
        };
        let record = &track.record;
        Some(AgentRecord {
            positions: record.positions[first..last]
                .iter()
                .map(|&p| add(point, turn(sub(p, pivot))))
                .collect(),
            velocities: record.velocities[first..last]
                .iter()
                .map(|&v| turn(v))
                .collect(),
            ..record.clone()
        })
    }
}

/// Whether a pedestrian whose footprints `footprint` gives (starting at step 0) keeps its gaps
/// from every agent of `agents` (footprints `placed`) where the later of the two enters: at
/// step 0 from those there, and where each later one enters.
fn starts_clear(
    footprint: &TrackFootprint,
    agents: &[AgentRecord],
    placed: &[TrackFootprint],
) -> bool {
    agents.iter().zip(placed).all(|(a, f)| {
        let gap = match a.kind {
            AgentKind::Vehicle => VEHICLE_GAP,
            AgentKind::Pedestrian => PEDESTRIAN_GAP,
        };
        match (footprint.at(a.start_step), f.at(a.start_step)) {
            (Some(me), Some(other)) => clearance(&me, &other) > gap,
            _ => true,
        }
    })
}

/// Whether a pedestrian's recorded track (footprints `footprint`, `samples` of them from step
/// 0) touches the recorded car's (`car`) at any step: in the recording nobody ever did, so a
/// composed scene's record does not either.
fn meets_the_recorded_car(
    footprint: &TrackFootprint,
    car: &TrackFootprint,
    samples: usize,
) -> bool {
    (0..samples as u32).any(|step| match (footprint.at(step), car.at(step)) {
        (Some(me), Some(c)) => clearance(&me, &c) <= 0.0,
        _ => false,
    })
}

/// Uniform in `0..n` (`n > 0`).
fn below(rng: &mut SplitMix64, n: usize) -> usize {
    (rng.next_u64() % n as u64) as usize
}

/// A role by the shares' weights among the roles that have a recorded meeting.
fn draw_role(
    shares: &RoleShares,
    meetings: &BTreeMap<Role, Vec<Meeting>>,
    rng: &mut SplitMix64,
) -> Option<Role> {
    let weight = |r: Role| {
        if meetings.get(&r).is_some_and(|m| !m.is_empty()) {
            shares.weight(r)
        } else {
            0.0
        }
    };
    let total: f64 = Role::ALL.iter().map(|&r| weight(r)).sum();
    if total <= 0.0 {
        return None;
    }
    let mut u = rng.next_f64() * total;
    for role in Role::ALL {
        let w = weight(role);
        if u < w {
            return Some(role);
        }
        u -= w;
    }
    Role::ALL.into_iter().rev().find(|&r| weight(r) > 0.0)
}

/// A uniformly random unit vector (rejection from the unit disc: no trigonometry).
fn random_unit(rng: &mut SplitMix64) -> V2 {
    loop {
        let v = [rng.range(-1.0, 1.0), rng.range(-1.0, 1.0)];
        let n = norm(v);
        if n > 1e-3 && n <= 1.0 {
            return scale(v, 1.0 / n);
        }
    }
}
