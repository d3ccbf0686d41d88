//! Fibre analysis of a recording (paper §4, figs. 6–10): MSD_23 (eq. 20) with its log-log
//! slope, ⟨|z1|⟩ ± σ per initial layer, signed z1 per fibre, ⟨σ²⟩(t), trajectories in the
//! x3–x2 plane. Metrics are recomputed from the recorded states (not trusted from the
//! metrics topic), so any recording of states can be analysed.

use crate::plot::{line_plot, Series};
use crate::{io_err, AnalysisError};
use fiberflow_messages::{decode, FiberGroupState};
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

/// Per-step, per-fibre metrics of one group.
#[derive(Debug, Clone, Default)]
pub struct GroupSeries {
    pub t_plus: Vec<f64>,
    /// [step][fibre] centre of mass.
    pub com: Vec<Vec<[f64; 3]>>,
    pub z1: Vec<Vec<f64>>,
    pub sigma2: Vec<Vec<f64>>,
    pub layer: Vec<u8>,
    pub density_ratio: f64,
    pub segment_length: f64,
}

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
}

/// Reads every FiberGroupState of a recording, grouped and ordered by step.
/// `mcap_path` is a run folder (all its segments, in order) or one `.mcap` file; states
/// that fail their consistency checks are skipped.
pub fn read_groups(mcap_path: &Path) -> Result<BTreeMap<String, GroupSeries>, AnalysisError> {
    use fiberflow_messages::sanity::Sane;
    let segs = fiberflow_messages::segments::segment_paths(mcap_path).map_err(io_err(mcap_path))?;
    let mut by: BTreeMap<String, BTreeMap<u64, FiberGroupState>> = BTreeMap::new();
    for seg in &segs {
        let bytes = std::fs::read(seg).map_err(io_err(seg))?;
        let stream =
            mcap::MessageStream::new(&bytes).map_err(|e| AnalysisError::Data(e.to_string()))?;
        for m in stream {
            let Ok(m) = m else { break }; // a damaged tail: analyse what is there
            if !m.channel.topic.ends_with("/state") {
                continue;
            }
            if let Ok(s) = decode::<FiberGroupState>(&m.data) {
                if s.check().is_ok() {
                    by.entry(s.group.clone()).or_default().insert(s.step, s);
                }
            }
        }
    }
    let mut out = BTreeMap::new();
    for (g, steps) in by {
        let mut gs = GroupSeries::default();
        let mut shape: Option<Vec<u32>> = None;
        for (_, s) in steps {
            // every state of a group must describe the same fibres
            if shape.get_or_insert_with(|| s.segments_per_fiber.clone()) != &s.segments_per_fiber {
                continue;
            }
            let mut com = Vec::new();
            let mut z1 = Vec::new();
            let mut s2 = Vec::new();
            let mut seg = 0usize;
            for &n in &s.segments_per_fiber {
                let n = n as usize;
                let mut c = [0.0; 3];
                let mut zs = [0.0; 3];
                for i in seg..seg + n {
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
                for i in seg..seg + n {
                    for a in 0..3 {
                        var += (s.axis[3 * i + a] - zh[a]).powi(2);
                    }
                }
                com.push(c);
                z1.push(zh[0]);
                s2.push(if n > 1 { var / (n - 1) as f64 } else { 0.0 });
                seg += n;
            }
            gs.t_plus.push(s.t_plus);
            gs.com.push(com);
            gs.z1.push(z1);
            gs.sigma2.push(s2);
            gs.layer = s.layer.clone();
            gs.density_ratio = s.density_ratio.first().copied().unwrap_or(0.0);
            gs.segment_length = s.segment_length.first().copied().unwrap_or(0.0);
        }
        out.insert(g, gs);
    }
    Ok(out)
}

/// MSD_23(τ) (eq. 20): mean over fibres and time origins of the cross-stream (x2, x3)
/// squared displacement of the centre of mass, for every lag. Lags are the true time
/// differences between states, in multiples of the smallest spacing: a recording with
/// gaps (decimated or lost states) gives each pair its real lag.
pub fn msd23(g: &GroupSeries) -> Vec<(f64, f64)> {
    let n = g.t_plus.len().min(g.com.len());
    if n < 2 {
        return Vec::new();
    }
    let dt = g
        .t_plus
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|d| *d > 0.0)
        .fold(f64::INFINITY, f64::min);
    if !dt.is_finite() {
        return Vec::new();
    }
    let span = ((g.t_plus[n - 1] - g.t_plus[0]) / dt).round() as usize;
    let mut sum = vec![0.0; span + 1];
    let mut count = vec![0usize; span + 1];
    for k in 0..n {
        for k2 in k + 1..n {
            let bin = ((g.t_plus[k2] - g.t_plus[k]) / dt).round() as usize;
            let Some(s) = sum.get_mut(bin) else { continue };
            for (a, b) in g.com[k].iter().zip(&g.com[k2]) {
                *s += (b[1] - a[1]).powi(2) + (b[2] - a[2]).powi(2);
                count[bin] += 1;
            }
        }
    }
    (1..=span)
        .filter(|&b| count[b] > 0)
        .map(|b| (b as f64 * dt, sum[b] / count[b] as f64))
        .collect()
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

/// Writes CSVs and PNGs for every group; returns the summaries.
pub fn analyse(mcap_path: &Path, out: &Path) -> Result<Vec<GroupSummary>, AnalysisError> {
    std::fs::create_dir_all(out).map_err(io_err(out))?;
    let groups = read_groups(mcap_path)?;
    if groups.is_empty() {
        return Err(AnalysisError::Data(format!(
            "{}: no fibre states recorded",
            mcap_path.display()
        )));
    }
    let mut summaries = Vec::new();
    let mut msd_series = Vec::new();
    let mut z1_series = Vec::new();
    let mut s2_series = Vec::new();
    for (ci, (name, g)) in groups.iter().enumerate() {
        let msd = msd23(g);
        let t_end = g.t_plus.last().copied().unwrap_or(0.0) - g.t_plus[0];
        let window = (1.0_f64.min(t_end / 10.0), t_end / 2.0);
        let slope = loglog_slope(&msd, window.0, window.1);
        let all = abs_z1(g, None);
        let s2: Vec<(f64, f64)> = g
            .t_plus
            .iter()
            .zip(&g.sigma2)
            .map(|(t, v)| (*t, mean_std(v).0))
            .collect();
        // CSVs
        let mut csv = String::from("lag_t_plus,msd23_plus\n");
        for (t, m) in &msd {
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
        for (k, t) in g.t_plus.iter().enumerate() {
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
        // per-case figures
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
        let signed: Vec<Series> = (0..g.z1[0].len())
            .filter(|f| g.layer.get(*f) == Some(&0))
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
                &format!("{name}: signed z1, fibres starting near the walls"),
                "t+",
                "z1",
                &signed,
                false,
                false,
            )?;
        }
        let traj: Vec<Series> = (0..g.com[0].len())
            .map(|f| Series {
                label: String::new(),
                points: g.com.iter().map(|c| (c[f][2], c[f][1])).collect(),
                colour: f,
                markers: false,
            })
            .collect();
        line_plot(
            &out.join(format!("{name}_trajectories_x3x2.png")),
            &format!("{name}: centre-of-mass trajectories in the x3-x2 plane"),
            "x3+",
            "x2+",
            &traj,
            false,
            false,
        )?;
        msd_series.push(Series {
            label: format!("{name} (slope {slope:.3})"),
            points: msd.clone(),
            colour: ci,
            markers: false,
        });
        z1_series.push(Series {
            label: name.clone(),
            points: all.iter().map(|x| (x.0, x.1)).collect(),
            colour: ci,
            markers: false,
        });
        s2_series.push(Series {
            label: name.clone(),
            points: s2.clone(),
            colour: ci,
            markers: false,
        });
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
        });
    }
    line_plot(
        &out.join("msd23.png"),
        "Ensemble MSD_23 (eq. 20)",
        "lag t+",
        "MSD_23+",
        &msd_series,
        true,
        true,
    )?;
    line_plot(
        &out.join("abs_z1.png"),
        "Alignment <|z1|> (all fibres)",
        "t+",
        "|z1|",
        &z1_series,
        false,
        false,
    )?;
    line_plot(
        &out.join("sigma2.png"),
        "Coiling <sigma^2>",
        "t+",
        "sigma^2",
        &s2_series,
        false,
        false,
    )?;
    Ok(summaries)
}

fn write(dir: &Path, name: &str, text: &str) -> Result<(), AnalysisError> {
    let p = dir.join(name);
    std::fs::write(&p, text).map_err(io_err(&p))
}

/// The summary table (markdown) with the paper's values beside ours.
pub fn summary_table(s: &[GroupSummary]) -> String {
    let mut md = String::from(
        "| case | l+ | rho_s/rho_f | fibres | MSD_23 slope (fit window t+) | paper slope | |z1| ramp time t+: all (near wall / next / middle) | paper ramp | final <|z1|> | final <sigma^2> |\n|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for g in s {
        let paper = if g.group == "case1" { "1.926" } else { "~1.9" };
        let _ = writeln!(
            md,
            "| {} | {:.2} | {:.0} | {} | {:.3} ({:.1}–{:.1}) | {} | {:.1} ({:.1} / {:.1} / {:.1}) | ~13 | {:.3} | {:.4} |",
            g.group,
            g.segment_length,
            g.density_ratio,
            g.fibres,
            g.msd_slope,
            g.fit_window.0,
            g.fit_window.1,
            paper,
            g.ramp_time,
            g.ramp_by_layer[0],
            g.ramp_by_layer[1],
            g.ramp_by_layer[2],
            g.final_abs_z1,
            g.final_sigma2
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
}
