//! Criterion benchmark of one full world step (cognition, risk, graph all on) for 1 AV + N
//! CR-SFM pedestrians at 0.25 pedestrians per square metre.

use criterion::{criterion_group, criterion_main, BatchSize, Criterion, Throughput};
use sim_core::world::StepScratch;
use sim_server::step_timing::{bench_world_threads, step_once_in};

fn world_step(c: &mut Criterion) {
    let mut group = c.benchmark_group("world_step");
    for n in [3usize, 10, 100, 1000, 10000] {
        if n >= 1000 {
            group.sample_size(10);
        }
        group.throughput(Throughput::Elements(n as u64));
        // Large scenes also on two threads (smaller ones never split).
        let threads: &[usize] = if n >= 1000 { &[1, 2] } else { &[1] };
        for &t in threads {
            let base = bench_world_threads(n, 0, t);
            let name = if t == 1 {
                format!("n={n}")
            } else {
                format!("n={n}/threads={t}")
            };
            // One scratch across the fresh clones, as a running world keeps its own.
            let mut scratch = StepScratch::new();
            group.bench_function(name, |b| {
                b.iter_batched_ref(
                    || base.clone(),
                    |w| step_once_in(w, &mut scratch),
                    BatchSize::LargeInput,
                )
            });
        }
    }
    group.finish();
}

criterion_group!(benches, world_step);
criterion_main!(benches);
