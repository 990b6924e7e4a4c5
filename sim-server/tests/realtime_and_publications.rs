//! Contract: (1) an observer subscribed to `{p}/env/{id}/states`, `uncertainty`, `risk_graph`
//! and `events` receives decodable messages describing the env's states while a trainer steps it;
//! (2) a realtime env advances on its own every `dt / realtime_factor` after a reset, applies the
//! latest action published on `{p}/env/{id}/action/{agent}` (zero-order hold) and publishes each
//! `StepResult` on `{p}/env/{id}/result`; `Step` on it answers `wrong_mode`.

mod common;

use std::time::{Duration, Instant};

use common::{client, config, episode_over, free_port, one_env, session, start, t};
use protocol::{
    decode, encode, ActionMsg, CreateEnv, ErrorCode, EventsMsg, F32Array, Mode, Reset,
    RiskGraphMsg, StatesMsg, StepResult, UncertaintyMsg,
};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn observer_receives_states_uncertainty_and_risk_graph() {
    let server = start(config(free_port(), "srv-pub")).await;
    let c = client(&server, "trainer").await;
    let env = one_env(&c).await;
    let keys = c.keys().clone();

    let obs = session(server.port).await;
    let subscribe = |key| async { t(obs.declare_subscriber(key)).await.unwrap() };
    let states = subscribe(keys.env_states(&env).unwrap()).await;
    let unc = subscribe(keys.env_uncertainty(&env).unwrap()).await;
    let risk = subscribe(keys.env_risk_graph(&env).unwrap()).await;
    let events = subscribe(keys.env_events(&env).unwrap()).await;

    // Publications are best-effort and the server learns of the subscribers asynchronously:
    // keep stepping until messages arrive.
    t(c.reset(&env, &Reset::default())).await.unwrap();
    let (mut got_s, mut got_u, mut got_r, mut got_e) = (None, None, None, None);
    let t0 = Instant::now();
    while got_s.is_none() || got_u.is_none() || got_r.is_none() || got_e.is_none() {
        assert!(
            t0.elapsed() < Duration::from_secs(10),
            "no publications received"
        );
        let s = t(c.step(&env, &[[0.3, 0.0]])).await.unwrap();
        if episode_over(&s) {
            t(c.reset(&env, &Reset::default())).await.unwrap();
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
        while let Ok(Some(m)) = states.try_recv() {
            got_s = Some(decode::<StatesMsg>(&m.payload().to_bytes()).expect("StatesMsg"));
        }
        while let Ok(Some(m)) = unc.try_recv() {
            got_u =
                Some(decode::<UncertaintyMsg>(&m.payload().to_bytes()).expect("UncertaintyMsg"));
        }
        while let Ok(Some(m)) = risk.try_recv() {
            got_r = Some(decode::<RiskGraphMsg>(&m.payload().to_bytes()).expect("RiskGraphMsg"));
        }
        while let Ok(Some(m)) = events.try_recv() {
            got_e = Some(decode::<EventsMsg>(&m.payload().to_bytes()).expect("EventsMsg"));
        }
    }
    let s = got_s.unwrap();
    assert_eq!(s.env_id, env);
    let n = s.ids.len() as u32;
    assert!(n >= 1);
    assert_eq!(s.positions.shape(), &[n, 2]);
    assert_eq!(s.kinds.len(), s.ids.len());
    let u = got_u.unwrap();
    assert_eq!(u.src.len(), u.u.len());
    let r = got_r.unwrap();
    assert_eq!(r.a.len(), r.psi.len());
    assert!(r.psi.iter().all(|p| p > 0.0 && p <= 1.0));
    assert!(!got_e.unwrap().events.is_empty());
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn realtime_env_steps_on_the_wall_clock_with_held_actions() {
    let server = start(config(free_port(), "srv-rt")).await;
    let c = client(&server, "rt-trainer").await;
    let keys = c.keys().clone();
    let mut req = CreateEnv::new("x");
    req.mode = Mode::Realtime;
    req.realtime_factor = 10.0; // a step every 50 ms of wall clock
    let env = t(c.create(req)).await.unwrap().env_ids.remove(0);
    let results = t(c
        .session()
        .declare_subscriber(keys.env_result(&env).unwrap()))
    .await
    .unwrap();
    // Nothing happens before the reset.
    tokio::time::sleep(Duration::from_millis(200)).await;
    assert!(results.try_recv().unwrap().is_none());

    let e = t(c.step(&env, &[[0.0, 0.0]])).await.unwrap_err();
    assert_eq!(e.server().unwrap().code, ErrorCode::WrongMode);

    let r = t(c.reset(&env, &Reset::default())).await.unwrap();
    let ego = r.agents.iter().find(|a| a.external).unwrap().name.clone();
    let action_key = keys.env_action(&env, &ego).unwrap();
    let act = |a: f32, seq: u64| {
        encode(&ActionMsg {
            action: F32Array::new(vec![2], &[a, 0.0]).unwrap().into(),
            seq,
        })
    };
    // Full acceleration, then an older (ignored) and a malformed (dropped) message.
    t(c.session().put(action_key.as_str(), act(1.0, 5)))
        .await
        .unwrap();
    t(c.session().put(action_key.as_str(), act(-1.0, 4)))
        .await
        .unwrap();
    t(c.session().put(action_key.as_str(), vec![0xc1u8]))
        .await
        .unwrap();
    let t0 = Instant::now();
    let mut steps = Vec::new();
    let mut speeds_up = 0;
    while steps.len() < 6 {
        let m = t(results.recv_async()).await.unwrap();
        let s: StepResult = decode(&m.payload().to_bytes()).expect("StepResult");
        assert_eq!(s.env_id, env);
        // Progress toward the goal grows while accelerating (held action 1.0).
        if s.reward_terms.progress.get(&[0]).unwrap() > 0.0 {
            speeds_up += 1;
        }
        steps.push(s.step);
        if episode_over(&s) {
            break;
        }
    }
    let elapsed = t0.elapsed();
    assert!(steps.windows(2).all(|w| w[1] == w[0] + 1), "{steps:?}");
    // 6 ticks of 50 ms: 5 intervals after the first (whose phase is arbitrary), so >= 200 ms
    // minus the first tick's phase; allow scheduling jitter.
    assert!(elapsed >= Duration::from_millis(150), "{elapsed:?}");
    assert!(speeds_up >= 1);
    t(c.close(&env)).await.unwrap();
    server.stop().await;
}
