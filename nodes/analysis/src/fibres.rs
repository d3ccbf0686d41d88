//! Fibre analysis of a recording (paper §4, figs. 6–10): MSD_23 (eq. 20) with its log-log
//! slope, ⟨|z1|⟩ ± σ per initial layer, signed z1 per fibre, ⟨σ²⟩(t), trajectories in the
//! x3–x2 plane; 95% bootstrap intervals over fibres for the MSD slope, the ramp time per
//! layer and the final ⟨σ²⟩. Metrics are recomputed from the recorded states; steps without
//! a state (a decimated recording) take the fibre node's metrics message.
//!
//! Size: one pass over a recording feeds every figure of the paper's §4, so the reader,
//! the per-layer series and their bootstrap intervals sit together; coiling onsets, plots
//! and the bootstrap itself are in their own files.

use crate::bootstrap::{self, weighted_mean, Interval};
use crate::plot::{line_plot, Series};
use crate::{io_err, AnalysisError};
use fiberflow_messages::pieces::Tiles;
use fiberflow_messages::{decode, FiberGroupMetrics, FiberGroupState};
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

pub use crate::series::GroupSeries;

/// Numbers for the summary table.
#[derive(Debug, Clone, Default)]
pub struct GroupSummary {
    pub group: String,
    pub fibres: usize,
    pub msd_slope: f64,
    pub fit_window: (f64, f64),
    pub ramp_time: f64,
    /// Ramp time per initial layer: near wall, next, middle.
    pub ramp_by_layer: [f64; 3],
    pub final_abs_z1: f64,
    pub final_sigma2: f64,
    pub segment_length: f64,
    pub density_ratio: f64,
    /// 95% bootstrap intervals over fibres.
    pub msd_slope_ci: Interval,
    pub ramp_by_layer_ci: [Interval; 3],
    pub final_sigma2_ci: Interval,
}

impl Default for Interval {
    fn default() -> Self {
        Interval::NAN
    }
}

/// One recorded instant of a group: per-fibre centre of mass, z1 and σ².
struct Row {
    t_plus: f64,
    com: Vec<[f64; 3]>,
    z1: Vec<f64>,
    sigma2: Vec<f64>,
}

/// Centre of mass, z1 and σ² of the fibre whose segments are `seg0 .. seg0 + n` in a state
/// (paper §4.3: ẑ = Σẑ_i/|Σẑ_i|, z1 = ẑ·ê1, σ² = Σ|ẑ_i − ẑ|²/(N−1), 0 for N = 1).
pub fn fibre_of_state(s: &FiberGroupState, seg0: usize, n: usize) -> ([f64; 3], f64, f64) {
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

/// Per-fibre metrics of a state ([`fibre_of_state`] for every fibre).
fn row_of_state(s: &FiberGroupState) -> Row {
    let nf = s.segments_per_fiber.len();
    let mut row = Row {
        t_plus: s.t_plus,
        com: Vec::with_capacity(nf),
        z1: Vec::with_capacity(nf),
        sigma2: Vec::with_capacity(nf),
    };
    let mut seg = 0usize;
    for &n in &s.segments_per_fiber {
        let (c, z1, s2) = fibre_of_state(s, seg, n as usize);
        row.com.push(c);
        row.z1.push(z1);
        row.sigma2.push(s2);
        seg += n as usize;
    }
    row
}

fn row_of_metrics(m: &FiberGroupMetrics) -> Row {
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
struct Reading {
    /// The first state's fibres: every later state must describe the same.
    shape: Option<Vec<u32>>,
    layer: Vec<u8>,
    density_ratio: f64,
    segment_length: f64,
    from_states: BTreeMap<u64, Row>,
    from_metrics: BTreeMap<u64, Row>,
    flocs: Vec<crate::flocs::FlocRow>,
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

/// Per-fibre sums of squared cross-stream displacements (eq. 20) per lag bin: the MSD and
/// its bootstrap both come from it.
#[derive(Debug, Clone, Default)]
pub struct MsdTable {
    /// Lag of bin b is b·dt.
    pub dt: f64,
    /// [fibre][bin] sum over time-origin pairs of |Δx2|² + |Δx3|².
    pub per_fibre: Vec<Vec<f64>>,
    /// [bin] number of time-origin pairs.
    pub pairs: Vec<usize>,
}

impl MsdTable {
    /// Lags are the true time differences between states, in multiples of the smallest
    /// spacing: a recording with gaps (decimated or lost states) gives each pair its real
    /// lag.
    pub fn new(g: &GroupSeries) -> Self {
        use rayon::prelude::*;
        let n = g.t_plus.len().min(g.com.len());
        if n < 2 {
            return Self::default();
        }
        let dt = g
            .t_plus
            .windows(2)
            .map(|w| w[1] - w[0])
            .filter(|d| *d > 0.0)
            .fold(f64::INFINITY, f64::min);
        if !dt.is_finite() {
            return Self::default();
        }
        let span = ((g.t_plus[n - 1] - g.t_plus[0]) / dt).round() as usize;
        let bins: Vec<Vec<(usize, usize)>> = {
            let mut b = vec![Vec::new(); span + 1];
            for k in 0..n {
                for k2 in k + 1..n {
                    let bin = ((g.t_plus[k2] - g.t_plus[k]) / dt).round() as usize;
                    if let Some(v) = b.get_mut(bin) {
                        v.push((k, k2));
                    }
                }
            }
            b
        };
        let nf = g.com[0].len();
        let per_fibre = (0..nf)
            .into_par_iter()
            .map(|f| {
                let x: Vec<[f64; 2]> = g.com[..n].iter().map(|c| [c[f][1], c[f][2]]).collect();
                bins.iter()
                    .map(|pairs| {
                        pairs
                            .iter()
                            .map(|&(a, b)| {
                                (x[b][0] - x[a][0]).powi(2) + (x[b][1] - x[a][1]).powi(2)
                            })
                            .sum::<f64>()
                    })
                    .collect()
            })
            .collect();
        Self {
            dt,
            per_fibre,
            pairs: bins.iter().map(|p| p.len()).collect(),
        }
    }

    /// MSD_23(τ) over the fibres with multiplicities `w` (None: every fibre once), for
    /// the lags in [lo, hi].
    pub fn msd(&self, w: Option<&[u32]>, lo: f64, hi: f64) -> Vec<(f64, f64)> {
        let bins: Vec<usize> = (1..self.pairs.len())
            .filter(|&b| self.pairs[b] > 0)
            .filter(|&b| {
                let t = b as f64 * self.dt;
                t >= lo && t <= hi
            })
            .collect();
        let mut sum = vec![0.0; bins.len()];
        let mut fibres = 0u64;
        for (f, s) in self.per_fibre.iter().enumerate() {
            let k = w.map_or(1, |w| w[f]);
            if k == 0 {
                continue;
            }
            fibres += k as u64;
            for (acc, &b) in sum.iter_mut().zip(&bins) {
                *acc += k as f64 * s[b];
            }
        }
        bins.iter()
            .zip(sum)
            .map(|(&b, s)| {
                (
                    b as f64 * self.dt,
                    s / (self.pairs[b] as u64 * fibres) as f64,
                )
            })
            .collect()
    }
}

/// MSD_23(τ) (eq. 20): mean over fibres and time origins of the cross-stream (x2, x3)
/// squared displacement of the centre of mass, for every lag (see [`MsdTable::new`]).
pub fn msd23(g: &GroupSeries) -> Vec<(f64, f64)> {
    MsdTable::new(g).msd(None, 0.0, f64::INFINITY)
}

/// Least-squares slope of log MSD against log τ over [lo, hi].
pub fn loglog_slope(msd: &[(f64, f64)], lo: f64, hi: f64) -> f64 {
    let pts: Vec<(f64, f64)> = msd
        .iter()
        .filter(|(t, m)| *t >= lo && *t <= hi && *m > 0.0)
        .map(|(t, m)| (t.ln(), m.ln()))
        .collect();
    let n = pts.len() as f64;
    if n < 2.0 {
        return f64::NAN;
    }
    let (sx, sy) = pts.iter().fold((0.0, 0.0), |a, p| (a.0 + p.0, a.1 + p.1));
    let (mx, my) = (sx / n, sy / n);
    let (num, den) = pts.iter().fold((0.0, 0.0), |a, p| {
        (a.0 + (p.0 - mx) * (p.1 - my), a.1 + (p.0 - mx).powi(2))
    });
    num / den
}

fn mean_std(v: &[f64]) -> (f64, f64) {
    let n = v.len().max(1) as f64;
    let m = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / n;
    (m, var.sqrt())
}

/// ⟨|z1|⟩(t) over the fibres of one layer (or all if `layer` is None), with σ.
pub fn abs_z1(g: &GroupSeries, layer: Option<u8>) -> Vec<(f64, f64, f64)> {
    g.t_plus
        .iter()
        .zip(&g.z1)
        .map(|(t, zs)| {
            let v: Vec<f64> = zs
                .iter()
                .enumerate()
                .filter(|(i, _)| layer.is_none_or(|l| g.layer.get(*i) == Some(&l)))
                .map(|(_, z)| z.abs())
                .collect();
            let (m, s) = mean_std(&v);
            (*t, m, s)
        })
        .collect()
}

/// Ramp time of ⟨|z1|⟩: first time it covers 1 − 1/e of the way from its initial value to
/// its mean over the last 10% of the run.
pub fn ramp_time(series: &[(f64, f64, f64)]) -> f64 {
    let n = series.len();
    if n < 10 {
        return f64::NAN;
    }
    let start = series[0].1;
    let tail = &series[n - n / 10..];
    let end = tail.iter().map(|x| x.1).sum::<f64>() / tail.len() as f64;
    let target = start + (1.0 - (-1.0f64).exp()) * (end - start);
    series
        .iter()
        .find(|x| {
            if end >= start {
                x.1 >= target
            } else {
                x.1 <= target
            }
        })
        .map(|x| x.0 - series[0].0)
        .unwrap_or(f64::NAN)
}

/// Fibres (indices) that started in `layer`.
fn in_layer(g: &GroupSeries, layer: u8) -> Vec<usize> {
    (0..g.layer.len())
        .filter(|&f| g.layer[f] == layer)
        .collect()
}

/// At most `max` of `items`, evenly spread (all of them if there are fewer).
fn spread<T: Copy>(items: &[T], max: usize) -> Vec<T> {
    if items.len() <= max {
        return items.to_vec();
    }
    (0..max).map(|i| items[i * items.len() / max]).collect()
}

/// Seed of the bootstrap of one statistic of one group: fixed, so intervals are
/// reproducible, and different per group and statistic.
fn seed(group: &str, what: u64) -> u64 {
    group.bytes().fold(0xcbf2_9ce4_8422_2325u64 ^ what, |h, b| {
        (h ^ b as u64).wrapping_mul(0x0100_0000_01b3)
    })
}

/// The three bootstrap intervals of a group (paper quantities: MSD slope over `window`,
/// |z1| ramp time per initial layer, final ⟨σ²⟩).
fn intervals(
    name: &str,
    g: &GroupSeries,
    table: &MsdTable,
    window: (f64, f64),
) -> (Interval, [Interval; 3], Interval) {
    let nf = g.layer.len().min(g.z1.first().map_or(0, |z| z.len()));
    let slope = bootstrap::interval(nf, bootstrap::REPLICATES, seed(name, 1), |w| {
        loglog_slope(&table.msd(Some(w), window.0, window.1), window.0, window.1)
    });
    let ramp = [0u8, 1, 2].map(|l| {
        let fibres = in_layer(g, l);
        let abs: Vec<Vec<f64>> =
            g.z1.iter()
                .map(|z| fibres.iter().map(|&f| z[f].abs()).collect())
                .collect();
        bootstrap::interval(
            fibres.len(),
            bootstrap::REPLICATES,
            seed(name, 2 + l as u64),
            |w| {
                let series: Vec<(f64, f64, f64)> = g
                    .t_plus
                    .iter()
                    .zip(&abs)
                    .map(|(t, a)| (*t, weighted_mean(a, w), 0.0))
                    .collect();
                ramp_time(&series)
            },
        )
    });
    let last = g.sigma2.last().map(|v| v.as_slice()).unwrap_or(&[]);
    let s2 = bootstrap::interval(last.len(), bootstrap::REPLICATES, seed(name, 9), |w| {
        weighted_mean(last, w)
    });
    (slope, ramp, s2)
}

/// Per-fibre CSV rows at most (a time stride keeps large runs' tables readable).
const MAX_FIBRE_ROWS: usize = 1_000_000;
/// Per-fibre lines in one plot at most (evenly spread over the fibres).
const MAX_PLOTTED_FIBRES: usize = 60;

/// What [`analyse`] found.
#[derive(Debug, Clone, Default)]
pub struct Analysis {
    pub summaries: Vec<GroupSummary>,
    /// Coiling-onset table (markdown), see [`crate::coiling`].
    pub coiling_table: String,
}

/// Writes CSVs and PNGs for every group (with coiling onsets for σ² `thresholds`);
/// returns the summaries.
pub fn analyse(
    mcap_path: &Path,
    out: &Path,
    thresholds: &[f64],
) -> Result<Analysis, AnalysisError> {
    std::fs::create_dir_all(out).map_err(io_err(out))?;
    let (groups, suspension_flocs) = read_recording(mcap_path)?;
    if groups.is_empty() {
        return Err(AnalysisError::Data(format!(
            "{}: no fibre states recorded",
            mcap_path.display()
        )));
    }
    let mut summaries = Vec::new();
    let mut ensemble = Ensemble::default();
    for (ci, (name, g)) in groups.iter().enumerate() {
        let table = MsdTable::new(g);
        let msd = table.msd(None, 0.0, f64::INFINITY);
        let t_end = g.t_plus.last().copied().unwrap_or(0.0) - g.t_plus[0];
        let window = (1.0_f64.min(t_end / 10.0), t_end / 2.0);
        let slope = loglog_slope(&msd, window.0, window.1);
        let (msd_slope_ci, ramp_by_layer_ci, final_sigma2_ci) = intervals(name, g, &table, window);
        let all = abs_z1(g, None);
        let s2: Vec<(f64, f64)> = g
            .t_plus
            .iter()
            .zip(&g.sigma2)
            .map(|(t, v)| (*t, mean_std(v).0))
            .collect();
        write_group_csvs(out, name, g, &msd)?;
        plot_group(out, name, g)?;
        ensemble.add(name, ci, slope, &msd, &all, &s2);
        summaries.push(GroupSummary {
            group: name.clone(),
            fibres: g.z1[0].len(),
            msd_slope: slope,
            fit_window: window,
            ramp_time: ramp_time(&all),
            ramp_by_layer: [0u8, 1, 2].map(|l| ramp_time(&abs_z1(g, Some(l)))),
            final_abs_z1: all.last().map(|x| x.1).unwrap_or(f64::NAN),
            final_sigma2: s2.last().map(|x| x.1).unwrap_or(f64::NAN),
            segment_length: g.segment_length,
            density_ratio: g.density_ratio,
            msd_slope_ci,
            ramp_by_layer_ci,
            final_sigma2_ci,
        });
    }
    ensemble.plot(out)?;
    let floc_rows: Vec<(String, Vec<crate::flocs::FlocRow>)> = groups
        .iter()
        .filter(|(_, g)| !g.flocs.is_empty())
        .map(|(n, g)| (n.clone(), g.flocs.clone()))
        .chain(suspension_flocs)
        .collect();
    for (name, rows) in &floc_rows {
        write(out, &format!("{name}_flocs.csv"), &crate::flocs::csv(rows))?;
        crate::flocs::plot(&out.join(format!("{name}_flocs.png")), name, rows)?;
    }
    if !floc_rows.is_empty() {
        write(out, "flocs.md", &crate::flocs::table(&floc_rows))?;
    }
    let (coiling_table, onsets_csv) = crate::coiling::report(&groups, thresholds);
    write(out, "coiling_onsets.csv", &onsets_csv)?;
    write(out, "coiling_onsets.md", &coiling_table)?;
    Ok(Analysis {
        summaries,
        coiling_table,
    })
}

/// One group's CSVs: MSD_23 over lag, <|z1|> per layer over time, and per-fibre rows
/// (decimated to at most `MAX_FIBRE_ROWS`).
fn write_group_csvs(
    out: &Path,
    name: &str,
    g: &GroupSeries,
    msd: &[(f64, f64)],
) -> Result<(), AnalysisError> {
    let mut csv = String::from("lag_t_plus,msd23_plus\n");
    for (t, m) in msd {
        let _ = writeln!(csv, "{t:.4},{m:.6e}");
    }
    write(out, &format!("{name}_msd23.csv"), &csv)?;
    let mut csv = String::from("t_plus,layer,mean_abs_z1,std_abs_z1\n");
    for (lname, l) in [
        ("all", None),
        ("near_wall", Some(0u8)),
        ("next", Some(1)),
        ("middle", Some(2)),
    ] {
        for (t, m, s) in abs_z1(g, l) {
            let _ = writeln!(csv, "{t:.4},{lname},{m:.6},{s:.6}");
        }
    }
    write(out, &format!("{name}_abs_z1.csv"), &csv)?;
    let mut csv = String::from("t_plus,fibre,layer,z1,sigma2,x1,x2,x3\n");
    let nf = g.z1.first().map_or(0, |z| z.len());
    let stride = (nf * g.t_plus.len()).div_ceil(MAX_FIBRE_ROWS).max(1);
    for (k, t) in g.t_plus.iter().enumerate().step_by(stride) {
        for f in 0..g.z1[k].len() {
            let c = g.com[k][f];
            let _ = writeln!(
                csv,
                "{t:.4},{f},{},{:.6},{:.6},{:.4},{:.4},{:.4}",
                g.layer.get(f).copied().unwrap_or(0),
                g.z1[k][f],
                g.sigma2[k][f],
                c[0],
                c[1],
                c[2]
            );
        }
    }
    write(out, &format!("{name}_fibres.csv"), &csv)?;
    Ok(())
}

/// One group's figures: <|z1|> per initial layer, signed z1 of near-wall fibres, and
/// centre-of-mass trajectories in the x3–x2 plane.
fn plot_group(out: &Path, name: &str, g: &GroupSeries) -> Result<(), AnalysisError> {
    let layers: Vec<Series> = [("near wall", 0u8), ("next", 1), ("middle", 2)]
        .iter()
        .flat_map(|(ln, l)| {
            let s = abs_z1(g, Some(*l));
            let c = *l as usize;
            vec![
                Series {
                    label: format!("<|z1|> {ln}"),
                    points: s.iter().map(|x| (x.0, x.1)).collect(),
                    colour: c,
                    markers: false,
                },
                Series {
                    label: String::new(),
                    points: s.iter().map(|x| (x.0, x.1 + x.2)).collect(),
                    colour: c,
                    markers: true,
                },
            ]
        })
        .collect();
    line_plot(
        &out.join(format!("{name}_abs_z1_layers.png")),
        &format!("{name}: alignment <|z1|> per initial layer (markers: +sigma)"),
        "t+",
        "|z1|",
        &layers,
        false,
        false,
    )?;
    let signed: Vec<Series> = spread(&in_layer(g, 0), MAX_PLOTTED_FIBRES)
        .into_iter()
        .map(|f| Series {
            label: String::new(),
            points: g
                .t_plus
                .iter()
                .zip(&g.z1)
                .map(|(t, z)| (*t, z[f]))
                .collect(),
            colour: f,
            markers: false,
        })
        .collect();
    if !signed.is_empty() {
        line_plot(
            &out.join(format!("{name}_signed_z1_near_wall.png")),
            &format!(
                "{name}: signed z1, {} of the {} fibres starting near the walls",
                signed.len(),
                in_layer(g, 0).len()
            ),
            "t+",
            "z1",
            &signed,
            false,
            false,
        )?;
    }
    let all_fibres: Vec<usize> = (0..g.com[0].len()).collect();
    let traj: Vec<Series> = spread(&all_fibres, MAX_PLOTTED_FIBRES)
        .into_iter()
        .map(|f| Series {
            label: String::new(),
            points: g.com.iter().map(|c| (c[f][2], c[f][1])).collect(),
            colour: f,
            markers: false,
        })
        .collect();
    line_plot(
        &out.join(format!("{name}_trajectories_x3x2.png")),
        &format!(
            "{name}: centre-of-mass trajectories in the x3-x2 plane ({} of {} fibres)",
            traj.len(),
            all_fibres.len()
        ),
        "x3+",
        "x2+",
        &traj,
        false,
        false,
    )?;
    Ok(())
}

/// The all-groups figures (MSD_23, <|z1|>, <σ²>), one curve per group.
#[derive(Default)]
struct Ensemble {
    msd: Vec<Series>,
    z1: Vec<Series>,
    s2: Vec<Series>,
}

impl Ensemble {
    fn add(
        &mut self,
        name: &str,
        colour: usize,
        slope: f64,
        msd: &[(f64, f64)],
        all: &[(f64, f64, f64)],
        s2: &[(f64, f64)],
    ) {
        let series = |label: String, points: Vec<(f64, f64)>| Series {
            label,
            points,
            colour,
            markers: false,
        };
        self.msd
            .push(series(format!("{name} (slope {slope:.3})"), msd.to_vec()));
        self.z1.push(series(
            name.to_string(),
            all.iter().map(|x| (x.0, x.1)).collect(),
        ));
        self.s2.push(series(name.to_string(), s2.to_vec()));
    }

    fn plot(&self, out: &Path) -> Result<(), AnalysisError> {
        let (msd_series, z1_series, s2_series) = (&self.msd, &self.z1, &self.s2);
        line_plot(
            &out.join("msd23.png"),
            "Ensemble MSD_23 (eq. 20)",
            "lag t+",
            "MSD_23+",
            msd_series,
            true,
            true,
        )?;
        line_plot(
            &out.join("abs_z1.png"),
            "Alignment <|z1|> (all fibres)",
            "t+",
            "|z1|",
            z1_series,
            false,
            false,
        )?;
        line_plot(
            &out.join("sigma2.png"),
            "Coiling <sigma^2>",
            "t+",
            "sigma^2",
            s2_series,
            false,
            false,
        )?;
        Ok(())
    }
}

fn write(dir: &Path, name: &str, text: &str) -> Result<(), AnalysisError> {
    let p = dir.join(name);
    std::fs::write(&p, text).map_err(io_err(&p))
}

fn ci(i: &Interval, decimals: usize) -> String {
    if i.lo.is_nan() {
        "[n/a]".into()
    } else {
        format!("[{:.*}, {:.*}]", decimals, i.lo, decimals, i.hi)
    }
}

/// The summary table (markdown) with the paper's values beside ours; brackets are 95%
/// bootstrap intervals over fibres.
pub fn summary_table(s: &[GroupSummary]) -> String {
    let mut md = String::from(
        "| case | l+ | rho_s/rho_f | fibres | MSD_23 slope [95% CI] (fit window t+) | paper slope | |z1| ramp time t+: all; near wall / next / middle [95% CI] | paper ramp | final <|z1|> | final <sigma^2> [95% CI] |\n|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for g in s {
        let paper = if g.group == "case1" { "1.926" } else { "~1.9" };
        let layers: Vec<String> = (0..3)
            .map(|l| {
                format!(
                    "{:.1} {}",
                    g.ramp_by_layer[l],
                    ci(&g.ramp_by_layer_ci[l], 1)
                )
            })
            .collect();
        let _ = writeln!(
            md,
            "| {} | {:.2} | {:.0} | {} | {:.3} {} ({:.1}–{:.1}) | {} | {:.1}; {} | ~13 | {:.3} | {:.4} {} |",
            g.group,
            g.segment_length,
            g.density_ratio,
            g.fibres,
            g.msd_slope,
            ci(&g.msd_slope_ci, 3),
            g.fit_window.0,
            g.fit_window.1,
            paper,
            g.ramp_time,
            layers.join(" / "),
            g.final_abs_z1,
            g.final_sigma2,
            ci(&g.final_sigma2_ci, 4)
        );
    }
    md
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Fibres moving ballistically in x2 and x3 (x = v t): MSD_23(τ) = (v2² + v3²) τ²
    /// exactly, at every lag, whether or not states are missing from the recording.
    #[test]
    fn msd_uses_true_lags_when_states_are_missing() {
        let v = [(0.3, -0.4), (1.0, 0.5)];
        let series = |steps: &[u64]| {
            let mut g = GroupSeries::default();
            for &k in steps {
                let t = k as f64 * 0.25;
                g.t_plus.push(t);
                g.com
                    .push(v.iter().map(|(a, b)| [7.0 * t, a * t, b * t]).collect());
            }
            g
        };
        let full: Vec<u64> = (0..=40).collect();
        let gappy: Vec<u64> = (0..=40)
            .filter(|k| (k % 3 != 1 || *k == 40) && *k != 17)
            .collect();
        let exact = |tau: f64| {
            v.iter()
                .map(|(a, b)| (a * a + b * b) * tau * tau)
                .sum::<f64>()
                / 2.0
        };
        for g in [series(&full), series(&gappy)] {
            let m = msd23(&g);
            assert_eq!(m.len(), 40, "every lag 0.25 .. 10 t+ is present");
            for (tau, msd) in m {
                assert!(
                    (msd - exact(tau)).abs() <= 1e-12 * exact(tau).max(1.0),
                    "tau {tau}: {msd} vs {}",
                    exact(tau)
                );
            }
        }
        assert!((loglog_slope(&msd23(&series(&gappy)), 0.25, 10.0) - 2.0).abs() < 1e-9);
    }

    /// Ballistic fibres with different speeds: every resample has MSD ∝ τ², so the slope's
    /// interval is 2 to round-off; diffusive-plus-ballistic mixtures give an interval that
    /// contains the full-sample slope.
    #[test]
    fn slope_interval_brackets_the_slope() {
        let mut g = GroupSeries::default();
        let speeds: Vec<(f64, f64)> = (0..40)
            .map(|i| ((i as f64 * 0.37).sin(), (i as f64 * 0.11).cos()))
            .collect();
        for k in 0..=80 {
            let t = k as f64 * 0.5;
            g.t_plus.push(t);
            g.com.push(
                speeds
                    .iter()
                    .enumerate()
                    // half the fibres move ballistically, half as √t (slope 1)
                    .map(|(i, (a, b))| {
                        let s = if i % 2 == 0 { t } else { (t * 4.0).sqrt() };
                        [0.0, a * s, b * s]
                    })
                    .collect(),
            );
            g.z1.push(vec![1.0; 40]);
            g.sigma2.push(vec![0.0; 40]);
        }
        g.layer = vec![0; 40];
        let table = MsdTable::new(&g);
        let window = (1.0, 20.0);
        let slope = loglog_slope(&table.msd(None, window.0, window.1), window.0, window.1);
        let (ci, _, s2) = intervals("t", &g, &table, window);
        assert!(ci.lo < slope && slope < ci.hi, "{slope} outside {ci:?}");
        assert!(ci.lo > 1.0 && ci.hi < 2.0, "{ci:?}");
        assert_eq!((s2.lo, s2.hi), (0.0, 0.0));
        let mut ballistic = g.clone();
        for (k, c) in ballistic.com.iter_mut().enumerate() {
            let t = k as f64 * 0.5;
            for (p, (a, b)) in c.iter_mut().zip(&speeds) {
                *p = [0.0, a * t, b * t];
            }
        }
        let t2 = MsdTable::new(&ballistic);
        let (ci, _, _) = intervals("t", &ballistic, &t2, window);
        assert!(
            (ci.lo - 2.0).abs() < 1e-9 && (ci.hi - 2.0).abs() < 1e-9,
            "{ci:?}"
        );
    }

    /// A decimated recording: states at steps 0 and 4, metrics at every step. The reader
    /// takes every step, states where they exist (recomputed, not the message's values)
    /// and the metrics message elsewhere.
    #[test]
    fn decimated_recording_reads_metrics_between_states() {
        use fiberflow_messages::{encode, SCHEMA_VERSION};
        let path = std::env::temp_dir().join(format!("ff-an-dec-{}.mcap", std::process::id()));
        let mut w = mcap::Writer::new(std::io::BufWriter::new(
            std::fs::File::create(&path).unwrap(),
        ))
        .unwrap();
        let empty = std::collections::BTreeMap::new();
        let sc = w
            .add_channel(0, "/fiberflow/r/fibers/g/state", "cdr", &empty)
            .unwrap();
        let mc = w
            .add_channel(0, "/fiberflow/r/fibers/g/metrics", "cdr", &empty)
            .unwrap();
        let state = |k: u64| FiberGroupState {
            schema_version: SCHEMA_VERSION,
            group: "g".into(),
            step: k,
            t_plus: k as f64,
            first_fiber: 0,
            group_fibers: 1,
            segments_per_fiber: vec![2],
            segment_length: vec![3.0],
            diameter: vec![0.2],
            density_ratio: vec![800.0],
            layer: vec![1],
            centre: vec![0.0, k as f64, 0.0, 3.0, k as f64, 0.0],
            axis: vec![1.0, 0.0, 0.0, 1.0, 0.0, 0.0],
            velocity: vec![0.0; 6],
            angular_velocity: vec![0.0; 6],
            hydro_force: vec![],
            contact_segment: vec![],
            contact_force: vec![],
            contacts: vec![],
        };
        let metrics = |k: u64| FiberGroupMetrics {
            schema_version: SCHEMA_VERSION,
            group: "g".into(),
            step: k,
            t_plus: k as f64,
            first_fiber: 0,
            group_fibers: 1,
            centre_of_mass: vec![1.5, k as f64, 0.0],
            // the message says 0.5: states must win where they exist
            z1: vec![0.5],
            sigma2: vec![0.25],
            end_to_end: vec![6.0],
            mean_abs_z1: 0.5,
            mean_sigma2: 0.25,
        };
        let mut seq = 0;
        let mut put = |ch: u16, k: u64, data: Vec<u8>| {
            seq += 1;
            let h = mcap::records::MessageHeader {
                channel_id: ch,
                sequence: seq,
                log_time: k * 1_000_000_000,
                publish_time: 0,
            };
            w.write_to_known_channel(&h, &data).unwrap();
        };
        for k in 0..=4u64 {
            if k % 4 == 0 {
                put(sc, k, encode(&state(k)));
            }
            put(mc, k, encode(&metrics(k)));
        }
        w.finish().unwrap();
        let groups = read_groups(&path).unwrap();
        let g = &groups["g"];
        assert_eq!(g.t_plus, vec![0.0, 1.0, 2.0, 3.0, 4.0]);
        let z1: Vec<f64> = g.z1.iter().map(|z| z[0]).collect();
        assert_eq!(z1, vec![1.0, 0.5, 0.5, 0.5, 1.0]);
        assert_eq!(g.com[2][0], [1.5, 2.0, 0.0]);
        assert_eq!(g.layer, vec![1]);
        std::fs::remove_file(&path).ok();
    }
}
