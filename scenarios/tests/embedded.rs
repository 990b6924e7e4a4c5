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

#[test]
fn the_embedded_recording_is_the_published_file() {
    use sha2::{Digest, Sha256};
    let csv = scenarios::embedded::hbs_csv().unwrap();
    assert_eq!(csv.len(), 4_180_343);
    let digest: String = Sha256::digest(&csv)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect();
    assert_eq!(digest, scenarios::embedded::HBS_CSV_SHA256);
    // And the committed paper pool is exactly what the extractor makes of it.
    let data = scenarios::hbs::parse_hbs(&csv).unwrap();
    let paper = scenarios::hbs::extract_paper(&data, &Default::default());
    assert_eq!(save_pool(&paper), HBS_PAPER_JSON);
}

#[test]
fn the_general_pool_has_crowds_entering_and_leaving_and_other_vehicles() {
    let pool = scenarios::embedded::general_pool();
    assert_eq!(pool.name, "hbs-general");
    validate_pool(&pool, "embedded hbs-general", OverlapCheck::Spawn).unwrap();
    assert!(
        pool.scenarios.len() > 300,
        "{} scenarios",
        pool.scenarios.len()
    );
    let peds = |s: &sim_core::scenario::Scenario| {
        s.agents
            .iter()
            .filter(|a| a.kind == AgentKind::Pedestrian)
            .count()
    };
    let crowd = pool
        .scenarios
        .iter()
        .find(|s| peds(s) >= 50)
        .expect("a scene with at least 50 pedestrians");
    let last = crowd.recorded_steps() - 1;
    let entering = crowd.agents.iter().filter(|a| a.start_step > 0).count();
    let leaving = crowd.agents.iter().filter(|a| a.end_step() < last).count();
    assert!(
        entering > 10 && leaving > 10,
        "{entering} enter, {leaving} leave"
    );
    assert!(pool.scenarios.iter().any(|s| s
        .agents
        .iter()
        .filter(|a| a.kind == AgentKind::Vehicle)
        .count()
        >= 2));
    assert!(pool.provenance.contains("Pascucci"));
}

#[test]
fn an_unknown_embedded_pool_is_refused_with_the_names_there_are() {
    let e = scenarios::embedded::pool_from_arg(std::path::Path::new("embedded:hbs-everything"))
        .unwrap_err();
    assert!(
        e.contains("hbs-everything") && e.contains("hbs-general"),
        "{e}"
    );
    let pool =
        scenarios::embedded::pool_from_arg(std::path::Path::new("embedded:hbs-paper")).unwrap();
    assert_eq!(pool.name, "hbs-paper");
}
