//! The flow node's coupling loop (DESIGN §3): join barrier, run announcement, then lockstep
//! — for each step k, wait for every group's state at t_k, sample v and ∇v at its segment
//! centres from the field at t_k, publish, and advance the field to t_{k+1}.

use crate::config::{FlowNodeConfig, FlowSource};
use crate::error::FlowError;
use crate::sampling::{Field, PieceSamples};
use crate::step_times::{Stages, StepTimes};
use fiberflow_bus::{BusHandle, DropCounter, Encode, Inbox, Outbox};
use fiberflow_dns::Solver;
use fiberflow_messages::pieces::Piece;
use fiberflow_messages::topics::Topics;
use fiberflow_messages::{
    encode, lifecycle, FiberGroupState, FlowProfiles, FlowSamples, FlowSlice, FlowStatus,
    Heartbeat, RunAnnouncement, SCHEMA_VERSION,
};
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

enum Admit {
    Take,
    /// The state of step k−1 again (a fluid-velocity start republishes step 0 with its
    /// velocities set): expected, not counted.
    Ignore,
    Drop(String),
}

/// Decides what to do with a state that decoded while serving step `k`: states that make
/// no sense (inconsistent arrays, an unknown group, another segment count than the
/// group's, a point outside the channel, a step from the past or the future) are dropped.
fn admit(s: &FiberGroupState, k: u64, run: &RunInfo) -> Admit {
    use fiberflow_messages::sanity::Sane;
    if let Err(why) = s.check() {
        return Admit::Drop(format!("inconsistent: {why}"));
    }
    if !run.groups.contains(&s.group) {
        return Admit::Drop(format!("state of unknown group {:?}", s.group));
    }
    let Some(p) = run
        .pieces
        .iter()
        .find(|p| p.group == s.group && p.first_fiber == s.first_fiber)
    else {
        return Admit::Drop(format!(
            "group {} has no shard starting at fibre {}",
            s.group, s.first_fiber
        ));
    };
    if s.group_fibers != p.group_fibers || s.centre.len() != 3 * p.segments {
        return Admit::Drop(format!(
            "shard {} has {} of {} fibres in {} segments, the state {} of {} in {}",
            p.node(),
            p.fibers,
            p.group_fibers,
            p.segments,
            s.segments_per_fiber.len(),
            s.group_fibers,
            s.centre.len() / 3
        ));
    }
    if s.step + 1 == k {
        return Admit::Ignore;
    }
    if s.step != k {
        return Admit::Drop(format!("state of step {} while serving step {k}", s.step));
    }
    let half = 0.5 * run.box_plus[1] * (1.0 + 1e-9);
    // one pass without an early exit (vectorised; the values are finite by now)
    let inside = s.centre.chunks_exact(3).fold(true, |ok, p| {
        ok & (p[1].abs() <= half) & (p[0].abs() <= 1e12) & (p[2].abs() <= 1e12)
    });
    if !inside {
        return Admit::Drop("a segment centre outside the channel".into());
    }
    Admit::Take
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

/// How often the flow node looks at heartbeats while it waits for states.
const HEARTBEAT_POLL: Duration = Duration::from_millis(200);

/// The samples last published to each piece: (step, topic, message). The message is
/// encoded on the outbox's thread, straight into the transport's buffer; its arrays are
/// sampled into again next step.
type Served = BTreeMap<(String, u32), (u64, String, Arc<Encode<FlowSamples>>)>;

/// Answers fibre nodes that wait (lifecycle WAITING) for samples this node already
/// published: the message was lost in transit, so it goes out again. A node waiting for a
/// step not served yet has re-sent its state instead; nothing to do here.
fn answer_waiting(
    bus: &BusHandle,
    hb_in: &mut Inbox,
    served: &Served,
    run: &RunInfo,
) -> Result<(), FlowError> {
    while let Some((_, hb)) = hb_in.recv::<Heartbeat>(Duration::ZERO) {
        if hb.state != lifecycle::WAITING {
            continue;
        }
        let Some(p) = run.pieces.iter().find(|p| p.node() == hb.node) else {
            continue;
        };
        if let Some((step, topic, msg)) = served.get(&(p.group.clone(), p.first_fiber)) {
            if *step == hb.step {
                tracing::info!(node = %hb.node, step, "node waits for samples already sent: sending them again");
                bus.publish_message(topic, msg.as_ref())?;
            }
        }
    }
    Ok(())
}

/// Waits until the recorder says it has this node's DONE (lifecycle FINISHING or DONE),
/// sending the DONE again after 1, 2, 4, … s: the run's end must not hang on one DONE the
/// transport lost while this process was exiting. Gives up after the step timeout (the
/// recorder then finishes on its own once the last states are in).
fn await_recorder_finishing(
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
            let finishing = (hb.state == lifecycle::FINISHING && hb.step == run.steps)
                || hb.state == lifecycle::DONE;
            if hb.node == "recorder" && finishing {
                return Ok(());
            }
        }
        // other nodes' heartbeats arriving must not hold the resend back
        if last_sent.elapsed() >= resend_after {
            tracing::info!("no word from the recorder on this node's DONE: sending it again");
            heartbeat(bus, t, lifecycle::DONE, run.steps, dropped)?;
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

/// Publishes the viewers' flow slices of the field at step `k` (DESIGN §3: u' at
/// `streaks_y_plus` and the x = 0 cross-section).
fn publish_slices(
    out: &mut Outbox,
    t: &Topics,
    solver: &Solver,
    cfg: &FlowNodeConfig,
    k: u64,
) -> Result<(), FlowError> {
    use fiberflow_dns::slice;
    let (g, re) = (&solver.grid, solver.cfg.re_tau);
    let [streaks, cross] = fiberflow_messages::topics::FLOW_SLICE_NAMES;
    for (name, p) in [
        (
            streaks,
            slice::streaks(g, &solver.vel, re, cfg.streaks_y_plus),
        ),
        (cross, slice::cross_section(g, &solver.vel, re)),
    ] {
        let msg = FlowSlice {
            schema_version: SCHEMA_VERSION,
            step: k,
            t_plus: k as f64 * cfg.dt_plus,
            name: name.into(),
            quantity: "u_fluct_plus".into(),
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

fn heartbeat(
    bus: &BusHandle,
    t: &Topics,
    state: u8,
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
    let mut st_in = Inbox::new(bus.subscribe(&t.fiber_state("*"))?);
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
    while let Some((topic, _)) = st_in.recv_raw(Duration::ZERO) {
        st_in
            .drops
            .drop_one(&topic, "message before the run started");
    }
    bus.publish(&t.announce(), &encode(&ann))?;
    tracing::info!(groups = ?run.groups, steps = run.steps, "run announced");
    let step_timeout = Duration::from_secs_f64(run.step_timeout_s);
    // states of the step being served, by (group, first fibre)
    let mut pending: BTreeMap<(String, u32), FiberGroupState> = BTreeMap::new();
    // states already served, decoded into again
    let mut spare_states: Vec<FiberGroupState> = Vec::new();
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
    let mut step_times = StepTimes::new((run.steps - run.start_step) as usize + 1);
    for k in run.start_step..=run.steps {
        step_times.begin(k, timing.stages());
        // gather every group's state at step k
        let wait_from = Instant::now();
        while pending.len() < run.pieces.len() {
            let left = step_timeout.saturating_sub(wait_from.elapsed());
            if left.is_zero() {
                let missing: Vec<_> = run
                    .pieces
                    .iter()
                    .filter(|p| !pending.contains_key(&(p.group.clone(), p.first_fiber)))
                    .map(|p| p.node())
                    .collect();
                heartbeat(&bus, &t, lifecycle::FAILED, k, st_in.drops.total())?;
                return Err(FlowError::Protocol(format!(
                    "step {k}: no state from fibre node(s) {} within {:.0} s",
                    missing.join(", "),
                    run.step_timeout_s
                )));
            }
            answer_waiting(&bus, &mut hb_in, &served, run)?;
            let Some((topic, bytes)) = st_in.recv_raw(left.min(HEARTBEAT_POLL)) else {
                continue;
            };
            if !topic.ends_with("/state") {
                continue; // metrics and other fibre topics are not for us
            }
            // decoded into a state served before, when there is one: its arrays (MBs per
            // group at scale) keep their allocations
            let mut s = spare_states.pop().unwrap_or_default();
            let decoded = fiberflow_messages::decode_state_into(&mut s, &bytes).map(|()| s);
            match decoded {
                Ok(s) => match admit(&s, k, run) {
                    Admit::Take => match pending.entry((s.group.clone(), s.first_fiber)) {
                        std::collections::btree_map::Entry::Vacant(e) => {
                            e.insert(s);
                        }
                        std::collections::btree_map::Entry::Occupied(_) => spare_states.push(s),
                    },
                    Admit::Ignore => {
                        tracing::debug!(group = %s.group, step = s.step, expected = k, "ignoring the state of the step just served");
                        spare_states.push(s);
                    }
                    Admit::Drop(why) => {
                        st_in.drops.drop_one(&topic, &why);
                        spare_states.push(s);
                    }
                },
                Err(e) => st_in.drops.drop_one(&topic, &e.to_string()),
            }
        }
        let t_plus = k as f64 * cfg.dt_plus;
        let waited_s = wait_from.elapsed().as_secs_f64();
        if k == run.start_step {
            start_wait_s = waited_s;
        } else {
            timing.waiting_s += waited_s;
        }
        // every piece's points in one pass, in cell order (parallel; the same bits as one
        // by one)
        let t0 = Instant::now();
        let states = std::mem::take(&mut pending);
        let pieces: Vec<(&[f64], &[u32])> = states
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
        let samples = field.sample_pieces(&pieces, spare);
        timing.sampling_s += t0.elapsed().as_secs_f64();
        // handed over together: the fibre nodes sharing a process are woken once for all
        let mut step_samples: Vec<(String, Arc<dyn fiberflow_bus::Outgoing>)> =
            Vec::with_capacity(states.len());
        for (((group, first_fiber), s), (vel, grad)) in states.into_iter().zip(samples) {
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
            spare_states.push(s);
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
        // coupled checkpoint of the field at t_k (the groups integrate meanwhile)
        if let Some(root) = &run.checkpoint_root {
            if k != run.start_step
                && fiberflow_messages::checkpoints::is_checkpoint_step(
                    k,
                    run.checkpoint_every,
                    run.steps,
                )
            {
                let dir = fiberflow_messages::checkpoints::step_dir(root, k);
                let t0 = Instant::now();
                match &field {
                    Field::Dns(d) => crate::checkpoint::write_dns(&dir, &d.solver, stats.as_ref())?,
                    Field::Analytic(_) => crate::checkpoint::write_analytic(&dir, k)?,
                }
                tracing::info!(
                    step = k,
                    ms = t0.elapsed().as_millis() as u64,
                    "checkpoint written"
                );
            }
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
                    let col = |f: fn(&fiberflow_dns::stats::ProfileRow) -> f64| {
                        p.rows.iter().map(f).collect::<Vec<_>>()
                    };
                    let msg = FlowProfiles {
                        schema_version: SCHEMA_VERSION,
                        step: k + 1,
                        t_plus: (k + 1) as f64 * cfg.dt_plus,
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
                    };
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
        loop_s = format!("{loop_s:.3}"),
        start_wait_s = format!("{start_wait_s:.3}"),
        cpu_s = format!("{:.3}", fiberflow_bus::usage::process_cpu_s() - cpu_from),
        threads_cpu_s = fiberflow_bus::usage::threads_cpu_since(&threads_from),
        "where the flow node's time went"
    );
    if let Some(path) = &run.step_times {
        // diagnostics: a run whose results are all out does not fail over them
        if let Err(e) = step_times.write(path) {
            tracing::warn!(error = %e, "the per-step times were not written");
        }
    }
    heartbeat(&bus, &t, lifecycle::DONE, run.steps, st_in.drops.total())?;
    if run.expected_nodes.iter().any(|n| n == "recorder") {
        await_recorder_finishing(&bus, &t, &mut hb_in, run, st_in.drops.total())?;
    }
    let mut drops = st_in.drops.clone();
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

#[cfg(test)]
mod fuzz {
    use super::*;
    use fiberflow_messages::fuzz::{random_payload, Rng};

    /// 10^5 random states (valid CDR, random lengths, values and steps) through the flow
    /// node's admission: no panic, and every admitted state has the group's segment count,
    /// finite values and centres inside the channel (what the sampler then reads).
    #[test]
    fn admission_survives_random_states() {
        let groups = vec!["case1".to_string()];
        let run = RunInfo {
            run_id: "fz".into(),
            config_digest: String::new(),
            groups: groups.clone(),
            expected_nodes: groups.clone(),
            steps: 400,
            box_plus: [942.0, 300.0, 471.0],
            step_timeout_s: 1.0,
            start_step: 0,
            resume_dir: None,
            checkpoint_every: 0,
            checkpoint_root: None,
            pieces: vec![Piece {
                group: "case1".into(),
                index: 0,
                shards: 1,
                first_fiber: 0,
                fibers: 1,
                group_fibers: 1,
                segments: 7,
            }],
            step_times: None,
        };
        let mut r = Rng::new(5);
        let mut taken = 0;
        for i in 0..100_000u64 {
            let b = random_payload("fiberflow_msgs/msg/FiberGroupState", &mut r, &groups);
            let Ok(mut s) = fiberflow_messages::decode::<FiberGroupState>(&b) else {
                continue;
            };
            // steer a share of the cases to the step being served and the right size
            if i % 3 == 0 {
                s.step = i % 50;
                for p in s.centre.chunks_mut(3) {
                    if p.len() == 3 {
                        p[1] = p[1].clamp(-150.0, 150.0);
                    }
                }
            }
            if let Admit::Take = admit(&s, i % 50, &run) {
                assert_eq!(s.centre.len(), 21);
                assert!(s.centre.iter().all(|x| x.is_finite()));
                assert!(s.centre.chunks(3).all(|p| p[1].abs() <= 150.0 + 1e-6));
                taken += 1;
            }
        }
        assert!(
            taken > 0,
            "no random state was ever admitted: the test does not reach it"
        );
    }
}
