//! A recorded run as Parquet tables (docs/export.md): fibre states per segment, fibre
//! metrics per fibre, the flow's status per step, its profiles per wall distance, and the
//! contact lists. Reads every segment of a run folder, puts sharded groups back together,
//! keeps each (group, step) once, and streams: memory is bounded by one step of the run.

pub mod columns;
mod rows;
mod table;

pub use columns::Table;
pub use table::{schema, BATCH_ROWS, ROW_GROUP_ROWS};

use fiberflow_messages::pieces::Tiles;
use fiberflow_messages::sanity::Sane;
use fiberflow_messages::{
    decode, FiberGroupMetrics, FiberGroupState, FlowProfiles, FlowStatus, Kind, RunAnnouncement,
};
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use table::TableWriter;

#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {source}")]
    Parquet {
        path: PathBuf,
        source: parquet::errors::ParquetError,
    },
    #[error(
        "unknown table '{0}' (--what takes a list of: states, metrics, flow, profiles, contacts)"
    )]
    UnknownTable(String),
    #[error("export: {0}")]
    Internal(String),
}

impl ExportError {
    fn io(path: &Path, source: std::io::Error) -> Self {
        Self::Io {
            path: path.to_path_buf(),
            source,
        }
    }
    fn parquet(path: &Path, source: parquet::errors::ParquetError) -> Self {
        Self::Parquet {
            path: path.to_path_buf(),
            source,
        }
    }
}

/// The tables named in a comma list such as `states,metrics` (all of them for `None`).
pub fn tables_named(names: Option<&[String]>) -> Result<Vec<Table>, ExportError> {
    let Some(names) = names else {
        return Ok(columns::ALL.to_vec());
    };
    let mut out: Vec<Table> = Vec::new();
    for n in names {
        let t = columns::by_name(n.trim()).ok_or_else(|| ExportError::UnknownTable(n.clone()))?;
        if !out.iter().any(|o| o.name == t.name) {
            out.push(t);
        }
    }
    Ok(out)
}

/// What an export wrote and what it left out.
#[derive(Debug, Clone, Default)]
pub struct Summary {
    /// (file, rows) per table written.
    pub files: Vec<(PathBuf, u64)>,
    /// Segment files read.
    pub segments: usize,
    /// Messages dropped because they did not decode or failed their consistency checks.
    pub dropped: u64,
    /// Messages of a (group, step) or step already exported (a repeated step).
    pub repeated: u64,
    /// (group, step) pairs of a sharded group whose slices never all came (a killed run).
    pub incomplete: usize,
    /// Why a segment's reading stopped early (a damaged or cut tail), per segment.
    pub damaged: Vec<String>,
}

/// How far the export has come: the last step read, of the run's announced steps.
#[derive(Debug, Clone, Copy)]
pub struct Progress {
    pub step: u64,
    pub steps: Option<u64>,
}

/// Held messages beyond this many bytes are written even if a group is behind (a group
/// the run announced but never recorded would otherwise hold the whole run).
pub const HELD_LIMIT_BYTES: usize = 256 << 20;

/// A group message's size in memory, roughly.
trait Weight {
    fn weight(&self) -> usize;
}

impl Weight for FiberGroupState {
    fn weight(&self) -> usize {
        8 * (self.centre.len()
            + self.axis.len()
            + self.velocity.len()
            + self.angular_velocity.len()
            + self.hydro_force.len()
            + self.contact_force.len())
    }
}

impl Weight for FiberGroupMetrics {
    fn weight(&self) -> usize {
        8 * (self.centre_of_mass.len() + 3 * self.z1.len())
    }
}

type Steps<T> = Vec<(u64, BTreeMap<String, Vec<T>>)>;

/// Complete group messages of one kind, held until every group of the run has passed
/// their step, then written in (step, group, fibre) order: the same rows in the same order
/// however the recorder interleaved groups and the slices of shards.
struct Ordered<T> {
    tiles: Tiles<T>,
    /// step -> group -> slices in fibre order
    held: BTreeMap<u64, BTreeMap<String, Vec<T>>>,
    held_bytes: usize,
    /// Newest complete step of each group.
    newest: BTreeMap<String, u64>,
    done: BTreeSet<(String, u64)>,
}

impl<T> Default for Ordered<T> {
    fn default() -> Self {
        Self {
            tiles: Tiles::default(),
            held: BTreeMap::new(),
            held_bytes: 0,
            newest: BTreeMap::new(),
            done: BTreeSet::new(),
        }
    }
}

impl<T: Weight> Ordered<T> {
    /// Adds a slice; returns the held steps that every group of `groups` has completed or
    /// passed, ready to write (and the oldest ones beyond [`HELD_LIMIT_BYTES`]).
    #[allow(clippy::too_many_arguments)]
    fn add(
        &mut self,
        groups: &[String],
        group: &str,
        step: u64,
        first: u32,
        n: u32,
        total: u32,
        item: T,
        repeated: &mut u64,
    ) -> Steps<T> {
        let key = (group.to_string(), step);
        if self.done.contains(&key) {
            *repeated += 1;
            return Vec::new();
        }
        if let Some(slices) = self.tiles.add(group, step, first, n, total, item) {
            self.done.insert(key);
            self.held_bytes += slices.iter().map(Weight::weight).sum::<usize>();
            self.held
                .entry(step)
                .or_default()
                .insert(group.to_string(), slices);
            let newest = self.newest.entry(group.to_string()).or_insert(step);
            *newest = (*newest).max(step);
        }
        // the step every group has reached (the groups seen, without an announcement)
        let reached = if groups.is_empty() {
            self.newest.values().min().copied()
        } else {
            groups
                .iter()
                .map(|g| self.newest.get(g).copied())
                .min()
                .flatten()
        };
        let mut ready = Vec::new();
        while let Some(entry) = self.held.first_entry() {
            let over = self.held_bytes > HELD_LIMIT_BYTES;
            if !over && reached.is_none_or(|r| *entry.key() > r) {
                break;
            }
            let (s, g) = entry.remove_entry();
            self.held_bytes -= g.values().flatten().map(Weight::weight).sum::<usize>();
            ready.push((s, g));
        }
        ready
    }

    fn rest(&mut self) -> Steps<T> {
        self.held_bytes = 0;
        std::mem::take(&mut self.held).into_iter().collect()
    }
}

/// The open writer of each table asked for.
struct Writers {
    states: Option<TableWriter>,
    metrics: Option<TableWriter>,
    flow: Option<TableWriter>,
    profiles: Option<TableWriter>,
    contacts: Option<TableWriter>,
}

impl Writers {
    fn write_states<I>(&mut self, steps: I) -> Result<(), ExportError>
    where
        I: IntoIterator<Item = (u64, BTreeMap<String, Vec<FiberGroupState>>)>,
    {
        for (_, groups) in steps {
            for slices in groups.values() {
                rows::state(slices, self.states.as_mut(), self.contacts.as_mut())?;
            }
        }
        Ok(())
    }

    fn write_metrics<I>(&mut self, steps: I) -> Result<(), ExportError>
    where
        I: IntoIterator<Item = (u64, BTreeMap<String, Vec<FiberGroupMetrics>>)>,
    {
        if let Some(w) = self.metrics.as_mut() {
            for (_, groups) in steps {
                for slices in groups.values() {
                    rows::metrics(slices, w)?;
                }
            }
        }
        Ok(())
    }
}

/// Exports the recording `run` (a run folder: all its segments; or one `.mcap` file) into
/// `out`, one `<table>.parquet` per table of `tables`. `progress` is called as steps go by.
pub fn export(
    run: &Path,
    out: &Path,
    tables: &[Table],
    mut progress: impl FnMut(Progress),
) -> Result<Summary, ExportError> {
    let segments =
        fiberflow_messages::segments::segment_paths(run).map_err(|e| ExportError::io(run, e))?;
    std::fs::create_dir_all(out).map_err(|e| ExportError::io(out, e))?;
    let launch_toml = run
        .is_dir()
        .then(|| std::fs::read_to_string(run.join("launch.toml")).ok())
        .flatten();
    let mut metadata = vec![(
        "fiberflow.source".to_string(),
        run.canonicalize()
            .unwrap_or_else(|_| run.to_path_buf())
            .display()
            .to_string(),
    )];
    if let Some(t) = &launch_toml {
        metadata.push(("fiberflow.launch_toml".to_string(), t.clone()));
    }
    let open = |name: &str| -> Result<Option<TableWriter>, ExportError> {
        match tables.iter().find(|t| t.name == name) {
            Some(t) => TableWriter::create(out, *t, &metadata).map(Some),
            None => Ok(None),
        }
    };
    let mut w = Writers {
        states: open("states")?,
        metrics: open("metrics")?,
        flow: open("flow")?,
        profiles: open("profiles")?,
        contacts: open("contacts")?,
    };
    let want_states = w.states.is_some() || w.contacts.is_some();
    let mut summary = Summary {
        segments: segments.len(),
        ..Summary::default()
    };
    let mut announcement: Option<RunAnnouncement> = None;
    let mut states = Ordered::<FiberGroupState>::default();
    let mut metrics = Ordered::<FiberGroupMetrics>::default();
    let mut flow_steps = BTreeSet::new();
    let mut profile_steps = BTreeSet::new();
    let mut failed: Option<ExportError> = None;
    for seg in &segments {
        let stop = fiberflow_messages::reading::for_each_message(seg, |m| {
            if failed.is_some() {
                return;
            }
            let r = message(
                m,
                &mut w,
                want_states,
                &mut announcement,
                &mut states,
                &mut metrics,
                &mut flow_steps,
                &mut profile_steps,
                &mut summary,
                &mut progress,
            );
            if let Err(e) = r {
                failed = Some(e);
            }
        })
        .map_err(|e| ExportError::io(seg, e))?;
        if let Some(e) = failed.take() {
            return Err(e);
        }
        if let Some(why) = stop {
            tracing::warn!("{}: read up to damage: {why}", seg.display());
            summary.damaged.push(format!("{}: {why}", seg.display()));
        }
    }
    w.write_states(states.rest())?;
    w.write_metrics(metrics.rest())?;
    summary.incomplete = states.tiles.incomplete() + metrics.tiles.incomplete();
    if let Some(a) = &announcement {
        for t in [
            &mut w.states,
            &mut w.metrics,
            &mut w.flow,
            &mut w.profiles,
            &mut w.contacts,
        ]
        .into_iter()
        .flatten()
        {
            t.add_metadata("fiberflow.run_id", &a.run_id);
            t.add_metadata("fiberflow.config_digest", &a.config_digest);
            t.add_metadata("fiberflow.groups", &a.groups.join(","));
            t.add_metadata("fiberflow.dt_plus", &a.dt_plus.to_string());
            t.add_metadata(
                "fiberflow.box_plus",
                &a.box_plus
                    .iter()
                    .map(|x| x.to_string())
                    .collect::<Vec<_>>()
                    .join(","),
            );
        }
    }
    for t in [w.states, w.metrics, w.flow, w.profiles, w.contacts]
        .into_iter()
        .flatten()
    {
        let path = t.path().to_path_buf();
        let rows = t.finish()?;
        summary.files.push((path, rows));
    }
    Ok(summary)
}

/// One recorded message into the tables.
#[allow(clippy::too_many_arguments)]
fn message(
    m: fiberflow_messages::reading::Message<'_>,
    w: &mut Writers,
    want_states: bool,
    announcement: &mut Option<RunAnnouncement>,
    states: &mut Ordered<FiberGroupState>,
    metrics: &mut Ordered<FiberGroupMetrics>,
    flow_steps: &mut BTreeSet<u64>,
    profile_steps: &mut BTreeSet<u64>,
    summary: &mut Summary,
    progress: &mut impl FnMut(Progress),
) -> Result<(), ExportError> {
    let Some(kind) = fiberflow_messages::topics::kind_of(m.topic) else {
        return Ok(());
    };
    let steps = announcement.as_ref().map(|a| a.steps);
    // decoded and checked, or dropped and counted
    fn sane<T: fiberflow_messages::Message + Sane>(data: &[u8], dropped: &mut u64) -> Option<T> {
        match decode::<T>(data) {
            Ok(x) if x.check().is_ok() => Some(x),
            _ => {
                *dropped += 1;
                None
            }
        }
    }
    match kind {
        Kind::RunAnnouncement if announcement.is_none() => {
            *announcement = sane(m.data, &mut summary.dropped);
        }
        Kind::FlowStatus if w.flow.is_some() => {
            if let Some(s) = sane::<FlowStatus>(m.data, &mut summary.dropped) {
                if !flow_steps.insert(s.step) {
                    summary.repeated += 1;
                } else if let Some(t) = w.flow.as_mut() {
                    rows::flow(&s, t)?;
                }
                progress(Progress {
                    step: s.step,
                    steps,
                });
            }
        }
        Kind::FlowProfiles if w.profiles.is_some() => {
            if let Some(p) = sane::<FlowProfiles>(m.data, &mut summary.dropped) {
                if !profile_steps.insert(p.step) {
                    summary.repeated += 1;
                } else if let Some(t) = w.profiles.as_mut() {
                    rows::profiles(&p, t)?;
                }
            }
        }
        Kind::FiberGroupState if want_states => {
            let Some(s) = sane::<FiberGroupState>(m.data, &mut summary.dropped) else {
                return Ok(());
            };
            if s.is_lean() {
                summary.dropped += 1;
                return Ok(());
            }
            let (group, step, first) = (s.group.clone(), s.step, s.first_fiber);
            let (n, total) = (s.segments_per_fiber.len() as u32, s.group_fibers);
            let groups = announcement
                .as_ref()
                .map(|a| a.groups.as_slice())
                .unwrap_or(&[]);
            let ready = states.add(
                groups,
                &group,
                step,
                first,
                n,
                total,
                s,
                &mut summary.repeated,
            );
            w.write_states(ready)?;
            progress(Progress { step, steps });
        }
        Kind::FiberGroupMetrics if w.metrics.is_some() => {
            let Some(mt) = sane::<FiberGroupMetrics>(m.data, &mut summary.dropped) else {
                return Ok(());
            };
            let (group, step, first) = (mt.group.clone(), mt.step, mt.first_fiber);
            let (n, total) = (mt.z1.len() as u32, mt.group_fibers);
            let groups = announcement
                .as_ref()
                .map(|a| a.groups.as_slice())
                .unwrap_or(&[]);
            let ready = metrics.add(
                groups,
                &group,
                step,
                first,
                n,
                total,
                mt,
                &mut summary.repeated,
            );
            w.write_metrics(ready)?;
            progress(Progress { step, steps });
        }
        _ => {}
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use fiberflow_messages::{encode, topics::Topics, SCHEMA_VERSION};
    use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;

    /// Fibres `first .. first + n` of a 4-fibre group `g` (2 segments each) at `step`.
    fn slice(group: &str, step: u64, first: u32, n: u32) -> FiberGroupState {
        let segs = 2 * n as usize;
        FiberGroupState {
            schema_version: SCHEMA_VERSION,
            group: group.into(),
            step,
            t_plus: step as f64 * 0.25,
            first_fiber: first,
            group_fibers: 4,
            segments_per_fiber: vec![2; n as usize],
            segment_length: vec![3.0; n as usize],
            diameter: vec![0.2; n as usize],
            density_ratio: vec![800.0; n as usize],
            layer: vec![0; n as usize],
            centre: (0..3 * segs)
                .map(|i| (first as usize * 6 + i) as f64)
                .collect(),
            axis: [1.0, 0.0, 0.0].repeat(segs),
            velocity: vec![0.5; 3 * segs],
            angular_velocity: vec![0.0; 3 * segs],
            hydro_force: vec![],
            contact_segment: vec![1],
            contact_force: vec![0.1, 0.2, 0.3],
            contacts: vec![2],
        }
    }

    fn rows(path: &Path) -> Vec<arrow_array::RecordBatch> {
        let f = std::fs::File::open(path).unwrap();
        ParquetRecordBatchReaderBuilder::try_new(f)
            .unwrap()
            .build()
            .unwrap()
            .map(|b| b.unwrap())
            .collect()
    }

    /// A recording as a killed, sharded run leaves it: two groups interleaved out of step
    /// order, group `a` in two shards whose slices come in either order, a slice sent
    /// twice, a step whose second slice never came, a message that does not decode and one
    /// that decodes but makes no sense. The export keeps each complete (group, step) once,
    /// in (step, group, fibre) order, and counts what it left out.
    #[test]
    fn a_messy_recording_exports_each_step_once_in_order() {
        let dir = std::env::temp_dir().join(format!("ff-export-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("run.mcap");
        let t = Topics::new("r");
        {
            let mut w = mcap::Writer::new(std::io::BufWriter::new(
                std::fs::File::create(&path).unwrap(),
            ))
            .unwrap();
            let mut n = 0u32;
            let mut put = |topic: &str, data: &[u8]| {
                let ch = w.add_channel(0, topic, "cdr", &Default::default()).unwrap();
                let h = mcap::records::MessageHeader {
                    channel_id: ch,
                    sequence: n,
                    log_time: n as u64,
                    publish_time: 0,
                };
                n += 1;
                w.write_to_known_channel(&h, data).unwrap();
            };
            let ann = RunAnnouncement {
                schema_version: SCHEMA_VERSION,
                run_id: "r".into(),
                config_digest: "d".into(),
                groups: vec!["a".into(), "b".into()],
                steps: 2,
                dt_plus: 0.25,
                box_plus: vec![10.0, 2.0, 5.0],
            };
            put(&t.announce(), &encode(&ann));
            let (sa, sb) = (t.fiber_state("a"), t.fiber_state("b"));
            put(&sb, &encode(&slice("b", 0, 0, 4)));
            put(&sb, &encode(&slice("b", 1, 0, 4)));
            put(&sa, &encode(&slice("a", 0, 2, 2)));
            put(&sa, &[1, 2, 3]);
            let mut nonsense = slice("a", 0, 0, 2);
            nonsense.centre.pop();
            put(&sa, &encode(&nonsense));
            put(&sa, &encode(&slice("a", 0, 0, 2)));
            put(&sa, &encode(&slice("a", 0, 0, 2)));
            put(&sa, &encode(&slice("a", 1, 0, 2)));
            w.finish().unwrap();
        }
        let out = dir.join("export");
        let s = export(&path, &out, &[columns::STATES, columns::CONTACTS], |_| {}).unwrap();
        assert_eq!((s.dropped, s.repeated, s.incomplete), (2, 1, 1));
        let batches = rows(&out.join("states.parquet"));
        let key = |b: &arrow_array::RecordBatch| {
            use arrow_array::cast::AsArray;
            use arrow_array::types::{UInt32Type, UInt64Type};
            let step = b.column(0).as_primitive::<UInt64Type>();
            let group = b.column(2).as_string::<i32>();
            let fiber = b.column(3).as_primitive::<UInt32Type>();
            (0..b.num_rows())
                .map(|i| (step.value(i), group.value(i).to_string(), fiber.value(i)))
                .collect::<Vec<_>>()
        };
        let got: Vec<_> = batches.iter().flat_map(key).collect();
        let mut want = Vec::new();
        for (step, group) in [(0, "a"), (0, "b"), (1, "b")] {
            for f in 0..4u32 {
                want.extend(std::iter::repeat_n((step, group.to_string(), f), 2));
            }
        }
        assert_eq!(got, want);
        // one touched segment per slice: a's two slices and b's one, at steps 0 and 1
        let contacts: usize = rows(&out.join("contacts.parquet"))
            .iter()
            .map(|b| b.num_rows())
            .sum();
        assert_eq!(contacts, 4);
        std::fs::remove_dir_all(&dir).ok();
    }
}
