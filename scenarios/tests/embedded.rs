//! Contract: the embedded default pool (`data/hbs-paper.json`) loads through the validating
//! loader, passes the all-steps overlap check, is the paper-like pool (one ego car and three
//! pedestrians per scenario, about 78 scenarios split about 77/23) and carries its attribution.

use scenarios::default_pool;
use scenarios::embedded::HBS_PAPER_JSON;
use scenarios::pool::{load_pool, save_pool, validate_pool, OverlapCheck};
use sim_core::scenario::{AgentKind, Split};

#[test]
fn embedded_pool_loads_and_validates() {
    let pool = load_pool(HBS_PAPER_JSON.as_bytes(), "data/hbs-paper.json").unwrap();
    validate_pool(&pool, "data/hbs-paper.json", OverlapCheck::AllSteps).unwrap();
    assert_eq!(default_pool(), pool);
    assert_eq!(pool.name, "hbs-paper");
    // The file is exactly what save_pool writes (so the extractor's output is committed as is).
    assert_eq!(save_pool(&pool), HBS_PAPER_JSON);
    assert!(
        HBS_PAPER_JSON.len() < 1_000_000,
        "{} bytes",
        HBS_PAPER_JSON.len()
    );
}

#[test]
fn embedded_pool_is_the_paper_setup() {
    let pool = default_pool();
    let n = pool.scenarios.len();
    assert!((70..=86).contains(&n), "{n} scenarios");
    let test = pool.split(Split::Test).count();
    assert!((0.18..=0.28).contains(&(test as f64 / n as f64)));
    for s in &pool.scenarios {
        assert_eq!(s.agents.len(), 4);
        assert_eq!(s.agents[s.ego].kind, AgentKind::Vehicle);
        assert_eq!(
            s.agents
                .iter()
                .filter(|a| a.kind == AgentKind::Pedestrian)
                .count(),
            3
        );
        assert!(s.recorded_steps() >= 10);
    }
    for cite in [
        "Pascucci",
        "Golchoubian",
        "MIT",
        "sha256 eccd747886abe3562d4bf4bdb31a3ef098d01c9bc9bd54d61c2bcb1a2222352c",
    ] {
        assert!(pool.provenance.contains(cite), "provenance lacks {cite}");
    }
}
