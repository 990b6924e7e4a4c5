//! The benchmark scene of one full world step (cognition, risk and graph all on): one external
//! AV among `N` CR-SFM pedestrians at 0.25 pedestrians per square metre, shared by the criterion
//! bench (`benches/world_step.rs`) and `sim-server bench-step`, which the pysocialforce
//! comparison script (`benchmarks/step_vs_pysocialforce.py`) runs side by side with pysocialforce.

use std::sync::Arc;
use std::time::Instant;

use scenarios::synthetic::{generate, Layout, SyntheticConfig};
use sim_core::params::{PedestrianModel, VehicleModel, WorldParams};
use sim_core::world::{AgentId, EpisodeConfig, StepScratch, World};

/// Steps taken before timing so that beliefs have a history (not all first sights).
pub const WARM_UP_STEPS: u32 = 3;

/// Threads a benchmark world may use: `SIM_STEP_THREADS` if set (default 1). Only scenes of at
/// least [`sim_core::world::PARALLEL_MIN_AGENTS`] agents are split; results are identical for
/// every thread count.
pub fn bench_threads() -> usize {
    std::env::var("SIM_STEP_THREADS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1)
}

/// A warmed-up world of 1 AV + `n` pedestrians (random layout, density 0.25 /m², `seed`).
pub fn bench_world(n: usize, seed: u64) -> World {
    bench_world_threads(n, seed, bench_threads())
}

/// [`bench_world`] stepping on `threads` threads.
pub fn bench_world_threads(n: usize, seed: u64, threads: usize) -> World {
    bench_traffic_world(n, seed, threads, 1, VehicleModel::Replay)
}

/// [`bench_world_threads`] with `vehicles` cars (the AV and `vehicles - 1` others on parallel
/// lanes through the crowd, [`SyntheticConfig::vehicles`]) moved by `model`.
pub fn bench_traffic_world(
    n: usize,
    seed: u64,
    threads: usize,
    vehicles: usize,
    model: VehicleModel,
) -> World {
    let cfg = SyntheticConfig {
        vehicles,
        ..SyntheticConfig::new(Layout::Random, n, seed)
    };
    let scenario = Arc::new(generate(&cfg).expect("benchmark scene is valid"));
    let mut config = EpisodeConfig::ego_external(&scenario, PedestrianModel::CrSfm);
    config.vehicle_model = model;
    let mut world = World::new(scenario, WorldParams::default(), config).expect("benchmark world");
    world.set_threads(threads);
    for _ in 0..WARM_UP_STEPS {
        if world.is_over() {
            break;
        }
        step_once(&mut world);
    }
    world
}

/// The AV holding a gentle constant action.
fn hold(world: &World) -> Vec<(AgentId, [f64; 2])> {
    world
        .active_externals()
        .map(|id| (id, [0.1, 0.0]))
        .collect()
}

/// One step with the AV holding a gentle constant action.
#[inline]
pub fn step_once(world: &mut World) {
    world.step(&hold(world)).expect("benchmark step");
}

/// [`step_once`] in `scratch`. The timed steps run in one scratch kept across the clones the
/// measurements restart from, as a running world (or a server thread) keeps its buffers: a
/// clone starts with an empty scratch, and its first step's allocations are not a step's cost.
#[inline]
pub fn step_once_in(world: &mut World, scratch: &mut StepScratch) {
    let actions = hold(world);
    world.step_in(scratch, &actions).expect("benchmark step");
}

/// Mean wall time of one step in nanoseconds, measured over at least `min_seconds` (restarting
/// from a clone of the warmed-up world every `steps_per_clone` steps; clones are not timed).
pub fn time_steps(
    n: usize,
    seed: u64,
    min_seconds: f64,
    steps_per_clone: u32,
) -> (f64, usize, u64) {
    time_traffic_steps(
        n,
        seed,
        1,
        VehicleModel::Replay,
        min_seconds,
        steps_per_clone,
    )
}

/// [`time_steps`] on [`bench_traffic_world`].
pub fn time_traffic_steps(
    n: usize,
    seed: u64,
    vehicles: usize,
    model: VehicleModel,
    min_seconds: f64,
    steps_per_clone: u32,
) -> (f64, usize, u64) {
    let base = bench_traffic_world(n, seed, bench_threads(), vehicles, model);
    let edges = base.edge_count();
    let mut total = 0.0;
    let mut steps = 0u64;
    let mut scratch = StepScratch::new();
    while total < min_seconds || steps == 0 {
        let mut w = base.clone();
        if w.is_over() {
            // The AV's episode ended during warm-up: time the pedestrians' world without it.
            let mut config = EpisodeConfig::replay_vehicles(PedestrianModel::CrSfm);
            config.vehicle_model = model;
            w = World::new(base.scenario().clone(), *base.params(), config)
                .expect("benchmark world");
            w.set_threads(base.threads());
        }
        let t0 = Instant::now();
        for _ in 0..steps_per_clone {
            if w.is_over() {
                break;
            }
            step_once_in(&mut w, &mut scratch);
            steps += 1;
        }
        total += t0.elapsed().as_secs_f64();
    }
    (total / steps as f64 * 1e9, edges, steps)
}
