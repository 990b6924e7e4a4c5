//! Scene variations (sim-core `variation.rs`) on the embedded HBS pools: no variation starts
//! in an overlap, and a variation is an exact function of (scene, spec, seed).

use std::sync::Arc;

use scenarios::embedded::{pool, EMBEDDED_POOLS};
use sim_core::params::{PedestrianModel, WorldParams};
use sim_core::scenario::Scenario;
use sim_core::variation::{Variation, VariationSpec, REDRAWS};
use sim_core::world::{EpisodeConfig, World};

/// The first pair of agents in contact when one of them appears, as the world sees it: every
/// agent replays its (varied) record, and at each step the graph's clearances between an agent
/// that has just entered and any other are checked.
fn first_spawn_contact(scene: &Scenario, params: &WorldParams) -> Option<(u32, u32, u32)> {
    let config = EpisodeConfig::replay_vehicles(PedestrianModel::Replay);
    let mut world = World::new(Arc::new(scene.clone()), *params, config).expect("world");
    let end = scene.recorded_steps();
    loop {
        let t = world.step_index();
        let entered = |id: u32| scene.agents[id as usize].start_step == t;
        if let Some(e) = world
            .graph_edges()
            .find(|e| e.clearance <= 0.0 && (entered(e.observer) || entered(e.target)))
        {
            return Some((t, e.observer, e.target));
        }
        if t + 1 >= end || world.is_over() {
            return None;
        }
        world.step(&[]).expect("step");
    }
}

/// The benchmark's variations, and a strong one with every kind switched on.
fn specs() -> [VariationSpec; 2] {
    [
        VariationSpec::benchmark(),
        VariationSpec {
            position_sigma: 0.5,
            start_offset_steps: 2,
            desired_speed_scale: 0.3,
            param_noise: [("a_ped".to_string(), 0.2), ("tau".to_string(), 0.2)].into(),
            mirror: true,
            rotation_deg: 180.0,
        },
    ]
}

#[test]
fn no_variation_of_an_hbs_scene_starts_in_an_overlap() {
    let params = WorldParams::default();
    let mut kept_records = 0usize;
    let mut pedestrians = 0usize;
    for name in EMBEDDED_POOLS {
        let pool = pool(name).expect("embedded pool");
        for scene in &pool.scenarios {
            let recorded = first_spawn_contact(scene, &params);
            for spec in specs() {
                for seed in 0..4 {
                    let v = spec.draw(scene, &params, seed);
                    let varied = v.apply(scene);
                    let params = v.apply_params(&params);
                    // Only the scene's own record may start two agents in contact (five
                    // hbs-general scenes do: a car slower than 0.1 m/s, whose heading the world
                    // and the extraction's footprint check take from different samples).
                    let contact = first_spawn_contact(&varied, &params);
                    assert!(
                        contact.is_none() || contact == recorded,
                        "{name}/{} variation {seed} of {spec:?}: agents in contact where one appears: {contact:?} (recorded scene: {recorded:?})",
                        scene.name
                    );
                    pedestrians += v.pedestrians.len();
                    kept_records += v.pedestrians.iter().filter(|p| p.redraws > REDRAWS).count();
                }
            }
        }
    }
    // The redraw almost always finds a free place: the variations really vary the crowd.
    assert!(
        kept_records * 100 < pedestrians,
        "{kept_records} of {pedestrians} pedestrians kept their record"
    );
}

#[test]
fn a_variation_is_a_function_of_scene_spec_and_seed() {
    let params = WorldParams::default();
    let general = pool("hbs-general").expect("embedded pool");
    for scene in general.scenarios.iter().take(20) {
        for spec in specs() {
            let a = spec.draw(scene, &params, 7);
            let b = spec.draw(scene, &params, 7);
            assert_eq!(a, b);
            assert_eq!(a.apply(scene), b.apply(scene));
            assert_ne!(a, spec.draw(scene, &params, 8), "{}", scene.name);
        }
    }
}

#[test]
fn the_default_spec_plays_the_recorded_scene_to_the_bit() {
    let params = WorldParams::default();
    let paper = pool("hbs-paper").expect("embedded pool");
    for scene in &paper.scenarios {
        let v = VariationSpec::default().draw(scene, &params, 3);
        let varied = v.apply(scene);
        for (a, b) in scene.agents.iter().zip(&varied.agents) {
            assert_eq!(a.positions, b.positions);
            assert_eq!(a.velocities, b.velocities);
            assert_eq!(a.start_step, b.start_step);
            assert_eq!(a.desired_speed().to_bits(), b.desired_speed().to_bits());
        }
        assert_eq!(v.apply_params(&params), params);
    }
}

/// Every ego-frame observation of an episode with the ego holding `action`, `steps` steps long.
fn observations(scene: &Scenario, params: &WorldParams, action: [f64; 2], steps: u32) -> Vec<f32> {
    const M: usize = 8;
    let f = sim_core::world::observation::NODE_FEATURES;
    let config = EpisodeConfig::ego_external(scene, PedestrianModel::CrSfm);
    let mut world = World::new(Arc::new(scene.clone()), *params, config).expect("world");
    let ego = scene.ego as u32;
    let mut out = Vec::new();
    for _ in 0..steps {
        let (mut feats, mut adj, mut mask) = (vec![0.0; M * f], vec![0.0; M * M], vec![0u8; M]);
        world
            .fill_observation(ego, M, (&mut feats, &mut adj, &mut mask))
            .expect("observation");
        out.extend(feats);
        out.extend(adj);
        out.extend(mask.iter().map(|&m| f32::from(m)));
        if world.is_over() || world.active_externals().next().is_none() {
            break;
        }
        world.step(&[(ego, action)]).expect("step");
    }
    out
}

#[test]
fn a_rotated_scene_gives_the_ego_the_same_observations() {
    let params = WorldParams::default();
    let paper = pool("hbs-paper").expect("embedded pool");
    let mut compared = 0usize;
    for scene in &paper.scenarios {
        let base = observations(scene, &params, [0.3, 0.1], 20);
        for degrees in [-150.0, -37.5, 90.0, 180.0] {
            let rotated = Variation {
                seed: 0,
                mirrored: false,
                rotation_deg: degrees,
                param_scales: Default::default(),
                pedestrians: Vec::new(),
            };
            let seen = observations(&rotated.apply(scene), &params, [0.3, 0.1], 20);
            assert_eq!(seen.len(), base.len(), "{}: episode length", scene.name);
            for (k, (a, b)) in base.iter().zip(&seen).enumerate() {
                assert!(
                    (a - b).abs() <= 1e-4 * (1.0 + a.abs()),
                    "{} rotated by {degrees}: value {k} is {b}, unrotated {a}",
                    scene.name
                );
            }
            compared += seen.len();
        }
    }
    assert!(compared > 10_000);
}

#[test]
fn a_mirrored_scene_mirrors_the_ego_frame() {
    // The mirror is about the ego's first heading, so in the ego's frame it flips lateral
    // offsets: at the first step every node's lateral position changes sign.
    let params = WorldParams::default();
    let paper = pool("hbs-paper").expect("embedded pool");
    let scene = &paper.scenarios[0];
    let mirrored = Variation {
        seed: 0,
        mirrored: true,
        rotation_deg: 0.0,
        param_scales: Default::default(),
        pedestrians: Vec::new(),
    };
    let f = sim_core::world::observation::NODE_FEATURES;
    let base = observations(scene, &params, [0.0, 0.0], 1);
    let seen = observations(&mirrored.apply(scene), &params, [0.0, 0.0], 1);
    for node in 0..8 {
        let (x, y) = (base[node * f], base[node * f + 1]);
        assert!((seen[node * f] - x).abs() < 1e-4, "node {node} x");
        assert!((seen[node * f + 1] + y).abs() < 1e-4, "node {node} y");
    }
}
