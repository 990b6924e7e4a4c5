//! The reactive vehicle model (sim-core `model/traffic.rs`, docs/MODEL.md "Traffic") on the recorded
//! `hbs-general` scenes and on hand-made ones: cars nobody controls never overlap each other, never
//! drive into a car standing in their way, keep their record on a free road, and step the same
//! on every thread count.

use std::sync::Arc;

use scenarios::embedded::general_pool;
use sim_core::geometry::{clearance, Placed};
use sim_core::params::{PedestrianModel, VehicleModel, WorldParams};
use sim_core::scenario::{AgentKind, AgentRecord, Scenario, Split};
use sim_core::world::{AgentView, Control, EpisodeConfig, Event, World};

/// The world of `scene` with its ego car external and every other car reactive.
fn reactive_world(scene: &Scenario, params: WorldParams) -> World {
    let mut config = EpisodeConfig::ego_external(scene, PedestrianModel::CrSfm);
    config.vehicle_model = VehicleModel::Idm;
    World::new(Arc::new(scene.clone()), params, config).expect("world")
}

fn placed(a: &AgentView) -> Placed {
    Placed {
        shape: a.shape,
        position: a.position,
        heading: a.heading,
    }
}

/// Runs `world` to its horizon with the ego braking to a stop from its recorded speed, calling
/// `check` on every step's world and events.
fn stop_the_ego(mut world: World, mut check: impl FnMut(&World, &[Event])) {
    check(&world, &[]);
    while !world.is_over() {
        let actions: Vec<_> = world
            .active_externals()
            .map(|id| (id, [-1.0, 0.0]))
            .collect();
        let out = world.step(&actions).expect("step");
        check(&world, &out.events);
    }
}

/// The pairs of reactive cars that overlap in `world`.
fn overlapping_reactive_cars(world: &World) -> Vec<(u32, u32, f64)> {
    let cars: Vec<AgentView> = world
        .agents()
        .filter(|a| matches!(a.control, Control::Vehicle(_)))
        .collect();
    let mut out = Vec::new();
    for (k, a) in cars.iter().enumerate() {
        for b in &cars[k + 1..] {
            let c = clearance(&placed(a), &placed(b));
            if c <= 0.0 {
                out.push((a.id, b.id, c));
            }
        }
    }
    out
}

#[test]
fn no_two_reactive_cars_ever_overlap_in_any_general_scene() {
    let pool = general_pool();
    let mut steps = 0usize;
    let mut cars = 0usize;
    for scene in &pool.scenarios {
        let world = reactive_world(scene, WorldParams::default());
        cars += scene
            .agents
            .iter()
            .filter(|a| a.kind == AgentKind::Vehicle)
            .count();
        stop_the_ego(world, |w, _| {
            steps += 1;
            let overlaps = overlapping_reactive_cars(w);
            assert!(
                overlaps.is_empty(),
                "{} step {}: reactive cars overlap: {overlaps:?}",
                scene.name,
                w.step_index()
            );
        });
    }
    assert_eq!(pool.scenarios.len(), 305);
    assert!(cars > 2000 && steps > 9_000, "{cars} cars, {steps} steps");
}

#[test]
fn no_reactive_car_drives_into_a_car_stopped_at_the_start_of_a_general_scene() {
    let pool = general_pool();
    let mut hit = Vec::new();
    for scene in &pool.scenarios {
        let world = reactive_world(scene, WorldParams::default());
        let ego = scene.ego as u32;
        let mut first: Option<(u32, u32)> = None;
        stop_the_ego(world, |w, events| {
            for e in events {
                if let Event::Collision { a, b } = *e {
                    let other = if a == ego {
                        b
                    } else if b == ego {
                        a
                    } else {
                        continue;
                    };
                    let is_car = scene.agents[other as usize].kind == AgentKind::Vehicle;
                    if is_car && first.is_none() {
                        first = Some((w.step_index(), other));
                    }
                }
            }
        });
        if let Some((step, other)) = first {
            hit.push(format!("{} (step {step}, car {other})", scene.name));
        }
    }
    assert!(
        hit.is_empty(),
        "a reactive car hit the stopped ego in: {hit:?}"
    );
}

/// A straight road along x, sampled every 0.5 s.
fn car(start_step: u32, x0: f64, speed: f64, steps: usize) -> AgentRecord {
    AgentRecord {
        record_id: 0,
        kind: AgentKind::Vehicle,
        start_step,
        positions: (0..steps)
            .map(|k| [x0 + speed * 0.5 * k as f64, 0.0])
            .collect(),
        velocities: vec![[speed, 0.0]; steps],
        non_reactive: false,
        desired_speed: None,
    }
}

/// An ego car standing at `(x, 0)` along x, whose goal is 200 m away (it never arrives).
fn parked_ego(x: f64, steps: usize) -> AgentRecord {
    let mut rec = car(0, x, 0.0, steps);
    rec.positions.last_mut().unwrap()[1] = 200.0;
    rec
}

fn road(agents: Vec<AgentRecord>) -> Arc<Scenario> {
    Arc::new(Scenario {
        name: "road".into(),
        split: Split::Test,
        dt: 0.5,
        ego: 0,
        agents,
    })
}

fn position_of(world: &World, id: u32) -> Option<f64> {
    world.agents().find(|a| a.id == id).map(|a| a.position.x)
}

#[test]
fn a_car_behind_a_stopped_car_stops_behind_it() {
    // The ego stands at x = 30; a car recorded driving through it at 5 m/s from x = 0.
    let scene = road(vec![parked_ego(30.0, 60), car(0, 0.0, 5.0, 40)]);
    let mut config = EpisodeConfig::ego_external(&scene, PedestrianModel::CrSfm);
    config.vehicle_model = VehicleModel::Idm;
    let mut world = World::new(scene, WorldParams::default(), config).unwrap();
    let mut last = 0.0;
    let mut min_gap = f64::INFINITY;
    for _ in 0..50 {
        world.step(&[(0, [0.0, 0.0])]).unwrap();
        let x = position_of(&world, 1).expect("still there");
        assert!(x >= last, "the car reversed: {last} -> {x}");
        last = x;
        min_gap = min_gap.min(30.0 - x - 4.0);
    }
    let speed = world.agents().find(|a| a.id == 1).unwrap().velocity.norm();
    // Bumper to bumper it keeps at least the corridor margin, and it stands still.
    assert!(min_gap >= 0.3 - 1e-9, "gap {min_gap}");
    assert!(min_gap <= 2.5, "it stopped {min_gap} m short");
    assert!(speed < 1e-9, "still moving at {speed}");
    // It braked no harder than the AV may (2 m/s²): the IDM saw the car in time.
    assert!(world.agents().all(|a| a.acceleration.norm() <= 2.0 + 1e-9));
}

#[test]
fn on_a_free_road_a_reactive_car_is_its_record() {
    let scene = road(vec![parked_ego(-100.0, 60), car(2, 0.0, 4.0, 30)]);
    let replay = EpisodeConfig::ego_external(&scene, PedestrianModel::CrSfm);
    let mut reactive = replay.clone();
    reactive.vehicle_model = VehicleModel::Idm;
    let mut a = World::new(scene.clone(), WorldParams::default(), replay).unwrap();
    let mut b = World::new(scene, WorldParams::default(), reactive).unwrap();
    assert_eq!(b.control(1), Some(Control::Vehicle(VehicleModel::Idm)));
    for _ in 0..40 {
        a.step(&[(0, [0.0, 0.0])]).unwrap();
        b.step(&[(0, [0.0, 0.0])]).unwrap();
        let view = |w: &World| {
            w.agents()
                .find(|v| v.id == 1)
                .map(|v| (v.position, v.velocity, v.heading))
        };
        assert_eq!(view(&a), view(&b), "step {}", a.step_index());
    }
}

#[test]
fn a_held_up_car_catches_up_at_its_desired_speed_and_leaves_at_its_path_end() {
    // A pedestrian stands on the road for 10 s, then walks off it; the car, recorded at 4 m/s,
    // waits, then drives on to the end of its path, later than its record.
    let mut ped = AgentRecord {
        record_id: 2,
        kind: AgentKind::Pedestrian,
        start_step: 0,
        positions: (0..40)
            .map(|k| [20.0, if k < 20 { 0.0 } else { (k - 20) as f64 * 0.6 }])
            .collect(),
        velocities: (0..40)
            .map(|k| [0.0, if k < 20 { 0.0 } else { 1.2 }])
            .collect(),
        non_reactive: true,
        desired_speed: None,
    };
    ped.velocities[0] = [0.0, 0.0];
    let scene = road(vec![parked_ego(-100.0, 80), car(0, 0.0, 4.0, 20), ped]);
    let mut config = EpisodeConfig::ego_external(&scene, PedestrianModel::Replay);
    config.vehicle_model = VehicleModel::Idm;
    let mut world = World::new(scene, WorldParams::default(), config).unwrap();
    let mut left_at = None;
    let mut top_speed: f64 = 0.0;
    for _ in 0..70 {
        let out = world.step(&[(0, [0.0, 0.0])]).unwrap();
        if let Some(v) = world.agents().find(|a| a.id == 1) {
            top_speed = top_speed.max(v.velocity.norm());
            assert!(v.position.x < 20.0 - 0.3 - 2.0 + 1e-9 || world.step_index() > 20);
        }
        if out.events.contains(&Event::Left { agent: 1 }) {
            left_at = Some(world.step_index());
        }
    }
    // Recorded: 20 samples, gone after step 19. Held up for ~10 s, it leaves well after.
    let left_at = left_at.expect("the car reached the end of its path");
    assert!(left_at > 30, "left at step {left_at}");
    assert!(top_speed <= 4.0 + 1e-9, "top speed {top_speed}");
}

#[test]
fn reactive_traffic_steps_the_same_on_every_thread_count() {
    let pool = general_pool();
    let scene = pool
        .scenarios
        .iter()
        .max_by_key(|s| s.agents.len())
        .unwrap();
    let run = |threads: usize| {
        let mut world = reactive_world(scene, WorldParams::default());
        world.set_threads(threads);
        let mut trace = Vec::new();
        stop_the_ego(world, |w, _| {
            for a in w.agents() {
                trace.push((a.id, a.position.x.to_bits(), a.position.y.to_bits()));
            }
        });
        trace
    };
    let one = run(1);
    assert_eq!(one, run(1), "a rerun differs");
    assert_eq!(one, run(2));
    assert_eq!(one, run(4));
}
