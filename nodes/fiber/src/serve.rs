//! The fibre node's loop: announce readiness, then per step publish the state at t_k,
//! wait for the flow samples of step k, and integrate to t_{k+1}.

use crate::config::{FiberNodeConfig, InitialVelocity};
use fiberflow_bus::{BusError, BusHandle, DropCounter, Inbox};
use fiberflow_fiber_model::metrics::metrics;
use fiberflow_fiber_model::{FibreError, FluidSample};
use fiberflow_messages::topics::Topics;
use fiberflow_messages::{
    encode, lifecycle, FiberGroupMetrics, FiberGroupState, FlowSamples, Heartbeat, RunAnnouncement,
    SCHEMA_VERSION,
};
use nalgebra::{Matrix3, Vector3};
use std::time::{Duration, Instant};

#[derive(Debug, thiserror::Error)]
pub enum FiberNodeError {
    #[error(transparent)]
    Model(#[from] FibreError),
    #[error(transparent)]
    Bus(#[from] BusError),
    #[error("{0}")]
    Protocol(String),
}

/// Runs one group to the end of the run; returns the drop counts.
pub fn serve(
    cfg: &FiberNodeConfig,
    bus: BusHandle,
    run_id: &str,
    box_plus: [f64; 3],
    timeout_s: f64,
) -> Result<DropCounter, FiberNodeError> {
    let t = Topics::new(run_id);
    let built = cfg.build(box_plus)?;
    let mut group = built.group;
    let layers = built.layers;
    let name = cfg.group.clone();
    let mut samples_in = Inbox::new(bus.subscribe(&t.flow_samples(&name))?);
    let mut ann_in = Inbox::new(bus.subscribe(&t.announce())?);
    let hb = |state: u8, step: u64, dropped: u64| -> Result<(), BusError> {
        bus.publish(
            &t.heartbeat(&name),
            &encode(&Heartbeat {
                schema_version: SCHEMA_VERSION,
                node: name.clone(),
                state,
                step,
                dropped,
            }),
        )
    };
    // readiness until the run is announced
    let deadline = Instant::now() + Duration::from_secs_f64(timeout_s);
    let ann = loop {
        if Instant::now() > deadline {
            return Err(FiberNodeError::Protocol(format!(
                "group {name}: no run announcement within {timeout_s:.0} s (is the flow node running?)"
            )));
        }
        hb(lifecycle::READY, 0, 0)?;
        if let Some((_, a)) = ann_in.recv::<RunAnnouncement>(Duration::from_millis(200)) {
            if a.groups.contains(&name) {
                break a;
            }
        }
    };
    let dt = ann.dt_plus;
    let publish_state =
        |group: &fiberflow_fiber_model::group::FibreGroup, step: u64| -> Result<(), BusError> {
            let mut st = FiberGroupState {
                schema_version: SCHEMA_VERSION,
                group: name.clone(),
                step,
                t_plus: step as f64 * dt,
                segments_per_fiber: Vec::with_capacity(group.fibres.len()),
                segment_length: Vec::new(),
                diameter: Vec::new(),
                density_ratio: Vec::new(),
                layer: layers.clone(),
                centre: Vec::with_capacity(3 * group.segment_count()),
                axis: Vec::with_capacity(3 * group.segment_count()),
                velocity: Vec::with_capacity(3 * group.segment_count()),
                angular_velocity: Vec::with_capacity(3 * group.segment_count()),
            };
            for f in &group.fibres {
                st.segments_per_fiber.push(f.len() as u32);
                st.segment_length.push(f.props[0].shape.length);
                st.diameter.push(f.props[0].shape.diameter);
                st.density_ratio.push(f.density);
                for s in &f.segments {
                    st.centre.extend_from_slice(s.r.as_slice());
                    st.axis.extend_from_slice(s.z.as_slice());
                    st.velocity.extend_from_slice(s.v.as_slice());
                    st.angular_velocity.extend_from_slice(s.w.as_slice());
                }
            }
            bus.publish(&t.fiber_state(&name), &encode(&st))
        };
    let publish_metrics =
        |group: &fiberflow_fiber_model::group::FibreGroup, step: u64| -> Result<(), BusError> {
            let ms: Vec<_> = group.fibres.iter().map(metrics).collect();
            let n = ms.len().max(1) as f64;
            let m = FiberGroupMetrics {
                schema_version: SCHEMA_VERSION,
                group: name.clone(),
                step,
                t_plus: step as f64 * dt,
                centre_of_mass: ms
                    .iter()
                    .flat_map(|m| m.centre_of_mass.iter().copied().collect::<Vec<_>>())
                    .collect(),
                z1: ms.iter().map(|m| m.z1).collect(),
                sigma2: ms.iter().map(|m| m.sigma2).collect(),
                end_to_end: ms.iter().map(|m| m.end_to_end).collect(),
                mean_abs_z1: ms.iter().map(|m| m.z1.abs()).sum::<f64>() / n,
                mean_sigma2: ms.iter().map(|m| m.sigma2).sum::<f64>() / n,
            };
            bus.publish(&t.fiber_metrics(&name), &encode(&m))
        };
    publish_state(&group, 0)?;
    publish_metrics(&group, 0)?;
    let step_timeout = Duration::from_secs_f64(timeout_s);
    for k in 0..ann.steps {
        let wait_from = Instant::now();
        let samples = loop {
            let left = step_timeout.saturating_sub(wait_from.elapsed());
            if left.is_zero() {
                hb(lifecycle::FAILED, k, samples_in.drops.total())?;
                return Err(FiberNodeError::Protocol(format!(
                    "group {name}: no flow samples for step {k} within {timeout_s:.0} s"
                )));
            }
            if let Some((_, s)) = samples_in.recv::<FlowSamples>(left) {
                if s.step == k && s.group == name {
                    break s;
                }
            }
        };
        let n = group.segment_count();
        if samples.velocity.len() != 3 * n || samples.velocity_gradient.len() != 9 * n {
            return Err(FiberNodeError::Protocol(format!(
                "group {name}: samples for {} points, group has {n} segments",
                samples.velocity.len() / 3
            )));
        }
        let fluid: Vec<FluidSample> = samples
            .velocity
            .chunks_exact(3)
            .zip(samples.velocity_gradient.chunks_exact(9))
            .map(|(v, g)| FluidSample {
                vel: Vector3::new(v[0], v[1], v[2]),
                grad: Matrix3::from_row_slice(g),
            })
            .collect();
        if k == 0 && cfg.initial_velocity == InitialVelocity::Fluid {
            group.set_velocity_to_fluid(&fluid)?;
        }
        group.step(&fluid, dt)?;
        publish_state(&group, k + 1)?;
        if (k + 1) % cfg.metrics_every == 0 || k + 1 == ann.steps {
            publish_metrics(&group, k + 1)?;
        }
    }
    hb(lifecycle::DONE, ann.steps, samples_in.drops.total())?;
    let mut drops = samples_in.drops.clone();
    for (k, v) in ann_in.drops.by_topic {
        *drops.by_topic.entry(k).or_insert(0) += v;
    }
    Ok(drops)
}
