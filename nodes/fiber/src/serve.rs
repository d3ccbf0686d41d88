//! The fibre node's loop: announce readiness, then per step publish the state at t_k,
//! wait for the flow samples of step k, and integrate to t_{k+1}.

use crate::config::{FiberNodeConfig, InitialVelocity};
use fiberflow_bus::{BusError, BusHandle, DropCounter, Encode, Inbox};
use fiberflow_fiber_model::checkpoint::{CheckpointError, GroupSnapshot};
use fiberflow_fiber_model::step::Fluid;
use fiberflow_fiber_model::FibreError;
use fiberflow_messages::checkpoints;
use fiberflow_messages::topics::Topics;
use fiberflow_messages::{
    encode, lifecycle, FiberGroupMetrics, FiberGroupState, Heartbeat, RunAnnouncement, SamplesView,
    SCHEMA_VERSION,
};
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// The shortest wait for samples after which the node sends its state again (a message
/// lost in transit would otherwise stall the lockstep until the step timeout).
const RESEND_AFTER_MIN: Duration = Duration::from_secs(5);

#[derive(Debug, thiserror::Error)]
pub enum FiberNodeError {
    #[error(transparent)]
    Model(#[from] FibreError),
    #[error(transparent)]
    Bus(#[from] BusError),
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    #[error("{0}")]
    Protocol(String),
}

/// Where a group starts, where it saves coupled checkpoints, which run it belongs to, and
/// at which steps its state goes out complete.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Checkpointing {
    /// First coupling step: 0, or the step of the checkpoint the run resumes from.
    pub start_step: u64,
    /// The checkpoint folder to resume from (its step is `start_step`).
    pub resume_dir: Option<PathBuf>,
    /// Save every this many steps (0 = never) under `root`.
    pub every: u64,
    pub root: Option<PathBuf>,
    /// SHA-256 of the launch configuration: announcements with another digest are dropped
    /// (empty = accept any).
    pub config_digest: String,
    /// Complete states every this many steps and at the last (the recorder's
    /// `states_every`; 0 and 1 = every step); lean states (centres only) at the others.
    pub full_states_every: u64,
}

/// Runs shard `shard` of a group (0 for an unsharded group) to the end of the run;
/// returns the drop counts.
pub fn serve(
    cfg: &FiberNodeConfig,
    shard: u32,
    bus: BusHandle,
    run_id: &str,
    box_plus: [f64; 3],
    timeout_s: f64,
    ck: &Checkpointing,
) -> Result<DropCounter, FiberNodeError> {
    let t = Topics::new(run_id);
    let piece = cfg
        .pieces(box_plus)?
        .into_iter()
        .nth(shard as usize)
        .ok_or_else(|| {
            FiberNodeError::Protocol(format!(
                "group {} has {} shards, no shard {shard}",
                cfg.group, cfg.shards
            ))
        })?;
    // every shard builds the whole group and keeps its slice: the same fibres, bit for
    // bit, whatever the shard count
    let built = cfg
        .build(box_plus)?
        .slice(piece.first_fiber as usize, piece.fibers as usize);
    let node = piece.node();
    let mut group = built.group;
    if let Some(dir) = &ck.resume_dir {
        let path = checkpoints::piece(dir, &node);
        let snap = GroupSnapshot::read(&path)?;
        if snap.step != ck.start_step {
            return Err(FiberNodeError::Protocol(format!(
                "{} holds step {}, the run resumes at step {}",
                path.display(),
                snap.step,
                ck.start_step
            )));
        }
        snap.restore(&mut group).map_err(|e| {
            FiberNodeError::Protocol(format!(
                "{} does not fit group {}: {e}",
                path.display(),
                cfg.group
            ))
        })?;
        tracing::info!(
            step = ck.start_step,
            "group restored from a coupled checkpoint"
        );
    }
    let layers = built.layers;
    let name = cfg.group.clone();
    let mut samples_in = Inbox::new(bus.subscribe(&piece.samples_topic(&t))?);
    let mut ann_in = Inbox::new(bus.subscribe(&t.announce())?);
    let hb = |state: u8, step: u64, dropped: u64| -> Result<(), BusError> {
        bus.publish(
            &t.heartbeat(&node),
            &encode(&Heartbeat {
                schema_version: SCHEMA_VERSION,
                node: node.clone(),
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
                "node {node}: no run announcement within {timeout_s:.0} s (is the flow node running?)"
            )));
        }
        hb(lifecycle::READY, 0, 0)?;
        if let Some((topic, a)) = ann_in.recv::<RunAnnouncement>(Duration::from_millis(200)) {
            if a.run_id != run_id
                || (!ck.config_digest.is_empty() && a.config_digest != ck.config_digest)
            {
                ann_in
                    .drops
                    .drop_one(&topic, "announcement of another run or configuration");
            } else if a.groups.contains(&name) {
                break a;
            }
        }
    };
    let dt = ann.dt_plus;
    // the state message is kept and refilled every step: its per-fibre arrays are set once
    // and the segment arrays (MBs per step at scale) keep their allocations
    let mut state_msg = Encode(FiberGroupState {
        schema_version: SCHEMA_VERSION,
        group: name.clone(),
        step: 0,
        t_plus: 0.0,
        first_fiber: piece.first_fiber,
        group_fibers: piece.group_fibers,
        segments_per_fiber: (0..group.len())
            .map(|k| group.fibre_len(k) as u32)
            .collect(),
        segment_length: (0..group.len())
            .map(|k| group.props(k).first().map_or(0.0, |p| p.shape.length))
            .collect(),
        diameter: (0..group.len())
            .map(|k| group.props(k).first().map_or(0.0, |p| p.shape.diameter))
            .collect(),
        density_ratio: (0..group.len()).map(|k| group.density(k)).collect(),
        layer: layers.clone(),
        centre: Vec::new(),
        axis: Vec::new(),
        velocity: Vec::new(),
        angular_velocity: Vec::new(),
    });
    let state_topic = t.fiber_state(&name);
    let mut publish_state =
        |group: &fiberflow_fiber_model::group::FibreGroup, step: u64| -> Result<(), BusError> {
            let full = ck.full_states_every <= 1
                || step.is_multiple_of(ck.full_states_every)
                || step == ann.steps;
            let st = &mut state_msg.0;
            st.step = step;
            st.t_plus = step as f64 * dt;
            st.centre.clear();
            st.axis.clear();
            st.velocity.clear();
            st.angular_velocity.clear();
            group.extend_state(
                full,
                &mut st.centre,
                &mut st.axis,
                &mut st.velocity,
                &mut st.angular_velocity,
            );
            bus.publish_message(&state_topic, &state_msg)
        };
    let publish_metrics =
        |group: &fiberflow_fiber_model::group::FibreGroup, step: u64| -> Result<(), BusError> {
            let ms = group.metrics();
            let n = ms.len().max(1) as f64;
            let m = FiberGroupMetrics {
                schema_version: SCHEMA_VERSION,
                group: name.clone(),
                step,
                t_plus: step as f64 * dt,
                first_fiber: piece.first_fiber,
                group_fibers: piece.group_fibers,
                centre_of_mass: ms
                    .iter()
                    .flat_map(|m| m.centre_of_mass.iter().copied())
                    .collect(),
                z1: ms.iter().map(|m| m.z1).collect(),
                sigma2: ms.iter().map(|m| m.sigma2).collect(),
                end_to_end: ms.iter().map(|m| m.end_to_end).collect(),
                mean_abs_z1: ms.iter().map(|m| m.z1.abs()).sum::<f64>() / n,
                mean_sigma2: ms.iter().map(|m| m.sigma2).sum::<f64>() / n,
            };
            bus.publish_message(&t.fiber_metrics(&name), &Encode(m))
        };
    let start = ck.start_step;
    publish_state(&group, start)?;
    if start == 0 || start.is_multiple_of(cfg.metrics_every) {
        publish_metrics(&group, start)?;
    }
    let step_timeout = Duration::from_secs_f64(timeout_s);
    // wall seconds: waiting for and decoding samples, fibre step, encoding and publishing
    let mut timing = (0.0, 0.0, 0.0);
    let cpu_from = fiberflow_bus::usage::process_cpu_s();
    // the longest wait for samples so far that needed no resend: a wait three times as
    // long (at least RESEND_AFTER_MIN, at most a quarter of the step timeout, so that
    // several resends fit in it) means a message was probably lost
    let mut longest_wait = Duration::ZERO;
    let resend_cap = (step_timeout / 4).max(RESEND_AFTER_MIN);
    for k in start..ann.steps {
        let wait_from = Instant::now();
        let mut resent = false;
        let mut resend_after = (3 * longest_wait).clamp(RESEND_AFTER_MIN, resend_cap);
        let mut resend_at = wait_from + resend_after;
        // the wait ends with the samples checked (checking counts as the fibre step); the
        // step reads them where they arrived (a transport's shared memory), not copied
        let (checking, samples) = loop {
            let left = step_timeout.saturating_sub(wait_from.elapsed());
            if left.is_zero() {
                hb(lifecycle::FAILED, k, samples_in.drops.total())?;
                return Err(FiberNodeError::Protocol(format!(
                    "node {node}: no flow samples for step {k} within {timeout_s:.0} s"
                )));
            }
            let now = Instant::now();
            if now >= resend_at {
                // our state or the samples were lost in transit: send the state again and
                // say we wait (the flow node resends samples it already served)
                tracing::info!(
                    step = k,
                    waited_s = format!("{:.1}", wait_from.elapsed().as_secs_f64()),
                    "no samples yet: sending the state again"
                );
                publish_state(&group, k)?;
                hb(lifecycle::WAITING, k, samples_in.drops.total())?;
                resent = true;
                resend_after = (2 * resend_after).min(resend_cap);
                resend_at = now + resend_after;
            }
            let wait = left.min(resend_at.saturating_duration_since(now));
            let Some((topic, bytes)) = samples_in.recv_raw(wait) else {
                continue;
            };
            let view = match SamplesView::read(&bytes) {
                Ok(v) => v,
                Err(e) => {
                    samples_in.drops.drop_one(&topic, &e.to_string());
                    continue;
                }
            };
            let n = group.segment_count();
            let h = &view.header;
            // the values' finiteness is checked while they are read, below
            if let Err(why) = view.check_shape() {
                samples_in
                    .drops
                    .drop_one(&topic, &format!("inconsistent: {why}"));
            } else if h.group != name || h.first_fiber != piece.first_fiber {
                samples_in
                    .drops
                    .drop_one(&topic, "samples for another group or shard");
            } else if h.step != k {
                samples_in.drops.drop_one(&topic, "samples of another step");
            } else if view.len() != n {
                samples_in
                    .drops
                    .drop_one(&topic, "samples for another number of segments");
            } else {
                let t0 = Instant::now();
                if view.values_finite() {
                    break (t0.elapsed(), bytes);
                }
                let why = view.check().err().unwrap_or_default();
                samples_in
                    .drops
                    .drop_one(&topic, &format!("inconsistent: {why}"));
            }
        };
        let (mut waited_s, mut stepped_s, mut published_s) = timing;
        // a wait that ended only after a resend says how long a loss took to repair, not
        // how long a healthy step takes: it must not stretch the next resend deadline
        let waited = wait_from.elapsed().saturating_sub(checking);
        if !resent {
            longest_wait = longest_wait.max(waited);
        }
        waited_s += waited.as_secs_f64();
        stepped_s += checking.as_secs_f64();
        let t0 = Instant::now();
        // read again: the view borrowed the payload inside the loop (read and checked
        // there; only the header is parsed here)
        let view = SamplesView::read(&samples)
            .map_err(|e| FiberNodeError::Protocol(format!("samples checked a moment ago: {e}")))?;
        let (velocity, gradient) = view.arrays();
        let fluid = Fluid::Wire { velocity, gradient };
        if k == 0 && cfg.initial_velocity == InitialVelocity::Fluid {
            group.set_velocity_to_fluid(fluid)?;
            // the state of step 0 went out before the fluid's velocity was known: send it
            // again complete (the recorder keeps the last state 0, the flow node ignores it)
            publish_state(&group, 0)?;
        }
        group.step(fluid, dt)?;
        drop(samples);
        stepped_s += t0.elapsed().as_secs_f64();
        let t0 = Instant::now();
        publish_state(&group, k + 1)?;
        if (k + 1) % cfg.metrics_every == 0 || k + 1 == ann.steps {
            publish_metrics(&group, k + 1)?;
        }
        published_s += t0.elapsed().as_secs_f64();
        timing = (waited_s, stepped_s, published_s);
        if let Some(root) = &ck.root {
            if checkpoints::is_checkpoint_step(k + 1, ck.every, ann.steps) {
                let dir = checkpoints::step_dir(root, k + 1);
                std::fs::create_dir_all(&dir).map_err(|source| CheckpointError::Io {
                    path: dir.display().to_string(),
                    source,
                })?;
                let t0 = Instant::now();
                GroupSnapshot::capture(&group, k + 1).write(&checkpoints::piece(&dir, &node))?;
                tracing::info!(
                    step = k + 1,
                    ms = t0.elapsed().as_millis() as u64,
                    "checkpoint written"
                );
            }
        }
    }
    tracing::info!(
        steps = ann.steps - start,
        waiting_for_samples_s = format!("{:.3}", timing.0),
        fibre_step_s = format!("{:.3}", timing.1),
        encoding_and_publishing_s = format!("{:.3}", timing.2),
        cpu_s = format!("{:.3}", fiberflow_bus::usage::process_cpu_s() - cpu_from),
        "where the group's time went"
    );
    hb(lifecycle::DONE, ann.steps, samples_in.drops.total())?;
    let mut drops = samples_in.drops.clone();
    for (k, v) in ann_in.drops.by_topic {
        *drops.by_topic.entry(k).or_insert(0) += v;
    }
    Ok(drops)
}
