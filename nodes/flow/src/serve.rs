//! The flow node's coupling loop (docs/architecture.md): join barrier, run announcement, then lockstep
//! — for each step k, wait for every group's state at t_k, sample v and ∇v at its segment
//! centres from the field at t_k, publish, and advance the field to t_{k+1}.

use crate::config::{FlowNodeConfig, FlowSource};
use crate::error::FlowError;
use crate::lockstep::{Served, States};
use crate::outgoing::{await_recorder_finishing, heartbeat, profiles_message, publish_slices};
use crate::sampling::{Field, PieceSamples};
use crate::step_times::{Stages, StepTimes};
use fiberflow_bus::{BusHandle, DropCounter, Encode, Inbox, Outbox};
use fiberflow_dns::Solver;
use fiberflow_messages::pieces::Piece;
use fiberflow_messages::topics::Topics;
use fiberflow_messages::{
    encode, lifecycle, FiberGroupState, FlowSamples, FlowStatus, Heartbeat, RunAnnouncement,
    SCHEMA_VERSION,
};
use rayon::prelude::*;
use std::collections::{BTreeMap, BTreeSet};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Run-level facts the launcher hands to every node.
#[derive(Debug, Clone, PartialEq)]
pub struct RunInfo {
    pub run_id: String,
    pub config_digest: String,
    pub groups: Vec<String>,
    /// Nodes that must join before the run starts (groups and, if any, the recorder).
    pub expected_nodes: Vec<String>,
    pub steps: u64,
    pub box_plus: [f64; 3],
    /// Seconds to wait for a group's state at one step before giving up.
    pub step_timeout_s: f64,
    /// First coupling step: 0, or the step of the checkpoint the run resumes from.
    pub start_step: u64,
    /// The checkpoint folder the run resumes from (its step is `start_step`).
    pub resume_dir: Option<PathBuf>,
    /// Coupled checkpoints: every this many steps (0 = never) under this folder.
    pub checkpoint_every: u64,
    pub checkpoint_root: Option<PathBuf>,
    /// Every fibre node's share of its group (one piece per unsharded group): the flow
    /// node waits for a state of each at every step, samples each on its own.
    pub pieces: Vec<Piece>,
    /// Where every step's wall and stages go as CSV at the end of the run (None: kept
    /// nowhere).
    pub step_times: Option<PathBuf>,
    /// Two-way coupling: the fibres' forces of every state go back to the fluid.
    pub two_way: bool,
}

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

/// Refuses a coupling time step the DNS cannot take from its starting field: the Courant
/// sum max(|u|/Δx + |v|/Δy + |w|/Δz)·Δt must stay below the RK3 limit √3.
fn check_stability(solver: &Solver, dt_plus: f64) -> Result<(), FlowError> {
    let rate = fiberflow_dns::timestep::max_courant_rate(&solver.grid, &solver.vel);
    let dt = dt_plus * solver.t_unit();
    let cfl = rate * dt;
    let limit = fiberflow_dns::timestep::RK3_CFL_LIMIT;
    if !(cfl <= limit) {
        let max_dt_plus = if rate > 0.0 {
            limit / rate / solver.t_unit()
        } else {
            f64::INFINITY
        };
        return Err(FlowError::Config(format!(
            "run.dt_plus = {dt_plus} gives a Courant sum of {cfl:.2} on the starting flow field \
             (RK3 stability limit {limit}): run.dt_plus must be in (0, {max_dt_plus:.3}]"
        )));
    }
    Ok(())
}

/// What the loop did.
#[derive(Debug, Clone, PartialEq)]
pub struct ServeSummary {
    pub steps: u64,
    pub drops: DropCounter,
}

/// Runs the coupling loop until `run.steps` steps are served.
pub fn serve(
    cfg: &FlowNodeConfig,
    bus: BusHandle,
    run: &RunInfo,
    mut on_status: impl FnMut(&FlowStatus),
) -> Result<ServeSummary, FlowError> {
    cfg.validate()?;
    let t = Topics::new(&run.run_id);
    let mut resumed_stats = None;
    let mut field = match &cfg.source {
        FlowSource::Analytic { flow } => Field::Analytic(*flow),
        FlowSource::Dns {
            dns,
            restart,
            regrid,
        } => {
            let mut d = dns.clone();
            d.dt_fixed_plus = Some(cfg.dt_plus);
            let mut s = Solver::new(d)?;
            if let Some(dir) = &run.resume_dir {
                resumed_stats = crate::checkpoint::read_dns(dir, &mut s)?;
            } else if let Some(r) = restart {
                if *regrid {
                    s.read_checkpoint_regridded(r)?;
                } else {
                    s.read_checkpoint(r)?;
                }
            }
            check_stability(&s, cfg.dt_plus)?;
            Field::dns(s, cfg.interpolation)
        }
    };
    if let (Field::Analytic(_), Some(dir)) = (&field, &run.resume_dir) {
        crate::checkpoint::read_analytic(dir, run.start_step)?;
    }
    let mut hb_in = Inbox::new(bus.subscribe(&format!("{}/control/heartbeat/**", t.prefix()))?);
    // the states alone: metrics (hundreds of kB per group and step at scale) never reach
    // this node
    let mut states = States::new(Inbox::new(bus.subscribe(&t.fiber_state("*"))?));
    // join barrier
    let mut joined = BTreeSet::new();
    let expected: BTreeSet<String> = run.expected_nodes.iter().cloned().collect();
    let deadline = Instant::now() + Duration::from_secs_f64(cfg.join_timeout_s);
    let mut last_hb = Instant::now() - Duration::from_secs(1);
    while !expected.is_subset(&joined) {
        if Instant::now() > deadline {
            let missing: Vec<_> = expected.difference(&joined).cloned().collect();
            heartbeat(&bus, &t, lifecycle::FAILED, 0, 0)?;
            return Err(FlowError::Protocol(format!(
                "join timeout after {:.0} s: no heartbeat from {}",
                cfg.join_timeout_s,
                missing.join(", ")
            )));
        }
        if last_hb.elapsed() > Duration::from_millis(200) {
            heartbeat(&bus, &t, lifecycle::READY, 0, 0)?;
            last_hb = Instant::now();
        }
        if let Some((_, hb)) = hb_in.recv::<Heartbeat>(Duration::from_millis(50)) {
            if hb.state == lifecycle::READY || hb.state == lifecycle::RUNNING {
                joined.insert(hb.node);
            }
        }
    }
    // let subscriptions settle on every side, then announce
    std::thread::sleep(Duration::from_millis(300));
    let ann = RunAnnouncement {
        schema_version: SCHEMA_VERSION,
        run_id: run.run_id.clone(),
        config_digest: run.config_digest.clone(),
        groups: run.groups.clone(),
        steps: run.steps,
        dt_plus: cfg.dt_plus,
        box_plus: run.box_plus.to_vec(),
    };
    // nothing sent before the run started is part of it
    states.drop_early();
    bus.publish(&t.announce(), &encode(&ann))?;
    tracing::info!(groups = ?run.groups, steps = run.steps, "run announced");
    // the samples last published to each piece, to send again when a node waits for them
    let mut served: Served = BTreeMap::new();
    // running plane/time statistics of the served field, published as FlowProfiles
    let mut stats: Option<fiberflow_dns::stats::RunningStats> = resumed_stats;
    if run.start_step > 0 {
        tracing::info!(step = run.start_step, "resuming from a coupled checkpoint");
    }
    let mut timing = Timing::default();
    let cpu_from = fiberflow_bus::usage::process_cpu_s();
    let threads_from = fiberflow_bus::usage::threads_cpu_s();
    // the loop's messages go out on the outbox's thread while the field steps on
    let mut out = Outbox::new(bus.clone(), outbox_depth(run))?;
    // the loop's whole wall, stages and what lies between them (statistics, status),
    // less the start-up wait for the first states (below)
    let loop_from = Instant::now();
    // the wait for the first step's states is the fibre nodes starting up (once per run,
    // tens of ms): start-up, logged apart from the loop's per-step stages
    let mut start_wait_s = 0.0;
    // diagnostics: a run does not fail over them (a file that cannot be written is left out)
    let mut step_times = StepTimes::new(run.step_times.as_deref()).unwrap_or_else(|e| {
        tracing::warn!(error = %e, "the per-step times are not kept");
        StepTimes::disabled()
    });
    let mut feedback = crate::feedback::Feedback::default();
    // the self-induced correction's memories per piece (kept in coupled checkpoints)
    let mut histories = match &run.resume_dir {
        Some(dir) if run.two_way => crate::checkpoint::read_histories(dir)?,
        _ => BTreeMap::new(),
    };
    let self_widths = match (&field, run.two_way, cfg.self_induced) {
        (Field::Dns(d), true, crate::config::SelfInduced::History) => Some(
            crate::self_induced::Widths::new(&d.solver.grid, d.solver.cfg.re_tau),
        ),
        _ => None,
    };
    if run.two_way {
        tracing::info!(
            self_induced = ?cfg.self_induced,
            "two-way coupling: the fibres' forces act on the fluid"
        );
    }
    for k in run.start_step..=run.steps {
        step_times.begin(k, timing.stages());
        step_times.flush_if_full();
        // gather every group's state at step k
        let wait_from = Instant::now();
        states.gather(k, run, &bus, &t, &mut hb_in, &served)?;
        let waited_s = wait_from.elapsed().as_secs_f64();
        let t_plus = k as f64 * cfg.dt_plus;
        if k == run.start_step {
            start_wait_s = waited_s;
        } else {
            timing.waiting_s += waited_s;
        }
        // coupled checkpoint of the field at t_k, before this step's samples: the
        // self-induced memories it holds are those of t_k, which a resumed run advances
        // again with the same forces
        if let Some(root) = &run.checkpoint_root {
            if k != run.start_step
                && k < run.steps
                && fiberflow_messages::checkpoints::is_checkpoint_step(
                    k,
                    run.checkpoint_every,
                    run.steps,
                )
            {
                let dir = fiberflow_messages::checkpoints::step_dir(root, k);
                let t0 = Instant::now();
                match &field {
                    Field::Dns(d) => {
                        crate::checkpoint::write_dns(&dir, &d.solver, stats.as_ref(), &histories)?
                    }
                    Field::Analytic(_) => crate::checkpoint::write_analytic(&dir, k)?,
                }
                tracing::info!(
                    step = k,
                    ms = t0.elapsed().as_millis() as u64,
                    "checkpoint written"
                );
                // the per-step times so far survive a kill from here on
                step_times.flush();
            }
        }
        // every piece's points in one pass, in cell order (parallel; the same bits as one
        // by one)
        let t0 = Instant::now();
        let step_states = states.take();
        let pieces: Vec<(&[f64], &[u32])> = step_states
            .values()
            .map(|s| (&s.centre[..], &s.segments_per_fiber[..]))
            .collect();
        // every node has answered the last step's samples: their arrays are sampled into
        // again (unless the outbox still holds one, which then stays with it)
        let spare: Vec<PieceSamples> = std::mem::take(&mut served)
            .into_values()
            .filter_map(|(_, _, msg)| Arc::try_unwrap(msg).ok())
            .map(|Encode(m)| (m.velocity, m.velocity_gradient))
            .collect();
        let mut samples = field.sample_pieces(&pieces, spare);
        timing.sampling_s += t0.elapsed().as_secs_f64();
        // two-way: the forces the states carry act on the fluid over its next step
        if let (true, Field::Dns(d)) = (run.two_way, &mut field) {
            let t0 = Instant::now();
            crate::feedback::gather(&step_states, d.solver.cfg.re_tau, &mut feedback)?;
            d.solver.set_body_force(&feedback.points, &feedback.forces);
            if let Some(w) = &self_widths {
                let re_tau = d.solver.cfg.re_tau;
                for key in step_states.keys() {
                    histories.entry(key.clone()).or_default();
                }
                let mut work: Vec<(&mut crate::self_induced::History, &FiberGroupState)> =
                    histories
                        .iter_mut()
                        .filter_map(|(k, h)| step_states.get(k).map(|s| (h, s)))
                        .collect();
                samples
                    .par_iter_mut()
                    .zip(work.par_iter_mut())
                    .for_each(|((vel, _), (h, s))| {
                        h.correct_and_advance(
                            w,
                            re_tau,
                            cfg.dt_plus,
                            &s.segments_per_fiber,
                            &s.centre,
                            &s.hydro_force,
                            vel,
                        )
                    });
            }
            timing.feedback_s += t0.elapsed().as_secs_f64();
        }
        // handed over together: the fibre nodes sharing a process are woken once for all
        let mut step_samples: Vec<(String, Arc<dyn fiberflow_bus::Outgoing>)> =
            Vec::with_capacity(step_states.len());
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
                .map(|p| p.samples_topic(&t))
                .unwrap_or_else(|| t.flow_samples(&group));
            let msg = Arc::new(Encode(msg));
            timing.encoding_s += t0.elapsed().as_secs_f64();
            step_samples.push((topic.clone(), msg.clone()));
            served.insert((group.clone(), first_fiber), (k, topic, msg));
            states.recycle(s);
        }
        let t0 = Instant::now();
        out.send_together(step_samples)?;
        timing.publishing_s += t0.elapsed().as_secs_f64();
        if let Field::Dns(d) = &field {
            let solver = &d.solver;
            if cfg.slices_every > 0 && (k.is_multiple_of(cfg.slices_every) || k == run.steps) {
                let t0 = Instant::now();
                publish_slices(&mut out, &t, solver, cfg, k)?;
                timing.publishing_s += t0.elapsed().as_secs_f64();
            }
        }
        if k == run.steps {
            break;
        }
        // advance the field to t_{k+1} while the groups integrate
        let status = match &mut field {
            Field::Analytic(_) => FlowStatus {
                schema_version: SCHEMA_VERSION,
                step: k + 1,
                t_plus: (k + 1) as f64 * cfg.dt_plus,
                dt_plus: cfg.dt_plus,
                cfl: 0.0,
                max_divergence: 0.0,
                bulk_velocity: 0.0,
                re_tau: 0.0,
                pressure_gradient: 0.0,
                fibre_force_plus: vec![],
            },
            Field::Dns(d) => {
                let solver = &mut d.solver;
                let t0 = Instant::now();
                let r = solver.step()?;
                timing.field_step_s += t0.elapsed().as_secs_f64();
                // the DNS branch always has statistics; the analytic one has none
                let stats = stats
                    .get_or_insert_with(|| fiberflow_dns::stats::RunningStats::new(&solver.grid));
                if (k + 1) % cfg.status_every == 0 {
                    stats.add(&solver.grid, &solver.vel, r.t_plus);
                }
                if ((k + 1) % cfg.profiles_every == 0 || k + 1 == run.steps) && stats.samples > 0 {
                    let p = stats.profiles(&solver.grid, solver.cfg.re_tau);
                    let msg = profiles_message(&p, k + 1, (k + 1) as f64 * cfg.dt_plus);
                    out.send(t.flow_profiles(), Arc::new(encode(&msg)))?;
                }
                FlowStatus {
                    schema_version: SCHEMA_VERSION,
                    step: k + 1,
                    t_plus: (k + 1) as f64 * cfg.dt_plus,
                    dt_plus: r.dt_plus,
                    cfl: r.cfl,
                    max_divergence: r.max_divergence,
                    bulk_velocity: r.bulk_velocity,
                    re_tau: if (k + 1) % cfg.status_every == 0 {
                        fiberflow_dns::stats::wall_re_tau(
                            &solver.grid,
                            &solver.vel,
                            solver.cfg.re_tau,
                        )
                    } else {
                        f64::NAN
                    },
                    pressure_gradient: r.forcing,
                    fibre_force_plus: if run.two_way {
                        feedback.total_plus.to_vec()
                    } else {
                        vec![]
                    },
                }
            }
        };
        if (k + 1) % cfg.status_every == 0 || k + 1 == run.steps {
            out.send(t.flow_status(), Arc::new(encode(&status)))?;
            on_status(&status);
        }
    }
    step_times.end(timing.stages());
    let loop_s = loop_from.elapsed().as_secs_f64() - start_wait_s;
    let background_publishing_s = out.finish()?;
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
        start_wait_s = format!("{start_wait_s:.3}"),
        cpu_s = format!("{:.3}", fiberflow_bus::usage::process_cpu_s() - cpu_from),
        threads_cpu_s = fiberflow_bus::usage::threads_cpu_since(&threads_from),
        "where the flow node's time went"
    );
    step_times.flush();
    heartbeat(&bus, &t, lifecycle::DONE, run.steps, states.drops().total())?;
    if run.expected_nodes.iter().any(|n| n == "recorder") {
        await_recorder_finishing(&bus, &t, &mut hb_in, run, states.drops().total())?;
    }
    let mut drops = states.drops().clone();
    for (k, v) in hb_in.drops.by_topic {
        *drops.by_topic.entry(k).or_insert(0) += v;
    }
    Ok(ServeSummary {
        steps: run.steps,
        drops,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A coupled run's dt_plus is checked against the RK3 Courant limit on the field it
    /// starts from, with an error that names the key and the allowed range.
    #[test]
    fn unstable_dt_plus_is_refused_up_front() {
        let cfg = fiberflow_dns::DnsConfig::with_cells(16, 16, 16);
        let solver = Solver::new(cfg).unwrap();
        assert!(check_stability(&solver, 0.05).is_ok());
        let e = check_stability(&solver, 50.0).unwrap_err().to_string();
        assert!(
            e.contains("run.dt_plus") && e.contains("Courant") && e.contains("(0, "),
            "{e}"
        );
        // the bound it states is the bound it applies
        let max: f64 = e
            .rsplit("(0, ")
            .next()
            .unwrap()
            .trim_end_matches(']')
            .parse()
            .unwrap();
        assert!(check_stability(&solver, 0.999 * max).is_ok());
        assert!(check_stability(&solver, 1.01 * max).is_err());
    }
}
