//! Runs across hosts that are really apart: launchers in Linux network namespaces (each
//! with its own network stack and its own /dev/shm), joined by veth pairs through a
//! bridge, zenoh over mutual TLS between them, with faults on the links
//! (`launch/multi-host/netns.sh`). Needs root, iproute2 and nftables; skipped, saying
//! so, when not run as root.

use fiberflow_e2e::*;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

/// True when run as root. Otherwise the test is skipped, and says so on the terminal
/// past the test harness's capture (a passing test's output is hidden); with
/// `FIBERFLOW_REQUIRE_ROOT_TESTS=1` (as `.ci/run` sets when it runs as root) a skip fails.
fn as_root() -> bool {
    // SAFETY: geteuid has no preconditions
    let root = unsafe { libc::geteuid() } == 0;
    if !root {
        let why = "SKIPPED: network-namespace tests need root, iproute2 and nftables \
                   (run the end-to-end tests as root)";
        assert!(
            std::env::var("FIBERFLOW_REQUIRE_ROOT_TESTS").as_deref() != Ok("1"),
            "{why}, but FIBERFLOW_REQUIRE_ROOT_TESTS=1"
        );
        use std::io::Write;
        let _ = writeln!(std::io::stderr().lock(), "\n{why}");
    }
    root
}

/// A finished launcher's stdout and stderr together.
fn said(o: &std::process::Output) -> String {
    String::from_utf8_lossy(&o.stdout).to_string() + &String::from_utf8_lossy(&o.stderr)
}

/// The same (group, step) keys, and the same bytes under each.
fn assert_same_by_step(
    a: &std::collections::BTreeMap<(String, u64), Vec<u8>>,
    b: &std::collections::BTreeMap<(String, u64), Vec<u8>>,
    what: &str,
) {
    assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
    for (k, v) in a {
        assert!(v == &b[k], "{k:?}: {what}");
    }
}

/// The namespaces of one test, removed when dropped.
struct Hosts {
    prefix: String,
}

impl Hosts {
    fn script() -> PathBuf {
        root().join("launch/multi-host/netns.sh")
    }

    fn up(prefix: &str) -> Self {
        let h = Self {
            prefix: prefix.to_string(),
        };
        h.down();
        h.call(&["up"]);
        h
    }

    fn command(&self, args: &[&str]) -> Command {
        let mut c = Command::new(Self::script());
        c.args(args).env("FFNS", &self.prefix);
        c
    }

    fn call(&self, args: &[&str]) {
        let o = self.command(args).output().expect("running netns.sh");
        assert!(
            o.status.success(),
            "netns.sh {args:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
    }

    fn down(&self) {
        let _ = self.command(&["down"]).output();
    }

    /// `fiberflow launch FILE --host HOST --out DIR` on the namespace `ns` (head, w1).
    fn launch(
        &self,
        ns: &str,
        file: &Path,
        host: &str,
        out: &Path,
        sets: &[&str],
    ) -> std::process::Child {
        self.launcher(ns, file, host, ("--out", out), sets)
    }

    /// `fiberflow launch FILE --host HOST --resume DIR` (with the run's `--set` options) on
    /// the namespace `ns`.
    fn resume(
        &self,
        ns: &str,
        file: &Path,
        host: &str,
        dir: &Path,
        sets: &[&str],
    ) -> std::process::Child {
        self.launcher(ns, file, host, ("--resume", dir), sets)
    }

    fn launcher(
        &self,
        ns: &str,
        file: &Path,
        host: &str,
        (flag, dir): (&str, &Path),
        sets: &[&str],
    ) -> std::process::Child {
        let mut c = self.command(&["run", ns]);
        c.arg(fiberflow())
            .arg("launch")
            .arg(file)
            .args(["--host", host, flag])
            .arg(dir);
        for s in sets {
            c.arg("--set").arg(s);
        }
        c.stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("starting a launcher in a namespace")
    }
}

impl Drop for Hosts {
    fn drop(&mut self) {
        self.down();
    }
}

/// The analytic-shear launch split over `head` (flow, recorder, case1, at 10.77.0.1)
/// and `worker` (stiff, at 10.77.0.2), with certificates naming those addresses.
fn namespaced_launch(dir: &Path) -> PathBuf {
    let st = Command::new(root().join("launch/multi-host/make-certs.sh"))
        .arg(dir.join("certs"))
        .args(["head=10.77.0.1", "worker=10.77.0.2"])
        .stdout(Stdio::null())
        .status()
        .expect("running launch/multi-host/make-certs.sh (needs openssl)");
    assert!(st.success(), "make-certs.sh failed");
    let base =
        std::fs::read_to_string(root().join("launch/validation/analytic-shear.toml")).unwrap();
    let text = base + &two_host_network("tls/10.77.0.1:7447", "tls/10.77.0.1:7447", "worker");
    let file = dir.join("two-hosts.toml");
    std::fs::write(&file, text).unwrap();
    file
}

/// Two hosts in two network namespaces, 1% of the worker's TCP packets dropped both ways
/// for the whole run and, 3 s into it, its link cut silently for 10 s: the run (4000
/// steps of analytic shear) completes on both hosts and records the same fibre states,
/// bit for bit, as the run in one process.
///
/// (It was ignored while zenoh's TLS link lost messages on a healthy link; see
/// `two_launchers_over_tls_lose_no_lockstep_message`.)
#[test]
fn two_hosts_apart_survive_packet_loss_and_a_partition_bitwise() {
    if !as_root() {
        return;
    }
    let _one = one_run_at_a_time();
    let dir = scratch("netns");
    let file = namespaced_launch(&dir);
    let hosts = Hosts::up(&format!("ff{}", std::process::id() % 100_000));
    hosts.call(&["loss", "w1", "1"]);
    let sets = ["run.steps=4000", "run.checkpoint_every_plus=500"];
    let head = hosts.launch("head", &file, "head", &dir.join("head"), &sets);
    std::thread::sleep(Duration::from_millis(500));
    let worker = hosts.launch("w1", &file, "worker", &dir.join("worker"), &sets);
    std::thread::sleep(Duration::from_secs(3));
    hosts.call(&["partition", "w1", "10"]);
    assert_all_succeed(vec![("head", head), ("worker", worker)]);
    assert_two_hosts_match_one_process(
        &dir.join("head/run.mcap"),
        &sets,
        "two hosts apart, with loss and a partition",
    );
}

/// Two hosts in two namespaces (analytic shear: head with the flow node, the recorder and
/// case1; worker with stiff), a checkpoint every 200 steps of 4000: once the head has a
/// complete checkpoint, the worker's whole launcher is killed (`kill -9`; its nodes die
/// with it) and started again with `--resume`. The head's flow node finds the worker's
/// node silent (`run.liveness_s = 4`), the head rolls back to its newest complete
/// checkpoint, the worker resumes from the same step, and both complete: the head's
/// segments hold every state of steps 0..=4000 once, bit for bit those of the run in one
/// process.
#[test]
fn a_killed_worker_launcher_resumes_and_the_run_completes_bitwise() {
    two_hosts_survive_a_kill(Kill::Launcher);
}

/// The same with only the worker's fibre node killed (`kill -9`): the worker's launcher
/// restarts it from the step the head's restarted flow node says.
#[test]
fn a_killed_node_on_the_worker_restarts_both_hosts_bitwise() {
    two_hosts_survive_a_kill(Kill::Node);
}

/// The same with the head's whole launcher killed (`kill -9`: the flow node, the recorder
/// and case1 die with it) and started again with `--resume`: it rolls back to its newest
/// complete checkpoint; the worker's node, waiting for samples, sees the flow node start
/// again and fails, and the worker's launcher restarts it from the same step.
#[test]
fn a_killed_head_launcher_resumes_and_the_worker_follows_bitwise() {
    two_hosts_survive_a_kill(Kill::HeadLauncher);
}

/// What dies.
#[derive(PartialEq)]
enum Kill {
    /// The worker's whole launcher, started again with `--resume`.
    Launcher,
    /// The worker's fibre node `stiff`.
    Node,
    /// The head's whole launcher, started again with `--resume`.
    HeadLauncher,
}

fn two_hosts_survive_a_kill(kill: Kill) {
    if !as_root() {
        return;
    }
    let _one = one_run_at_a_time();
    let name = match kill {
        Kill::Launcher => "netns-kill",
        Kill::Node => "netns-kill-node",
        Kill::HeadLauncher => "netns-kill-head",
    };
    let dir = scratch(name);
    let file = namespaced_launch(&dir);
    let hosts = Hosts::up(&format!("fk{}", std::process::id() % 100_000));
    let sets = [
        "run.steps=4000",
        "run.checkpoint_every_plus=100",
        "run.liveness_s=4",
    ];
    let mut head = hosts.launch("head", &file, "head", &dir.join("head"), &sets);
    std::thread::sleep(Duration::from_millis(500));
    let mut worker = hosts.launch("w1", &file, "worker", &dir.join("worker"), &sets);
    wait_for_checkpoint(&dir.join("head"), 300);
    if kill == Kill::HeadLauncher {
        // SAFETY: plain syscall on a child we started (netns.sh execs into the launcher)
        unsafe {
            libc::kill(head.id() as i32, libc::SIGKILL);
        }
        let _ = head.wait();
        head = hosts.resume("head", &file, "head", &dir.join("head"), &sets);
    }
    let worker = match kill {
        Kill::HeadLauncher => worker,
        Kill::Launcher => {
            // SAFETY: plain syscall on a child we started (netns.sh execs into the launcher)
            unsafe {
                libc::kill(worker.id() as i32, libc::SIGKILL);
            }
            let _ = worker.wait();
            hosts.resume("w1", &file, "worker", &dir.join("worker"), &sets)
        }
        Kill::Node => {
            let spec = dir.join("worker/config/stiff.toml");
            let pids = pids_with(&format!("--spec {}", spec.display()));
            assert_eq!(pids.len(), 1, "the worker's fibre node: {pids:?}");
            // SAFETY: plain syscall on a process this test's launcher started
            unsafe {
                libc::kill(pids[0], libc::SIGKILL);
            }
            worker
        }
    };
    let (restarted, follows) = match kill {
        Kill::HeadLauncher => (worker, head),
        _ => (head, worker),
    };
    // the side that rolled back by itself says so; the other completes
    let out = restarted
        .wait_with_output()
        .expect("waiting for a launcher");
    let text = said(&out);
    assert!(out.status.success(), "failed:\n{text}");
    assert!(
        text.contains("restarting every node from step"),
        "no restart:\n{text}"
    );
    assert_all_succeed(vec![("the other host", follows)]);
    let (b, _) = states_by_step(&dir.join("head"));
    let one = scratch(&format!("{name}-one"));
    launch_with(
        &root().join("launch/validation/analytic-shear.toml"),
        &one,
        "inproc",
        &sets,
    );
    let (a, _) = states_by_step(&one);
    assert_eq!(a.len(), 2 * 4001, "two groups, steps 0..=4000");
    assert_same_by_step(&a, &b, "the restarted two-host run's state differs");
}

/// Three hosts (`launch/multi-host/three-hosts.toml`, 6 × 10⁴ fibres in three shards per
/// group over both workers): once the head has a complete checkpoint, w1's whole launcher
/// is killed (`kill -9`) and started again with `--resume`. The head's flow node finds
/// w1's nodes silent (`run.liveness_s = 10`) and the head rolls back; w2's nodes, alive
/// in the middle of the run, see the flow node start again and fail, and w2's launcher
/// restarts them from the step the flow node says, as w1's resumed launcher does. All
/// three complete, and the head's segments hold every group's states once, bit for bit
/// those of the same fibres unsharded in one process.
#[test]
fn three_hosts_a_killed_worker_resumes_and_the_other_follows_bitwise() {
    if !as_root() {
        return;
    }
    let _one = one_run_at_a_time();
    let dir = scratch("netns3-kill");
    let file = three_hosts_launch(&dir);
    let hosts = Hosts::up(&format!("fm{}", std::process::id() % 100_000));
    // 10 s: with 6 × 10⁴ fibres starting in 18 processes on two cores, a node's first
    // state can take longer than 4 s after the join
    let sets = ["run.liveness_s=10", "flow.join_timeout_s=120"];
    let head = hosts.launch("head", &file, "head", &dir.join("head"), &sets);
    std::thread::sleep(Duration::from_millis(500));
    let mut w1 = hosts.launch("w1", &file, "w1", &dir.join("w1"), &sets);
    let w2 = hosts.launch("w2", &file, "w2", &dir.join("w2"), &sets);
    wait_for_checkpoint(&dir.join("head"), 300);
    // SAFETY: plain syscall on a child we started (netns.sh execs into the launcher)
    unsafe {
        libc::kill(w1.id() as i32, libc::SIGKILL);
    }
    let _ = w1.wait();
    let again = hosts.resume("w1", &file, "w1", &dir.join("w1"), &sets);
    let outputs: Vec<(&str, std::process::Output)> = vec![
        ("head", head.wait_with_output().unwrap()),
        ("w2", w2.wait_with_output().unwrap()),
        ("w1, resumed", again.wait_with_output().unwrap()),
    ];
    for (name, o) in &outputs {
        let text = said(o);
        assert!(o.status.success(), "{name} failed:\n{text}");
        let want = match *name {
            "w1, resumed" => "resuming",
            _ => "restarting every node from step",
        };
        assert!(text.contains(want), "{name} did not say {want:?}:\n{text}");
    }
    let b = whole_states(&dir.join("head"));
    let a = one_process_states(&dir, &file);
    assert_eq!(a.len(), 6 * 7, "six groups, a state every 10 of 60 steps");
    assert_same_by_step(&a, &b, "the restarted three hosts' state differs");
}

/// Certificates for the three namespaced hosts and a copy of
/// `launch/multi-host/three-hosts.toml` beside them; returns the launch file.
fn three_hosts_launch(dir: &Path) -> PathBuf {
    let st = Command::new(root().join("launch/multi-host/make-certs.sh"))
        .arg(dir.join("certs"))
        .args(["head=10.77.0.1", "w1=10.77.0.2", "w2=10.77.0.3"])
        .stdout(Stdio::null())
        .status()
        .expect("running launch/multi-host/make-certs.sh (needs openssl)");
    assert!(st.success(), "make-certs.sh failed");
    let file = dir.join("three-hosts.toml");
    std::fs::copy(root().join("launch/multi-host/three-hosts.toml"), &file).unwrap();
    file
}

/// Every group's whole states of the three-host launch `file` run with each group whole
/// (`shards = 1`) in one process.
fn one_process_states(
    dir: &Path,
    file: &Path,
) -> std::collections::BTreeMap<(String, u64), Vec<u8>> {
    let one = scratch(&format!(
        "{}-one",
        dir.file_name().unwrap().to_string_lossy()
    ));
    let text = std::fs::read_to_string(file).unwrap();
    let text = &text[..text.find("[network]").unwrap()];
    let path = dir.join("one.toml");
    std::fs::write(&path, text.replace("shards = 3", "shards = 1")).unwrap();
    launch_with(&path, &one, "inproc", &[]);
    whole_states(&one)
}

/// Waits until the flow node has written the checkpoint of `step` in `out`.
fn wait_for_flow_checkpoint(out: &Path, step: u64, secs: u64) {
    let file = out.join(format!("checkpoints/step-{step:09}/flow.ckpt"));
    let t0 = std::time::Instant::now();
    while !file.exists() {
        assert!(
            t0.elapsed() < Duration::from_secs(secs),
            "no flow checkpoint {} after {secs} s",
            file.display()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Three hosts in three namespaces (`launch/multi-host/three-hosts.toml`): the head with
/// the flow node and the recorder, two workers with 6 × 10⁴ fibres, every group in three
/// shards spread over both. 1% of every host's TCP packets dropped, both ways, for the
/// whole run, and w1 cut off silently for 12 s once the head has written the checkpoint of
/// step 20 (of 60): every launcher completes without a restart and the head's recording
/// holds every group's states, bit for bit those of the same fibres unsharded in one
/// process.
///
/// Once, with zenoh's default link lease of 10 s (now 30 s), a 10 s partition closed w1's
/// link on one end only: its client reconnected while the router still held the old link
/// ("Resource remapped"), w1 was never heard again and the flow node gave up after
/// run.liveness_s. Not seen again since (this test passed with the 10 s lease too).
#[test]
fn three_hosts_with_loss_on_every_link_and_a_partition_match_one_process() {
    if !as_root() {
        return;
    }
    let _one = one_run_at_a_time();
    let dir = scratch("netns3");
    let file = three_hosts_launch(&dir);
    let hosts = Hosts::up(&format!("ff{}", std::process::id() % 100_000));
    for h in ["head", "w1", "w2"] {
        hosts.call(&["loss", h, "1"]);
    }
    let mut children = vec![(
        "head",
        hosts.launch("head", &file, "head", &dir.join("head"), &[]),
    )];
    std::thread::sleep(Duration::from_millis(500));
    for w in ["w1", "w2"] {
        children.push((w, hosts.launch(w, &file, w, &dir.join(w), &[])));
    }
    wait_for_flow_checkpoint(&dir.join("head"), 20, 300);
    hosts.call(&["partition", "w1", "12"]);
    // ridden through on the same links: no node is taken as gone, nothing restarts
    let head = children.remove(0).1.wait_with_output().unwrap();
    let text = said(&head);
    assert!(head.status.success(), "head failed:\n{text}");
    assert!(!text.contains("restarting"), "the head restarted:\n{text}");
    assert_all_succeed(children);
    let b = whole_states(&dir.join("head"));
    let a = one_process_states(&dir, &file);
    assert_eq!(a.len(), 6 * 7, "six groups, a state every 10 of 60 steps");
    assert_same_by_step(&a, &b, "the three hosts' state differs from one process'");
}

/// Two launchers on one machine (zenoh router and clients over mutual TLS on loopback), a
/// healthy link, 4000 steps of analytic shear: no lockstep message is lost while both ends
/// live — no fibre node waits the 5 s after which it sends its state again, the flow node
/// never sends samples again — and the recording holds every state, bit for bit the
/// in-process run's. Before zenoh's TLS link was patched
/// (`third_party/zenoh-link-tls/README.fiberflow.md`) the link failed every few seconds
/// and 4 of 6 such runs lost messages (1–3 each).
#[test]
fn two_launchers_over_tls_lose_no_lockstep_message() {
    let _one = one_run_at_a_time();
    let dir = scratch("tls-clean");
    let file = two_host_launch(&dir, "worker", "");
    let sets = ["run.steps=4000"];
    let head = launch_host(&file, "head", &dir.join("head"), &sets);
    std::thread::sleep(Duration::from_millis(500));
    let worker = launch_host(&file, "worker", &dir.join("worker"), &sets);
    assert_all_succeed(vec![("head", head), ("worker", worker)]);
    for log in [
        "head/logs/flow.log",
        "head/logs/case1.log",
        "worker/logs/stiff.log",
    ] {
        let text = std::fs::read_to_string(dir.join(log)).unwrap();
        let resent: Vec<&str> = text
            .lines()
            .filter(|l| l.contains("sending the state again") || l.contains("sending them again"))
            .collect();
        assert!(
            resent.is_empty(),
            "{log}: a message was lost in transit:\n{}",
            resent.join("\n")
        );
    }
    let b = states(&dir.join("head/run.mcap"));
    assert_eq!(b["case1"].len(), 4001, "every state of case1 recorded");
    assert_two_hosts_match_one_process(&dir.join("head/run.mcap"), &sets, "two launchers over TLS");
}
