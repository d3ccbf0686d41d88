//! Bootstrap over fibres: the fibres of a case are resampled with replacement and a
//! statistic recomputed per replicate; the 2.5% and 97.5% percentiles of the replicates are
//! the 95% confidence interval. Replicate r draws from its own seeded generator, so the
//! interval is the same bits on any number of threads.

use rayon::prelude::*;

/// Replicates per interval.
pub const REPLICATES: usize = 1000;

/// A 95% percentile interval (NaN bounds when the statistic is undefined).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Interval {
    pub lo: f64,
    pub hi: f64,
}

impl Interval {
    pub const NAN: Interval = Interval {
        lo: f64::NAN,
        hi: f64::NAN,
    };

    pub fn half_width(&self) -> f64 {
        0.5 * (self.hi - self.lo)
    }
}

/// SplitMix64: small, fast and well mixed; enough for drawing indices.
struct SplitMix(u64);

impl SplitMix {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in 0..n (n > 0), by rejection: no modulo bias.
    fn below(&mut self, n: u64) -> u64 {
        let zone = u64::MAX - u64::MAX % n;
        loop {
            let x = self.next();
            if x < zone {
                return x % n;
            }
        }
    }
}

/// Multiplicities of `n` items in one resample of size `n` (they sum to `n`).
fn resample_counts(n: usize, rng: &mut SplitMix) -> Vec<u32> {
    let mut w = vec![0u32; n];
    for _ in 0..n {
        w[rng.below(n as u64) as usize] += 1;
    }
    w
}

/// Percentile interval of `stat` over `replicates` resamples of `n` items. `stat` gets the
/// multiplicity of each item; non-finite replicate values are left out (an interval needs
/// at least 90% of them finite, else NaN).
pub fn interval<F>(n: usize, replicates: usize, seed: u64, stat: F) -> Interval
where
    F: Fn(&[u32]) -> f64 + Sync,
{
    if n == 0 || replicates == 0 {
        return Interval::NAN;
    }
    let mut values: Vec<f64> = (0..replicates)
        .into_par_iter()
        .map(|r| {
            let mut rng = SplitMix(seed ^ (r as u64).wrapping_mul(0xD6E8_FEB8_6659_FD93));
            stat(&resample_counts(n, &mut rng))
        })
        .filter(|v| v.is_finite())
        .collect();
    if values.len() * 10 < replicates * 9 {
        return Interval::NAN;
    }
    values.sort_by(f64::total_cmp);
    Interval {
        lo: percentile(&values, 0.025),
        hi: percentile(&values, 0.975),
    }
}

/// Linear interpolation between order statistics of sorted `v`.
fn percentile(v: &[f64], p: f64) -> f64 {
    let x = p * (v.len() - 1) as f64;
    let i = x.floor() as usize;
    let j = (i + 1).min(v.len() - 1);
    v[i] + (x - i as f64) * (v[j] - v[i])
}

/// Weighted mean of `values` with multiplicities `w`.
pub fn weighted_mean(values: &[f64], w: &[u32]) -> f64 {
    let (s, n) = values.iter().zip(w).fold((0.0, 0u64), |(s, n), (v, &k)| {
        (s + v * k as f64, n + k as u64)
    });
    s / n as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The interval of a mean of n values with standard deviation s is about
    /// mean ± 1.96 s/√n: within 10% for n = 2000, and it narrows as 1/√n.
    #[test]
    fn interval_of_a_mean_matches_the_normal_theory() {
        let mut rng = SplitMix(5);
        let n = 2000;
        // uniform on [0, 1): s = 1/√12
        let v: Vec<f64> = (0..n)
            .map(|_| (rng.next() >> 11) as f64 / (1u64 << 53) as f64)
            .collect();
        let m = v.iter().sum::<f64>() / n as f64;
        let ci = interval(n, REPLICATES, 1, |w| weighted_mean(&v, w));
        let expect = 1.96 / 12f64.sqrt() / (n as f64).sqrt();
        assert!(ci.lo < m && m < ci.hi, "{ci:?} around {m}");
        assert!(
            (ci.half_width() / expect - 1.0).abs() < 0.1,
            "half width {} vs {expect}",
            ci.half_width()
        );
        let quarter = interval(n / 4, REPLICATES, 1, |w| weighted_mean(&v[..n / 4], w));
        let ratio = quarter.half_width() / ci.half_width();
        assert!((ratio - 2.0).abs() < 0.25, "n/4 widens by {ratio}, not 2");
    }

    /// Same seed, same interval; a statistic that does not depend on the resample has a
    /// zero-width interval at its value.
    #[test]
    fn interval_is_deterministic_and_exact_for_constants() {
        let v: Vec<f64> = (0..50).map(|i| (i as f64).sin()).collect();
        let a = interval(50, 300, 9, |w| weighted_mean(&v, w));
        let b = interval(50, 300, 9, |w| weighted_mean(&v, w));
        assert_eq!(a, b);
        let c = interval(50, 300, 9, |_| 2.0);
        assert_eq!((c.lo, c.hi), (2.0, 2.0));
        assert!(interval(50, 300, 9, |_| f64::NAN).lo.is_nan());
    }
}
