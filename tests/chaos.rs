//! A chaos soak of the two-launcher run (docs/architecture.md, "Runs across hosts"): the
//! analytic-shear launch split over two launchers on loopback ("head": flow and case1;
//! "worker": stiff), the recorder on one host or the other in turn; at seeded random
//! moments a random process is killed with SIGKILL — a node, either launcher, or
//! everything on one host — several times per run, and what must be resumed is resumed
//! (`--resume`). Every trial must end with the recording holding every state of the run
//! exactly once, bit for bit those of the run in one process. A failing trial prints its
//! seed; `FIBERFLOW_CHAOS_SEED=<seed> FIBERFLOW_CHAOS_TRIALS=1` replays it.
//!
//! The suite runs 10 trials (seeds 1–10); `tests/scripts/chaos-soak.sh [TRIALS] [FIRST]`
//! runs a longer soak (`FIBERFLOW_CHAOS_TRIALS`, `FIBERFLOW_CHAOS_SEED`).

use fiberflow_e2e::*;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::time::{Duration, Instant};

const SETS: [&str; 5] = [
    "run.steps=3000",
    "run.checkpoint_every_plus=50",
    "run.liveness_s=4",
    "run.restart.max_restarts=20",
    "run.step_timeout_s=60",
];

/// A small deterministic generator (xorshift), seeded per trial.
struct Rng(u64);

impl Rng {
    fn below(&mut self, n: u64) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0 % n
    }
}

/// The two-host launch with the recorder on `recorder_host`.
fn launch_file(dir: &Path, recorder_host: &str) -> PathBuf {
    if recorder_host == "worker" {
        recorder_on_worker(dir)
    } else {
        two_host_launch(dir, "worker", "")
    }
}

/// One host's launcher: started fresh or with `--resume`, its output to a log file.
fn launcher(file: &Path, host: &str, out: &Path, resume: bool, n: usize) -> Child {
    std::fs::create_dir_all(out).unwrap();
    let log = std::fs::File::create(out.with_extension(format!("{n}.log"))).unwrap();
    let mut c = Command::new(fiberflow());
    c.arg("launch").arg(file).args(["--host", host]);
    c.arg(if resume { "--resume" } else { "--out" }).arg(out);
    for s in SETS {
        c.arg("--set").arg(s);
    }
    c.stdout(log.try_clone().unwrap())
        .stderr(log)
        .spawn()
        .expect("starting a launcher")
}

fn kill(pid: i32) {
    // SAFETY: plain syscall on a process this test started (or one of its nodes)
    unsafe { libc::kill(pid, libc::SIGKILL) };
}

/// Waits until no process names `out` any more.
fn wait_gone(out: &Path) {
    let t0 = Instant::now();
    while !pids_with(&out.display().to_string()).is_empty() {
        assert!(
            t0.elapsed() < Duration::from_secs(10),
            "nodes outlived a kill"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// One trial; Err(what happened) when the recording is not the clean run's.
fn trial(seed: u64, reference: &BTreeMap<(String, u64), Vec<u8>>) -> Result<String, String> {
    let mut rng = Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1);
    let recorder_host = if seed.is_multiple_of(2) {
        "head"
    } else {
        "worker"
    };
    let dir = scratch(&format!("chaos-{seed}"));
    let file = launch_file(&dir, recorder_host);
    let outs = [dir.join("head"), dir.join("worker")];
    let hosts = ["head", "worker"];
    let mut started = [1usize, 1];
    let mut kids: [Child; 2] = [launcher(&file, "head", &outs[0], false, 0), {
        std::thread::sleep(Duration::from_millis(300));
        launcher(&file, "worker", &outs[1], false, 0)
    }];
    let mut said = Vec::new();
    let kills = 1 + rng.below(3);
    for _ in 0..kills {
        std::thread::sleep(Duration::from_millis(500 + rng.below(2500)));
        if kids
            .iter_mut()
            .any(|k| k.try_wait().ok().flatten().is_some())
        {
            break;
        }
        let h = rng.below(2) as usize;
        let what = rng.below(3);
        match what {
            // a node of host h
            0 => {
                let nodes: Vec<String> = std::fs::read_dir(outs[h].join("config"))
                    .into_iter()
                    .flatten()
                    .flatten()
                    .map(|e| e.path().display().to_string())
                    .collect();
                if nodes.is_empty() {
                    continue;
                }
                let spec = &nodes[rng.below(nodes.len() as u64) as usize];
                let pids = pids_with(&format!("--spec {spec}"));
                for p in &pids {
                    kill(*p);
                }
                said.push(format!("node {spec} ({} pids)", pids.len()));
            }
            // host h's launcher alone, or everything on host h: resumed
            _ => {
                kill(kids[h].id() as i32);
                if what == 2 {
                    for p in pids_with(&outs[h].display().to_string()) {
                        kill(p);
                    }
                }
                let _ = kids[h].wait();
                wait_gone(&outs[h]);
                said.push(format!(
                    "{} of {}",
                    if what == 2 {
                        "everything"
                    } else {
                        "the launcher"
                    },
                    hosts[h]
                ));
                kids[h] = launcher(&file, hosts[h], &outs[h], true, started[h]);
                started[h] += 1;
            }
        }
    }
    let story = format!(
        "seed {seed}, recorder on {recorder_host}, killed: {}",
        said.join("; ")
    );
    let t0 = Instant::now();
    for (i, k) in kids.iter_mut().enumerate() {
        loop {
            match k.try_wait() {
                Ok(Some(st)) if st.success() => break,
                Ok(Some(st)) => {
                    return Err(format!(
                        "{story}: {} exited with {st} (logs {})",
                        hosts[i],
                        dir.display()
                    ))
                }
                _ if t0.elapsed() > Duration::from_secs(300) => {
                    return Err(format!("{story}: {} did not finish", hosts[i]))
                }
                _ => std::thread::sleep(Duration::from_millis(100)),
            }
        }
    }
    let recording = if recorder_host == "head" {
        &outs[0]
    } else {
        &outs[1]
    };
    let got = std::panic::catch_unwind(|| states_by_step(recording).0)
        .map_err(|_| format!("{story}: a state recorded twice ({})", dir.display()))?;
    if got.keys().ne(reference.keys()) {
        let missing = reference.keys().filter(|k| !got.contains_key(*k)).count();
        return Err(format!(
            "{story}: {} states recorded, {missing} missing ({})",
            got.len(),
            dir.display()
        ));
    }
    if let Some(k) = reference.keys().find(|k| got[*k] != reference[*k]) {
        return Err(format!("{story}: state {k:?} differs ({})", dir.display()));
    }
    // and the user's own check says so
    let o = Command::new(fiberflow())
        .arg("inspect")
        .arg(recording)
        .output()
        .map_err(|e| format!("{story}: fiberflow inspect: {e}"))?;
    let said = String::from_utf8_lossy(&o.stdout);
    let lines: Vec<&str> = said
        .lines()
        .filter(|l| l.starts_with("states of "))
        .collect();
    if !o.status.success()
        || lines.len() != 2
        || !lines
            .iter()
            .all(|l| l.ends_with("steps 0..=3000, 3001 recorded, every step once"))
    {
        return Err(format!(
            "{story}: fiberflow inspect says {lines:?} ({})",
            dir.display()
        ));
    }
    std::fs::remove_dir_all(&dir).ok();
    Ok(story)
}

/// `FIBERFLOW_CHAOS_TRIALS` seeded trials (default 10), from `FIBERFLOW_CHAOS_SEED` on
/// (default 1): every one ends with every state recorded once, bit for bit the clean run's.
#[test]
fn chaos_soak_loses_nothing() {
    let _one = one_run_at_a_time();
    let env = |k: &str, d: u64| {
        std::env::var(k)
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(d)
    };
    let (trials, first) = (
        env("FIBERFLOW_CHAOS_TRIALS", 10),
        env("FIBERFLOW_CHAOS_SEED", 1),
    );
    let clean = scratch("chaos-clean");
    launch_with(
        &root().join("launch/validation/analytic-shear.toml"),
        &clean,
        "inproc",
        &SETS,
    );
    let reference = states_by_step(&clean).0;
    assert_eq!(reference.len(), 2 * 3001);
    let mut failed = Vec::new();
    for seed in first..first + trials {
        match trial(seed, &reference) {
            Ok(story) => eprintln!("ok: {story}"),
            Err(why) => {
                eprintln!("FAILED: {why}");
                failed.push(why);
            }
        }
    }
    assert!(
        failed.is_empty(),
        "{} of {trials} trials failed:\n{}",
        failed.len(),
        failed.join("\n")
    );
}
