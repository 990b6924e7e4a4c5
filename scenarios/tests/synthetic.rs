//! Contract: synthetic scenarios are reproducible from their seed, start non-overlapping
//! (clearance above 0 under the model's footprints), have straight start-to-goal tracks at
//! 1.0-1.5 m/s, fill a square of side sqrt(N / density), and scale to 10 000 pedestrians;
//! intersection routes cross at the square's centre.

use std::time::Instant;

use scenarios::footprint::{first_spawn_overlap, PED_RADIUS, VEHICLE_LENGTH};
use scenarios::pool::{load_pool, save_pool, validate_pool, OverlapCheck};
use scenarios::synthetic::{
    generate, generate_pool, Layout, Routes, SyntheticConfig, SyntheticError, LANE_SPACING,
    MAX_ENTRY_LAG_STEPS,
};
use sim_core::scenario::AgentKind;

#[test]
fn same_seed_same_scenario_other_seed_differs() {
    for layout in Layout::ALL {
        let cfg = SyntheticConfig::new(layout, 50, 42);
        let a = generate(&cfg).unwrap();
        let b = generate(&cfg).unwrap();
        assert_eq!(a, b);
        let c = generate(&SyntheticConfig::new(layout, 50, 43)).unwrap();
        assert_ne!(a.agents, c.agents);
    }
}

#[test]
fn scenarios_are_valid_and_well_formed() {
    let configs: Vec<_> = Layout::ALL
        .into_iter()
        .flat_map(|l| [0, 1, 3, 40, 200].map(move |n| SyntheticConfig::new(l, n, 7)))
        .collect();
    let pool = generate_pool("synthetic-test", &configs).unwrap();
    let text = save_pool(&pool);
    let back = load_pool(text.as_bytes(), "synthetic").unwrap();
    assert_eq!(back, pool);
    for (s, cfg) in pool.scenarios.iter().zip(&configs) {
        let n = cfg.pedestrians;
        assert_eq!(s.agents.len(), n + 1);
        assert_eq!(s.agents[s.ego].kind, AgentKind::Vehicle);
        let side = (n as f64 / 0.25).sqrt();
        for a in &s.agents[1..] {
            assert_eq!(a.kind, AgentKind::Pedestrian);
            let [x, y] = a.positions[0];
            assert!(
                x >= PED_RADIUS && x <= side - PED_RADIUS,
                "{x} outside [0, {side}]"
            );
            assert!(y >= PED_RADIUS && y <= side - PED_RADIUS);
            let v = a.mean_speed();
            assert!((1.0..=1.5).contains(&v), "speed {v}");
            // Straight: every sample on the start-goal segment.
            let g = a.goal();
            let (dx, dy) = (g[0] - x, g[1] - y);
            let len = dx.hypot(dy);
            assert!((len - side.min(30.0)).abs() < 1e-9);
            for p in &a.positions {
                let cross = (p[0] - x) * dy - (p[1] - y) * dx;
                assert!(cross.abs() / len < 1e-9);
            }
            match cfg.layout {
                Layout::Crossing => assert!(dy.abs() > dx.abs()),
                Layout::CounterFlow => assert!(dx < 0.0 && dx.abs() > dy.abs()),
                Layout::Random => {}
            }
        }
    }
}

#[test]
fn initial_positions_never_overlap_even_when_dense() {
    // Dense enough that rejection sampling fails and the lattice fallback is used.
    for density in [0.25, 1.0, 1.3, 2.0, 2.5] {
        let mut cfg = SyntheticConfig::new(Layout::Random, 400, 3);
        cfg.density = density;
        let s = generate(&cfg).unwrap();
        assert_eq!(first_spawn_overlap(&s.agents), None, "density {density}");
        // Brute-force pairwise check of the pedestrians' initial discs.
        let p: Vec<[f64; 2]> = s.agents[1..].iter().map(|a| a.positions[0]).collect();
        for i in 0..p.len() {
            for j in i + 1..p.len() {
                let d = (p[i][0] - p[j][0]).hypot(p[i][1] - p[j][1]);
                assert!(
                    d > 2.0 * PED_RADIUS,
                    "density {density}: {i} and {j} at {d} m"
                );
            }
        }
    }
}

#[test]
fn intersection_routes_cross_at_the_centre_and_keep_the_crowd_of_the_lanes_scene() {
    let side = SyntheticConfig::new(Layout::Crossing, 40, 5).side();
    let centre = 0.5 * side;
    let mut lags = Vec::new();
    for seed in 0..16 {
        let mut cfg = SyntheticConfig::new(Layout::Crossing, 40, seed);
        cfg.vehicles = 4;
        let lanes = generate(&cfg).unwrap();
        cfg.routes = Routes::Intersection;
        let s = generate(&cfg).unwrap();
        assert_eq!(
            s.name,
            format!("synthetic-crossing-n40-v4-intersection-seed{seed}")
        );
        // The pedestrians are those of the lanes scene of the same seed.
        assert_eq!(s.agents[4..], lanes.agents[4..]);
        let reach = centre + 0.5 * VEHICLE_LENGTH + 1.0;
        for (k, car) in s.agents[..4].iter().enumerate() {
            assert_eq!(car.kind, AgentKind::Vehicle);
            let (from, to) = (car.positions[0], *car.positions.last().unwrap());
            let heading = (to[1] - from[1]).atan2(to[0] - from[0]);
            let want = k as f64 * std::f64::consts::FRAC_PI_2;
            assert!((heading - want).sin().abs() < 1e-9 && (heading - want).cos() > 0.0);
            // Half a lane right of the centre line through the square's centre.
            let (sin, cos) = want.sin_cos();
            let across = (from[0] - centre) * -sin + (from[1] - centre) * cos;
            assert!(
                (across + 0.5 * LANE_SPACING).abs() < 1e-9,
                "car {k}: {across}"
            );
            // Every car is there from the first step, outside the square, where no pedestrian
            // is: none can appear on top of one.
            assert_eq!(car.start_step, 0, "car {k}");
            assert!(from.iter().any(|&c| c < 0.0 || c > side));
            let front = VEHICLE_LENGTH / 2.0;
            for ped in &s.agents[4..] {
                let p = ped.positions[0];
                let ahead = (p[0] - from[0]) * cos + (p[1] - from[1]) * sin;
                assert!(ahead > front, "car {k} starts on a pedestrian");
            }
            // It ends 1 m past the square; the ego starts 1 m before it, the others a lag of
            // whole steps of driving behind that line.
            let to_centre = (centre - from[0]) * cos + (centre - from[1]) * sin;
            let lag = (to_centre - reach) / (cfg.vehicle_speed * 0.5);
            assert!((lag - lag.round()).abs() < 1e-9, "car {k}: lag {lag}");
            assert!(lag.round() as u64 <= MAX_ENTRY_LAG_STEPS);
            if k == 0 {
                assert!(lag.abs() < 1e-9, "the ego keeps the start line");
            } else {
                lags.push(lag.round() as u64);
            }
            let past = (to[0] - centre) * cos + (to[1] - centre) * sin;
            assert!((past - reach).abs() < 1e-9);
        }
        // Perpendicular routes cross inside the square: car 0 (+x) at y = c - 2, car 1 (+y) at
        // x = c + 2.
        assert!((s.agents[0].positions[0][1] - (centre - 2.0)).abs() < 1e-9);
        assert!((s.agents[1].positions[0][0] - (centre + 2.0)).abs() < 1e-9);
    }
    // The lags vary with the seed.
    assert!(lags.iter().min() < lags.iter().max(), "{lags:?}");
    let mut cfg = SyntheticConfig::new(Layout::Crossing, 10, 1);
    (cfg.vehicles, cfg.routes) = (5, Routes::Intersection);
    assert!(generate(&cfg).unwrap_err().to_string().contains("4 arms"));
    assert!("roundabout".parse::<Routes>().is_err());
}

#[test]
fn impossible_density_and_bad_config_are_errors() {
    let mut cfg = SyntheticConfig::new(Layout::Crossing, 100, 1);
    cfg.density = 10.0;
    assert!(matches!(
        generate(&cfg),
        Err(SyntheticError::TooDense { .. })
    ));
    for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        let mut cfg = SyntheticConfig::new(Layout::Crossing, 10, 1);
        cfg.density = bad;
        let e = generate(&cfg).unwrap_err();
        assert!(e.to_string().contains("density"), "{e}");
    }
    let mut cfg = SyntheticConfig::new(Layout::Crossing, 10, 1);
    cfg.density = 1e-12;
    assert!(generate(&cfg).unwrap_err().to_string().contains("10 km"));
    let mut cfg = SyntheticConfig::new(Layout::Crossing, 10, 1);
    cfg.vehicle_speed = 1e-9;
    assert!(generate(&cfg)
        .unwrap_err()
        .to_string()
        .contains("vehicle_speed"));
    let mut cfg = SyntheticConfig::new(Layout::Crossing, 10, 1);
    cfg.ped_speed_max = 0.5;
    assert!(generate(&cfg)
        .unwrap_err()
        .to_string()
        .contains("ped_speed_max"));
}

#[test]
fn scales_to_ten_thousand_pedestrians() {
    let t = Instant::now();
    let cfg = SyntheticConfig::new(Layout::Crossing, 10_000, 9);
    let s = generate(&cfg).unwrap();
    let gen = t.elapsed();
    assert_eq!(s.agents.len(), 10_001);
    let pool = generate_pool("big", std::slice::from_ref(&cfg)).unwrap();
    validate_pool(&pool, "big", OverlapCheck::Spawn).unwrap();
    let total = t.elapsed();
    // Generous bounds for unoptimised test builds; O(N^2) would take far longer.
    assert!(gen.as_secs_f64() < 10.0, "generation took {gen:?}");
    assert!(
        total.as_secs_f64() < 30.0,
        "generation and validation took {total:?}"
    );
}
