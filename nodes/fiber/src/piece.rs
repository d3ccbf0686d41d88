//! One fibre node: its slice of a group (built, or restored from a checkpoint), its
//! messages and topics, and its step — wait for the samples ([`crate::lockstep`]), step
//! the fibres, solve contact with the pieces it touches ([`crate::exchange`]); what it
//! publishes is [`crate::publish`], what it counts [`crate::tally`].

use crate::config::{FiberNodeConfig, InitialVelocity};
use crate::exchange::Exchange;
use crate::flow_watch::{flow_restarted, FlowWatch};
use crate::serve::{FiberNodeError, RunSettings};
use crate::tally::{ContactTally, StepTimes};
use fiberflow_bus::{BusError, BusHandle, DropCounter, Encode, Inbox};
use fiberflow_fiber_model::checkpoint::{CheckpointError, GroupSnapshot};
use fiberflow_fiber_model::group::{FiberGroup, StepReport};
use fiberflow_fiber_model::metrics::FiberMetrics;
use fiberflow_fiber_model::step::Fluid;
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

/// One fibre node's group, its messages and its bookkeeping between steps.
pub(crate) struct ServedPiece {
    pub(crate) node: String,
    pub(crate) name: String,
    pub(crate) t: Topics,
    pub(crate) bus: BusHandle,
    pub(crate) piece: Piece,
    pub(crate) group: FiberGroup,
    pub(crate) run_id: String,
    /// The step the run starts (or resumes) from.
    pub(crate) start: u64,
    pub(crate) initial_velocity: InitialVelocity,
    pub(crate) metrics_every_steps: u64,
    /// Fibre steps per coupling step with the samples held (`fibers[].substeps`).
    pub(crate) substeps: u32,
    pub(crate) samples_in: Inbox,
    pub(crate) ann_in: Inbox,
    /// The flow node's heartbeats, when it lives on another host ([`RunSettings::flow_elsewhere`]).
    pub(crate) flow_hb: Option<FlowWatch>,
    /// Contact across pieces (the group's other shards, its suspension's other groups): the
    /// free step this piece sends to the suspension's first piece and the part of the
    /// solve it takes back, or (on the first piece) the others' free steps and their parts.
    pub(crate) exchange: Option<Exchange>,
    /// Index of this piece's first fibre in the order of the contact solve.
    pub(crate) order: usize,
    /// Refilled every step: its per-fibre arrays are set once and the segment arrays (MBs
    /// per step at scale) keep their allocations.
    pub(crate) state_msg: Encode<FiberGroupState>,
    pub(crate) state_topic: String,
    /// Refilled every step like the state (the per-fibre metrics and their message).
    pub(crate) fiber_metrics: Vec<FiberMetrics>,
    pub(crate) metrics_msg: Encode<FiberGroupMetrics>,
    pub(crate) metrics_topic: String,
    pub(crate) full_states_every: u64,
    pub(crate) two_way: bool,
    /// What contact's solve left undone, over the run.
    pub(crate) tally: ContactTally,
    pub(crate) checkpoint_every: u64,
    pub(crate) checkpoint_root: Option<PathBuf>,
    pub(crate) dt: f64,
    pub(crate) steps: u64,
    /// Where the node's wall time went.
    pub(crate) times: StepTimes,
    /// The longest wait for samples so far that needed no resend: a wait three times as
    /// long (at least RESEND_AFTER_MIN, at most a quarter of the step timeout, so that
    /// several resends fit in it) means a message was probably lost.
    pub(crate) longest_wait: Duration,
    pub(crate) cpu_from: f64,
    /// What this node's pulse shows (`fiberflow_bus::pulse`).
    pub(crate) beat: std::sync::Arc<fiberflow_bus::pulse::Beat>,
    /// Stamped by this node's loop as it goes: no stamp for a while, no pulse.
    pub(crate) watch: std::sync::Arc<fiberflow_bus::pulse::Watch>,
    /// In-process runs: set when another node of the run failed.
    pub(crate) stop: Option<std::sync::Arc<std::sync::atomic::AtomicBool>>,
}

impl ServedPiece {
    /// Builds (or restores) the node's slice of its group and subscribes to its topics.
    ///
    /// Long (≈120 lines): fresh start and restore from a checkpoint side by side, so
    /// both visibly build the same state.
    pub(crate) fn prepare(
        cfg: &FiberNodeConfig,
        shard: u32,
        bus: BusHandle,
        run_id: &str,
        box_plus: [f64; 3],
        ck: &RunSettings,
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
                .map(|k| group.fiber_len(k) as u32)
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
            fiber_metrics: Vec::new(),
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
            substeps: cfg.substeps,
            samples_in,
            ann_in,
            flow_hb,
            exchange,
            order,
            state_msg,
            full_states_every: ck.full_states_every,
            two_way: ck.two_way,
            tally: ContactTally::default(),
            checkpoint_every: ck.every,
            checkpoint_root: ck.root.clone(),
            dt: 0.0,
            steps: 0,
            times: StepTimes::default(),
            longest_wait: Duration::ZERO,
            cpu_from: 0.0,
            beat: Default::default(),
            watch: Default::default(),
            stop: None,
        })
    }

    pub(crate) fn hb(&self, state: Lifecycle, step: u64) -> Result<(), BusError> {
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
    pub(crate) fn stopped(&self) -> Result<(), FiberNodeError> {
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
    pub(crate) fn flow_restarted(&mut self, k: u64) -> Result<(), FiberNodeError> {
        flow_restarted(self.flow_hb.as_mut(), &self.node, self.start, k)
    }

    /// The run's announcement for this node's group, if one arrives within `wait`
    /// (announcements of another run or configuration are dropped and counted).
    pub(crate) fn announcement(
        &mut self,
        wait: Duration,
        ck: &RunSettings,
    ) -> Option<RunAnnouncement> {
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
    pub(crate) fn start(&mut self, ann: RunAnnouncement) -> Result<(), FiberNodeError> {
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

    /// Waits for the samples of step `k` ([`Self::wait_for_samples`]; `resend_others`
    /// sends the states of the nodes stepped after this one on its thread) and integrates
    /// to t_{k+1}, contact with the other pieces included; [`ServedPiece::publish_step`]
    /// then sends the new state.
    pub(crate) fn step(
        &mut self,
        k: u64,
        step_timeout: Duration,
        timeout_s: f64,
        resend_others: &mut dyn FnMut() -> Result<usize, BusError>,
    ) -> Result<(), FiberNodeError> {
        let arrived = self.wait_for_samples(k, step_timeout, timeout_s, resend_others)?;
        self.times.waiting_s += arrived.waited.as_secs_f64();
        self.times.stepping_s += arrived.checking.as_secs_f64();
        let t0 = Instant::now();
        // read again: the view borrowed the payload inside the wait (read and checked
        // there; only the header is parsed here)
        let samples = arrived.payload;
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
        let report = if self.exchange.is_none() {
            self.group.step_in_substeps(fluid, self.dt, self.substeps)?
        } else {
            self.group.step_free(fluid, self.dt)?;
            drop(samples);
            self.resolve_with_other_shards(k, step_timeout)?
        };
        self.tally.record(&self.node, k + 1, &self.group, &report);
        self.times.stepping_s += t0.elapsed().as_secs_f64();
        Ok(())
    }

    /// With contact across pieces, after the free step of step `k`: the suspension's first
    /// piece gathers the others' free steps, solves and sends them their parts; any other
    /// piece sends its free step and takes its part ([`Exchange::contact`]).
    pub(crate) fn resolve_with_other_shards(
        &mut self,
        k: u64,
        step_timeout: Duration,
    ) -> Result<StepReport, FiberNodeError> {
        let Some(mut x) = self.exchange.take() else {
            return Ok(StepReport::default());
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

    /// Saves the group's coupled checkpoint of step `step` when one is due.
    pub(crate) fn checkpoint(&self, step: u64) -> Result<(), FiberNodeError> {
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
    pub(crate) fn finish(self) -> Result<(String, DropCounter), FiberNodeError> {
        tracing::info!(
            group = %self.node,
            steps = self.steps - self.start,
            waiting_for_samples_s = format!("{:.3}", self.times.waiting_s),
            fiber_step_s = format!("{:.3}", self.times.stepping_s),
            encoding_and_publishing_s = format!("{:.3}", self.times.publishing_s),
            cpu_s = format!("{:.3}", fiberflow_bus::usage::process_cpu_s() - self.cpu_from),
            "where the group's time went"
        );
        if self.group.contact().is_some() {
            tracing::info!(
                group = %self.node,
                steps = self.steps - self.start,
                steps_with_a_locked_floc = self.tally.locked_steps,
                steps_left_closer_than_0_99_d = self.tally.unresolved_steps,
                steps_with_fibers_kept_at_their_start = self.tally.frozen_steps,
                fibers_kept_at_their_start = self.tally.frozen_fibers,
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
