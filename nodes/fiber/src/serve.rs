//! The fibre node's loop: announce readiness, then per step publish the state at t_k,
//! wait for the flow samples of step k, and integrate to t_{k+1}. Several small fibre
//! nodes of one process ([`serve_many`]) step in turn on one thread: at paper size a
//! thread each cost the process more in task switches than the fibres' physics.
//!
//! Size: the one-node and many-nodes loops share their per-step protocol (announce, send
//! again on request, checkpoints) and must stay in step with each other; the fibre
//! equations are in `fiber-model`.

use crate::config::{FiberNodeConfig, InitialVelocity};
use crate::exchange::Exchange;
use crate::flow_watch::{flow_restarted, FlowWatch};
use fiberflow_bus::{BusError, BusHandle, DropCounter, Encode, Inbox};
use fiberflow_fiber_model::checkpoint::{CheckpointError, GroupSnapshot};
use fiberflow_fiber_model::group::{FibreGroup, PARALLEL_MIN_SEGMENTS};
use fiberflow_fiber_model::metrics::FibreMetrics;
use fiberflow_fiber_model::step::Fluid;
use fiberflow_fiber_model::FibreError;
use fiberflow_messages::checkpoints;
use fiberflow_messages::pieces::Piece;
use fiberflow_messages::topics::Topics;
use fiberflow_messages::Lifecycle;
use fiberflow_messages::{
    encode, FiberGroupMetrics, FiberGroupState, Heartbeat, RunAnnouncement, SamplesView,
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

/// How often a fibre node's wait for samples wakes (without samples): to stamp its watch
/// (the pulse beats only while the loop advances), look for a stop, and read the flow
/// node's heartbeats when it lives on another host.
const WAIT_POLL: Duration = Duration::from_millis(500);

/// Where a group starts, where it saves coupled checkpoints, which run it belongs to, and
/// what its states carry (complete at which steps; the forces of two-way coupling).
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
    ck: &Checkpointing,
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
    ck: &Checkpointing,
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

/// One fibre node's group, its messages and its bookkeeping between steps.
struct ServedPiece {
    node: String,
    name: String,
    t: Topics,
    bus: BusHandle,
    piece: Piece,
    group: FibreGroup,
    run_id: String,
    /// The step the run starts (or resumes) from.
    start: u64,
    initial_velocity: InitialVelocity,
    metrics_every_steps: u64,
    samples_in: Inbox,
    ann_in: Inbox,
    /// The flow node's heartbeats, when it lives on another host ([`Checkpointing::flow_elsewhere`]).
    flow_hb: Option<FlowWatch>,
    /// Contact across pieces (the group's other shards, its suspension's other groups): the
    /// free step this piece sends to the suspension's first piece and the part of the
    /// solve it takes back, or (on the first piece) the others' free steps and their parts.
    exchange: Option<Exchange>,
    /// Index of this piece's first fibre in the order of the contact solve.
    order: usize,
    /// Refilled every step: its per-fibre arrays are set once and the segment arrays (MBs
    /// per step at scale) keep their allocations.
    state_msg: Encode<FiberGroupState>,
    state_topic: String,
    /// Refilled every step like the state (the per-fibre metrics and their message).
    fibre_metrics: Vec<FibreMetrics>,
    metrics_msg: Encode<FiberGroupMetrics>,
    metrics_topic: String,
    full_states_every: u64,
    two_way: bool,
    /// Steps whose contact solve left a pair closer than 0.99 d.
    unresolved_contact_steps: u64,
    /// Steps whose contact solve locked an island (docs/contact.md).
    locked_contact_steps: u64,
    /// Steps whose contact solve kept fibres where they started, and how many in all.
    frozen_contact_steps: u64,
    frozen_fibres: u64,
    checkpoint_every: u64,
    checkpoint_root: Option<PathBuf>,
    dt: f64,
    steps: u64,
    /// Wall seconds: waiting for and decoding samples, fibre step, encoding and publishing.
    timing: (f64, f64, f64),
    /// The longest wait for samples so far that needed no resend: a wait three times as
    /// long (at least RESEND_AFTER_MIN, at most a quarter of the step timeout, so that
    /// several resends fit in it) means a message was probably lost.
    longest_wait: Duration,
    cpu_from: f64,
    /// What this node's pulse shows (`fiberflow_bus::pulse`).
    beat: std::sync::Arc<fiberflow_bus::pulse::Beat>,
    /// Stamped by this node's loop as it goes: no stamp for a while, no pulse.
    watch: std::sync::Arc<fiberflow_bus::pulse::Watch>,
    /// In-process runs: set when another node of the run failed.
    stop: Option<std::sync::Arc<std::sync::atomic::AtomicBool>>,
}

impl ServedPiece {
    /// Builds (or restores) the node's slice of its group and subscribes to its topics.
    ///
    /// Long (≈120 lines): fresh start and restore from a checkpoint side by side, so
    /// both visibly build the same state.
    fn prepare(
        cfg: &FiberNodeConfig,
        shard: u32,
        bus: BusHandle,
        run_id: &str,
        box_plus: [f64; 3],
        ck: &Checkpointing,
    ) -> Result<Self, FiberNodeError> {
        let t = Topics::new(run_id);
        let pieces = cfg.pieces(box_plus)?;
        let piece = pieces.get(shard as usize).cloned().ok_or_else(|| {
            FiberNodeError::Protocol(format!(
                "group {} has {} shards, no shard {shard}",
                cfg.group, cfg.shards
            ))
        })?;
        // every shard builds the whole group (and the groups of its suspension) and keeps
        // its slice: the same fibres, bit for bit, whatever the shard count; with contact,
        // the pieces this one touches (the group's other shards, the other groups of its
        // suspension) exchange their free steps every step
        let members = ck
            .suspensions
            .iter()
            .find(|m| m.iter().any(|c| c.group == cfg.group))
            .map_or(&[][..], Vec::as_slice);
        let touching = crate::exchange::touching(cfg, &piece, members, box_plus)?;
        let order = touching.order;
        let exchange = if touching.others.is_empty() {
            None
        } else {
            Some(Exchange::new(&bus, &t, &piece, order, touching.others)?)
        };
        let built = touching
            .whole
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
                node = %node,
                step = ck.start_step,
                "group restored from a coupled checkpoint"
            );
        }
        let name = cfg.group.clone();
        let samples_in = Inbox::new(bus.subscribe(&piece.samples_topic(&t))?);
        let ann_in = Inbox::new(bus.subscribe(&t.announce())?);
        let flow_hb = if ck.flow_elsewhere {
            Some(FlowWatch {
                inbox: Inbox::new(bus.subscribe(&t.heartbeat("flow"))?),
                heard: None,
                silent_after: Duration::from_secs_f64(ck.flow_liveness_s.max(0.1)),
                announced: None,
            })
        } else {
            None
        };
        let state_msg = Encode(FiberGroupState {
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
            layer: built.layers,
            centre: Vec::new(),
            axis: Vec::new(),
            velocity: Vec::new(),
            angular_velocity: Vec::new(),
            hydro_force: Vec::new(),
            contact_segment: Vec::new(),
            contact_force: Vec::new(),
            contacts: Vec::new(),
        });
        let metrics_msg = Encode(FiberGroupMetrics {
            schema_version: SCHEMA_VERSION,
            group: name.clone(),
            step: 0,
            t_plus: 0.0,
            first_fiber: piece.first_fiber,
            group_fibers: piece.group_fibers,
            centre_of_mass: Vec::new(),
            z1: Vec::new(),
            sigma2: Vec::new(),
            end_to_end: Vec::new(),
            mean_abs_z1: 0.0,
            mean_sigma2: 0.0,
        });
        Ok(Self {
            state_topic: t.fiber_state(&name),
            metrics_topic: t.fiber_metrics(&name),
            fibre_metrics: Vec::new(),
            metrics_msg,
            node,
            name,
            t,
            bus,
            piece,
            group,
            run_id: run_id.to_string(),
            start: ck.start_step,
            initial_velocity: cfg.initial_velocity,
            metrics_every_steps: cfg.metrics_every_steps,
            samples_in,
            ann_in,
            flow_hb,
            exchange,
            order,
            state_msg,
            full_states_every: ck.full_states_every,
            two_way: ck.two_way,
            unresolved_contact_steps: 0,
            locked_contact_steps: 0,
            frozen_contact_steps: 0,
            frozen_fibres: 0,
            checkpoint_every: ck.every,
            checkpoint_root: ck.root.clone(),
            dt: 0.0,
            steps: 0,
            timing: (0.0, 0.0, 0.0),
            longest_wait: Duration::ZERO,
            cpu_from: 0.0,
            beat: Default::default(),
            watch: Default::default(),
            stop: None,
        })
    }

    fn hb(&self, state: Lifecycle, step: u64) -> Result<(), BusError> {
        self.bus.publish(
            &self.t.heartbeat(&self.node),
            &encode(&Heartbeat {
                schema_version: SCHEMA_VERSION,
                node: self.node.clone(),
                state,
                step,
                dropped: self.samples_in.drops.total(),
            }),
        )
    }

    /// Fails when the launcher of an in-process run said another node failed.
    fn stopped(&self) -> Result<(), FiberNodeError> {
        if self
            .stop
            .as_ref()
            .is_some_and(|s| s.load(std::sync::atomic::Ordering::SeqCst))
        {
            return Err(FiberNodeError::Protocol(format!(
                "node {}: stopped: the run is stopping (another node failed, or Ctrl-C)",
                self.node
            )));
        }
        Ok(())
    }

    /// Fails when the flow node has started the run again ([`flow_restarted`]).
    fn flow_restarted(&mut self, k: u64) -> Result<(), FiberNodeError> {
        flow_restarted(self.flow_hb.as_mut(), &self.node, self.start, k)
    }

    /// The run's announcement for this node's group, if one arrives within `wait`
    /// (announcements of another run or configuration are dropped and counted).
    fn announcement(&mut self, wait: Duration, ck: &Checkpointing) -> Option<RunAnnouncement> {
        let (topic, a) = self.ann_in.recv::<RunAnnouncement>(wait)?;
        if a.run_id != self.run_id
            || (!ck.config_digest.is_empty() && a.config_digest != ck.config_digest)
        {
            self.ann_in
                .drops
                .drop_one(&topic, "announcement of another run or configuration");
            None
        } else if a.groups.contains(&self.name) {
            Some(a)
        } else {
            None
        }
    }

    /// Takes the run's time step and length and publishes the state the run starts from.
    fn start(&mut self, ann: RunAnnouncement) -> Result<(), FiberNodeError> {
        self.dt = ann.dt_plus;
        self.steps = ann.steps;
        if let Some(w) = self.flow_hb.as_mut() {
            w.announced = Some(Instant::now());
        }
        let start = self.start;
        self.publish_state(start)?;
        if start == 0 || start.is_multiple_of(self.metrics_every_steps) {
            self.publish_metrics(start)?;
        }
        self.cpu_from = fiberflow_bus::usage::process_cpu_s();
        Ok(())
    }

    fn publish_state(&mut self, step: u64) -> Result<(), BusError> {
        let full = self.full_states_every <= 1
            || step.is_multiple_of(self.full_states_every)
            || step == self.steps;
        let st = &mut self.state_msg.0;
        st.step = step;
        st.t_plus = step as f64 * self.dt;
        st.centre.clear();
        st.axis.clear();
        st.velocity.clear();
        st.angular_velocity.clear();
        self.group.extend_state(
            full,
            &mut st.centre,
            &mut st.axis,
            &mut st.velocity,
            &mut st.angular_velocity,
        );
        st.hydro_force.clear();
        if self.two_way {
            self.group.extend_forces(&mut st.hydro_force);
        }
        let load = self.group.contact_load();
        st.contact_segment.clone_from(&load.segment);
        st.contact_force.clone_from(&load.force);
        st.contacts.clone_from(&load.count);
        self.bus.publish_message(&self.state_topic, &self.state_msg)
    }

    fn publish_metrics(&mut self, step: u64) -> Result<(), BusError> {
        self.group.metrics_into(&mut self.fibre_metrics);
        let ms = &self.fibre_metrics;
        let n = ms.len().max(1) as f64;
        let m = &mut self.metrics_msg.0;
        m.step = step;
        m.t_plus = step as f64 * self.dt;
        m.centre_of_mass.clear();
        m.centre_of_mass
            .extend(ms.iter().flat_map(|m| m.centre_of_mass.iter().copied()));
        m.z1.clear();
        m.z1.extend(ms.iter().map(|m| m.z1));
        m.sigma2.clear();
        m.sigma2.extend(ms.iter().map(|m| m.sigma2));
        m.end_to_end.clear();
        m.end_to_end.extend(ms.iter().map(|m| m.end_to_end));
        m.mean_abs_z1 = ms.iter().map(|m| m.z1.abs()).sum::<f64>() / n;
        m.mean_sigma2 = ms.iter().map(|m| m.sigma2).sum::<f64>() / n;
        self.bus
            .publish_message(&self.metrics_topic, &self.metrics_msg)
    }

    /// Waits for the samples of step `k` (sending the state again when they are late,
    /// and the states `resend_others` sends: those of the nodes stepped after this one on
    /// its thread; it returns how many) and integrates to t_{k+1};
    /// [`ServedPiece::publish_step`] then sends the new state.
    fn step(
        &mut self,
        k: u64,
        step_timeout: Duration,
        timeout_s: f64,
        resend_others: &mut dyn FnMut() -> Result<usize, BusError>,
    ) -> Result<(), FiberNodeError> {
        use std::sync::atomic::Ordering;
        self.beat.step.store(k, Ordering::Relaxed);
        self.beat
            .dropped
            .store(self.samples_in.drops.total(), Ordering::Relaxed);
        let resend_cap = (step_timeout / 4).max(RESEND_AFTER_MIN);
        let wait_from = Instant::now();
        let mut resent = false;
        let mut resend_after = (3 * self.longest_wait).clamp(RESEND_AFTER_MIN, resend_cap);
        let mut resend_at = wait_from + resend_after;
        // the wait ends with the samples checked (checking counts as the fibre step); the
        // step reads them where they arrived (a transport's shared memory), not copied
        let (checking, samples) = loop {
            self.watch.touch();
            self.stopped()?;
            self.flow_restarted(k)?;
            let left = step_timeout.saturating_sub(wait_from.elapsed());
            if left.is_zero() {
                self.hb(Lifecycle::Failed, k)?;
                return Err(FiberNodeError::Protocol(format!(
                    "node {}: no flow samples for step {k} within {timeout_s:.0} s",
                    self.node
                )));
            }
            let now = Instant::now();
            if now >= resend_at {
                // our state or the samples were lost in transit: send the state again and
                // say we wait (the flow node resends samples it already served)
                self.publish_state(k)?;
                // a shard still waiting for our free step of the last step may have lost it
                if let Some(x) = &self.exchange {
                    x.resend(&self.bus)?;
                }
                let others = resend_others()?;
                self.hb(Lifecycle::Waiting, k)?;
                tracing::info!(
                    node = %self.node,
                    step = k,
                    waited_s = format!("{:.1}", wait_from.elapsed().as_secs_f64()),
                    also_resent = others,
                    "no samples yet: sending the state again"
                );
                resent = true;
                resend_after = (2 * resend_after).min(resend_cap);
                resend_at = now + resend_after;
            }
            let wait = left
                .min(resend_at.saturating_duration_since(now))
                .min(WAIT_POLL);
            let Some((topic, bytes)) = self.samples_in.recv_raw(wait) else {
                continue;
            };
            let view = match SamplesView::read(&bytes) {
                Ok(v) => v,
                Err(e) => {
                    self.samples_in.drops.drop_one(&topic, &e.to_string());
                    continue;
                }
            };
            let n = self.group.segment_count();
            let h = &view.header;
            let drops = &mut self.samples_in.drops;
            // the values' finiteness is checked while they are read, below
            if let Err(why) = view.check_shape() {
                drops.drop_one(&topic, &format!("inconsistent: {why}"));
            } else if h.group != self.name || h.first_fiber != self.piece.first_fiber {
                drops.drop_one(&topic, "samples for another group or shard");
            } else if h.step != k {
                drops.drop_one(&topic, "samples of another step");
            } else if view.len() != n {
                drops.drop_one(&topic, "samples for another number of segments");
            } else {
                let t0 = Instant::now();
                if view.values_finite() {
                    break (t0.elapsed(), bytes);
                }
                let why = view.check().err().unwrap_or_default();
                drops.drop_one(&topic, &format!("inconsistent: {why}"));
            }
        };
        let (mut waited_s, mut stepped_s, published_s) = self.timing;
        // a wait that ended only after a resend says how long a loss took to repair, not
        // how long a healthy step takes: it must not stretch the next resend deadline
        let waited = wait_from.elapsed().saturating_sub(checking);
        if !resent {
            self.longest_wait = self.longest_wait.max(waited);
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
        if k == 0 && self.initial_velocity == InitialVelocity::Fluid {
            self.group.set_velocity_to_fluid(fluid)?;
            // the state of step 0 went out before the fluid's velocity was known: send it
            // again complete (the recorder keeps the last state 0, the flow node ignores it)
            self.publish_state(0)?;
        }
        if self.exchange.is_none() {
            self.group.step(fluid, self.dt)?;
        } else {
            self.group.step_free(fluid, self.dt)?;
            drop(samples);
            self.resolve_with_other_shards(k, step_timeout)?;
        }
        self.report_unresolved_contact(k + 1);
        stepped_s += t0.elapsed().as_secs_f64();
        self.timing = (waited_s, stepped_s, published_s);
        Ok(())
    }

    /// With contact across pieces, after the free step of step `k`: the suspension's first
    /// piece gathers the others' free steps, solves and sends them their parts; any other
    /// piece sends its free step and takes its part ([`Exchange::contact`]).
    fn resolve_with_other_shards(
        &mut self,
        k: u64,
        step_timeout: Duration,
    ) -> Result<(), FiberNodeError> {
        let Some(mut x) = self.exchange.take() else {
            return Ok(());
        };
        let (flow_hb, node, start, watch, stop) = (
            &mut self.flow_hb,
            &self.node,
            self.start,
            &self.watch,
            &self.stop,
        );
        let result = x.contact(
            &self.bus,
            node,
            &mut self.group,
            self.order,
            k,
            k as f64 * self.dt,
            self.dt,
            step_timeout,
            &mut || {
                watch.touch();
                if stop
                    .as_ref()
                    .is_some_and(|s| s.load(std::sync::atomic::Ordering::SeqCst))
                {
                    return Err(FiberNodeError::Protocol(format!(
                        "node {node}: stopped: the run is stopping (another node failed, or Ctrl-C)"
                    )));
                }
                flow_restarted(flow_hb.as_mut(), node, start, k)
            },
        );
        self.exchange = Some(x);
        result
    }

    /// With contact on, says when the contact solve left a pair closer than 0.99 of its
    /// contact distance (the first such step, then every 100th): the sweeps ran out.
    fn report_unresolved_contact(&mut self, step: u64) {
        let Some(c) = self.group.contact() else {
            return;
        };
        let out = self.group.last_contact();
        let d = self
            .group
            .props(0)
            .first()
            .map_or(0.0, |p| p.shape.diameter);
        if out.worst_gap < -0.01 * d {
            if self.unresolved_contact_steps.is_multiple_of(100) {
                tracing::warn!(
                    node = %self.node,
                    step,
                    worst_gap_over_d = out.worst_gap / d,
                    sweeps = out.sweeps,
                    max_sweeps = c.sweeps,
                    contacts = self.group.contact_pairs(),
                    steps_so_far = self.unresolved_contact_steps + 1,
                    "contact left a pair closer than 0.99 d (raise fibers.contact.sweeps?)"
                );
            }
            self.unresolved_contact_steps += 1;
        }
        if !out.locked.is_empty() {
            if self.locked_contact_steps.is_multiple_of(100) {
                tracing::info!(
                    node = %self.node,
                    step,
                    fibres = out.locked.len(),
                    steps_so_far = self.locked_contact_steps + 1,
                    "contact locked fibres the sweeps could not separate (they moved as one body this step)"
                );
            }
            self.locked_contact_steps += 1;
        }
        if !out.frozen.is_empty() {
            if self.frozen_contact_steps.is_multiple_of(100) {
                tracing::info!(
                    node = %self.node,
                    step,
                    fibres = out.frozen.len(),
                    steps_so_far = self.frozen_contact_steps + 1,
                    "contact kept fibres where they started the step (still overlapping when the rounds ran out)"
                );
            }
            self.frozen_contact_steps += 1;
            self.frozen_fibres += out.frozen.len() as u64;
        }
    }

    /// Publishes the state of step `step` just integrated to (and its metrics when due).
    fn publish_step(&mut self, step: u64) -> Result<(), BusError> {
        let t0 = Instant::now();
        self.publish_state(step)?;
        if step.is_multiple_of(self.metrics_every_steps) || step == self.steps {
            self.publish_metrics(step)?;
        }
        self.timing.2 += t0.elapsed().as_secs_f64();
        Ok(())
    }

    /// Saves the group's coupled checkpoint of step `step` when one is due.
    fn checkpoint(&self, step: u64) -> Result<(), FiberNodeError> {
        let Some(root) = &self.checkpoint_root else {
            return Ok(());
        };
        if !checkpoints::is_checkpoint_step(step, self.checkpoint_every, self.steps) {
            return Ok(());
        }
        let dir = checkpoints::step_dir(root, step);
        std::fs::create_dir_all(&dir).map_err(|source| CheckpointError::Io {
            path: dir.display().to_string(),
            source,
        })?;
        let t0 = Instant::now();
        let path = checkpoints::piece(&dir, &self.node);
        // atomic: a crash leaves the old file or the new one
        checkpoints::write_atomic(&path, &GroupSnapshot::capture(&self.group, step).to_bytes())
            .map_err(|source| CheckpointError::Io {
                path: path.display().to_string(),
                source,
            })?;
        tracing::info!(
            node = %self.node,
            step,
            ms = t0.elapsed().as_millis() as u64,
            "checkpoint written"
        );
        Ok(())
    }

    /// Logs where the node's time went, says DONE, and returns its drop counts.
    fn finish(self) -> Result<(String, DropCounter), FiberNodeError> {
        tracing::info!(
            group = %self.node,
            steps = self.steps - self.start,
            waiting_for_samples_s = format!("{:.3}", self.timing.0),
            fibre_step_s = format!("{:.3}", self.timing.1),
            encoding_and_publishing_s = format!("{:.3}", self.timing.2),
            cpu_s = format!("{:.3}", fiberflow_bus::usage::process_cpu_s() - self.cpu_from),
            "where the group's time went"
        );
        if self.group.contact().is_some() {
            tracing::info!(
                group = %self.node,
                steps = self.steps - self.start,
                steps_with_a_locked_floc = self.locked_contact_steps,
                steps_left_closer_than_0_99_d = self.unresolved_contact_steps,
                steps_with_fibres_kept_at_their_start = self.frozen_contact_steps,
                fibres_kept_at_their_start = self.frozen_fibres,
                solves_for_the_suspension = self.exchange.as_ref().is_some_and(|x| x.solves()),
                exchanging_s = format!(
                    "{:.3}",
                    self.exchange.as_ref().map_or(0.0, |x| x.exchange_s())
                ),
                "contact over the run"
            );
            let t = self.group.contact_time();
            if t.steps > 0 {
                tracing::info!(
                    group = %self.node,
                    steps_solved = t.steps,
                    rebuild_s = format!("{:.3}", t.rebuild_s),
                    scan_s = format!("{:.3}", t.scan_s),
                    sweeps_s = format!("{:.3}", t.sweeps_s),
                    around_s = format!("{:.3}", t.around_s),
                    rest_s = format!("{:.3}", t.rest_s),
                    rounds = t.rounds,
                    "where contact's time went"
                );
            }
        }
        self.hb(Lifecycle::Done, self.steps)?;
        let mut drops = self.samples_in.drops.clone();
        let exchanged = self.exchange.as_ref().map(|x| x.drops().by_topic.clone());
        for (k, v) in self
            .ann_in
            .drops
            .by_topic
            .into_iter()
            .chain(exchanged.into_iter().flatten())
        {
            *drops.by_topic.entry(k).or_insert(0) += v;
        }
        Ok((self.node, drops))
    }
}
