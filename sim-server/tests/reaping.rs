//! Contract: a trainer that vanishes without closing its envs (its zenoh session closed, so its
//! liveliness token `{p}/trainer/{client_id}` disappears) has its envs reaped within 10 s; envs
//! created under a client id that never declares a token are reaped after the grace period;
//! reaped envs answer `env_closed` and other trainers' envs stay open.

mod common;

use std::time::{Duration, Instant};

use common::{client, config, free_port, start, t, TestServer};
use protocol::{BatchStep, CreateEnv, ErrorCode, F32Array, Reset};
use sim_server::server::client::Client;

async fn wait_load(
    c: &sim_server::server::client::Client,
    want: u32,
    within: Duration,
) -> Duration {
    let t0 = Instant::now();
    t(async {
        loop {
            if c.info().await.unwrap().load == want {
                break;
            }
            assert!(
                t0.elapsed() < within,
                "load did not reach {want} within {within:?}"
            );
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    })
    .await;
    t0.elapsed()
}

/// A server that reaps a trainer `grace_s` seconds after its session is gone, and a watching
/// client that stays.
async fn server_with_grace(server_id: &str, grace_s: f64) -> (TestServer, Client) {
    let mut cfg = config(free_port(), server_id);
    cfg.trainer_grace_s = grace_s;
    let server = start(cfg).await;
    let watcher = client(&server, "watcher").await;
    (server, watcher)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn vanished_trainer_is_reaped() {
    let (server, watcher) = server_with_grace("srv-reap", 1.0).await;
    let kept = t(watcher.create(CreateEnv::new("w")))
        .await
        .unwrap()
        .env_ids;

    // A trainer creates envs and its session goes away without closing them.
    let doomed = client(&server, "doomed").await;
    let mut req = CreateEnv::new("doomed");
    req.count = 3;
    let ids = t(doomed.create(req)).await.unwrap().env_ids;
    t(doomed.reset(&ids[0], &Reset::default())).await.unwrap();
    assert_eq!(t(watcher.info()).await.unwrap().load, 4);
    t(doomed.session().clone().close()).await.unwrap();
    drop(doomed);
    let took = wait_load(&watcher, 1, Duration::from_secs(10)).await;
    println!("reaped after {took:?}");
    for id in &ids {
        let e = t(watcher.reset(id, &Reset::default())).await.unwrap_err();
        assert_eq!(e.server().unwrap().code, ErrorCode::EnvClosed, "{e}");
    }
    // The watcher's env is untouched.
    t(watcher.reset(&kept[0], &Reset::default())).await.unwrap();

    // Envs of a client id without any liveliness token are reaped after the grace period (1 s).
    let mut ghost = CreateEnv::new("ghost");
    ghost.count = 2;
    let raw = protocol::encode(&ghost);
    let key = watcher.keys().env_create("srv-reap").unwrap();
    let reply: protocol::EnvCreated = t(watcher.request(&key, raw)).await.unwrap();
    assert_eq!(reply.env_ids.len(), 2);
    assert_eq!(t(watcher.info()).await.unwrap().load, 3);
    let took = wait_load(&watcher, 1, Duration::from_secs(5)).await;
    assert!(
        took >= Duration::from_millis(500),
        "reaped too early: {took:?}"
    );
    server.stop().await;
}

/// The server's tables (`ServerInfo.tables`) with the pools of reusable step buffers left out:
/// those are bounded, not emptied (at most 8 buffers, 4 step scratches per batch thread).
fn tables_without_pools(info: &protocol::ServerInfo) -> Vec<(String, u64)> {
    info.tables
        .iter()
        .filter(|(name, _)| !name.starts_with("pooled_"))
        .map(|(name, n)| (name.clone(), *n))
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_table_is_back_to_its_idle_size_once_the_trainers_are_gone() {
    let (server, watcher) = server_with_grace("srv-tables", 0.5).await;
    let idle = t(watcher.info()).await.unwrap();
    for name in ["envs", "trainers", "fair_trainers", "watched_envs"] {
        assert!(
            idle.tables.contains_key(name),
            "no table {name}: {:?}",
            idle.tables
        );
    }
    let batch = |ids: &[String]| BatchStep {
        env_ids: ids.to_vec(),
        actions: F32Array::new(vec![ids.len() as u32, 1, 2], &vec![0.3; 2 * ids.len()])
            .unwrap()
            .into(),
    };
    for cycle in 0..6 {
        // A trainer with a liveliness token: batches, closes some envs, then vanishes.
        let name = format!("trainer-{cycle}");
        let trainer = client(&server, &name).await;
        let mut req = CreateEnv::new(&name);
        req.count = 4;
        let ids = t(trainer.create(req)).await.unwrap().env_ids;
        for id in &ids {
            t(trainer.reset(id, &Reset::default())).await.unwrap();
        }
        for _ in 0..3 {
            t(trainer.batch_step(&batch(&ids))).await.unwrap();
        }
        t(trainer.close(&ids[0])).await.unwrap();
        t(trainer.session().clone().close()).await.unwrap();
        drop(trainer);
        // A client id without a token: creates, batches and closes all its envs itself.
        let ghost = format!("ghost-{cycle}");
        let mut req = CreateEnv::new(&ghost);
        req.count = 2;
        let key = watcher.keys().env_create("srv-tables").unwrap();
        let created: protocol::EnvCreated = t(watcher.request(&key, protocol::encode(&req)))
            .await
            .unwrap();
        for id in &created.env_ids {
            t(watcher.reset(id, &Reset::default())).await.unwrap();
        }
        t(watcher.batch_step(&batch(&created.env_ids)))
            .await
            .unwrap();
        for id in &created.env_ids {
            t(watcher.close(id)).await.unwrap();
        }
    }
    wait_load(&watcher, 0, Duration::from_secs(10)).await;
    // The vanished trainers' entries go with the sweep after their grace.
    let t0 = Instant::now();
    let end = loop {
        let info = t(watcher.info()).await.unwrap();
        if tables_without_pools(&info) == tables_without_pools(&idle)
            || t0.elapsed() > Duration::from_secs(10)
        {
            break info;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    };
    assert_eq!(
        tables_without_pools(&end),
        tables_without_pools(&idle),
        "tables after 6 trainers came and went: {:?}",
        end.tables
    );
    assert!(end.tables["pooled_step_buffers"] <= 8, "{:?}", end.tables);
    server.stop().await;
}
