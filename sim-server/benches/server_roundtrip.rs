//! Loopback round-trip benchmark of the zenoh server (`harness = false`):
//!
//! * single-env lockstep `Step` round trip, next to a bare zenoh get/reply with the same request
//!   and reply payload sizes;
//! * `BatchStep` throughput (env-steps/s) for K = 1, 16, 256, each next to a bare get/reply with
//!   the same payload sizes.
//!
//! Server, bare queryable and client run in this process, each in its own zenoh session, over
//! tcp/127.0.0.1 with multicast scouting off. Run with
//! `cargo bench -p sim-server --features bench --bench server_roundtrip` (optional argument:
//! seconds per measurement, default 2).

use std::time::{Duration, Instant};

use protocol::{encode, BatchStep, CreateEnv, F32Array, KeySpace, Reset, Step};
use serde_json::json;
use sim_server::server::client::{raw_get, Client};
use sim_server::server::{Server, ServerConfig};
use zenoh::Session;

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

async fn open(cfg: serde_json::Value) -> Session {
    zenoh::open(zenoh::Config::from_json5(&cfg.to_string()).unwrap())
        .await
        .unwrap()
}

fn peer(port: u16) -> serde_json::Value {
    json!({"mode": "peer", "listen": {"endpoints": [format!("tcp/127.0.0.1:{port}")]},
           "scouting": {"multicast": {"enabled": false}}})
}

async fn client_session(ports: &[u16]) -> Session {
    let eps: Vec<String> = ports.iter().map(|p| format!("tcp/127.0.0.1:{p}")).collect();
    open(json!({"mode": "client", "connect": {"endpoints": eps},
                "scouting": {"multicast": {"enabled": false}}}))
    .await
}

/// Mean seconds per call of `f` over at least `secs` (after a short warm-up).
async fn time_it<F, Fut>(secs: f64, mut f: F) -> (f64, u64)
where
    F: FnMut() -> Fut,
    Fut: std::future::Future<Output = ()>,
{
    for _ in 0..50 {
        f().await;
    }
    let t0 = Instant::now();
    let mut n = 0u64;
    while t0.elapsed().as_secs_f64() < secs {
        for _ in 0..20 {
            f().await;
        }
        n += 20;
    }
    (t0.elapsed().as_secs_f64() / n as f64, n)
}

/// [`time_it`] of the server's round trip: `payload` sent to `key` by client `c`.
async fn time_raw(c: &Client, key: &str, payload: &[u8], secs: f64) -> (f64, u64) {
    time_it(secs, || async move {
        c.raw(key, payload.to_vec()).await.unwrap();
    })
    .await
}

const T: Duration = Duration::from_secs(30);

/// Per thread name (numbered suffixes merged, e.g. `rx-0` and `rx-1` into `rx`): seconds on a
/// CPU and seconds runnable but waiting for one, summed over this process's threads.
fn threads_sched() -> std::collections::BTreeMap<String, (f64, f64)> {
    let mut out = std::collections::BTreeMap::new();
    let Ok(dir) = std::fs::read_dir("/proc/self/task") else {
        return out;
    };
    for t in dir.flatten() {
        let p = t.path();
        let (Ok(comm), Ok(stat)) = (
            std::fs::read_to_string(p.join("comm")),
            std::fs::read_to_string(p.join("schedstat")),
        ) else {
            continue;
        };
        let name = comm.trim().trim_end_matches(|c: char| c.is_ascii_digit());
        let name = name.trim_end_matches('-').to_string();
        let mut f = stat
            .split_whitespace()
            .map(|v| v.parse::<f64>().unwrap_or(0.0));
        let (run, wait) = (f.next().unwrap_or(0.0), f.next().unwrap_or(0.0));
        let e = out.entry(name).or_insert((0.0, 0.0));
        e.0 += run * 1e-9;
        e.1 += wait * 1e-9;
    }
    out
}

/// `after - before` of [`threads_sched`] per call, as "name on-CPU/waiting" in microseconds,
/// for threads that used at least 1 us per call.
fn threads_delta(
    before: &std::collections::BTreeMap<String, (f64, f64)>,
    after: &std::collections::BTreeMap<String, (f64, f64)>,
    calls: u64,
) -> String {
    let mut parts = Vec::new();
    for (name, a) in after {
        let b = before.get(name).copied().unwrap_or((0.0, 0.0));
        let (run, wait) = (
            (a.0 - b.0) / calls as f64 * 1e6,
            (a.1 - b.1) / calls as f64 * 1e6,
        );
        if run >= 1.0 {
            parts.push(format!("{name} {run:.0}/{wait:.0}"));
        }
    }
    parts.join(", ")
}

/// CPU seconds used so far by all threads of this process (`/proc/self/stat`, in clock ticks
/// of 10 ms: meaningful over a measurement of a second or more).
fn process_cpu() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the parenthesised command name; utime and stime are fields 14 and 15.
    let rest = &s[s.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

/// This thread's (time on a CPU, time runnable but waiting for one) so far, in seconds, from
/// Linux's `/proc/thread-self/schedstat`: tells a slower computation from one that waited.
fn thread_sched() -> Option<(f64, f64)> {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    let mut f = s.split_whitespace().map(|v| v.parse::<f64>().ok());
    Some((f.next()?? * 1e-9, f.next()?? * 1e-9))
}

fn main() {
    let secs: f64 = std::env::args()
        .skip(1)
        .find_map(|a| a.parse().ok())
        .unwrap_or(2.0);
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(bench(secs));
}

async fn bench(secs: f64) {
    let (p_server, p_bare) = (free_port(), free_port());
    let cfg = ServerConfig {
        server_id: Some("bench".into()),
        // BATCH_THREADS=N: the server's `batch_threads` (default 0: one per core).
        batch_threads: std::env::var("BATCH_THREADS")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(0),
        zenoh: peer(p_server),
        ..ServerConfig::default()
    };
    let server = Server::start(cfg).await.unwrap();

    // The bare get/reply: a queryable answering `reply_size` zero bytes (size taken from the
    // query's first 4 bytes, so one queryable serves every case), handled like the server's
    // queries (FIFO channel, a task per query).
    let bare = open(peer(p_bare)).await;
    let q = bare.declare_queryable("bench/bare").await.unwrap();
    tokio::spawn(async move {
        while let Ok(query) = q.recv_async().await {
            tokio::spawn(async move {
                let p = query
                    .payload()
                    .map(|p| p.to_bytes().into_owned())
                    .unwrap_or_default();
                let n = u32::from_le_bytes([p[0], p[1], p[2], p[3]]) as usize;
                let _ = query.reply("bench/bare", vec![0u8; n]).await;
            });
        }
    });

    // A zenoh client connects to one endpoint only: one client session per target.
    let session = client_session(&[p_server]).await;
    let bare_session = client_session(&[p_bare]).await;
    let c = Client::new(
        session.clone(),
        KeySpace::default(),
        "bench",
        "bench-client",
    )
    .await
    .unwrap();
    let t0 = Instant::now();
    while c.info().await.is_err()
        || raw_get(&bare_session, "bench/bare", vec![0; 8], T)
            .await
            .is_err()
    {
        assert!(t0.elapsed() < T, "server not reachable");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let bare_call = |req: usize, reply: usize| {
        let mut payload = vec![0u8; req.max(4)];
        payload[..4].copy_from_slice(&(reply as u32).to_le_bytes());
        let s = bare_session.clone();
        move || {
            let s = s.clone();
            let p = payload.clone();
            async move {
                let r = raw_get(&s, "bench/bare", p, T).await.unwrap();
                assert_eq!(r.len(), reply);
            }
        }
    };

    let date = std::process::Command::new("date")
        .arg("-u")
        .arg("+%Y-%m-%dT%H:%M:%SZ")
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
        .unwrap_or_default();
    println!("server_roundtrip benchmark, {date}, {secs} s per measurement, loopback tcp, hbs-paper pool");

    // --- single env
    let mut req = CreateEnv::new("bench-client");
    req.autoreset = true;
    let env = c.create(req).await.unwrap().env_ids.remove(0);
    c.reset(&env, &Reset::default()).await.unwrap();
    let step_req = encode(&Step::from_rows(&[[0.2, 0.01]]));
    let step_key = c.keys().env_step("bench", &env).unwrap();
    let reply_len = c.raw(&step_key, step_req.clone()).await.unwrap().len();
    let (t_srv, n_srv) = time_raw(&c, &step_key, &step_req, secs).await;
    let (t_bare, n_bare) = time_it(secs, bare_call(step_req.len(), reply_len)).await;
    println!(
        "single-env step: server {:.1} us/round trip ({n_srv} calls), bare zenoh get/reply {:.1} us ({n_bare} calls; request {} B, reply {} B), ratio {:.2}x",
        t_srv * 1e6,
        t_bare * 1e6,
        step_req.len(),
        reply_len,
        t_srv / t_bare
    );
    let mut rows = vec![
        json!({"case": "single", "server_us": t_srv * 1e6, "bare_us": t_bare * 1e6,
        "ratio": t_srv / t_bare, "request_bytes": step_req.len(), "reply_bytes": reply_len}),
    ];

    // --- batches
    for k in [1usize, 16, 256] {
        let mut req = CreateEnv::new("bench-client");
        req.autoreset = true;
        req.count = k as u32;
        req.seed = 1000 + k as u64;
        let ids = c.create(req).await.unwrap().env_ids;
        for id in &ids {
            c.reset(id, &Reset::default()).await.unwrap();
        }
        let vals: Vec<f32> = (0..k).flat_map(|i| [0.2 + 0.001 * i as f32, 0.0]).collect();
        let b = encode(&BatchStep {
            env_ids: ids.clone(),
            actions: F32Array::new(vec![k as u32, 1, 2], &vals).unwrap().into(),
        });
        let key = c.keys().batch_step("bench").unwrap();
        let reply_len = c.raw(&key, b.clone()).await.unwrap().len();
        let th0 = threads_sched();
        let (t_srv, n_srv) = time_raw(&c, &key, &b, secs).await;
        let th_srv = threads_delta(&th0, &threads_sched(), n_srv + 50);
        let th0 = threads_sched();
        let (t_bare, n_bare) = time_it(secs, bare_call(b.len(), reply_len)).await;
        let th_bare = threads_delta(&th0, &threads_sched(), n_bare + 50);
        // The same batch through the pure core alone (no zenoh): where the time goes.
        let core = server.core().clone();
        let s0 = thread_sched();
        let p0 = process_cpu();
        let (t_core, n_core) = time_it(secs.min(1.0), || {
            let core = core.clone();
            let p = b.clone();
            async move {
                let r = core.handle_batch(&p, &sim_server::server::env::Gates::NONE);
                assert!(r.reply.len() > 16);
            }
        })
        .await;
        // Per measured batch (the warm-up's 50 included in the count).
        let n = (n_core + 50) as f64;
        let sched = match (s0, thread_sched(), p0, process_cpu()) {
            (Some(a), Some(b), Some(p0), Some(p1)) => format!(
                " (on CPU {:.1} us, waiting for a CPU {:.1} us; all threads of the process {:.1} us CPU)",
                (b.0 - a.0) / n * 1e6,
                (b.1 - a.1) / n * 1e6,
                (p1 - p0) / n * 1e6
            ),
            _ => String::new(),
        };
        println!(
            "batch K={k:>3}: core alone (decode, step, observe, encode) {:.1} us/batch = {:.0} env-steps/s{sched}",
            t_core * 1e6,
            k as f64 / t_core
        );
        let rate = k as f64 / t_srv;
        println!(
            "batch K={k:>3}: server {:.1} us/batch = {:.0} env-steps/s ({n_srv} batches), bare zenoh {:.1} us ({n_bare} calls; request {} B, reply {} B), ratio {:.2}x",
            t_srv * 1e6,
            rate,
            t_bare * 1e6,
            b.len(),
            reply_len,
            t_srv / t_bare
        );
        println!("batch K={k:>3}: per call, us on CPU/waiting for one, by thread: server: {th_srv}; bare: {th_bare}");
        rows.push(
            json!({"case": format!("batch{k}"), "k": k, "server_us": t_srv * 1e6,
            "bare_us": t_bare * 1e6, "ratio": t_srv / t_bare, "env_steps_per_s": rate,
            "request_bytes": b.len(), "reply_bytes": reply_len}),
        );
        for id in &ids {
            c.close(id).await.unwrap();
        }
    }
    println!("{}", json!({"date": date, "results": rows}));
    drop(c);
    let _ = session.close().await;
    let _ = bare_session.close().await;
    server.stop().await;
    let _ = bare.close().await;
}
