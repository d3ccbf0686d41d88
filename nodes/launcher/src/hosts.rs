//! Restarts across hosts (docs/architecture.md, "Runs across hosts"): which part a
//! launcher plays in a run, what completes its checkpoints, and where it resumes from.
//!
//! The head (the host with the flow node) decides: its checkpoint of step k is complete
//! when its own nodes' files are in and the flow node has confirmed the other hosts'
//! ([`fiberflow_messages::checkpoints::REMOTE_PIECE`]); it rolls back to the newest such
//! one, as a launcher on one host does. A worker host follows: when one of its nodes dies
//! (or the head restarts the run, which makes them fail) or it is started with `--resume`,
//! it waits for the flow node to say READY, which carries the step the run starts from,
//! and starts its nodes from its own checkpoint of that step.

use crate::nodes::NodeSpec;
use anyhow::{bail, Context, Result};
use fiberflow_bus::Inbox;
use fiberflow_messages::checkpoints::{piece, step_dir, step_of, REMOTE_PIECE};
use fiberflow_messages::Lifecycle;
use fiberflow_messages::NodeRole;
use fiberflow_messages::{lifecycle, Heartbeat};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// The part a launcher plays in its run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// Every node on this host.
    Single,
    /// A multi-host run's host with the flow node; `remote`: some fibre nodes live on
    /// other hosts.
    Head { remote: bool },
    /// A multi-host run's host without the flow node.
    Worker,
}

/// How many of its newest checkpoints a worker host keeps at least.
pub const WORKER_KEEPS: usize = 3;

/// A worker host also keeps every checkpoint within this many steps of its newest. The
/// head completes step c once every node has sent its state of c + 1 and the recorder
/// (which the lockstep keeps at most [`lifecycle::RECORDER_LAG_STEPS`] behind) has c on
/// disk, so its newest complete checkpoint trails a worker's newest by about
/// `RECORDER_LAG_STEPS + 1` steps and a checkpoint interval, more while messages are in
/// flight; with a checkpoint every step, three checkpoints were not enough (test
/// `a_worker_keeps_the_step_the_head_resumes_from`). Four times the lag is kept.
pub const WORKER_WINDOW_STEPS: u64 = 4 * lifecycle::RECORDER_LAG_STEPS;

impl Role {
    pub fn of(spec: &NodeSpec) -> Result<Self> {
        let (Some(_), Some(host)) = (&spec.launch.network, &spec.host) else {
            return Ok(Self::Single);
        };
        if spec
            .launch
            .host(host)?
            .nodes
            .iter()
            .any(|n| NodeRole::Flow.is(n))
        {
            let remote = !crate::nodes::remote_pieces(spec)?.is_empty();
            Ok(Self::Head { remote })
        } else {
            Ok(Self::Worker)
        }
    }

    /// The files that make this host's checkpoint complete: its nodes' and, on a head
    /// with fibre nodes elsewhere, the flow node's confirmation of theirs.
    pub fn pieces(&self, nodes: &[String]) -> Vec<String> {
        let mut p = crate::coupled::pieces(nodes);
        if *self == (Self::Head { remote: true }) {
            p.push(REMOTE_PIECE.to_string());
        }
        p
    }

    /// Points `base` at the step to start again from: the newest complete checkpoint
    /// (head, one host) or the step the flow node announces (worker; `stop`, set by
    /// Ctrl-C or SIGTERM, ends the wait). A worker may instead hear that the run is
    /// complete ([`Next::Complete`]).
    pub fn roll_back(
        &self,
        base: &mut NodeSpec,
        pieces: &[String],
        digest: &str,
        stop: &AtomicBool,
    ) -> Result<Next> {
        match self {
            Self::Worker => follow(base, pieces, stop),
            _ => crate::supervise::roll_back(base, pieces, digest).map(|_| Next::Run),
        }
    }
}

/// What a launcher does after a roll-back.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Next {
    /// Start its nodes from `base.start_step`.
    Run,
    /// Nothing: every node of the run has finished.
    Complete,
}

/// Written to a host's `logs/` once it knows every node of the run finished (on the head
/// by the flow node, on a worker by its launcher): `--resume` of that folder has nothing
/// to do. A fresh run removes it.
pub const RUN_COMPLETE_MARKER: &str = "run.complete";

/// Whether the run in `out_dir` is known complete ([`RUN_COMPLETE_MARKER`]).
pub fn known_complete(out_dir: &Path) -> bool {
    out_dir.join("logs").join(RUN_COMPLETE_MARKER).is_file()
}

/// The line [`RUN_COMPLETE_MARKER`] ends with on the head once every worker host has
/// answered the flow node's COMPLETE.
const EVERY_HOST_KNOWS: &str = "every host knows";

/// Marks the run in `out_dir` complete.
pub fn mark_complete(out_dir: &Path) -> Result<()> {
    let p = out_dir.join("logs").join(RUN_COMPLETE_MARKER);
    std::fs::write(&p, "complete\n").with_context(|| format!("writing {}", p.display()))
}

/// Says the run is complete ([`Lifecycle::Complete`], as the flow node, on `bus`) until
/// every worker host's launcher has answered, or for at most the run's step timeout;
/// notes in the head's [`RUN_COMPLETE_MARKER`] that every host knows.
pub fn say_complete(bus: &fiberflow_bus::BusHandle, spec: &NodeSpec) -> Result<()> {
    let lf = &spec.launch;
    let t = fiberflow_messages::topics::Topics::new(&lf.run.id);
    let mut answers = Inbox::new(bus.subscribe(&format!("{}/control/heartbeat/**", t.prefix()))?);
    let mut waiting: std::collections::BTreeSet<String> =
        worker_hosts(lf).iter().map(|h| host_beat_name(h)).collect();
    let beat = fiberflow_messages::encode(&Heartbeat {
        schema_version: fiberflow_messages::SCHEMA_VERSION,
        node: "flow".into(),
        state: Lifecycle::Complete,
        step: lf.run.steps,
        dropped: 0,
    });
    let deadline = Instant::now() + Duration::from_secs_f64(lf.run.step_timeout_s);
    let mut said: Option<Instant> = None;
    while !waiting.is_empty() && Instant::now() < deadline {
        if said.is_none_or(|t| t.elapsed() >= Duration::from_millis(200)) {
            bus.publish(&t.heartbeat("flow"), &beat)?;
            said = Some(Instant::now());
        }
        if let Some((_, h)) = answers.recv::<Heartbeat>(Duration::from_millis(50)) {
            if h.state == Lifecycle::Complete {
                waiting.remove(&h.node);
            }
        }
    }
    if !waiting.is_empty() {
        let missing: Vec<_> = waiting.into_iter().collect();
        tracing::warn!(hosts = %missing.join(", "), "no answer to \"the run is complete\" from these hosts");
        return Ok(());
    }
    let p = spec.out_dir.join("logs").join(RUN_COMPLETE_MARKER);
    std::fs::write(&p, format!("complete\n{EVERY_HOST_KNOWS}\n"))
        .with_context(|| format!("writing {}", p.display()))
}

/// On a head whose run is complete but whose flow node did not hear every worker host
/// answer (it was killed, or the head's launcher was): says it from a router of its own
/// (the flow node's endpoint), so a worker waiting to learn whether the run starts again
/// hears that it is complete. Anything else: nothing to do.
pub fn tell_workers_complete(base: &NodeSpec, role: Role) -> Result<()> {
    let marker = base.out_dir.join("logs").join(RUN_COMPLETE_MARKER);
    let told = std::fs::read_to_string(&marker).is_ok_and(|m| m.contains(EVERY_HOST_KNOWS));
    if role != (Role::Head { remote: true }) || !known_complete(&base.out_dir) || told {
        return Ok(());
    }
    println!("telling the other hosts that the run is complete");
    let mut spec = base.clone();
    spec.node = "flow".into();
    spec.zenoh_endpoint_file = None;
    let bus = crate::nodes::open_bus(&spec).context("opening the run's router")?;
    say_complete(&bus, &spec)
}

/// The heartbeat name under which a worker host's launcher answers the flow node's
/// COMPLETE.
pub fn host_beat_name(host: &str) -> String {
    format!("host-{host}")
}

/// The hosts of a multi-host launch that do not run the flow node.
pub fn worker_hosts(lf: &crate::launchfile::LaunchFile) -> Vec<String> {
    lf.network
        .iter()
        .flat_map(|n| &n.hosts)
        .filter(|h| !h.nodes.iter().any(|n| NodeRole::Flow.is(n)))
        .map(|h| h.name.clone())
        .collect()
}

/// Removes a worker host's checkpoint folders but its [`WORKER_KEEPS`] newest and those
/// within [`WORKER_WINDOW_STEPS`] of its newest.
pub fn prune_worker(root: &Path) -> Result<()> {
    let mut dirs: Vec<(u64, std::path::PathBuf)> = std::fs::read_dir(root)
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|e| step_of(&e.file_name().to_string_lossy()).map(|k| (k, e.path())))
        .collect();
    dirs.sort();
    let newest = dirs.last().map_or(0, |(k, _)| *k);
    let by_count = dirs.len().saturating_sub(WORKER_KEEPS);
    let by_window = dirs.partition_point(|(k, _)| k + WORKER_WINDOW_STEPS < newest);
    for (_, d) in &dirs[..by_count.min(by_window)] {
        std::fs::remove_dir_all(d).with_context(|| format!("removing {}", d.display()))?;
    }
    Ok(())
}

/// A worker host's restart, or its wait once its nodes have finished: waits (up to the
/// run's step timeout) for the flow node to say READY, and points `base` at this host's
/// checkpoint of the step it says, which must hold every one of `pieces`, and a recorder
/// here at a new segment; or to say COMPLETE, which this host marks and answers. Ctrl-C or
/// SIGTERM (`stop`) ends the wait at once.
pub fn follow(base: &mut NodeSpec, pieces: &[String], stop: &AtomicBool) -> Result<Next> {
    let mut spec = base.clone();
    spec.node = "launcher".into();
    let wait_s = base.launch.run.step_timeout_s;
    println!("waiting for the flow node to say which step the run starts again from, or that it is complete");
    let t0 = Instant::now();
    // joining blocks while the head's router is away: on a thread of its own, so that a
    // stop is heard meanwhile (a thread left behind ends with the process)
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(crate::nodes::open_bus(&spec));
    });
    let bus = loop {
        if stop.load(Ordering::SeqCst) {
            bail!("interrupted while waiting for the flow node to start the run again");
        }
        match rx.recv_timeout(Duration::from_millis(100)) {
            Ok(b) => break b.context("joining the run to learn where it resumes")?,
            Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {}
            Err(e) => bail!("joining the run to learn where it resumes: {e}"),
        }
    };
    let t = fiberflow_messages::topics::Topics::new(&base.launch.run.id);
    let mut hb = Inbox::new(bus.subscribe(&t.heartbeat("flow"))?);
    let k = loop {
        if stop.load(Ordering::SeqCst) {
            bail!("interrupted while waiting for the flow node to start the run again");
        }
        if t0.elapsed().as_secs_f64() > wait_s {
            bail!(
                "the flow node did not start the run again within {wait_s:.0} s \
                 (run.step_timeout_s): is the head's launcher running?"
            );
        }
        if let Some((_, h)) = hb.recv::<Heartbeat>(Duration::from_millis(200)) {
            if h.state == Lifecycle::Ready {
                break h.step;
            }
            if h.state == Lifecycle::Complete {
                // marked before it is answered: a launcher killed after answering finds
                // the mark on --resume (the head closes once every worker answered)
                mark_complete(&base.out_dir)?;
                let host = base.host.clone().unwrap_or_default();
                let ack = Heartbeat {
                    schema_version: fiberflow_messages::SCHEMA_VERSION,
                    node: host_beat_name(&host),
                    state: Lifecycle::Complete,
                    step: h.step,
                    dropped: 0,
                };
                bus.publish(&t.heartbeat(&ack.node), &fiberflow_messages::encode(&ack))?;
                return Ok(Next::Complete);
            }
        }
    };
    base.start_step = k;
    base.resume_dir = None;
    // a recorder on this host goes on in a new segment after the killed one, finished
    for s in crate::coupled::finish_segments(&base.out_dir)? {
        println!("finished the interrupted segment {}", s.display());
    }
    base.segment = fiberflow_messages::segments::next_segment_index(&base.out_dir);
    if k > 0 {
        let root = fiberflow_messages::checkpoints::root(&base.out_dir);
        let dir = step_dir(&root, k);
        let missing: Vec<&String> = pieces
            .iter()
            .filter(|n| !piece(&dir, n).is_file())
            .collect();
        if !missing.is_empty() {
            bail!(
                "the run starts again from step {k}, but this host has no checkpoint of it for {} (in {})",
                missing.iter().map(|s| s.as_str()).collect::<Vec<_>>().join(", "),
                dir.display()
            );
        }
        base.resume_dir = Some(dir);
    }
    Ok(Next::Run)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A worker keeps its three newest checkpoint folders, and every one within
    /// [`WORKER_WINDOW_STEPS`] of the newest.
    #[test]
    fn a_worker_keeps_its_three_newest_checkpoints_and_a_window() {
        let root = std::env::temp_dir().join(format!("ff-worker-ck-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        // the checkpoint folders of `steps` made, the worker pruned: what is left
        let prune = |steps: &mut dyn Iterator<Item = u64>| -> Vec<u64> {
            for k in steps {
                std::fs::create_dir_all(step_dir(&root, k)).unwrap();
            }
            prune_worker(&root).unwrap();
            let mut left: Vec<u64> = std::fs::read_dir(&root)
                .unwrap()
                .flatten()
                .filter_map(|e| step_of(&e.file_name().to_string_lossy()))
                .collect();
            left.sort();
            left
        };
        assert_eq!(
            prune(&mut [20u64, 40, 60, 80, 100].into_iter()),
            [60, 80, 100]
        );
        // a checkpoint every step: the window
        let want: Vec<u64> = (130 - WORKER_WINDOW_STEPS..=130).collect();
        assert_eq!(prune(&mut (101..=130u64)), want);
        std::fs::remove_dir_all(&root).ok();
    }
}
