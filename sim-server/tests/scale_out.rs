//! Contract (scale-out and failover, Rust-only so it runs without Python): behind one
//! `sim-server router`, two `sim-server serve` processes (zenoh client mode, server credentials)
//! are discovered by trainers through `{p}/server/*/info`; two trainers (trainer credentials)
//! place their envs on the least loaded server, so the envs spread over both servers. When the
//! server of trainer A is SIGKILLed mid-run, A's next request fails with a clear error (no reply
//! / timeout) and the server's liveliness token `{p}/server/{id}/alive` is gone; A re-creates
//! its envs on the surviving server and carries on (its new trajectory equals an undisturbed run
//! of the same seeds); trainer B, whose envs live on the surviving server, is undisturbed (its
//! trajectory equals a solo run).

mod common;
mod procs;

use std::time::Duration;

use common::{episode_over, outcome_bytes};
use procs::{free_port, router, serve, session, t, Scratch, SERVER_USER, TRAINER_USER};
use protocol::{decode, encode, CreateEnv, InfoRequest, KeySpace, Reply, Reset, ServerInfo};
use sim_server::server::client::{Client, ClientError};
use tokio::sync::oneshot;
use zenoh::query::{ConsolidationMode, QueryTarget};
use zenoh::Session;

/// One recorded transition: env index, scenario, step, reward/flag bits, observation bits.
type Record = (usize, String, u32, Vec<u8>, Vec<u8>);

const ENVS: u32 = 2;

/// Every live server's `ServerInfo` (a `get` on `{p}/server/*/info`), sorted by server id.
async fn discover(s: &Session, keys: &KeySpace) -> Vec<ServerInfo> {
    let replies = t(s
        .get(keys.server_info_all())
        .payload(encode(&InfoRequest::default()))
        .target(QueryTarget::All)
        .consolidation(ConsolidationMode::None)
        .timeout(Duration::from_secs(2)))
    .await
    .unwrap();
    let mut out = Vec::new();
    while let Ok(Ok(r)) = tokio::time::timeout(Duration::from_secs(4), replies.recv_async()).await {
        if let Ok(sample) = r.result() {
            let reply: Reply<ServerInfo> = decode(&sample.payload().to_bytes()).unwrap();
            out.push(reply.into_result().unwrap());
        }
    }
    out.sort_by(|a, b| a.server_id.cmp(&b.server_id));
    out
}

/// The least loaded server (open envs / capacity; ties by id).
fn least_loaded(infos: &[ServerInfo]) -> String {
    infos
        .iter()
        .min_by(|a, b| {
            let la = f64::from(a.load) / f64::from(a.capacity);
            let lb = f64::from(b.load) / f64::from(b.capacity);
            la.total_cmp(&lb).then(a.server_id.cmp(&b.server_id))
        })
        .expect("at least one server")
        .server_id
        .clone()
}

/// A trainer's connection to the least loaded server among those it discovers.
async fn connect_least_loaded(s: &Session, client_id: &str) -> Client {
    let keys = KeySpace::default();
    let infos = discover(s, &keys).await;
    let target = least_loaded(&infos);
    t(Client::new(s.clone(), keys, &target, client_id))
        .await
        .unwrap()
}

/// Creates `ENVS` envs (seeds `seed`, `seed + 1`) and steps each `steps` times with a
/// deterministic action pattern (resetting ended episodes). When `kill` is given, after
/// `kill.0` steps it asks the test to kill this client's server and waits until it did. Returns
/// the records so far and, if a request failed, its error.
async fn run(
    c: &Client,
    seed: u64,
    steps: u32,
    phase: f32,
    mut kill: Option<(u32, oneshot::Sender<String>, oneshot::Receiver<()>)>,
) -> (Vec<Record>, Option<ClientError>) {
    let mut out = Vec::new();
    let mut req = CreateEnv::new(c.client_id());
    req.seed = seed;
    req.count = ENVS;
    let envs = t(c.create(req)).await.unwrap().env_ids;
    let mut over = vec![true; envs.len()];
    for k in 0..steps {
        if let Some((at, _, _)) = &kill {
            if *at == k {
                let (_, tx, rx) = kill.take().unwrap();
                tx.send(c.server_id().to_string()).unwrap();
                t(rx).await.unwrap();
            }
        }
        for (i, env) in envs.iter().enumerate() {
            if over[i] {
                match t(c.reset(env, &Reset::default())).await {
                    Ok(r) => out.push((
                        i,
                        r.scenario.clone(),
                        0,
                        Vec::new(),
                        r.obs.features.as_le_bytes().to_vec(),
                    )),
                    Err(e) => return (out, Some(e)),
                }
            }
            let a = [
                ((k as f32) * 0.37 + phase + i as f32).sin(),
                ((k as f32) * 0.11).cos() * 0.5,
            ];
            let s = match t(c.step(env, &[a])).await {
                Ok(s) => s,
                Err(e) => return (out, Some(e)),
            };
            over[i] = episode_over(&s);
            out.push((
                i,
                s.scenario.clone(),
                s.step,
                outcome_bytes(&s),
                s.obs.features.as_le_bytes().to_vec(),
            ));
        }
    }
    for env in &envs {
        t(c.close(env)).await.unwrap();
    }
    (out, None)
}

/// Waits until no liveliness token `{p}/server/{server_id}/alive` is left.
async fn wait_token_gone(s: &Session, server_id: &str) {
    let key = KeySpace::default().server_alive(server_id).unwrap();
    t(async {
        loop {
            let replies = s
                .liveliness()
                .get(&key)
                .timeout(Duration::from_secs(1))
                .await
                .unwrap();
            let mut n = 0;
            while let Ok(Ok(_)) =
                tokio::time::timeout(Duration::from_secs(2), replies.recv_async()).await
            {
                n += 1;
            }
            if n == 0 {
                break;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn envs_spread_and_fail_over() {
    const STEPS_A: u32 = 20;
    const KILL_AT: u32 = 5;
    const STEPS_B: u32 = 30;
    let scratch = Scratch::new("scale-out");
    let port = free_port();
    let mut rt = router(&scratch, port).await;
    let mut servers = vec![
        serve(&scratch, port, "srv-1", SERVER_USER),
        serve(&scratch, port, "srv-2", SERVER_USER),
    ];

    let sa = session(port, Some(TRAINER_USER)).await;
    let sb = session(port, Some(TRAINER_USER)).await;
    // Both servers joined the router and are discovered.
    t(async {
        while discover(&sb, &KeySpace::default()).await.len() < 2 {
            for p in &mut servers {
                p.assert_running();
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    })
    .await;

    // Placement by load: B first (both empty → srv-1), then A (srv-1 holds B's envs → srv-2).
    let b = connect_least_loaded(&sb, "trainer-b").await;
    let mut req = CreateEnv::new("trainer-b");
    req.count = 1;
    let probe = t(b.create(req)).await.unwrap().env_ids; // B's placeholder: load 1 on its server
    let a = connect_least_loaded(&sa, "trainer-a").await;
    assert_ne!(
        a.server_id(),
        b.server_id(),
        "envs spread over both servers"
    );
    let infos = discover(&sa, &KeySpace::default()).await;
    assert_eq!(infos.iter().map(|i| i.load).sum::<u32>(), 1);

    // Run both trainers; A's server is killed after KILL_AT of A's steps.
    let (kill_tx, kill_rx) = oneshot::channel::<String>();
    let (killed_tx, killed_rx) = oneshot::channel::<()>();
    let ta = tokio::spawn(async move {
        let first = run(&a, 21, STEPS_A, 0.0, Some((KILL_AT, kill_tx, killed_rx))).await;
        (a, first)
    });
    let tb = tokio::spawn(async move {
        let r = run(&b, 31, STEPS_B, 1.3, None).await;
        (b, r)
    });
    let victim = t(kill_rx).await.unwrap();
    eprintln!("trainer B still running at the kill: {}", !tb.is_finished());
    let k = if victim == "srv-1" { 0 } else { 1 };
    servers[k].kill();
    killed_tx.send(()).unwrap();

    // A: a clear error, the server's liveliness token gone, then failover to the survivor.
    let (_a, (before, err)) = t(ta).await.unwrap();
    let err = err.expect("a request to the killed server fails");
    eprintln!("trainer A after the kill: {err}");
    assert!(
        matches!(err, ClientError::NoReply | ClientError::Timeout(_)),
        "unexpected error {err:?}"
    );
    assert!(before.len() >= (KILL_AT * ENVS) as usize);
    wait_token_gone(&sa, &victim).await;
    let survivors = discover(&sa, &KeySpace::default()).await;
    assert_eq!(survivors.len(), 1);
    assert_ne!(survivors[0].server_id, victim);
    let a2 = connect_least_loaded(&sa, "trainer-a").await;
    assert_ne!(a2.server_id(), victim);
    let (after, err) = run(&a2, 21, STEPS_A, 0.0, None).await;
    assert!(err.is_none(), "{err:?}");
    assert!(after.len() as u32 >= STEPS_A * ENVS);
    // The re-created envs behave like an undisturbed run of the same seeds and actions.
    let (again, err) = run(&a2, 21, STEPS_A, 0.0, None).await;
    assert!(err.is_none(), "{err:?}");
    assert_eq!(after, again);
    // Before the kill, A's envs followed the same trajectory too (same seeds, same actions).
    assert_eq!(before[..], after[..before.len()]);

    // B: never disturbed; its trajectory equals a solo run.
    let (b, (rb, err)) = t(tb).await.unwrap();
    assert!(err.is_none(), "trainer B was disturbed: {err:?}");
    assert_ne!(b.server_id(), victim);
    let (solo, err) = run(&b, 31, STEPS_B, 1.3, None).await;
    assert!(err.is_none(), "{err:?}");
    assert_eq!(rb, solo, "trainer B's envs differ from a solo run");
    t(b.close(&probe[0])).await.unwrap();

    rt.assert_running();
    servers[1 - k].assert_running();
}
