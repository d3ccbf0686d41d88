//! e^x of many arguments at once, for the self-induced correction's drift factors
//! e^{−½ Σ_b ⟨k_b²⟩⟨o_b²⟩} (docs/two-way.md, "Self-induced velocity"): one per (mode,
//! component) of every fibre, which the C library's `exp` takes one call at a time. Plain arithmetic in one branch-free loop, so that it
//! vectorises, with AVX2 or AVX-512 where the processor has them, and gives the same bits
//! on every path (no fused multiply-adds: Rust does not contract them). Within 4e-16 of
//! `f64::exp` relative (test `exp_is_the_library_exp`); arguments below −700 give
//! e^−700 (≈ 1e-304: the factor multiplies a force memory, and below that it is zero for
//! every purpose).

/// Round to nearest by the 1.5·2^52 trick (plain additions: vectorisable, exact).
const ROUND: f64 = 6_755_399_441_055_744.0;
/// ln 2 in two parts, the first exact in n·ln 2 for |n| < 2¹¹ (Cody–Waite).
const LN2_HI: f64 = 0.693_147_180_369_123_8;
const LN2_LO: f64 = 1.908_214_929_270_587_7e-10;
const LOWEST: f64 = -700.0;

/// e^x for x ≤ 0 (clamped at −700 below; x > 0 is not asked for): x = n ln 2 + r with
/// |r| ≤ ½ ln 2, e^r by its Taylor series through r¹³ (truncation below 5e-18), 2^n put
/// in the exponent's bits.
#[inline(always)]
fn exp_one(x: f64) -> f64 {
    let x = if x < LOWEST { LOWEST } else { x };
    let n = (x * std::f64::consts::LOG2_E + ROUND) - ROUND;
    let r = (x - n * LN2_HI) - n * LN2_LO;
    let mut p = 1.0 / 6_227_020_800.0;
    for d in [
        479_001_600.0,
        39_916_800.0,
        3_628_800.0,
        362_880.0,
        40_320.0,
        5_040.0,
        720.0,
        120.0,
        24.0,
        6.0,
        2.0,
        1.0,
        1.0,
    ] {
        p = p * r + 1.0 / d;
    }
    // 2^n for −1010 ≤ n ≤ 0: n + 1023 + 2^52 holds n + 1023 in its low bits, which the
    // shift moves into the exponent field
    let biased = n + (1023.0 + 4_503_599_627_370_496.0);
    let scale = f64::from_bits(biased.to_bits() << 52);
    p * scale
}

/// Replaces every value of `x` (each ≤ 0) by its exponential.
pub fn exp_in_place(x: &mut [f64]) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU supports AVX-512F (checked just above); the function only
            // lets the compiler use it for the same arithmetic.
            return unsafe { exp_avx512(x) };
        }
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked just above); the function only lets
            // the compiler use it for the same arithmetic.
            return unsafe { exp_avx2(x) };
        }
    }
    exp_lanes(x)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn exp_avx512(x: &mut [f64]) {
    exp_lanes(x)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn exp_avx2(x: &mut [f64]) {
    exp_lanes(x)
}

#[inline(always)]
fn exp_lanes(x: &mut [f64]) {
    for v in x.iter_mut() {
        *v = exp_one(*v);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Within 4e-16 of the library's e^x, relative, over [−700, 0] (and at the ends and
    /// near the rounding points of n), exactly 1 at 0; below −700, e^−700.
    #[test]
    fn exp_is_the_library_exp() {
        let mut xs: Vec<f64> = (0..2_000_000).map(|i| -700.0 * i as f64 / 2e6).collect();
        for n in 0..1010 {
            let m = -(n as f64 + 0.5) * std::f64::consts::LN_2;
            xs.extend([m, m.next_up(), m.next_down()]);
        }
        xs.extend([0.0, -0.0, -1e-300, -1e-20, -700.0]);
        let mut y = xs.clone();
        exp_in_place(&mut y);
        let mut worst: f64 = 0.0;
        for (x, y) in xs.iter().zip(&y) {
            let want = x.exp();
            worst = worst.max((y / want - 1.0).abs());
        }
        assert!(worst < 4e-16, "worst {worst:e}");
        let mut one = [0.0];
        exp_in_place(&mut one);
        assert_eq!(one[0], 1.0);
        let mut low = [-1e4, f64::MIN];
        exp_in_place(&mut low);
        assert_eq!(low, [exp_one(-700.0); 2]);
    }

    /// The AVX-512, AVX2 and plain paths give the same bits (each vector path where the
    /// CPU has it).
    #[test]
    fn every_path_gives_the_same_bits() {
        let xs: Vec<f64> = (0..1001).map(|i| -0.37 * i as f64).collect();
        let mut plain = xs.clone();
        exp_lanes(&mut plain);
        #[cfg(target_arch = "x86_64")]
        {
            type Path = unsafe fn(&mut [f64]);
            let paths: [(bool, Path); 2] = [
                (std::arch::is_x86_feature_detected!("avx512f"), exp_avx512),
                (std::arch::is_x86_feature_detected!("avx2"), exp_avx2),
            ];
            for (_, path) in paths.into_iter().filter(|p| p.0) {
                let mut y = xs.clone();
                // SAFETY: the CPU has the path's features (checked just above)
                unsafe { path(&mut y) };
                for (a, b) in y.iter().zip(&plain) {
                    assert_eq!(a.to_bits(), b.to_bits());
                }
            }
        }
    }
}
