//! Flow-step throughput: cell-updates per second and wall seconds per viscous time unit.
//! Run with `cargo bench -p fiberflow-dns`; RAYON_NUM_THREADS selects the thread count.
//! `FIBERFLOW_BENCH_CKPT_<NX>=path/flow.ckpt` starts from a developed field (else the
//! initial perturbations are stepped a little first).

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use fiberflow_dns::{DnsConfig, InitialField, Solver};

fn solver(nx: usize) -> Solver {
    let mut cfg = DnsConfig::with_cells(nx, 64, 64);
    cfg.init = InitialField::Turbulent {
        amplitude: 0.25,
        seed: 1,
    };
    let mut s = match Solver::new(cfg) {
        Ok(s) => s,
        Err(e) => panic!("solver: {e}"),
    };
    match std::env::var(format!("FIBERFLOW_BENCH_CKPT_{nx}")) {
        Ok(p) => {
            if let Err(e) = s.read_checkpoint(std::path::Path::new(&p)) {
                panic!("checkpoint {p}: {e}");
            }
        }
        Err(_) => {
            for _ in 0..20 {
                if let Err(e) = s.step() {
                    panic!("warm-up: {e}");
                }
            }
        }
    }
    s
}

fn bench_step(c: &mut Criterion) {
    let mut group = c.benchmark_group("flow_step");
    group.sample_size(10);
    for (name, nx) in [("coarse_64x64x64", 64usize), ("fine_192x64x64", 192)] {
        let mut s = solver(nx);
        eprintln!(
            "{name}: dt+ = {:.4} at CFL {}",
            s.next_dt() * s.cfg.re_tau,
            s.cfg.cfl
        );
        group.throughput(Throughput::Elements(s.grid.cells() as u64));
        group.bench_function(name, |b| {
            b.iter(|| {
                if let Err(e) = s.step() {
                    panic!("step: {e}");
                }
            })
        });
        // the figure users plan with: wall seconds per viscous time unit, from a plain
        // timed loop at two Courant numbers on the same developed field
        for cfl in [1.2, 1.5] {
            let mut s = solver(nx);
            s.cfg.cfl = cfl;
            let n = 20;
            let t0 = std::time::Instant::now();
            let mut t_plus = 0.0;
            for _ in 0..n {
                match s.step() {
                    Ok(r) => t_plus += r.dt_plus,
                    Err(e) => panic!("step: {e}"),
                }
            }
            let secs = t0.elapsed().as_secs_f64();
            eprintln!(
                "{name}: Courant {cfl}: {:.1} ms per step, mean dt+ {:.3} -> {:.3} s per t+, \
                 {:.1} M cell-updates/s",
                1e3 * secs / n as f64,
                t_plus / n as f64,
                secs / t_plus,
                (s.grid.cells() * n) as f64 / secs / 1e6
            );
        }
    }
    group.finish();
}

/// What the flow node adds every `status_every_steps` steps beside the step: a statistics
/// sample of the field and the wall Re_tau.
fn bench_statistics(c: &mut Criterion) {
    let mut group = c.benchmark_group("statistics");
    group.sample_size(20);
    let s = solver(192);
    let mut stats = fiberflow_dns::stats::RunningStats::new(&s.grid);
    group.bench_function("add_fine_192x64x64", |b| {
        b.iter(|| stats.add(&s.grid, &s.vel, 0.0))
    });
    group.bench_function("wall_re_tau_fine_192x64x64", |b| {
        b.iter(|| fiberflow_dns::stats::wall_re_tau(&s.grid, &s.vel, s.cfg.re_tau))
    });
    group.finish();
    // the halo refresh the solver runs after every sub-step (its z-periodic plane copies
    // ran on the calling thread alone)
    let mut group = c.benchmark_group("halos");
    group.sample_size(50);
    let mut s = solver(192);
    let grid = s.grid.clone();
    group.bench_function("update_halos_fine_192x64x64", |b| {
        b.iter(|| s.vel.update_halos(&grid))
    });
    group.finish();
}

/// Two-way coupling's share of the field step at paper size: the coarse grid's step with
/// and without the body force of 300 seven-segment fibres (2100 points at random in the
/// channel), alternately in one group.
fn bench_body_force(c: &mut Criterion) {
    let mut group = c.benchmark_group("flow_step_two_way");
    group.sample_size(20);
    let mut rng = fiberflow_dns::init::SplitMix64::new(0x5eed);
    let mut rnd = move || 0.5 * (rng.symmetric() + 1.0);
    let pi = std::f64::consts::PI;
    let points: Vec<[f64; 3]> = (0..2100)
        .map(|_| [2.0 * pi * rnd(), 1.8 * rnd() - 0.9, pi * rnd()])
        .collect();
    let forces: Vec<[f64; 3]> = (0..2100)
        .map(|_| [rnd() - 0.5, rnd() - 0.5, rnd() - 0.5].map(|f| 1e-6 * f))
        .collect();
    let mut plain = solver(64);
    let mut laden = solver(64);
    laden.set_body_force(&points, &forces);
    for (name, s) in [
        ("coarse_one_way", &mut plain),
        ("coarse_body_force_300_fibers", &mut laden),
    ] {
        group.bench_function(name, |b| {
            b.iter(|| {
                if let Err(e) = s.step() {
                    panic!("step: {e}");
                }
            })
        });
    }
    group.bench_function("spread_300_fibers", |b| {
        b.iter(|| laden.set_body_force(&points, &forces))
    });
    // 10⁵ seven-segment fibres on the fine grid, listed fibre by fibre as the flow node
    // lists them (segments 3 wall units apart along a random direction)
    let mut rng = fiberflow_dns::init::SplitMix64::new(0xf1b);
    let mut rnd = move || 0.5 * (rng.symmetric() + 1.0);
    let mut points = Vec::with_capacity(700_000);
    for _ in 0..100_000 {
        let start = [2.0 * pi * rnd(), 1.8 * rnd() - 0.9, pi * rnd()];
        let dir = [rnd() - 0.5, rnd() - 0.5, rnd() - 0.5];
        let norm = dir.iter().map(|x| x * x).sum::<f64>().sqrt().max(1e-9);
        for i in 0..7 {
            let at = i as f64 * 3.0 / 150.0 / norm;
            let y = (start[1] + at * dir[1]).clamp(-0.99, 0.99);
            points.push([start[0] + at * dir[0], y, start[2] + at * dir[2]]);
        }
    }
    let forces: Vec<[f64; 3]> = (0..points.len())
        .map(|_| [rnd() - 0.5, rnd() - 0.5, rnd() - 0.5].map(|f| 1e-6 * f))
        .collect();
    let mut fine = solver(192);
    group.sample_size(10);
    group.bench_function("spread_1e5_fibers_fine", |b| {
        b.iter(|| fine.set_body_force(&points, &forces))
    });
    group.finish();
}

criterion_group!(benches, bench_step, bench_statistics, bench_body_force);
criterion_main!(benches);
