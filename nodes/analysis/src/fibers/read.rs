//! Reading a recording's fibres: every group's per-fibre series (centre of mass, z1, σ²)
//! from its states (or, at steps without one, its metrics), and the suspensions' flocs.

use super::GroupSeries;
use crate::{io_err, AnalysisError};
use fiberflow_messages::pieces::Tiles;
use fiberflow_messages::{decode, FiberGroupMetrics, FiberGroupState};
use std::collections::BTreeMap;
use std::path::Path;

/// One recorded instant of a group: per-fibre centre of mass, z1 and σ².
pub(crate) struct Row {
    pub(crate) t_plus: f64,
    pub(crate) com: Vec<[f64; 3]>,
    pub(crate) z1: Vec<f64>,
    pub(crate) sigma2: Vec<f64>,
}

/// Centre of mass, z1 and σ² of the fibre whose segments are `seg0 .. seg0 + n` in a state
/// (paper §4.3: ẑ = Σẑ_i/|Σẑ_i|, z1 = ẑ·ê1, σ² = Σ|ẑ_i − ẑ|²/(N−1), 0 for N = 1).
pub fn fiber_of_state(s: &FiberGroupState, seg0: usize, n: usize) -> ([f64; 3], f64, f64) {
    let mut c = [0.0; 3];
    let mut zs = [0.0; 3];
    for i in seg0..seg0 + n {
        for a in 0..3 {
            c[a] += s.centre[3 * i + a] / n as f64;
            zs[a] += s.axis[3 * i + a];
        }
    }
    let norm = (zs[0] * zs[0] + zs[1] * zs[1] + zs[2] * zs[2])
        .sqrt()
        .max(1e-300);
    let zh = [zs[0] / norm, zs[1] / norm, zs[2] / norm];
    let mut var = 0.0;
    for i in seg0..seg0 + n {
        for a in 0..3 {
            var += (s.axis[3 * i + a] - zh[a]).powi(2);
        }
    }
    (c, zh[0], if n > 1 { var / (n - 1) as f64 } else { 0.0 })
}

/// Per-fibre metrics of a state ([`fiber_of_state`] for every fibre).
pub(crate) fn row_of_state(s: &FiberGroupState) -> Row {
    let nf = s.segments_per_fiber.len();
    let mut row = Row {
        t_plus: s.t_plus,
        com: Vec::with_capacity(nf),
        z1: Vec::with_capacity(nf),
        sigma2: Vec::with_capacity(nf),
    };
    let mut seg = 0usize;
    for &n in &s.segments_per_fiber {
        let (c, z1, s2) = fiber_of_state(s, seg, n as usize);
        row.com.push(c);
        row.z1.push(z1);
        row.sigma2.push(s2);
        seg += n as usize;
    }
    row
}

pub(crate) fn row_of_metrics(m: &FiberGroupMetrics) -> Row {
    Row {
        t_plus: m.t_plus,
        com: m
            .centre_of_mass
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect(),
        z1: m.z1.clone(),
        sigma2: m.sigma2.clone(),
    }
}

/// What one group's recording holds, as it is read.
#[derive(Default)]
pub(crate) struct Reading {
    /// The first state's fibres: every later state must describe the same.
    pub(crate) shape: Option<Vec<u32>>,
    pub(crate) layer: Vec<u8>,
    pub(crate) density_ratio: f64,
    pub(crate) segment_length: f64,
    pub(crate) from_states: BTreeMap<u64, Row>,
    pub(crate) from_metrics: BTreeMap<u64, Row>,
    pub(crate) flocs: Vec<crate::flocs::FlocRow>,
}

/// Reads a recording's fibre groups, ordered by step. `mcap_path` is a run folder (all
/// its segments, in order) or one `.mcap` file. Each state is reduced to per-fibre metrics
/// as it is read (so memory grows with fibres x steps, not segments); steps without a state
/// (a recording with `states_every_steps` > 1) take the fibre node's own metrics message.
/// Messages that fail their consistency checks are skipped.
pub fn read_groups(mcap_path: &Path) -> Result<BTreeMap<String, GroupSeries>, AnalysisError> {
    Ok(read_recording(mcap_path)?.0)
}

/// The contacts and flocs of each suspension of a run (groups whose fibres touch each
/// other, `[[suspensions]]` in the run folder's `launch.toml`) over its recorded complete
/// states, named by its groups joined with `+`.
pub type SuspensionFlocs = Vec<(String, Vec<crate::flocs::FlocRow>)>;

/// [`read_groups`], and the flocs of the run's suspensions.
pub fn read_recording(
    mcap_path: &Path,
) -> Result<(BTreeMap<String, GroupSeries>, SuspensionFlocs), AnalysisError> {
    use fiberflow_messages::sanity::Sane;
    let suspensions = crate::flocs::suspensions_of_run(mcap_path);
    let mut suspension_rows: Vec<Vec<crate::flocs::FlocRow>> = vec![Vec::new(); suspensions.len()];
    // a suspension's groups' states of a step, until all have come
    let mut pending: BTreeMap<(usize, u64), BTreeMap<String, FiberGroupState>> = BTreeMap::new();
    let segs = fiberflow_messages::segments::segment_paths(mcap_path).map_err(io_err(mcap_path))?;
    let mut by: BTreeMap<String, Reading> = BTreeMap::new();
    // a sharded group's slices, put back together per step
    let mut state_tiles = Tiles::default();
    let mut metric_tiles = Tiles::default();
    // the box (periodic along x1 and x3) that contacts are found in
    let mut box_plus: Option<[f64; 3]> = None;
    for seg in &segs {
        // streamed a chunk at a time; a damaged tail ends the segment: analyse what is there
        fiberflow_messages::reading::for_each_message(seg, |m| {
            let topic = m.topic;
            if topic.ends_with("/control/announce") {
                if let Ok(a) = decode::<fiberflow_messages::RunAnnouncement>(m.data) {
                    if let [x, y, z] = a.box_plus[..] {
                        box_plus.get_or_insert([x, y, z]);
                    }
                }
            } else if topic.ends_with("/state") {
                let Ok(s) = decode::<FiberGroupState>(m.data) else {
                    return;
                };
                // a lean state (centres only) has no orientation to analyse
                if s.check().is_err() || s.is_lean() {
                    return;
                }
                let Some(s) = state_tiles.add_slice(s) else {
                    return;
                };
                let r = by.entry(s.group.clone()).or_default();
                if r.shape.get_or_insert_with(|| s.segments_per_fiber.clone())
                    != &s.segments_per_fiber
                {
                    return;
                }
                if r.layer.is_empty() {
                    r.layer = s.layer.clone();
                    r.density_ratio = s.density_ratio.first().copied().unwrap_or(0.0);
                    r.segment_length = s.segment_length.first().copied().unwrap_or(0.0);
                }
                if let Some(b) = box_plus {
                    r.flocs.push(crate::flocs::of_state(&s, b));
                    if let Some(i) = suspensions.iter().position(|m| m.contains(&s.group)) {
                        let got = pending.entry((i, s.step)).or_default();
                        got.insert(s.group.clone(), s.clone());
                        if suspensions[i].iter().all(|g| got.contains_key(g)) {
                            let states: Vec<&FiberGroupState> =
                                suspensions[i].iter().filter_map(|g| got.get(g)).collect();
                            if let Some(m) = crate::flocs::merged(&states) {
                                suspension_rows[i].push(crate::flocs::of_state(&m, b));
                            }
                            pending.remove(&(i, s.step));
                        }
                    }
                }
                r.from_states.insert(s.step, row_of_state(&s));
            } else if topic.ends_with("/metrics") && topic.contains("/fibers/") {
                let Ok(mt) = decode::<FiberGroupMetrics>(m.data) else {
                    return;
                };
                if mt.check().is_err() {
                    return;
                }
                if let Some(mt) = metric_tiles.add_slice(mt) {
                    by.entry(mt.group.clone())
                        .or_default()
                        .from_metrics
                        .insert(mt.step, row_of_metrics(&mt));
                }
            }
        })
        .map_err(io_err(seg))?;
    }
    let mut out = BTreeMap::new();
    for (g, mut r) in by {
        // a group needs at least one state: its fibres and layers
        let Some(shape) = &r.shape else { continue };
        let nf = shape.len();
        let mut rows = std::mem::take(&mut r.from_states);
        for (k, row) in std::mem::take(&mut r.from_metrics) {
            if row.z1.len() == nf {
                rows.entry(k).or_insert(row);
            }
        }
        r.flocs.sort_by_key(|f| f.step);
        r.flocs.dedup_by_key(|f| f.step);
        let mut gs = GroupSeries {
            flocs: std::mem::take(&mut r.flocs),
            layer: r.layer,
            density_ratio: r.density_ratio,
            segment_length: r.segment_length,
            ..Default::default()
        };
        for (_, row) in rows {
            gs.t_plus.push(row.t_plus);
            gs.com.push(row.com);
            gs.z1.push(row.z1);
            gs.sigma2.push(row.sigma2);
        }
        out.insert(g, gs);
    }
    let named = suspensions
        .iter()
        .map(|m| m.join("+"))
        .zip(suspension_rows)
        .filter(|(_, rows)| !rows.is_empty())
        .collect();
    Ok((out, named))
}
