//! A group's step allocates nothing once it has run (issue point "no allocation in the
//! step"): the working arrays live in the group between steps. Counted with an allocator
//! that counts, over groups stepped on the calling thread (the fibre node's path below
//! `PARALLEL_MIN_SEGMENTS`) in SIMD lanes and fibre by fibre, from decoded samples and
//! from the wire bytes a fibre node reads in place.

use fiberflow_fiber_model::fiber::Fiber;
use fiberflow_fiber_model::group::FiberGroup;
use fiberflow_fiber_model::step::Fluid;
use fiberflow_fiber_model::{DragModel, FluidSample, ModelParams};
use nalgebra::{Matrix3, Vector3};
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

/// The system allocator, counting allocations made while `COUNTING` is set.
struct Counting;

static COUNTING: AtomicBool = AtomicBool::new(false);
static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

// SAFETY: every call is passed on to the system allocator unchanged.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if COUNTING.load(Ordering::SeqCst) {
            ALLOCATIONS.fetch_add(1, Ordering::SeqCst);
        }
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if COUNTING.load(Ordering::SeqCst) {
            ALLOCATIONS.fetch_add(1, Ordering::SeqCst);
        }
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// 50 fibres of 7 segments (SIMD lanes) and, with `mixed`, one of 5 after them (its
/// block is stepped fibre by fibre), with inertial drag, gravity and bending.
fn group(mixed: bool) -> FiberGroup {
    let params = ModelParams {
        drag: DragModel {
            viscosity: 1.0,
            fluid_density: 1.0,
            drag_coefficient: 1.0,
        },
        gravity: Vector3::new(0.0, -0.01, 0.0),
        bending_stiffness: 1.0,
        twisting_stiffness: 0.0,
        tikhonov: 0.0,
        wall_half_height: Some(150.0),
    };
    let mut fibers: Vec<Fiber> = (0..50)
        .map(|i| {
            let a = i as f64 * 0.37;
            Fiber::straight(
                Vector3::new(i as f64, a.sin() * 100.0, 3.0 * i as f64),
                Vector3::new(a.cos(), 1.0, a.sin()),
                &[3.0; 7],
                &[0.232; 7],
                1150.0,
            )
            .expect("valid fibre")
        })
        .collect();
    if mixed {
        fibers.push(
            Fiber::straight(
                Vector3::new(7.0, 20.0, 9.0),
                Vector3::new(0.0, 1.0, 0.0),
                &[3.0; 5],
                &[0.232; 5],
                1150.0,
            )
            .expect("valid fibre"),
        );
    }
    FiberGroup::new(params, fibers)
}

fn samples(g: &FiberGroup) -> Vec<FluidSample> {
    g.segment_centres()
        .iter()
        .map(|r| FluidSample {
            vel: Vector3::new(0.1 * r.y + 10.0, 0.3, -0.2),
            grad: Matrix3::new(0.01, 0.1, 0.0, 0.0, -0.02, 0.03, 0.01, 0.0, 0.01),
        })
        .collect()
}

/// Allocations made by `f`.
fn allocations(f: impl FnOnce()) -> usize {
    ALLOCATIONS.store(0, Ordering::SeqCst);
    COUNTING.store(true, Ordering::SeqCst);
    f();
    COUNTING.store(false, Ordering::SeqCst);
    ALLOCATIONS.load(Ordering::SeqCst)
}

/// One test (the counter is global: a second test on another thread would count into
/// it). A fresh group's first step does allocate (its working arrays are sized), so the
/// zeros after it are not a counter that never moves.
#[test]
fn a_step_allocates_nothing_after_the_first() {
    let mut fresh = group(true);
    let fluid = samples(&fresh);
    assert!(
        allocations(|| {
            fresh.step(&fluid, 0.01).expect("step");
        }) > 0
    );
    for mixed in [false, true] {
        let mut g = group(mixed);
        let fluid = samples(&g);
        // the wire form: 3 velocity and 9 gradient values per segment, little endian
        let velocity: Vec<u8> = fluid
            .iter()
            .flat_map(|s| {
                s.vel
                    .iter()
                    .flat_map(|v| v.to_le_bytes())
                    .collect::<Vec<_>>()
            })
            .collect();
        let gradient: Vec<u8> = fluid
            .iter()
            .flat_map(|s| {
                s.grad
                    .transpose()
                    .iter()
                    .flat_map(|v| v.to_le_bytes())
                    .collect::<Vec<_>>()
            })
            .collect();
        let wire = || Fluid::Wire {
            velocity: &velocity,
            gradient: &gradient,
        };
        // the first step sizes the working arrays
        g.step(&fluid, 0.01).expect("step");
        g.step(wire(), 0.01).expect("step");
        let n = allocations(|| {
            for _ in 0..3 {
                g.step(&fluid, 0.01).expect("step");
                g.step(wire(), 0.01).expect("step");
            }
        });
        assert_eq!(n, 0, "allocations in six steps (mixed lengths: {mixed})");
    }
}
