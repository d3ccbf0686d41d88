//! Fault paths of runs across hosts (docs/architecture.md, "Runs across hosts"): two
//! launchers on loopback as two hosts, zenoh over mutual TLS, processes killed with
//! SIGKILL mid-run; nothing recorded may be lost or recorded twice.

use fiberflow_e2e::*;
use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

/// `fiberflow launch FILE --host HOST --resume DIR` with `sets`, its output captured.
fn resume(file: &Path, host: &str, dir: &Path, sets: &[&str]) -> std::process::Child {
    let mut c = Command::new(fiberflow());
    c.arg("launch")
        .arg(file)
        .args(["--host", host, "--resume"])
        .arg(dir);
    for s in sets {
        c.arg("--set").arg(s);
    }
    c.stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap()
}

/// [`resume`] of the worker.
fn resume_worker(file: &Path, worker_dir: &Path, sets: &[&str]) -> std::process::Child {
    resume(file, "worker", worker_dir, sets)
}

/// Starts the head and the worker of `file` (in `dir/head`, `dir/worker`), kills the
/// worker's launcher and nodes (`kill -9`) `after` the head's first complete checkpoint,
/// and starts the worker again with `--resume`: (head, resumed worker).
fn kill_and_resume_the_worker(
    file: &Path,
    dir: &Path,
    sets: &[&str],
    after: Duration,
) -> (std::process::Child, std::process::Child) {
    let (head_dir, worker_dir) = (dir.join("head"), dir.join("worker"));
    let head = launch_host(file, "head", &head_dir, sets);
    std::thread::sleep(Duration::from_millis(500));
    let mut worker = launch_host(file, "worker", &worker_dir, sets);
    wait_for_checkpoint(&head_dir, 300);
    std::thread::sleep(after);
    kill_host(&mut worker, &worker_dir);
    (head, resume_worker(file, &worker_dir, sets))
}

/// Asserts that `recording` holds every state of the analytic-shear launch with `sets`
/// (4000 steps) exactly once, bit for bit those of the run in one process.
fn assert_every_state_once(recording: &Path, sets: &[&str], dir: &Path) {
    let (b, _) = states_by_step(recording);
    let one = dir.join("one");
    launch_with(
        &root().join("launch/validation/analytic-shear.toml"),
        &one,
        "inproc",
        sets,
    );
    let (a, _) = states_by_step(&one);
    assert_eq!(a.len(), 2 * 4001, "two groups, steps 0..=4000");
    assert_eq!(
        a.keys().collect::<Vec<_>>(),
        b.keys().collect::<Vec<_>>(),
        "the recording lost or gained steps"
    );
    for (k, v) in &a {
        assert!(v == &b[k], "{k:?}: the resumed run's state differs");
    }
}

/// The recorder on the worker: once the head has a complete checkpoint, the worker's
/// launcher and all its nodes are killed (`kill -9`) and the worker is started again with
/// `--resume`. The head rolls back to its newest complete checkpoint, which it completed
/// only once the worker's recorder had said the step was on its disk; the resumed
/// recorder finishes the killed segment and goes on in a new one. Both complete, and the
/// worker's recording holds every state of steps 0..=4000 exactly once, bit for bit
/// those of the run in one process. (Before, the resumed recorder started `run.mcap`
/// again: steps 0, 1, 2, … were gone, and nothing warned.)
#[test]
fn a_recorder_on_a_killed_worker_keeps_every_step_once() {
    let _one = one_run_at_a_time();
    let dir = scratch("faults-recorder-on-worker");
    let file = recorder_on_worker(&dir);
    let sets = [
        "run.steps=4000",
        "run.checkpoint_every_plus=100",
        "run.liveness_s=4",
    ];
    let worker_dir = dir.join("worker");
    let (head, resumed) = kill_and_resume_the_worker(&file, &dir, &sets, Duration::ZERO);
    let o = head.wait_with_output().unwrap();
    let said = String::from_utf8_lossy(&o.stdout).to_string() + &String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "head failed:\n{said}");
    assert!(
        said.contains("restarting every node from step"),
        "no restart:\n{said}"
    );
    assert_all_succeed(vec![("the resumed worker", resumed)]);
    let segments = fiberflow_messages::segments::segment_paths(&worker_dir).unwrap();
    assert!(
        segments.len() >= 2,
        "the resumed recorder writes a new segment"
    );
    assert_every_state_once(&worker_dir, &sets, &dir);
    std::fs::remove_dir_all(&dir).ok();
}

/// A checkpoint every step, the recorder on the worker: the head's newest complete
/// checkpoint trails the worker's newest by the steps the recorder may lag, so a worker
/// that kept only its three newest had often pruned the step the head resumed from (the
/// head restarted from step 50 with the worker's folders at 51–53; two of three trials
/// failed so). The worker's launcher and nodes killed (`kill -9`) mid-run and resumed: it
/// finds its checkpoint of the head's step, and its recording holds every state once, bit
/// for bit the one-process run's.
#[test]
fn a_worker_keeps_the_step_the_head_resumes_from() {
    let _one = one_run_at_a_time();
    let dir = scratch("faults-worker-keeps");
    let file = recorder_on_worker(&dir);
    let sets = [
        "run.steps=4000",
        "run.checkpoint_every_plus=0.5",
        "run.liveness_s=4",
    ];
    let worker_dir = dir.join("worker");
    let (head, resumed) =
        kill_and_resume_the_worker(&file, &dir, &sets, Duration::from_millis(300));
    assert_all_succeed(vec![("head", head), ("the resumed worker", resumed)]);
    assert_every_state_once(&worker_dir, &sets, &dir);
    std::fs::remove_dir_all(&dir).ok();
}

/// A worker started with `--resume` waits for the head to say where the run starts again;
/// SIGTERM (as Ctrl-C) ends that wait at once and says so, instead of after the step
/// timeout (60 s here).
#[test]
fn a_worker_waiting_for_the_head_stops_on_sigterm() {
    let _one = one_run_at_a_time();
    let dir = scratch("faults-worker-sigterm");
    let file = two_host_launch(&dir, "worker", "");
    let sets = ["run.step_timeout_s=60"];
    let worker_dir = dir.join("worker");
    // a worker folder as a killed worker leaves it (no head ever came)
    let mut first = launch_host(&file, "worker", &worker_dir, &sets);
    let t0 = Instant::now();
    while !worker_dir.join("launch.toml").exists() {
        assert!(
            t0.elapsed() < Duration::from_secs(30),
            "the worker never started"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    kill_host(&mut first, &worker_dir);
    let resumed = resume_worker(&file, &worker_dir, &sets);
    std::thread::sleep(Duration::from_secs(2));
    let t0 = Instant::now();
    // SAFETY: plain syscall on a child this test started
    unsafe { libc::kill(resumed.id() as i32, libc::SIGTERM) };
    let o = resumed.wait_with_output().unwrap();
    let said = String::from_utf8_lossy(&o.stdout).to_string() + &String::from_utf8_lossy(&o.stderr);
    assert!(
        t0.elapsed() < Duration::from_secs(5),
        "took {:?} to stop:\n{said}",
        t0.elapsed()
    );
    assert!(!o.status.success());
    assert!(
        said.contains("waiting for the flow node") && said.contains("interrupted"),
        "{said}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// [`resume`] run to its end: (success, what it said).
fn resume_host(file: &Path, host: &str, dir: &Path, sets: &[&str]) -> (bool, String) {
    let o = resume(file, host, dir, sets).wait_with_output().unwrap();
    let said = String::from_utf8_lossy(&o.stdout).to_string() + &String::from_utf8_lossy(&o.stderr);
    (o.status.success(), said)
}

/// A two-host run that completed, resumed on either host (a user who resumes a finished
/// folder, or a chaos kill after the last step): each launcher knows the run is complete
/// (`logs/run.complete`, written once every node of the run said DONE) and says so,
/// starting no node and adding no segment. Before, the worker waited for a head that had gone (failing after
/// the step timeout) and the head rolled back and waited for a worker that had gone.
#[test]
fn a_complete_run_resumed_on_either_host_ends_at_once() {
    let _one = one_run_at_a_time();
    let dir = scratch("faults-complete-resumed");
    let file = two_host_launch(&dir, "worker", "");
    let sets = ["run.steps=200", "run.step_timeout_s=20"];
    let (head_dir, worker_dir) = (dir.join("head"), dir.join("worker"));
    let head = launch_host(&file, "head", &head_dir, &sets);
    std::thread::sleep(Duration::from_millis(500));
    let worker = launch_host(&file, "worker", &worker_dir, &sets);
    assert_all_succeed(vec![("head", head), ("worker", worker)]);
    let segments = fiberflow_messages::segments::segment_paths(&head_dir).unwrap();
    for (host, d) in [("worker", &worker_dir), ("head", &head_dir)] {
        assert!(
            d.join("logs/run.complete").is_file(),
            "{host} has no run.complete"
        );
        let (ok, said) = resume_host(&file, host, d, &sets);
        assert!(ok, "{host} resumed failed:\n{said}");
        assert!(said.contains("is complete: nothing to resume"), "{said}");
    }
    assert_eq!(
        fiberflow_messages::segments::segment_paths(&head_dir).unwrap(),
        segments
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// The recorder on the head; the head's launcher and nodes killed (`kill -9`) as soon as
/// its flow node has served the last step, while the recorder finishes, then resumed.
/// The worker, whose node had finished, has not left: it waits until the run is
/// complete, hears the head start again from its newest complete checkpoint and follows.
/// Both complete and the recording holds every state once, bit for bit the one-process
/// run's. (Before, the worker left once its node finished; the resumed head waited for it
/// in vain: "join timeout … no heartbeat from stiff".)
#[test]
fn a_worker_whose_node_finished_follows_a_head_restarted_at_the_end() {
    let _one = one_run_at_a_time();
    let dir = scratch("faults-worker-after-end");
    let file = two_host_launch(&dir, "worker", "");
    let sets = [
        "run.steps=4000",
        "run.checkpoint_every_plus=100",
        "run.liveness_s=4",
    ];
    let (head_dir, worker_dir) = (dir.join("head"), dir.join("worker"));
    let mut head = launch_host(&file, "head", &head_dir, &sets);
    std::thread::sleep(Duration::from_millis(500));
    let worker = launch_host(&file, "worker", &worker_dir, &sets);
    let t0 = Instant::now();
    while !head_dir.join("logs/flow.done").exists() {
        assert!(
            t0.elapsed() < Duration::from_secs(300),
            "the run never ended"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    kill_host(&mut head, &head_dir);
    assert!(
        !head_dir.join("logs/run.complete").exists(),
        "the run completed before the kill: nothing tested"
    );
    let (ok, said) = resume_host(&file, "head", &head_dir, &sets);
    assert!(ok, "the resumed head failed:\n{said}");
    assert!(said.contains("resuming"), "{said}");
    assert_all_succeed(vec![("worker", worker)]);
    assert_every_state_once(&head_dir, &sets, &dir);
    std::fs::remove_dir_all(&dir).ok();
}
