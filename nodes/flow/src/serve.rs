//! The flow node's coupling loop (docs/architecture.md): join barrier, run announcement, then lockstep
//! — for each step k, wait for every group's state at t_k, sample v and ∇v at its segment
//! centres from the field at t_k, publish, and advance the field to t_{k+1}.

use crate::config::{FlowNodeConfig, FlowSource};
use crate::coupling::Coupling;
use crate::error::FlowError;
use crate::lockstep::States;
use crate::outgoing::heartbeat;
pub use crate::run::{RunInfo, ServeSummary};
use crate::sampling::Field;
use fiberflow_bus::{BusHandle, Inbox};
use fiberflow_dns::Solver;
use fiberflow_messages::topics::Topics;
use fiberflow_messages::Lifecycle;
use fiberflow_messages::{encode, FlowStatus, Heartbeat, RunAnnouncement, SCHEMA_VERSION};
use std::collections::BTreeSet;
use std::time::{Duration, Instant};

/// Refuses a coupling time step the DNS cannot take from its starting field: the Courant
/// sum max(|u|/Δx + |v|/Δy + |w|/Δz)·Δt must stay below the RK3 limit √3.
/// The field takes `field_steps` steps of `dt_plus / field_steps` per coupling step.
fn check_stability(solver: &Solver, dt_plus: f64, field_steps: u32) -> Result<(), FlowError> {
    let rate = fiberflow_dns::timestep::max_courant_rate(&solver.grid, &solver.vel);
    let m = f64::from(field_steps);
    let dt = dt_plus / m * solver.t_unit();
    let cfl = rate * dt;
    let limit = fiberflow_dns::timestep::RK3_CFL_LIMIT;
    if !(cfl <= limit) {
        let max_dt_plus = if rate > 0.0 {
            limit / rate / solver.t_unit() * m
        } else {
            f64::INFINITY
        };
        // the field steps that would take it (flow.field_steps allows up to 16)
        let more = (cfl / limit * m).ceil();
        let or_more = if more <= 16.0 {
            format!(", or flow.field_steps at least {more}")
        } else {
            String::new()
        };
        return Err(FlowError::Config(format!(
            "run.dt_plus = {dt_plus} in {field_steps} field step(s) gives a Courant sum of {cfl:.2} \
             on the starting flow field (RK3 stability limit {limit}): run.dt_plus must be in \
             (0, {max_dt_plus:.3}] with flow.field_steps = {field_steps}{or_more}"
        )));
    }
    Ok(())
}

/// Runs the coupling loop until `run.steps` steps are served: join, announce, then for
/// each step k gather every piece's state at t_k, sample the field at t_k for it (and, two-
/// way, put the fibres' forces on the fluid), publish, and advance the field to t_{k+1}.
pub fn serve(
    cfg: &FlowNodeConfig,
    bus: BusHandle,
    run: &RunInfo,
    mut on_status: impl FnMut(&FlowStatus),
) -> Result<ServeSummary, FlowError> {
    cfg.validate()?;
    let t = Topics::new(&run.run_id);
    let (field, resumed_stats) = open_field(cfg, run)?;
    let mut hb_in = Inbox::new(bus.subscribe(&format!("{}/control/heartbeat/**", t.prefix()))?);
    // the states alone: metrics (hundreds of kB per group and step at scale) never reach
    // this node
    let mut states = States::new(Inbox::new(bus.subscribe(&t.fiber_state("*"))?));
    // two-way: the self-induced correction's weights, computed while the nodes join
    let widths = crate::coupling::PendingWidths::start(cfg, run, &field);
    join(cfg, &bus, &t, run, &mut hb_in)?;
    announce(cfg, &bus, &t, run, &mut states)?;
    let mut c = Coupling::new(
        cfg,
        bus,
        t,
        run,
        field,
        states,
        hb_in,
        resumed_stats,
        widths,
    )?;
    for k in run.start_step..=run.steps {
        c.gather(k)?;
        c.checkpoint_if_due(k)?;
        let (step_states, samples) = c.sample()?;
        let stepped = c.serve_and_step(k, step_states, samples)?;
        if k == run.steps {
            break;
        }
        let status = c.advance(k, stepped)?;
        c.report(k, &status, &mut on_status)?;
    }
    c.finish()
}

/// The field the run starts from (analytic, or the DNS from a restart or the coupled
/// checkpoint it resumes from) and, when resumed, its running statistics.
fn open_field(
    cfg: &FlowNodeConfig,
    run: &RunInfo,
) -> Result<(Field, Option<fiberflow_dns::stats::RunningStats>), FlowError> {
    let mut resumed_stats = None;
    let field = match &cfg.source {
        FlowSource::Analytic { flow } => {
            if let Some(dir) = &run.resume_dir {
                crate::checkpoint::read_analytic(dir, run.start_step)?;
            }
            Field::Analytic(*flow)
        }
        FlowSource::Dns {
            dns,
            restart,
            regrid,
        } => {
            let mut d = dns.clone();
            d.dt_fixed_plus = Some(cfg.dt_plus / f64::from(cfg.field_steps));
            let mut s = Solver::new(d)?;
            if let Some(dir) = &run.resume_dir {
                resumed_stats = crate::checkpoint::read_dns(dir, &mut s)?;
            } else {
                if let Some(r) = restart {
                    if *regrid {
                        s.read_checkpoint_regridded(r)?;
                    } else {
                        s.read_checkpoint(r)?;
                    }
                }
                if cfg.realisation > 0 {
                    s.perturb(fiberflow_dns::perturb::realisation_seed(
                        crate::config::FLOW_DISTURBANCE_SEED,
                        cfg.realisation,
                    ));
                }
            }
            check_stability(&s, cfg.dt_plus, cfg.field_steps)?;
            Field::dns(s, cfg.interpolation)
        }
    };
    Ok((field, resumed_stats))
}

/// The join barrier: says READY until every expected node has said READY or RUNNING;
/// after `join_timeout_s` says FAILED and names the silent nodes.
fn join(
    cfg: &FlowNodeConfig,
    bus: &BusHandle,
    t: &Topics,
    run: &RunInfo,
    hb_in: &mut Inbox,
) -> Result<(), FlowError> {
    let mut joined = BTreeSet::new();
    let expected: BTreeSet<String> = run.expected_nodes.iter().cloned().collect();
    let deadline = Instant::now() + Duration::from_secs_f64(cfg.join_timeout_s);
    let mut last_hb = Instant::now() - Duration::from_secs(1);
    while !expected.is_subset(&joined) {
        if Instant::now() > deadline {
            let missing: Vec<_> = expected.difference(&joined).cloned().collect();
            heartbeat(bus, t, Lifecycle::Failed, 0, 0)?;
            return Err(FlowError::Protocol(format!(
                "join timeout after {:.0} s: no heartbeat from {}",
                cfg.join_timeout_s,
                missing.join(", ")
            )));
        }
        if last_hb.elapsed() > Duration::from_millis(200) {
            // the step it starts from: a worker host restarting its nodes after a
            // restart here resumes them from the same checkpoint
            heartbeat(bus, t, Lifecycle::Ready, run.start_step, 0)?;
            last_hb = Instant::now();
        }
        // READY only: a node says RUNNING once it has this run's announcement, which goes
        // out after the join, so a RUNNING now comes from a node of the run before a
        // restart (a worker host's node still stepping, about to fail on this READY), which
        // will not answer the announcement
        if let Some((_, hb)) = hb_in.recv::<Heartbeat>(Duration::from_millis(50)) {
            if hb.state == Lifecycle::Ready {
                joined.insert(hb.node);
            }
        }
    }
    Ok(())
}

/// Lets subscriptions settle on every side, drops states sent before the run started,
/// and announces the run.
fn announce(
    cfg: &FlowNodeConfig,
    bus: &BusHandle,
    t: &Topics,
    run: &RunInfo,
    states: &mut States,
) -> Result<(), FlowError> {
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
    let bytes = encode(&ann);
    bus.publish(&t.announce(), &bytes)?;
    // a node that missed it (a partition or loss as it went out) keeps saying READY and
    // is announced to again
    states.announced(t.announce(), bytes);
    tracing::info!(groups = ?run.groups, steps = run.steps, "run announced");
    if run.start_step > 0 {
        tracing::info!(step = run.start_step, "resuming from a coupled checkpoint");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Only READY joins a node: a RUNNING heartbeat (a node of the run before a restart,
    /// still stepping) leaves the join waiting, and times out naming the node; READY
    /// completes it.
    #[test]
    fn a_running_node_of_the_run_before_does_not_join() {
        use fiberflow_messages::{encode, SCHEMA_VERSION};
        let bus: BusHandle = std::sync::Arc::new(fiberflow_bus::inproc::InprocBus::new());
        let mut run = crate::lockstep::one_piece_run();
        run.expected_nodes = vec!["stiff".into()];
        let t = Topics::new(&run.run_id);
        let mut cfg = crate::config::tests::dns_config();
        cfg.join_timeout_s = 1.0;
        let say = |state: Lifecycle| {
            let hb = Heartbeat {
                schema_version: SCHEMA_VERSION,
                node: "stiff".into(),
                state,
                step: 229,
                dropped: 0,
            };
            let (bus, topic) = (bus.clone(), t.heartbeat("stiff"));
            std::thread::spawn(move || {
                for _ in 0..30 {
                    bus.publish(&topic, &encode(&hb)).unwrap();
                    std::thread::sleep(Duration::from_millis(50));
                }
            })
        };
        let mut hb_in = Inbox::new(
            bus.subscribe(&format!("{}/control/heartbeat/**", t.prefix()))
                .unwrap(),
        );
        let talker = say(Lifecycle::Running);
        let e = join(&cfg, &bus, &t, &run, &mut hb_in)
            .unwrap_err()
            .to_string();
        assert!(e.contains("join timeout") && e.contains("stiff"), "{e}");
        talker.join().unwrap();
        let talker = say(Lifecycle::Ready);
        join(&cfg, &bus, &t, &run, &mut hb_in).unwrap();
        talker.join().unwrap();
    }

    /// A coupled run's dt_plus is checked against the RK3 Courant limit on the field it
    /// starts from, with an error that names the key and the allowed range; field steps
    /// divide the field's time step, and the error says how many would do.
    #[test]
    fn unstable_dt_plus_is_refused_up_front() {
        let cfg = fiberflow_dns::DnsConfig::with_cells(16, 16, 16);
        let solver = Solver::new(cfg).unwrap();
        assert!(check_stability(&solver, 0.05, 1).is_ok());
        let e = check_stability(&solver, 50.0, 1).unwrap_err().to_string();
        assert!(
            e.contains("run.dt_plus")
                && e.contains("Courant")
                && e.contains("(0, ")
                && e.contains("flow.field_steps"),
            "{e}"
        );
        // the bound it states is the bound it applies
        let stated = |e: &str| -> f64 {
            e.rsplit("(0, ")
                .next()
                .and_then(|x| x.split(']').next())
                .unwrap()
                .parse()
                .unwrap()
        };
        let max = stated(&e);
        assert!(check_stability(&solver, 0.999 * max, 1).is_ok());
        assert!(check_stability(&solver, 1.01 * max, 1).is_err());
        // three field steps take three times the coupling step
        let e3 = check_stability(&solver, 50.0, 3).unwrap_err().to_string();
        assert!((stated(&e3) / max - 3.0).abs() < 1e-2, "{e3}");
        assert!(check_stability(&solver, 2.99 * max, 3).is_ok());
        // the field steps it names are enough, and no fewer would do
        let dt = 3.5 * max;
        let e = check_stability(&solver, dt, 1).unwrap_err().to_string();
        let more: u32 = e
            .rsplit("at least ")
            .next()
            .unwrap()
            .trim()
            .parse()
            .unwrap();
        assert_eq!(more, 4, "{e}");
        assert!(check_stability(&solver, dt, more).is_ok(), "{e}");
        assert!(check_stability(&solver, dt, more - 1).is_err(), "{e}");
    }
}
