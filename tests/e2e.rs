//! End-to-end tests: real `fiberflow` processes on real transports.

use fiberflow_e2e::*;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// Large messages (1500 fibres: ≈ 1 MB of samples and 0.3 MB of states per step) take the
/// transports' shared-memory paths — zenoh's pools (the flow node logs adding one) and
/// iceoryx2's in-place delivery — and still give the in-process bus's states bit for bit.
/// Over iceoryx2 the two fibre nodes share one process, where a group this large gets a
/// thread of its own (`fiberflow_fiber::serve::serve_many`).
#[test]
fn large_messages_in_shared_memory_give_identical_states() {
    let _one = one_run_at_a_time();
    let file = root().join("launch/validation/analytic-shear.toml");
    let sets = ["run.steps=40", "fibers.case1.placement.per_layer=300"];
    let a = scratch("large-inproc");
    launch_with(&file, &a, "inproc", &sets);
    let sa = states(&a.join("run.mcap"));
    for transport in ["zenoh", "iceoryx2"] {
        let b = scratch(&format!("large-{transport}"));
        let mut sets = sets.to_vec();
        if transport == "iceoryx2" {
            sets.push("run.fiber_processes=1");
        }
        launch_with(&file, &b, transport, &sets);
        let sb = states(&b.join("run.mcap"));
        assert_eq!(sa["case1"].len(), 41, "case1: states for steps 0..=40");
        if transport == "iceoryx2" {
            let logs = std::fs::read_dir(b.join("logs")).unwrap().flatten();
            let names: Vec<String> = logs
                .map(|e| e.file_name().to_string_lossy().to_string())
                .collect();
            assert!(names.contains(&"fibers-1.log".to_string()), "{names:?}");
            let log = std::fs::read_to_string(b.join("logs/fibers-1.log")).unwrap();
            assert!(log.contains("fibre nodes on a thread each"), "{log}");
        }
        assert_same_states(&sa, &sb, transport);
        if transport == "zenoh" {
            let log = std::fs::read_to_string(b.join("logs/flow.log")).unwrap();
            if log.contains("no zenoh shared memory") {
                // a pool is locked in memory (mlock): without CAP_IPC_LOCK or a large enough
                // `ulimit -l` zenoh cannot make one and the messages are copied — the states
                // above are still checked, the shared-memory path is not
                eprintln!("zenoh shared memory unavailable on this machine: path not checked");
            } else {
                assert!(
                    log.contains("zenoh shared-memory pool added"),
                    "the flow node's samples did not go through zenoh shared memory"
                );
            }
        }
    }
}

/// The same launch over the in-process bus, over zenoh and over iceoryx2 (separate
/// processes for both) records bitwise-identical fibre states.
#[test]
fn transports_give_bitwise_identical_states() {
    let _one = one_run_at_a_time();
    let file = root().join("launch/validation/analytic-shear.toml");
    let a = scratch("inproc");
    launch(&file, &a, "inproc");
    let sa = states(&a.join("run.mcap"));
    assert_eq!(sa.keys().collect::<Vec<_>>(), vec!["case1", "stiff"]);
    for transport in ["zenoh", "iceoryx2"] {
        let b = scratch(transport);
        // over iceoryx2 the fibre nodes run idle-scheduled: they say so, the flow node and
        // the recorder do not, and no bit changes
        let idle = transport == "iceoryx2";
        let sets: &[&str] = if idle {
            &["run.fiber_scheduling=idle"]
        } else {
            &[]
        };
        launch_with(&file, &b, transport, sets);
        for (node, want) in [
            ("case1", idle),
            ("stiff", idle),
            ("flow", false),
            ("recorder", false),
        ] {
            let log = std::fs::read_to_string(b.join(format!("logs/{node}.log"))).unwrap();
            assert_eq!(
                log.contains("running under SCHED_IDLE"),
                want,
                "{transport}: {node}'s log"
            );
        }
        let sb = states(&b.join("run.mcap"));
        let w = warnings_in_logs(&b);
        assert!(
            w.is_empty(),
            "a healthy {transport} run logged warnings: {w:#?}"
        );
        for (g, v) in &sa {
            assert_eq!(v.len(), 201, "group {g}: states for steps 0..=200");
        }
        assert_same_states(&sa, &sb, transport);
    }
    // the recording carries its provenance
    let md = metadata(&a.join("run.mcap"));
    assert_eq!(md["fiberflow.run"]["run_id"], "analytic-shear");
    assert!(md["fiberflow.node_configs"].contains_key("case1"));
}

/// The flow alone (no fibre group) with the recorder on runs to its last step and records
/// its status at every step: the flow node does not wait for the recorder to hold fibre
/// states there are none of.
#[test]
fn the_flow_alone_with_the_recorder_on_runs_to_the_end() {
    let _one = one_run_at_a_time();
    let dir = scratch("flow-alone");
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("flow-alone.toml");
    std::fs::write(
        &file,
        "[run]\nid = \"flow-alone\"\nsteps = 30\ndt_plus = 0.5\nstep_timeout_s = 20\n\n\
         [flow]\nstatus_every_steps = 1\n\n\
         [flow.source]\nkind = \"analytic\"\nflow = { kind = \"simple_shear\", shear_rate = 0.1 }\n",
    )
    .unwrap();
    let out = dir.join("run");
    // (before, the launch failed at step 5, after `run.step_timeout_s`)
    launch(&file, &out, "inproc");
    // the status of every step 1..=30, read by the independent Python reader
    let summary = decode_all(&out.join("run.mcap"));
    assert!(
        summary.contains("\"fiberflow_msgs/msg/FlowStatus\": 30"),
        "{summary}"
    );
}

/// Runs tests/decode_all.py (the independent Python reader and ROS 2 decoder) on a
/// recording; its JSON summary, after asserting it succeeded.
fn decode_all(mcap: &std::path::Path) -> String {
    let o = Command::new("python3")
        .arg(root().join("tests/decode_all.py"))
        .arg(mcap)
        .output()
        .expect("python3");
    let text = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(
        o.status.success(),
        "decode failed: {text}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    text
}

/// The MCAP opens with the Python `mcap` reader and every message decodes with the
/// independent `mcap-ros2-support` CDR decoder against the stored `.msg` schemas.
#[test]
fn recording_decodes_with_independent_reader() {
    let _one = one_run_at_a_time();
    assert!(
        python_ok(),
        "python3 with `mcap` and `mcap-ros2-support` is required (pip install mcap mcap-ros2-support)"
    );
    let out = scratch("python");
    launch(
        &root().join("launch/validation/analytic-shear.toml"),
        &out,
        "inproc",
    );
    let text = decode_all(&out.join("run.mcap"));
    for t in [
        "FiberGroupState",
        "FiberGroupMetrics",
        "FlowSamples",
        "FlowStatus",
        "Heartbeat",
        "RunAnnouncement",
        "PointCloud2",
    ] {
        assert!(text.contains(t), "no {t} messages decoded: {text}");
    }
    assert!(text.contains("\"case1\": 200"), "{text}");
}

/// Steps of a run that the test itself stops (Ctrl-C or a kill): the most `run.steps`
/// allows, so the run cannot end first however fast it steps (the analytic-shear run
/// steps at ≈ 0.3 ms).
const UNTIL_STOPPED: u64 = 100_000_000;

fn long_launch(dir: &std::path::Path, steps: u64) -> std::path::PathBuf {
    let text =
        std::fs::read_to_string(root().join("launch/validation/analytic-shear.toml")).unwrap();
    let text = text
        .replace("steps = 200", &format!("steps = {steps}"))
        .replace("dt_plus = 0.5", "dt_plus = 0.05");
    let p = dir.join("long.toml");
    std::fs::write(&p, text).unwrap();
    p
}

/// Starts a zenoh launch in the background; returns it with its rendezvous endpoint.
fn spawn_launch(file: &std::path::Path, out: &std::path::Path) -> (std::process::Child, String) {
    let child = Command::new(fiberflow())
        .arg("launch")
        .arg(file)
        .arg("--out")
        .arg(out)
        .arg("--transport")
        .arg("zenoh")
        .stdout(Stdio::null())
        .stderr(
            std::fs::File::create(out.with_extension("stderr"))
                .map(Stdio::from)
                .expect("launcher stderr file"),
        )
        .spawn()
        .expect("launch");
    let endpoint = wait_for(&out.join("endpoint.txt"), 20);
    (child, endpoint)
}

/// Waits until the recorder has opened `run.mcap` in `out` (the run is underway), so a
/// test that interrupts the run does not depend on how fast the processes started.
fn wait_for_recording(out: &std::path::Path, secs: u64) {
    wait_for_recording_bytes(out, 1, secs);
}

/// Waits until the recorder has written `bytes` to `out/run.mcap` (the run is stepping).
fn wait_for_recording_bytes(out: &std::path::Path, bytes: u64, secs: u64) {
    let path = out.join("run.mcap");
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_secs(secs) {
        if std::fs::metadata(&path).is_ok_and(|m| m.len() >= bytes) {
            return;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    panic!(
        "{} did not reach {bytes} bytes within {secs} s\n{}",
        path.display(),
        log_tails(out)
    );
}

/// The last lines of every node's log in `out/logs`, for a failure's message.
fn log_tails(out: &std::path::Path) -> String {
    let mut s = String::new();
    let Ok(dir) = std::fs::read_dir(out.join("logs")) else {
        return "(no logs)".into();
    };
    let mut paths: Vec<_> = dir.filter_map(|e| e.ok().map(|e| e.path())).collect();
    paths.sort();
    for p in paths {
        let text = std::fs::read_to_string(&p).unwrap_or_default();
        let lines: Vec<&str> = text.lines().collect();
        s += &format!("--- {}\n", p.display());
        for l in &lines[lines.len().saturating_sub(8)..] {
            s += l;
            s.push('\n');
        }
    }
    s
}

fn wait_for(path: &std::path::Path, secs: u64) -> String {
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_secs(secs) {
        if let Ok(s) = std::fs::read_to_string(path) {
            if !s.is_empty() {
                return s;
            }
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    panic!("{} did not appear", path.display());
}

/// 10,000 random byte strings on every topic during a run: no node crashes, the fibre states
/// are bitwise identical to a clean run's (none missing), and the recorder counts 10,000
/// drops per topic.
#[test]
fn garbage_on_every_topic_is_dropped_and_counted() {
    let _one = one_run_at_a_time();
    inject_into_a_run("garbage", false);
}

/// The same with 10,000 messages per topic that decode (valid CDR of the topic's type)
/// but make no sense: arrays that disagree with the segment counts, NaN and infinite
/// values, unknown groups and nodes, steps beyond the run, announcements of another run.
/// No node panics or stalls, the states are bitwise those of a clean run, and the
/// recorder counts every one of them.
#[test]
fn inconsistent_messages_are_dropped_and_counted() {
    let _one = one_run_at_a_time();
    inject_into_a_run("nonsense", true);
}

/// Injects into a run far longer than the test and stops it (Ctrl-C) once the injector is
/// done and the run has stepped on for 2 s more, so the run cannot end before the
/// injection arrives, however fast it steps (an 8000-step run once ended 1.7 s after its
/// recording appeared, before the injector had reached it); then compares every recorded
/// state with a clean in-process run of as many steps.
fn inject_into_a_run(name: &str, structured: bool) {
    let dir = scratch(name);
    let file = long_launch(&dir, UNTIL_STOPPED);
    let dirty = dir.join("dirty");
    let (mut child, endpoint) = spawn_launch(&file, &dirty);
    // wait until the recorder has joined and the run is stepping
    wait_for_recording(&dirty, 60);
    std::thread::sleep(Duration::from_secs(1));
    let topics = [
        "control/announce",
        "control/heartbeat/flow",
        "control/heartbeat/case1",
        "flow/status",
        "flow/samples/case1",
        "flow/samples/stiff",
        "fibers/case1/state",
        "fibers/case1/metrics",
        "fibers/stiff/state",
    ];
    let mut inj = Command::new(fiberflow());
    inj.args([
        "inject",
        "--run",
        "analytic-shear",
        "--connect",
        endpoint.trim(),
        "--count",
        "10000",
    ]);
    for t in topics {
        inj.args(["--topic", t]);
    }
    if structured {
        inj.arg("--structured");
    }
    let injecting = Instant::now();
    let o = inj.output().expect("inject");
    // what the injector said (e.g. topics without a subscriber) and how long it took, for
    // a failure below
    let injector = format!(
        "injection took {:.1} s; injector said: {} {}",
        injecting.elapsed().as_secs_f64(),
        String::from_utf8_lossy(&o.stdout).trim(),
        String::from_utf8_lossy(&o.stderr).trim()
    );
    assert!(o.status.success(), "{injector}\n{}", log_tails(&dirty));
    // the injected messages cross loopback in milliseconds; the run steps on meanwhile
    std::thread::sleep(Duration::from_secs(2));
    assert!(
        child.try_wait().expect("launcher status").is_none(),
        "the run ended during the injection\n{}",
        log_tails(&dirty)
    );
    unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
    let _ = child.wait();
    let md = metadata(&dirty.join("run.mcap"));
    assert!(
        md.contains_key("fiberflow.run"),
        "recording not finished after Ctrl-C\n{}",
        log_tails(&dirty)
    );
    // no node failed and was restarted (a restart starts a new segment)
    let (b, segments) = states_by_step(&dirty);
    assert_eq!(segments, 1, "a node was restarted\n{}", log_tails(&dirty));
    let last = b
        .keys()
        .map(|(_, step)| *step)
        .max()
        .expect("states recorded");
    let clean = dir.join("clean");
    launch_with(&file, &clean, "inproc", &[&format!("run.steps={last}")]);
    let (a, _) = states_by_step(&clean);
    for (key, state) in &b {
        assert!(
            a.get(key) == Some(state),
            "garbage changed the state {key:?} (of {} recorded, steps up to {last})",
            b.len()
        );
    }
    // and none is missing: every state of the clean run up to the step every group
    // reached before the Ctrl-C is recorded (the groups stop one step apart at most)
    let mut reached: std::collections::BTreeMap<&str, u64> = Default::default();
    for (g, step) in b.keys() {
        let r = reached.entry(g.as_str()).or_insert(0);
        *r = (*r).max(*step);
    }
    let common = reached.values().copied().min().unwrap_or(0);
    let missing: Vec<_> = a
        .keys()
        .filter(|(_, step)| *step <= common)
        .filter(|k| !b.contains_key(*k))
        .collect();
    assert!(
        missing.is_empty(),
        "states missing from the run under injection (steps up to {common}): {missing:?}"
    );
    let drops = &md["fiberflow.drops"];
    for t in topics {
        let key = format!("fiberflow/analytic-shear/{t}");
        assert_eq!(
            drops.get(&key).map(String::as_str),
            Some("10000"),
            "drops on {key}: {drops:?}; {injector}"
        );
    }
}

/// kill -9 of the launcher alone mid-run: its nodes (processes it started, its children)
/// end instead of running on as orphans (the parent-death signal each node sets before it
/// starts; the run would go on until stopped, so 30 s is only how long the test waits).
#[test]
fn a_launcher_killed_outright_takes_its_nodes_with_it() {
    let _one = one_run_at_a_time();
    let dir = scratch("kill-launcher");
    let file = long_launch(&dir, UNTIL_STOPPED);
    let out = dir.join("run");
    let (mut child, _) = spawn_launch(&file, &out);
    wait_for_recording_bytes(&out, 1 << 20, 60);
    let nodes = pids_with(&out.display().to_string());
    assert!(nodes.len() >= 3, "nodes running: {nodes:?}");
    // SAFETY: plain syscall on the launcher this test started
    unsafe { libc::kill(child.id() as i32, libc::SIGKILL) };
    let _ = child.wait();
    let t0 = Instant::now();
    while !pids_with(&out.display().to_string()).is_empty() {
        assert!(
            t0.elapsed() < Duration::from_secs(30),
            "nodes outlived their launcher by 30 s: {:?}",
            pids_with(&out.display().to_string())
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// kill -9 of the recorder mid-run (with restarts off): `inspect --recover` gets back
/// everything up to at most the last second before the kill (by the wall-clock receipt
/// times in the file).
#[test]
fn killed_recorder_is_recoverable() {
    let _one = one_run_at_a_time();
    let dir = scratch("kill");
    let file = long_launch(&dir, UNTIL_STOPPED);
    let mut text = std::fs::read_to_string(&file).unwrap();
    text.push_str("\n[run.restart]\npolicy = \"never\"\n");
    std::fs::write(&file, text).unwrap();
    let out = dir.join("run");
    let (mut child, _) = spawn_launch(&file, &out);
    // the run is stepping (a start-up that takes seconds on a loaded host is not what
    // this test is about), then runs on a while before the kill
    wait_for_recording_bytes(&out, 2 << 20, 60);
    std::thread::sleep(Duration::from_secs(2));
    let spec = out.join("config/recorder.toml").display().to_string();
    let pids = pids_with(&spec);
    assert_eq!(pids.len(), 1, "recorder process not found");
    let kill_ns = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap()
        .as_nanos() as u64;
    unsafe { libc::kill(pids[0], libc::SIGKILL) };
    let st = child.wait().expect("launcher");
    assert!(!st.success(), "the launcher must report the dead recorder");
    let o = Command::new(fiberflow())
        .arg("inspect")
        .arg("--recover")
        .arg(out.join("run.mcap"))
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{text}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let rec = out.join("run.recovered.mcap");
    let bytes = std::fs::read(&rec).unwrap();
    let mut last = 0u64;
    let mut n = 0u64;
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        last = last.max(m.publish_time);
        n += 1;
    }
    assert!(n > 100, "only {n} messages recovered\n{}", log_tails(&out));
    let lost_ms = kill_ns.saturating_sub(last) / 1_000_000;
    assert!(
        lost_ms <= 1000,
        "recovered data ends {lost_ms} ms before the kill\n{}",
        log_tails(&out)
    );
    assert!(
        pids_with(&out.display().to_string()).is_empty(),
        "orphan processes left"
    );
}

/// Ctrl-C on the launcher: every child is gone within 5 s, the MCAP is finished, and the
/// launcher says how to resume the run.
#[test]
fn ctrl_c_stops_everything_cleanly() {
    let _one = one_run_at_a_time();
    let dir = scratch("ctrlc");
    let file = long_launch(&dir, UNTIL_STOPPED);
    let out = dir.join("run");
    let (mut child, _) = spawn_launch(&file, &out);
    wait_for_recording(&out, 60);
    std::thread::sleep(Duration::from_secs(2));
    let t0 = Instant::now();
    unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
    let _ = child.wait();
    loop {
        if pids_with(&out.display().to_string()).is_empty() {
            break;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(5),
            "children still alive 5 s after Ctrl-C"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let md = metadata(&out.join("run.mcap"));
    assert!(
        md.contains_key("fiberflow.run"),
        "recording not finished properly"
    );
    let said = std::fs::read_to_string(out.with_extension("stderr")).expect("launcher stderr");
    let resume = format!("--resume {}", out.display());
    assert!(
        said.contains("interrupted") && said.contains(&resume),
        "the launcher did not say how to resume ({resume}): {said}"
    );
}

/// A shortened quick launch (DNS from the shipped coarse checkpoint, six cases): the
/// analysis output exists and its numbers are finite and within physical bounds
/// (|z1| <= 1, sigma² >= 0, MSD >= 0).
#[test]
fn shortened_quick_run_produces_sane_analysis() {
    let _one = one_run_at_a_time();
    let dir = scratch("quick");
    let text = std::fs::read_to_string(root().join("launch/quick.toml")).unwrap();
    let text = text.replace("steps = 324", "steps = 24").replace(
        "../recordings/samples/",
        &format!("{}/recordings/samples/", root().display()),
    );
    let file = dir.join("quick-short.toml");
    std::fs::write(&file, text).unwrap();
    let out = dir.join("run");
    let stdout = launch(&file, &out, "zenoh");
    assert!(
        stdout.contains("| case1 |"),
        "summary table not printed:\n{stdout}"
    );
    let a = out.join("analysis");
    for f in [
        "summary.md",
        "msd23.png",
        "abs_z1.png",
        "sigma2.png",
        "case1_msd23.csv",
        "case6_abs_z1.csv",
        "case3_fibers.csv",
        "coiling_onsets.csv",
    ] {
        assert!(a.join(f).exists(), "missing {f}");
    }
    // the flow slices (streaks and cross-section, every 4 steps of 0..=24) are in the
    // scene, and in the raw MCAP both as themselves and as sensor_msgs/Image, which an
    // independent ROS 2 decoder reads
    assert!(
        stdout.contains("300 of 300 fibres shown") && stdout.contains("14 flow slices"),
        "scene summary:\n{stdout}"
    );
    let text = decode_all(&out.join("run.mcap"));
    for t in [
        "\"fiberflow_msgs/msg/FlowSlice\": 14",
        "\"sensor_msgs/msg/Image\": 14",
    ] {
        assert!(text.contains(t), "expected {t}: {text}");
    }
    let summary = std::fs::read_to_string(a.join("summary.md")).unwrap();
    assert!(
        summary.contains("## Coiling onsets") && summary.contains("| case4 | 0.1 | middle |"),
        "coiling-onset table missing:\n{summary}"
    );
    for c in 1..=6 {
        let csv = std::fs::read_to_string(a.join(format!("case{c}_fibers.csv"))).unwrap();
        let mut rows = 0;
        for l in csv.lines().skip(1) {
            let v: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
            assert!(v.iter().all(|x| x.is_finite()), "non-finite row {l}");
            assert!(v[3].abs() <= 1.0 + 1e-12, "|z1| > 1: {l}");
            assert!(v[4] >= 0.0, "sigma² < 0: {l}");
            assert!(
                v[6].abs() <= 150.0 + 1e-9,
                "centre of mass outside the channel: {l}"
            );
            rows += 1;
        }
        assert_eq!(rows, 25 * 50, "case{c}: 25 states of 50 fibres");
        let msd = std::fs::read_to_string(a.join(format!("case{c}_msd23.csv"))).unwrap();
        for l in msd.lines().skip(1) {
            let v: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
            assert!(v[1].is_finite() && v[1] >= 0.0, "MSD {l}");
        }
    }
}

/// `replay` republishes a recording on the bus: a listener (`echo`) receives every bus
/// message of the recording (the derived PointCloud2 channels are not bus topics).
#[test]
fn replay_republishes_the_recording() {
    let _one = one_run_at_a_time();
    let out = scratch("replay");
    launch(
        &root().join("launch/validation/analytic-shear.toml"),
        &out,
        "inproc",
    );
    // the run folder (its segments in order); here one segment
    let text = replay_and_echo(&out, "analytic-shear");
    // every state of both groups arrives, in step order per group
    for g in ["case1", "stiff"] {
        let line = format!("total fiberflow/analytic-shear/fibers/{g}/state 201");
        assert!(
            text.contains(&line),
            "missing {line}:\n{}",
            text.lines()
                .filter(|l| l.starts_with("total"))
                .collect::<Vec<_>>()
                .join("\n")
        );
    }
    assert!(
        !text.contains("/points"),
        "derived point clouds must not be replayed"
    );
    // with nobody to replay to, the replay is an error that says so (it tries a second
    // session first), not a silent success
    let o = Command::new(fiberflow())
        .arg("replay")
        .arg(&out)
        .args([
            "--speed",
            "0",
            "--listen",
            "tcp/127.0.0.1:0",
            "--wait-s",
            "1",
        ])
        .output()
        .expect("replay");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "a replay to nobody succeeded: {err}");
    assert!(
        err.contains("trying a new session") && err.contains("no peer of the run reached"),
        "{err}"
    );
}

/// A replay into a listener of one topic starts once that listener is heard (not after
/// waiting out `--wait-s` for a subscriber on every recorded topic), and
/// `--topics` replays only the topics it matches.
#[test]
fn replay_starts_for_the_subscribers_there_are_and_filters_topics() {
    let _one = one_run_at_a_time();
    let out = scratch("replay-one");
    launch(
        &root().join("launch/validation/analytic-shear.toml"),
        &out,
        "inproc",
    );
    let state = "fiberflow/analytic-shear/fibers/case1/state";
    // an echo of one topic; the replay offers all of them, or (second round) only that one
    for only in [None, Some(state)] {
        let ep = loopback_endpoint();
        let echo = Command::new(fiberflow())
            .args(["echo", state, "--listen", &ep, "--idle-s", "5", "--raw"])
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap();
        std::thread::sleep(std::time::Duration::from_millis(800));
        let mut replay = Command::new(fiberflow());
        replay
            .arg("replay")
            .arg(&out)
            .args(["--speed", "0", "--connect", &ep, "--wait-s", "60"]);
        if let Some(p) = only {
            replay.args(["--topics", p]);
        }
        let r = replay.output().unwrap();
        let err = String::from_utf8_lossy(&r.stderr);
        let said = String::from_utf8_lossy(&r.stdout);
        assert!(r.status.success(), "{err}");
        assert!(
            err.contains("waiting up to 60 s for a subscriber to"),
            "{err}"
        );
        assert!(
            !err.contains("no subscriber after"),
            "it waited for the others: {err}"
        );
        let text = String::from_utf8_lossy(&echo.wait_with_output().unwrap().stdout).to_string();
        assert!(text.contains(&format!("total {state} 201")), "{text}");
        let replayed: u64 = said
            .split_whitespace()
            .nth(1)
            .and_then(|n| n.parse().ok())
            .unwrap_or(0);
        match only {
            Some(_) => assert_eq!(replayed, 201, "{said}"),
            None => assert!(replayed > 201, "{said}"),
        }
    }
}

/// A run split over two "hosts" (two launchers, zenoh router + clients over mutual TLS on
/// loopback) records the same bits as the in-process run; a peer whose certificate is
/// signed by the run's CA but whose common name is not allowed is shut out by access
/// control, and the flow node's join timeout names the group that never arrived.
#[test]
fn two_host_tls_run_matches_and_acl_shuts_out_strangers() {
    let _one = one_run_at_a_time();
    let dir = scratch("two-hosts");
    let file = two_host_launch(&dir, "worker", "");
    let head = launch_host(&file, "head", &dir.join("head"), &[]);
    std::thread::sleep(Duration::from_millis(500));
    let worker = launch_host(&file, "worker", &dir.join("worker"), &[]);
    assert_all_succeed(vec![("head", head), ("worker", worker)]);
    assert_two_hosts_match_one_process(&dir.join("head/run.mcap"), &[], "two hosts");

    let bad_dir = scratch("two-hosts-acl");
    let file = two_host_launch(&bad_dir, "intruder", "join_timeout_s = 6");
    let head = launch_host(&file, "head", &bad_dir.join("head"), &[]);
    std::thread::sleep(Duration::from_millis(500));
    let mut worker = launch_host(&file, "worker", &bad_dir.join("worker"), &[]);
    let o = head.wait_with_output().unwrap();
    assert!(
        !o.status.success(),
        "the head must fail when a group cannot join"
    );
    let flow_log = std::fs::read_to_string(bad_dir.join("head/logs/flow.log")).unwrap();
    assert!(
        flow_log.contains("join timeout") && flow_log.contains("stiff"),
        "flow log should name the missing group:\n{flow_log}"
    );
    let _ = worker.kill();
    let _ = worker.wait();
}

/// A group split over three fibre nodes (`shards = 3`, 50 fibres as 16 + 17 + 17) gives the
/// same fibre states, bit for bit, as the unsharded group: 40 steps of the quick launch in
/// turbulence over iceoryx2, two groups sharded. The sharded run's analysis and checkpoints
/// treat the group as one (same summary table; one checkpoint file per shard).
#[test]
fn sharded_groups_match_unsharded_bitwise() {
    let _one = one_run_at_a_time();
    let run_on = |name: &str, shards: u32, transport: &str, processes: u32| {
        let out = scratch(name);
        let mut c = Command::new(fiberflow());
        c.arg("launch")
            .arg(root().join("launch/quick.toml"))
            .args(["--transport", transport, "--out"])
            .arg(&out);
        for s in [
            "run.steps=40".to_string(),
            "run.checkpoint_every_plus=5".into(),
            format!("fibers.case1.shards={shards}"),
            format!("fibers.case4.shards={shards}"),
            format!("run.fiber_processes={processes}"),
        ] {
            c.arg("--set").arg(s);
        }
        let o = c.output().unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "shards = {shards}: {stderr}");
        assert!(!stderr.contains("WARN"), "{stderr}");
        let w = warnings_in_logs(&out);
        assert!(
            w.is_empty(),
            "shards = {shards}: warnings in node logs: {w:#?}"
        );
        let stdout = String::from_utf8_lossy(&o.stdout).to_string();
        let table: Vec<String> = stdout
            .lines()
            .filter(|l| l.starts_with("| case") && !l.starts_with("| case |"))
            .map(String::from)
            .collect();
        (out, table)
    };
    let run = |name: &str, shards: u32| run_on(name, shards, "iceoryx2", 0);
    let (one, table_one) = run("shards-1", 1);
    let (three, table_three) = run("shards-3", 3);
    let a = whole_states(&one);
    let b = whole_states(&three);
    assert_eq!(a.len(), 6 * 41, "six groups, steps 0..=40");
    assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
    for (k, v) in &a {
        assert!(v == &b[k], "{k:?}: sharded state differs");
    }
    // the ten fibre nodes as threads of two processes (iceoryx2), or of one (zenoh):
    // the same bits, one log per process
    for (name, transport, processes) in [
        ("shards-3-in-2", "iceoryx2", 2),
        ("shards-3-in-1", "zenoh", 1),
    ] {
        let (out, table) = run_on(name, 3, transport, processes);
        let log = std::fs::read_to_string(out.join("logs/fibers-1.log")).unwrap();
        assert!(
            log.contains("fibre nodes stepped in turn on one thread"),
            "{name}: {log}"
        );
        let c = whole_states(&out);
        assert_eq!(a.keys().collect::<Vec<_>>(), c.keys().collect::<Vec<_>>());
        for (k, v) in &a {
            assert!(v == &c[k], "{name}: {k:?}: state differs");
        }
        assert_eq!(table, table_one, "{name}: analysis differs");
        let mut logs: Vec<String> = std::fs::read_dir(out.join("logs"))
            .unwrap()
            .flatten()
            .map(|e| e.file_name().to_string_lossy().to_string())
            .filter(|n| n.ends_with(".log"))
            .collect();
        logs.sort();
        let mut want: Vec<String> = (1..=processes)
            .map(|i| format!("fibers-{i}.log"))
            .chain(["flow.log".into(), "recorder.log".into()])
            .collect();
        want.sort();
        assert_eq!(logs, want, "{name}");
    }
    // the sharded recording really holds slices
    let slices = states(&three.join("run.mcap"));
    assert_eq!(slices["case1"].len(), 3 * 41);
    assert_eq!(slices["case2"].len(), 41);
    assert_eq!(table_one.len(), 6);
    assert_eq!(
        table_one, table_three,
        "analysis of the sharded run differs"
    );
    let ck = std::fs::read_dir(three.join("checkpoints"))
        .unwrap()
        .flatten()
        .find(|e| e.file_name().to_string_lossy().starts_with("step-"))
        .expect("a checkpoint")
        .path();
    for shard in ["case1.0", "case1.1", "case1.2", "case4.2", "case2"] {
        let any = std::fs::read_dir(&ck).unwrap().flatten().any(|e| {
            e.file_name()
                .to_string_lossy()
                .starts_with(&format!("{shard}."))
        });
        assert!(any, "{shard}: no checkpoint piece in {}", ck.display());
    }
}
