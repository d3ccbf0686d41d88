//! The launcher's supervision of its node processes: start them (one process group, each
//! dying with its launcher), watch them, stop them with escalation, roll every node back
//! to the newest complete checkpoint and start again when one dies, complete checkpoints
//! in the background. The wiring of a run (its folder, its nodes, what runs after it) is
//! [`crate::launch`].
//!
//! Size: the supervision loop (start, watch, stop, roll back, restart) is one state
//! machine over the node processes.

use crate::launch::progress_thread;
use crate::nodes::{open_bus, NodeSpec};
use anyhow::{bail, Context, Result};
use fiberflow_bus::Transport;
use fiberflow_messages::NodeRole;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// In a child between fork and exec: a launcher killed outright takes its nodes with it
/// (no orphans). The parent-death signal only covers a parent that dies after it is set,
/// so a child whose parent is already gone (re-parented: `getppid` is no longer the
/// launcher) ends at once.
pub(crate) fn die_with_parent(launcher_pid: libc::pid_t) -> std::io::Result<()> {
    // SAFETY: async-signal-safe calls that change no memory of this process
    unsafe {
        if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL) != 0 {
            return Err(std::io::Error::last_os_error());
        }
        if libc::getppid() != launcher_pid {
            libc::_exit(1);
        }
    }
    Ok(())
}

/// Waits for the flow node to write the endpoint its zenoh session got (a loopback run's
/// rendezvous); fails at once, naming its log, if the node ends first.
pub(crate) fn await_endpoint(path: &Path, flow: &mut Node, timeout: Duration) -> Result<String> {
    let t0 = std::time::Instant::now();
    loop {
        if let Ok(text) = std::fs::read_to_string(path) {
            if !text.trim().is_empty() {
                return Ok(text.trim().to_string());
            }
        }
        if let Some(status) = flow.child.try_wait()? {
            bail!(
                "the flow node ended ({status}) before it listened; see {}",
                flow.log.display()
            );
        }
        if t0.elapsed() > timeout {
            bail!(
                "the flow node did not report its zenoh endpoint in {} s ({}); see {}",
                timeout.as_secs(),
                path.display(),
                flow.log.display()
            );
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}

pub(crate) struct Node {
    pub(crate) name: String,
    pub(crate) child: Child,
    pub(crate) log: PathBuf,
}

pub(crate) fn signal_group(pgid: i32, sig: i32) {
    // SAFETY: plain syscall; a stale group id only yields ESRCH
    unsafe {
        libc::kill(-pgid, sig);
    }
}

/// Points `base` at the newest complete checkpoint of its run folder (or the start) and a
/// new recording segment, after finishing any segment whose writer was killed.
pub(crate) fn roll_back(base: &mut NodeSpec, pieces: &[String], digest: &str) -> Result<()> {
    for s in crate::coupled::finish_segments(&base.out_dir)? {
        println!("finished the interrupted segment {}", s.display());
    }
    let root = fiberflow_messages::checkpoints::root(&base.out_dir);
    match crate::coupled::newest(&root, pieces, digest)? {
        Some((k, dir)) => {
            base.start_step = k;
            base.resume_dir = Some(dir);
        }
        None => {
            base.start_step = 0;
            base.resume_dir = None;
        }
    }
    base.segment = fiberflow_messages::segments::next_segment_index(&base.out_dir);
    Ok(())
}

/// Completes checkpoints (manifest, pruning) in the background while the run goes on.
pub(crate) struct Watcher {
    pub(crate) finished: Arc<AtomicBool>,
    pub(crate) handle: Option<std::thread::JoinHandle<()>>,
}

impl Watcher {
    pub(crate) fn stop(mut self) {
        self.finished.store(true, Ordering::SeqCst);
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

/// Completes checkpoints every 0.2 s (a worker host of a multi-host run only prunes its
/// own: the head completes them for the whole run).
pub(crate) fn checkpoint_watcher(
    base: &NodeSpec,
    role: crate::hosts::Role,
    pieces: Vec<String>,
    digest: String,
) -> Watcher {
    let finished = Arc::new(AtomicBool::new(false));
    let root = base.checkpoint_root();
    let handle = root.map(|root| {
        let finished = finished.clone();
        std::thread::spawn(move || loop {
            let last = finished.load(Ordering::SeqCst);
            let done = match role {
                crate::hosts::Role::Worker => crate::hosts::prune_worker(&root).map(|_| None),
                _ => crate::coupled::complete(&root, &pieces, &digest),
            };
            if let Err(e) = done {
                tracing::warn!(error = %format!("{e:#}"), "completing checkpoints");
            }
            if last {
                break;
            }
            std::thread::sleep(Duration::from_millis(200));
        })
    });
    Watcher { finished, handle }
}

/// Runs the nodes as processes; when one dies mid-run and `run.restart` allows it, rolls
/// every node back to the newest complete checkpoint and goes on.
pub(crate) fn supervise_restarts(
    base: &mut NodeSpec,
    role: crate::hosts::Role,
    nodes: &[String],
    pieces: &[String],
    digest: &str,
    stop: Arc<AtomicBool>,
) -> Result<()> {
    let policy = &base.launch.run.restart;
    let can_restart = policy.policy == crate::launchfile::RestartPolicy::OnFailure;
    let max = policy.max_restarts;
    let mut restarts = 0u32;
    loop {
        let started_at = base.start_step;
        let t0;
        let (why, signalled) = match run_processes(base, nodes, stop.clone())? {
            Ended::Finished if role != crate::hosts::Role::Worker => {
                // a flow node killed after it marked the run complete may not have heard
                // every worker answer: the launcher tells them in its place
                return crate::hosts::tell_workers_complete(base, role);
            }
            // a worker's nodes are done, but the head may still roll the run back (say,
            // its recorder killed before the end): the worker waits until the run is
            // complete, and follows a restart meanwhile
            Ended::Finished => {
                t0 = Instant::now();
                if role.roll_back(base, pieces, digest, &stop)? == crate::hosts::Next::Complete {
                    return Ok(());
                }
                let why = "the head started the run again after this host's last step";
                if !can_restart || restarts >= max {
                    bail!("{why}; not restarting (run.restart)");
                }
                (why.to_string(), true)
            }
            Ended::Interrupted => bail!("interrupted"),
            Ended::NodeDied { why, signalled } => {
                if !can_restart {
                    bail!(why);
                }
                if restarts >= max {
                    bail!("{why}; gave up after {max} restart(s) (run.restart.max_restarts)");
                }
                t0 = Instant::now();
                if role.roll_back(base, pieces, digest, &stop)? == crate::hosts::Next::Complete {
                    return Ok(());
                }
                (why, signalled)
            }
        };
        // a node that exits with an error (not killed by a signal) before the run
        // has a newer checkpoint would fail the same way again: the steps are
        // deterministic, and so is a configuration error (a worker host's nodes
        // fail when the head restarts the run, and follow it)
        if !signalled && base.start_step <= started_at && role != crate::hosts::Role::Worker {
            bail!("{why}; not restarting: it failed with an error before any new checkpoint (see its log)");
        }
        restarts += 1;
        let recording = if nodes.iter().any(|n| NodeRole::Recorder.is(n)) {
            format!(
                ", recording into {}",
                fiberflow_messages::segments::segment_name(base.segment)
            )
        } else {
            String::new()
        };
        let msg = format!(
            "{why}; restarting every node from step {} (restart {restarts} of {max}){recording}",
            base.start_step,
        );
        eprintln!("{msg}");
        let log = base.out_dir.join("logs").join("launcher.log");
        let line = format!("{msg} (roll-back took {} ms)\n", t0.elapsed().as_millis());
        let _ = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&log)
            .and_then(|mut f| std::io::Write::write_all(&mut f, line.as_bytes()));
    }
}

/// How a set of node processes ended.
pub(crate) enum Ended {
    Finished,
    Interrupted,
    /// A node exited with a failure (the message names it, its status and its log);
    /// `signalled`: it was killed by a signal (or, the flow node, it lost another node:
    /// [`fiberflow_flow::error::PEER_LOST_EXIT`]) rather than exiting with an error of its
    /// own, which would repeat itself.
    NodeDied {
        why: String,
        signalled: bool,
    },
}

/// The `ZENOH_RUNTIME` a node process is started with: zenoh's thread pools on one worker
/// ([`fiberflow_bus::zenoh_bus::ONE_THREAD_RUNTIME`]) for zenoh on one host, unless the
/// launcher's own environment names a runtime (`user`), which the node then inherits;
/// none for iceoryx2, in-process runs and `[network]` launches (their links carry TLS
/// between hosts, where one thread would encrypt everything).
pub fn node_zenoh_runtime(
    transport: Transport,
    multi_host: bool,
    user: Option<&std::ffi::OsStr>,
) -> Option<&'static str> {
    (transport == Transport::Zenoh && !multi_host && user.is_none())
        .then_some(fiberflow_bus::zenoh_bus::ONE_THREAD_RUNTIME)
}

/// Runs the nodes here as processes and supervises them until the run ends. Long (≈105
/// lines): the supervision loop's cases (exit, failure, stop signal) in one place.
pub(crate) fn run_processes(
    base: &NodeSpec,
    nodes: &[String],
    stop: Arc<AtomicBool>,
) -> Result<Ended> {
    let zenoh = base.transport == Transport::Zenoh;
    let rendezvous = if let (Some(net), Some(h)) = (&base.launch.network, &base.host) {
        println!(
            "host {h}: nodes {}; zenoh over mutual TLS via {} (access control: {})",
            nodes.join(", "),
            net.rendezvous,
            net.allowed_common_names.join(", ")
        );
        net.rendezvous.clone()
    } else if zenoh {
        // the flow node listens on a port the OS gives it and reports it (below)
        String::new()
    } else {
        println!(
            "iceoryx2 shared memory, services fiberflow/{}/...",
            base.launch.run.id
        );
        "iceoryx2".to_string()
    };
    // an earlier incarnation's "last step served" is not this one's
    let flow_done = base
        .out_dir
        .join("logs")
        .join(crate::nodes::FLOW_DONE_MARKER);
    match std::fs::remove_file(&flow_done) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            return Err(e).with_context(|| format!("removing {}", flow_done.display()))
        }
        _ => {}
    }
    let endpoint_file = base.out_dir.join("endpoint.txt");
    let loopback_zenoh = zenoh && rendezvous.is_empty();
    if loopback_zenoh {
        // a stale endpoint of an earlier run must not be read as this one's
        match std::fs::remove_file(&endpoint_file) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                return Err(e).with_context(|| format!("removing {}", endpoint_file.display()))
            }
            _ => {}
        }
    } else {
        std::fs::write(&endpoint_file, &rendezvous)?;
    }
    let mut rendezvous = rendezvous;
    let exe = std::env::current_exe().context("locating the fiberflow executable")?;
    let mut children: Vec<Node> = Vec::new();
    let mut pgid: i32 = 0;
    for (n, members) in processes(nodes, base.launch.run.fiber_processes) {
        let mut spec = process_spec(base, &members);
        if !zenoh {
            // shared memory: nothing to configure
        } else if NodeRole::Flow.is(&n) && loopback_zenoh {
            spec.zenoh_listen = vec!["tcp/127.0.0.1:0".into()];
            spec.zenoh_endpoint_file = Some(endpoint_file.clone());
        } else if NodeRole::Flow.is(&n) {
            spec.zenoh_listen = vec![rendezvous.clone()];
        } else {
            spec.zenoh_listen = vec!["tcp/127.0.0.1:0".into()];
            spec.zenoh_connect = vec![rendezvous.clone()];
        }
        let spec_path = base.out_dir.join("config").join(format!("{n}.toml"));
        std::fs::write(&spec_path, toml::to_string(&spec)?)?;
        let log = base.out_dir.join("logs").join(format!("{n}.log"));
        // appended: a restarted node's log follows the one that died
        let mut logf = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&log)
            .with_context(|| format!("opening {}", log.display()))?;
        if base.start_step > 0 || base.segment > 0 {
            use std::io::Write;
            writeln!(logf, "---- restarted from step {} ----", base.start_step)?;
        }
        let mut cmd = Command::new(&exe);
        cmd.arg("node")
            .arg("--spec")
            .arg(&spec_path)
            .stdin(Stdio::null())
            .stdout(logf.try_clone()?)
            .stderr(logf)
            .process_group(pgid);
        if let Some(rt) = node_zenoh_runtime(
            base.transport,
            base.launch.network.is_some(),
            std::env::var_os("ZENOH_RUNTIME").as_deref(),
        ) {
            cmd.env("ZENOH_RUNTIME", rt);
        }
        let launcher_pid = std::process::id() as libc::pid_t;
        // SAFETY: prctl, getppid and _exit are async-signal-safe; they only set this
        // child's parent-death signal or end it
        unsafe {
            cmd.pre_exec(move || die_with_parent(launcher_pid));
        }
        let child = cmd.spawn().with_context(|| format!("starting node {n}"))?;
        if pgid == 0 {
            pgid = child.id() as i32;
        }
        children.push(Node {
            name: n.clone(),
            child,
            log,
        });
        if NodeRole::Flow.is(&n) && loopback_zenoh {
            let flow = children.last_mut().context("the flow node's process")?;
            rendezvous = await_endpoint(&endpoint_file, flow, Duration::from_secs(120))?;
            println!("zenoh rendezvous {rendezvous} (loopback only, multicast scouting off)");
        } else if NodeRole::Flow.is(&n) {
            std::thread::sleep(Duration::from_millis(200));
        }
    }
    // the launcher's own bus connection, for the progress bar
    let mut me = base.clone();
    me.node = "launcher".into();
    if zenoh {
        me.zenoh_listen = vec!["tcp/127.0.0.1:0".into()];
        me.zenoh_connect = vec![rendezvous];
    }
    let finished = Arc::new(AtomicBool::new(false));
    // a multi-host run shows no progress bar: one more client of the router per host
    // only adds traffic to the links the run depends on
    let prog = if base.launch.network.is_none() {
        let bus = open_bus(&me)?;
        Some(progress_thread(bus, &base.launch, finished.clone())?)
    } else {
        None
    };
    let result = supervise(
        &mut children,
        pgid,
        &stop,
        &base
            .out_dir
            .join("logs")
            .join(crate::hosts::RUN_COMPLETE_MARKER),
    );
    finished.store(true, Ordering::SeqCst);
    if let Some(p) = prog {
        let _ = p.join();
    }
    result
}

/// The spec of a process (or in-process thread) that runs its first node and the others
/// beside it.
pub(crate) fn process_spec(base: &NodeSpec, members: &[String]) -> NodeSpec {
    let mut spec = base.clone();
    if let Some((first, rest)) = members.split_first() {
        spec.node = first.clone();
        spec.co_nodes = rest.to_vec();
    }
    spec
}

/// The node processes of one launcher, in start order: (process name, its nodes). The
/// flow node and the recorder run alone; with `fiber_processes` = N ≥ 1 the fibre nodes
/// are cut into N runs of consecutive nodes, near-equal in count, named `fibers-1`, …
/// (a run of one keeps its node's name); with 0 each is a process of its own.
pub(crate) fn processes(nodes: &[String], fiber_processes: u32) -> Vec<(String, Vec<String>)> {
    let is_fiber = |n: &String| NodeRole::Fiber.is(n);
    let fibers: Vec<&String> = nodes.iter().filter(|n| is_fiber(n)).collect();
    let k = if fiber_processes == 0 {
        fibers.len()
    } else {
        (fiber_processes as usize).min(fibers.len())
    };
    let mut chunks: Vec<Vec<String>> = Vec::new();
    let mut rest = &fibers[..];
    for i in 0..k {
        let take = rest.len().div_ceil(k - i);
        let (a, b) = rest.split_at(take);
        chunks.push(a.iter().map(|n| n.to_string()).collect());
        rest = b;
    }
    let mut out = Vec::new();
    let mut chunks = chunks.into_iter().enumerate();
    for n in nodes {
        if !is_fiber(n) {
            out.push((n.clone(), vec![n.clone()]));
        } else {
            // the fibre processes take the place of the first fibre node (the iterator
            // is empty after that)
            for (i, c) in chunks.by_ref() {
                let name = match &c[..] {
                    [one] => one.clone(),
                    _ => format!("fibers-{}", i + 1),
                };
                out.push((name, c));
            }
        }
    }
    out
}

/// Waits for the children; on a signal or a failed node, stops the rest (TERM, then KILL).
/// Watches the node processes until all have exited: the first failure (or a stop) ends
/// the others. A flow node killed after it wrote `run_complete` (every node of the run
/// said DONE: [`crate::hosts::RUN_COMPLETE_MARKER`]) is not a failure: the others finish
/// as usual.
pub(crate) fn supervise(
    children: &mut [Node],
    pgid: i32,
    stop: &AtomicBool,
    run_complete: &Path,
) -> Result<Ended> {
    let mut ended: Option<Ended> = None;
    let mut exited = vec![false; children.len()];
    loop {
        if stop.load(Ordering::SeqCst) && ended.is_none() {
            ended = Some(Ended::Interrupted);
            signal_group(pgid, libc::SIGTERM);
        }
        for (i, n) in children.iter_mut().enumerate() {
            if exited[i] {
                continue;
            }
            if let Some(st) = n.child.try_wait()? {
                exited[i] = true;
                if !st.success() && NodeRole::Flow.is(&n.name) && run_complete.is_file() {
                    tracing::warn!(status = %st, "the flow node ended once the run was complete");
                    continue;
                }
                if !st.success() && ended.is_none() {
                    let why = format!(
                        "node {} exited with {st}; its log: {}",
                        n.name,
                        n.log.display()
                    );
                    // killed by a signal, or a flow node that lost another node: not a
                    // failure that would repeat itself
                    let signalled = std::os::unix::process::ExitStatusExt::signal(&st).is_some()
                        || st.code() == Some(fiberflow_flow::error::PEER_LOST_EXIT);
                    ended = Some(Ended::NodeDied { why, signalled });
                    signal_group(pgid, libc::SIGTERM);
                }
            }
        }
        if exited.iter().all(|e| *e) {
            break;
        }
        if ended.is_some() {
            // escalation: give the group 3 s to finish (recorder closes its file), then KILL
            let t0 = Instant::now();
            while t0.elapsed() < Duration::from_secs(3) {
                if children
                    .iter_mut()
                    .all(|n| matches!(n.child.try_wait(), Ok(Some(_))))
                {
                    break;
                }
                std::thread::sleep(Duration::from_millis(20));
            }
            signal_group(pgid, libc::SIGKILL);
            for n in children.iter_mut() {
                let _ = n.child.wait();
            }
            break;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    Ok(ended.unwrap_or(Ended::Finished))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A flow node killed after it wrote the "last step served" marker is not a failure:
    /// the other node finishes and the run is done; without the marker the same kill is a
    /// death that ends the others at once.
    #[test]
    fn a_flow_node_killed_once_the_run_is_complete_is_not_restarted() {
        let dir = std::env::temp_dir().join(format!("ff-run-complete-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let marker = dir.join(crate::hosts::RUN_COMPLETE_MARKER);
        for done in [true, false] {
            let _ = std::fs::remove_file(&marker);
            if !done {
                // a flow node that lost another node (status 75) may be restarted like a
                // killed one; an error of its own (status 1) may not
                for (code, restartable) in [(75, true), (1, false)] {
                    let mut c = Command::new("sh");
                    c.args(["-c", &format!("exit {code}")]).process_group(0);
                    let child = c.spawn().unwrap();
                    let pgid = child.id() as i32;
                    let mut one = vec![Node {
                        name: "flow".into(),
                        child,
                        log: dir.join("flow.log"),
                    }];
                    match supervise(&mut one, pgid, &AtomicBool::new(false), &marker).unwrap() {
                        Ended::NodeDied { signalled, .. } => assert_eq!(signalled, restartable),
                        _ => panic!("status {code}: not a death"),
                    }
                }
            }
            let node = |name: &str, script: &str| {
                let mut c = Command::new("sh");
                c.args(["-c", script]).process_group(0);
                Node {
                    name: name.into(),
                    child: c.spawn().unwrap(),
                    log: dir.join(format!("{name}.log")),
                }
            };
            let flow_script = if done {
                format!("echo 7 > {}; kill -9 $$", marker.display())
            } else {
                "kill -9 $$".to_string()
            };
            let flow = node("flow", &flow_script);
            let pgid = flow.child.id() as i32;
            let mut children = vec![flow, node("case1", "sleep 0.5")];
            let t0 = Instant::now();
            let ended = supervise(&mut children, pgid, &AtomicBool::new(false), &marker).unwrap();
            match (done, ended) {
                (true, Ended::Finished) => assert!(t0.elapsed() >= Duration::from_millis(400)),
                (false, Ended::NodeDied { signalled, .. }) => assert!(signalled),
                (done, _) => panic!("marker {done}: wrong ending"),
            }
        }
        std::fs::remove_dir_all(&dir).ok();
    }

    /// A child whose launcher is not its parent any more (it died before the parent-death
    /// signal was set) ends at once with status 1; one whose launcher lives goes on. (A
    /// launcher killed while its nodes run: tests/e2e.rs,
    /// `a_launcher_killed_outright_takes_its_nodes_with_it`.)
    #[test]
    fn a_child_whose_launcher_is_not_its_parent_ends_at_once() {
        // (the launcher it was started by is its parent, status 0; is not, status 1)
        for (launcher_is_parent, status) in [(true, 0), (false, 1)] {
            // SAFETY: the child calls only async-signal-safe functions, then _exit
            let pid = unsafe { libc::fork() };
            assert!(pid >= 0, "fork failed");
            if pid == 0 {
                // SAFETY: as above
                unsafe {
                    let launcher = if launcher_is_parent {
                        libc::getppid()
                    } else {
                        -1
                    };
                    let _ = die_with_parent(launcher);
                    libc::_exit(0);
                }
            }
            let mut st = 0;
            // SAFETY: waits for the child forked above
            unsafe { libc::waitpid(pid, &mut st, 0) };
            assert!(libc::WIFEXITED(st), "child did not exit: {st}");
            assert_eq!(libc::WEXITSTATUS(st), status);
        }
    }

    /// Node processes of a one-host zenoh launch get zenoh's one-thread runtime; a user's
    /// own `ZENOH_RUNTIME`, iceoryx2, in-process runs and multi-host launches keep theirs.
    #[test]
    fn one_host_zenoh_nodes_run_zenoh_on_one_thread() {
        use fiberflow_bus::zenoh_bus::ONE_THREAD_RUNTIME;
        let user = std::ffi::OsStr::new("(rx: (worker_threads: 4))");
        assert_eq!(
            node_zenoh_runtime(Transport::Zenoh, false, None),
            Some(ONE_THREAD_RUNTIME)
        );
        assert_eq!(
            node_zenoh_runtime(Transport::Zenoh, false, Some(user)),
            None
        );
        assert_eq!(node_zenoh_runtime(Transport::Zenoh, true, None), None);
        assert_eq!(node_zenoh_runtime(Transport::Iceoryx2, false, None), None);
        assert_eq!(node_zenoh_runtime(Transport::Inproc, false, None), None);
    }

    /// 30 steps of the analytic-shear launch on `bus` (in-process threads, recorder
    /// included); returns every recorded state by (topic, step).
    /// `run.fiber_processes`: 0 keeps a process per node; N cuts the fibre nodes into N
    /// runs of consecutive nodes, near-equal, between the flow node and the recorder.
    #[test]
    fn fiber_nodes_are_spread_over_the_processes_asked_for() {
        let nodes: Vec<String> = ["flow", "a", "b", "c", "d", "e", "recorder"]
            .map(String::from)
            .to_vec();
        let shape = |k| -> Vec<(String, String)> {
            processes(&nodes, k)
                .into_iter()
                .map(|(p, n)| (p, n.join(" ")))
                .collect()
        };
        let own = |n: &str| (n.to_string(), n.to_string());
        assert_eq!(
            shape(0),
            ["flow", "a", "b", "c", "d", "e", "recorder"]
                .map(own)
                .to_vec()
        );
        let p = |name: &str, n: &str| (name.to_string(), n.to_string());
        assert_eq!(
            shape(1),
            [own("flow"), p("fibers-1", "a b c d e"), own("recorder")]
        );
        assert_eq!(
            shape(2),
            [
                own("flow"),
                p("fibers-1", "a b c"),
                p("fibers-2", "d e"),
                own("recorder")
            ]
        );
        // as many processes as nodes, or more: a process each, named by its node
        assert_eq!(shape(5), shape(0));
        assert_eq!(shape(9), shape(0));
        // a launcher with no fibre nodes (a worker host may have only some)
        let alone = ["flow".to_string()];
        assert_eq!(
            processes(&alone, 3),
            [("flow".to_string(), vec!["flow".to_string()])]
        );
    }
}
