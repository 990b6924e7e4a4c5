//! Contract: two trainers stepping lockstep envs on one server at the same time never see each
//! other: each env's trajectory (scenarios, observations, rewards, flags) equals the trajectory
//! of the same env (same seed and actions) run alone.

mod common;

use common::{client, config, episode_over, free_port, outcome_bytes, start, t};
use protocol::{CreateEnv, Reset};
use sim_server::server::client::Client;

/// One recorded transition: scenario, step, reward and observation bits.
type Record = (String, u32, Vec<u8>, Vec<u8>, Vec<u8>);

/// Runs `steps` lockstep steps on a fresh env (resetting whenever an episode ends) with a
/// deterministic action pattern, then closes the env.
async fn trajectory(c: &Client, seed: u64, steps: u32, phase: f32) -> Vec<Record> {
    let mut req = CreateEnv::new(c.client_id());
    req.seed = seed;
    let env = t(c.create(req)).await.unwrap().env_ids.remove(0);
    let mut out = Vec::new();
    let mut over = true; // the first step starts from a reset
    for k in 0..steps {
        if over {
            let r = t(c.reset(&env, &Reset::default())).await.unwrap();
            let (features, node_ids) = (r.obs.features.as_le_bytes(), r.obs.node_ids.as_le_bytes());
            out.push((
                r.scenario.clone(),
                0,
                Vec::new(),
                features.to_vec(),
                node_ids.to_vec(),
            ));
        }
        let a = [
            ((k as f32) * 0.37 + phase).sin(),
            ((k as f32) * 0.11).cos() * 0.5,
        ];
        let s = t(c.step(&env, &[a])).await.unwrap();
        over = episode_over(&s);
        out.push((
            s.scenario.clone(),
            s.step,
            outcome_bytes(&s),
            s.obs.features.as_le_bytes().to_vec(),
            s.obs.adjacency.as_le_bytes().to_vec(),
        ));
    }
    t(c.close(&env)).await.unwrap();
    out
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn concurrent_trainers_match_solo_runs() {
    let server = start(config(free_port(), "srv-two")).await;
    let a = client(&server, "trainer-a").await;
    let b = client(&server, "trainer-b").await;
    const STEPS: u32 = 70;

    let (ta, tb) = tokio::join!(
        trajectory(&a, 11, STEPS, 0.0),
        trajectory(&b, 12, STEPS, 1.3)
    );
    // The two trainers' envs are different envs (different seeds/actions give other data).
    assert_ne!(ta, tb);

    let solo_a = trajectory(&a, 11, STEPS, 0.0).await;
    let solo_b = trajectory(&b, 12, STEPS, 1.3).await;
    assert_eq!(ta, solo_a, "trainer a's env differs from its solo run");
    assert_eq!(tb, solo_b, "trainer b's env differs from its solo run");
    // Episodes ended and were reset at least once in 70 steps (the sequence is exercised).
    assert!(ta.iter().filter(|r| r.1 == 0).count() >= 2);
    server.stop().await;
}
