//! A rollout of a scene large enough to be split over threads writes the same bytes on one
//! thread and on two, with and without a scene variation.

use std::sync::Arc;

use scenarios::synthetic::{generate, Layout, SyntheticConfig};
use sim_core::params::{PedestrianModel, VehicleModel, WorldParams};
use sim_core::variation::VariationSpec;
use sim_core::world::PARALLEL_MIN_AGENTS;
use sim_server::rollout::{rollout, EgoDrive, RolloutModels};

#[test]
fn rollout_lines_do_not_depend_on_the_thread_count() {
    let mut cfg = SyntheticConfig::new(Layout::Random, 560, 3);
    // Short walks and no time beyond the records: a few steps of a dense scene.
    cfg.max_walk = 3.0;
    cfg.vehicle_speed = 3.0;
    let scenario = Arc::new(generate(&cfg).expect("synthetic scene"));
    assert!(
        scenario.agents.len() >= PARALLEL_MIN_AGENTS,
        "the scene must be split"
    );
    let params = WorldParams {
        horizon_extra: 0.0,
        ..WorldParams::default()
    };
    let spec = VariationSpec {
        param_noise: [("a_ped".to_string(), 0.2)].into(),
        mirror: true,
        rotation_deg: 90.0,
        ..VariationSpec::benchmark()
    };
    let variation = spec.draw(&scenario, &params, 11);
    let run = |threads, varied: bool| {
        let mut out = Vec::new();
        let steps = rollout(
            scenario.clone(),
            params,
            RolloutModels {
                pedestrians: PedestrianModel::CrSfm,
                vehicles: VehicleModel::Idm,
            },
            EgoDrive::Constant([0.2, 0.05]),
            varied.then_some(&variation),
            threads,
            &mut out,
        )
        .expect("rollout");
        (steps, out)
    };
    let (steps_v1, varied_1) = run(1, true);
    let (steps_v2, varied_2) = run(2, true);
    assert_eq!(steps_v1, steps_v2);
    assert!(
        varied_1 == varied_2,
        "the varied two-thread rollout wrote other bytes"
    );
    let (steps_1, one) = run(1, false);
    let (steps_2, two) = run(2, false);
    assert!(one != varied_1, "the variation changed nothing");
    assert!(steps_1 >= 3, "a few steps at least, got {steps_1}");
    let text = String::from_utf8(one.clone()).unwrap();
    assert!(
        text.lines().nth(2).unwrap().len() > 100_000,
        "a dense graph in every step"
    );
    assert_eq!(steps_1, steps_2);
    assert!(one == two, "the two-thread rollout wrote other bytes");
}
