//! Four-lane arithmetic for stepping four fibres at once ([`crate::batch`]): a value per
//! fibre in each lane, vectors and 3×3 matrices of such values. Every operation does, lane
//! by lane, exactly the floating-point operations nalgebra does for `Vector3<f64>` and
//! `Matrix3<f64>` (same products, same order of sums), so a lane gets the same bits as the
//! scalar code.

use std::ops::{Add, Div, Mul, Neg, Sub};

/// Number of fibres stepped together.
pub const LANES: usize = 4;

/// One `f64` per lane.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct F4(pub [f64; LANES]);

impl F4 {
    #[inline(always)]
    pub fn splat(x: f64) -> Self {
        F4([x; LANES])
    }

    #[inline(always)]
    pub fn sqrt(self) -> Self {
        let a = self.0;
        F4([a[0].sqrt(), a[1].sqrt(), a[2].sqrt(), a[3].sqrt()])
    }

    /// Per lane: `a` where `mask`, else `b`.
    #[inline(always)]
    pub fn select(mask: [bool; LANES], a: Self, b: Self) -> Self {
        F4([
            if mask[0] { a.0[0] } else { b.0[0] },
            if mask[1] { a.0[1] } else { b.0[1] },
            if mask[2] { a.0[2] } else { b.0[2] },
            if mask[3] { a.0[3] } else { b.0[3] },
        ])
    }

    /// Per lane: `self < x`.
    #[inline(always)]
    pub fn lt(self, x: f64) -> [bool; LANES] {
        [self.0[0] < x, self.0[1] < x, self.0[2] < x, self.0[3] < x]
    }
}

/// Above this |x| (radians) [`sin_cos`] hands the lane to the C library: the three-part
/// reduction by π/2 below stays exact to well beyond it.
const SIN_COS_REDUCED_MAX: f64 = 1.0e5;

/// sin x and cos x in every lane, with the same bits whatever the instruction set and
/// whatever the lane (the fibre step's rotations, eq. 12, in lanes and one at a time):
/// x reduced by π/2 in three parts (Cody–Waite), then the minimax polynomials of the
/// Cephes library on [−π/4, π/4]. Within 1.5 ulp of the C library
/// (1.5 ulp at worst, test `sin_cos_matches_the_c_library`); exact for x = 0 and tiny x.
#[inline(always)]
#[allow(clippy::excessive_precision)] // the constants as Cephes prints them
pub fn sin_cos(x: F4) -> (F4, F4) {
    // π/2 = P1 + P2 + P3, P1 and P2 with trailing zero bits so k P1, k P2 are exact
    const P1: f64 = 1.570_796_251_296_997_070_31;
    const P2: f64 = 7.549_789_415_861_596_353_36e-8;
    const P3: f64 = 5.390_302_858_158_119_052_90e-15;
    const SIN: [f64; 6] = [
        1.589_623_015_765_465_680_60e-10,
        -2.505_074_776_285_780_728_66e-8,
        2.755_731_362_138_572_452_13e-6,
        -1.984_126_982_958_953_859_96e-4,
        8.333_333_333_322_118_588_78e-3,
        -1.666_666_666_666_663_072_95e-1,
    ];
    const COS: [f64; 6] = [
        -1.135_853_652_138_768_173_00e-11,
        2.087_570_084_197_473_167_78e-9,
        -2.755_731_417_929_673_881_12e-7,
        2.480_158_728_885_170_453_48e-5,
        -1.388_888_888_887_305_641_16e-3,
        4.166_666_666_666_659_292_18e-2,
    ];
    // round to nearest (ties to even) by the 1.5·2^52 shift
    const SHIFT: f64 = 6_755_399_441_055_744.0;
    let sp = F4::splat;
    let k = (x * sp(std::f64::consts::FRAC_2_PI) + sp(SHIFT)) - sp(SHIFT);
    let r = ((x - k * sp(P1)) - k * sp(P2)) - k * sp(P3);
    let z = r * r;
    let poly = |c: &[f64; 6]| {
        let mut p = sp(c[0]);
        for &ci in &c[1..] {
            p = p * z + sp(ci);
        }
        p
    };
    let s = r + r * z * poly(&SIN);
    let c = (sp(1.0) - sp(0.5) * z) + z * z * poly(&COS);
    let (mut sin, mut cos) = (F4::default(), F4::default());
    for l in 0..LANES {
        let (sl, cl) = (s.0[l], c.0[l]);
        (sin.0[l], cos.0[l]) = if !(x.0[l].abs() <= SIN_COS_REDUCED_MAX) {
            x.0[l].sin_cos()
        } else {
            match (k.0[l] as i64) & 3 {
                0 => (sl, cl),
                1 => (cl, -sl),
                2 => (-sl, -cl),
                _ => (-cl, sl),
            }
        };
    }
    (sin, cos)
}

/// [`sin_cos`] of one value (the same bits as any lane of it).
pub fn sin_cos1(x: f64) -> (f64, f64) {
    let (s, c) = sin_cos(F4::splat(x));
    (s.0[0], c.0[0])
}

impl Add for F4 {
    type Output = F4;
    #[inline(always)]
    fn add(self, o: F4) -> F4 {
        let (a, b) = (self.0, o.0);
        F4([a[0] + b[0], a[1] + b[1], a[2] + b[2], a[3] + b[3]])
    }
}

impl Sub for F4 {
    type Output = F4;
    #[inline(always)]
    fn sub(self, o: F4) -> F4 {
        let (a, b) = (self.0, o.0);
        F4([a[0] - b[0], a[1] - b[1], a[2] - b[2], a[3] - b[3]])
    }
}

impl Mul for F4 {
    type Output = F4;
    #[inline(always)]
    fn mul(self, o: F4) -> F4 {
        let (a, b) = (self.0, o.0);
        F4([a[0] * b[0], a[1] * b[1], a[2] * b[2], a[3] * b[3]])
    }
}

impl Div for F4 {
    type Output = F4;
    #[inline(always)]
    fn div(self, o: F4) -> F4 {
        let (a, b) = (self.0, o.0);
        F4([a[0] / b[0], a[1] / b[1], a[2] / b[2], a[3] / b[3]])
    }
}

impl Neg for F4 {
    type Output = F4;
    #[inline(always)]
    fn neg(self) -> F4 {
        let a = self.0;
        F4([-a[0], -a[1], -a[2], -a[3]])
    }
}

/// A 3-vector per lane.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct V3(pub [F4; 3]);

impl V3 {
    #[inline(always)]
    pub fn splat(v: [f64; 3]) -> Self {
        V3([F4::splat(v[0]), F4::splat(v[1]), F4::splat(v[2])])
    }

    /// The vector in lane `l`.
    #[inline(always)]
    pub fn lane(&self, l: usize) -> [f64; 3] {
        [self.0[0].0[l], self.0[1].0[l], self.0[2].0[l]]
    }

    /// `s * v` (nalgebra's scalar product, element by element).
    #[inline(always)]
    pub fn scale(self, s: F4) -> V3 {
        V3([self.0[0] * s, self.0[1] * s, self.0[2] * s])
    }

    /// `v / s`, element by element (nalgebra's `unscale`).
    #[inline(always)]
    pub fn unscale(self, s: F4) -> V3 {
        V3([self.0[0] / s, self.0[1] / s, self.0[2] / s])
    }

    /// (a0 b0 + a1 b1) + a2 b2, as nalgebra's `dot` of 3-vectors.
    #[inline(always)]
    pub fn dot(self, o: V3) -> F4 {
        self.0[0] * o.0[0] + self.0[1] * o.0[1] + self.0[2] * o.0[2]
    }

    #[inline(always)]
    pub fn cross(self, b: V3) -> V3 {
        let [ax, ay, az] = self.0;
        let [bx, by, bz] = b.0;
        V3([ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx])
    }

    /// sqrt(0 + dot(v, v)), as nalgebra's `norm`.
    #[inline(always)]
    pub fn norm(self) -> F4 {
        (F4::splat(0.0) + self.dot(self)).sqrt()
    }

    /// `v / |v|`, as nalgebra's `normalize`.
    #[inline(always)]
    pub fn normalize(self) -> V3 {
        self.unscale(self.norm())
    }

    /// Per lane: `a` where `mask`, else `b`.
    #[inline(always)]
    pub fn select(mask: [bool; LANES], a: V3, b: V3) -> V3 {
        V3([
            F4::select(mask, a.0[0], b.0[0]),
            F4::select(mask, a.0[1], b.0[1]),
            F4::select(mask, a.0[2], b.0[2]),
        ])
    }
}

impl Add for V3 {
    type Output = V3;
    #[inline(always)]
    fn add(self, o: V3) -> V3 {
        V3([self.0[0] + o.0[0], self.0[1] + o.0[1], self.0[2] + o.0[2]])
    }
}

impl Sub for V3 {
    type Output = V3;
    #[inline(always)]
    fn sub(self, o: V3) -> V3 {
        V3([self.0[0] - o.0[0], self.0[1] - o.0[1], self.0[2] - o.0[2]])
    }
}

impl Neg for V3 {
    type Output = V3;
    #[inline(always)]
    fn neg(self) -> V3 {
        V3([-self.0[0], -self.0[1], -self.0[2]])
    }
}

/// A 3×3 matrix per lane, `0[row][column]`.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct M3(pub [[F4; 3]; 3]);

impl M3 {
    #[inline(always)]
    pub fn from_fn(f: impl Fn(usize, usize) -> F4) -> M3 {
        M3([
            [f(0, 0), f(0, 1), f(0, 2)],
            [f(1, 0), f(1, 1), f(1, 2)],
            [f(2, 0), f(2, 1), f(2, 2)],
        ])
    }

    /// The identity's entry (a, b) as a lane value.
    #[inline(always)]
    pub fn identity_at(a: usize, b: usize) -> F4 {
        F4::splat(if a == b { 1.0 } else { 0.0 })
    }

    /// z zᵀ.
    #[inline(always)]
    pub fn outer(z: V3) -> M3 {
        M3::from_fn(|a, b| z.0[a] * z.0[b])
    }

    #[inline(always)]
    pub fn transpose(self) -> M3 {
        M3::from_fn(|a, b| self.0[b][a])
    }

    #[inline(always)]
    pub fn scale(self, s: F4) -> M3 {
        M3::from_fn(|a, b| s * self.0[a][b])
    }

    /// (A_a0 x0 + A_a1 x1) + A_a2 x2 per row, as nalgebra's gemv.
    #[inline(always)]
    pub fn mul_v(self, x: V3) -> V3 {
        let row = |a: usize| self.0[a][0] * x.0[0] + self.0[a][1] * x.0[1] + self.0[a][2] * x.0[2];
        V3([row(0), row(1), row(2)])
    }

    /// A B, column by column as nalgebra's gemm.
    #[inline(always)]
    pub fn mul_m(self, o: M3) -> M3 {
        M3::from_fn(|a, b| {
            self.0[a][0] * o.0[0][b] + self.0[a][1] * o.0[1][b] + self.0[a][2] * o.0[2][b]
        })
    }

    /// The inverse by cofactors, as nalgebra's `try_inverse` of a 3×3 matrix, and the
    /// determinant (the inverse is meaningless in lanes where it is zero).
    #[inline(always)]
    pub fn inverse(self) -> (M3, F4) {
        let [[m11, m12, m13], [m21, m22, m23], [m31, m32, m33]] = self.0;
        let minor_m12_m23 = m22 * m33 - m32 * m23;
        let minor_m11_m23 = m21 * m33 - m31 * m23;
        let minor_m11_m22 = m21 * m32 - m31 * m22;
        let det = m11 * minor_m12_m23 - m12 * minor_m11_m23 + m13 * minor_m11_m22;
        let inv = M3([
            [
                minor_m12_m23 / det,
                (m13 * m32 - m33 * m12) / det,
                (m12 * m23 - m22 * m13) / det,
            ],
            [
                -minor_m11_m23 / det,
                (m11 * m33 - m31 * m13) / det,
                (m13 * m21 - m23 * m11) / det,
            ],
            [
                minor_m11_m22 / det,
                (m12 * m31 - m32 * m11) / det,
                (m11 * m22 - m21 * m12) / det,
            ],
        ]);
        (inv, det)
    }
}

impl Add for M3 {
    type Output = M3;
    #[inline(always)]
    fn add(self, o: M3) -> M3 {
        M3::from_fn(|a, b| self.0[a][b] + o.0[a][b])
    }
}

impl Sub for M3 {
    type Output = M3;
    #[inline(always)]
    fn sub(self, o: M3) -> M3 {
        M3::from_fn(|a, b| self.0[a][b] - o.0[a][b])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix3, Vector3};

    fn lanes_of(v: [Vector3<f64>; LANES]) -> V3 {
        V3([0, 1, 2].map(|c| F4([v[0][c], v[1][c], v[2][c], v[3][c]])))
    }

    fn mat_lanes(m: [Matrix3<f64>; LANES]) -> M3 {
        M3::from_fn(|a, b| F4([m[0][(a, b)], m[1][(a, b)], m[2][(a, b)], m[3][(a, b)]]))
    }

    /// Awkward values (mixed magnitudes and signs), so any change of operation order
    /// shows in the last bits.
    fn value(seed: u64) -> f64 {
        let x = (seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407)
            >> 11) as f64
            / (1u64 << 53) as f64;
        (x - 0.4) * 10f64.powi((seed % 7) as i32 - 3)
    }

    fn vec(seed: u64) -> Vector3<f64> {
        Vector3::new(value(seed), value(seed + 1), value(seed + 2))
    }

    fn mat(seed: u64) -> Matrix3<f64> {
        Matrix3::from_fn(|a, b| value(seed + 3 * a as u64 + b as u64))
    }

    /// Each lane operation gives exactly nalgebra's bits.
    #[test]
    fn lanes_match_nalgebra_bit_for_bit() {
        let mut inverted = 0;
        for trial in 0..200u64 {
            let s = 100 * trial;
            let a = [0, 1, 2, 3].map(|l| vec(s + 10 * l));
            let b = [0, 1, 2, 3].map(|l| vec(s + 10 * l + 5));
            let m = [0, 1, 2, 3].map(|l| mat(s + 30 * l + 1));
            let n = [0, 1, 2, 3].map(|l| mat(s + 30 * l + 17));
            let (va, vb, ma, mb) = (lanes_of(a), lanes_of(b), mat_lanes(m), mat_lanes(n));
            let (inv, det) = ma.inverse();
            for l in 0..LANES {
                let v3 = |v: V3| Vector3::new(v.0[0].0[l], v.0[1].0[l], v.0[2].0[l]);
                let m3 = |x: M3| Matrix3::from_fn(|r, c| x.0[r][c].0[l]);
                let bits = |v: Vector3<f64>| v.map(f64::to_bits);
                let mbits = |x: Matrix3<f64>| x.map(f64::to_bits);
                assert_eq!(va.dot(vb).0[l].to_bits(), a[l].dot(&b[l]).to_bits());
                assert_eq!(bits(v3(va.cross(vb))), bits(a[l].cross(&b[l])));
                assert_eq!(va.norm().0[l].to_bits(), a[l].norm().to_bits());
                assert_eq!(bits(v3(va.normalize())), bits(a[l].normalize()));
                assert_eq!(bits(v3(ma.mul_v(va))), bits(m[l] * a[l]));
                assert_eq!(mbits(m3(ma.mul_m(mb))), mbits(m[l] * n[l]));
                assert_eq!(mbits(m3(M3::outer(va))), mbits(a[l] * a[l].transpose()));
                let want = m[l].try_inverse().map(mbits);
                if det.0[l] != 0.0 {
                    inverted += 1;
                    assert_eq!(Some(mbits(m3(inv))), want, "trial {trial} lane {l}");
                } else {
                    assert_eq!(want, None, "nalgebra refuses the same matrices");
                }
            }
        }
        assert!(inverted > 700, "only {inverted} of 800 matrices inverted");
    }

    /// The lane sine and cosine against the C library's: within 1 ulp of the larger of
    /// the result and 2⁻⁵³ (absolute error near the zeros) plus half an ulp, over small angles (what the
    /// step sees: |ω Δt| ≪ 1), moderate ones and large ones up to 10⁵ rad; beyond that the
    /// C library's own values; 0 exact; every lane the same bits as the one-value form.
    #[test]
    fn sin_cos_matches_the_c_library() {
        let mut worst: f64 = 0.0;
        let mut seed = 11u64;
        let mut next = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        for scale in [1e-12, 1e-6, 1e-3, 0.1, 1.0, 4.0, 100.0, 1e4, 1e5] {
            for _ in 0..50_000 {
                let x = F4([
                    next() * scale,
                    next() * scale,
                    next() * scale,
                    next() * scale,
                ]);
                let (s, c) = sin_cos(x);
                for l in 0..LANES {
                    let (ws, wc) = x.0[l].sin_cos();
                    for (got, want) in [(s.0[l], ws), (c.0[l], wc)] {
                        let ulp = want.abs().max(2f64.powi(-53)) * f64::EPSILON;
                        worst = worst.max((got - want).abs() / ulp);
                    }
                    let one = sin_cos1(x.0[l]);
                    assert_eq!(
                        (one.0.to_bits(), one.1.to_bits()),
                        (s.0[l].to_bits(), c.0[l].to_bits())
                    );
                }
            }
        }
        assert!(worst <= 1.5, "worst error {worst} ulp");
        eprintln!("sin_cos: worst {worst:.2} ulp");
        assert_eq!(sin_cos1(0.0), (0.0, 1.0));
        assert_eq!(sin_cos1(3e7), 3e7f64.sin_cos());
        let tiny = 1e-200;
        assert_eq!(sin_cos1(tiny), (tiny, 1.0));
    }
}
