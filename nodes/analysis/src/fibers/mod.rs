//! Fibre analysis of a recording (paper §4, figs. 6–10): MSD_23 (eq. 20) with its log-log
//! slope, ⟨|z1|⟩ ± σ per initial layer, signed z1 per fibre, ⟨σ²⟩(t), trajectories in the
//! x3–x2 plane; 95% bootstrap intervals over fibres for the MSD slope, the ramp time per
//! layer and the final ⟨σ²⟩. Metrics are recomputed from the recorded states; steps without
//! a state (a decimated recording) take the fibre node's metrics message.
//!
//! Reading a recording is [`read`], the statistics [`stats`]; this file turns them into
//! the CSV, PNG and summary of a run. Coiling onsets, plots and the bootstrap itself are
//! in their own files.

use crate::bootstrap::Interval;
use crate::plot::{line_plot, Series};
use crate::{io_err, AnalysisError};
use std::fmt::Write as _;
use std::path::Path;

pub use crate::series::GroupSeries;

mod read;
mod stats;

pub use read::{fiber_of_state, read_groups, read_recording, SuspensionFlocs};
pub use stats::{abs_z1, loglog_slope, msd23, ramp_time, MsdTable};
use stats::{in_layer, intervals, mean_std, spread};

/// Numbers for the summary table.
#[derive(Debug, Clone, Default)]
pub struct GroupSummary {
    pub group: String,
    pub fibers: usize,
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

/// Per-fibre CSV rows at most (a time stride keeps large runs' tables readable).
const MAX_FIBER_ROWS: usize = 1_000_000;
/// Per-fibre lines in one plot at most (evenly spread over the fibres).
const MAX_PLOTTED_FIBERS: usize = 60;

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
        return Err(AnalysisError::NoFiberStates(
            mcap_path.display().to_string(),
        ));
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
            fibers: g.z1[0].len(),
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
/// (decimated to at most `MAX_FIBER_ROWS`).
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
    let mut csv = String::from("t_plus,fiber,layer,z1,sigma2,x1,x2,x3\n");
    let nf = g.z1.first().map_or(0, |z| z.len());
    let stride = (nf * g.t_plus.len()).div_ceil(MAX_FIBER_ROWS).max(1);
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
    write(out, &format!("{name}_fibers.csv"), &csv)?;
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
    let signed: Vec<Series> = spread(&in_layer(g, 0), MAX_PLOTTED_FIBERS)
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
    let all_fibers: Vec<usize> = (0..g.com[0].len()).collect();
    let traj: Vec<Series> = spread(&all_fibers, MAX_PLOTTED_FIBERS)
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
            all_fibers.len()
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
            g.fibers,
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
    use fiberflow_messages::{FiberGroupMetrics, FiberGroupState};

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
