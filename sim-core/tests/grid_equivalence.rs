//! The O(N) grid neighbour search finds exactly the edge set of a brute-force O(N^2) scan, dense, sparse or degenerate.

mod common;

use std::collections::BTreeSet;

use common::{line, scenario, Rng};
use sim_core::geometry::Vec2;
use sim_core::scenario::{AgentKind, AgentRecord};
use sim_core::support::grid::Grid;
use sim_core::{EpisodeConfig, PedestrianModel, World, WorldParams};

const R: f64 = 15.0;

/// Ordered pairs `(i, j)`, `i != j`, with centres at most `r` apart (the world's test:
/// `|x_i - x_j|^2 <= r^2`).
fn brute_force(pos: &[Vec2], r: f64) -> BTreeSet<(usize, usize)> {
    let mut s = BTreeSet::new();
    for i in 0..pos.len() {
        for j in 0..pos.len() {
            if i != j && (pos[i] - pos[j]).norm_squared() <= r * r {
                s.insert((i, j));
            }
        }
    }
    s
}

fn via_grid(grid: &mut Grid, pos: &[Vec2], r: f64) -> BTreeSet<(usize, usize)> {
    grid.rebuild(pos, r);
    let mut s = BTreeSet::new();
    for i in 0..pos.len() {
        let mut seen = BTreeSet::new();
        grid.for_each_candidate(i, |j| {
            assert!(seen.insert(j), "candidate {j} visited twice for {i}");
            if i != j && (pos[i] - pos[j]).norm_squared() <= r * r {
                s.insert((i, j));
            }
        });
        assert!(seen.contains(&i), "an agent is its own candidate");
    }
    s
}

fn random_points(rng: &mut Rng, n: usize, size: f64) -> Vec<Vec2> {
    (0..n)
        .map(|_| Vec2::new(rng.uniform(0.0, size), rng.uniform(0.0, size)))
        .collect()
}

#[test]
fn grid_candidates_cover_every_neighbour_in_random_scenes() {
    let mut grid = Grid::default();
    let mut rng = Rng::new(11);
    for (n, size) in [(300, 100.0), (300, 30.0), (50, 500.0), (2, 10.0), (1, 1.0)] {
        let pos = random_points(&mut rng, n, size);
        assert_eq!(
            via_grid(&mut grid, &pos, R),
            brute_force(&pos, R),
            "n {n} size {size}"
        );
    }
    // empty scene
    grid.rebuild(&[], R);
}

#[test]
fn grid_handles_sparse_far_apart_agents() {
    let mut grid = Grid::default();
    let mut rng = Rng::new(12);
    // 300 agents over 1e5 m: almost nobody sees anybody; add a few tight pairs and the corners
    let mut pos = random_points(&mut rng, 300, 1e5);
    for k in 0..20 {
        let p = pos[k];
        pos.push(p + Vec2::new(rng.uniform(-15.0, 15.0), rng.uniform(-10.0, 10.0)));
    }
    pos.push(Vec2::new(0.0, 0.0));
    pos.push(Vec2::new(1e5, 1e5));
    pos.push(Vec2::new(1e5 - 14.9, 1e5));
    let want = brute_force(&pos, R);
    assert!(want.len() >= 2, "{} pairs", want.len());
    assert_eq!(via_grid(&mut grid, &pos, R), want);
    // extreme spread: the grid widens its cells instead of allocating ~1e22 of them
    let pos = vec![
        Vec2::new(-1e12, -1e12),
        Vec2::new(1e12, 1e12),
        Vec2::new(1e12 - 3.0, 1e12),
    ];
    assert_eq!(via_grid(&mut grid, &pos, R), brute_force(&pos, R));
}

#[test]
fn grid_handles_all_agents_at_one_point() {
    let mut grid = Grid::default();
    let pos = vec![Vec2::new(3.0, -7.0); 300];
    let got = via_grid(&mut grid, &pos, R);
    assert_eq!(got.len(), 300 * 299);
    assert_eq!(got, brute_force(&pos, R));
}

#[test]
fn grid_is_exact_at_the_radius_boundary() {
    let mut grid = Grid::default();
    // pairs exactly R apart along the axes, on cell boundaries of a grid anchored at 0
    let pos: Vec<Vec2> = (0..10)
        .flat_map(|i| (0..10).map(move |j| Vec2::new(i as f64 * R, j as f64 * R)))
        .collect();
    let got = via_grid(&mut grid, &pos, R);
    assert_eq!(got, brute_force(&pos, R));
    // each interior point has its 4 axis neighbours exactly at R; diagonals are beyond
    assert_eq!(got.len(), 2 * 2 * 10 * 9);
}

// ---------------------------------------------------------------- the world's graph

fn pedestrians_at(pos: &[Vec2], model: PedestrianModel) -> World {
    let mut rng = Rng::new(pos.len() as u64);
    let agents: Vec<AgentRecord> = pos
        .iter()
        .map(|p| {
            let v = [rng.uniform(-1.5, 1.5), rng.uniform(-1.5, 1.5)];
            line(AgentKind::Pedestrian, 0, [p.x, p.y], v, 12)
        })
        .collect();
    let sc = scenario(0, agents);
    World::new(
        sc,
        WorldParams::default(),
        EpisodeConfig::replay_vehicles(model),
    )
    .unwrap()
}

/// Directed edges `(observer, target)` by agent id.
type EdgeSet = BTreeSet<(u32, u32)>;

/// The world's edges by agent id, and the brute-force pairs over its present agents.
fn world_vs_brute_force(w: &World) -> (EdgeSet, EdgeSet) {
    let ids: Vec<u32> = w.agents().map(|a| a.id).collect();
    let pos: Vec<Vec2> = w.agents().map(|a| a.position).collect();
    let got: EdgeSet = w.graph_edges().map(|e| (e.observer, e.target)).collect();
    assert_eq!(got.len(), w.edge_count(), "no duplicate edges");
    let want = brute_force(&pos, w.params().perception_radius)
        .into_iter()
        .map(|(i, j)| (ids[i], ids[j]))
        .collect();
    (got, want)
}

fn assert_symmetric_clearances(w: &World) {
    let edges: Vec<_> = w.graph_edges().collect();
    for e in &edges {
        let back = edges
            .iter()
            .find(|b| b.observer == e.target && b.target == e.observer)
            .expect("perception is symmetric");
        assert_eq!(e.clearance.to_bits(), back.clearance.to_bits());
    }
}

#[test]
fn world_graph_equals_brute_force_in_a_dense_moving_crowd() {
    let mut rng = Rng::new(21);
    let pos = random_points(&mut rng, 300, 60.0);
    let mut w = pedestrians_at(&pos, PedestrianModel::Sfm);
    for _ in 0..4 {
        let (got, want) = world_vs_brute_force(&w);
        assert!(want.len() > 1000, "{} pairs", want.len());
        assert_eq!(got, want, "step {}", w.step_index());
        w.step(&[]).unwrap();
    }
    assert_symmetric_clearances(&w);
}

#[test]
fn world_graph_equals_brute_force_when_sparse() {
    let mut rng = Rng::new(22);
    let mut pos = random_points(&mut rng, 300, 1e5);
    pos.push(pos[0] + Vec2::new(5.0, 0.0));
    let mut w = pedestrians_at(&pos, PedestrianModel::CrSfm);
    for _ in 0..2 {
        let (got, want) = world_vs_brute_force(&w);
        assert!(!want.is_empty());
        assert_eq!(got, want);
        w.step(&[]).unwrap();
    }
}

#[test]
fn world_graph_equals_brute_force_when_everyone_is_at_one_point() {
    let pos = vec![Vec2::new(10.0, 10.0); 300];
    let w = pedestrians_at(&pos, PedestrianModel::Replay);
    let (got, want) = world_vs_brute_force(&w);
    assert_eq!(got.len(), 300 * 299);
    assert_eq!(got, want);
}
