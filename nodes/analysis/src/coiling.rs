//! Coiling events: per fibre, the first t+ at which its coiling measure σ² (paper §4.3,
//! σ² = Σ|ẑ_i − ẑ|²/(N−1): 0 straight, growing as the fibre coils) reaches each of a set of
//! thresholds — the paper's "increasingly complex geometrical conformations", made
//! measurable — and per case (and initial layer) the share of fibres that got there and the
//! median and quartiles of their onset times.

use crate::series::GroupSeries;
use std::collections::BTreeMap;
use std::fmt::Write as _;

/// Default σ² thresholds: slightly bent, clearly bent, coiled (a straight fibre has 0; a
/// 7-segment fibre whose segments point every which way has ≈ 7/6).
pub const DEFAULT_THRESHOLDS: [f64; 3] = [0.1, 0.5, 1.0];

/// First time `s2` reaches `threshold`, linearly interpolated between the two samples that
/// bracket the crossing; `None` if it never does. A series that starts at or above the
/// threshold has its onset at the first time.
pub fn first_crossing(t_plus: &[f64], s2: &[f64], threshold: f64) -> Option<f64> {
    let n = t_plus.len().min(s2.len());
    if n == 0 {
        return None;
    }
    if s2[0] >= threshold {
        return Some(t_plus[0]);
    }
    (1..n).find(|&k| s2[k] >= threshold).map(|k| {
        let (a, b) = (s2[k - 1], s2[k]);
        let f = (threshold - a) / (b - a);
        t_plus[k - 1] + f * (t_plus[k] - t_plus[k - 1])
    })
}

/// Onset times of every fibre of a group, per threshold: `[threshold][fiber]`.
pub fn onsets(g: &GroupSeries, thresholds: &[f64]) -> Vec<Vec<Option<f64>>> {
    let nf = g.sigma2.first().map_or(0, |v| v.len());
    let series: Vec<Vec<f64>> = (0..nf)
        .map(|f| g.sigma2.iter().map(|s| s[f]).collect())
        .collect();
    thresholds
        .iter()
        .map(|&thr| {
            series
                .iter()
                .map(|s| first_crossing(&g.t_plus, s, thr))
                .collect()
        })
        .collect()
}

/// Share, median and quartiles of a set of onsets (fibres that never reach are counted in
/// the share only).
#[derive(Debug, Clone, PartialEq)]
pub struct OnsetStats {
    pub fibers: usize,
    pub reached: usize,
    pub median: f64,
    pub q25: f64,
    pub q75: f64,
}

/// Quantile by linear interpolation between order statistics of sorted `v`.
fn quantile(v: &[f64], p: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let x = p * (v.len() - 1) as f64;
    let i = x.floor() as usize;
    let j = (i + 1).min(v.len() - 1);
    v[i] + (x - i as f64) * (v[j] - v[i])
}

pub fn stats(onsets: &[Option<f64>]) -> OnsetStats {
    let mut v: Vec<f64> = onsets.iter().flatten().copied().collect();
    v.sort_by(f64::total_cmp);
    OnsetStats {
        fibers: onsets.len(),
        reached: v.len(),
        median: quantile(&v, 0.5),
        q25: quantile(&v, 0.25),
        q75: quantile(&v, 0.75),
    }
}

const LAYERS: [(&str, Option<u8>); 4] = [
    ("all", None),
    ("near wall", Some(0)),
    ("next", Some(1)),
    ("middle", Some(2)),
];

fn cell(s: &OnsetStats) -> String {
    let share = 100.0 * s.reached as f64 / s.fibers.max(1) as f64;
    if s.reached == 0 {
        "0% | –".to_string()
    } else {
        format!("{share:.0}% | {:.1} ({:.1}–{:.1})", s.median, s.q25, s.q75)
    }
}

/// The per-case table (markdown) and the per-fibre CSV rows
/// (`group,fiber,layer,threshold,onset_t_plus`, empty onset = never).
pub fn report(groups: &BTreeMap<String, GroupSeries>, thresholds: &[f64]) -> (String, String) {
    let mut md = String::from(
        "| case | sigma^2 threshold | layer | fibres reaching it | median onset t+ (quartiles) |\n|---|---|---|---|---|\n",
    );
    let mut csv = String::from("group,fiber,layer,threshold,onset_t_plus\n");
    for (name, g) in groups {
        let on = onsets(g, thresholds);
        for (ti, thr) in thresholds.iter().enumerate() {
            for (lname, layer) in LAYERS {
                let sel: Vec<Option<f64>> = on[ti]
                    .iter()
                    .enumerate()
                    .filter(|(f, _)| layer.is_none_or(|l| g.layer.get(*f) == Some(&l)))
                    .map(|(_, o)| *o)
                    .collect();
                if sel.is_empty() {
                    continue;
                }
                let _ = writeln!(md, "| {name} | {thr} | {lname} | {} |", cell(&stats(&sel)));
            }
            for (f, o) in on[ti].iter().enumerate() {
                let _ = writeln!(
                    csv,
                    "{name},{f},{},{thr},{}",
                    g.layer.get(f).copied().unwrap_or(0),
                    o.map(|t| format!("{t:.3}")).unwrap_or_default()
                );
            }
        }
    }
    (md, csv)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A linear ramp σ² = 0.02 t crosses 0.1 at t = 5 and 0.5 at t = 25 exactly (between
    /// samples, by interpolation); a series that never reaches 1.0 has no onset; one that
    /// starts above the threshold has its onset at the start; a fluctuating series counts its
    /// first crossing, not a later one.
    #[test]
    fn onsets_of_synthetic_series() {
        let t: Vec<f64> = (0..=40).map(|k| k as f64 * 0.75).collect();
        let ramp: Vec<f64> = t.iter().map(|t| 0.02 * t).collect();
        assert!((first_crossing(&t, &ramp, 0.1).unwrap() - 5.0).abs() < 1e-12);
        assert!((first_crossing(&t, &ramp, 0.5).unwrap() - 25.0).abs() < 1e-12);
        assert_eq!(first_crossing(&t, &ramp, 1.0), None);
        let high = vec![0.7; t.len()];
        assert_eq!(first_crossing(&t, &high, 0.5), Some(0.0));
        // up through 0.5 at t = 3.0 (samples 0.4 at 2.25 and 0.6 at 3.0: crossing at
        // 2.625), down, up again later
        let mut wiggle = vec![0.0; t.len()];
        wiggle[3] = 0.4;
        wiggle[4] = 0.6;
        wiggle[5] = 0.2;
        wiggle[20] = 0.9;
        assert!((first_crossing(&t, &wiggle, 0.5).unwrap() - 2.625).abs() < 1e-12);
    }

    /// Share and quartiles: 4 of 5 fibres reach, onsets 1, 2, 3, 4 → median 2.5,
    /// quartiles 1.75 and 3.25; the table and the CSV list them by group, layer, threshold.
    #[test]
    fn stats_and_report() {
        let s = stats(&[Some(3.0), None, Some(1.0), Some(4.0), Some(2.0)]);
        assert_eq!((s.fibers, s.reached), (5, 4));
        assert_eq!((s.median, s.q25, s.q75), (2.5, 1.75, 3.25));
        let mut g = GroupSeries::default();
        for k in 0..=10 {
            let t = k as f64;
            g.t_plus.push(t);
            // fibre 0 (near wall) bends fast, fibre 1 (middle) slowly, fibre 2 never
            g.sigma2.push(vec![0.1 * t, 0.02 * t, 0.0]);
            g.z1.push(vec![1.0; 3]);
            g.com.push(vec![[0.0; 3]; 3]);
        }
        g.layer = vec![0, 2, 2];
        let groups: BTreeMap<String, GroupSeries> = [("c1".to_string(), g)].into();
        let (md, csv) = report(&groups, &[0.1]);
        assert!(
            md.contains("| c1 | 0.1 | all | 67% | 3.0 (2.0–4.0) |"),
            "{md}"
        );
        assert!(
            md.contains("| c1 | 0.1 | near wall | 100% | 1.0 (1.0–1.0) |"),
            "{md}"
        );
        assert!(
            md.contains("| c1 | 0.1 | middle | 50% | 5.0 (5.0–5.0) |"),
            "{md}"
        );
        assert!(
            !md.contains("| next |"),
            "no fibre started in the next layer: {md}"
        );
        assert!(
            csv.contains("c1,0,0,0.1,1.000") && csv.contains("c1,2,2,0.1,\n"),
            "{csv}"
        );
    }
}
