//! Runs that survive (coupled checkpoints, restart, resume): real processes killed with
//! SIGKILL mid-run; the fibre states over all recording segments must be bitwise those of
//! an uninterrupted run.

use fiberflow_e2e::*;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// The quick launch, shortened: 120 coupling steps (30 t+), a checkpoint every 5 t+.
fn quick_sets() -> Vec<String> {
    [
        "run.steps=120",
        "run.checkpoint_every_plus=5",
        "run.analyze=false",
        "run.step_timeout_s=60",
    ]
    .iter()
    .map(|s| s.to_string())
    // the fluid-velocity start: its step 0 is published twice, which a resume must respect
    .chain((1..=6).map(|c| format!("fibers.case{c}.initial_velocity=\"fluid\"")))
    .collect()
}

fn launch_cmd(out: &Path, transport: &str, extra: &[&str]) -> Command {
    let mut c = Command::new(fiberflow());
    c.arg("launch")
        .arg(root().join("launch/quick.toml"))
        .arg("--transport")
        .arg(transport);
    for s in quick_sets() {
        c.arg("--set").arg(s);
    }
    c.args(extra);
    if !extra.contains(&"--resume") {
        c.arg("--out").arg(out);
    }
    c
}

/// A launch in the background with its output captured to files.
fn spawn(out: &Path, transport: &str) -> std::process::Child {
    spawn_with(out, transport, &[])
}

/// [`spawn`] with more arguments.
fn spawn_with(out: &Path, transport: &str, extra: &[&str]) -> std::process::Child {
    std::fs::create_dir_all(out).unwrap();
    let so = std::fs::File::create(out.with_extension("stdout")).unwrap();
    let se = std::fs::File::create(out.with_extension("stderr")).unwrap();
    launch_cmd(out, transport, extra)
        .stdout(so)
        .stderr(se)
        .spawn()
        .expect("launch")
}

/// Sends `signal` to the process of `node` in the run in `out` (asserting it is found, one
/// process, while `child`, the launch, still goes).
fn signal_node(out: &Path, node: &str, child: &mut std::process::Child, signal: i32) {
    let spec = out
        .join(format!("config/{node}.toml"))
        .display()
        .to_string();
    let pids = pids_with(&spec);
    assert_eq!(
        pids.len(),
        1,
        "node {node} not found (run over already: {})",
        child.try_wait().ok().flatten().is_some()
    );
    unsafe { libc::kill(pids[0], signal) };
}

/// The kills land this long at most after the first checkpoint (step 20), while the run
/// still goes: well inside the time the remaining 100 steps take.
const KILL_WITHIN_MS: u64 = 700;

/// A pseudo-random delay in [0, max_ms) from the clock (printed, so a failure can be
/// matched to it).
fn random_delay(max_ms: u64) -> Duration {
    let ns = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .subsec_nanos() as u64;
    let ms = (ns.wrapping_mul(0x9E37_79B9) >> 7) % max_ms;
    eprintln!("kill delay {ms} ms after the first complete checkpoint");
    Duration::from_millis(ms)
}

fn text(p: PathBuf) -> String {
    std::fs::read_to_string(p).unwrap_or_default()
}

/// Every state payload of every group, by step, over all segments; no step twice.
fn all_states(dir: &Path) -> BTreeMap<(String, u64), Vec<u8>> {
    let (states, segments) = states_by_step(dir);
    assert!(segments >= 1);
    states
}

fn assert_same(reference: &BTreeMap<(String, u64), Vec<u8>>, dir: &Path, what: &str) {
    let got = all_states(dir);
    assert_eq!(
        got.len(),
        reference.len(),
        "{what}: {} states, the uninterrupted run has {}",
        got.len(),
        reference.len()
    );
    for (k, v) in reference {
        let g = got
            .get(k)
            .unwrap_or_else(|| panic!("{what}: state {k:?} missing"));
        assert!(
            g == v,
            "{what}: state {k:?} differs from the uninterrupted run"
        );
    }
}

#[test]
fn killed_nodes_and_launcher_lose_nothing() {
    let _one = one_run_at_a_time();
    let dir = scratch("survive");
    // the uninterrupted run
    let reference_out = dir.join("reference");
    let o = launch_cmd(&reference_out, "zenoh", &[]).output().unwrap();
    assert!(
        o.status.success(),
        "reference run failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let reference = all_states(&reference_out);
    assert_eq!(reference.len(), 6 * 121, "six groups, steps 0..=120");
    // the fibres start at the fluid's velocity, and the recorded step 0 says so
    let s0: fiberflow_messages::FiberGroupState =
        fiberflow_messages::decode(&reference[&("case1".to_string(), 0)]).unwrap();
    assert!(
        s0.velocity.iter().any(|v| v.abs() > 1.0) && s0.angular_velocity.iter().any(|w| *w != 0.0),
        "step 0 recorded with v = ω = 0 although the fibres start at the fluid's velocity"
    );

    // kill -9 of one node at a random step after the first checkpoint: the launcher rolls
    // everything back to the newest complete checkpoint and the run completes on its own
    // (states are bitwise the same over every transport: both process transports here)
    for (node, transport) in [
        ("case3", "zenoh"),
        ("flow", "iceoryx2"),
        ("recorder", "zenoh"),
    ] {
        let out = dir.join(format!("kill-{node}"));
        let mut child = spawn(&out, transport);
        wait_for_checkpoint(&out, 90);
        std::thread::sleep(random_delay(KILL_WITHIN_MS));
        signal_node(&out, node, &mut child, libc::SIGKILL);
        let st = child.wait().unwrap();
        let err = text(out.with_extension("stderr"));
        assert!(
            st.success(),
            "run with killed {node} did not complete: {err}"
        );
        assert!(
            err.contains(&format!("node {node} exited"))
                && err.contains("restarting every node from step"),
            "the launcher must say which node died and where it resumed: {err}"
        );
        let segs = fiberflow_messages::segments::segment_paths(&out).unwrap();
        assert!(
            segs.len() >= 2,
            "a restart records into a new segment: {segs:?}"
        );
        assert_same(&reference, &out, &format!("kill -9 {node}"));
        assert!(
            pids_with(&out.display().to_string()).is_empty(),
            "orphans left"
        );
    }

    // kill -9 of the launcher and every node at once (shared memory left behind), then
    // --resume
    let out = dir.join("kill-all");
    let mut child = spawn(&out, "iceoryx2");
    wait_for_checkpoint(&out, 90);
    std::thread::sleep(random_delay(KILL_WITHIN_MS));
    kill_host(&mut child, &out);
    let o = launch_cmd(&out, "iceoryx2", &["--resume", out.to_str().unwrap()])
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let so = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "resume failed: {so}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(so.contains("resuming"), "{so}");
    assert_same(&reference, &out, "kill -9 of everything, then --resume");
    // the segments are finished files: the Rust reader's summary opens each
    for seg in fiberflow_messages::segments::segment_paths(&out).unwrap() {
        let b = std::fs::read(&seg).unwrap();
        assert!(
            matches!(mcap::Summary::read(&b), Ok(Some(_))),
            "{} is not a finished MCAP",
            seg.display()
        );
    }
    // inspect and view read the folder as one recording
    let i = Command::new(fiberflow())
        .arg("inspect")
        .arg(&out)
        .output()
        .unwrap();
    let it = String::from_utf8_lossy(&i.stdout);
    assert!(
        i.status.success() && it.contains("segment(s)") && !it.contains("DAMAGED"),
        "{it}"
    );
    let rrd = out.join("scene.rrd");
    let v = Command::new(fiberflow())
        .arg("view")
        .arg(&out)
        .arg("--save")
        .arg(&rrd)
        .output()
        .unwrap();
    assert!(v.status.success(), "{}", String::from_utf8_lossy(&v.stderr));
    assert!(std::fs::metadata(&rrd).unwrap().len() > 10_000);
    // replay republishes the segments as one recording: every state once
    let echoed = replay_and_echo(&out, "quick");
    for g in 1..=6 {
        let line = format!("total fiberflow/quick/fibers/case{g}/state 121");
        assert!(echoed.contains(&line), "missing {line}");
    }
    // analysis reads the folder as one recording
    let a = Command::new(fiberflow())
        .arg("analyze")
        .arg(&out)
        .output()
        .unwrap();
    assert!(a.status.success(), "{}", String::from_utf8_lossy(&a.stderr));
    let csv = std::fs::read_to_string(out.join("analysis/case1_fibers.csv")).unwrap();
    assert_eq!(
        csv.lines().count() - 1,
        121 * 50,
        "121 states of 50 fibres, once each"
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// A fibre node that hangs (SIGSTOP: alive to the kernel and the launcher, silent on the
/// bus, as a node behind a lost link or on a frozen host is) is found by its missing pulse
/// after `run.liveness_s` (here 4 s; the step timeout is 60 s): the flow node fails the
/// step naming it, the launcher rolls every node back to the newest checkpoint (the hung
/// process killed with the others) and the run completes with every state bitwise that of
/// an uninterrupted run.
#[test]
fn a_hung_fiber_node_is_found_by_its_silence_and_the_run_goes_on() {
    let _one = one_run_at_a_time();
    let dir = scratch("hung");
    let reference_out = dir.join("reference");
    let o = launch_cmd(&reference_out, "zenoh", &[]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let reference = all_states(&reference_out);
    let out = dir.join("hung");
    let mut child = spawn_with(&out, "zenoh", &["--set", "run.liveness_s=4"]);
    wait_for_checkpoint(&out, 90);
    std::thread::sleep(random_delay(KILL_WITHIN_MS));
    signal_node(&out, "case2", &mut child, libc::SIGSTOP);
    let st = child.wait().unwrap();
    let err = text(out.with_extension("stderr"));
    assert!(
        st.success(),
        "run with a hung case2 did not complete: {err}"
    );
    assert!(
        err.contains("restarting every node from step"),
        "the launcher must restart the run: {err}"
    );
    let flow_log = text(out.join("logs/flow.log"));
    assert!(
        flow_log.contains("fibre node(s) case2")
            && flow_log.contains("silent for more than run.liveness_s"),
        "the flow node must name the silent node: {flow_log}"
    );
    assert_same(&reference, &out, "a hung case2");
    assert!(
        pids_with(&out.display().to_string()).is_empty(),
        "the hung process outlived the run"
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// A node that exits with an error before any checkpoint (here: the flow node's restart
/// file does not exist) is not restarted over and over: the launcher stops at once and
/// says which node, why it did not restart, and where its log is.
#[test]
fn deterministic_failure_is_not_restarted() {
    let _one = one_run_at_a_time();
    let dir = scratch("no-restart");
    let out = dir.join("run");
    let o = Command::new(fiberflow())
        .arg("launch")
        .arg(root().join("launch/quick.toml"))
        .args(["--transport", "zenoh", "--out"])
        .arg(&out)
        .args(["--set", "flow.source.restart=/nonexistent/flow.ckpt"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("node flow exited")
            && err.contains("not restarting")
            && err.contains("flow.log"),
        "{err}"
    );
    assert!(!err.contains("restart 1 of"), "it was restarted: {err}");
    std::fs::remove_dir_all(&dir).ok();
}

/// A run folder belongs to its live launcher: a second launch with the same `--out`, and a
/// `--resume` of the run while it still goes, are refused before they touch the folder,
/// naming the live process (a resume would otherwise finish the live recorder's segment
/// and resume from a checkpoint the live run then prunes, losing states).
#[test]
fn a_live_run_folder_is_not_launched_or_resumed_into() {
    let _one = one_run_at_a_time();
    let out = scratch("live-folder");
    let file = root().join("launch/validation/analytic-shear.toml");
    let sets = [
        "run.steps=100000000",
        "recorder.enabled=false",
        "run.analyze=false",
    ];
    let cmd = |extra: &[&str]| {
        let mut c = Command::new(fiberflow());
        c.arg("launch").arg(&file).args(["--transport", "inproc"]);
        for s in sets {
            c.arg("--set").arg(s);
        }
        c.args(extra);
        c
    };
    let out_s = out.to_string_lossy().to_string();
    let mut live = cmd(&["--out", &out_s])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("launch");
    let pid = live.id().to_string();
    let lock = out.join(".fiberflow.lock");
    let from = Instant::now();
    while std::fs::read_to_string(&lock).unwrap_or_default() != pid {
        assert!(
            live.try_wait().unwrap().is_none(),
            "the live run ended early"
        );
        assert!(
            from.elapsed() < Duration::from_secs(60),
            "no lock after 60 s"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let launch_toml = std::fs::read_to_string(out.join("launch.toml")).ok();
    for extra in [
        vec!["--out", out_s.as_str()],
        vec!["--resume", out_s.as_str()],
    ] {
        let o = cmd(&extra).output().unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr);
        let stdout = String::from_utf8_lossy(&o.stdout);
        assert!(!o.status.success(), "{extra:?} was not refused:\n{stdout}");
        assert!(
            stderr.contains("in use by a live run") && stderr.contains(&format!("process {pid}")),
            "{extra:?}: {stderr}"
        );
        assert!(
            !stdout.contains("finished the interrupted segment"),
            "{stdout}"
        );
    }
    assert!(
        live.try_wait().unwrap().is_none(),
        "the live run was disturbed"
    );
    assert_eq!(
        std::fs::read_to_string(out.join("launch.toml")).ok(),
        launch_toml,
        "the live run's launch.toml was touched"
    );
    live.kill().unwrap();
    live.wait().unwrap();
    std::fs::remove_dir_all(&out).ok();
}
