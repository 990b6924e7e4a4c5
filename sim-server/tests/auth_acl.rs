//! Contract: behind `sim-server router` with the shipped `deploy/router.json5` (user/password
//! authentication, access control), a session without credentials or with a wrong password
//! cannot be opened at all (zenoh refuses it during the handshake); a trainer with the trainer
//! credentials reaches a `sim-server serve` that joined the router as a client with the server
//! credentials (info, create, reset, step, `states` publications); and a trainer cannot act as
//! a server: its queryable and liveliness token under `{prefix}/server/**` are never seen by
//! other clients, while the same declarations by a session with the server credentials are.

mod common;
mod procs;

use std::time::Duration;

use procs::{
    free_port, router, serve, session, t, wait_server, Scratch, SERVER_USER, TRAINER_USER,
};
use protocol::{CreateEnv, KeySpace, Reset};
use sim_server::server::client::Client;
use zenoh::query::{ConsolidationMode, QueryTarget};
use zenoh::Session;

/// The payloads of every reply to a `get` on `key` within `timeout`.
async fn get_all(s: &Session, key: &str, timeout: Duration) -> Vec<Vec<u8>> {
    let replies = t(s
        .get(key)
        .target(QueryTarget::All)
        .consolidation(ConsolidationMode::None)
        .timeout(timeout))
    .await
    .unwrap();
    let mut out = Vec::new();
    while let Ok(Ok(r)) = tokio::time::timeout(timeout * 2, replies.recv_async()).await {
        if let Ok(sample) = r.result() {
            out.push(sample.payload().to_bytes().into_owned());
        }
    }
    out
}

/// The keys of the live liveliness tokens matching `key`.
async fn alive(s: &Session, key: &str) -> Vec<String> {
    let replies = t(s.liveliness().get(key).timeout(Duration::from_secs(2)))
        .await
        .unwrap();
    let mut out = Vec::new();
    while let Ok(Ok(r)) = tokio::time::timeout(Duration::from_secs(4), replies.recv_async()).await {
        if let Ok(sample) = r.result() {
            out.push(sample.key_expr().as_str().to_string());
        }
    }
    out.sort();
    out.dedup(); // a session sees its own token locally and through the router
    out
}

/// Declares in session `s` what server `name` declares: a queryable on
/// `sharedspace/server/{name}/info` (answering `name`) and the liveliness token
/// `sharedspace/server/{name}/alive`.
async fn declare_server(
    s: &Session,
    name: &'static str,
) -> (
    zenoh::query::Queryable<()>,
    zenoh::liveliness::LivelinessToken,
) {
    let queryable = t(s
        .declare_queryable(format!("sharedspace/server/{name}/info"))
        .callback(move |q| {
            tokio::spawn(async move {
                let _ = q.reply(q.key_expr().clone(), name).await;
            });
        }))
    .await
    .unwrap();
    let token = t(s
        .liveliness()
        .declare_token(format!("sharedspace/server/{name}/alive")))
    .await
    .unwrap();
    (queryable, token)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn auth_and_access_control() {
    let scratch = Scratch::new("auth-acl");
    let port = free_port();
    let mut rt = router(&scratch, port).await;
    let mut srv = serve(&scratch, port, "srv-acl", SERVER_USER);

    // --- Authentication: no credentials / a wrong password: the session does not open.
    let e = t(zenoh::open(procs::client_config(port, None)))
        .await
        .expect_err("a session without credentials must be refused");
    // zenoh reports the refused handshake as an unreachable endpoint.
    assert!(e.to_string().contains("Unable to connect"), "{e}");
    let e2 = t(zenoh::open(procs::client_config(
        port,
        Some((TRAINER_USER.0, "wrong-password")),
    )))
    .await
    .expect_err("a session with a wrong password must be refused");
    assert!(e2.to_string().contains("Unable to connect"), "{e2}");

    // --- A trainer with credentials uses the server through the router.
    let trainer = session(port, Some(TRAINER_USER)).await;
    let c = t(Client::new(
        trainer.clone(),
        KeySpace::default(),
        "srv-acl",
        "trainer-ok",
    ))
    .await
    .unwrap();
    wait_server(&c, &mut srv).await;
    let info = t(c.info()).await.unwrap();
    assert_eq!(info.server_id, "srv-acl");
    let env = t(c.create(CreateEnv::new("trainer-ok")))
        .await
        .unwrap()
        .env_ids
        .remove(0);
    // Publications reach the trainer through the router (its subscription is allowed): step
    // until the server's publication gate has seen the subscriber and a `states` sample arrives.
    let states = t(trainer.declare_subscriber(format!("sharedspace/env/{env}/states")))
        .await
        .unwrap();
    t(c.reset(&env, &Reset::default())).await.unwrap();
    let mut steps = 0;
    t(async {
        loop {
            let s = c.step(&env, &[[0.3, 0.0]]).await.unwrap();
            steps += 1;
            assert_eq!(s.step, steps);
            if tokio::time::timeout(Duration::from_millis(200), states.recv_async())
                .await
                .is_ok()
            {
                break;
            }
        }
    })
    .await;

    // --- Access control: a trainer declares a queryable and a liveliness token in the servers'
    // namespace; a session with the server credentials does the same on other keys.
    let evil = session(port, Some(TRAINER_USER)).await;
    // The declarations themselves are accepted locally; the router drops the trainer's.
    let _evil = declare_server(&evil, "evil").await;
    let good = session(port, Some(SERVER_USER)).await;
    let _good = declare_server(&good, "good").await;

    // The server-credential declarations (made after the trainer's) become visible ...
    t(async {
        while get_all(
            &c.session().clone(),
            "sharedspace/server/good/info",
            Duration::from_millis(500),
        )
        .await
        .is_empty()
        {
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    })
    .await;
    tokio::time::sleep(Duration::from_millis(300)).await;
    // ... the trainer's never do: no reply from its queryable, even to a wildcard query, and its
    // token is not among the live ones.
    let observer = session(port, Some(TRAINER_USER)).await;
    for s in [&trainer, &observer, &good] {
        assert!(
            get_all(s, "sharedspace/server/evil/info", Duration::from_secs(1))
                .await
                .is_empty(),
            "a trainer's queryable under sharedspace/server/** answered"
        );
        let all = get_all(s, "sharedspace/server/*/info", Duration::from_secs(1)).await;
        assert_eq!(
            all.len(),
            2,
            "the real server and `good` answer, not `evil`"
        );
        assert!(!all.iter().any(|p| p == b"evil"));
        assert_eq!(
            alive(s, "sharedspace/server/*/alive").await,
            vec![
                "sharedspace/server/good/alive".to_string(),
                "sharedspace/server/srv-acl/alive".to_string()
            ]
        );
    }
    // The trainer's own token is allowed (servers reap by it) and the env still steps.
    assert_eq!(
        alive(&observer, "sharedspace/trainer/trainer-ok").await,
        vec!["sharedspace/trainer/trainer-ok".to_string()]
    );
    let s = t(c.step(&env, &[[0.3, 0.0]])).await.unwrap();
    assert_eq!(s.step, steps + 1);
    t(c.close(&env)).await.unwrap();

    rt.assert_running();
    srv.assert_running();
    eprintln!("router log:\n{}", rt.log());
}
