//! The `sim-server bench-step` scene (1 external AV + `N` CR-SFM pedestrians, random layout,
//! 0.25 /m²) without the server's dependencies, for quick timing, profiling and regression dumps
//! while working on `World::step`.
//!
//! ```text
//! cargo run --release -p scenarios --example step_timing -- time N [SECONDS]
//! cargo run --release -p scenarios --example step_timing -- steps N STEPS   # for callgrind
//! cargo run --release -p scenarios --example step_timing -- dump FILE [portable]  # trajectories
//! cargo run --release -p scenarios --example step_timing -- allocs N STEPS  # heap use per step
//! ```
//!
//! `STEP_TIMING_KERNELS=portable|avx2|avx512` makes `time`, `steps` and `allocs` run that
//! variant of the observe pass instead of the widest one the CPU has (`STEP_TIMING_PORTABLE=1`
//! is `portable`), and `STEP_TIMING_THREADS=T` steps on `T` threads (default 1).
//!
//! `dump` writes the bits of every agent's state and every graph edge after each step of a fixed
//! set of episodes (synthetic scenes of several sizes, layouts, models and seeds, and the
//! embedded HBS pool): two builds that step identically write identical files (one SHA-256 per
//! episode).

use std::alloc::{GlobalAlloc, Layout, System};
use std::io::Write;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Instant;

use scenarios::embedded::default_pool;
use scenarios::synthetic::{generate, Layout as SceneLayout, SyntheticConfig};
use sha2::{Digest, Sha256};
use sim_core::params::{PedestrianModel, WorldParams};
use sim_core::scenario::Scenario;
use sim_core::world::{AgentId, EpisodeConfig, Kernels, StepScratch, World};

/// The system allocator, counting allocations (for `allocs`).
struct Counting;

static ALLOCS: AtomicU64 = AtomicU64::new(0);
static ALLOC_BYTES: AtomicU64 = AtomicU64::new(0);

// SAFETY: forwards every call unchanged to the system allocator; the counters have no effect on
// the memory handed out.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCS.fetch_add(1, Ordering::Relaxed);
        ALLOC_BYTES.fetch_add(layout.size() as u64, Ordering::Relaxed);
        System.alloc(layout)
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        System.dealloc(ptr, layout)
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCS.fetch_add(1, Ordering::Relaxed);
        ALLOC_BYTES.fetch_add(new_size as u64, Ordering::Relaxed);
        System.realloc(ptr, layout, new_size)
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// Steps taken before timing, as `sim-server`'s `step_timing::WARM_UP_STEPS`.
const WARM_UP_STEPS: u32 = 3;

fn scene(layout: SceneLayout, n: usize, seed: u64) -> Arc<Scenario> {
    Arc::new(generate(&SyntheticConfig::new(layout, n, seed)).expect("valid scene"))
}

/// The AV holding a gentle constant action.
fn hold(world: &World) -> Vec<(AgentId, [f64; 2])> {
    world
        .active_externals()
        .map(|id| (id, [0.1, 0.0]))
        .collect()
}

fn step_once(world: &mut World) {
    world.step(&hold(world)).expect("step");
}

/// The world `sim-server bench-step` times (seed 0): warmed up, or, when the AV's episode ended
/// during warm-up, the same scene with the AV replayed, stepping with the kernels that
/// `STEP_TIMING_KERNELS` names (see the module documentation).
fn bench_world(n: usize) -> World {
    let mut world = bench_world_default(n);
    let named = std::env::var("STEP_TIMING_KERNELS").ok();
    let portable = std::env::var("STEP_TIMING_PORTABLE").is_ok_and(|v| v == "1");
    let kernels = match (named.as_deref(), portable) {
        (Some("portable"), _) | (None, true) => Kernels::Portable,
        (Some("avx2"), _) => Kernels::Avx2,
        (Some("avx512"), _) => Kernels::Avx512,
        (None, false) => Kernels::detect(),
        (Some(other), _) => {
            eprintln!("STEP_TIMING_KERNELS: unknown variant {other:?} (portable, avx2, avx512)");
            std::process::exit(2);
        }
    };
    if let Err(e) = world.use_kernels(kernels) {
        eprintln!("STEP_TIMING_KERNELS: {e}");
        std::process::exit(2);
    }
    match std::env::var("STEP_TIMING_THREADS").map(|t| t.parse::<usize>()) {
        Ok(Ok(t)) => world.set_threads(t),
        Ok(Err(e)) => {
            eprintln!("STEP_TIMING_THREADS: {e}");
            std::process::exit(2);
        }
        Err(_) => {}
    }
    world
}

fn bench_world_default(n: usize) -> World {
    let scenario = scene(SceneLayout::Random, n, 0);
    let config = EpisodeConfig::ego_external(&scenario, PedestrianModel::CrSfm);
    let mut world = World::new(scenario, WorldParams::default(), config).expect("world");
    for _ in 0..WARM_UP_STEPS {
        if world.is_over() {
            break;
        }
        step_once(&mut world);
    }
    if world.is_over() {
        let config = EpisodeConfig::replay_vehicles(PedestrianModel::CrSfm);
        world = World::new(world.scenario().clone(), *world.params(), config).expect("world");
    }
    world
}

/// Steps `k` times from clones of the warmed-up world, 10 steps per clone (as `bench-step`), in
/// one scratch kept across the clones as a running world keeps its own (a clone starts with an
/// empty one); returns the wall time spent stepping.
fn run_steps(base: &World, k: u64) -> f64 {
    let (mut total, mut steps) = (0.0, 0u64);
    let mut scratch = StepScratch::new();
    while steps < k {
        let mut w = base.clone();
        let t0 = Instant::now();
        for _ in 0..10 {
            if w.is_over() || steps == k {
                break;
            }
            w.step_in(&mut scratch, &hold(&w)).expect("step");
            steps += 1;
        }
        total += t0.elapsed().as_secs_f64();
    }
    total
}

fn time(n: usize, seconds: f64) {
    let base = bench_world(n);
    let (mut total, mut steps) = (0.0, 0u64);
    while total < seconds {
        total += run_steps(&base, 100);
        steps += 100;
    }
    println!(
        "N={n}: {:.3} us/step over {steps} steps ({} edges)",
        total / steps as f64 * 1e6,
        base.edge_count()
    );
}

fn steps(n: usize, k: u64) {
    let base = bench_world(n);
    run_steps(&base, k);
    println!("N={n}: {k} steps, {} edges", base.edge_count());
}

/// Allocations (and bytes) made by each of `k` steps from a clone of the warmed-up world.
fn allocs(n: usize, k: u32) {
    let base = bench_world(n);
    let mut w = base.clone();
    for s in 0..k {
        if w.is_over() {
            break;
        }
        let (a0, b0) = (
            ALLOCS.load(Ordering::Relaxed),
            ALLOC_BYTES.load(Ordering::Relaxed),
        );
        step_once(&mut w);
        let (a1, b1) = (
            ALLOCS.load(Ordering::Relaxed),
            ALLOC_BYTES.load(Ordering::Relaxed),
        );
        println!("step {s}: {} allocations, {} bytes", a1 - a0, b1 - b0);
    }
}

fn record(out: &mut Vec<u8>, w: &World) {
    for a in w.agents() {
        out.extend_from_slice(&a.id.to_le_bytes());
        for x in [
            a.position.x,
            a.position.y,
            a.velocity.x,
            a.velocity.y,
            a.acceleration.x,
            a.acceleration.y,
            a.heading,
        ] {
            out.extend_from_slice(&x.to_bits().to_le_bytes());
        }
    }
    for e in w.graph_edges() {
        out.extend_from_slice(&e.observer.to_le_bytes());
        out.extend_from_slice(&e.target.to_le_bytes());
        for x in [e.clearance, e.psi, e.u, e.a] {
            out.extend_from_slice(&x.to_bits().to_le_bytes());
        }
    }
}

/// Runs one episode and appends a line with the SHA-256 of its record to `out`.
fn episode(
    portable: bool,
    out: &mut String,
    scenario: Arc<Scenario>,
    params: WorldParams,
    config: EpisodeConfig,
    max_steps: u32,
) {
    let label = format!("{} {:?} {}", scenario.name, config, params.horizon_extra);
    let mut w = World::new(scenario, params, config).expect("world");
    if portable {
        w.use_kernels(Kernels::Portable)
            .expect("the portable kernels always run");
    }
    let mut hash = Sha256::new();
    let mut buf = Vec::new();
    record(&mut buf, &w);
    for _ in 0..max_steps {
        if w.is_over() {
            break;
        }
        let actions: Vec<_> = w.active_externals().map(|id| (id, [0.3, -0.05])).collect();
        let o = w.step(&actions).expect("step");
        buf.extend_from_slice(format!("{o:?}").as_bytes());
        record(&mut buf, &w);
        hash.update(&buf);
        buf.clear();
    }
    let digest: String = hash.finalize().iter().map(|b| format!("{b:02x}")).collect();
    out.push_str(&format!("{digest} steps={} {label}\n", w.step_index()));
}

fn dump(path: &str, portable: bool) {
    let mut out = String::new();
    let models = [
        PedestrianModel::CrSfm,
        PedestrianModel::RaSfm,
        PedestrianModel::Sfm,
        PedestrianModel::Cv,
    ];
    let short = WorldParams::default();
    // A longer horizon, so that the pedestrians keep walking (and arriving) for hundreds of steps.
    let long = WorldParams {
        horizon_extra: 120.0,
        ..WorldParams::default()
    };
    for (n, steps, seeds) in [(3, 400, 3), (10, 400, 3), (100, 300, 3), (1000, 40, 2)] {
        for seed in 0..seeds {
            for layout in SceneLayout::ALL {
                let s = scene(layout, n, seed);
                let cfg = EpisodeConfig::ego_external(&s, PedestrianModel::CrSfm);
                episode(portable, &mut out, s.clone(), short, cfg, steps);
                // Several external agents, so that some leave while the episode goes on.
                let mut cfg = EpisodeConfig::ego_external(&s, PedestrianModel::CrSfm);
                cfg.external
                    .extend((1..s.agents.len() as u32).step_by(3).take(4));
                episode(portable, &mut out, s.clone(), long, cfg, steps);
                let ms: &[PedestrianModel] = if n <= 100 { &models } else { &models[..1] };
                for &m in ms {
                    episode(
                        portable,
                        &mut out,
                        s.clone(),
                        long,
                        EpisodeConfig::replay_vehicles(m),
                        steps,
                    );
                }
            }
        }
    }
    for s in default_pool().scenarios {
        let s = Arc::new(s);
        for m in models {
            let cfg = EpisodeConfig::ego_external(&s, m);
            episode(portable, &mut out, s.clone(), short, cfg, 10_000);
            let cfg = EpisodeConfig::replay_vehicles(m);
            episode(portable, &mut out, s.clone(), short, cfg, 10_000);
        }
    }
    std::fs::File::create(path)
        .and_then(|mut f| f.write_all(out.as_bytes()))
        .expect("write dump");
    println!("{path}: {} episodes", out.lines().count());
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let arg = |k: usize| args.get(k).map(String::as_str);
    match (arg(0), arg(1), arg(2)) {
        (Some("time"), Some(n), s) => time(
            n.parse().expect("N"),
            s.map_or(3.0, |s| s.parse().expect("seconds")),
        ),
        (Some("steps"), Some(n), Some(k)) => steps(n.parse().expect("N"), k.parse().expect("K")),
        (Some("allocs"), Some(n), Some(k)) => allocs(n.parse().expect("N"), k.parse().expect("K")),
        (Some("dump"), Some(path), None) => dump(path, false),
        (Some("dump"), Some(path), Some("portable")) => dump(path, true),
        _ => {
            eprintln!("usage: step_timing time N [SECONDS] | steps N STEPS | allocs N STEPS | dump FILE [portable]");
            std::process::exit(2);
        }
    }
}
