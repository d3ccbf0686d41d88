//! Time-sliced runs for `fiberflow-bench scale --slice-ms`: several runs alive at once,
//! only one of them running at a time, in turns of a few hundred milliseconds (every
//! process of the others stopped with SIGSTOP). Run by run, a shared host's speed drifts
//! by ±10% (whole-run ratios scatter that much); in turns of 0.2 s every run sees the same
//! host, so a 1–3% difference between them shows. A step that a pause fell into is left
//! out, by the flow node's per-step times (`logs/flow-steps.csv`).

use anyhow::{bail, Context, Result};
use std::collections::BTreeMap;
use std::process::{Child, ExitStatus};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

/// Nanoseconds since the Unix epoch (the clock of the per-step times).
pub fn unix_nanos() -> u128 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_nanos())
        .unwrap_or(0)
}

/// `pid` and every process below it, parents before children (from `/proc`).
fn process_tree(pid: u32) -> Vec<i32> {
    let mut children: BTreeMap<i32, Vec<i32>> = BTreeMap::new();
    if let Ok(dir) = std::fs::read_dir("/proc") {
        for e in dir.flatten() {
            let Some(p) = e.file_name().to_str().and_then(|s| s.parse::<i32>().ok()) else {
                continue;
            };
            let Ok(stat) = std::fs::read_to_string(e.path().join("stat")) else {
                continue;
            };
            // "pid (comm) state ppid …": comm may hold spaces and parentheses
            let ppid = stat
                .rsplit_once(')')
                .and_then(|(_, rest)| rest.split_whitespace().nth(1))
                .and_then(|s| s.parse::<i32>().ok());
            if let Some(pp) = ppid {
                children.entry(pp).or_default().push(p);
            }
        }
    }
    let mut tree = vec![pid as i32];
    let mut i = 0;
    while i < tree.len() {
        if let Some(c) = children.get(&tree[i]) {
            tree.extend(c);
        }
        i += 1;
    }
    tree
}

/// Sends `sig` to each launcher and everything below it (a launcher first, so it starts
/// nothing new meanwhile).
fn signal_trees<'a>(launchers: impl IntoIterator<Item = &'a Child>, sig: libc::c_int) {
    for l in launchers {
        for p in process_tree(l.id()) {
            // SAFETY: kill only sends a signal; a process that has gone is ESRCH
            unsafe {
                libc::kill(p, sig);
            }
        }
    }
}

/// One run of a sliced set: its launchers (one, or head and worker), what is known of
/// them, and when it was stopped.
pub struct SlicedRun {
    launchers: Vec<Option<Child>>,
    /// (stopped, continued) in Unix nanoseconds.
    pub pauses: Vec<(u128, u128)>,
    stopped_at: Option<u128>,
    /// CPU seconds of its processes (RUSAGE_CHILDREN growth as its launchers were reaped).
    pub cpu_s: f64,
    /// A launcher that exited unsuccessfully.
    pub failed: Option<ExitStatus>,
}

impl SlicedRun {
    pub fn new(launchers: Vec<Child>) -> Self {
        Self {
            launchers: launchers.into_iter().map(Some).collect(),
            pauses: Vec::new(),
            stopped_at: None,
            cpu_s: 0.0,
            failed: None,
        }
    }

    fn alive(&self) -> bool {
        self.launchers.iter().any(Option::is_some)
    }

    fn stop(&mut self) {
        signal_trees(self.launchers.iter().flatten(), libc::SIGSTOP);
        self.stopped_at = Some(unix_nanos());
    }

    fn resume(&mut self) {
        signal_trees(self.launchers.iter().flatten(), libc::SIGCONT);
        if let Some(s) = self.stopped_at.take() {
            self.pauses.push((s, unix_nanos()));
        }
    }

    /// Kills what is left of the run (stopped or not) and reaps its launchers.
    fn kill(&mut self) {
        for c in self.launchers.iter_mut().flatten() {
            signal_trees(std::iter::once(&*c), libc::SIGKILL);
            let _ = c.wait();
        }
        self.launchers.clear();
    }

    /// Reaps launchers that have exited; their CPU goes to this run.
    fn reap(&mut self) -> Result<()> {
        for slot in &mut self.launchers {
            let Some(child) = slot else { continue };
            let before = fiberflow_bus::usage::children_cpu_s();
            if let Some(st) = child.try_wait().context("waiting for fiberflow launch")? {
                self.cpu_s += fiberflow_bus::usage::children_cpu_s() - before;
                if !st.success() {
                    self.failed = Some(st);
                }
                *slot = None;
            }
        }
        Ok(())
    }
}

/// A run given up on (an error or a panic in the benchmark) leaves no process stopped
/// forever behind it.
impl Drop for SlicedRun {
    fn drop(&mut self) {
        self.kill();
    }
}

/// Runs `runs` to their ends in turns of `slice`: the first runs while the others are
/// stopped, then the next, and so on over the runs still alive. If one fails, the others
/// are killed.
pub fn run_in_turns(runs: &mut [SlicedRun], slice: Duration) -> Result<()> {
    if runs.is_empty() {
        return Ok(());
    }
    for r in runs.iter_mut().skip(1) {
        r.stop();
    }
    let mut cur = 0;
    loop {
        let until = std::time::Instant::now() + slice;
        while std::time::Instant::now() < until {
            runs[cur].reap()?;
            if !runs[cur].alive() {
                break;
            }
            std::thread::sleep(Duration::from_millis(2));
        }
        if runs.iter().any(|r| r.failed.is_some()) {
            runs.iter_mut().for_each(SlicedRun::kill);
            return Ok(());
        }
        let Some(next) = (1..=runs.len())
            .map(|d| (cur + d) % runs.len())
            .find(|&i| runs[i].alive())
        else {
            return Ok(());
        };
        if next != cur {
            if runs[cur].alive() {
                runs[cur].stop();
            }
            runs[next].resume();
            cur = next;
        }
    }
}

/// The pauses of a run as CSV (`stopped_unix_nanos,continued_unix_nanos`), kept beside
/// its logs so that its per-step times can be filtered again.
pub fn pauses_csv(pauses: &[(u128, u128)]) -> String {
    let mut s = String::from("stopped_unix_nanos,continued_unix_nanos\n");
    for (a, b) in pauses {
        s.push_str(&format!("{a},{b}\n"));
    }
    s
}

/// A run's per-step figures over the steps no pause touched, seconds per step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CleanSteps {
    pub steps: usize,
    pub left_out: usize,
    pub wall_s: f64,
    pub field_step_s: f64,
    pub sampling_s: f64,
    pub waiting_s: f64,
    pub publishing_s: f64,
}

/// From the flow node's per-step CSV: the means over the steps that neither overlap a
/// pause (widened by `margin_nanos` either side, for signals on their way) nor are the
/// first (the wait for the fibre nodes' start).
pub fn clean_steps(csv: &str, pauses: &[(u128, u128)], margin_nanos: u128) -> Result<CleanSteps> {
    let mut lines = csv.lines();
    let header = lines.next().unwrap_or_default();
    if header != fiberflow_flow::step_times::HEADER {
        bail!("per-step times: unexpected header {header:?}");
    }
    let mut sums = [0u128; 5];
    let (mut n, mut left_out) = (0usize, 0usize);
    for (i, line) in lines.enumerate() {
        let v: Vec<u128> = line
            .split(',')
            .map(|x| x.parse::<u128>())
            .collect::<Result<_, _>>()
            .with_context(|| format!("per-step times: row {line:?}"))?;
        let [_, start, wall, field, sampling, waiting, publishing] = v[..] else {
            bail!("per-step times: row {line:?} does not have 7 values");
        };
        let end = start + wall;
        let paused = pauses
            .iter()
            .any(|&(s, c)| s < end + margin_nanos && c + margin_nanos > start);
        if i == 0 || paused {
            left_out += 1;
            continue;
        }
        n += 1;
        for (s, x) in sums
            .iter_mut()
            .zip([wall, field, sampling, waiting, publishing])
        {
            *s += x;
        }
    }
    if n == 0 {
        bail!("per-step times: every step was paused or the first");
    }
    let mean = |k: usize| sums[k] as f64 * 1e-9 / n as f64;
    Ok(CleanSteps {
        steps: n,
        left_out,
        wall_s: mean(0),
        field_step_s: mean(1),
        sampling_s: mean(2),
        waiting_s: mean(3),
        publishing_s: mean(4),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn csv(rows: &[[u128; 7]]) -> String {
        let mut s = format!("{}\n", fiberflow_flow::step_times::HEADER);
        for r in rows {
            let cells: Vec<String> = r.iter().map(|x| x.to_string()).collect();
            s.push_str(&cells.join(","));
            s.push('\n');
        }
        s
    }

    /// Steps a pause overlaps, and the first, are left out; the rest are averaged.
    #[test]
    fn paused_steps_and_the_first_are_left_out() {
        // steps of 10 ns from t = 100; step 0 slow (start-up), step 2 paused
        let rows = [
            [0, 100, 50, 1, 0, 40, 0],
            [1, 150, 10, 8, 1, 0, 1],
            [2, 160, 510, 508, 1, 0, 1],
            [3, 670, 12, 10, 1, 0, 1],
        ];
        let c = clean_steps(&csv(&rows), &[(170, 665)], 0).unwrap();
        assert_eq!((c.steps, c.left_out), (2, 2));
        assert!((c.wall_s - 11e-9).abs() < 1e-18, "{c:?}");
        assert!((c.field_step_s - 9e-9).abs() < 1e-18, "{c:?}");
        // a margin reaches a neighbour: a pause ending at 665 + 6 touches step 3 (from
        // 670), one starting at 170 - 6 not step 1 (to 160)
        let c = clean_steps(&csv(&rows), &[(170, 665)], 6).unwrap();
        assert_eq!((c.steps, c.left_out), (1, 3));
        // a pause wholly between steps touches none
        let rows = [
            [0, 0, 5, 0, 0, 0, 0],
            [1, 10, 5, 0, 0, 0, 0],
            [2, 30, 5, 0, 0, 0, 0],
        ];
        let c = clean_steps(&csv(&rows), &[(16, 29)], 0).unwrap();
        assert_eq!((c.steps, c.left_out), (2, 1));
    }

    #[test]
    fn malformed_step_times_are_an_error() {
        assert!(clean_steps("step,wall\n1,2\n", &[], 0).is_err());
        let bad = format!("{}\n1,2,3\n", fiberflow_flow::step_times::HEADER);
        assert!(clean_steps(&bad, &[], 0).is_err());
        let only_first = format!("{}\n0,1,2,3,4,5,6\n", fiberflow_flow::step_times::HEADER);
        assert!(clean_steps(&only_first, &[], 0).is_err());
    }

    /// A run dropped while stopped (the benchmark gave up on it) is killed, not left
    /// stopped behind.
    #[test]
    fn a_dropped_run_leaves_no_process_behind() {
        let child = std::process::Command::new("sleep")
            .arg("30")
            .spawn()
            .unwrap();
        let pid = child.id();
        let mut run = SlicedRun::new(vec![child]);
        run.stop();
        drop(run);
        // reaped by the drop: the pid no longer names this process
        assert!(!std::path::Path::new(&format!("/proc/{pid}")).exists());
    }

    /// Two processes in turns: while one runs the other is stopped (its clock of work
    /// does not move), and both reach their ends.
    #[test]
    fn runs_take_turns_and_both_finish() {
        let spawn = |path: &std::path::Path| {
            // counts in steps of 10 ms into a file, 60 times
            std::process::Command::new("sh")
                .arg("-c")
                .arg(format!(
                    "i=0; while [ $i -lt 60 ]; do i=$((i+1)); echo $i > {}; sleep 0.01; done",
                    path.display()
                ))
                .spawn()
                .unwrap()
        };
        let dir = std::env::temp_dir().join(format!("ff-slicing-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let (a, b) = (dir.join("a"), dir.join("b"));
        let mut runs = vec![
            SlicedRun::new(vec![spawn(&a)]),
            SlicedRun::new(vec![spawn(&b)]),
        ];
        run_in_turns(&mut runs, Duration::from_millis(100)).unwrap();
        for (r, p) in runs.iter().zip([&a, &b]) {
            assert!(r.failed.is_none());
            assert_eq!(std::fs::read_to_string(p).unwrap().trim(), "60");
        }
        // the second waited for the first's turn, and each was paused at least once
        // (60 × 10 ms each is well over one 100 ms turn)
        assert!(!runs[1].pauses.is_empty() && !runs[0].pauses.is_empty());
        for r in &runs {
            assert!(r.pauses.iter().all(|(s, c)| c > s));
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
