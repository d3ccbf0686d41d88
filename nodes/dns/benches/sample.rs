//! Sampling throughput (the flow node's per-step work for the fibres): velocity and
//! gradient at 10^5 points spread over the fine grid, trilinear and tricubic, one thread;
//! in random order and ordered by grid cell.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use fiberflow_dns::sample::{Interpolation, Sampler};
use fiberflow_dns::{DnsConfig, InitialField, Solver};

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
    // points in outer units, spread like fibre segments (7 close together per fibre)
    let n = 100_000;
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
                b.iter(|| {
                    let mut acc = 0.0;
                    for q in p.iter() {
                        acc += smp.sample(g, &s.vel, *q).grad[4];
                    }
                    acc
                })
            });
        }
    }
    group.finish();
}

criterion_group!(benches, bench_sample);
criterion_main!(benches);
