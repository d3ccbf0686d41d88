//! The stages of the flow node's coupling loop (`serve::serve` calls them in order, each
//! step): gather every piece's state at t_k, write a coupled checkpoint when one is due,
//! sample the field at t_k at the states' segment centres (two-way: put the fibres'
//! forces on the fluid), then advance the field to t_{k+1} while each fibre's own
//! disturbance leaves its samples (two-way) and the samples and the viewers' slices go out,
//! and report the field's status.
//!
//! Size (≈ 690 lines before the tests): the stages share the step's state ([`Coupling`]: the
//! pieces, the samples in flight, the timers) and run in the loop's order; apart, each would
//! take the whole struct.

use crate::config::FlowNodeConfig;
use crate::error::FlowError;
use crate::lockstep::{SentSamples, States};
use crate::outgoing::{await_recorder_finishing, heartbeat, profiles_message, publish_slices};
use crate::run::{RunInfo, ServeSummary};
use crate::sampling::{Field, PieceSamples};
use crate::step_times::{Stages, StepTimes};
use fiberflow_bus::{BusHandle, Encode, Inbox, Outbox};
use fiberflow_dns::stats::RunningStats;
use fiberflow_dns::StepReport;
use fiberflow_messages::topics::Topics;
use fiberflow_messages::Lifecycle;
use fiberflow_messages::NodeRole;
use fiberflow_messages::{encode, FiberGroupState, FlowSamples, FlowStatus, SCHEMA_VERSION};
use rayon::prelude::*;
use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;
use std::time::Instant;

/// Every piece's state of one step, by (group, first fibre).
pub(crate) type StepStates = BTreeMap<(String, u32), FiberGroupState>;

/// Wall seconds per stage of the coupling loop (logged at the end of a run).
#[derive(Debug, Default)]
struct Timing {
    waiting_s: f64,
    sampling_s: f64,
    /// Building the messages (the samples are encoded on the outbox's thread, straight
    /// into the transport's buffer: that counts as background publishing).
    encoding_s: f64,
    /// Handing messages to the outbox (publishing itself overlaps the field step).
    publishing_s: f64,
    field_step_s: f64,
    /// Two-way coupling: gathering the fibres' forces and spreading them on the grid.
    feedback_s: f64,
}

impl Timing {
    /// The sums a per-step row is taken from (building and handing over messages count
    /// as publishing).
    fn stages(&self) -> Stages {
        Stages {
            field_step_s: self.field_step_s,
            sampling_s: self.sampling_s,
            waiting_s: self.waiting_s,
            publishing_s: self.encoding_s + self.publishing_s,
        }
    }
}

/// Messages the outbox may hold unpublished: a step's samples, slices, profiles and status.
fn outbox_depth(run: &RunInfo) -> usize {
    run.pieces.len() + 8
}

/// The coupling loop's state between its stages.
/// The self-induced correction's kernel weights: being computed on a thread of their
/// own from the start, or ready.
pub(crate) enum PendingWidths {
    Computing(std::thread::JoinHandle<crate::self_induced::Widths>),
    Ready(crate::self_induced::Widths),
    /// The thread computing them panicked (reported once, as an error).
    Failed,
}

impl PendingWidths {
    /// Starts computing the weights on a thread of their own when the run needs them (a
    /// two-way run on the DNS with the history correction): started before the flow node
    /// waits for its nodes to join, so that the wait hides them (a quadrature per grid row:
    /// a fraction of a second of CPU).
    pub(crate) fn start(cfg: &FlowNodeConfig, run: &RunInfo, field: &Field) -> Option<Self> {
        match (field, run.two_way, cfg.self_induced) {
            (Field::Dns(d), true, crate::config::SelfInduced::History) => {
                let (grid, re_tau) = (d.solver.grid.clone(), d.solver.cfg.re_tau);
                Some(Self::Computing(std::thread::spawn(move || {
                    crate::self_induced::Widths::new(&grid, re_tau)
                })))
            }
            _ => None,
        }
    }

    /// The weights, waiting for their thread the first time.
    fn get(&mut self) -> Result<&crate::self_induced::Widths, FlowError> {
        if matches!(self, Self::Computing(_)) {
            if let Self::Computing(h) = std::mem::replace(self, Self::Failed) {
                if let Ok(w) = h.join() {
                    *self = Self::Ready(w);
                }
            }
        }
        match self {
            Self::Ready(w) => Ok(w),
            _ => Err(FlowError::Protocol(
                "computing the self-induced correction's weights failed (its thread panicked)"
                    .into(),
            )),
        }
    }
}

pub(crate) struct Coupling<'a> {
    cfg: &'a FlowNodeConfig,
    run: &'a RunInfo,
    bus: BusHandle,
    t: Topics,
    field: Field,
    states: States,
    hb_in: Inbox,
    /// The samples last published to each piece, to send again when a node waits for them.
    served: SentSamples,
    /// Running plane/time statistics of the served field, published as FlowProfiles.
    stats: Option<RunningStats>,
    /// The loop's messages go out on the outbox's thread while the field steps on.
    out: Outbox,
    timing: Timing,
    step_times: StepTimes,
    /// Two-way: the fibres' forces of the step, as points and forces.
    feedback: crate::feedback::Feedback,
    /// The self-induced correction's memories per piece (kept in coupled checkpoints).
    histories: BTreeMap<(String, u32), crate::self_induced::History>,
    self_widths: Option<PendingWidths>,
    /// The wait for the first step's states is the fibre nodes starting up (once per
    /// run, tens of ms): logged apart from the loop's per-step stages.
    start_wait_s: f64,
    /// Multi-host runs: checkpoint steps whose remote fibre nodes are confirmed, waiting for
    /// a recorder on another host to say the step is on its disk.
    unconfirmed: Unconfirmed,
    loop_from: Instant,
    cpu_from: f64,
    threads_from: BTreeMap<String, f64>,
}

impl<'a> Coupling<'a> {
    pub(crate) fn new(
        cfg: &'a FlowNodeConfig,
        bus: BusHandle,
        t: Topics,
        run: &'a RunInfo,
        field: Field,
        states: States,
        hb_in: Inbox,
        stats: Option<RunningStats>,
        self_widths: Option<PendingWidths>,
    ) -> Result<Self, FlowError> {
        let cpu_from = fiberflow_bus::usage::process_cpu_s();
        let threads_from = fiberflow_bus::usage::threads_cpu_s();
        let out = Outbox::new(bus.clone(), outbox_depth(run))?;
        // diagnostics: a run does not fail over them (a file that cannot be written is left out)
        let step_times = StepTimes::new(run.step_times.as_deref()).unwrap_or_else(|e| {
            tracing::warn!(error = %e, "the per-step times are not kept");
            StepTimes::disabled()
        });
        let histories = match &run.resume_dir {
            Some(dir) if run.two_way => crate::checkpoint::read_histories(dir)?,
            _ => BTreeMap::new(),
        };
        if run.two_way {
            tracing::info!(
                self_induced = ?cfg.self_induced,
                "two-way coupling: the fibres' forces act on the fluid"
            );
        }
        Ok(Self {
            cfg,
            run,
            bus,
            t,
            field,
            states,
            hb_in,
            served: BTreeMap::new(),
            stats,
            out,
            timing: Timing::default(),
            step_times,
            feedback: crate::feedback::Feedback::default(),
            histories,
            self_widths,
            start_wait_s: 0.0,
            unconfirmed: Unconfirmed::default(),
            // the loop's whole wall, stages and what lies between them (statistics,
            // status), less the start-up wait for the first states
            loop_from: Instant::now(),
            cpu_from,
            threads_from,
        })
    }

    /// Waits for every piece's state at step `k` (answering nodes that wait for samples
    /// already served), and for the recorder to be at most
    /// [`fiberflow_messages::lifecycle::RECORDER_LAG_STEPS`] behind.
    pub(crate) fn gather(&mut self, k: u64) -> Result<(), FlowError> {
        self.step_times.begin(k, self.timing.stages());
        self.step_times.flush_if_full();
        let wait_from = Instant::now();
        self.states.gather(
            k,
            self.run,
            &self.bus,
            &self.t,
            &mut self.hb_in,
            &self.served,
        )?;
        self.confirm_remote_checkpoint(k)?;
        let waited_s = wait_from.elapsed().as_secs_f64();
        if k == self.run.start_step {
            self.start_wait_s = waited_s;
        } else {
            self.timing.waiting_s += waited_s;
        }
        Ok(())
    }

    /// Multi-host runs: with every state of step `k` in, the fibre nodes on other hosts
    /// have each written their checkpoint of step k − 1 (a node saves it before it steps
    /// on). When k − 1 was a checkpoint step, this node's folder of it gets the file that
    /// says so, which completes the checkpoint on this host for the whole run — once a
    /// recorder on another host has also said that its segment is on disk through that
    /// step (a step it never saved cannot be resumed from without losing what it missed);
    /// until then the step waits here, and is confirmed at a later step.
    fn confirm_remote_checkpoint(&mut self, k: u64) -> Result<(), FlowError> {
        let run = self.run;
        let Some(root) = &run.checkpoint_root else {
            return Ok(());
        };
        if run.remote_pieces.is_empty() {
            return Ok(());
        }
        let fibers_in = k.checked_sub(1).filter(|&c| {
            c >= run.start_step
                && fiberflow_messages::checkpoints::is_checkpoint_step(
                    c,
                    run.checkpoint_every,
                    run.steps,
                )
        });
        let remote_recorder = run
            .remote_pieces
            .iter()
            .any(|(n, _)| NodeRole::Recorder.is(n));
        let committed = remote_recorder.then(|| self.states.recorder_committed());
        for c in self.unconfirmed.ready(fibers_in, committed) {
            let dir = fiberflow_messages::checkpoints::step_dir(root, c);
            // where each piece is: its node and the host whose run folder holds its file
            let mut text = format!(
                "# every fibre node on another host sent its state of step {}, after writing \
                 its checkpoint of step {c} into that host's run folder{}\nstep = {c}\n[hosts]\n",
                c + 1,
                if remote_recorder {
                    ", and the recorder there said its segment is on disk through it"
                } else {
                    ""
                }
            );
            for (node, host) in &run.remote_pieces {
                text.push_str(&format!("{node:?} = {host:?}\n"));
            }
            let file = fiberflow_messages::checkpoints::piece(
                &dir,
                fiberflow_messages::checkpoints::REMOTE_PIECE,
            );
            std::fs::create_dir_all(&dir)
                .and_then(|()| {
                    fiberflow_messages::checkpoints::write_atomic(&file, text.as_bytes())
                })
                .map_err(crate::error::io_err(&file))?;
        }
        Ok(())
    }

    /// The coupled checkpoint of the field at t_k, before this step's samples: the
    /// self-induced memories it holds are those of t_k, which a resumed run advances again
    /// with the same forces.
    pub(crate) fn checkpoint_if_due(&mut self, k: u64) -> Result<(), FlowError> {
        let run = self.run;
        let Some(root) = &run.checkpoint_root else {
            return Ok(());
        };
        let due = k != run.start_step
            && k < run.steps
            && fiberflow_messages::checkpoints::is_checkpoint_step(
                k,
                run.checkpoint_every,
                run.steps,
            );
        if !due {
            return Ok(());
        }
        let dir = fiberflow_messages::checkpoints::step_dir(root, k);
        let t0 = Instant::now();
        match &self.field {
            Field::Dns(d) => {
                crate::checkpoint::write_dns(&dir, &d.solver, self.stats.as_ref(), &self.histories)?
            }
            Field::Analytic(_) => crate::checkpoint::write_analytic(&dir, k)?,
        }
        tracing::info!(
            step = k,
            ms = t0.elapsed().as_millis() as u64,
            "checkpoint written"
        );
        // the per-step times so far survive a kill from here on
        self.step_times.flush();
        Ok(())
    }

    /// Every piece's samples of the field at t_k, in one pass in cell order (parallel; the
    /// same bits as one by one). Two-way: the states' forces are gathered as points, the
    /// fluid's body force over its next step (spread in [`Self::serve_and_step`]).
    pub(crate) fn sample(&mut self) -> Result<(StepStates, Vec<PieceSamples>), FlowError> {
        let t0 = Instant::now();
        let step_states = self.states.take();
        let pieces: Vec<(&[f64], &[u32])> = step_states
            .values()
            .map(|s| (&s.centre[..], &s.segments_per_fiber[..]))
            .collect();
        // every node has answered the last step's samples: their arrays are sampled into
        // again (unless the outbox still holds one, which then stays with it)
        let spare: Vec<PieceSamples> = std::mem::take(&mut self.served)
            .into_values()
            .filter_map(|(_, _, msg)| Arc::try_unwrap(msg).ok())
            .map(|Encode(m)| (m.velocity, m.velocity_gradient))
            .collect();
        let samples = self.field.sample_pieces(&pieces, spare);
        self.timing.sampling_s += t0.elapsed().as_secs_f64();
        if self.run.two_way {
            if let Field::Dns(d) = &self.field {
                let t0 = Instant::now();
                // a copy: the states go back to the inbox once their samples are out
                crate::feedback::gather(&step_states, d.solver.cfg.re_tau, &mut self.feedback)?;
                self.timing.feedback_s += t0.elapsed().as_secs_f64();
            }
        }
        Ok((step_states, samples))
    }

    /// Serves step `k` and advances the field: the viewers' slices of t_k when due, then,
    /// while the field takes the fibres' forces (two-way) and steps to t_{k+1} (unless `k`
    /// is the last step), each fibre's own disturbance leaves its samples (two-way) and the
    /// samples go out, so that the fibre nodes step while the field does. Neither side
    /// reads what the other writes, so the bits are those of one after the other
    /// (docs/history/two-way-cost.md). Returns the field step's report (None for the last step
    /// or the analytic flow).
    pub(crate) fn serve_and_step(
        &mut self,
        k: u64,
        step_states: StepStates,
        mut samples: Vec<PieceSamples>,
    ) -> Result<Option<StepReport>, FlowError> {
        self.publish_slices_if_due(k)?;
        let last = k == self.run.steps;
        let (cfg, run) = (self.cfg, self.run);
        let Self {
            field,
            histories,
            self_widths,
            timing,
            feedback,
            out,
            served,
            t,
            ..
        } = self;
        let (solver, re_tau) = match field {
            Field::Dns(d) => {
                let re_tau = d.solver.cfg.re_tau;
                (Some(&mut d.solver), re_tau)
            }
            Field::Analytic(_) => (None, 0.0),
        };
        let widths = match (run.two_way, solver.is_some(), self_widths.as_mut()) {
            (true, true, Some(w)) => Some(w.get()?),
            _ => None,
        };
        let (served_states, stepped) = rayon::join(
            || -> Result<Vec<FiberGroupState>, FlowError> {
                if let Some(w) = widths {
                    let t0 = Instant::now();
                    correct(
                        histories,
                        w,
                        re_tau,
                        cfg.dt_plus,
                        &step_states,
                        &mut samples,
                    );
                    timing.feedback_s += t0.elapsed().as_secs_f64();
                }
                let to = Publish {
                    run,
                    t,
                    dt_plus: cfg.dt_plus,
                    out,
                    served,
                    timing,
                };
                publish(to, k, step_states, samples)
            },
            || -> Result<Option<(StepReport, f64, f64)>, FlowError> {
                let Some(solver) = solver else {
                    return Ok(None);
                };
                let t0 = Instant::now();
                if run.two_way {
                    solver.set_body_force(&feedback.points, &feedback.forces);
                }
                let spread_s = t0.elapsed().as_secs_f64();
                if last {
                    return Ok(None);
                }
                let t0 = Instant::now();
                let r = crate::field_steps::advance(solver, cfg.field_steps)?;
                Ok(Some((r, spread_s, t0.elapsed().as_secs_f64())))
            },
        );
        for s in served_states? {
            self.states.recycle(s);
        }
        Ok(match stepped? {
            Some((r, spread_s, field_step_s)) => {
                self.timing.feedback_s += spread_s;
                self.timing.field_step_s += field_step_s;
                Some(r)
            }
            None => None,
        })
    }

    /// The viewers' slices of the field at t_k, when due (before it steps on).
    fn publish_slices_if_due(&mut self, k: u64) -> Result<(), FlowError> {
        let (cfg, run, t) = (self.cfg, self.run, &self.t);
        if let Field::Dns(d) = &self.field {
            if cfg.slices_every_steps > 0
                && (k.is_multiple_of(cfg.slices_every_steps) || k == run.steps)
            {
                let t0 = Instant::now();
                publish_slices(&mut self.out, t, &d.solver, cfg, k)?;
                self.timing.publishing_s += t0.elapsed().as_secs_f64();
            }
        }
        Ok(())
    }

    /// After the field stepped to t_{k+1} (`stepped`, its report): takes statistics and
    /// publishes the profiles when due. Returns the status of step k + 1.
    pub(crate) fn advance(
        &mut self,
        k: u64,
        stepped: Option<StepReport>,
    ) -> Result<FlowStatus, FlowError> {
        let (cfg, run) = (self.cfg, self.run);
        let next = k + 1;
        let t_plus = next as f64 * cfg.dt_plus;
        let d = match &mut self.field {
            Field::Analytic(_) => {
                return Ok(FlowStatus {
                    schema_version: SCHEMA_VERSION,
                    step: next,
                    t_plus,
                    dt_plus: cfg.dt_plus,
                    cfl: 0.0,
                    max_divergence: 0.0,
                    bulk_velocity: 0.0,
                    re_tau: 0.0,
                    pressure_gradient: 0.0,
                    fiber_force_plus: vec![],
                })
            }
            Field::Dns(d) => d,
        };
        let solver = &mut d.solver;
        let Some(r) = stepped else {
            return Err(FlowError::Protocol(format!(
                "step {k}: the field did not step (an internal error)"
            )));
        };
        // the DNS branch always has statistics; the analytic one has none
        let stats = self
            .stats
            .get_or_insert_with(|| RunningStats::new(&solver.grid));
        let sampled = next.is_multiple_of(cfg.status_every_steps);
        if sampled {
            stats.add(&solver.grid, &solver.vel, r.t_plus);
        }
        if (next.is_multiple_of(cfg.profiles_every_steps) || next == run.steps) && stats.samples > 0
        {
            let p = stats.profiles(&solver.grid, solver.cfg.re_tau);
            let msg = profiles_message(&p, next, t_plus);
            self.out
                .send(self.t.flow_profiles(), Arc::new(encode(&msg)))?;
        }
        Ok(FlowStatus {
            schema_version: SCHEMA_VERSION,
            step: next,
            t_plus,
            dt_plus: r.dt_plus,
            cfl: r.cfl,
            max_divergence: r.max_divergence,
            bulk_velocity: r.bulk_velocity,
            re_tau: if sampled {
                fiberflow_dns::stats::wall_re_tau(&solver.grid, &solver.vel, solver.cfg.re_tau)
            } else {
                f64::NAN
            },
            pressure_gradient: r.forcing,
            fiber_force_plus: if run.two_way {
                self.feedback.total_plus.to_vec()
            } else {
                vec![]
            },
        })
    }

    /// Publishes the status of step k + 1 when due (and hands it to the caller).
    pub(crate) fn report(
        &mut self,
        k: u64,
        status: &FlowStatus,
        on_status: &mut impl FnMut(&FlowStatus),
    ) -> Result<(), FlowError> {
        let next = k + 1;
        if next.is_multiple_of(self.cfg.status_every_steps) || next == self.run.steps {
            self.out
                .send(self.t.flow_status(), Arc::new(encode(status)))?;
            on_status(status);
        }
        Ok(())
    }

    /// Logs where the time went, says DONE, waits for the recorder to finish its file,
    /// and sums what was dropped.
    pub(crate) fn finish(mut self) -> Result<ServeSummary, FlowError> {
        let (run, timing) = (self.run, &self.timing);
        self.step_times.end(timing.stages());
        let loop_s = self.loop_from.elapsed().as_secs_f64() - self.start_wait_s;
        let background_publishing_s = self.out.finish()?;
        tracing::info!(
            steps = run.steps - run.start_step,
            background_publishing_s = format!("{background_publishing_s:.3}"),
            waiting_for_states_s = format!("{:.3}", timing.waiting_s),
            sampling_s = format!("{:.3}", timing.sampling_s),
            encoding_and_publishing_s = format!("{:.3}", timing.encoding_s + timing.publishing_s),
            encoding_s = format!("{:.3}", timing.encoding_s),
            field_step_s = format!("{:.3}", timing.field_step_s),
            feedback_s = format!("{:.3}", timing.feedback_s),
            loop_s = format!("{loop_s:.3}"),
            start_wait_s = format!("{:.3}", self.start_wait_s),
            cpu_s = format!(
                "{:.3}",
                fiberflow_bus::usage::process_cpu_s() - self.cpu_from
            ),
            threads_cpu_s = fiberflow_bus::usage::threads_cpu_since(&self.threads_from),
            "where the flow node's time went"
        );
        self.step_times.flush();
        let dropped = self.states.drops().total();
        heartbeat(&self.bus, &self.t, Lifecycle::Done, run.steps, dropped)?;
        if run.expected_nodes.iter().any(|n| NodeRole::Recorder.is(n)) {
            await_recorder_finishing(&self.bus, &self.t, &mut self.hb_in, run, dropped)?;
        }
        let mut drops = self.states.drops().clone();
        for (k, v) in std::mem::take(&mut self.hb_in.drops.by_topic) {
            *drops.by_topic.entry(k).or_insert(0) += v;
        }
        Ok(ServeSummary {
            steps: run.steps,
            drops,
        })
    }
}

/// What publishing a step's samples writes to: the outbox, the samples kept to serve again,
/// and the loop's timing.
struct Publish<'p> {
    run: &'p RunInfo,
    t: &'p Topics,
    dt_plus: f64,
    out: &'p mut Outbox,
    served: &'p mut SentSamples,
    timing: &'p mut Timing,
}

/// Hands every piece's samples to the outbox together (the fibre nodes sharing a process
/// are woken once for all). Returns the states served, whose arrays later states are
/// decoded into.
fn publish(
    to: Publish<'_>,
    k: u64,
    step_states: StepStates,
    samples: Vec<PieceSamples>,
) -> Result<Vec<FiberGroupState>, FlowError> {
    let (run, t) = (to.run, to.t);
    let t_plus = k as f64 * to.dt_plus;
    let mut step_samples: Vec<(String, Arc<dyn fiberflow_bus::Outgoing>)> =
        Vec::with_capacity(step_states.len());
    let mut done = Vec::with_capacity(step_states.len());
    for (((group, first_fiber), s), (vel, grad)) in step_states.into_iter().zip(samples) {
        let t0 = Instant::now();
        let msg = FlowSamples {
            schema_version: SCHEMA_VERSION,
            group: group.clone(),
            step: k,
            t_plus,
            first_fiber,
            group_fibers: s.group_fibers,
            velocity: vel,
            velocity_gradient: grad,
        };
        // admitted states belong to a piece of the run
        let topic = run
            .pieces
            .iter()
            .find(|p| p.group == group && p.first_fiber == first_fiber)
            .map(|p| p.samples_topic(t))
            .unwrap_or_else(|| t.flow_samples(&group));
        let msg = Arc::new(Encode(msg));
        to.timing.encoding_s += t0.elapsed().as_secs_f64();
        step_samples.push((topic.clone(), msg.clone()));
        to.served
            .insert((group.clone(), first_fiber), (k, topic, msg));
        done.push(s);
    }
    let t0 = Instant::now();
    to.out.send_together(step_samples)?;
    to.timing.publishing_s += t0.elapsed().as_secs_f64();
    Ok(done)
}

/// Two-way: removes each fibre's own disturbance from its samples and books the step's
/// forces in its memories (`self_induced::History`), piece by piece in parallel (every
/// fibre's arithmetic is its own: the bits do not depend on the threads).
fn correct(
    histories: &mut BTreeMap<(String, u32), crate::self_induced::History>,
    widths: &crate::self_induced::Widths,
    re_tau: f64,
    dt_plus: f64,
    step_states: &StepStates,
    samples: &mut [PieceSamples],
) {
    for key in step_states.keys() {
        histories.entry(key.clone()).or_default();
    }
    let mut work: Vec<(&mut crate::self_induced::History, &FiberGroupState)> = histories
        .iter_mut()
        .filter_map(|(k, h)| step_states.get(k).map(|s| (h, s)))
        .collect();
    samples
        .par_iter_mut()
        .zip(work.par_iter_mut())
        .for_each(|((vel, _), (h, s))| {
            h.correct_and_advance(
                widths,
                re_tau,
                dt_plus,
                &s.segments_per_fiber,
                &s.centre,
                &s.hydro_force,
                vel,
            )
        });
}
/// Checkpoint steps whose remote fibre nodes are in, until a recorder on another host
/// has them on disk.
#[derive(Debug, Default)]
struct Unconfirmed {
    steps: BTreeSet<u64>,
}

impl Unconfirmed {
    /// Adds `fibers_in` (a checkpoint step whose remote fibre nodes are confirmed) and
    /// returns, oldest first, the steps now confirmed for the whole run: all of them without
    /// a remote recorder (`committed` None), else those through the newest step it has
    /// said is on its disk (`committed` Some(None): nothing yet).
    fn ready(&mut self, fibers_in: Option<u64>, committed: Option<Option<u64>>) -> Vec<u64> {
        self.steps.extend(fibers_in);
        let through = match committed {
            None => u64::MAX,
            Some(None) => return Vec::new(),
            Some(Some(c)) => c,
        };
        let later = self.steps.split_off(&through.saturating_add(1));
        std::mem::replace(&mut self.steps, later)
            .into_iter()
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Without a remote recorder a checkpoint is confirmed as soon as its remote fibre
    /// nodes are in; with one, it waits until the recorder has said it is on its disk,
    /// and then every waiting step through that one goes at once, in order.
    #[test]
    fn a_remote_recorder_holds_checkpoints_until_it_has_them_on_disk() {
        let mut u = Unconfirmed::default();
        assert_eq!(u.ready(Some(10), None), [10]);
        assert_eq!(u.ready(None, None), Vec::<u64>::new());
        let mut u = Unconfirmed::default();
        assert_eq!(u.ready(Some(10), Some(None)), Vec::<u64>::new());
        assert_eq!(u.ready(Some(20), Some(Some(5))), Vec::<u64>::new());
        assert_eq!(u.ready(Some(30), Some(Some(20))), [10, 20]);
        assert_eq!(u.ready(None, Some(Some(20))), Vec::<u64>::new());
        assert_eq!(u.ready(None, Some(Some(30))), [30]);
    }
}
