//! The two-way feedback's cost per step (docs/two-way.md, "Cost"), two threads as on the
//! reference machine:
//! - `correct_and_advance_1e4_case1_fibers`: one `History::correct_and_advance` over 10^4
//!   case-1 fibres (7 segments of 3 wall units, random places and directions in the fine
//!   grid's channel, random forces), the memories carried from step to step as in a run;
//! - at paper size (300 such fibres in six pieces of 50 on the coarse 64³ grid, as the
//!   quick launch): spreading their forces on the grid (`spread_300_fibers`), the
//!   correction of the six pieces (`correct_300_fibers`), and the correction's weights
//!   computed once at start (`weights_coarse_grid`).

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use fiberflow_dns::Grid;
use fiberflow_flow::self_induced::{History, Widths};

const FIBERS: usize = 10_000;
const SEGMENTS: usize = 7;
const RE_TAU: f64 = 150.0;

/// `fibres` straight case-1 fibres at random places and directions in the channel of
/// grid `g`, with random forces: (centres, forces), wall units, 3 per segment.
fn fibers(fibers: usize, seed: u64) -> (Vec<f64>, Vec<f64>) {
    let pi = std::f64::consts::PI;
    let mut x = seed;
    let mut rnd = move || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        (x >> 11) as f64 / (1u64 << 53) as f64
    };
    let (mut centre, mut force) = (Vec::new(), Vec::new());
    for _ in 0..fibers {
        let c = [rnd() * 2.0 * pi, rnd() * 1.8 - 0.9, rnd() * pi].map(|v| v * RE_TAU);
        let p = [rnd() - 0.5, rnd() - 0.5, rnd() - 0.5];
        let n = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
        for s in 0..SEGMENTS {
            let along = 3.0 * (s as f64 - 3.0);
            centre.extend((0..3).map(|a| c[a] + along * p[a] / n));
            force.extend((0..3).map(|_| rnd() - 0.5));
        }
    }
    (centre, force)
}

fn bench(c: &mut Criterion) {
    let pi = std::f64::consts::PI;
    let g = Grid::new(192, 64, 64, 2.0 * pi, pi, RE_TAU, Some(0.33)).expect("grid");
    let widths = Widths::new(&g, RE_TAU);
    let (centre, force) = fibers(FIBERS, 0x0dd_5eed);
    let spf = vec![SEGMENTS as u32; FIBERS];
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .expect("pool");
    let mut history = History::default();
    let mut velocity = vec![0.0; centre.len()];
    let mut group = c.benchmark_group("self_induced");
    group.throughput(Throughput::Elements(FIBERS as u64));
    group.sample_size(20);
    group.bench_function("correct_and_advance_1e4_case1_fibers", |b| {
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

/// The quick launch's feedback: 300 fibres in six pieces of 50 on the coarse grid.
fn paper_size(c: &mut Criterion) {
    let pi = std::f64::consts::PI;
    let g = Grid::new(64, 64, 64, 2.0 * pi, pi, RE_TAU, Some(0.33)).expect("grid");
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .expect("pool");
    let widths = pool.install(|| Widths::new(&g, RE_TAU));
    let pieces: Vec<(Vec<f64>, Vec<f64>)> = (0..6).map(|p| fibers(50, 0x5eed + p)).collect();
    let spf = vec![SEGMENTS as u32; 50];
    let points: Vec<[f64; 3]> = pieces
        .iter()
        .flat_map(|(c, _)| {
            c.chunks_exact(3)
                .map(|c| [c[0], c[1], c[2]].map(|x| x / RE_TAU))
        })
        .collect();
    let forces: Vec<[f64; 3]> = pieces
        .iter()
        .flat_map(|(_, f)| {
            f.chunks_exact(3)
                .map(|f| [f[0], f[1], f[2]].map(|x| x * 1e-4))
        })
        .collect();
    let mut body = fiberflow_dns::spread::BodyForce::zeros(&g);
    let mut histories = vec![History::default(); 6];
    let mut velocity: Vec<Vec<f64>> = pieces.iter().map(|(c, _)| vec![0.0; c.len()]).collect();
    let mut group = c.benchmark_group("feedback_paper_size");
    group.throughput(Throughput::Elements(300));
    group.sample_size(20);
    group.bench_function("spread_300_fibers", |b| {
        b.iter(|| pool.install(|| fiberflow_dns::spread::spread(&g, &points, &forces, &mut body)))
    });
    group.bench_function("correct_300_fibers", |b| {
        b.iter(|| {
            pool.install(|| {
                use rayon::prelude::*;
                velocity
                    .par_iter_mut()
                    .zip(histories.par_iter_mut())
                    .zip(pieces.par_iter())
                    .for_each(|((v, h), (c, f))| {
                        v.iter_mut().for_each(|x| *x = 0.0);
                        h.correct_and_advance(&widths, RE_TAU, 0.25, &spf, c, f, v)
                    })
            })
        })
    });
    group.sample_size(10);
    group.bench_function("weights_coarse_grid", |b| {
        b.iter(|| pool.install(|| Widths::new(&g, RE_TAU)))
    });
    group.finish();
}

criterion_group!(benches, bench, paper_size);
criterion_main!(benches);
