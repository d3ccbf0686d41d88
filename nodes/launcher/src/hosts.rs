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
        if spec.launch.host(host)?.nodes.iter().any(|n| n == "flow") {
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
    /// Ctrl-C or SIGTERM, ends the wait).
    pub fn roll_back(
        &self,
        base: &mut NodeSpec,
        pieces: &[String],
        digest: &str,
        stop: &AtomicBool,
    ) -> Result<()> {
        match self {
            Self::Worker => follow(base, pieces, stop),
            _ => crate::launch::roll_back(base, pieces, digest),
        }
    }
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

/// A worker host's restart: waits (up to the run's step timeout) for the flow node to
/// say READY and points `base` at this host's checkpoint of the step it says, which must
/// hold every one of `pieces`, and a recorder here at a new segment. Ctrl-C or SIGTERM
/// (`stop`) ends the wait at once.
fn follow(base: &mut NodeSpec, pieces: &[String], stop: &AtomicBool) -> Result<()> {
    let mut spec = base.clone();
    spec.node = "launcher".into();
    let wait_s = base.launch.run.step_timeout_s;
    println!("waiting for the flow node to say which step the run starts again from");
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
            if h.state == lifecycle::READY {
                break h.step;
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
    Ok(())
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
