//! The self-induced correction's pair shares (docs/two-way.md, "Self-induced velocity"):
//! segment i of a fibre sees segment j's share of the fibre's force, in memory mode k and
//! component a, through the mode's average of e^{ik·r_ij}, modelled as sinc(√u) with
//! u = 3 r_ijᵀ⟨kkᵀ⟩_ka r_ij (exact to second order in r_ij). Per pair of segments, all
//! (mode, component) lanes at once, branch-free so that the loop vectorises; the same bits
//! with and without AVX2 (no fused multiply-adds: Rust does not contract them).
//!
//! In single precision: the shares are a model's estimate, exact to second order in r,
//! and sinc is within 3e-7 of sin x / x (test `sinc_is_sin_over_x`), far below what the
//! model leaves out; eight lanes a vector and a shorter series make the shares ≈ 3 times
//! cheaper than in double precision (docs/history/two-way-cost.md).

/// sin(x)/x for x ≥ 0, without a branch: x = nπ + r with |r| ≤ π/2 (Cody–Waite, two parts
/// of π, the first exact in n·π for n < 2¹⁶), sin r by its Taylor series through r¹¹
/// (error below 6e-8), the sign (−1)^n. Within 3e-7 of sin x / x for x up to 10³ (test
/// `sinc_is_sin_over_x`).
#[inline(always)]
pub fn sinc(x: f32) -> f32 {
    // round to nearest by the 1.5·2^23 trick (plain additions: vectorisable, exact)
    const ROUND: f32 = 12_582_912.0;
    const PI_HI: f32 = 3.140_625;
    const PI_LO: f32 = 9.676_536e-4;
    let n = (x * std::f32::consts::FRAC_1_PI + ROUND) - ROUND;
    let r = (x - n * PI_HI) - n * PI_LO;
    let r2 = r * r;
    let p = 1.0
        + r2 * (-1.0 / 6.0
            + r2 * (1.0 / 120.0
                + r2 * (-1.0 / 5040.0 + r2 * (1.0 / 362_880.0 + r2 * (-1.0 / 39_916_800.0)))));
    // (−1)^n: n − 2·round(n/2) is 0 for even n, ±1 for odd
    let half = (0.5 * n + ROUND) - ROUND;
    let odd = (n - 2.0 * half).abs();
    let sign = 1.0 - 2.0 * odd;
    // for n = 0, r is x itself and r/x = 1 (also at x = 0)
    let ratio = if n == 0.0 { 1.0 } else { r / x };
    sign * p * ratio
}

/// For one pair of segments with squared offsets `r2` (x², y², z²): adds, per lane q of
/// `lanes`, sinc(√u_q) with u_q = coeff[0][q] r2[0] + coeff[1][q] r2[1] + coeff[2][q] r2[2]
/// to `near[q]` and `far[q]` (the shares of the pair's two segments).
pub fn add_pair(
    coeff: &[Vec<f32>; 3],
    lanes: std::ops::Range<usize>,
    r2: [f32; 3],
    near: &mut [f32],
    far: &mut [f32],
) {
    let end = lanes.end.min(near.len()).min(far.len());
    let start = lanes.start.min(end);
    let (near, far) = (&mut near[start..end], &mut far[start..end]);
    let coeff = [0, 1, 2].map(|b| &coeff[b][start..end]);
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU supports AVX-512F (checked just above); the function only
            // lets the compiler use it for the same arithmetic.
            return unsafe { add_pair_avx512(coeff, r2, near, far) };
        }
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked just above); the function only lets
            // the compiler use it for the same arithmetic.
            return unsafe { add_pair_avx2(coeff, r2, near, far) };
        }
    }
    add_pair_lanes(coeff, r2, near, far)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn add_pair_avx2(coeff: [&[f32]; 3], r2: [f32; 3], near: &mut [f32], far: &mut [f32]) {
    add_pair_lanes(coeff, r2, near, far)
}

/// Sixteen lanes a vector: the same operations lane by lane, so the same bits.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn add_pair_avx512(coeff: [&[f32]; 3], r2: [f32; 3], near: &mut [f32], far: &mut [f32]) {
    add_pair_lanes(coeff, r2, near, far)
}

#[inline(always)]
fn add_pair_lanes(coeff: [&[f32]; 3], r2: [f32; 3], near: &mut [f32], far: &mut [f32]) {
    let n = near.len().min(far.len());
    let (cx, cy, cz) = (&coeff[0][..n], &coeff[1][..n], &coeff[2][..n]);
    let (near, far) = (&mut near[..n], &mut far[..n]);
    for q in 0..n {
        let u = cx[q] * r2[0] + cy[q] * r2[1] + cz[q] * r2[2];
        let s = sinc(u.sqrt());
        near[q] += s;
        far[q] += s;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The branch-free sinc is sin(x)/x within 3e-7 over (0, 1000] (at the single-precision
    /// argument), exactly 1 at 0.
    #[test]
    fn sinc_is_sin_over_x() {
        let mut worst: f64 = 0.0;
        for i in 1..2_000_000 {
            let x = i as f32 * 5e-4;
            let exact = (x as f64).sin() / x as f64;
            worst = worst.max((sinc(x) as f64 - exact).abs());
        }
        assert!(worst < 3e-7, "worst {worst:e}");
        assert_eq!(sinc(0.0), 1.0);
    }

    /// The AVX-512, AVX2 and plain paths give the same bits (each vector path where the
    /// CPU has it).
    #[test]
    fn every_path_gives_the_same_bits() {
        let coeff: [Vec<f32>; 3] =
            std::array::from_fn(|b| (0..141).map(|q| 1e-3 * (q * q + b + 1) as f32).collect());
        let r2 = [2.25, 0.09, 7.3];
        let (mut a, mut b) = (vec![0.5; 141], vec![0.0; 141]);
        let (mut c, mut d) = (vec![0.5; 141], vec![0.0; 141]);
        add_pair(&coeff, 0..141, r2, &mut a, &mut b);
        add_pair_lanes([0, 1, 2].map(|b| &coeff[b][..]), r2, &mut c, &mut d);
        #[cfg(target_arch = "x86_64")]
        {
            type Path = unsafe fn([&[f32]; 3], [f32; 3], &mut [f32], &mut [f32]);
            let paths: [(bool, Path); 2] = [
                (
                    std::arch::is_x86_feature_detected!("avx512f"),
                    add_pair_avx512,
                ),
                (std::arch::is_x86_feature_detected!("avx2"), add_pair_avx2),
            ];
            for (_, path) in paths.into_iter().filter(|p| p.0) {
                let (mut e, mut f) = (vec![0.5; 141], vec![0.0; 141]);
                // SAFETY: the CPU has the path's features (checked just above)
                unsafe { path([0, 1, 2].map(|b| &coeff[b][..]), r2, &mut e, &mut f) };
                for q in 0..141 {
                    assert_eq!(e[q].to_bits(), c[q].to_bits());
                    assert_eq!(f[q].to_bits(), d[q].to_bits());
                }
            }
        }
        // a range of lanes touches only those
        let (mut e, mut f) = (vec![0.5; 141], vec![0.0; 141]);
        add_pair(&coeff, 30..90, r2, &mut e, &mut f);
        for q in 0..141 {
            let inside = (30..90).contains(&q);
            assert_eq!(e[q].to_bits(), if inside { a[q] } else { 0.5 }.to_bits());
            assert_eq!(f[q].to_bits(), if inside { b[q] } else { 0.0 }.to_bits());
        }
        for q in 0..141 {
            assert_eq!(a[q].to_bits(), c[q].to_bits());
            assert_eq!(b[q].to_bits(), d[q].to_bits());
            let u = (coeff[0][q] * r2[0] + coeff[1][q] * r2[1] + coeff[2][q] * r2[2]) as f64;
            assert!((b[q] as f64 - u.sqrt().sin() / u.sqrt()).abs() < 1e-6);
        }
    }
}
