//! Flow-step throughput: cell-updates per second and wall seconds per viscous time unit.
//! Run with `cargo bench -p fiberflow-dns`; RAYON_NUM_THREADS selects the thread count.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use fiberflow_dns::{DnsConfig, InitialField, Solver};

fn bench_step(c: &mut Criterion) {
    let mut group = c.benchmark_group("flow_step");
    group.sample_size(10);
    for (name, nx) in [("coarse_64x64x64", 64usize), ("fine_192x64x64", 192)] {
        let mut cfg = DnsConfig::with_cells(nx, 64, 64);
        cfg.init = InitialField::Turbulent {
            amplitude: 0.25,
            seed: 1,
        };
        let mut s = match Solver::new(cfg) {
            Ok(s) => s,
            Err(e) => panic!("solver: {e}"),
        };
        // developed turbulence from a checkpoint when given (FIBERFLOW_BENCH_CKPT_<NX>),
        // else let the initial perturbations develop a little
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
    }
    group.finish();
}

criterion_group!(benches, bench_step);
criterion_main!(benches);
