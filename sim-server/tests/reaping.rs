//! Contract: a trainer that vanishes without closing its envs (its zenoh session closed, so its
//! liveliness token `{p}/trainer/{client_id}` disappears) has its envs reaped within 10 s; envs
//! created under a client id that never declares a token are reaped after the grace period;
//! reaped envs answer `env_closed` and other trainers' envs stay open.

mod common;

use std::time::{Duration, Instant};

use common::{client, config, free_port, start, t};
use protocol::{CreateEnv, ErrorCode, Reset};

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

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn vanished_trainer_is_reaped() {
    let mut cfg = config(free_port(), "srv-reap");
    cfg.trainer_grace_s = 1.0;
    let server = start(cfg).await;
    let watcher = client(&server, "watcher").await;
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
