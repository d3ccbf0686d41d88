//! The self-induced correction's pair shares (docs/two-way.md, "Self-induced velocity"):
//! segment i of a fibre sees segment j's share of the fibre's force, in memory mode k and
//! component a, through the mode's average of e^{ik·r_ij}, modelled as sinc(√u) with
//! u = 3 r_ijᵀ⟨kkᵀ⟩_ka r_ij (exact to second order in r_ij). Per pair of segments, all
//! (mode, component) lanes at once in blocks of sixteen, each block branch-free so that it
//! vectorises; the same bits with and without AVX2 and AVX-512 (no fused multiply-adds:
//! Rust does not contract them).
//!
//! In single precision: the shares are a model's estimate, exact to second order in r,
//! and sinc is within 3e-7 of sin x / x (test `sinc_is_sin_over_x`), far below what the
//! model leaves out; eight lanes a vector and a shorter series make the shares ≈ 3 times
//! cheaper than in double precision (docs/history/two-way-cost.md).
//!
//! The lanes of long waves have small arguments (k r < π/2; on the coarse grid 4–7 of a
//! row's 7–8 blocks for segments 3–18 wall units apart): there sinc(√u) is its series in
//! u alone, without the square root, the range reduction and the division, and a block
//! whose arguments are all small takes only that. Every lane's value is the same whichever way its block goes (`sinc_of_square`
//! uses the same series at n = 0), so the bits depend on no vector width.

/// Round to nearest by the 1.5·2^23 trick (plain additions: vectorisable, exact).
const ROUND: f32 = 12_582_912.0;
const PI_HI: f32 = 3.140_625;
const PI_LO: f32 = 9.676_536e-4;

/// sin r / r for |r| ≤ π/2 from r² = `r2`: its Taylor series through r¹⁰ (error below
/// 6e-8).
#[inline(always)]
fn series(r2: f32) -> f32 {
    1.0 + r2
        * (-1.0 / 6.0
            + r2 * (1.0 / 120.0
                + r2 * (-1.0 / 5040.0 + r2 * (1.0 / 362_880.0 + r2 * (-1.0 / 39_916_800.0)))))
}

/// sin(x)/x for x ≥ 0, without a branch: x = nπ + r with |r| ≤ π/2 (Cody–Waite, two parts
/// of π, the first exact in n·π for n < 2¹⁶), sin r by its Taylor series through r¹¹
/// (error below 6e-8), the sign (−1)^n. Within 3e-7 of sin x / x for x up to 10³ (test
/// `sinc_is_sin_over_x`).
#[inline(always)]
pub fn sinc(x: f32) -> f32 {
    let n = (x * std::f32::consts::FRAC_1_PI + ROUND) - ROUND;
    let r = (x - n * PI_HI) - n * PI_LO;
    reduced(x, n, r, r * r)
}

/// sin x / x from x = nπ + r and r² = `r2`.
#[inline(always)]
fn reduced(x: f32, n: f32, r: f32, r2: f32) -> f32 {
    let p = series(r2);
    // (−1)^n: n − 2·round(n/2) is 0 for even n, ±1 for odd
    let half = (0.5 * n + ROUND) - ROUND;
    let odd = (n - 2.0 * half).abs();
    let sign = 1.0 - 2.0 * odd;
    // for n = 0, r is x itself and r/x = 1 (also at x = 0)
    let ratio = if n == 0.0 { 1.0 } else { r / x };
    sign * p * ratio
}

/// Arguments u below this have √u < π/2 with room to spare (√2.4/π = 0.493), so n = 0 in
/// [`sinc_of_square`].
const SMALL: f32 = 2.4;

/// sin(√u)/√u for u ≥ 0: [`sinc`] at √u, but where n = 0 the series takes u itself
/// (rather than r² = (√u)², which rounds differently), so that small arguments need
/// neither the square root nor the division: there it is `series(u)` exactly. Within 3e-7
/// of sin √u / √u (test `sinc_of_square_is_sin_over_x`).
#[inline(always)]
pub fn sinc_of_square(u: f32) -> f32 {
    let x = u.sqrt();
    let n = (x * std::f32::consts::FRAC_1_PI + ROUND) - ROUND;
    let r = (x - n * PI_HI) - n * PI_LO;
    let r2 = if n == 0.0 { u } else { r * r };
    reduced(x, n, r, r2)
}

/// Lanes whose arguments decide together whether they take the series alone.
const BLOCK: usize = 16;

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
    let full = n - n % BLOCK;
    let mut q = 0;
    while q < full {
        let block = q..q + BLOCK;
        if let (Ok(a), Ok(b), Ok(c), Ok(nr), Ok(fr)) = (
            <&[f32; BLOCK]>::try_from(&cx[block.clone()]),
            <&[f32; BLOCK]>::try_from(&cy[block.clone()]),
            <&[f32; BLOCK]>::try_from(&cz[block.clone()]),
            <&mut [f32; BLOCK]>::try_from(&mut near[block.clone()]),
            <&mut [f32; BLOCK]>::try_from(&mut far[block]),
        ) {
            add_block([a, b, c], r2, nr, fr);
        }
        q += BLOCK;
    }
    if full < n {
        // the last lanes as a whole block, padded with zero coefficients
        let m = n - full;
        let mut c = [[0.0f32; BLOCK]; 3];
        for (cb, src) in c.iter_mut().zip([cx, cy, cz]) {
            cb[..m].copy_from_slice(&src[full..]);
        }
        let (mut nr, mut fr) = ([0.0f32; BLOCK], [0.0f32; BLOCK]);
        nr[..m].copy_from_slice(&near[full..]);
        fr[..m].copy_from_slice(&far[full..]);
        add_block([&c[0], &c[1], &c[2]], r2, &mut nr, &mut fr);
        near[full..].copy_from_slice(&nr[..m]);
        far[full..].copy_from_slice(&fr[..m]);
    }
}

/// [`add_pair_lanes`] for one block of [`BLOCK`] lanes: fixed lengths, so every loop
/// vectorises.
#[inline(always)]
fn add_block(c: [&[f32; BLOCK]; 3], r2: [f32; 3], near: &mut [f32; BLOCK], far: &mut [f32; BLOCK]) {
    let mut u = [0.0f32; BLOCK];
    let mut small = true;
    for l in 0..BLOCK {
        u[l] = c[0][l] * r2[0] + c[1][l] * r2[1] + c[2][l] * r2[2];
        small &= u[l] < SMALL;
    }
    if small {
        // every lane's n is 0: the series in u, as `sinc_of_square` takes it there
        for l in 0..BLOCK {
            let s = series(u[l]);
            near[l] += s;
            far[l] += s;
        }
    } else {
        for l in 0..BLOCK {
            let s = sinc_of_square(u[l]);
            near[l] += s;
            far[l] += s;
        }
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

    /// sin(√u)/√u within 3e-7 over u in (0, 10⁶] (x up to 10³), the series alone equal to
    /// it bit for bit below [`SMALL`], and exactly 1 at 0.
    #[test]
    fn sinc_of_square_is_sin_over_x() {
        let mut worst: f64 = 0.0;
        for i in 1..2_000_000 {
            let x = i as f32 * 5e-4;
            let u = x * x;
            let exact = (u as f64).sqrt().sin() / (u as f64).sqrt();
            worst = worst.max((sinc_of_square(u) as f64 - exact).abs());
            if u < SMALL {
                assert_eq!(series(u).to_bits(), sinc_of_square(u).to_bits(), "u {u}");
            }
        }
        assert!(worst < 3e-7, "worst {worst:e}");
        assert_eq!(sinc_of_square(0.0), 1.0);
    }

    /// The AVX-512, AVX2 and plain paths give the same bits (each vector path where the
    /// CPU has it).
    #[test]
    fn every_path_gives_the_same_bits() {
        let coeff: [Vec<f32>; 3] =
            std::array::from_fn(|b| (0..141).map(|q| 1e-3 * (q * q + b + 1) as f32).collect());
        let r2 = [2.25, 0.09, 7.3];
        // the first sixteen lanes' arguments are all small, the rest are not
        let u = |q: usize| coeff[0][q] * r2[0] + coeff[1][q] * r2[1] + coeff[2][q] * r2[2];
        assert!((0..16).all(|q| u(q) < SMALL) && u(16) >= SMALL);
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
            let u = coeff[0][q] * r2[0] + coeff[1][q] * r2[1] + coeff[2][q] * r2[2];
            // each lane is its own sinc_of_square, whichever way its block went (the first
            // block here takes the series alone, the others the whole range reduction)
            assert_eq!(b[q].to_bits(), sinc_of_square(u).to_bits(), "lane {q}");
            let u = u as f64;
            assert!((b[q] as f64 - u.sqrt().sin() / u.sqrt()).abs() < 1e-6);
        }
    }
}
