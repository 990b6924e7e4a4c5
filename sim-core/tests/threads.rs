//! A step split over several threads, or run with any variant of the observe pass the CPU has
//! (portable, AVX2, AVX-512), gives bit-identical results to the single-threaded step.

mod common;

use common::{fingerprint, line, mixed_models, scenario, Rng};
use sim_core::params::PredictionModel;
use sim_core::scenario::{AgentKind, AgentRecord};
use sim_core::world::{Kernels, PARALLEL_MIN_AGENTS};
use sim_core::{PedestrianModel, World, WorldParams};

const MODELS: [PedestrianModel; 4] = [
    PedestrianModel::CrSfm,
    PedestrianModel::Sfm,
    PedestrianModel::RaSfm,
    PedestrianModel::Cv,
];

/// An external ego car and a replayed car among 700 pedestrians of all models on 60 m x 60 m,
/// some entering later and some arriving early.
fn world(threads: usize) -> World {
    world_with(threads, WorldParams::default())
}

fn world_with(threads: usize, params: WorldParams) -> World {
    let mut rng = Rng::new(7);
    let mut agents: Vec<AgentRecord> = vec![
        line(AgentKind::Vehicle, 0, [-5.0, 20.0], [2.0, 0.0], 60),
        line(AgentKind::Vehicle, 0, [-5.0, 40.0], [1.5, 0.0], 40),
    ];
    let mut overrides = Vec::new();
    for k in 0..700 {
        let p0 = [rng.uniform(0.0, 60.0), rng.uniform(0.0, 60.0)];
        let heading = rng.uniform(-3.1, 3.1);
        let speed = rng.uniform(0.3, 1.8);
        let v = [speed * heading.cos(), speed * heading.sin()];
        let start = if k % 11 == 0 { (k % 5) as u32 } else { 0 };
        agents.push(line(AgentKind::Pedestrian, start, p0, v, 6 + k % 30));
        overrides.push(((agents.len() - 1) as u32, MODELS[k % 4]));
    }
    let config = mixed_models(overrides);
    let mut w = World::new(scenario(0, agents), params, config).unwrap();
    w.set_threads(threads);
    w
}

/// Steps `worlds` side by side (same actions) for 12 steps or until one episode ends, asserting
/// after every step that all give the first one's fingerprint.
fn assert_same_bits(worlds: &mut [World]) {
    for t in 0..12 {
        let prints: Vec<_> = worlds.iter().map(|w| fingerprint(w, None)).collect();
        assert!(prints[0].len() > 10_000, "a dense graph");
        for p in &prints[1..] {
            assert!(p == &prints[0], "diverged at step {t}");
        }
        for w in worlds.iter_mut() {
            if w.is_over() {
                return;
            }
            let actions: Vec<_> = w.active_externals().map(|id| (id, [0.3, 0.1])).collect();
            w.step(&actions).unwrap();
        }
    }
}

#[test]
fn thread_count_does_not_change_any_bit() {
    let mut worlds: Vec<World> = [1, 2, 3].into_iter().map(world).collect();
    assert!(
        worlds[0].len() >= PARALLEL_MIN_AGENTS,
        "the scene must be split"
    );
    assert_eq!(worlds[1].threads(), 2);
    assert_same_bits(&mut worlds);
}

/// Every kernel variant this CPU runs, on one and on two threads, under `params`.
fn every_variant(params: &WorldParams) -> Vec<World> {
    let mut worlds = Vec::new();
    for kernels in Kernels::available() {
        for threads in [1, 2] {
            let mut w = world_with(threads, *params);
            w.use_kernels(kernels).unwrap();
            assert_eq!(w.kernels(), kernels);
            worlds.push(w);
        }
    }
    worlds
}

#[test]
fn vector_instruction_set_does_not_change_any_bit() {
    let mut worlds = every_variant(&WorldParams::default());
    assert_eq!(worlds[0].kernels(), Kernels::Portable);
    assert_same_bits(&mut worlds);
}

#[test]
fn vector_instruction_set_does_not_change_any_bit_with_constant_acceleration() {
    let mut params = WorldParams::default();
    params.cognition.prediction = PredictionModel::ConstantAcceleration;
    assert_same_bits(&mut every_variant(&params));
}

/// A small process noise makes the variance schedule hundreds of updates long (the AVX-512
/// pass then gathers the update constants instead of holding them in registers).
#[test]
fn vector_instruction_set_does_not_change_any_bit_with_a_long_variance_schedule() {
    let mut params = WorldParams::default();
    params.cognition.q = 0.01;
    assert!(sim_core::model::cognition::VarianceSchedule::new(&params.cognition).len() > 100);
    assert_same_bits(&mut every_variant(&params));
}

#[test]
fn a_variant_the_cpu_lacks_is_refused() {
    let mut w = world(1);
    let before = w.kernels();
    for k in [Kernels::Portable, Kernels::Avx2, Kernels::Avx512] {
        if !k.is_available() {
            let err = w.use_kernels(k).unwrap_err();
            assert!(err.to_string().contains(&format!("{k:?}")), "{err}");
            assert_eq!(w.kernels(), before);
        }
    }
    assert!(w.use_kernels(Kernels::Portable).is_ok());
    assert_eq!(Kernels::detect(), *Kernels::available().last().unwrap());
}
