//! Helpers for the end-to-end tests: locate the `fiberflow` binary, run launches, read
//! recordings.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

static LAUNCHES: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// Held by every test that starts a run: the runs of one test binary go one at a time.
/// Each run is already 4–9 processes on a 2-core machine; nine of them at once starved
/// zenoh links long enough to lose messages and log warnings, which is not what these
/// tests are about.
pub fn one_run_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    LAUNCHES.lock().unwrap_or_else(|e| e.into_inner())
}

/// The `fiberflow` binary next to the test executable (cargo builds it for `cargo test`).
pub fn fiberflow() -> PathBuf {
    let exe = std::env::current_exe().expect("test executable path");
    let dir = exe.parent().and_then(|d| d.parent()).expect("target dir");
    let bin = dir.join("fiberflow");
    assert!(
        bin.exists(),
        "fiberflow binary not found at {} (run cargo build first)",
        bin.display()
    );
    bin
}

/// The repository root. Read at run time (cargo sets CARGO_MANIFEST_DIR for test
/// processes): a compile-time path goes stale when a shared target directory serves
/// checkouts at different paths.
pub fn root() -> PathBuf {
    let manifest = std::env::var_os("CARGO_MANIFEST_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")));
    // the first folder up from the test's package that holds the launch files
    manifest
        .ancestors()
        .find(|d| d.join("launch/quick.toml").is_file())
        .expect("repository root (a folder with launch/quick.toml) above CARGO_MANIFEST_DIR")
        .to_path_buf()
}

/// A fresh scratch folder. The first call of a test process removes the scratch folders
/// of earlier test processes that have exited more than an hour ago: a failed run's files
/// stay for inspection, and runs no longer pile up (≈ 0.6 GB per run of the suite).
pub fn scratch(name: &str) -> PathBuf {
    static CLEARED: std::sync::Once = std::sync::Once::new();
    CLEARED.call_once(remove_stale_scratch);
    let d = std::env::temp_dir().join(format!("fiberflow-e2e-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).expect("scratch dir");
    d
}

/// Removes `fiberflow-e2e-<pid>-*` folders whose process no longer runs and which were
/// last changed over an hour ago.
fn remove_stale_scratch() {
    let Ok(entries) = std::fs::read_dir(std::env::temp_dir()) else {
        return;
    };
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().to_string();
        let pid = name
            .strip_prefix("fiberflow-e2e-")
            .and_then(|rest| rest.split('-').next())
            .and_then(|p| p.parse::<u32>().ok());
        if let Some(pid) = pid {
            let old = e
                .metadata()
                .and_then(|m| m.modified())
                .ok()
                .and_then(|t| t.elapsed().ok())
                .is_some_and(|age| age > std::time::Duration::from_secs(3600));
            if old && !Path::new(&format!("/proc/{pid}")).exists() {
                let _ = std::fs::remove_dir_all(e.path());
            }
        }
    }
}

/// Runs `fiberflow launch` and asserts success; returns stdout.
pub fn launch(file: &Path, out: &Path, transport: &str) -> String {
    launch_with(file, out, transport, &[])
}

/// [`launch`] with `--set` overrides (`key=value` each).
pub fn launch_with(file: &Path, out: &Path, transport: &str, sets: &[&str]) -> String {
    let mut c = Command::new(fiberflow());
    c.arg("launch")
        .arg(file)
        .arg("--out")
        .arg(out)
        .arg("--transport")
        .arg(transport);
    for s in sets {
        c.arg("--set").arg(s);
    }
    let o = c.output().expect("running fiberflow launch");
    let stdout = String::from_utf8_lossy(&o.stdout).to_string();
    let stderr = String::from_utf8_lossy(&o.stderr).to_string();
    // a healthy run prints no warning a newcomer would read as failure
    assert!(
        !["WARN", "ERROR", "[W]", "[E]"]
            .iter()
            .any(|w| stderr.contains(w)),
        "launch {} --transport {transport} printed warnings:\n{stderr}",
        file.display()
    );
    assert!(
        o.status.success(),
        "launch {} --transport {transport} failed:\n{stdout}\n{}",
        file.display(),
        String::from_utf8_lossy(&o.stderr)
    );
    stdout
}

/// Lines with a WARN or ERROR in a run's node logs (`<out>/logs/*.log`), but for zenoh's
/// notice of a slow peer start.
pub fn warnings_in_logs(out: &Path) -> Vec<String> {
    let mut v = Vec::new();
    for e in std::fs::read_dir(out.join("logs"))
        .expect("logs dir")
        .flatten()
    {
        let text = std::fs::read_to_string(e.path()).unwrap_or_default();
        for l in text.lines() {
            // zenoh's notice that a peer's start took its whole scouting delay (15 s) is
            // about this machine's load while the tests run side by side, not about the run
            // (it happened once in about ten suites, with the states still bitwise equal)
            let slow_start = l.contains("Scouting delay elapsed before start conditions");
            if [" WARN", "ERROR", "[W]", "[E]"]
                .iter()
                .any(|w| l.contains(w))
                && !slow_start
            {
                v.push(format!("{}: {l}", e.file_name().to_string_lossy()));
            }
        }
    }
    v
}

/// Fibre-state payloads per group, ordered by step (read with the Rust mcap reader).
pub fn states(mcap_path: &Path) -> BTreeMap<String, Vec<Vec<u8>>> {
    let bytes = std::fs::read(mcap_path).expect("reading mcap");
    let mut out: BTreeMap<String, Vec<Vec<u8>>> = BTreeMap::new();
    for m in mcap::MessageStream::new(&bytes).expect("mcap stream") {
        let m = m.expect("mcap message");
        if m.channel.topic.ends_with("/state") {
            let group = m
                .channel
                .topic
                .rsplit('/')
                .nth(1)
                .unwrap_or_default()
                .to_string();
            // the file holds each group's states in publication (step) order
            out.entry(group).or_default().push(m.data.to_vec());
        }
    }
    out
}

/// Calls `f` with every fibre-group state of a run folder's segments, in order.
pub fn for_each_state(path: &Path, mut f: impl FnMut(fiberflow_messages::FiberGroupState)) {
    for seg in fiberflow_messages::segments::segment_paths(path).expect("segments") {
        let bytes = std::fs::read(&seg).unwrap();
        for m in mcap::MessageStream::new(&bytes).unwrap() {
            let m = m.unwrap();
            if m.channel.topic.ends_with("/state") {
                f(fiberflow_messages::decode(&m.data).unwrap());
            }
        }
    }
}

/// Every group's whole state per step, with a sharded group's slices put back together
/// (re-encoded, so an unsharded group's state compares byte for byte).
pub fn whole_states(path: &Path) -> BTreeMap<(String, u64), Vec<u8>> {
    use fiberflow_messages::pieces::Tiles;
    let mut tiles = Tiles::default();
    let mut out = BTreeMap::new();
    // every segment of the run folder, in order (a step's slices may span two)
    for_each_state(path, |s| {
        if let Some(w) = tiles.add_slice(s) {
            let key = (w.group.clone(), w.step);
            let whole = fiberflow_messages::encode(&w);
            assert!(
                out.insert(key.clone(), whole).is_none(),
                "{key:?} recorded twice"
            );
        }
    });
    assert_eq!(tiles.incomplete(), 0, "a step's slices never completed");
    out
}

/// Metadata records of a recording by name.
pub fn metadata(mcap_path: &Path) -> BTreeMap<String, BTreeMap<String, String>> {
    let bytes = std::fs::read(mcap_path).expect("reading mcap");
    mcap::Summary::read(&bytes)
        .expect("summary")
        .expect("a finished file has a summary section");
    let mut out = BTreeMap::new();
    for rec in mcap::read::LinearReader::new(&bytes).expect("mcap records") {
        if let Ok(mcap::records::Record::Metadata(md)) = rec {
            out.insert(md.name.clone(), md.metadata.clone());
        }
    }
    out
}

/// Python with the independent decoders (`mcap`, `mcap-ros2-support`) installed?
pub fn python_ok() -> bool {
    Command::new("python3")
        .args(["-c", "import mcap, mcap_ros2"])
        .status()
        .map(|s| s.success())
        .unwrap_or(false)
}

/// Every fibre-group state of a recording (a run folder: all its segments) keyed by
/// (group, step), and the number of segments. Panics if a step appears twice.
pub fn states_by_step(path: &Path) -> (BTreeMap<(String, u64), Vec<u8>>, usize) {
    let segs = fiberflow_messages::segments::segment_paths(path).expect("segments");
    let mut out = BTreeMap::new();
    for seg in &segs {
        let bytes = std::fs::read(seg).expect("reading mcap");
        for m in mcap::MessageStream::new(&bytes).expect("mcap stream") {
            let m = m.expect("mcap message");
            if !m.channel.topic.ends_with("/state") {
                continue;
            }
            let s: fiberflow_messages::FiberGroupState =
                fiberflow_messages::decode(&m.data).expect("state decodes");
            let key = (s.group.clone(), s.step);
            assert!(
                out.insert(key.clone(), m.data.to_vec()).is_none(),
                "{key:?} recorded twice ({})",
                seg.display()
            );
        }
    }
    (out, segs.len())
}

/// Process ids whose command line contains `needle` (e.g. a node's spec path).
pub fn pids_with(needle: &str) -> Vec<i32> {
    let mut out = Vec::new();
    for e in std::fs::read_dir("/proc").unwrap().flatten() {
        let Ok(pid) = e.file_name().to_string_lossy().parse::<i32>() else {
            continue;
        };
        if let Ok(cmd) = std::fs::read(e.path().join("cmdline")) {
            let cmd = String::from_utf8_lossy(&cmd).replace('\0', " ");
            if cmd.contains(needle) {
                out.push(pid);
            }
        }
    }
    out
}

/// A loopback TCP port that was free a moment ago.
pub fn free_loopback_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("a free loopback port")
        .port()
}

/// A zenoh endpoint on a loopback port that was free a moment ago.
pub fn loopback_endpoint() -> String {
    format!("tcp/127.0.0.1:{}", free_loopback_port())
}

/// Replays a recording (`replay PATH --speed 0`) to an `echo` listener on a free loopback
/// port and returns what `echo` printed (a `total <topic> <count>` line per topic).
pub fn replay_and_echo(path: &Path, run_id: &str) -> String {
    use std::process::Stdio;
    // the echo stops once it has every bus message of the recording (the derived point
    // clouds are not bus topics), or after 60 s without one: no guess at how long the
    // replay may pause on a loaded host (once, under CI load, an echo that stopped after
    // 5 s of quiet ended five messages short; such a pause is one explanation, not shown)
    let mut expected = 0u64;
    for seg in fiberflow_messages::segments::segment_paths(path).expect("recording segments") {
        fiberflow_messages::reading::for_each_message(&seg, |m| {
            if m.topic.starts_with(&format!("fiberflow/{run_id}/")) && !m.topic.ends_with("/points")
            {
                expected += 1;
            }
        })
        .expect("recording reads");
    }
    let ep = loopback_endpoint();
    let echo = Command::new(fiberflow())
        .args([
            "echo",
            &format!("fiberflow/{run_id}/**"),
            "--listen",
            &ep,
            "--idle-s",
            "60",
            "--count",
            &expected.to_string(),
            "--raw",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    std::thread::sleep(std::time::Duration::from_millis(800));
    let r = Command::new(fiberflow())
        .arg("replay")
        .arg(path)
        .args(["--speed", "0", "--connect", &ep])
        .output()
        .unwrap();
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let o = echo.wait_with_output().unwrap();
    String::from_utf8_lossy(&o.stdout).to_string()
}

/// Asserts two recordings' states (from [`states`]) are bitwise identical; on a mismatch
/// the message names the group, the record index, both steps and the first field that
/// differs, so a flaky run says what it saw.
pub fn assert_same_states(
    a: &BTreeMap<String, Vec<Vec<u8>>>,
    b: &BTreeMap<String, Vec<Vec<u8>>>,
    what: &str,
) {
    for (g, va) in a {
        let vb = b
            .get(g)
            .unwrap_or_else(|| panic!("group {g}: missing in {what}"));
        assert_eq!(va.len(), vb.len(), "group {g}: state count ({what})");
        for (i, (x, y)) in va.iter().zip(vb).enumerate() {
            if x == y {
                continue;
            }
            let sx: fiberflow_messages::FiberGroupState =
                fiberflow_messages::decode(x).expect("state decodes");
            let sy: fiberflow_messages::FiberGroupState =
                fiberflow_messages::decode(y).expect("state decodes");
            let field = [
                ("step", sx.step != sy.step),
                ("t_plus", sx.t_plus.to_bits() != sy.t_plus.to_bits()),
                ("first_fiber", sx.first_fiber != sy.first_fiber),
                ("centre", sx.centre != sy.centre),
                ("axis", sx.axis != sy.axis),
                ("velocity", sx.velocity != sy.velocity),
                (
                    "angular_velocity",
                    sx.angular_velocity != sy.angular_velocity,
                ),
            ]
            .into_iter()
            .find(|(_, d)| *d)
            .map(|(n, _)| n)
            .unwrap_or("encoding only");
            let later = va.iter().zip(vb).skip(i).filter(|(x, y)| x != y).count();
            panic!(
                "group {g}: states differ between inproc and {what} at record {i} \
                 (steps {} / {}; first field: {field}; {later} of the remaining {} records differ)",
                sx.step,
                sy.step,
                va.len() - i
            );
        }
    }
}

/// Runs `launch` (a `fiberflow launch … --out out` command), kills its flow node with
/// SIGKILL once the run has its first complete checkpoint, and checks that the launcher
/// rolled every node back and finished the run.
pub fn launch_and_kill_the_flow_node(mut launch: Command, out: &Path) {
    std::fs::create_dir_all(out).unwrap();
    let se = std::fs::File::create(out.with_extension("stderr")).unwrap();
    let mut child = launch
        .stdout(std::process::Stdio::null())
        .stderr(se)
        .spawn()
        .unwrap();
    wait_for_checkpoint(out, 90);
    let spec = out.join("config/flow.toml").display().to_string();
    let pids = pids_with(&spec);
    assert_eq!(pids.len(), 1, "flow node not found (run over already?)");
    unsafe { libc::kill(pids[0], libc::SIGKILL) };
    assert!(child.wait().unwrap().success());
    let err = std::fs::read_to_string(out.with_extension("stderr")).unwrap();
    assert!(err.contains("restarting every node from step"), "{err}");
}

/// Waits until the run has a complete checkpoint (a manifest).
pub fn wait_for_checkpoint(out: &Path, secs: u64) {
    let t0 = std::time::Instant::now();
    let root = out.join("checkpoints");
    while t0.elapsed() < std::time::Duration::from_secs(secs) {
        let done = std::fs::read_dir(&root)
            .into_iter()
            .flatten()
            .flatten()
            .any(|e| e.path().join("manifest.toml").exists());
        if done {
            return;
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    panic!(
        "no complete checkpoint in {} after {secs} s",
        root.display()
    );
}

/// The `[network]` part of a two-host launch: a router at `rendezvous` (listening on
/// `listen`) on `head` (flow, recorder, case1), the group `stiff` on `worker` with the
/// identity `worker_cert` (certificates from launch/multi-host/make-certs.sh in `certs/`).
pub fn two_host_network(rendezvous: &str, listen: &str, worker_cert: &str) -> String {
    format!(
        r#"
[network]
rendezvous = "{rendezvous}"
listen = "{listen}"
root_ca_certificate = "certs/ca.pem"
allowed_common_names = ["fiberflow-head", "fiberflow-worker"]

[[network.hosts]]
name = "head"
nodes = ["flow", "recorder", "case1"]
certificate = "certs/head.pem"
private_key = "certs/head-key.pem"

[[network.hosts]]
name = "worker"
nodes = ["stiff"]
certificate = "certs/{worker_cert}.pem"
private_key = "certs/{worker_cert}-key.pem"
"#
    )
}

/// Waits for each named launcher and asserts it succeeded, showing its output if not.
pub fn assert_all_succeed(children: Vec<(&str, std::process::Child)>) {
    for (name, c) in children {
        let o = c.wait_with_output().expect("waiting for a launcher");
        assert!(
            o.status.success(),
            "{name} failed:\n{}\n{}",
            String::from_utf8_lossy(&o.stdout),
            String::from_utf8_lossy(&o.stderr)
        );
    }
}

/// Writes certificates (launch/multi-host/make-certs.sh) and a two-host version of the
/// analytic-shear launch on loopback (router on a free port) whose worker uses the identity
/// `worker_cert`, with `extra_flow` in its `[flow]` section; returns the launch file.
pub fn two_host_launch(dir: &Path, worker_cert: &str, extra_flow: &str) -> PathBuf {
    let st = Command::new(root().join("launch/multi-host/make-certs.sh"))
        .arg(dir.join("certs"))
        .args(["head", "worker", "intruder"])
        .stdout(std::process::Stdio::null())
        .status()
        .expect("running launch/multi-host/make-certs.sh (needs openssl)");
    assert!(st.success(), "make-certs.sh failed");
    let port = free_loopback_port();
    let base = std::fs::read_to_string(root().join("launch/validation/analytic-shear.toml"))
        .expect("reading analytic-shear.toml");
    let text = base.replacen(
        "[flow.source]",
        &format!("[flow]\n{extra_flow}\n\n[flow.source]"),
        1,
    ) + &two_host_network(
        &format!("tls/localhost:{port}"),
        &format!("tls/127.0.0.1:{port}"),
        worker_cert,
    );
    let file = dir.join("two-hosts.toml");
    std::fs::write(&file, text).expect("writing the launch file");
    file
}

/// `fiberflow launch FILE --host HOST --out OUT` with `--set` for each of `sets`.
pub fn launch_host(file: &Path, host: &str, out: &Path, sets: &[&str]) -> std::process::Child {
    let mut c = Command::new(fiberflow());
    c.arg("launch")
        .arg(file)
        .args(["--host", host, "--out"])
        .arg(out);
    for s in sets {
        c.arg("--set").arg(s);
    }
    c.stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("starting fiberflow launch --host")
}

/// Runs the analytic-shear launch in one process with `sets` and asserts the two-host
/// recording in `recording` (groups case1 and stiff) holds the same states, bit for bit.
pub fn assert_two_hosts_match_one_process(recording: &Path, sets: &[&str], what: &str) {
    let one = scratch(&format!("{}-ref", what.replace(' ', "-")));
    launch_with(
        &root().join("launch/validation/analytic-shear.toml"),
        &one,
        "inproc",
        sets,
    );
    let a = states(&one.join("run.mcap"));
    let b = states(recording);
    assert_eq!(b.keys().collect::<Vec<_>>(), vec!["case1", "stiff"]);
    assert_same_states(&a, &b, what);
}

/// The two-host analytic-shear launch on loopback with the recorder on the worker (flow
/// and case1 on the head; recorder and stiff on the worker): a user whose disk is on the
/// worker.
pub fn recorder_on_worker(dir: &Path) -> PathBuf {
    let file = two_host_launch(dir, "worker", "");
    let text = std::fs::read_to_string(&file).unwrap();
    let moved = text
        .replace(
            r#"nodes = ["flow", "recorder", "case1"]"#,
            r#"nodes = ["flow", "case1"]"#,
        )
        .replace(r#"nodes = ["stiff"]"#, r#"nodes = ["recorder", "stiff"]"#);
    assert_ne!(moved, text, "the launch file's hosts changed shape");
    std::fs::write(&file, moved).unwrap();
    file
}

/// Kills (SIGKILL) the launcher `child` and every process whose command line names
/// `out` (its nodes), and waits until they are gone.
pub fn kill_host(child: &mut std::process::Child, out: &Path) {
    // SAFETY: plain syscalls on processes this test started
    unsafe { libc::kill(child.id() as i32, libc::SIGKILL) };
    for pid in pids_with(&out.display().to_string()) {
        unsafe { libc::kill(pid, libc::SIGKILL) };
    }
    let _ = child.wait();
    let t0 = std::time::Instant::now();
    while !pids_with(&out.display().to_string()).is_empty() {
        assert!(
            t0.elapsed() < std::time::Duration::from_secs(5),
            "nodes outlived the kill"
        );
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
}
