//! Statistics over realisations (docs/realisations.md): independent runs of the same flow,
//! each cut into the same number of batches after its transient.
//!
//! The estimate is the mean of all R × B batch means. Its interval counts the spread
//! between realisations as follows: a one-way analysis of variance compares the scatter of
//! the realisations' means with what their batches allow, F = MS_between / MS_within. When
//! F is below its 95% quantile F₀.₉₅(R − 1, R(B − 1)), the realisations differ no more than
//! batches of one run do, and the interval is Student's t over all R·B batch means about
//! the pooled mean (R·B − 1 degrees of freedom; realisation-to-realisation differences are
//! in that scatter). When F is above it, the realisations' means differ more than their
//! batches say (batches too short, or a drift a run's window has not left), and the interval is
//! Student's t over the R realisation means alone (R − 1 degrees of freedom), the wider and
//! honest one. One realisation is the batch-means interval of one run.

use crate::modulation::{profile_batches, scalar_batches, Estimate, FlowSeries};
use crate::AnalysisError;

/// A pooled estimate and whether it is the realisations' interval (their means scattered
/// beyond their batches).
pub type Pooled = (Estimate, bool);

/// Profile batches (`[batch][quantity][row]`) and the rows' y+.
pub type ProfileBatches = (Vec<f64>, Vec<[Vec<f64>; 6]>);

/// The pooled estimate of equally long realisations' batch means (`batches[r][b]`), and
/// whether their means scattered beyond their batches (then the interval is the
/// realisations').
pub fn pooled(batches: &[Vec<f64>]) -> Option<Pooled> {
    let r = batches.len();
    let b = batches.first()?.len();
    if r == 0 || b < 2 || batches.iter().any(|v| v.len() != b) {
        return None;
    }
    let all: Vec<f64> = batches.iter().flatten().copied().collect();
    let pooled = Estimate::of_batches(&all);
    if r == 1 {
        return Some((pooled, false));
    }
    let means: Vec<f64> = batches
        .iter()
        .map(|v| v.iter().sum::<f64>() / b as f64)
        .collect();
    let grand = pooled.mean;
    let between =
        b as f64 * means.iter().map(|m| (m - grand).powi(2)).sum::<f64>() / (r - 1) as f64;
    let within = batches
        .iter()
        .zip(&means)
        .map(|(v, m)| v.iter().map(|x| (x - m).powi(2)).sum::<f64>())
        .sum::<f64>()
        / (r * (b - 1)) as f64;
    let f = if within > 0.0 {
        between / within
    } else if between > 0.0 {
        f64::INFINITY
    } else {
        0.0
    };
    if f <= f_quantile_95(r - 1, r * (b - 1)) {
        return Some((pooled, false));
    }
    let by_realisation = Estimate::of_batches(&means);
    Some((
        Estimate {
            mean: grand,
            half_width: by_realisation.half_width,
            batches: r * b,
        },
        true,
    ))
}

/// Each scalar of [`crate::modulation::scalars`] pooled over `runs`: name, estimate, and
/// whether the realisations scattered beyond their batches.
pub fn pooled_scalars(
    runs: &[FlowSeries],
    from: f64,
    batches: usize,
) -> Vec<(&'static str, Option<Pooled>)> {
    let per_run: Vec<_> = runs
        .iter()
        .map(|f| scalar_batches(f, from, batches))
        .collect();
    let Some(first) = per_run.first() else {
        return Vec::new();
    };
    first
        .iter()
        .enumerate()
        .map(|(q, (name, _))| {
            let sets: Option<Vec<Vec<f64>>> = per_run.iter().map(|r| r[q].1.clone()).collect();
            (*name, sets.and_then(|s| pooled(&s)))
        })
        .collect()
}

/// Every run's profile batches after `from`, put together (`[batch][quantity][row]`), and
/// the rows' y+; runs on other rows are an error.
pub fn pooled_profile_batches(
    runs: &[FlowSeries],
    from: f64,
) -> Result<ProfileBatches, AnalysisError> {
    let mut y0: Option<Vec<f64>> = None;
    let mut all = Vec::new();
    for (i, f) in runs.iter().enumerate() {
        let (y, b) = profile_batches(f, from);
        if b.is_empty() {
            continue;
        }
        match &y0 {
            None => y0 = Some(y),
            Some(y0) => {
                let same = y0.len() == y.len()
                    && y0
                        .iter()
                        .zip(&y)
                        .all(|(a, b)| (a - b).abs() <= 1e-9 * a.abs().max(1.0));
                if !same {
                    return Err(AnalysisError::Data(format!(
                        "realisation {} has other profile rows than the first ({} against {}): \
                         realisations must share the grid",
                        i + 1,
                        y.len(),
                        y0.len()
                    )));
                }
            }
        }
        all.extend(b);
    }
    Ok((y0.unwrap_or_default(), all))
}

/// ln Γ(x) for x > 0 (Lanczos, g = 7, nine terms: ≈ 1e-15 relative).
fn ln_gamma(x: f64) -> f64 {
    const C: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    if x < 0.5 {
        let pi = std::f64::consts::PI;
        return (pi / (pi * x).sin()).ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let mut a = C[0];
    let t = x + 7.5;
    for (i, c) in C.iter().enumerate().skip(1) {
        a += c / (x + i as f64);
    }
    0.5 * (2.0 * std::f64::consts::PI).ln() + (x + 0.5) * t.ln() - t + a.ln()
}

/// The regularised incomplete beta function I_x(a, b) (continued fraction, Lentz).
fn incomplete_beta(x: f64, a: f64, b: f64) -> f64 {
    if x <= 0.0 {
        return 0.0;
    }
    if x >= 1.0 {
        return 1.0;
    }
    let front =
        (ln_gamma(a + b) - ln_gamma(a) - ln_gamma(b) + a * x.ln() + b * (1.0 - x).ln()).exp();
    // the fraction converges fast for x < (a + 1)/(a + b + 2); use the symmetry otherwise
    if x > (a + 1.0) / (a + b + 2.0) {
        return 1.0 - incomplete_beta(1.0 - x, b, a);
    }
    let tiny = 1e-300;
    let mut c = 1.0;
    let mut d = 1.0 - (a + b) * x / (a + 1.0);
    if d.abs() < tiny {
        d = tiny;
    }
    d = 1.0 / d;
    let mut h = d;
    for m in 1..300 {
        let m = m as f64;
        let even = m * (b - m) * x / ((a + 2.0 * m - 1.0) * (a + 2.0 * m));
        for num in [
            even,
            -(a + m) * (a + b + m) * x / ((a + 2.0 * m) * (a + 2.0 * m + 1.0)),
        ] {
            d = 1.0 + num * d;
            if d.abs() < tiny {
                d = tiny;
            }
            c = 1.0 + num / c;
            if c.abs() < tiny {
                c = tiny;
            }
            d = 1.0 / d;
            h *= d * c;
        }
        if (d * c - 1.0).abs() < 1e-15 {
            break;
        }
    }
    front * h / a
}

/// The 95% quantile of Fisher's F with (d1, d2) degrees of freedom (bisection on its
/// distribution function).
pub fn f_quantile_95(d1: usize, d2: usize) -> f64 {
    let (a, b) = (0.5 * d1 as f64, 0.5 * d2 as f64);
    let cdf = |f: f64| incomplete_beta(d1 as f64 * f / (d1 as f64 * f + d2 as f64), a, b);
    let (mut lo, mut hi) = (0.0, 1.0);
    while cdf(hi) < 0.95 {
        hi *= 2.0;
        if hi > 1e12 {
            return f64::INFINITY;
        }
    }
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if cdf(mid) < 0.95 {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// F quantiles against the published table (95%): F(1, 18) = 4.41, F(2, 27) = 3.35,
    /// F(3, 36) = 2.87, F(4, 10) = 3.48, F(1, 1) = 161.4 (to the table's three digits).
    #[test]
    fn f_quantiles_match_the_table() {
        for (d1, d2, want) in [
            (1, 18, 4.414),
            (2, 27, 3.354),
            (3, 36, 2.866),
            (4, 10, 3.478),
            (1, 1, 161.45),
        ] {
            let q = f_quantile_95(d1, d2);
            assert!(
                (q - want).abs() < 2e-3 * want,
                "F({d1}, {d2}) = {q}, table {want}"
            );
        }
    }

    /// Three realisations of four batches whose means agree with their batches' scatter:
    /// the pooled mean and Student's t over all twelve batch means, by hand. Batches
    /// 1.0 1.2 0.8 1.0 | 1.1 0.9 1.0 1.0 | 0.9 1.1 1.2 0.8: mean 1.0, Σ(x − 1)² = 0.20,
    /// s² = 0.20/11, half-width t(11) = 2.201 × √(s²/12) = 0.08566. Realisation means
    /// 1.0, 1.0, 1.0: F = 0, pooled.
    #[test]
    fn pooled_interval_of_a_small_set_by_hand() {
        let sets = vec![
            vec![1.0, 1.2, 0.8, 1.0],
            vec![1.1, 0.9, 1.0, 1.0],
            vec![0.9, 1.1, 1.2, 0.8],
        ];
        let (e, by_realisation) = pooled(&sets).unwrap();
        assert!(!by_realisation);
        assert!((e.mean - 1.0).abs() < 1e-12, "{e:?}");
        let want = 2.201 * (0.20 / 11.0 / 12.0f64).sqrt();
        assert!(
            (e.half_width - want).abs() < 1e-12,
            "{} against {want}",
            e.half_width
        );
        assert_eq!(e.batches, 12);
    }

    /// Realisations whose means differ far beyond their batches (2.0 ± 0.01 against
    /// 1.0 ± 0.01): F ≫ F₀.₉₅(1, 6) and the interval is Student's t over the two
    /// realisation means: 12.706 × |2 − 1|/2 = 6.353 (sd of two means 1/√2, over √2).
    #[test]
    fn realisations_that_disagree_get_their_own_interval() {
        let sets = vec![vec![1.01, 0.99, 1.01, 0.99], vec![2.01, 1.99, 2.01, 1.99]];
        let (e, by_realisation) = pooled(&sets).unwrap();
        assert!(by_realisation);
        assert!((e.mean - 1.5).abs() < 1e-12);
        assert!((e.half_width - 12.706 * 0.5).abs() < 1e-9, "{e:?}");
    }

    #[test]
    fn one_realisation_is_its_batch_means() {
        let v = vec![1.1, 0.9, 1.1, 0.9, 1.0];
        let (e, by) = pooled(std::slice::from_ref(&v)).unwrap();
        assert!(!by);
        assert_eq!(e, Estimate::of_batches(&v));
        assert!(
            pooled(&[vec![1.0, 2.0], vec![1.0]]).is_none(),
            "unequal batch counts"
        );
    }
}
