//! What a composed scene costs beside the episode it is played in (docs/BENCHMARKS.md,
//! "Composed scenes"): taking a pool apart, composing a scene, and building and playing its
//! world (the ego holding a gentle constant action, CR-SFM pedestrians, the pool's cars by IDM
//! when the pool says so), on one thread.
//!
//! ```text
//! cargo run --release -p scenarios --example compose_cost -- embedded:hbs-paper
//! cargo run --release -p scenarios --example compose_cost -- out/table2g/pool-general.json
//! ```

use std::sync::Arc;
use std::time::Instant;

use scenarios::composed::{ComposeConfig, Parts};
use sim_core::params::{PedestrianModel, WorldParams};
use sim_core::world::{EpisodeConfig, World};

/// Scenes composed for the timing of composition.
const COMPOSED: u64 = 20_000;
/// Episodes played for the timing of an episode.
const EPISODES: u64 = 300;

fn main() {
    let arg = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "embedded:hbs-paper".into());
    let pool = scenarios::embedded::pool_from_arg(arg.as_ref()).expect("a pool");
    let clock = Instant::now();
    let parts = Parts::new(&pool, &[]).expect("parts");
    let take_apart = clock.elapsed().as_secs_f64();
    let config = ComposeConfig::default();
    let clock = Instant::now();
    let mut agents = 0usize;
    for i in 0..COMPOSED {
        agents += parts.compose(&config, i).agents.len();
    }
    let compose = clock.elapsed().as_secs_f64() / COMPOSED as f64;
    let params = WorldParams::default();
    let (mut build, mut play, mut steps) = (0.0, 0.0, 0u64);
    for i in 0..EPISODES {
        let scene = Arc::new(parts.compose(&config, i));
        let mut episode = EpisodeConfig::ego_external(&scene, PedestrianModel::CrSfm);
        episode.vehicle_model = pool.vehicle_model;
        let clock = Instant::now();
        let mut world = World::new(scene, params, episode).expect("a world");
        build += clock.elapsed().as_secs_f64();
        let clock = Instant::now();
        while !world.is_over() {
            let actions: Vec<_> = world
                .active_externals()
                .map(|id| (id, [0.3, 0.0]))
                .collect();
            world.step(&actions).expect("a step");
            steps += 1;
        }
        play += clock.elapsed().as_secs_f64();
    }
    let per = |s: f64| s / EPISODES as f64 * 1e6;
    println!(
        "{}: take apart {:.1} ms once; compose {:.1} µs a scene ({:.1} agents); world::new \
         {:.1} µs; an episode {:.0} µs ({:.1} steps); composing is {:.1} % of an episode",
        pool.name,
        take_apart * 1e3,
        compose * 1e6,
        agents as f64 / COMPOSED as f64,
        per(build),
        per(play),
        steps as f64 / EPISODES as f64,
        100.0 * compose * 1e6 / (per(build) + per(play)),
    );
}
