//! Seeded synthetic scenarios: one ego vehicle crossing a square of pedestrians.
//!
//! For `N` pedestrians at `density` (pedestrians per m², default 0.25) the area is the square
//! `[0, side]²` with `side = sqrt(N / density)`. Pedestrian record ids are `V..V+N` (`1..=N`
//! with one vehicle); the ego
//! vehicle (record id 0, agent index 0) drives along `+x` on the line `y = side / 2` from
//! `x = -(length/2 + 1 m)` to `x = side + length/2 + 1 m` at `vehicle_speed` (default 3 m/s), so
//! it starts 1 m clear of the square. Layouts set each pedestrian's walking direction:
//! - `crossing`: across the vehicle's path, `+y` or `-y` (equal odds) turned by a uniform jitter
//!   in `[-0.2, 0.2]` rad;
//! - `counter_flow`: towards the oncoming vehicle, `-x` with the same jitter;
//! - `random`: uniform in `[0, 2π)`.
//!
//! The side may not exceed [`MAX_SIDE`] (10 km) and speeds must be at least 0.1 m/s, so that
//! tracks stay bounded.
//!
//! Each pedestrian gets a speed uniform in `[ped_speed_min, ped_speed_max]` (default 1.0–1.5 m/s)
//! and a straight recorded track from its start to its goal `start + direction * walk`, with
//! `walk = min(side, max_walk)` (default `max_walk` 30 m), sampled every 0.5 s at that constant
//! velocity (the last sample is the goal), so goals and mean speeds are defined. All agents start
//! at step 0. The vehicle's track is sampled the same way. With `V > 1` vehicles the others
//! (record ids `1..V`) drive by [`Routes`]: on parallel lanes [`LANE_SPACING`] apart, alternately
//! oncoming (`lanes`, the default), or through a four-way intersection at the square's centre
//! (`intersection`, at most 4 vehicles): vehicle `k` heads `k * 90°` (`+x`, `+y`, `-x`, `-y`),
//! keeping half a lane to the right of the centre lines, from 1 m outside the square to 1 m past
//! it, so perpendicular routes cross at the centre and opposite ones pass 4 m apart. Vehicle
//! `k > 0` starts a lag of 0–4 steps (0–2 s) of driving farther back on its route, drawn from a
//! stream of its own (`SplitMix64::new(seed ^ ROUTE_STREAM)`), so who reaches the crossing first
//! varies with the seed while the pedestrians stay those of the `lanes` scene of the same seed.
//! Every vehicle is there from step 0, outside the square, where no pedestrian starts: a car
//! that entered later could appear on top of a pedestrian walking out of the square, a collision
//! no driver could avoid.
//!
//! Initial positions are uniform in `[0.3 + ε, side - 0.3 - ε]²` and pairwise non-overlapping
//! (centre distance `> 0.6 m + ε`, ε = 1e-6 m, so clearance `> 0`): rejection sampling with at
//! most 64 tries per pedestrian against a uniform grid (cell 0.6 m + ε, 3×3 neighbourhood, so
//! `O(N)` overall), then a fallback that scans a square lattice of spacing `0.6 m + 2ε` from a
//! seeded offset and takes the first free point. When `N` is at least half the lattice's capacity
//! (density above about 1.4 per m², where random placement jams) the pedestrians are placed
//! directly on `N` lattice points chosen by a seeded partial Fisher-Yates shuffle. A
//! configuration that even the lattice cannot hold (about 2.7 per m²) fails with
//! [`SyntheticError::TooDense`].
//!
//! Randomness comes only from [`SplitMix64`] seeded with `seed`: the same configuration gives an
//! identical scenario on every platform.

use std::f64::consts::TAU;
use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};
use sim_core::scenario::{
    AgentKind, AgentRecord, Scenario, ScenarioPool, Split, SCENARIO_FORMAT_VERSION,
};

use crate::footprint::{PED_RADIUS, VEHICLE_LENGTH};
use crate::pool::DT;

const EPS: f64 = 1e-6;
const TRIES: usize = 64;
const JITTER: f64 = 0.2;
/// Upper bound on the side of the square (m), to keep tracks and grids bounded.
pub const MAX_SIDE: f64 = 10_000.0;
/// Upper bound on the number of pedestrians, to keep allocations bounded.
pub const MAX_PEDESTRIANS: usize = 1_000_000;

pub use sim_core::support::rng::SplitMix64;

/// How pedestrians walk relative to the ego vehicle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Layout {
    Crossing,
    CounterFlow,
    Random,
}

impl Layout {
    pub const ALL: [Layout; 3] = [Layout::Crossing, Layout::CounterFlow, Layout::Random];

    pub fn as_str(self) -> &'static str {
        match self {
            Layout::Crossing => "crossing",
            Layout::CounterFlow => "counter_flow",
            Layout::Random => "random",
        }
    }
}

impl fmt::Display for Layout {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for Layout {
    type Err = SyntheticError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Layout::ALL
            .into_iter()
            .find(|l| l.as_str() == s)
            .ok_or_else(|| SyntheticError::UnknownLayout(s.to_string()))
    }
}

/// How the vehicles of a scene drive (see the module docs).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Routes {
    /// Parallel lanes [`LANE_SPACING`] apart, alternately oncoming.
    #[default]
    Lanes,
    /// A four-way intersection at the square's centre; at most [`MAX_INTERSECTION_VEHICLES`].
    Intersection,
}

impl Routes {
    pub const ALL: [Routes; 2] = [Routes::Lanes, Routes::Intersection];

    pub fn as_str(self) -> &'static str {
        match self {
            Routes::Lanes => "lanes",
            Routes::Intersection => "intersection",
        }
    }
}

impl fmt::Display for Routes {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for Routes {
    type Err = SyntheticError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Routes::ALL
            .into_iter()
            .find(|r| r.as_str() == s)
            .ok_or_else(|| SyntheticError::UnknownRoutes(s.to_string()))
    }
}

/// Arms of the intersection: at most one vehicle per heading.
pub const MAX_INTERSECTION_VEHICLES: usize = 4;
/// Most steps of driving a vehicle of an `intersection` scene starts behind the others' start
/// line (its lag, `lag * vehicle_speed * 0.5 s` metres).
pub const MAX_ENTRY_LAG_STEPS: u64 = 4;
/// Mixed into the seed for the vehicles' own random stream (their lags), so that the
/// pedestrians' draws are untouched by the routes.
const ROUTE_STREAM: u64 = 0x9E37_79B9_7F4A_7C15;

/// An unusable synthetic configuration.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SyntheticError {
    #[error("unknown layout `{0}` (expected crossing, counter_flow or random)")]
    UnknownLayout(String),
    #[error("unknown routes `{0}` (expected lanes or intersection)")]
    UnknownRoutes(String),
    #[error("field `{field}`: {value} is invalid: {problem}")]
    Invalid {
        field: &'static str,
        value: f64,
        problem: &'static str,
    },
    #[error("field `pedestrians`: {0} exceeds the limit {MAX_PEDESTRIANS}")]
    TooMany(usize),
    #[error(
        "cannot place {pedestrians} non-overlapping pedestrians in a {side} m square \
         (density {density} per m² is too high; placed {placed})"
    )]
    TooDense {
        pedestrians: usize,
        density: f64,
        side: f64,
        placed: usize,
    },
}

/// A synthetic scenario's configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct SyntheticConfig {
    pub layout: Layout,
    /// Number of pedestrians `N`.
    pub pedestrians: usize,
    /// Pedestrians per square metre.
    pub density: f64,
    pub seed: u64,
    /// Pedestrian speed range (m/s).
    pub ped_speed_min: f64,
    pub ped_speed_max: f64,
    /// Longest pedestrian walk (m).
    pub max_walk: f64,
    /// Ego vehicle speed (m/s).
    pub vehicle_speed: f64,
    pub split: Split,
    /// Vehicles `V` (at least 1): the ego, then `V - 1` others on parallel lanes
    /// [`LANE_SPACING`] apart (alternately below and above the ego's line), odd ones oncoming
    /// (`-x`), even ones along `+x`, at `vehicle_speed`.
    pub vehicles: usize,
    /// How the vehicles drive: parallel lanes (default) or through an intersection.
    pub routes: Routes,
}

/// Distance between the vehicles' parallel lanes (m): a car's width plus clearance.
pub const LANE_SPACING: f64 = 4.0;
/// Upper bound on the number of vehicles.
pub const MAX_VEHICLES: usize = 64;

impl Default for SyntheticConfig {
    fn default() -> Self {
        Self {
            layout: Layout::Crossing,
            pedestrians: 10,
            density: 0.25,
            seed: 0,
            ped_speed_min: 1.0,
            ped_speed_max: 1.5,
            max_walk: 30.0,
            vehicle_speed: 3.0,
            split: Split::Train,
            vehicles: 1,
            routes: Routes::Lanes,
        }
    }
}

impl SyntheticConfig {
    /// Defaults with the given layout, pedestrian count and seed.
    pub fn new(layout: Layout, pedestrians: usize, seed: u64) -> Self {
        Self {
            layout,
            pedestrians,
            seed,
            ..Self::default()
        }
    }

    /// Side of the square area in metres: `sqrt(N / density)`.
    pub fn side(&self) -> f64 {
        (self.pedestrians as f64 / self.density).sqrt()
    }

    fn check(&self) -> Result<(), SyntheticError> {
        let invalid = |field, value, problem| {
            Err(SyntheticError::Invalid {
                field,
                value,
                problem,
            })
        };
        let positive = "must be finite and > 0";
        if !(self.density.is_finite() && self.density > 0.0) {
            return invalid("density", self.density, positive);
        }
        let min_speed = "must be finite and >= 0.1 m/s";
        if !(self.ped_speed_min.is_finite() && self.ped_speed_min >= 0.1) {
            return invalid("ped_speed_min", self.ped_speed_min, min_speed);
        }
        if !(self.ped_speed_max.is_finite() && self.ped_speed_max >= self.ped_speed_min) {
            return invalid(
                "ped_speed_max",
                self.ped_speed_max,
                "must be finite and >= ped_speed_min",
            );
        }
        if !(self.max_walk.is_finite() && self.max_walk > 0.0) {
            return invalid("max_walk", self.max_walk, positive);
        }
        if !(self.vehicle_speed.is_finite() && self.vehicle_speed >= 0.1) {
            return invalid("vehicle_speed", self.vehicle_speed, min_speed);
        }
        if self.vehicles == 0 || self.vehicles > MAX_VEHICLES {
            return invalid("vehicles", self.vehicles as f64, "must be between 1 and 64");
        }
        if self.routes == Routes::Intersection && self.vehicles > MAX_INTERSECTION_VEHICLES {
            return invalid(
                "vehicles",
                self.vehicles as f64,
                "an intersection has 4 arms: at most 4 vehicles",
            );
        }
        if self.pedestrians > MAX_PEDESTRIANS {
            return Err(SyntheticError::TooMany(self.pedestrians));
        }
        if self.side() > MAX_SIDE {
            return invalid(
                "density",
                self.density,
                "too low: the square's side would exceed 10 km",
            );
        }
        Ok(())
    }

    /// The scenario name: `synthetic-<layout>-n<N>-seed<seed>`, with `-v<V>` after `n<N>`
    /// when there is more than one vehicle, and `-intersection` after it for those routes.
    pub fn name(&self) -> String {
        let vehicles = match (self.vehicles > 1, self.routes) {
            (false, Routes::Lanes) => String::new(),
            (true, Routes::Lanes) => format!("-v{}", self.vehicles),
            (_, Routes::Intersection) => format!("-v{}-intersection", self.vehicles),
        };
        format!(
            "synthetic-{}-n{}{vehicles}-seed{}",
            self.layout, self.pedestrians, self.seed
        )
    }
}

/// Constant-velocity straight track from `start` to `goal` at `speed`, sampled every [`DT`].
fn straight_track(start: [f64; 2], goal: [f64; 2], speed: f64) -> (Vec<[f64; 2]>, Vec<[f64; 2]>) {
    let (dx, dy) = (goal[0] - start[0], goal[1] - start[1]);
    let dist = dx.hypot(dy);
    let steps = (dist / (speed * DT)).ceil().max(1.0) as usize;
    let (ux, uy) = if dist > 0.0 {
        (dx / dist, dy / dist)
    } else {
        (0.0, 0.0)
    };
    let mut pos = Vec::with_capacity(steps + 1);
    for k in 0..steps {
        let s = (k as f64 * speed * DT).min(dist);
        pos.push([start[0] + ux * s, start[1] + uy * s]);
    }
    pos.push(goal);
    let vel = vec![[ux * speed, uy * speed]; pos.len()];
    (pos, vel)
}

/// Uniform grid of placed pedestrian centres for the overlap checks.
struct Grid {
    cell: f64,
    n: usize,
    cells: Vec<Vec<[f64; 2]>>,
}

impl Grid {
    /// A grid over `[0, side]²` with cells of at least `min_cell` (so that a 3x3 neighbourhood
    /// holds every point within `min_cell`) and at most about `4 * points` cells.
    fn new(side: f64, min_cell: f64, points: usize) -> Self {
        let max_n = 2 * ((points as f64).sqrt().ceil() as usize) + 1;
        let n = ((side / min_cell).floor() as usize).clamp(1, max_n);
        Self {
            cell: (side / n as f64).max(min_cell),
            n,
            cells: vec![Vec::new(); n * n],
        }
    }

    fn coord(&self, v: f64) -> usize {
        ((v / self.cell).floor().max(0.0) as usize).min(self.n - 1)
    }

    fn free(&self, p: [f64; 2], min_dist: f64) -> bool {
        let (cx, cy) = (self.coord(p[0]), self.coord(p[1]));
        for x in cx.saturating_sub(1)..=(cx + 1).min(self.n - 1) {
            for y in cy.saturating_sub(1)..=(cy + 1).min(self.n - 1) {
                for q in &self.cells[x * self.n + y] {
                    if (p[0] - q[0]).hypot(p[1] - q[1]) <= min_dist {
                        return false;
                    }
                }
            }
        }
        true
    }

    fn insert(&mut self, p: [f64; 2]) {
        let (cx, cy) = (self.coord(p[0]), self.coord(p[1]));
        self.cells[cx * self.n + cy].push(p);
    }
}

/// Non-overlapping initial positions (see the module docs).
fn place(
    cfg: &SyntheticConfig,
    side: f64,
    rng: &mut SplitMix64,
) -> Result<Vec<[f64; 2]>, SyntheticError> {
    let n = cfg.pedestrians;
    let min_dist = 2.0 * PED_RADIUS + EPS;
    let (lo, hi) = (PED_RADIUS + EPS, side - PED_RADIUS - EPS);
    let too_dense = |placed| SyntheticError::TooDense {
        pedestrians: n,
        density: cfg.density,
        side,
        placed,
    };
    if n > 0 && hi < lo {
        return Err(too_dense(0));
    }
    let mut grid = Grid::new(side, min_dist, n);
    let mut out = Vec::with_capacity(n);
    // Lattice fallback state.
    let spacing = min_dist + EPS;
    let per_row = if hi >= lo {
        ((hi - lo) / spacing).floor() as usize + 1
    } else {
        0
    };
    let lattice = per_row.saturating_mul(per_row);
    if n > 0 && 2 * n >= lattice {
        // Dense: rejection sampling would jam; take n lattice points by a seeded partial shuffle.
        if n > lattice {
            return Err(too_dense(0));
        }
        let mut idx: Vec<usize> = (0..lattice).collect();
        for k in 0..n {
            let j = k + (rng.next_u64() % (lattice - k) as u64) as usize;
            idx.swap(k, j);
        }
        return Ok(idx[..n]
            .iter()
            .map(|&c| {
                [
                    lo + (c / per_row) as f64 * spacing,
                    lo + (c % per_row) as f64 * spacing,
                ]
            })
            .collect());
    }
    let mut cursor = 0usize;
    let mut cursor_seeded = false;
    let mut scanned_since_success = 0usize;
    for _ in 0..n {
        let mut spot = None;
        for _ in 0..TRIES {
            let p = [rng.range(lo, hi), rng.range(lo, hi)];
            if grid.free(p, min_dist) {
                spot = Some(p);
                break;
            }
        }
        if spot.is_none() {
            if !cursor_seeded {
                cursor = (rng.next_u64() % lattice.max(1) as u64) as usize;
                cursor_seeded = true;
            }
            while scanned_since_success < lattice {
                let (i, j) = (cursor / per_row, cursor % per_row);
                cursor = (cursor + 1) % lattice;
                scanned_since_success += 1;
                let p = [lo + i as f64 * spacing, lo + j as f64 * spacing];
                if grid.free(p, min_dist) {
                    spot = Some(p);
                    break;
                }
            }
        }
        let Some(p) = spot else {
            return Err(too_dense(out.len()));
        };
        scanned_since_success = 0;
        grid.insert(p);
        out.push(p);
    }
    Ok(out)
}

/// Each vehicle's start and goal (see the module docs).
fn vehicle_routes(cfg: &SyntheticConfig, side: f64) -> Vec<([f64; 2], [f64; 2])> {
    let margin = 0.5 * VEHICLE_LENGTH + 1.0;
    let centre = 0.5 * side;
    match cfg.routes {
        // Vehicle 0 (the ego) drives along the centre line, left to right; the others alternate
        // direction on lanes either side of it, drawn without randomness so that V = 1 scenes
        // stay as they were.
        Routes::Lanes => (0..cfg.vehicles)
            .map(|k| {
                let side_sign = if k % 2 == 1 { -1.0 } else { 1.0 };
                let y = centre + (k as f64 / 2.0).ceil() * LANE_SPACING * side_sign;
                if k % 2 == 1 {
                    ([side + margin, y], [-margin, y])
                } else {
                    ([-margin, y], [side + margin, y])
                }
            })
            .collect(),
        Routes::Intersection => {
            let mut lags = SplitMix64::new(cfg.seed ^ ROUTE_STREAM);
            let reach = centre + margin;
            (0..cfg.vehicles)
                .map(|k| {
                    let (sin, cos) = (k as f64 * 0.25 * TAU).sin_cos();
                    // Half a lane to the right of the heading: right normal (sin, -cos).
                    let offset = 0.5 * LANE_SPACING;
                    let (cx, cy) = (centre + offset * sin, centre - offset * cos);
                    // The draw is made for the ego too, so that car k's lag stays its own
                    // whatever the number of cars; the ego keeps the start line.
                    let lag = (lags.next_u64() % (MAX_ENTRY_LAG_STEPS + 1)) as f64;
                    let back = if k == 0 {
                        0.0
                    } else {
                        lag * cfg.vehicle_speed * DT
                    };
                    let from = [cx - (reach + back) * cos, cy - (reach + back) * sin];
                    let to = [cx + reach * cos, cy + reach * sin];
                    (from, to)
                })
                .collect()
        }
    }
}

/// Generate one synthetic scenario (see the module docs).
pub fn generate(cfg: &SyntheticConfig) -> Result<Scenario, SyntheticError> {
    cfg.check()?;
    let side = cfg.side();
    let mut rng = SplitMix64::new(cfg.seed);
    let starts = place(cfg, side, &mut rng)?;
    let walk = side.min(cfg.max_walk);
    let mut agents = Vec::with_capacity(cfg.pedestrians + cfg.vehicles);
    for (k, (from, to)) in vehicle_routes(cfg, side).into_iter().enumerate() {
        let (pos, vel) = straight_track(from, to, cfg.vehicle_speed);
        agents.push(AgentRecord {
            record_id: k as u64,
            kind: AgentKind::Vehicle,
            start_step: 0,
            positions: pos,
            velocities: vel,
            non_reactive: false,
            desired_speed: None,
        });
    }
    let first_ped_id = cfg.vehicles as u64;
    for (i, start) in starts.into_iter().enumerate() {
        let angle = match cfg.layout {
            Layout::Crossing => {
                let base = if rng.next_u64() & 1 == 0 {
                    0.25 * TAU
                } else {
                    -0.25 * TAU
                };
                base + rng.range(-JITTER, JITTER)
            }
            Layout::CounterFlow => 0.5 * TAU + rng.range(-JITTER, JITTER),
            Layout::Random => rng.range(0.0, TAU),
        };
        let speed = rng.range(cfg.ped_speed_min, cfg.ped_speed_max);
        let (s, c) = angle.sin_cos();
        let goal = [start[0] + c * walk, start[1] + s * walk];
        let (pos, vel) = straight_track(start, goal, speed);
        agents.push(AgentRecord {
            record_id: i as u64 + first_ped_id,
            kind: AgentKind::Pedestrian,
            start_step: 0,
            positions: pos,
            velocities: vel,
            non_reactive: false,
            desired_speed: None,
        });
    }
    Ok(Scenario {
        name: cfg.name(),
        split: cfg.split,
        dt: DT,
        ego: 0,
        agents,
    })
}

/// A pool of synthetic scenarios, one per configuration, in order.
pub fn generate_pool(
    name: &str,
    configs: &[SyntheticConfig],
) -> Result<ScenarioPool, SyntheticError> {
    let scenarios = configs
        .iter()
        .map(generate)
        .collect::<Result<Vec<_>, _>>()?;
    let list: Vec<String> = configs.iter().map(|c| format!("{c:?}")).collect();
    Ok(ScenarioPool {
        version: SCENARIO_FORMAT_VERSION,
        vehicle_model: sim_core::params::VehicleModel::Replay,
        name: name.to_string(),
        provenance: format!(
            "synthetic scenarios generated by the scenarios crate {} (SplitMix64, see \
             scenarios::synthetic); configurations: [{}]",
            env!("CARGO_PKG_VERSION"),
            list.join(", ")
        ),
        scenarios,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splitmix_reference_values() {
        // Reference outputs of SplitMix64 seeded with 0 (Vigna's splitmix64.c).
        let mut r = SplitMix64::new(0);
        assert_eq!(r.next_u64(), 0xe220_a839_7b1d_cdaf);
        assert_eq!(r.next_u64(), 0x6e78_9e6a_a1b9_65f4);
        assert_eq!(r.next_u64(), 0x06c4_5d18_8009_454f);
    }

    #[test]
    fn layout_round_trips_through_str() {
        for l in Layout::ALL {
            assert_eq!(l.as_str().parse::<Layout>(), Ok(l));
        }
        assert!("diagonal".parse::<Layout>().is_err());
    }
}
