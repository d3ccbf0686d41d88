//! Every coupling step's wall and stages as CSV (`logs/flow-steps.csv` of a launch): what
//! a per-run total hides — slow steps, drift, a step that a pause of the process fell
//! into. `fiberflow-bench scale --slice-ms` reads it to leave out the steps its pauses
//! touched. The rows go to the file as the run steps — every [`FLUSH_ROWS`] rows, at
//! every checkpoint and at the end — so memory stays bounded however long the run, and a
//! killed flow node leaves the rows up to its last flush.

use crate::error::{io_err, FlowError};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Instant, SystemTime, UNIX_EPOCH};

/// The header of the CSV, one row per coupling step.
pub const HEADER: &str =
    "step,start_unix_nanos,wall_nanos,field_step_nanos,sampling_nanos,waiting_nanos,publishing_nanos";

/// Rows held in memory before they go to the file (460 KB).
pub const FLUSH_ROWS: usize = 4096;

/// Stage seconds summed over the run so far (a step's are the change over it).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Stages {
    pub field_step_s: f64,
    pub sampling_s: f64,
    pub waiting_s: f64,
    pub publishing_s: f64,
}

#[derive(Debug, Clone, Copy)]
struct Open {
    step: u64,
    from: Instant,
    stages: Stages,
}

/// The rows of one run, on their way to the file.
#[derive(Debug)]
pub struct StepTimes {
    origin: Instant,
    origin_unix_nanos: u128,
    open: Option<Open>,
    /// Rows not yet in the file (at most [`FLUSH_ROWS`]).
    rows: Vec<[u128; 7]>,
    /// The CSV being written; `None`: the times are not kept.
    file: Option<(PathBuf, std::fs::File)>,
}

impl StepTimes {
    /// Keeps the times in `path` (created with its header, or replaced), or nowhere.
    pub fn new(path: Option<&Path>) -> Result<Self, FlowError> {
        let origin = Instant::now();
        let origin_unix_nanos = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map(|d| d.as_nanos())
            .unwrap_or(0);
        let file = match path {
            Some(p) => {
                let mut f = std::fs::File::create(p).map_err(io_err(p))?;
                writeln!(f, "{HEADER}").map_err(io_err(p))?;
                Some((p.to_path_buf(), f))
            }
            None => None,
        };
        Ok(Self {
            origin,
            origin_unix_nanos,
            open: None,
            rows: Vec::with_capacity(if file.is_some() { FLUSH_ROWS } else { 0 }),
            file,
        })
    }

    /// Step `step` begins now; the step before it (if any) ends here. `totals`: the
    /// stage sums so far.
    pub fn begin(&mut self, step: u64, totals: Stages) {
        let now = Instant::now();
        self.close_at(now, totals);
        self.open = Some(Open {
            step,
            from: now,
            stages: totals,
        });
    }

    /// The last step ends now.
    pub fn end(&mut self, totals: Stages) {
        self.close_at(Instant::now(), totals);
    }

    fn close_at(&mut self, now: Instant, totals: Stages) {
        let Some(o) = self.open.take() else { return };
        if self.file.is_none() {
            return;
        }
        let nanos = |s: f64| (s.max(0.0) * 1e9).round() as u128;
        self.rows.push([
            o.step as u128,
            self.origin_unix_nanos + o.from.duration_since(self.origin).as_nanos(),
            now.duration_since(o.from).as_nanos(),
            nanos(totals.field_step_s - o.stages.field_step_s),
            nanos(totals.sampling_s - o.stages.sampling_s),
            nanos(totals.waiting_s - o.stages.waiting_s),
            nanos(totals.publishing_s - o.stages.publishing_s),
        ]);
    }

    /// Rows not yet in the file (bounded by [`FLUSH_ROWS`]).
    pub fn pending(&self) -> usize {
        self.rows.len()
    }

    /// Keeps nothing.
    pub fn disabled() -> Self {
        Self {
            origin: Instant::now(),
            origin_unix_nanos: 0,
            open: None,
            rows: Vec::new(),
            file: None,
        }
    }

    /// Appends the rows held so far to the file (a checkpoint's or the end's flush). They
    /// are diagnostics: a file that cannot be written is logged and left out from then on.
    pub fn flush(&mut self) {
        if let Err(e) = self.try_flush() {
            tracing::warn!(error = %e, "the per-step times are no longer written");
            self.file = None;
            self.rows = Vec::new();
        }
    }

    fn try_flush(&mut self) -> Result<(), FlowError> {
        let Some((path, f)) = &mut self.file else {
            return Ok(());
        };
        let mut s = String::with_capacity(64 * self.rows.len());
        for r in &self.rows {
            let cells: Vec<String> = r.iter().map(|x| x.to_string()).collect();
            s.push_str(&cells.join(","));
            s.push('\n');
        }
        self.rows.clear();
        f.write_all(s.as_bytes()).map_err(io_err(path))?;
        f.sync_data().map_err(io_err(path))
    }

    /// Flushes once [`FLUSH_ROWS`] rows have gathered.
    pub fn flush_if_full(&mut self) {
        if self.rows.len() >= FLUSH_ROWS {
            self.flush();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("ff-steptimes-{}-{name}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        d.join("flow-steps.csv")
    }

    /// 10,000 steps: never more than FLUSH_ROWS rows in memory; the file holds every row
    /// flushed so far (what a killed node leaves), all of them after the last flush; no
    /// path keeps nothing.
    #[test]
    fn rows_stream_to_the_file_and_memory_stays_bounded() {
        let path = temp("stream");
        let mut t = StepTimes::new(Some(&path)).unwrap();
        let totals = Stages::default();
        let mut most = 0;
        for k in 0..10_000 {
            t.begin(k, totals);
            t.flush_if_full();
            most = most.max(t.pending());
            if k == 6000 {
                // a checkpoint: what is on disk now survives a kill -9
                t.flush();
                let on_disk = std::fs::read_to_string(&path).unwrap().lines().count();
                assert_eq!(on_disk, 1 + 6000, "header and steps 0..6000 closed");
            }
        }
        assert!(most <= FLUSH_ROWS, "{most}");
        t.end(totals);
        t.flush();
        let text = std::fs::read_to_string(&path).unwrap();
        let steps: Vec<u64> = text
            .lines()
            .skip(1)
            .map(|l| l.split(',').next().unwrap().parse().unwrap())
            .collect();
        assert_eq!(steps, (0..10_000).collect::<Vec<u64>>());
        let mut none = StepTimes::new(None).unwrap();
        none.begin(0, totals);
        none.end(totals);
        assert_eq!(none.pending(), 0);
    }

    #[test]
    fn each_row_is_one_step_with_its_own_stage_times() {
        let path = temp("rows");
        let mut t = StepTimes::new(Some(&path)).unwrap();
        let mut totals = Stages::default();
        t.begin(5, totals);
        std::thread::sleep(std::time::Duration::from_millis(3));
        totals.field_step_s += 0.002;
        totals.sampling_s += 0.000_5;
        t.begin(6, totals);
        totals.waiting_s += 0.001;
        totals.publishing_s += 0.000_25;
        t.end(totals);
        t.end(totals); // nothing open: no row
        t.flush();
        let csv = std::fs::read_to_string(&path).unwrap();
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines.len(), 3, "a header and two rows");
        assert_eq!(lines[0], HEADER);
        let row =
            |i: usize| -> Vec<u128> { lines[i].split(',').map(|x| x.parse().unwrap()).collect() };
        let (a, b) = (row(1), row(2));
        assert_eq!((a[0], b[0]), (5, 6));
        // each step's stages are its own, not the running sums
        assert_eq!(&a[3..], &[2_000_000, 500_000, 0, 0]);
        assert_eq!(&b[3..], &[0, 0, 1_000_000, 250_000]);
        // the first step lasted at least the sleep, and the second began as it ended
        assert!(a[2] >= 3_000_000, "{a:?}");
        assert_eq!(b[1], a[1] + a[2]);
        // the start is wall-clock time (after 2020)
        assert!(a[1] > 1_577_836_800_000_000_000, "{a:?}");
    }
}
