//! One case-1 fibre settling under gravity along x in still fluid at the channel's centre,
//! two-way coupled through the flow node's own stages (`feedback::gather`, the solver's
//! body force, `self_induced::History`) in the flow node's order, beside the same fibre
//! one-way. Shared by `tests/settling.rs` and `examples/settling.rs`.

use fiberflow_dns::sample::Sampler;
use fiberflow_dns::{DnsConfig, Forcing, InitialField, Solver};
use fiberflow_fiber_model::cases::paper_diameter_plus;
use fiberflow_fiber_model::hydro::DragModel;
use fiberflow_fiber_model::step::{step, FluidSample, ModelParams};
use fiberflow_fiber_model::Fiber;
use fiberflow_flow::feedback::{gather, Feedback};
use fiberflow_flow::self_induced::{History, Widths};
use fiberflow_messages::FiberGroupState;
use nalgebra::{Matrix3, Vector3};
use std::collections::BTreeMap;

/// Coupling time step (t+).
pub const DT_PLUS: f64 = 0.2;

/// The channel at rest, held at no net flow, on the coarse (64³) or fine (192×64×64) grid,
/// with its sampler and self-induced weights; and Re_τ.
fn still_channel(fine: bool) -> (Solver, Sampler, Widths, f64) {
    let mut cfg = DnsConfig::with_cells(if fine { 192 } else { 64 }, 64, 64);
    cfg.dt_fixed_plus = Some(DT_PLUS);
    cfg.forcing = Forcing::FlowRate { bulk_velocity: 0.0 };
    cfg.init = InitialField::Rest;
    let re = cfg.re_tau;
    let s = Solver::new(cfg).unwrap();
    let sampler = Sampler::new(&s.grid);
    let widths = Widths::new(&s.grid, re);
    (s, sampler, widths, re)
}

/// (t+, mean x velocity one-way, two-way) every `every` steps up to `t_end` t+, on the
/// coarse (64³) or fine (192×64×64) grid, with or without the self-induced correction.
pub fn settle(
    fine: bool,
    correct: bool,
    t_end: f64,
    segments: usize,
    every: usize,
) -> Vec<[f64; 3]> {
    settle_in_field_steps(fine, correct, t_end, segments, every, 1)
}

/// [`settle`] with a coupling step of `field_steps` field steps of [`DT_PLUS`] each
/// (`flow.field_steps`): the fibres, the sampling, the spreading and the correction step
/// once per coupling step, the field `field_steps` times; `every` counts coupling steps.
pub fn settle_in_field_steps(
    fine: bool,
    correct: bool,
    t_end: f64,
    segments: usize,
    every: usize,
    field_steps: usize,
) -> Vec<[f64; 3]> {
    let dt_plus = DT_PLUS * field_steps as f64;
    let (mut s, sampler, widths, re) = still_channel(fine);
    let p = ModelParams {
        drag: DragModel {
            viscosity: 1.0,
            fluid_density: 1.0,
            drag_coefficient: 1.0,
        },
        gravity: Vector3::new(0.02, 0.0, 0.0),
        bending_stiffness: 0.0,
        twisting_stiffness: 0.0,
        tikhonov: 0.0,
        wall_half_height: Some(re),
    };
    let d = paper_diameter_plus();
    let make = || {
        Fiber::straight(
            Vector3::new(
                0.5 * s.grid.lx * re + 0.37,
                0.0,
                0.5 * s.grid.lz * re + 0.21,
            ),
            Vector3::new(0.0, 0.0, 1.0),
            &vec![3.0; segments],
            &vec![d; segments],
            1150.0,
        )
        .unwrap()
    };
    let (mut two, mut one) = (make(), make());
    let rest = vec![FluidSample::at_rest(); segments];
    let mut fb = Feedback::default();
    let mut history = History::default();
    let mean = |f: &Fiber| f.segments.iter().map(|s| s.v.x).sum::<f64>() / segments as f64;
    let steps = (t_end / dt_plus).round() as usize;
    let mut out = Vec::new();
    for k in 0..=steps {
        // state k: the forces of the last step act on the fluid's next step
        let mut st = FiberGroupState {
            group: "g".into(),
            segments_per_fiber: vec![segments as u32],
            ..Default::default()
        };
        for seg in &two.segments {
            st.centre.extend_from_slice(seg.r.as_slice());
            st.hydro_force.extend_from_slice(seg.f.as_slice());
        }
        let mut states = BTreeMap::new();
        states.insert(("g".to_string(), 0u32), st);
        gather(&states, re, &mut fb).unwrap();
        s.set_body_force(&fb.points, &fb.forces);
        let st = &states[&("g".to_string(), 0u32)];
        let mut vel = Vec::new();
        let mut grads = Vec::new();
        for c in st.centre.chunks(3) {
            let sm = sampler.sample(&s.grid, &s.vel, [c[0] / re, c[1] / re, c[2] / re]);
            vel.extend_from_slice(&sm.vel);
            grads.push(Matrix3::from_row_slice(&sm.grad) / re);
        }
        if correct {
            history.correct_and_advance(
                &widths,
                re,
                dt_plus,
                &st.segments_per_fiber,
                &st.centre,
                &st.hydro_force,
                &mut vel,
            );
        }
        if k % every == 0 {
            out.push([k as f64 * dt_plus, mean(&one), mean(&two)]);
        }
        if k == steps {
            break;
        }
        let fluid: Vec<FluidSample> = vel
            .chunks(3)
            .zip(&grads)
            .map(|(v, g)| FluidSample {
                vel: Vector3::new(v[0], v[1], v[2]),
                grad: *g,
            })
            .collect();
        step(&p, &mut two, &fluid, dt_plus).unwrap();
        step(&p, &mut one, &rest, dt_plus).unwrap();
        for _ in 0..field_steps {
            s.step().unwrap();
        }
    }
    out
}

/// A constant unit force along x held at one point of still fluid: (t+, the disturbance
/// the DNS shows there, the memories' estimate of it) every `every` steps. The memories are
/// fed the DNS's samples, as in the flow node.
pub fn probe(fine: bool, t_end: f64, every: usize) -> Vec<[f64; 3]> {
    let (mut s, sampler, widths, re) = still_channel(fine);
    let pt = [
        0.5 * s.grid.lx + 0.37 / re,
        0.0,
        0.5 * s.grid.lz + 0.21 / re,
    ];
    let centre = [pt[0] * re, pt[1] * re, pt[2] * re];
    // F^h on the "fibre" is −1 along x: the fluid receives +1
    let force = [-1.0, 0.0, 0.0];
    let mut history = History::default();
    let mut out = Vec::new();
    for k in 0..=((t_end / DT_PLUS).round() as usize) {
        let sampled = sampler.sample(&s.grid, &s.vel, pt).vel;
        let mut v = sampled;
        history.correct_and_advance(&widths, re, DT_PLUS, &[1], &centre, &force, &mut v);
        if k % every == 0 {
            out.push([k as f64 * DT_PLUS, sampled[0], sampled[0] - v[0]]);
        }
        s.set_body_force(&[pt], &[[1.0 / (re * re), 0.0, 0.0]]);
        s.step().unwrap();
    }
    out
}
