//! Criterion benchmark of one full world step (cognition, risk, graph all on) for 1 AV + N
//! CR-SFM pedestrians at 0.25 pedestrians per square metre.

use criterion::{criterion_group, criterion_main, BatchSize, Criterion, Throughput};
use sim_server::step_timing::{bench_world, step_once};

fn world_step(c: &mut Criterion) {
    let mut group = c.benchmark_group("world_step");
    for n in [3usize, 10, 100, 1000, 10000] {
        if n >= 1000 {
            group.sample_size(10);
        }
        let base = bench_world(n, 0);
        group.throughput(Throughput::Elements(n as u64));
        group.bench_function(format!("n={n}"), |b| {
            b.iter_batched_ref(|| base.clone(), step_once, BatchSize::LargeInput)
        });
    }
    group.finish();
}

criterion_group!(benches, world_step);
criterion_main!(benches);
