//! The flow node's coupling loop (DESIGN §3): join barrier, run announcement, then lockstep
//! — for each step k, wait for every group's state at t_k, sample v and ∇v at its segment
//! centres from the field at t_k, publish, and advance the field to t_{k+1}.

use crate::analytic::AnalyticFlow;
use crate::config::{FlowNodeConfig, FlowSource};
use crate::error::FlowError;
use fiberflow_bus::{BusHandle, DropCounter, Inbox};
use fiberflow_dns::sample::Sampler;
use fiberflow_dns::Solver;
use fiberflow_messages::topics::Topics;
use fiberflow_messages::{
    encode, lifecycle, FiberGroupState, FlowProfiles, FlowSamples, FlowStatus, Heartbeat,
    RunAnnouncement, SCHEMA_VERSION,
};
use std::collections::{BTreeMap, BTreeSet};
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
}

enum Field {
    Analytic(AnalyticFlow),
    Dns(Box<Solver>, Sampler),
}

/// What the loop did.
#[derive(Debug, Clone, PartialEq)]
pub struct ServeSummary {
    pub steps: u64,
    pub drops: DropCounter,
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
    let mut field = match &cfg.source {
        FlowSource::Analytic { flow } => Field::Analytic(*flow),
        FlowSource::Dns { dns, restart } => {
            let mut d = dns.clone();
            d.dt_fixed_plus = Some(cfg.dt_plus);
            let mut s = Solver::new(d)?;
            if let Some(r) = restart {
                s.read_checkpoint(r)?;
            }
            let smp = Sampler::with_scheme(&s.grid, cfg.interpolation);
            Field::Dns(Box::new(s), smp)
        }
    };
    let mut hb_in = Inbox::new(bus.subscribe(&format!("{}/control/heartbeat/**", t.prefix()))?);
    let mut st_in = Inbox::new(bus.subscribe(&format!("{}/fibers/**", t.prefix()))?);
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
    bus.publish(&t.announce(), &encode(&ann))?;
    tracing::info!(groups = ?run.groups, steps = run.steps, "run announced");
    let step_timeout = Duration::from_secs_f64(run.step_timeout_s);
    let mut pending: BTreeMap<String, FiberGroupState> = BTreeMap::new();
    // running plane/time statistics of the served field, published as FlowProfiles
    let mut stats: Option<fiberflow_dns::stats::RunningStats> = None;
    for k in 0..=run.steps {
        // gather every group's state at step k
        let wait_from = Instant::now();
        while pending.len() < run.groups.len() {
            let left = step_timeout.saturating_sub(wait_from.elapsed());
            if left.is_zero() {
                let missing: Vec<_> = run
                    .groups
                    .iter()
                    .filter(|g| !pending.contains_key(*g))
                    .cloned()
                    .collect();
                heartbeat(&bus, &t, lifecycle::FAILED, k, st_in.drops.total())?;
                return Err(FlowError::Protocol(format!(
                    "step {k}: no state from fibre group(s) {} within {:.0} s",
                    missing.join(", "),
                    run.step_timeout_s
                )));
            }
            let Some((topic, bytes)) = st_in.recv_raw(left) else {
                continue;
            };
            if !topic.ends_with("/state") {
                continue; // metrics and other fibre topics are not for us
            }
            match fiberflow_messages::decode::<FiberGroupState>(&bytes) {
                Ok(s) if s.step == k && run.groups.contains(&s.group) => {
                    pending.insert(s.group.clone(), s);
                }
                Ok(s) => {
                    tracing::debug!(group = %s.group, step = s.step, expected = k, "ignoring out-of-step state")
                }
                Err(e) => st_in.drops.drop_one(&topic, &e.to_string()),
            }
        }
        let t_plus = k as f64 * cfg.dt_plus;
        for (group, s) in std::mem::take(&mut pending) {
            let n = s.centre.len() / 3;
            let mut vel = Vec::with_capacity(3 * n);
            let mut grad = Vec::with_capacity(9 * n);
            for p in s.centre.chunks_exact(3) {
                let (v, g) = match &field {
                    Field::Analytic(a) => a.sample([p[0], p[1], p[2]]),
                    Field::Dns(solver, smp) => {
                        let re = solver.cfg.re_tau;
                        let sm = smp.sample(
                            &solver.grid,
                            &solver.vel,
                            [p[0] / re, p[1] / re, p[2] / re],
                        );
                        let mut g = sm.grad;
                        g.iter_mut().for_each(|x| *x /= re);
                        (sm.vel, g)
                    }
                };
                vel.extend_from_slice(&v);
                grad.extend_from_slice(&g);
            }
            let msg = FlowSamples {
                schema_version: SCHEMA_VERSION,
                group: group.clone(),
                step: k,
                t_plus,
                velocity: vel,
                velocity_gradient: grad,
            };
            bus.publish(&t.flow_samples(&group), &encode(&msg))?;
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
            },
            Field::Dns(solver, _) => {
                let r = solver.step()?;
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
                    bus.publish(&t.flow_profiles(), &encode(&msg))?;
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
            bus.publish(&t.flow_status(), &encode(&status))?;
            on_status(&status);
        }
    }
    heartbeat(&bus, &t, lifecycle::DONE, run.steps, st_in.drops.total())?;
    let mut drops = st_in.drops.clone();
    for (k, v) in hb_in.drops.by_topic {
        *drops.by_topic.entry(k).or_insert(0) += v;
    }
    Ok(ServeSummary {
        steps: run.steps,
        drops,
    })
}
