//! Focused timing of `ServerCore::handle_batch` (no zenoh): `core_batch [K] [iterations]`.

use std::time::Instant;

use protocol::{decode, encode, BatchStep, CreateEnv, EnvCreated, F32Array, KeySpace, Reply};
use sim_server::params_file::{ModelParams, ParamsDoc};
use sim_server::server::core::{Limits, ServerCore};
use sim_server::server::env::Gates;
use sim_server::server::pools::ServedPool;

fn main() {
    let args: Vec<usize> = std::env::args()
        .skip(1)
        .filter_map(|a| a.parse().ok())
        .collect();
    let k = args.first().copied().unwrap_or(256);
    let iters = args.get(1).copied().unwrap_or(200);
    let mut core = ServerCore::new(
        "bench".into(),
        KeySpace::default(),
        Limits::default(),
        vec![ServedPool::new(scenarios::embedded::default_pool())],
        // The parameters `sim-server serve` runs with by default (params/calibrated.json5).
        ModelParams::from_doc(&ParamsDoc::shipped()).expect("shipped parameters are valid"),
    );
    // CORE_BATCH_THREADS=N: step large batches on up to N threads (default: the server's).
    if let Some(n) = std::env::var("CORE_BATCH_THREADS")
        .ok()
        .and_then(|v| v.parse().ok())
    {
        core.set_batch_threads(n);
    }
    let mut req = CreateEnv::new("c");
    req.autoreset = true;
    req.count = k as u32;
    req.seed = 1000 + k as u64;
    let r = core.handle_create(&encode(&req), Instant::now());
    let ids = decode::<Reply<EnvCreated>>(&r.reply)
        .unwrap()
        .into_result()
        .unwrap()
        .env_ids;
    for id in &ids {
        core.handle_reset(id, &[], Gates::NONE);
    }
    let vals: Vec<f32> = (0..k).flat_map(|i| [0.2 + 0.001 * i as f32, 0.0]).collect();
    let b = encode(&BatchStep {
        env_ids: ids,
        actions: F32Array::new(vec![k as u32, 1, 2], &vals).unwrap().into(),
    });
    if let Some(path) = std::env::var_os("CORE_BATCH_DUMP") {
        // The replies of `iters` batches, concatenated (for comparing builds).
        let mut all = Vec::new();
        for _ in 0..iters {
            all.extend(core.handle_batch(&b, &Gates::NONE).reply);
        }
        std::fs::write(path, all).unwrap();
        return;
    }
    // CORE_BATCH_WARM_THREAD=N: N batches first on another thread, as when a server's runtime
    // workers stepped the envs before (their worlds then live in that thread's malloc arena).
    let warm: usize = std::env::var("CORE_BATCH_WARM_THREAD")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(0);
    let core = std::sync::Arc::new(core);
    if warm > 0 {
        let (core, b) = (core.clone(), b.clone());
        std::thread::spawn(move || {
            for _ in 0..warm {
                core.handle_batch(&b, &Gates::NONE);
            }
        })
        .join()
        .unwrap();
    }
    // CORE_BATCH_POLLUTE=BYTES: between batches, write and read a buffer of that size (untimed),
    // as a server's network threads move each reply through several copies between two batches:
    // the envs' state is then no longer in the nearer caches when the next batch starts.
    let pollute: usize = std::env::var("CORE_BATCH_POLLUTE")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(0);
    let measure = move || {
        let mut junk = vec![0u8; pollute];
        let mut spoil = |round: usize| {
            if pollute > 0 {
                junk.fill(round as u8);
                std::hint::black_box(junk.iter().map(|&x| x as u64).sum::<u64>());
            }
        };
        for r in 0..20 {
            core.handle_batch(&b, &Gates::NONE);
            spoil(r);
        }
        let mut timed = std::time::Duration::ZERO;
        let mut len = 0;
        for r in 0..iters {
            let t0 = Instant::now();
            len += core.handle_batch(&b, &Gates::NONE).reply.len();
            timed += t0.elapsed();
            spoil(r);
        }
        (timed.as_secs_f64() / iters as f64, len)
    };
    // CORE_BATCH_THREAD=1: measured on a spawned thread (as on a tokio worker).
    let (dt, len) = if std::env::var_os("CORE_BATCH_THREAD").is_some() {
        std::thread::spawn(measure).join().unwrap()
    } else {
        measure()
    };
    println!(
        "K={k}: {:.1} us/batch, {:.2} us/env-step, reply {} B",
        dt * 1e6,
        dt * 1e6 / k as f64,
        len / iters
    );
}
