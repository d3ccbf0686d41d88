//! Sampling throughput (the flow node's per-step work for the fibres): velocity and
//! gradient at points spread over the fine grid, one thread. 10^5 points, trilinear and
//! tricubic, in random order and ordered by grid cell; then 4.2 × 10^5 points ordered by
//! cell (the 7 × 6 × 10^4 segment centres of the 6 × 10^4-fibre benchmark), sampled
//! directly and from the per-step tables (filled once per step, two threads), one point
//! and four points at a time (`Tables::sample4`), and as many samples at one point (all
//! cache hits: the arithmetic alone).

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use fiberflow_dns::sample::{Interpolation, Sampler, Tables, LANES};
use fiberflow_dns::{DnsConfig, Grid, InitialField, Solver};

/// `n` points in outer units, spread like fibre segments (7 close together per fibre);
/// in random order and sorted by cell (z plane, y row, x).
fn points(g: &Grid, n: usize) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
    let mut x = 0x1234_5678_9abc_def0u64;
    let mut rnd = || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        (x >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut pts = Vec::with_capacity(n);
    while pts.len() < n {
        let c = [rnd() * g.lx, rnd() * 1.8 - 0.9, rnd() * g.lz];
        for k in 0..7 {
            pts.push([c[0] + 0.02 * k as f64, c[1], c[2]]);
        }
    }
    pts.truncate(n);
    let mut sorted = pts.clone();
    sorted.sort_by(|a, b| {
        let key = |p: &[f64; 3]| {
            (
                (p[2] / g.dz) as u64,
                ((p[1] + 1.0) * 32.0) as u64,
                (p[0] / g.dx) as u64,
            )
        };
        key(a).cmp(&key(b))
    });
    (pts, sorted)
}

fn sum_direct(smp: &Sampler, s: &Solver, p: &[[f64; 3]]) -> f64 {
    p.iter()
        .map(|q| smp.sample(&s.grid, &s.vel, *q).grad[4])
        .sum()
}

fn sum_tables(t: &Tables, smp: &Sampler, s: &Solver, p: &[[f64; 3]]) -> f64 {
    p.iter().map(|q| t.sample(smp, &s.grid, *q).grad[4]).sum()
}

fn sum_tables4(t: &Tables, smp: &Sampler, s: &Solver, p: &[[f64; 3]]) -> f64 {
    p.chunks_exact(LANES)
        .map(|q| {
            let four = t.sample4(smp, &s.grid, std::array::from_fn(|l| q[l]));
            four.iter().map(|x| x.grad[4]).sum::<f64>()
        })
        .sum()
}

fn bench_sample(c: &mut Criterion) {
    let mut cfg = DnsConfig::with_cells(192, 64, 64);
    cfg.init = InitialField::Turbulent {
        amplitude: 0.25,
        seed: 1,
    };
    let s = match Solver::new(cfg) {
        Ok(s) => s,
        Err(e) => panic!("solver: {e}"),
    };
    let g = &s.grid;
    let n = 100_000;
    let (pts, sorted) = points(g, n);
    let mut group = c.benchmark_group("sample_1e5_points");
    group.sample_size(10);
    group.throughput(Throughput::Elements(n as u64));
    for (name, scheme) in [
        ("trilinear", Interpolation::Trilinear),
        ("tricubic", Interpolation::Tricubic),
    ] {
        let smp = Sampler::with_scheme(g, scheme);
        for (order, p) in [("random", &pts), ("by_cell", &sorted)] {
            group.bench_function(format!("{name}/{order}"), |b| {
                b.iter(|| sum_direct(&smp, &s, p))
            });
        }
    }
    group.finish();

    let n = 420_000;
    let (_, sorted) = points(g, n);
    let smp = Sampler::new(g);
    let mut t = Tables::new();
    let mut group = c.benchmark_group("sample_4e5_points_by_cell");
    group.sample_size(10);
    group.bench_function("tables_fill", |b| b.iter(|| t.fill(&smp, g, &s.vel)));
    // filled here too, so that a filtered run that skips the fill has tables
    t.fill(&smp, g, &s.vel);
    group.throughput(Throughput::Elements(n as u64));
    group.bench_function("direct", |b| b.iter(|| sum_direct(&smp, &s, &sorted)));
    group.bench_function("tables", |b| b.iter(|| sum_tables(&t, &smp, &s, &sorted)));
    group.bench_function("tables_four_at_once", |b| {
        b.iter(|| sum_tables4(&t, &smp, &s, &sorted))
    });
    // the same number of samples all at one point: every read a cache hit, so what is
    // left is the arithmetic
    let one: Vec<[f64; 3]> = vec![sorted[1000]; n];
    group.bench_function("direct_one_point", |b| {
        b.iter(|| sum_direct(&smp, &s, &one))
    });
    group.bench_function("tables_one_point", |b| {
        b.iter(|| sum_tables(&t, &smp, &s, &one))
    });
    group.bench_function("tables_four_at_once_one_point", |b| {
        b.iter(|| sum_tables4(&t, &smp, &s, &one))
    });
    group.finish();
}

criterion_group!(benches, bench_sample);
criterion_main!(benches);
