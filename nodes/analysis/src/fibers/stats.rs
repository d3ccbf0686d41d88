//! The fibre statistics of the paper's §4: MSD_23 and its log-log slope, ⟨|z1|⟩ and its
//! ramp time per layer, and their bootstrap intervals over fibres.

use super::GroupSeries;
use crate::bootstrap::{self, weighted_mean, Interval};

/// Per-fibre sums of squared cross-stream displacements (eq. 20) per lag bin: the MSD and
/// its bootstrap both come from it.
#[derive(Debug, Clone, Default)]
pub struct MsdTable {
    /// Lag of bin b is b·dt.
    pub dt: f64,
    /// [fibre][bin] sum over time-origin pairs of |Δx2|² + |Δx3|².
    pub per_fiber: Vec<Vec<f64>>,
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
        let per_fiber = (0..nf)
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
            per_fiber,
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
        let mut fibers = 0u64;
        for (f, s) in self.per_fiber.iter().enumerate() {
            let k = w.map_or(1, |w| w[f]);
            if k == 0 {
                continue;
            }
            fibers += k as u64;
            for (acc, &b) in sum.iter_mut().zip(&bins) {
                *acc += k as f64 * s[b];
            }
        }
        bins.iter()
            .zip(sum)
            .map(|(&b, s)| {
                (
                    b as f64 * self.dt,
                    s / (self.pairs[b] as u64 * fibers) as f64,
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

pub(crate) fn mean_std(v: &[f64]) -> (f64, f64) {
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
pub(crate) fn in_layer(g: &GroupSeries, layer: u8) -> Vec<usize> {
    (0..g.layer.len())
        .filter(|&f| g.layer[f] == layer)
        .collect()
}

/// At most `max` of `items`, evenly spread (all of them if there are fewer).
pub(crate) fn spread<T: Copy>(items: &[T], max: usize) -> Vec<T> {
    if items.len() <= max {
        return items.to_vec();
    }
    (0..max).map(|i| items[i * items.len() / max]).collect()
}

/// Seed of the bootstrap of one statistic of one group: fixed, so intervals are
/// reproducible, and different per group and statistic.
pub(crate) fn seed(group: &str, what: u64) -> u64 {
    group.bytes().fold(0xcbf2_9ce4_8422_2325u64 ^ what, |h, b| {
        (h ^ b as u64).wrapping_mul(0x0100_0000_01b3)
    })
}

/// The three bootstrap intervals of a group (paper quantities: MSD slope over `window`,
/// |z1| ramp time per initial layer, final ⟨σ²⟩).
pub(crate) fn intervals(
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
        let fibers = in_layer(g, l);
        let abs: Vec<Vec<f64>> =
            g.z1.iter()
                .map(|z| fibers.iter().map(|&f| z[f].abs()).collect())
                .collect();
        bootstrap::interval(
            fibers.len(),
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
