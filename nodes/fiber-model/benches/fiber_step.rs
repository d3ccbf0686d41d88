//! Fibre-step throughput for N = 7 with all hydrodynamics (viscous + inertial drag):
//! 1, 10³ and 10⁵ fibres, on one thread and on all threads; on one thread also one fibre
//! at a time (`one_thread_unbatched`, no SIMD batching), the reference for the batched step.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use fiberflow_fiber_model::fiber::Fiber;
use fiberflow_fiber_model::group::FiberGroup;
use fiberflow_fiber_model::{DragModel, FluidSample, ModelParams};
use nalgebra::{Matrix3, Vector3};

fn group(n: usize) -> (FiberGroup, Vec<FluidSample>) {
    let params = ModelParams {
        drag: DragModel {
            viscosity: 1.0,
            fluid_density: 1.0,
            drag_coefficient: 1.0,
        },
        gravity: Vector3::zeros(),
        bending_stiffness: 0.0,
        twisting_stiffness: 0.0,
        tikhonov: 0.0,
        wall_half_height: Some(150.0),
    };
    let fibers: Vec<Fiber> = (0..n)
        .map(|i| {
            let a = i as f64 * 0.37;
            Fiber::straight(
                Vector3::new(i as f64, (a.sin()) * 100.0, 3.0 * i as f64),
                Vector3::new(a.cos(), 1.0, a.sin()),
                &[3.0; 7],
                &[0.232; 7],
                1150.0,
            )
            .expect("valid fibre")
        })
        .collect();
    let g = FiberGroup::new(params, fibers);
    let fluid: Vec<FluidSample> = g
        .segment_centres()
        .iter()
        .map(|r| FluidSample {
            vel: Vector3::new(0.1 * r.y + 10.0, 0.3, -0.2),
            grad: Matrix3::new(0.01, 0.1, 0.0, 0.0, -0.02, 0.03, 0.01, 0.0, 0.01),
        })
        .collect();
    (g, fluid)
}

fn bench(c: &mut Criterion) {
    let mut grp = c.benchmark_group("fiber_step_n7");
    grp.sample_size(10);
    for n in [1usize, 1_000, 100_000] {
        let (mut g, fluid) = group(n);
        grp.throughput(Throughput::Elements(n as u64));
        grp.bench_with_input(BenchmarkId::new("one_thread", n), &n, |b, _| {
            b.iter(|| g.step_serial(&fluid, 0.01).expect("step"))
        });
        let (mut g, fluid) = group(n);
        grp.bench_with_input(BenchmarkId::new("one_thread_unbatched", n), &n, |b, _| {
            b.iter(|| g.step_serial_unbatched(&fluid, 0.01).expect("step"))
        });
        let (mut g, fluid) = group(n);
        grp.bench_with_input(BenchmarkId::new("all_threads", n), &n, |b, _| {
            b.iter(|| g.step(&fluid, 0.01).expect("step"))
        });
    }
    grp.finish();
}

/// What a fibre node reads out of its group every step, 10⁴ fibres of 7 segments (a
/// fibre node's share at 6 × 10⁴): per-fibre metrics and a state message's arrays, read
/// in the lane storage, beside the same through a copied-out `Segment` per segment (the
/// way before).
fn output(c: &mut Criterion) {
    use fiberflow_fiber_model::metrics::metrics_of;
    use rayon::prelude::*;
    let mut grp = c.benchmark_group("group_output_1e4");
    grp.sample_size(20);
    let (g, _) = group(10_000);
    grp.bench_function("metrics", |b| b.iter(|| g.metrics()));
    grp.bench_function("metrics_by_segments", |b| {
        b.iter(|| {
            (0..g.len())
                .into_par_iter()
                .map_init(Vec::new, |buf, k| {
                    buf.clear();
                    buf.extend(g.segments(k));
                    metrics_of(buf, g.props(k))
                })
                .collect::<Vec<_>>()
        })
    });
    let mut arrays: [Vec<f64>; 4] = Default::default();
    for full in [false, true] {
        let name = if full { "full_state" } else { "lean_state" };
        grp.bench_function(name, |b| {
            b.iter(|| {
                let [c, a, v, w] = &mut arrays;
                for x in [&mut *c, &mut *a, &mut *v, &mut *w] {
                    x.clear();
                }
                g.extend_state(full, c, a, v, w);
            })
        });
        grp.bench_function(format!("{name}_by_segments"), |b| {
            b.iter(|| {
                let [c, a, v, w] = &mut arrays;
                for x in [&mut *c, &mut *a, &mut *v, &mut *w] {
                    x.clear();
                }
                for k in 0..g.len() {
                    for s in g.segments(k) {
                        c.extend_from_slice(s.r.as_slice());
                        if full {
                            a.extend_from_slice(s.z.as_slice());
                            v.extend_from_slice(s.v.as_slice());
                            w.extend_from_slice(s.w.as_slice());
                        }
                    }
                }
            })
        });
    }
    grp.finish();
}

criterion_group!(benches, bench, output);
criterion_main!(benches);
