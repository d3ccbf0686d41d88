//! Every coupling step's wall and stages, kept in memory while the run steps and written
//! as CSV when it ends (`logs/flow-steps.csv` of a launch): what a per-run total hides —
//! slow steps, drift, a step that a pause of the process fell into. `fiberflow
//! bench-scale --slice-ms` reads it to leave out the steps its pauses touched.

use crate::error::{io_err, FlowError};
use std::io::Write;
use std::path::Path;
use std::time::{Instant, SystemTime, UNIX_EPOCH};

/// The header of the CSV, one row per coupling step.
pub const HEADER: &str =
    "step,start_unix_nanos,wall_nanos,field_step_nanos,sampling_nanos,waiting_nanos,publishing_nanos";

/// The most rows reserved up front (7 MB): `run.steps` may be up to 10⁸, and 10⁸ rows
/// reserved at the start would ask for 11 GB.
pub const RESERVED_ROWS_MAX: usize = 1 << 16;

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

/// The rows of one run.
#[derive(Debug)]
pub struct StepTimes {
    origin: Instant,
    origin_unix_nanos: u128,
    open: Option<Open>,
    rows: Vec<[u128; 7]>,
}

impl StepTimes {
    /// Room for `steps` rows, up to [`RESERVED_ROWS_MAX`] (no allocation while stepping
    /// below that; a longer run's rows grow as it steps, 112 bytes each).
    pub fn new(steps: usize) -> Self {
        let origin = Instant::now();
        let origin_unix_nanos = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map(|d| d.as_nanos())
            .unwrap_or(0);
        Self {
            origin,
            origin_unix_nanos,
            open: None,
            rows: Vec::with_capacity(steps.saturating_add(1).min(RESERVED_ROWS_MAX)),
        }
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

    /// The CSV text: [`HEADER`], then a row per step.
    pub fn csv(&self) -> String {
        let mut s = String::with_capacity(64 * (self.rows.len() + 1));
        s.push_str(HEADER);
        s.push('\n');
        for r in &self.rows {
            let cells: Vec<String> = r.iter().map(|x| x.to_string()).collect();
            s.push_str(&cells.join(","));
            s.push('\n');
        }
        s
    }

    /// Writes the CSV to `path` (through a temporary file: a reader never sees half).
    pub fn write(&self, path: &Path) -> Result<(), FlowError> {
        let tmp = path.with_extension("csv.partial");
        let mut f = std::fs::File::create(&tmp).map_err(io_err(&tmp))?;
        f.write_all(self.csv().as_bytes()).map_err(io_err(&tmp))?;
        std::fs::rename(&tmp, path).map_err(io_err(path))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_row_is_one_step_with_its_own_stage_times() {
        let mut t = StepTimes::new(3);
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
        let csv = t.csv();
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

    #[test]
    fn the_longest_allowed_run_reserves_a_bounded_table() {
        // run.steps may be 10^8: reserving a row per step would ask for 11 GB at the start
        let t = StepTimes::new(100_000_000);
        assert_eq!(t.rows.capacity(), RESERVED_ROWS_MAX);
        let t = StepTimes::new(usize::MAX);
        assert_eq!(t.rows.capacity(), RESERVED_ROWS_MAX);
        // a run within the bound reserves all of its rows
        assert!(StepTimes::new(404).rows.capacity() >= 405);
    }

    #[test]
    fn the_file_appears_whole() {
        let dir = std::env::temp_dir().join(format!("ff-step-times-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("flow-steps.csv");
        let mut t = StepTimes::new(1);
        t.begin(0, Stages::default());
        t.end(Stages::default());
        t.write(&path).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert_eq!(text.lines().count(), 2);
        assert!(!path.with_extension("csv.partial").exists());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
