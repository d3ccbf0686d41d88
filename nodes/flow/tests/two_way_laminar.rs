//! Two-way coupling against an exact balance (docs/two-way.md): a uniform array of fibres
//! held fixed in laminar channel flow at a constant flow rate. At the steady state the
//! driving pressure gradient times the volume equals the wall shear force plus the fibres'
//! total drag. The forces travel the flow node's own path: fibre states carrying F^h,
//! gathered by `feedback::gather`, spread by the solver.

use fiberflow_dns::sample::Sampler;
use fiberflow_dns::{DnsConfig, Forcing, InitialField, Solver};
use fiberflow_fiber_model::hydro::{resistance_axisymmetric, DragModel, SegmentShape};
use fiberflow_flow::feedback::{gather, Feedback};
use fiberflow_messages::FiberGroupState;
use nalgebra::{Matrix3, Vector3};
use std::collections::BTreeMap;

const RE_TAU: f64 = 20.0;

#[test]
fn fixed_fiber_array_balances_driving_against_walls_and_drag() {
    let mut cfg = DnsConfig::with_cells(16, 32, 8);
    cfg.lx = 2.0;
    cfg.lz = 1.0;
    cfg.re_tau = RE_TAU;
    cfg.y1_plus = None;
    cfg.forcing = Forcing::FlowRate { bulk_velocity: 5.0 };
    cfg.init = InitialField::Laminar {
        centre_velocity: 7.5,
    };
    let mut s = Solver::new(cfg).unwrap();
    let sampler = Sampler::new(&s.grid);
    // 2 × 2 × 2 fibres of 3 segments (l+ = 3, d+ = 0.232), axes along x, held at rest
    let shape = SegmentShape::new(3.0, 0.232);
    let drag = DragModel {
        viscosity: 1.0,
        fluid_density: 1.0,
        drag_coefficient: 1.0,
    };
    let axis = Vector3::new(1.0, 0.0, 0.0);
    let mut centre = Vec::new();
    for (x, y, z) in [0.3, 1.3]
        .iter()
        .flat_map(|&x| [-0.5, 0.35].map(move |y| (x, y)))
        .flat_map(|(x, y)| [0.25, 0.75].map(move |z| (x, y, z)))
    {
        for i in 0..3 {
            // wall units
            centre.extend_from_slice(&[
                x * RE_TAU + 3.0 * (i as f64 - 1.0),
                y * RE_TAU,
                z * RE_TAU,
            ]);
        }
    }
    let n = centre.len() / 3;
    let mut state = FiberGroupState {
        group: "array".into(),
        segments_per_fiber: vec![3; n / 3],
        centre: centre.clone(),
        hydro_force: vec![0.0; 3 * n],
        ..Default::default()
    };
    let volume = s.grid.lx * 2.0 * s.grid.lz;
    let mut fb = Feedback::default();
    let mut last_forcing = f64::NAN;
    let mut steady = 0;
    let mut drag_x = 0.0;
    for step in 0..60_000 {
        // F^h = A (v − 0) at each segment, from the field at the start of the step
        drag_x = 0.0;
        for (c, f) in centre.chunks(3).zip(state.hydro_force.chunks_mut(3)) {
            let p = [c[0] / RE_TAU, c[1] / RE_TAU, c[2] / RE_TAU];
            let sm = sampler.sample(&s.grid, &s.vel, p);
            let v = Vector3::from(sm.vel);
            let v_perp = (v - axis * axis.dot(&v)).norm();
            let r = resistance_axisymmetric(&shape, &drag, &axis, &Matrix3::zeros(), v_perp);
            let fh = r.a.apply(&axis, &v);
            f.copy_from_slice(fh.as_slice());
            drag_x += fh.x;
        }
        let mut states = BTreeMap::new();
        states.insert(("array".to_string(), 0u32), state.clone());
        gather(&states, RE_TAU, &mut fb).unwrap();
        s.set_body_force(&fb.points, &fb.forces);
        let r = s.step().unwrap();
        if (r.forcing - last_forcing).abs() <= 1e-13 * r.forcing.abs() {
            steady += 1;
            if steady == 50 {
                eprintln!("steady after {step} steps");
                break;
            }
        } else {
            steady = 0;
        }
        last_forcing = r.forcing;
    }
    assert_eq!(steady, 50, "no steady state within 60000 steps");
    // outer units: driving F_p V, the walls' pull on the fluid (negative), the fibres' drag
    // (wall units / Re_τ²)
    let driving = last_forcing * volume;
    let walls = s.wall_gradients()[0];
    let drag_outer = drag_x / (RE_TAU * RE_TAU);
    let rel = (driving - (-walls + drag_outer)).abs() / driving;
    eprintln!(
        "driving {driving:.10e} = wall shear {:.10e} + drag {drag_outer:.10e}; relative residual {rel:.2e}",
        -walls
    );
    assert!(
        drag_outer > 0.2 * driving,
        "the fibres must carry a real share"
    );
    assert!(rel < 1e-8, "relative residual {rel:e}");
}
