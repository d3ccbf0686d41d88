//! The self-induced correction's cost per step (docs/two-way.md, "Cost"): one
//! `History::correct_and_advance` over 10^4 case-1 fibres (7 segments of 3 wall units, random
//! places and directions in the fine grid's channel, random forces), the memories carried
//! from step to step as in a run; two threads as on the reference machine.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use fiberflow_dns::Grid;
use fiberflow_flow::self_induced::{History, Widths};

const FIBRES: usize = 10_000;
const SEGMENTS: usize = 7;
const RE_TAU: f64 = 150.0;

fn bench(c: &mut Criterion) {
    let pi = std::f64::consts::PI;
    let g = Grid::new(192, 64, 64, 2.0 * pi, pi, RE_TAU, Some(0.33)).expect("grid");
    let widths = Widths::new(&g, RE_TAU);
    let mut x = 0x0dd_5eed_u64;
    let mut rnd = move || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        (x >> 11) as f64 / (1u64 << 53) as f64
    };
    let (mut centre, mut force) = (Vec::new(), Vec::new());
    for _ in 0..FIBRES {
        let c = [rnd() * 2.0 * pi, rnd() * 1.8 - 0.9, rnd() * pi].map(|v| v * RE_TAU);
        let p = [rnd() - 0.5, rnd() - 0.5, rnd() - 0.5];
        let n = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
        for s in 0..SEGMENTS {
            let along = 3.0 * (s as f64 - 3.0);
            centre.extend((0..3).map(|a| c[a] + along * p[a] / n));
            force.extend((0..3).map(|_| rnd() - 0.5));
        }
    }
    let spf = vec![SEGMENTS as u32; FIBRES];
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .expect("pool");
    let mut history = History::default();
    let mut velocity = vec![0.0; centre.len()];
    let mut group = c.benchmark_group("self_induced");
    group.throughput(Throughput::Elements(FIBRES as u64));
    group.sample_size(20);
    group.bench_function("correct_and_advance_1e4_case1_fibres", |b| {
        b.iter(|| {
            velocity.iter_mut().for_each(|v| *v = 0.0);
            pool.install(|| {
                history.correct_and_advance(
                    &widths,
                    RE_TAU,
                    0.2,
                    &spf,
                    &centre,
                    &force,
                    &mut velocity,
                )
            });
        })
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
