//! The fibre node's loop: announce readiness, then per step publish the state at t_k,
//! wait for the flow samples of step k, and integrate to t_{k+1}. Several small fibre
//! nodes of one process ([`serve_many`]) step in turn on one thread: at paper size a
//! thread each cost the process more in task switches than the fibres' physics.
//!
//! One node's parts are in [`crate::piece`] (its group and messages, the step), the wait
//! for its samples in [`crate::lockstep`], what it publishes in [`crate::publish`]; the
//! fibre equations are in `fiber-model`.

use crate::config::FiberNodeConfig;
use crate::piece::ServedPiece;
use fiberflow_bus::{BusError, BusHandle, DropCounter};
use fiberflow_fiber_model::checkpoint::CheckpointError;
use fiberflow_fiber_model::group::PARALLEL_MIN_SEGMENTS;
use fiberflow_fiber_model::FiberError;
use fiberflow_messages::{Lifecycle, RunAnnouncement};
use std::path::PathBuf;
use std::time::{Duration, Instant};

#[derive(Debug, thiserror::Error)]
pub enum FiberNodeError {
    #[error(transparent)]
    Model(#[from] FiberError),
    #[error(transparent)]
    Bus(#[from] BusError),
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    #[error("{0}")]
    Protocol(String),
}

/// The run's settings a fibre node needs: where its group starts, where it saves coupled
/// checkpoints, which run it belongs to, what its states carry (complete at which steps;
/// the forces of two-way coupling), which groups touch, and where the flow node lives.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RunSettings {
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
    /// `states_every_steps`; 0 and 1 = every step); lean states (centres only) at the others.
    pub full_states_every: u64,
    /// Two-way coupling (`run.coupling = "two-way"`): every state, lean or complete,
    /// carries each segment's hydrodynamic force of the last step for the flow node.
    pub two_way: bool,
    /// The groups whose fibres touch each other (the launch file's `[[suspensions]]`), each
    /// in its order.
    pub suspensions: Vec<Vec<FiberNodeConfig>>,
    /// The flow node runs on another host and may be restarted there (multi-host runs):
    /// a flow node that says READY again after this node's first step has started the
    /// run over from a checkpoint, and this node fails so that its launcher restarts it
    /// from the same step.
    pub flow_elsewhere: bool,
    /// With the flow node elsewhere: once it has been heard, a flow node silent this long
    /// (`run.liveness_s`) is gone (its host or its router), and this node fails so that its
    /// launcher joins the run afresh and follows the restart.
    pub flow_liveness_s: f64,
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
    ck: &RunSettings,
) -> Result<DropCounter, FiberNodeError> {
    let mut drops = serve_many(&[(cfg, shard)], bus, run_id, box_plus, timeout_s, ck, None)?;
    Ok(drops.pop().map(|(_, d)| d).unwrap_or_default())
}

/// Runs several fibre nodes (each a group's shard) to the end of the run. Small groups
/// (below [`PARALLEL_MIN_SEGMENTS`] segments) are stepped in turn on this thread: every
/// node publishes its state of step k before any waits for its samples of step k, so the
/// flow node, which answers once it holds every state, is never kept waiting by the
/// order, and one thread is woken once per step instead of one per node (a node whose
/// samples are late sends the states of the nodes after it again with its own, since the
/// flow node answers none before it holds them all). If any group is
/// larger, each node gets a thread of its own. Returns each node's name and drop counts.
/// `stop` (in-process runs): set by the launcher when another node of the run failed; the
/// nodes' waits then end at once.
pub fn serve_many(
    nodes: &[(&FiberNodeConfig, u32)],
    bus: BusHandle,
    run_id: &str,
    box_plus: [f64; 3],
    timeout_s: f64,
    ck: &RunSettings,
    stop: Option<std::sync::Arc<std::sync::atomic::AtomicBool>>,
) -> Result<Vec<(String, DropCounter)>, FiberNodeError> {
    let mut served = nodes
        .iter()
        .map(|(cfg, shard)| ServedPiece::prepare(cfg, *shard, bus.clone(), run_id, box_plus, ck))
        .collect::<Result<Vec<_>, _>>()?;
    for s in served.iter_mut() {
        s.stop = stop.clone();
    }
    // readiness until every node's run is announced
    let deadline = Instant::now() + Duration::from_secs_f64(timeout_s);
    let mut announced: Vec<Option<RunAnnouncement>> = vec![None; served.len()];
    while announced.iter().any(Option::is_none) {
        if Instant::now() > deadline {
            let waiting: Vec<&str> = served
                .iter()
                .zip(&announced)
                .filter(|(_, a)| a.is_none())
                .map(|(s, _)| s.node.as_str())
                .collect();
            return Err(FiberNodeError::Protocol(format!(
                "node {}: no run announcement within {timeout_s:.0} s (is the flow node running?)",
                waiting.join(", ")
            )));
        }
        for (s, a) in served.iter_mut().zip(announced.iter_mut()) {
            if a.is_none() {
                s.hb(Lifecycle::Ready, 0)?;
            }
        }
        let wait = Duration::from_millis(200) / served.len().max(1) as u32;
        for (s, a) in served.iter_mut().zip(announced.iter_mut()) {
            if a.is_none() {
                *a = s.announcement(wait, ck);
            }
        }
    }
    for (s, a) in served.iter_mut().zip(announced) {
        if let Some(a) = a {
            s.start(a)?;
        }
    }
    // groups large enough to step on the thread pool run a thread each: their serial
    // parts (the samples' check, the state arrays, publishing) then overlap; shards that
    // exchange their free steps within a step must not wait for each other on one thread
    let on_threads = served.len() > 1
        && served
            .iter()
            .any(|s| s.group.segment_count() >= PARALLEL_MIN_SEGMENTS || s.exchange.is_some());
    if !on_threads {
        // one loop steps them all: one watch of its progress
        let shared = std::sync::Arc::new(fiberflow_bus::pulse::Watch::default());
        for s in served.iter_mut() {
            s.watch = shared.clone();
        }
    }
    // every node of this process says it is alive once a second while its loop advances
    let _pulse = fiberflow_bus::pulse::Pulse::start(
        bus.clone(),
        served
            .iter()
            .map(|s| {
                let topic = s.t.heartbeat(&s.node);
                (topic, s.node.clone(), s.beat.clone(), s.watch.clone())
            })
            .collect(),
    )
    .map_err(|e| FiberNodeError::Protocol(format!("starting the pulse thread: {e}")))?;
    let step_timeout = Duration::from_secs_f64(timeout_s);
    if on_threads {
        tracing::info!(nodes = served.len(), "fibre nodes on a thread each");
        return serve_on_threads(served, step_timeout, timeout_s, ck.start_step);
    }
    if served.len() > 1 {
        tracing::info!(
            nodes = served.len(),
            "fibre nodes stepped in turn on one thread"
        );
    }
    let steps = served.iter().map(|s| s.steps).max().unwrap_or(0);
    for k in ck.start_step..steps {
        for i in 0..served.len() {
            let (head, later) = served.split_at_mut(i + 1);
            let s = &mut head[i];
            if k >= s.steps {
                continue;
            }
            // the nodes after this one wait for the same step's samples, which the flow
            // node sends once it holds every state: when this node's samples are late,
            // their states go out again with its own (one of them may be the state lost;
            // they send nothing while this thread waits here)
            let mut resend_later = || -> Result<usize, BusError> {
                let mut sent = 0;
                for o in later.iter_mut().filter(|o| k < o.steps) {
                    o.publish_state(k)?;
                    sent += 1;
                }
                Ok(sent)
            };
            s.step(k, step_timeout, timeout_s, &mut resend_later)?;
        }
        // the new states together: one wake-up of each subscribing process per step,
        // not one per node
        bus.publish_together(&mut || {
            for s in served.iter_mut().filter(|s| k < s.steps) {
                s.publish_step(k + 1)?;
            }
            Ok(())
        })?;
        for s in served.iter().filter(|s| k < s.steps) {
            s.checkpoint(k + 1)?;
        }
    }
    served.into_iter().map(ServedPiece::finish).collect()
}

/// Runs each node on a thread of its own to the end of the run; the first failure
/// returns at once (the process then ends, and its other nodes with it).
fn serve_on_threads(
    served: Vec<ServedPiece>,
    step_timeout: Duration,
    timeout_s: f64,
    start: u64,
) -> Result<Vec<(String, DropCounter)>, FiberNodeError> {
    let (done_tx, done_rx) = std::sync::mpsc::channel();
    let n = served.len();
    for (i, mut s) in served.into_iter().enumerate() {
        let done = done_tx.clone();
        std::thread::Builder::new()
            .name(format!("node-{}", s.node))
            .spawn(move || {
                let run = || -> Result<(String, DropCounter), FiberNodeError> {
                    for k in start..s.steps {
                        s.step(k, step_timeout, timeout_s, &mut || Ok(0))?;
                        s.publish_step(k + 1)?;
                        s.checkpoint(k + 1)?;
                    }
                    s.finish()
                };
                let _ = done.send((i, run()));
            })
            .map_err(|e| FiberNodeError::Protocol(format!("starting a node thread: {e}")))?;
    }
    drop(done_tx);
    let mut out: Vec<Option<(String, DropCounter)>> = vec![None; n];
    for _ in 0..n {
        match done_rx.recv() {
            Ok((i, Ok(r))) => out[i] = Some(r),
            Ok((_, Err(e))) => return Err(e),
            // a node thread that panicked dropped its sender without a result
            Err(_) => {
                return Err(FiberNodeError::Protocol(
                    "a fibre node thread panicked".into(),
                ))
            }
        }
    }
    Ok(out.into_iter().flatten().collect())
}
