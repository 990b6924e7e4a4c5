//! Pedestrian-model evaluation (model.md 9) replays the vehicles, simulates the pedestrians from their recorded start and scores them against their record over the whole recorded window.

mod common;

use std::sync::Arc;

use common::{line, scenario, track};
use sim_core::pedeval::{evaluate, evaluate_scenario};
use sim_core::scenario::{AgentKind, Scenario};
use sim_core::{PedestrianModel, WorldParams};

fn close(got: f64, want: f64) {
    assert!((got - want).abs() <= 1e-12, "got {got}, want {want}");
}

/// A car far away (100 m) and pedestrian 1 walking at (1, 0) m/s from (0, 20) for 5 samples.
fn straight_walker() -> Arc<Scenario> {
    scenario(
        0,
        vec![
            line(AgentKind::Vehicle, 0, [100.0, 0.0], [2.0, 0.0], 5),
            line(AgentKind::Pedestrian, 0, [0.0, 20.0], [1.0, 0.0], 5),
        ],
    )
}

#[test]
fn cv_on_a_straight_walker_scores_by_hand() {
    // pedestrian 1: 5 samples at (1, 0) m/s from (0, 20): x = 0, 0.5, 1.0, 1.5, 2.0; goal (2, 20).
    // cv reproduces it until step 3, where it is 0.5 m from its goal and leaves; at step 4 its
    // last position 1.5 stands for it: errors at steps 1..=4 are 0, 0, 0, 0.5
    // ADE = 0.5 / 4 = 0.125, FDE = 0.5
    let sc = straight_walker();
    let e = evaluate_scenario(sc.clone(), &WorldParams::default(), PedestrianModel::Cv).unwrap();
    close(e.errors.ade, 0.125);
    close(e.errors.fde, 0.5);
    assert!(!e.collided);
    // simulated track: the start and steps 1..=3 (absent afterwards)
    assert_eq!(e.simulated.len(), 1);
    assert_eq!(e.simulated[0].0, 1);
    let xs: Vec<f64> = e.simulated[0].1.iter().map(|p| p.x).collect();
    assert_eq!(xs, vec![0.0, 0.5, 1.0, 1.5]);
    // the run summary of one episode is that episode
    let s = evaluate([&sc], &WorldParams::default(), PedestrianModel::Cv).unwrap();
    assert_eq!(s.episodes, 1);
    close(s.ade, 0.125);
    close(s.fde, 0.5);
    assert_eq!(s.collision_rate, 0.0);
}

#[test]
fn replay_model_simulates_nobody() {
    let sc = straight_walker();
    let e = evaluate_scenario(sc, &WorldParams::default(), PedestrianModel::Replay).unwrap();
    assert!(e.simulated.is_empty());
    assert_eq!((e.errors.ade, e.errors.fde), (0.0, 0.0));
}

#[test]
fn colliding_simulated_pedestrians_count_as_a_collision() {
    // two cv pedestrians walking head-on at 1 m/s from 3 m apart close 1 m per step:
    // clearance 3 - t - 0.6 <= 0 first at t = 3 (both at x = 1.5, 1 m from their goals)
    let sc = scenario(
        0,
        vec![
            line(AgentKind::Vehicle, 0, [100.0, 0.0], [2.0, 0.0], 6),
            line(AgentKind::Pedestrian, 0, [0.0, 0.0], [1.0, 0.0], 6),
            line(AgentKind::Pedestrian, 0, [3.0, 0.0], [-1.0, 0.0], 6),
        ],
    );
    let e = evaluate_scenario(sc.clone(), &WorldParams::default(), PedestrianModel::Cv).unwrap();
    assert!(e.collided);
    let s = evaluate([&sc, &sc], &WorldParams::default(), PedestrianModel::Cv).unwrap();
    assert_eq!(s.collision_rate, 1.0);
}

#[test]
fn the_whole_recorded_window_is_evaluated_even_past_the_ego_horizon() {
    // the ego car's record is 3 samples (horizon (1 + 15)/0.5 = 32 steps) but the pedestrian is
    // recorded for 60 steps: evaluation must cover all 59 transitions, not stop or panic at 32
    let n = 60;
    let sc = scenario(
        0,
        vec![
            line(AgentKind::Vehicle, 0, [100.0, 0.0], [2.0, 0.0], 3),
            track(
                AgentKind::Pedestrian,
                0,
                (0..n).map(|k| [0.0, 0.25 * k as f64]).collect(),
                vec![[0.0, 0.5]; n],
            ),
        ],
    );
    let e = evaluate_scenario(sc, &WorldParams::default(), PedestrianModel::Cv).unwrap();
    // cv walks exactly on the record until 0.5 m before the goal (y = 14.75 - 0.5 = 14.25 at
    // step 57), then stands for the last two steps: errors 0.25 and 0.5 at steps 58 and 59
    assert_eq!(e.simulated[0].1.len(), 58);
    assert!((e.errors.fde - 0.5).abs() < 1e-9, "{:?}", e.errors);
    assert!((e.errors.ade - 0.75 / 59.0).abs() < 1e-9, "{:?}", e.errors);
}
