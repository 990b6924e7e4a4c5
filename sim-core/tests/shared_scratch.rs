//! A world stepped in a scratch that other worlds of other sizes step in too
//! (`World::step_in`, as a server's batch thread does) gives the same bits as stepping in its
//! own (`World::step`).

mod common;

use common::{fingerprint, line, mixed_models, scenario, Rng};
use sim_core::scenario::{AgentKind, AgentRecord};
use sim_core::{PedestrianModel, StepScratch, World, WorldParams};

/// An external car among `n` pedestrians on a `side` x `side` square, a third of them
/// entering after the start and some arriving early, of every simulated model.
fn world(seed: u64, n: usize, side: f64) -> World {
    const MODELS: [PedestrianModel; 4] = [
        PedestrianModel::CrSfm,
        PedestrianModel::Sfm,
        PedestrianModel::RaSfm,
        PedestrianModel::Cv,
    ];
    let mut rng = Rng::new(seed);
    let mut agents: Vec<AgentRecord> = vec![line(
        AgentKind::Vehicle,
        0,
        [-2.0, side / 2.0],
        [1.5, 0.0],
        30,
    )];
    let mut overrides = Vec::new();
    for k in 0..n {
        let p0 = [rng.uniform(0.0, side), rng.uniform(0.0, side)];
        let heading = rng.uniform(-3.1, 3.1);
        let speed = rng.uniform(0.3, 1.8);
        let v = [speed * heading.cos(), speed * heading.sin()];
        let start = if k % 3 == 1 { 1 + (k % 4) as u32 } else { 0 };
        agents.push(line(AgentKind::Pedestrian, start, p0, v, 4 + k % 17));
        overrides.push((k as u32 + 1, MODELS[k % 4]));
    }
    let config = mixed_models(overrides);
    World::new(scenario(0, agents), WorldParams::default(), config).unwrap()
}

#[test]
fn a_shared_scratch_changes_no_bit() {
    // Sizes in an order that makes the shared buffers grow, shrink back and regrow.
    let scenes = [
        (1, 3, 4.0),
        (2, 60, 16.0),
        (3, 10, 7.0),
        (4, 0, 5.0),
        (5, 25, 10.0),
    ];
    let mut own: Vec<World> = scenes
        .iter()
        .map(|&(s, n, side)| world(s, n, side))
        .collect();
    let mut shared: Vec<World> = own.clone();
    let mut scratch = StepScratch::new();
    let mut changes = 0;
    for t in 0..25 {
        for (a, b) in own.iter_mut().zip(shared.iter_mut()) {
            assert!(
                fingerprint(a, None) == fingerprint(b, None),
                "diverged at step {t}"
            );
            if a.is_over() {
                continue;
            }
            let actions: Vec<_> = a.active_externals().map(|id| (id, [0.4, -0.2])).collect();
            let before = a.len();
            let oa = a.step(&actions).unwrap();
            let ob = b.step_in(&mut scratch, &actions).unwrap();
            let same = fingerprint(a, Some(&oa)) == fingerprint(b, Some(&ob));
            assert!(same, "outcomes at step {t}");
            changes += usize::from(a.len() != before);
        }
    }
    assert!(changes > 5, "agents entered and left ({changes} changes)");
}
