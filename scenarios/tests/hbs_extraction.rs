//! Contract: HBS extraction is deterministic (same CSV -> byte-identical JSON), the paper-like
//! pool holds one ego car and exactly three pedestrians present through the whole window and
//! collision-free at every step, the general pool passes the loader, the CSV parser names the line
//! and field of malformed input, and on the full file (when `../shared` is present) the paper-like
//! pool has about 78 scenarios split about 77 % / 23 %.

use scenarios::hbs::{
    extract_general, extract_paper, parse_hbs, GeneralParams, HbsError, PaperParams,
};
use scenarios::pool::{load_pool, save_pool, validate_pool, OverlapCheck};
use sim_core::scenario::{AgentKind, ScenarioPool, Split};

const EXCERPT: &[u8] = include_bytes!("fixtures/hbs_excerpt.csv");
const FULL: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data/hbs/hbs.csv");

fn paper(csv: &[u8]) -> String {
    save_pool(&extract_paper(
        &parse_hbs(csv).unwrap(),
        &PaperParams::default(),
    ))
}

fn general(csv: &[u8]) -> String {
    save_pool(&extract_general(
        &parse_hbs(csv).unwrap(),
        &GeneralParams::default(),
    ))
}

fn check_paper_pool(pool: &ScenarioPool) {
    validate_pool(pool, "paper", OverlapCheck::AllSteps).unwrap();
    for s in &pool.scenarios {
        assert_eq!(s.ego, 0, "{}", s.name);
        assert_eq!(s.dt, 0.5);
        assert_eq!(s.agents.len(), 4, "{}", s.name);
        assert_eq!(s.agents[0].kind, AgentKind::Vehicle);
        assert_eq!(s.name, format!("hbs-car{}", s.agents[0].record_id));
        let steps = s.agents[0].positions.len();
        assert!(steps >= 10, "{}: window of {steps} steps", s.name);
        for a in &s.agents[1..] {
            assert_eq!(a.kind, AgentKind::Pedestrian, "{}", s.name);
            assert_eq!(a.start_step, 0, "{}", s.name);
            assert_eq!(
                a.positions.len(),
                steps,
                "{}: pedestrian absent part of the window",
                s.name
            );
            assert!(!a.non_reactive);
        }
    }
}

fn check_general_pool(pool: &ScenarioPool) {
    validate_pool(pool, "general", OverlapCheck::Spawn).unwrap();
    for s in &pool.scenarios {
        assert_eq!(s.ego, 0);
        let steps = s.agents[0].positions.len() as u32;
        for a in &s.agents[1..] {
            assert!(a.end_step() < steps, "{}: agent outside the window", s.name);
            assert_eq!(a.non_reactive, a.kind == AgentKind::Vehicle);
        }
    }
}

#[test]
fn excerpt_extraction_is_deterministic() {
    let a = paper(EXCERPT);
    let b = paper(EXCERPT);
    assert_eq!(a, b, "paper pool differs between runs");
    let g1 = general(EXCERPT);
    let g2 = general(EXCERPT);
    assert_eq!(g1, g2, "general pool differs between runs");
    // Re-serialising a loaded pool reproduces the bytes.
    let pool = load_pool(a.as_bytes(), "excerpt paper").unwrap();
    assert_eq!(save_pool(&pool), a);
    let pool = load_pool(g1.as_bytes(), "excerpt general").unwrap();
    assert_eq!(save_pool(&pool), g1);
}

#[test]
fn excerpt_pools_satisfy_the_contract() {
    let data = parse_hbs(EXCERPT).unwrap();
    let p = extract_paper(&data, &PaperParams::default());
    assert!(
        p.scenarios.len() >= 3,
        "excerpt yields {} paper scenarios",
        p.scenarios.len()
    );
    check_paper_pool(&p);
    assert!(p.provenance.contains(&data.sha256));
    assert!(p.provenance.contains("Pascucci") && p.provenance.contains("Golchoubian"));
    let g = extract_general(&data, &GeneralParams::default());
    assert!(g.scenarios.iter().any(|s| s.split == Split::Test));
    check_general_pool(&g);
    // Every general scenario holds its car's pedestrians; some hold other cars.
    assert!(g
        .scenarios
        .iter()
        .any(|s| s.agents.iter().filter(|a| a.non_reactive).count() > 0));
}

#[test]
fn row_order_does_not_matter() {
    // Reversing the data rows gives the same pools.
    let text = std::str::from_utf8(EXCERPT).unwrap();
    let mut lines: Vec<&str> = text.lines().collect();
    lines[1..].reverse();
    let reversed = lines.join("\n");
    // (The provenance differs: it records the input's sha256.)
    let scen = |csv: &[u8], general: bool| {
        let data = parse_hbs(csv).unwrap();
        let pool = if general {
            extract_general(&data, &GeneralParams::default())
        } else {
            extract_paper(&data, &PaperParams::default())
        };
        pool.scenarios
    };
    assert_eq!(scen(reversed.as_bytes(), false), scen(EXCERPT, false));
    assert_eq!(scen(reversed.as_bytes(), true), scen(EXCERPT, true));
}

#[test]
fn no_general_train_scene_shares_a_recorded_agent_with_a_test_scene() {
    for pool in [
        extract_general(&parse_hbs(EXCERPT).unwrap(), &GeneralParams::default()),
        scenarios::embedded::general_pool(),
    ] {
        let agents = |split| -> std::collections::HashSet<(AgentKind, u64)> {
            pool.split(split)
                .flat_map(|s| s.agents.iter().map(|a| (a.kind, a.record_id)))
                .collect()
        };
        let (train, test) = (agents(Split::Train), agents(Split::Test));
        assert!(!test.is_empty());
        assert!(train.is_disjoint(&test), "{}", pool.name);
        // The test scenes come first (a block of the recording's start).
        let first_train = pool.scenarios.iter().position(|s| s.split == Split::Train);
        let last_test = pool.scenarios.iter().rposition(|s| s.split == Split::Test);
        assert!(first_train.is_none_or(|t| last_test.is_some_and(|l| l < t)));
    }
}

#[test]
fn split_rule_in_pool_order() {
    let p = extract_paper(&parse_hbs(EXCERPT).unwrap(), &PaperParams::default());
    for (i, s) in p.scenarios.iter().enumerate() {
        let want = if [2, 6, 10].contains(&(i % 13)) {
            Split::Test
        } else {
            Split::Train
        };
        assert_eq!(s.split, want, "{}", s.name);
    }
}

const HEADER: &str = "frame_id,agent_id,pos_x,pos_y,label,scene_id,timestamp,vel_x,vel_y\n";

fn csv_err(body: &str) -> String {
    let e: HbsError = parse_hbs(format!("{HEADER}{body}").as_bytes()).unwrap_err();
    e.to_string()
}

#[test]
fn csv_errors_name_line_and_field() {
    let ok = "0,1,1.0,2.0,ped,0,0.0,0.1,0.2\n";
    assert!(parse_hbs(format!("{HEADER}{ok}").as_bytes()).is_ok());
    let cases = [
        ("0,1,1.0,2.0,ped,0,0.0,0.1\n", "line 2: 8 fields"),
        (
            "0,x,1.0,2.0,ped,0,0.0,0.1,0.2\n",
            "line 2: field `agent_id`",
        ),
        (
            "-1,1,1.0,2.0,ped,0,0.0,0.1,0.2\n",
            "line 2: field `frame_id`",
        ),
        ("0,1,abc,2.0,ped,0,0.0,0.1,0.2\n", "line 2: field `pos_x`"),
        (
            "0,1,1.0,NaN,ped,0,0.0,0.1,0.2\n",
            "line 2: field `pos_y`: not a finite number",
        ),
        ("0,1,1.0,2.0,bus,0,0.0,0.1,0.2\n", "line 2: field `label`"),
        (
            "0,1,1.0,2.0,ped,z,0.0,0.1,0.2\n",
            "line 2: field `scene_id`",
        ),
        (
            "3,1,1.0,2.0,ped,0,0.0,0.1,0.2\n",
            "line 2: field `timestamp`",
        ),
        ("0,1,1.0,2.0,ped,0,0.0,inf,0.2\n", "line 2: field `vel_x`"),
        ("0,1,1.0,2.0,ped,0,0.0,0.1,\n", "line 2: field `vel_y`"),
    ];
    for (body, want) in cases {
        let msg = csv_err(body);
        assert!(msg.contains(want), "`{msg}` lacks `{want}`");
    }
    let msg = csv_err(&format!("{ok}{ok}"));
    assert!(
        msg.contains("line 3") && msg.contains("line 2") && msg.contains("frame_id"),
        "{msg}"
    );
    let msg = csv_err(&format!("{ok}1,1,1.0,2.0,car,0,0.5,0.1,0.2\n"));
    assert!(msg.contains("line 3: field `label`"), "{msg}");
    let msg = parse_hbs(b"frame,agent\n").unwrap_err().to_string();
    assert!(msg.contains("line 1") && msg.contains("header"), "{msg}");
    assert!(matches!(parse_hbs(b""), Err(HbsError::Empty)));
    let msg = parse_hbs(
        format!("{HEADER}{ok}0,2,\u{0}\u{0}")
            .as_bytes()
            .iter()
            .map(|&b| if b == 0 { 0xff } else { b })
            .collect::<Vec<_>>()
            .as_slice(),
    )
    .unwrap_err()
    .to_string();
    assert!(msg.contains("line 3") && msg.contains("UTF-8"), "{msg}");
}

#[test]
fn full_file_pool_is_near_78_and_77_23() {
    let Ok(bytes) = std::fs::read(FULL) else {
        println!("skipped: ../shared/data/hbs/hbs.csv absent");
        return;
    };
    let data = parse_hbs(&bytes).unwrap();
    let p = extract_paper(&data, &PaperParams::default());
    let n = p.scenarios.len();
    assert!(
        (70..=86).contains(&n),
        "{n} paper scenarios, expected about 78"
    );
    let test = p.split(Split::Test).count();
    let frac = test as f64 / n as f64;
    assert!((0.18..=0.28).contains(&frac), "test fraction {frac}");
    check_paper_pool(&p);
    assert_eq!(
        save_pool(&p),
        paper(&bytes),
        "full-file extraction not deterministic"
    );
    // The committed embedded pool is exactly this extraction.
    assert_eq!(
        save_pool(&p),
        scenarios::embedded::HBS_PAPER_JSON,
        "data/hbs-paper.json is stale"
    );
    let g = extract_general(&data, &GeneralParams::default());
    assert!(
        g.scenarios.len() > 300,
        "{} general scenarios",
        g.scenarios.len()
    );
    check_general_pool(&g);
    let frac = g.split(Split::Test).count() as f64 / g.scenarios.len() as f64;
    assert!((0.2..=0.26).contains(&frac), "general test fraction {frac}");
}
