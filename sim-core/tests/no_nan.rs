//! No finite scenario and no finite action, however extreme, lets NaN or infinity into the state, and the speed limits always hold.

mod common;

use common::{scenario, track};
use proptest::prelude::*;
use sim_core::geometry::{clearance, clearance_and_normal, Placed, Shape, Vec2};
use sim_core::scenario::{AgentKind, AgentRecord};
use sim_core::world::Control;
use sim_core::{EpisodeConfig, PedestrianModel, World, WorldParams};

const STEPS: usize = 8;

fn model() -> impl Strategy<Value = PedestrianModel> {
    prop_oneof![
        Just(PedestrianModel::CrSfm),
        Just(PedestrianModel::Sfm),
        Just(PedestrianModel::RaSfm),
        Just(PedestrianModel::Cv),
        Just(PedestrianModel::Replay),
    ]
}

/// One action component: ordinary, huge, tiny, signed zeros.
fn component() -> impl Strategy<Value = f64> {
    prop_oneof![
        4 => -2.0..2.0f64,
        1 => -1e300..1e300f64,
        1 => Just(1e300),
        1 => Just(-1e300),
        1 => Just(f64::MAX),
        1 => Just(1e-300),
        1 => Just(-f64::MIN_POSITIVE),
        1 => Just(-0.0),
    ]
}

fn point() -> impl Strategy<Value = [f64; 2]> {
    [0.0..30.0f64, 0.0..30.0f64]
}

fn velocity() -> impl Strategy<Value = [f64; 2]> {
    [-3.0..3.0f64, -3.0..3.0f64]
}

/// A record of 1..=5 samples with random positions and velocities, starting at step 0..=2.
fn record(kind: AgentKind, min_len: usize) -> impl Strategy<Value = AgentRecord> {
    (
        0..3u32,
        prop::collection::vec((point(), velocity()), min_len..=5),
    )
        .prop_map(move |(start, samples)| {
            let (p, v) = samples.into_iter().unzip();
            track(kind, start, p, v)
        })
}

#[derive(Debug, Clone)]
struct Case {
    vehicle: AgentRecord,
    pedestrians: Vec<AgentRecord>,
    model: PedestrianModel,
    disc_vehicle: bool,
    /// Pedestrian 1 is driven by actions too.
    external_pedestrian: bool,
    actions: Vec<[f64; 2]>,
}

fn case() -> impl Strategy<Value = Case> {
    (
        record(AgentKind::Vehicle, 2),
        prop::collection::vec(record(AgentKind::Pedestrian, 1), 1..6),
        model(),
        any::<bool>(),
        any::<bool>(),
        prop::collection::vec([component(), component()], STEPS),
    )
        .prop_map(
            |(mut vehicle, pedestrians, model, disc_vehicle, external_pedestrian, actions)| {
                vehicle.start_step = 0;
                Case {
                    vehicle,
                    pedestrians,
                    model,
                    disc_vehicle,
                    external_pedestrian,
                    actions,
                }
            },
        )
}

fn finite(xs: &[f64]) -> bool {
    xs.iter().all(|x| x.is_finite())
}

fn run_case(c: &Case) -> Result<(), TestCaseError> {
    let mut agents = vec![c.vehicle.clone()];
    agents.extend(c.pedestrians.iter().cloned());
    if c.external_pedestrian {
        agents[1].start_step = 0;
    }
    let sc = scenario(0, agents);
    let mut params = WorldParams::default();
    if c.disc_vehicle {
        params.vehicle.shape = Shape::Disc { radius: 1.2 };
    }
    let mut config = EpisodeConfig::ego_external(&sc, c.model);
    if c.external_pedestrian {
        config.external.push(1);
    }
    let mut w = World::new(sc, params, config).unwrap();
    for a in c.actions.iter() {
        if w.is_over() {
            break;
        }
        let before: Vec<u32> = w.agents().map(|a| a.id).collect();
        let actions: Vec<(u32, [f64; 2])> = w.active_externals().map(|id| (id, *a)).collect();
        let out = w.step(&actions).unwrap();
        for o in &out.agents {
            let r = o.reward;
            prop_assert!(
                finite(&[r.progress, r.success, r.collision, r.danger, r.comfort]),
                "reward {r:?}"
            );
            if let Some(m) = o.metrics {
                prop_assert!(finite(&[m.avg_speed, m.avg_abs_jerk, m.max_abs_acc]));
            }
        }
        for ag in w.agents() {
            prop_assert!(
                finite(&[
                    ag.position.x,
                    ag.position.y,
                    ag.velocity.x,
                    ag.velocity.y,
                    ag.acceleration.x,
                    ag.acceleration.y,
                    ag.heading,
                    ag.goal.x,
                    ag.goal.y,
                ]),
                "agent {ag:?}"
            );
            let speed = ag.velocity.norm();
            let moved = before.contains(&ag.id); // present at t, so simulated to t + 1
            match ag.control {
                Control::Model(_) | Control::External
                    if moved && ag.kind == AgentKind::Pedestrian =>
                {
                    prop_assert!(speed <= 2.0 + 1e-12, "pedestrian {} speed {speed}", ag.id);
                }
                Control::External if moved => {
                    prop_assert!(speed <= 6.0 + 1e-12, "AV speed {speed}");
                }
                _ => {}
            }
        }
        for e in w.graph_edges() {
            prop_assert!(finite(&[e.clearance, e.psi, e.u, e.a]), "edge {e:?}");
            prop_assert!(e.clearance >= 0.0);
            prop_assert!(e.psi > 0.0 && e.psi <= 1.0, "psi {}", e.psi);
            prop_assert!(e.u >= -1e-12, "u {}", e.u);
        }
        for row in w.dense_adjacency() {
            prop_assert!(finite(&row));
        }
        let n = 4;
        let [fl, al, ml] = sim_core::world::observation::buffer_lengths(n);
        let (mut f, mut adj, mut m) = (vec![0f32; fl], vec![0f32; al], vec![0u8; ml]);
        if w.fill_observation(0, n, (&mut f, &mut adj, &mut m))
            .unwrap()
        {
            prop_assert!(f.iter().chain(&adj).all(|x| x.is_finite()));
        }
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    #[test]
    fn random_scenes_and_actions_keep_the_state_finite_and_speeds_bounded(c in case()) {
        run_case(&c)?;
    }
}

// ---------------------------------------------------------------- geometry

fn shape() -> impl Strategy<Value = Shape> {
    prop_oneof![
        (0.01..5.0f64).prop_map(|radius| Shape::Disc { radius }),
        (0.01..10.0f64, 0.01..10.0f64).prop_map(|(length, width)| Shape::Rect { length, width }),
    ]
}

fn placed() -> impl Strategy<Value = Placed> {
    (shape(), -50.0..50.0f64, -50.0..50.0f64, -10.0..10.0f64).prop_map(|(shape, x, y, heading)| {
        Placed {
            shape,
            position: Vec2::new(x, y),
            heading,
        }
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

    #[test]
    fn clearance_is_finite_non_negative_and_symmetric(a in placed(), b in placed()) {
        let ab = clearance(&a, &b);
        let ba = clearance(&b, &a);
        prop_assert!(ab.is_finite() && ab >= 0.0, "{ab}");
        prop_assert_eq!(ab.to_bits(), ba.to_bits(), "{} vs {}", ab, ba);
        let (_, n) = clearance_and_normal(&a, &b);
        prop_assert!(n.x.is_finite() && n.y.is_finite());
        // the normal is a unit vector unless the centres coincide
        prop_assert!((n.norm() - 1.0).abs() < 1e-9 || n.norm() == 0.0);
        // never more than the gap between the bounding discs' centres
        let centre = (a.position - b.position).norm();
        prop_assert!(ab <= centre + 1e-9);
    }

    #[test]
    fn clearance_of_coincident_shapes_is_zero(a in placed()) {
        prop_assert_eq!(clearance(&a, &a), 0.0);
    }
}
