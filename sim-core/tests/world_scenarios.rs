//! A World built from a hand-made Scenario produces the graph, events, episode ends, step errors and observations that model.md sections 5–7 prescribe.

mod common;

use std::sync::Arc;

use common::{line, paper_world, scenario, track, with_external};
use sim_core::geometry::Vec2;
use sim_core::metrics::EpisodeStatus;
use sim_core::scenario::{AgentKind, AgentRecord, Scenario};
use sim_core::world::observation::{buffer_lengths, ObservationError, NODE_FEATURES};
use sim_core::world::{AgentView, Control, Event, GraphEdge};
use sim_core::{
    EpisodeConfig, PedestrianModel, StepError, StepOutcome, World, WorldError, WorldParams,
};

const EPS: f64 = 1e-12;

fn close(got: f64, want: f64) {
    assert!(
        (got - want).abs() <= EPS * want.abs().max(1.0),
        "got {got}, want {want}"
    );
}

/// `u` of every update-1 belief whose observation equals its mean (default parameters):
/// KL = 0.5 [2 * 1.09/0.25 - 2 + 2 ln(0.25/1.09)] (prior 1 + 0.3^2 = 1.09, s_o^2 = 0.25).
fn k1() -> f64 {
    0.5 * (2.0 * 1.09 / 0.25 - 2.0 + 2.0 * (0.25f64 / 1.09).ln())
}

fn world(sc: &Arc<Scenario>, config: EpisodeConfig) -> World {
    World::new(sc.clone(), WorldParams::default(), config).unwrap()
}

fn ids(w: &World) -> Vec<u32> {
    w.agents().map(|a| a.id).collect()
}

fn edge(w: &World, observer: u32, target: u32) -> Option<GraphEdge> {
    w.graph_edges()
        .find(|e| e.observer == observer && e.target == target)
}

/// Everything observable about a world's state.
fn snapshot(w: &World) -> (Vec<AgentView>, Vec<GraphEdge>, u32, bool, Vec<u32>) {
    (
        w.agents().collect(),
        w.graph_edges().collect(),
        w.step_index(),
        w.is_over(),
        w.active_externals().collect(),
    )
}

/// The graph references only present agents and matches the dense adjacency.
fn assert_graph_consistent(w: &World) {
    let present = ids(w);
    let dense = w.dense_adjacency();
    assert_eq!(dense.len(), present.len());
    let mut count = 0;
    for e in w.graph_edges() {
        count += 1;
        let i = present
            .iter()
            .position(|&x| x == e.observer)
            .expect("observer present");
        let j = present
            .iter()
            .position(|&x| x == e.target)
            .expect("target present");
        assert_ne!(i, j);
        assert_eq!(dense[i][j], e.a);
    }
    assert_eq!(count, w.edge_count());
    for (i, row) in dense.iter().enumerate() {
        assert_eq!(row.len(), present.len());
        assert_eq!(row[i], 0.0, "no self loops");
    }
}

// ---------------------------------------------------------------- adjacency (model.md 4, 6)

/// Car 0 (replayed) at (0,0) driving (2,0); pedestrian 1 at (6,0) walking (-1,0) then (-2,0);
/// pedestrian 2 standing at (6,3). Everybody replays.
fn three_agents() -> World {
    let sc = scenario(
        0,
        vec![
            line(AgentKind::Vehicle, 0, [0.0, 0.0], [2.0, 0.0], 11),
            track(
                AgentKind::Pedestrian,
                0,
                vec![[6.0, 0.0], [5.0, 0.0], [4.0, 0.0]],
                vec![[-1.0, 0.0], [-2.0, 0.0], [-2.0, 0.0]],
            ),
            track(
                AgentKind::Pedestrian,
                0,
                vec![[6.0, 3.0]; 11],
                vec![[0.0, 0.0]; 11],
            ),
        ],
    );
    world(&sc, EpisodeConfig::replay_vehicles(PedestrianModel::Replay))
}

fn psi(dv: f64) -> f64 {
    // psi = 1 / (1 + gamma2 d_v), gamma2 = 1
    1.0 / (1.0 + dv)
}

fn assert_adjacency(w: &World, want: [[f64; 3]; 3], want_u: [[f64; 3]; 3]) {
    assert_eq!(ids(w), vec![0, 1, 2]);
    let dense = w.dense_adjacency();
    for i in 0..3 {
        for j in 0..3 {
            close(dense[i][j], want[i][j]);
            if i != j {
                let e = edge(w, i as u32, j as u32).expect("all within 15 m");
                close(e.a, want[i][j]);
                close(e.u, want_u[i][j]);
                // A = psi (1 + lambda u), lambda = 1
                close(e.a, e.psi * (1.0 + e.u));
            }
        }
    }
    assert_eq!(w.edge_count(), 6);
}

#[test]
fn adjacency_at_first_sight_is_psi() {
    let w = three_agents();
    // clearances: c01 = 6 - 2 - 0.3 = 3.7; c02 = |(6-2, 3-0.9)| - 0.3 = sqrt(20.41) - 0.3;
    // c12 = 3 - 0.6 = 2.4
    let c01 = 3.7;
    let c02 = 20.41f64.sqrt() - 0.3;
    let c12 = 2.4;
    close(edge(&w, 0, 1).unwrap().clearance, c01);
    close(edge(&w, 2, 0).unwrap().clearance, c02);
    close(edge(&w, 1, 2).unwrap().clearance, c12);
    // psi(0,1): v1 = (-1,0) towards 0 (k = -1), radial 1: d_v = 3.7 (1 + tanh(-0.5))
    // psi(1,0): v0 = (2,0) towards 1 (k = -1), radial 2: d_v = 3.7 (1 + tanh(-1))
    // psi(0,2): v2 = 0: d_v = c02
    // psi(2,0): v0 . (6,3) = 12 > 0 (k = -1), radial 12/sqrt(45): d_v = c02 (1 + tanh(-6/sqrt45))
    // psi(1,2): v2 = 0: d_v = 2.4
    // psi(2,1): v1 . (0,3) = 0 (k = +1), radial 0: d_v = 2.4
    let want = [
        [0.0, psi(c01 * (1.0 + (-0.5f64).tanh())), psi(c02)],
        [psi(c01 * (1.0 + (-1.0f64).tanh())), 0.0, psi(c12)],
        [
            psi(c02 * (1.0 + (-6.0 / 45f64.sqrt()).tanh())),
            psi(c12),
            0.0,
        ],
    ];
    // u = 0 at first sight, so A = psi
    assert_adjacency(&w, want, [[0.0; 3]; 3]);
    for e in w.graph_edges() {
        assert_eq!(e.u, 0.0);
        assert_eq!(e.a, e.psi);
    }
}

#[test]
fn adjacency_after_one_step_uses_beliefs_and_accelerations() {
    let mut w = three_agents();
    let out = w.step(&[]).unwrap();
    assert_eq!(out.step, 1);
    // state: car (1,0) v (2,0) a 0; ped 1 (5,0) v (-2,0) a ((-2) - (-1))/0.5 = (-2,0), |a| = 2;
    // ped 2 (6,3) still.
    let p1 = w.agent(1).unwrap();
    assert_eq!(p1.acceleration, Vec2::new(-2.0, 0.0));
    // c01 = 4 - 2 - 0.3 = 1.7; c02 = |(5-2, 3-0.9)| - 0.3 = sqrt(13.41) - 0.3;
    // c12 = |(1,3)| - 0.6 = sqrt(10) - 0.6
    let c01 = 1.7;
    let c02 = 13.41f64.sqrt() - 0.3;
    let c12 = 10f64.sqrt() - 0.6;
    // psi(0,1): v1 = (-2,0) towards 0, radial 2, |a| 2: d_v = 1.7 (1 + tanh(-0.5 (2 + 2)))
    // psi(1,0): v0 = (2,0) towards 1, radial 2, a 0: d_v = 1.7 (1 + tanh(-1))
    // psi(0,2), psi(1,2): v2 = 0, a 0: d_v = clearance
    // psi(2,0): v0 . (5,3) = 10 > 0, radial 10/sqrt34: d_v = c02 (1 + tanh(-5/sqrt34))
    // psi(2,1): v1 . (1,3) = -2 <= 0 (k = +1), radial 2/sqrt10, |a| 2:
    //           d_v = c12 (1 + tanh(0.5 (2/sqrt10 + 2)))
    let psi_ = [
        [0.0, psi(c01 * (1.0 + (-2.0f64).tanh())), psi(c02)],
        [psi(c01 * (1.0 + (-1.0f64).tanh())), 0.0, psi(c12)],
        [
            psi(c02 * (1.0 + (-5.0 / 34f64.sqrt()).tanh())),
            psi(c12 * (1.0 + (0.5 * (2.0 / 10f64.sqrt() + 2.0)).tanh())),
            0.0,
        ],
    ];
    // u: beliefs about 0 and 2 observe their unchanged velocity: u = K1;
    // about 1: |(-2,0) - (-1,0)|^2 / (2 * 0.25) = 2 on top: u = K1 + 2
    let k = k1();
    let u = [[0.0, k + 2.0, k], [k, 0.0, k], [k, k + 2.0, 0.0]];
    let mut want = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            // A = psi (1 + 1.0 u)
            want[i][j] = psi_[i][j] * (1.0 + u[i][j]);
        }
    }
    assert_adjacency(&w, want, u);
    for (i, j) in [(0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1)] {
        close(edge(&w, i, j).unwrap().psi, psi_[i as usize][j as usize]);
    }
}

// ---------------------------------------------------------------- entering and leaving

#[test]
fn agents_enter_at_their_first_frame_and_leave_at_goal_or_record_end() {
    let sc = scenario(
        0,
        vec![
            // 0: replayed car, 8 samples (steps 0..=7): leaves when step 8 is reached
            line(AgentKind::Vehicle, 0, [-20.0, -10.0], [2.0, 0.0], 8),
            // 1: simulated pedestrian walking to its goal (20, 4)
            line(AgentKind::Pedestrian, 0, [20.0, 0.0], [0.0, 1.0], 9),
            // 2: simulated pedestrian entering at step 3
            line(AgentKind::Pedestrian, 3, [-20.0, 10.0], [1.0, 0.0], 12),
            // 3: non-reactive pedestrian near 1, replayed for 20 steps
            AgentRecord {
                non_reactive: true,
                ..line(AgentKind::Pedestrian, 0, [25.0, 2.0], [0.0, 0.0], 20)
            },
            // 4: non-reactive pedestrian whose record ends at step 4
            AgentRecord {
                non_reactive: true,
                ..line(AgentKind::Pedestrian, 0, [22.0, 1.0], [0.0, 0.5], 5)
            },
        ],
    );
    let mut w = world(&sc, EpisodeConfig::replay_vehicles(PedestrianModel::CrSfm));
    assert_eq!(w.control(3), Some(Control::Replay));
    assert_eq!(w.control(1), Some(Control::Model(PedestrianModel::CrSfm)));
    assert_eq!(ids(&w), vec![0, 1, 3, 4]);
    assert!(w.agent(2).is_none());
    assert_graph_consistent(&w);
    assert!(edge(&w, 1, 3).is_some());

    let mut gone: Vec<u32> = Vec::new();
    let mut goal_step = None;
    for _ in 0..20 {
        let before = ids(&w);
        let out = w.step(&[]).unwrap();
        let t = out.step;
        assert_graph_consistent(&w);
        let entered: Vec<u32> = out
            .events
            .iter()
            .filter_map(|e| match e {
                Event::Entered { agent } => Some(*agent),
                _ => None,
            })
            .collect();
        let left: Vec<u32> = out
            .events
            .iter()
            .filter_map(|e| match e {
                Event::Left { agent } => Some(*agent),
                _ => None,
            })
            .collect();
        // counts follow the events
        assert_eq!(
            w.len(),
            before.len() + entered.len() - left.len(),
            "step {t}"
        );
        let departed: Vec<u32> = w.departed().iter().map(|d| d.0).collect();
        assert_eq!(departed, left, "departed() lists the agents that left");
        for id in &left {
            assert!(before.contains(id));
            assert!(w.agent(*id).is_none());
            gone.push(*id);
        }
        for id in &gone {
            assert!(w.agent(*id).is_none(), "{id} came back at step {t}");
        }
        if t == 3 {
            assert_eq!(entered, vec![2]);
            let a = w.agent(2).unwrap();
            assert_eq!(a.position, Vec2::new(-20.0, 10.0));
            assert_eq!(a.velocity, Vec2::new(1.0, 0.0));
            assert_eq!(a.acceleration, Vec2::zeros());
        } else {
            assert!(entered.is_empty(), "step {t}: {entered:?}");
        }
        match t {
            // replayed pedestrian 4: 5 samples (steps 0..=4)
            5 => assert!(left.contains(&4)),
            // replayed car: 8 samples
            8 => assert!(left.contains(&0)),
            _ => assert!(!left.contains(&0) && !left.contains(&4), "step {t}"),
        }
        if t <= 4 {
            // replay follows the record exactly
            assert_eq!(
                w.agent(4).unwrap().position,
                Vec2::new(22.0, 1.0 + 0.25 * t as f64)
            );
        }
        if out.events.contains(&Event::GoalReached { agent: 1 }) {
            assert!(left.contains(&1), "leaves on the step it arrives");
            // where it arrived: within 0.5 m of its goal (20, 4)
            let at = w.departed().iter().find(|d| d.0 == 1).unwrap().1;
            assert!((at - Vec2::new(20.0, 4.0)).norm() <= 0.5);
            goal_step = Some(t);
        }
        if t < 3 {
            assert_eq!(w.len(), 4);
        }
    }
    // 1 walks 0.5 m per step towards (20, 4): within 0.5 m from about step 7
    let g = goal_step.expect("pedestrian 1 reached its goal");
    assert!((6..=9).contains(&g), "arrived at step {g}");
    assert!(gone.contains(&0) && gone.contains(&1) && gone.contains(&4));
}

#[test]
fn belief_restarts_at_first_sight_when_an_agent_reenters_perception() {
    // 1 jumps out of 0's 15 m range at step 1 and is back at step 2; velocity constant (1, 0)
    let sc = scenario(
        0,
        vec![
            line(AgentKind::Pedestrian, 0, [0.0, 0.0], [0.0, 0.0], 6),
            track(
                AgentKind::Pedestrian,
                0,
                vec![[5.0, 0.0], [20.0, 0.0], [5.0, 0.0], [5.0, 0.0], [5.0, 0.0]],
                vec![[1.0, 0.0]; 5],
            ),
        ],
    );
    let mut w = world(&sc, EpisodeConfig::replay_vehicles(PedestrianModel::Replay));
    assert_eq!(edge(&w, 0, 1).unwrap().u, 0.0); // first sight
    w.step(&[]).unwrap();
    assert!(edge(&w, 0, 1).is_none() && edge(&w, 1, 0).is_none()); // 20 m apart
    assert_eq!(w.edge_count(), 0);
    w.step(&[]).unwrap();
    assert_eq!(edge(&w, 0, 1).unwrap().u, 0.0); // re-entry: first sight again
    assert_eq!(edge(&w, 1, 0).unwrap().u, 0.0);
    w.step(&[]).unwrap();
    // one update with an observation equal to the mean: u = K1
    close(edge(&w, 0, 1).unwrap().u, k1());
    close(edge(&w, 1, 0).unwrap().u, k1());
}

#[test]
fn perception_radius_bounds_the_graph() {
    // centres 15 m apart are perceived (<= R_perc), 15.001 m apart are not
    let sc = scenario(
        0,
        vec![
            line(AgentKind::Pedestrian, 0, [0.0, 0.0], [0.0, 0.0], 3),
            line(AgentKind::Pedestrian, 0, [15.0, 0.0], [0.0, 0.0], 3),
            line(AgentKind::Pedestrian, 0, [-15.001, 0.0], [0.0, 0.0], 3),
        ],
    );
    let w = world(&sc, EpisodeConfig::replay_vehicles(PedestrianModel::Replay));
    assert!(edge(&w, 0, 1).is_some() && edge(&w, 1, 0).is_some());
    assert!(edge(&w, 0, 2).is_none() && edge(&w, 2, 0).is_none());
    assert_eq!(w.edge_count(), 2);
}

#[test]
fn two_vehicles_one_external_one_replayed() {
    let sc = scenario(
        0,
        vec![
            line(AgentKind::Vehicle, 0, [0.0, 0.0], [2.0, 0.0], 11),
            line(AgentKind::Vehicle, 0, [0.0, 5.0], [1.0, 0.0], 6),
            line(AgentKind::Pedestrian, 0, [10.0, 10.0], [0.0, -1.0], 11),
        ],
    );
    let mut w = world(
        &sc,
        EpisodeConfig::ego_external(&sc, PedestrianModel::CrSfm),
    );
    assert_eq!(w.control(0), Some(Control::External));
    assert_eq!(w.control(1), Some(Control::Replay));
    assert_eq!(w.control(2), Some(Control::Model(PedestrianModel::CrSfm)));
    // side by side, both heading 0: rect-rect clearance 5 - 0.9 - 0.9 = 3.2
    close(edge(&w, 0, 1).unwrap().clearance, 3.2);
    close(edge(&w, 1, 0).unwrap().clearance, 3.2);
    for t in 1..=5u32 {
        let out = w.step(&[(0, [0.0, 0.0])]).unwrap();
        assert_eq!(out.agents.len(), 1);
        assert!(!out.agents[0].terminated);
        // the replayed car is exactly on its record
        let rec = sc.agents[1].position_at(t).unwrap();
        assert_eq!(w.agent(1).unwrap().position, Vec2::new(rec[0], rec[1]));
        // the ego drives at 2 m/s: (t, 0)
        close(w.agent(0).unwrap().position.x, t as f64);
        // still side by side (the 4 m long cars overlap in x): 3.2
        close(edge(&w, 0, 1).unwrap().clearance, 3.2);
    }
    let out = w.step(&[(0, [0.0, 0.0])]).unwrap();
    assert!(out.events.contains(&Event::Left { agent: 1 }));
    assert!(w.agent(1).is_none());
    assert!(!w.is_over());
}

// ---------------------------------------------------------------- episode ends (model.md 7)

#[test]
fn episode_terminates_on_goal_with_success() {
    // goal (10, 0); full throttle: speeds 3, 4, 5, 6 -> x = 1.5, 3.5, 6.0, 9.0 -> d = 1 <= 2 at 4
    let mut w = paper_world(
        vec![line(AgentKind::Vehicle, 0, [0.0, 0.0], [2.0, 0.0], 11)],
        PedestrianModel::CrSfm,
    );
    for t in 1..=4u32 {
        let out = w.step(&[(0, [1.0, 0.0])]).unwrap();
        let a = &out.agents[0];
        if t < 4 {
            assert!(!a.terminated && !out.episode_over && a.metrics.is_none());
        } else {
            close(w.agent(0).unwrap().position.x, 9.0);
            assert!(a.terminated && !a.truncated);
            assert!(out.episode_over && w.is_over());
            assert_eq!(a.reward.success, 10.0);
            assert!(out.events.contains(&Event::GoalReached { agent: 0 }));
            let m = a.metrics.unwrap();
            assert_eq!(m.status, EpisodeStatus::Success);
            assert_eq!(m.steps, 4);
            // speeds 2, 3, 4, 5, 6: avg (3+4+5+6)/4 = 4.5; acc 2 each step: jerk 0, max 2
            close(m.avg_speed, 4.5);
            close(m.avg_abs_jerk, 0.0);
            close(m.max_abs_acc, 2.0);
        }
    }
    assert_eq!(w.active_externals().count(), 0);
    assert_eq!(w.step(&[(0, [0.0, 0.0])]), Err(StepError::EpisodeOver));
}

#[test]
fn episode_terminates_on_av_pedestrian_collision() {
    // standing pedestrian (cv, zero velocity, goal elsewhere) at (5.2, 0); car front at 2 + 1 t:
    // t = 3: 5.2 - 5.0 - 0.3 = -0.1 -> overlap
    let mut w = paper_world(
        vec![
            line(AgentKind::Vehicle, 0, [0.0, 0.0], [2.0, 0.0], 11),
            track(
                AgentKind::Pedestrian,
                0,
                vec![[5.2, 0.0], [5.2, 9.0]],
                vec![[0.0, 0.0]; 2],
            ),
        ],
        PedestrianModel::Cv,
    );
    for t in 1..=3u32 {
        let out = w.step(&[(0, [0.0, 0.0])]).unwrap();
        let a = &out.agents[0];
        if t < 3 {
            assert!(!a.terminated && !out.episode_over);
            assert!(!out
                .events
                .iter()
                .any(|e| matches!(e, Event::Collision { .. })));
        } else {
            assert!(a.terminated && out.episode_over);
            assert_eq!(a.reward.collision, -20.0);
            assert_eq!(a.metrics.unwrap().status, EpisodeStatus::Collision);
            assert!(out.events.contains(&Event::Collision { a: 0, b: 1 }));
        }
    }
    assert_eq!(w.step(&[(0, [0.0, 0.0])]), Err(StepError::EpisodeOver));
}

#[test]
fn the_horizon_covers_the_recording_of_every_controlled_vehicle() {
    // The ego's recording ends at step 10; a second car enters at step 6 and its recording ends
    // at step 6 + 20 = 26. With both controlled the horizon is (26 * 0.5 + 15) / 0.5 = 56 steps,
    // so the later car gets its own recorded time plus the margin; with the ego alone it is
    // (10 * 0.5 + 15) / 0.5 = 40, as before.
    let sc = scenario(
        0,
        vec![
            line(AgentKind::Vehicle, 0, [0.0, 0.0], [2.0, 0.0], 11),
            line(AgentKind::Vehicle, 6, [0.0, 20.0], [1.0, 0.0], 21),
            line(AgentKind::Pedestrian, 0, [10.0, 10.0], [0.0, -1.0], 11),
        ],
    );
    assert_eq!(world(&sc, with_external(vec![0, 1])).horizon(), 56);
    assert_eq!(world(&sc, with_external(vec![1])).horizon(), 56);
    assert_eq!(world(&sc, with_external(vec![0])).horizon(), 40);
    // A controlled pedestrian does not stretch the ego's horizon.
    assert_eq!(world(&sc, with_external(vec![0, 2])).horizon(), 40);
}

#[test]
fn episode_truncates_at_recorded_duration_plus_fifteen_seconds() {
    // 11 samples: recorded duration 10 * 0.5 = 5 s; horizon (5 + 15)/0.5 = 40 steps. The car
    // stands still (recorded velocity 0) 10 m from its goal.
    let mut w = paper_world(
        vec![track(
            AgentKind::Vehicle,
            0,
            (0..11).map(|k| [k as f64, 0.0]).collect(),
            vec![[0.0, 0.0]; 11],
        )],
        PedestrianModel::CrSfm,
    );
    assert_eq!(w.horizon(), 40);
    for t in 1..=40u32 {
        let out = w.step(&[(0, [0.0, 0.0])]).unwrap();
        let a = &out.agents[0];
        assert!(!a.terminated);
        if t < 40 {
            assert!(!a.truncated && !out.episode_over);
        } else {
            assert!(a.truncated && out.episode_over);
            let m = a.metrics.unwrap();
            assert_eq!(m.status, EpisodeStatus::Timeout);
            assert_eq!(m.steps, 40);
            assert_eq!(m.avg_speed, 0.0);
        }
    }
    close(w.time(), 20.0);
    assert_eq!(w.step(&[(0, [0.0, 0.0])]), Err(StepError::EpisodeOver));
}

#[test]
fn external_agent_entering_later_keeps_the_episode_running() {
    // the ego car's record starts at step 2: the episode must wait for it
    let mut w = paper_world(
        vec![
            line(AgentKind::Vehicle, 2, [0.0, 0.0], [2.0, 0.0], 11),
            line(AgentKind::Pedestrian, 0, [5.0, 10.0], [0.0, 1.0], 20),
        ],
        PedestrianModel::Sfm,
    );
    assert_eq!(w.active_externals().count(), 0);
    let out = w.step(&[]).unwrap();
    assert!(!out.episode_over && out.agents.is_empty());
    let out = w.step(&[]).unwrap();
    assert!(out.events.contains(&Event::Entered { agent: 0 }));
    assert!(!out.episode_over);
    assert_eq!(w.active_externals().collect::<Vec<_>>(), vec![0]);
    assert_eq!(w.step(&[]), Err(StepError::MissingAction { agent: 0 }));
    let out = w.step(&[(0, [0.0, 0.0])]).unwrap();
    assert_eq!(out.agents.len(), 1);
    close(out.agents[0].reward.progress, 1.0); // 2 m/s for 0.5 s
}

// ---------------------------------------------------------------- step errors

fn error_world() -> World {
    paper_world(
        vec![
            line(AgentKind::Vehicle, 0, [0.0, 0.0], [2.0, 0.0], 11),
            line(AgentKind::Pedestrian, 0, [5.0, 3.0], [0.0, -1.0], 11),
        ],
        PedestrianModel::CrSfm,
    )
}

/// `bad` is refused with an error matching `check`, and the world is as before: same
/// observable state, and the same future as an untouched copy.
fn assert_refused(bad: &[(u32, [f64; 2])], check: impl Fn(&StepError) -> bool) {
    let mut w = error_world();
    w.step(&[(0, [0.3, 0.1])]).unwrap(); // beliefs have history
    let copy = w.clone();
    let before = snapshot(&w);
    let err = w.step(bad).unwrap_err();
    assert!(check(&err), "unexpected {err:?}");
    assert_eq!(snapshot(&w), before);
    let mut copy = copy;
    let a = w.step(&[(0, [0.5, -0.2])]).unwrap();
    let b = copy.step(&[(0, [0.5, -0.2])]).unwrap();
    assert_eq!(a, b);
    assert_eq!(snapshot(&w), snapshot(&copy));
}

#[test]
fn non_finite_action_is_refused_and_changes_nothing() {
    assert_refused(
        &[(0, [f64::NAN, 0.0])],
        |e| matches!(e, StepError::NonFiniteAction { agent: 0, index: 0, value } if value.is_nan()),
    );
    assert_refused(&[(0, [0.0, f64::INFINITY])], |e| {
        *e == StepError::NonFiniteAction {
            agent: 0,
            index: 1,
            value: f64::INFINITY,
        }
    });
    assert_refused(&[(0, [f64::NEG_INFINITY, 0.0])], |e| {
        matches!(e, StepError::NonFiniteAction { index: 0, .. })
    });
}

#[test]
fn missing_duplicate_and_unknown_actions_are_refused() {
    assert_refused(&[], |e| *e == StepError::MissingAction { agent: 0 });
    assert_refused(&[(0, [0.0, 0.0]), (0, [0.1, 0.0])], |e| {
        *e == StepError::DuplicateAction { agent: 0 }
    });
    // an agent that does not exist
    assert_refused(&[(0, [0.0, 0.0]), (7, [0.0, 0.0])], |e| {
        *e == StepError::NotExternal { agent: 7 }
    });
    // a present pedestrian that is not external
    assert_refused(&[(0, [0.0, 0.0]), (1, [0.0, 0.0])], |e| {
        *e == StepError::NotExternal { agent: 1 }
    });
}

#[test]
fn out_of_range_finite_actions_are_clipped_and_reported() {
    let mut w = error_world();
    let out = w.step(&[(0, [0.5, -0.5])]).unwrap();
    assert!(!out.agents[0].action_clipped);
    let out = w.step(&[(0, [1.0, -1.0])]).unwrap();
    assert!(!out.agents[0].action_clipped);
    // [1e300, -3] acts as [1, -1]: same next state as the in-range action
    let mut a = w.clone();
    let mut b = w.clone();
    let oa = a.step(&[(0, [1e300, -3.0])]).unwrap();
    let ob = b.step(&[(0, [1.0, -1.0])]).unwrap();
    assert!(oa.agents[0].action_clipped);
    assert!(!ob.agents[0].action_clipped);
    assert_eq!(snapshot(&a), snapshot(&b));
    // omega in the comfort term is the clipped one: -0.5 * 0.2^2 on both
    assert_eq!(oa.agents[0].reward, ob.agents[0].reward);
}

#[test]
fn external_pedestrian_actions_are_clipped_and_reported() {
    let sc = scenario(
        0,
        vec![
            line(AgentKind::Vehicle, 0, [0.0, 0.0], [2.0, 0.0], 11),
            line(AgentKind::Pedestrian, 0, [5.0, 3.0], [1.0, 0.0], 11),
        ],
    );
    let config = with_external(vec![1]);
    let mut w = world(&sc, config);
    assert_eq!(w.control(0), Some(Control::Replay));
    let out = w.step(&[(1, [-5.0, 0.0])]).unwrap();
    assert!(out.agents[0].action_clipped);
    // forward -1 -> -2 m/s^2 along its heading (1, 0): v = 1 - 2 * 0.5 = 0, x stays at 5
    let p = w.agent(1).unwrap();
    close(p.velocity.norm(), 0.0);
    close(p.position.x, 5.0);
}

#[test]
fn world_new_rejects_bad_configs() {
    let sc = scenario(
        0,
        vec![line(AgentKind::Vehicle, 0, [0.0, 0.0], [2.0, 0.0], 3)],
    );
    let params = WorldParams::default();
    let ext = with_external;
    assert!(matches!(
        World::new(sc.clone(), params, ext(vec![3])),
        Err(WorldError::UnknownAgent { agent: 3, .. })
    ));
    assert_eq!(
        World::new(sc.clone(), params, ext(vec![0, 0])).unwrap_err(),
        WorldError::DuplicateExternal { agent: 0 }
    );
    let mut wrong_dt = (*sc).clone();
    wrong_dt.dt = 0.1;
    assert!(matches!(
        World::new(Arc::new(wrong_dt), params, ext(vec![0])),
        Err(WorldError::DtMismatch { .. })
    ));
    let mut bad = (*sc).clone();
    bad.agents[0].velocities.pop();
    assert!(matches!(
        World::new(Arc::new(bad), params, ext(vec![0])),
        Err(WorldError::Scenario { .. })
    ));
    let mut nan = (*sc).clone();
    nan.agents[0].positions[1][0] = f64::NAN;
    assert!(matches!(
        World::new(Arc::new(nan), params, ext(vec![0])),
        Err(WorldError::Scenario { .. })
    ));
    let mut p = params;
    p.dt = -1.0;
    assert!(matches!(
        World::new(sc, p, ext(vec![0])),
        Err(WorldError::Param(_))
    ));
}

#[test]
fn outcome_lists_active_externals_in_config_order() {
    let sc = scenario(
        0,
        vec![
            line(AgentKind::Vehicle, 0, [0.0, 0.0], [2.0, 0.0], 11),
            line(AgentKind::Vehicle, 0, [0.0, 20.0], [2.0, 0.0], 11),
        ],
    );
    let config = with_external(vec![1, 0]);
    let mut w = world(&sc, config);
    let out: StepOutcome = w.step(&[(0, [0.0, 0.0]), (1, [0.0, 0.0])]).unwrap();
    let order: Vec<u32> = out.agents.iter().map(|a| a.agent).collect();
    assert_eq!(order, vec![1, 0]);
}

// ---------------------------------------------------------------- observation (model.md 7)

/// Ego car at (0,0) heading 0 with goal (10,0); pedestrian 1 at (3,3) walking (0,-1);
/// pedestrian 2 at (-4,0) walking (1,0); pedestrian 3 at (40,0), out of range.
fn observation_world() -> World {
    paper_world(
        vec![
            line(AgentKind::Vehicle, 0, [0.0, 0.0], [2.0, 0.0], 11),
            line(AgentKind::Pedestrian, 0, [3.0, 3.0], [0.0, -1.0], 11),
            line(AgentKind::Pedestrian, 0, [-4.0, 0.0], [1.0, 0.0], 11),
            line(AgentKind::Pedestrian, 0, [40.0, 0.0], [0.0, 1.0], 11),
        ],
        PedestrianModel::CrSfm,
    )
}

fn buffers(max_agents: usize) -> (Vec<f32>, Vec<f32>, Vec<u8>) {
    let [f, a, m] = buffer_lengths(max_agents);
    // filled with junk to check that everything is overwritten
    (vec![7.0; f], vec![7.0; a], vec![7; m])
}

fn row(f: &[f32], node: usize) -> &[f32] {
    &f[node * NODE_FEATURES..(node + 1) * NODE_FEATURES]
}

fn close32(got: f32, want: f64) {
    assert!(
        (got as f64 - want).abs() <= 1e-5 * want.abs().max(1.0),
        "got {got}, want {want}"
    );
}

#[test]
fn observation_ego_first_then_nearest_with_padding_mask() {
    let w = observation_world();
    let (mut f, mut a, mut m) = buffers(5);
    assert_eq!(w.fill_observation(0, 5, (&mut f, &mut a, &mut m)), Ok(true));
    assert_eq!(m, vec![1, 1, 1, 0, 0]);
    // ego: rel 0, rel v 0, speed 2, heading diff 0, radius 0.5 sqrt(4^2 + 1.8^2), vehicle,
    // goal offset (10, 0), distance 10
    let ego = row(&f, 0);
    let rect_r = 0.5 * 19.24f64.sqrt();
    for (k, want) in [0.0, 0.0, 0.0, 0.0, 2.0, 0.0, rect_r, 1.0, 10.0, 0.0, 10.0]
        .into_iter()
        .enumerate()
    {
        close32(ego[k], want);
    }
    // clearances: ped 2 at (-4,0): 4 - 2 - 0.3 = 1.7; ped 1 at (3,3): |(1, 2.1)| - 0.3 ~ 2.03
    // -> node 1 is ped 2, node 2 is ped 1
    let p2 = row(&f, 1);
    // rel (-4, 0), rel v (1 - 2, 0) = (-1, 0), speed 1, heading diff 0, r 0.3, pedestrian, no goal
    for (k, want) in [-4.0, 0.0, -1.0, 0.0, 1.0, 0.0, 0.3, 0.0, 0.0, 0.0, 0.0]
        .into_iter()
        .enumerate()
    {
        close32(p2[k], want);
    }
    let p1 = row(&f, 2);
    // rel (3, 3), rel v (0 - 2, -1 - 0) = (-2, -1), speed 1, heading diff -pi/2
    for (k, want) in [
        3.0,
        3.0,
        -2.0,
        -1.0,
        1.0,
        -std::f64::consts::FRAC_PI_2,
        0.3,
        0.0,
        0.0,
        0.0,
        0.0,
    ]
    .into_iter()
    .enumerate()
    {
        close32(p1[k], want);
    }
    // padding rows are zero
    assert!(f[3 * NODE_FEATURES..].iter().all(|&x| x == 0.0));
    // adjacency among nodes [0, 2, 1] equals the graph's A, padding zero
    let nodes = [0u32, 2, 1];
    for na in 0..5 {
        for nb in 0..5 {
            let got = a[na * 5 + nb];
            let want = if na < 3 && nb < 3 && na != nb {
                edge(&w, nodes[na], nodes[nb]).unwrap().a as f32
            } else {
                0.0
            };
            assert_eq!(got, want, "A[{na}][{nb}]");
        }
    }
}

#[test]
fn observation_is_in_the_ego_frame() {
    // car heading pi/2 (driving (0, 2)) with goal (0, 10); pedestrian 5 m ahead at (0, 5)
    let w = paper_world(
        vec![
            line(AgentKind::Vehicle, 0, [0.0, 0.0], [0.0, 2.0], 11),
            line(AgentKind::Pedestrian, 0, [0.0, 5.0], [1.0, 0.0], 11),
        ],
        PedestrianModel::CrSfm,
    );
    let (mut f, mut a, mut m) = buffers(3);
    assert_eq!(w.fill_observation(0, 3, (&mut f, &mut a, &mut m)), Ok(true));
    assert_eq!(m, vec![1, 1, 0]);
    // goal (0, 10) is straight ahead: (10, 0), distance 10
    close32(f[8], 10.0);
    close32(f[9], 0.0);
    close32(f[10], 10.0);
    let p = row(&f, 1);
    // ahead: rel (5, 0); rel v = R(-pi/2) ((1,0) - (0,2)) = R(-pi/2) (1, -2) = (-2, -1)
    close32(p[0], 5.0);
    close32(p[1], 0.0);
    close32(p[2], -2.0);
    close32(p[3], -1.0);
    // heading diff 0 - pi/2 = -pi/2
    close32(p[5], -std::f64::consts::FRAC_PI_2);
}

#[test]
fn observation_keeps_only_the_nearest_when_full() {
    let w = observation_world();
    let (mut f, mut a, mut m) = buffers(2);
    assert_eq!(w.fill_observation(0, 2, (&mut f, &mut a, &mut m)), Ok(true));
    assert_eq!(m, vec![1, 1]);
    close32(row(&f, 1)[0], -4.0); // pedestrian 2, the nearer
    assert_eq!(a[1], edge(&w, 0, 2).unwrap().a as f32);
    assert_eq!(a[2], edge(&w, 2, 0).unwrap().a as f32);
    assert_eq!((a[0], a[3]), (0.0, 0.0));
}

#[test]
fn observation_errors_and_absent_ego() {
    let w = observation_world();
    let (mut f, mut a, mut m) = buffers(4);
    let mut short = vec![0.0f32; 3];
    assert_eq!(
        w.fill_observation(0, 4, (&mut short, &mut a, &mut m)),
        Err(ObservationError::BufferSize {
            got: [3, 16, 4],
            want: [44, 16, 4]
        })
    );
    assert_eq!(
        w.fill_observation(0, 0, (&mut [], &mut [], &mut [])),
        Err(ObservationError::NoRoom)
    );
    // an agent that is not present: Ok(false) and zeroed buffers
    assert_eq!(
        w.fill_observation(99, 4, (&mut f, &mut a, &mut m)),
        Ok(false)
    );
    assert!(f.iter().all(|&x| x == 0.0));
    assert!(a.iter().all(|&x| x == 0.0));
    assert!(m.iter().all(|&x| x == 0));
    // a pedestrian can be observed from too (ego of its own observation)
    let (mut f, mut a, mut m) = buffers(4);
    assert_eq!(w.fill_observation(3, 4, (&mut f, &mut a, &mut m)), Ok(true));
    assert_eq!(m, vec![1, 0, 0, 0]); // nobody within 15 m of (40, 0)
}

// ---------------------------------------------------------------- an external pedestrian

/// The documented integration of an external pedestrian's action (model.md 2b): the action,
/// clipped to [-1, 1]², is an acceleration along and to the left of its heading at `t`, times
/// `ped_acc_max`; `v' = clip_norm(v + a dt, ped_speed_max)`, `x' = x + v' dt`, and its heading
/// turns to `v'` (kept while it stands).
#[test]
fn an_external_pedestrian_follows_the_documented_integration() {
    let sc = scenario(
        0,
        vec![
            line(AgentKind::Vehicle, 0, [-30.0, -30.0], [1.0, 0.0], 41),
            line(AgentKind::Pedestrian, 0, [0.0, 0.0], [1.0, 0.5], 41),
            line(AgentKind::Pedestrian, 0, [4.0, 3.0], [-0.5, 0.0], 41),
        ],
    );
    let params = WorldParams::default();
    let mut w = world(&sc, with_external(vec![1]));
    assert_eq!(w.control(1), Some(Control::External));
    let (dt, a_max, v_max) = (params.dt, params.ped_acc_max, params.ped_speed_max);
    let start = w.agent(1).unwrap();
    let (mut x, mut v, mut heading) = (start.position, start.velocity, start.heading);
    let actions = [
        [1.0, 0.0],
        [0.5, -0.5],
        [-1.0, 1.0],
        [3.0, -2.0], // clipped to [1, -1]
        [0.0, 0.0],
        [-1.0, 0.0],
        [-1.0, 0.0],
        [0.2, 0.9],
    ];
    for (t, act) in actions.iter().enumerate() {
        let out = w.step(&[(1, *act)]).unwrap();
        let (f, l) = (act[0].clamp(-1.0, 1.0), act[1].clamp(-1.0, 1.0));
        assert_eq!(out.agents[0].action_clipped, f != act[0] || l != act[1]);
        let (s, c) = heading.sin_cos();
        let acc = Vec2::new(c * f - s * l, s * f + c * l) * a_max;
        v += acc * dt;
        if v.norm() > v_max {
            v = v * (v_max / v.norm());
        }
        x += v * dt;
        if v.norm() > 0.0 {
            heading = v.y.atan2(v.x);
        }
        let got = w.agent(1).unwrap();
        for (g, want) in [
            (got.position.x, x.x),
            (got.position.y, x.y),
            (got.velocity.x, v.x),
            (got.velocity.y, v.y),
        ] {
            assert!((g - want).abs() < 1e-9, "step {t}: {g} != {want}");
        }
        assert!((got.heading - heading).abs() < 1e-9, "step {t}: heading");
    }
}

/// Runs an external car (id 0, action `[0, 0]`: constant speed and heading) and an external
/// pedestrian (id 1, `walk` each step) until the episode ends; the collision events and the
/// at-fault events seen.
fn car_meets_pedestrian(
    car_v: [f64; 2],
    ped: [f64; 2],
    ped_v: [f64; 2],
    walk: [f64; 2],
) -> (usize, usize) {
    let sc = scenario(
        0,
        vec![
            line(AgentKind::Vehicle, 0, [0.0, 0.0], car_v, 41),
            line(AgentKind::Pedestrian, 0, ped, ped_v, 41),
        ],
    );
    let mut w = world(&sc, with_external(vec![0, 1]));
    let (mut collisions, mut faults) = (0, 0);
    while !w.is_over() {
        let active: Vec<u32> = w.active_externals().collect();
        let acts: Vec<(u32, [f64; 2])> = active
            .iter()
            .map(|&id| (id, if id == 0 { [0.0, 0.0] } else { walk }))
            .collect();
        let out = w.step(&acts).unwrap();
        for e in &out.events {
            match e {
                Event::Collision { .. } => collisions += 1,
                Event::AtFault {
                    vehicle,
                    pedestrian,
                } => {
                    assert_eq!((*vehicle, *pedestrian), (0, 1));
                    faults += 1;
                }
                _ => {}
            }
        }
    }
    (collisions, faults)
}

/// model.md 2c: a car that drives on into a pedestrian standing in its path, seen from further
/// than its braking distance, is at fault.
#[test]
fn a_car_driving_into_a_pedestrian_standing_in_its_path_is_at_fault() {
    assert_eq!(
        car_meets_pedestrian([4.0, 0.0], [20.0, 0.0], [0.0, 0.05], [0.0, 0.0]),
        (1, 1)
    );
}

/// model.md 2c: touching a car's side is never its fault.
#[test]
fn a_pedestrian_walking_into_a_cars_side_is_not_its_fault() {
    assert_eq!(
        car_meets_pedestrian([2.0, 0.0], [1.0, -3.0], [0.0, 1.5], [1.0, 0.0]),
        (1, 0)
    );
}

/// model.md 2c: a pedestrian who steps into the path nearer than the car's braking distance
/// (6.25 m at 5 m/s) is not the car's fault.
#[test]
fn a_pedestrian_stepping_in_nearer_than_the_braking_distance_is_not_the_cars_fault() {
    assert_eq!(
        car_meets_pedestrian([5.0, 0.0], [6.0, -1.8], [0.0, 2.0], [0.0, 0.0]),
        (1, 0)
    );
}
