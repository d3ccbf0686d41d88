//! The flow node's own messages besides the samples: heartbeats, the viewers' flow
//! slices, the running profiles, and the wait for the recorder at the end of a run.

use crate::config::FlowNodeConfig;
use crate::error::FlowError;
use crate::run::RunInfo;
use fiberflow_bus::{BusHandle, Inbox, Outbox};
use fiberflow_dns::stats::{ProfileRow, Profiles};
use fiberflow_dns::Solver;
use fiberflow_messages::topics::Topics;
use fiberflow_messages::Lifecycle;
use fiberflow_messages::NodeRole;
use fiberflow_messages::{encode, FlowProfiles, FlowSlice, Heartbeat, SCHEMA_VERSION};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Says this node's lifecycle state on its heartbeat topic.
pub(crate) fn heartbeat(
    bus: &BusHandle,
    t: &Topics,
    state: Lifecycle,
    step: u64,
    dropped: u64,
) -> Result<(), FlowError> {
    let hb = Heartbeat {
        schema_version: SCHEMA_VERSION,
        node: "flow".into(),
        state,
        step,
        dropped,
    };
    bus.publish(&t.heartbeat("flow"), &encode(&hb))?;
    Ok(())
}

/// Waits until the recorder says it has this node's DONE (lifecycle FINISHING or DONE),
/// sending the DONE again after 1, 2, 4, … s: the run's end must not hang on one DONE the
/// transport lost while this process was exiting. Gives up after the step timeout (the
/// recorder then finishes on its own once the last states are in).
pub(crate) fn await_recorder_finishing(
    bus: &BusHandle,
    t: &Topics,
    hb_in: &mut Inbox,
    run: &RunInfo,
    dropped: u64,
) -> Result<(), FlowError> {
    let from = Instant::now();
    let mut resend_after = Duration::from_secs(1);
    let mut last_sent = Instant::now();
    while from.elapsed().as_secs_f64() < run.step_timeout_s {
        if let Some((_, hb)) = hb_in.recv::<Heartbeat>(Duration::from_millis(50)) {
            // FINISHING names the run's last step; DONE (file complete) carries step 0
            let finishing = (hb.state == Lifecycle::Finishing && hb.step == run.steps)
                || hb.state == Lifecycle::Done;
            if NodeRole::Recorder.is(&hb.node) && finishing {
                return Ok(());
            }
        }
        // other nodes' heartbeats arriving must not hold the resend back
        if last_sent.elapsed() >= resend_after {
            tracing::info!("no word from the recorder on this node's DONE: sending it again");
            heartbeat(bus, t, Lifecycle::Done, run.steps, dropped)?;
            last_sent = Instant::now();
            resend_after *= 2;
        }
    }
    tracing::warn!(
        waited_s = run.step_timeout_s,
        "the recorder never confirmed this node's DONE"
    );
    Ok(())
}

/// Publishes the viewers' flow slices of the field at step `k` (docs/architecture.md: u' at
/// `streaks_y_plus` and the x = 0 cross-section; two-way, the fibres' force on the fluid
/// in the streaks' plane).
pub(crate) fn publish_slices(
    out: &mut Outbox,
    t: &Topics,
    solver: &Solver,
    cfg: &FlowNodeConfig,
    k: u64,
) -> Result<(), FlowError> {
    use fiberflow_dns::slice;
    let (g, re) = (&solver.grid, solver.cfg.re_tau);
    let [streaks, cross, force] = fiberflow_messages::topics::FLOW_SLICE_NAMES;
    let mut planes = vec![
        (
            streaks,
            "u_fluct_plus",
            slice::streaks(g, &solver.vel, re, cfg.streaks_y_plus),
        ),
        (
            cross,
            "u_fluct_plus",
            slice::cross_section(g, &solver.vel, re),
        ),
    ];
    // two-way: the fibres' force on the fluid beside the streaks
    if let Some(f) = solver.body_force() {
        planes.push((
            force,
            fiberflow_messages::palette::FIBER_FORCE_QUANTITY,
            slice::fiber_force_plane(g, f, re, cfg.streaks_y_plus),
        ));
    }
    for (name, quantity, p) in planes {
        let msg = FlowSlice {
            schema_version: SCHEMA_VERSION,
            step: k,
            t_plus: k as f64 * cfg.dt_plus,
            name: name.into(),
            quantity: quantity.into(),
            origin: p.origin_plus.to_vec(),
            axis_u: p.axis_u.to_vec(),
            axis_v: p.axis_v.to_vec(),
            u_plus: p.u_plus,
            v_plus: p.v_plus,
            values: p.values,
        };
        out.send(t.flow_slice(name), Arc::new(encode(&msg)))?;
    }
    Ok(())
}

/// The running plane/time statistics as the FlowProfiles message of step `step`.
pub(crate) fn profiles_message(p: &Profiles, step: u64, t_plus: f64) -> FlowProfiles {
    let col = |f: fn(&ProfileRow) -> f64| p.rows.iter().map(f).collect::<Vec<_>>();
    FlowProfiles {
        schema_version: SCHEMA_VERSION,
        step,
        t_plus,
        samples: p.samples,
        t_plus_span: p.t_plus_span,
        re_tau: p.re_tau,
        bulk_velocity: p.bulk_velocity,
        y_plus: col(|r| r.y_plus),
        u_mean: col(|r| r.u_mean),
        u_rms: col(|r| r.u_rms),
        v_rms: col(|r| r.v_rms),
        w_rms: col(|r| r.w_rms),
        uv: col(|r| r.uv),
        omega_z_mean: col(|r| r.omega_z_mean),
        omega_x_rms: col(|r| r.omega_x_rms),
        omega_y_rms: col(|r| r.omega_y_rms),
        omega_z_rms: col(|r| r.omega_z_rms),
    }
}
