//! Two-way coupling's self-induced disturbance (docs/two-way.md, "Self-induced velocity").
//!
//! A fibre's force, spread onto the grid, disturbs the very velocity its segments then
//! sample; the drag laws (paper eq. 21–31) already account for the fibre's own disturbance,
//! so left in, it would be counted twice (a settling case-1 fibre would fall ≈ 1.6 times as
//! fast on the coarse grid). The flow node removes it from the samples, quasi-steadily:
//!
//!   u_i ← u_i + Σ_j M(r_i − r_j) F^h_j   (j over the segments of the same fibre),
//!
//! since the fluid received −F^h_j. M is the Stokes mobility of a force spread with a
//! Gaussian and sampled at a distance r: the regularised Stokeslet
//!   M(r) = [ (H − B′/r) I + (3B′/r − H) r̂r̂ ] / μ,
//!   H = erf(r/a)/(4πr),  B′ = [ (r²/2 − a²/4) erf(r/a) + a r e^{−r²/a²}/(2√π) ] / (4πr²),
//! a = σ√2, which is the Oseen tensor (I + r̂r̂)/(8πμr) far away and 1/(3√2 π^{3/2} μσ) at
//! r = 0 (tests below). The width stands for the spreading kernel and the trilinear
//! sampler together: per direction σ_a² = (0.298 + 1/6) Δ_a², the variance of the
//! three-point Roma–Peskin function plus that of the hat function, in units of the local
//! grid spacing Δ_a. The grid is anisotropic (Δx ≠ Δy(y) ≠ Δz), so M is the isotropic
//! kernel of the geometric mean width, scaled per component to the anisotropic Gaussian's
//! exact self-mobility ([`anisotropic_self_mobility`], a one-dimensional integral).
//!
//! What it leaves out, said plainly: the history of the disturbance (it builds up over
//! ≈ σ²/ν, 25–100 t+ here; quasi-steady is exact for a steady force, e.g. terminal
//! settling), the disturbance's gradient (the samples' ∇v is left as sampled), the walls'
//! and the periodic images' share of the fibre's own disturbance, and the difference
//! between the second-order discrete operators and the continuum at the kernel's scale.
//! The test of all of it together is the settling fibre (docs/two-way.md).

use fiberflow_dns::Grid;

/// Variance of the spreading kernel plus the sampler's, in squared grid spacings.
pub const KERNEL_VARIANCE: f64 = 0.298_466_737 + 1.0 / 6.0;

/// The isotropic regularised Stokeslet M(r) (times μ) of Gaussian width `sigma`, as a
/// symmetric 3×3 matrix, row-major.
pub fn stokeslet(r: [f64; 3], sigma: f64) -> [f64; 9] {
    let a = sigma * std::f64::consts::SQRT_2;
    let rr = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
    let pi = std::f64::consts::PI;
    let (iso, rad) = if rr < 1e-6 * a {
        // the r → 0 limit (series to O(r²))
        let c = 1.0 / (3.0 * pi.powf(1.5) * a);
        (c, 0.0)
    } else {
        let x = rr / a;
        let erf = libm_erf(x);
        let h = erf / (4.0 * pi * rr);
        let b1 = ((rr * rr / 2.0 - a * a / 4.0) * erf
            + a * rr * (-x * x).exp() / (2.0 * pi.sqrt()))
            / (4.0 * pi * rr * rr);
        (h - b1 / rr, 3.0 * b1 / rr - h)
    };
    let mut m = [0.0; 9];
    for i in 0..3 {
        for j in 0..3 {
            let u = if rr > 0.0 { r[i] * r[j] / (rr * rr) } else { 0.0 };
            m[3 * i + j] = if i == j { iso } else { 0.0 } + rad * u;
        }
    }
    m
}

/// erf(x), x ≥ 0: the Taylor series below 2.5, the continued fraction of erfc beyond
/// (|error| < 1e-13, test `erf_values`).
fn libm_erf(x: f64) -> f64 {
    if x < 2.5 {
        // Σ (−1)^n x^(2n+1) / (n! (2n+1)) · 2/√π
        let mut term = x;
        let mut sum = x;
        let x2 = x * x;
        let mut n = 0.0;
        while term.abs() > 1e-17 * sum.abs() {
            n += 1.0;
            term *= -x2 / n;
            sum += term / (2.0 * n + 1.0);
        }
        sum * 2.0 / std::f64::consts::PI.sqrt()
    } else {
        // erfc(x) = e^{−x²}/√π · 1/(x + 1/2/(x + 1/(x + 3/2/(x + 2/(x + …)))))
        let mut f = x;
        for k in (1..400).rev() {
            f = x + (k as f64 / 2.0) / f;
        }
        1.0 - (-x * x).exp() / (std::f64::consts::PI.sqrt() * f)
    }
}

/// μ times the self-mobility M_aa(0) of a force spread with an anisotropic Gaussian of
/// widths `sigma` and sampled at its centre:
///   M_aa = ∫₀^∞ Π_b (4π s_b)^{−1/2} [1 − t/(2 s_a)] dt,  s_b = σ_b²/2 + t
/// (Fourier form of the Stokes Green's function, 1/k² = ∫ e^{−tk²} dt); midpoint rule in
/// ln t over 1e-12..1e8 σ², plus the tail beyond, (4π)^{−3/2} T^{−1/2} (relative error
/// below 1e-8, test `anisotropic_reduces_to_isotropic`).
pub fn anisotropic_self_mobility(sigma: [f64; 3]) -> [f64; 3] {
    let scale = sigma.iter().map(|s| s * s).fold(0.0f64, f64::max);
    let (lo, hi) = ((1e-12 * scale).ln(), (1e8 * scale).ln());
    let n = 4000;
    let h = (hi - lo) / n as f64;
    let mut out = [0.0; 3];
    for k in 0..n {
        let t = (lo + (k as f64 + 0.5) * h).exp();
        let s = sigma.map(|x| 0.5 * x * x + t);
        let phi = 1.0 / (4.0 * std::f64::consts::PI).powf(1.5) / (s[0] * s[1] * s[2]).sqrt();
        for a in 0..3 {
            out[a] += phi * (1.0 - t / (2.0 * s[a])) * t * h;
        }
    }
    let tail = 1.0 / (4.0 * std::f64::consts::PI).powf(1.5) / hi.exp().sqrt();
    out.map(|x| x + tail)
}

/// Gaussian widths (wall units) at wall-normal position `y_outer` of a grid, and the
/// factors that scale the isotropic kernel of their geometric mean to the anisotropic
/// self-mobility: one entry per grid row, looked up by the nearest row.
#[derive(Debug, Clone)]
pub struct Widths {
    rows_y: Vec<f64>,
    /// (σ_iso, per-component scale) per row.
    rows: Vec<(f64, [f64; 3])>,
}

impl Widths {
    pub fn new(g: &Grid, re_tau: f64) -> Self {
        let mut rows_y = Vec::with_capacity(g.ny);
        let mut rows = Vec::with_capacity(g.ny);
        for j in 1..=g.ny {
            let d = [g.dx, g.dyf[j], g.dz].map(|x| x * re_tau);
            let sigma = d.map(|x| (KERNEL_VARIANCE * x * x).sqrt());
            let iso = (sigma[0] * sigma[1] * sigma[2]).cbrt();
            let m0 = stokeslet([0.0; 3], iso)[0];
            let an = anisotropic_self_mobility(sigma);
            rows_y.push(g.yc[j]);
            rows.push((iso, an.map(|x| x / m0)));
        }
        Self { rows_y, rows }
    }

    fn at(&self, y_outer: f64) -> (f64, [f64; 3]) {
        let j = self.rows_y.partition_point(|&y| y < y_outer);
        let j = match j {
            0 => 0,
            j if j >= self.rows_y.len() => self.rows_y.len() - 1,
            j if y_outer - self.rows_y[j - 1] < self.rows_y[j] - y_outer => j - 1,
            j => j,
        };
        self.rows[j]
    }
}

/// Adds each segment's own fibre's disturbance back to its sampled velocity (see the
/// module's documentation): `centre` and `force` (F^h) in wall units, 3 per segment,
/// `velocity` the samples (3 per segment), `viscosity` μ in wall units (1).
pub fn correct(
    widths: &Widths,
    re_tau: f64,
    segments_per_fiber: &[u32],
    centre: &[f64],
    force: &[f64],
    velocity: &mut [f64],
) {
    let mut first = 0usize;
    for &n in segments_per_fiber {
        let n = n as usize;
        for i in first..first + n {
            let ri = &centre[3 * i..3 * i + 3];
            let mut du = [0.0; 3];
            for j in first..first + n {
                let rj = &centre[3 * j..3 * j + 3];
                let (sigma, scale) = widths.at(rj[1] / re_tau);
                let m = stokeslet([ri[0] - rj[0], ri[1] - rj[1], ri[2] - rj[2]], sigma);
                let f = &force[3 * j..3 * j + 3];
                for a in 0..3 {
                    for b in 0..3 {
                        du[a] += (scale[a] * scale[b]).sqrt() * m[3 * a + b] * f[b];
                    }
                }
            }
            for a in 0..3 {
                velocity[3 * i + a] += du[a];
            }
        }
        first += n;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// erf against tabulated values (1e-14).
    #[test]
    fn erf_values() {
        for (x, want) in [
            (0.1, 0.112_462_916_018_284_9),
            (1.0, 0.842_700_792_949_714_9),
            (2.4, 0.999_311_486_103_355),
            (2.6, 0.999_763_965_583_470_7),
            (4.0, 0.999_999_984_582_742_1),
        ] {
            assert!((libm_erf(x) - want).abs() < 1e-13, "erf({x}) = {}", libm_erf(x));
        }
    }

    /// Far away the regularised Stokeslet is the Oseen tensor (I + r̂r̂)/(8πr) plus the
    /// blob's second-moment term σ²(I − 3r̂r̂)/(8πr³) (1e-9 relative at r = 12σ, where the
    /// rest is e^{−72}); at r = 0 it is 1/(3√2 π^{3/2} σ) (1e-12), and continuous there.
    #[test]
    fn stokeslet_limits() {
        let sigma = 2.0;
        let r = [10.0, -15.0, 12.0];
        let rr: f64 = r.iter().map(|x| x * x).sum::<f64>().sqrt();
        let m = stokeslet(r, sigma);
        for i in 0..3 {
            for j in 0..3 {
                let d = if i == j { 1.0 } else { 0.0 };
                let u = r[i] * r[j] / (rr * rr);
                let o = (d + u) / (8.0 * std::f64::consts::PI * rr)
                    + sigma * sigma * (d - 3.0 * u) / (8.0 * std::f64::consts::PI * rr.powi(3));
                assert!((m[3 * i + j] - o).abs() < 1e-9 * o.abs().max(1e-3 / rr), "{i}{j}");
            }
        }
        let m0 = stokeslet([0.0; 3], sigma);
        let want = 1.0 / (3.0 * 2f64.sqrt() * std::f64::consts::PI.powf(1.5) * sigma);
        assert!((m0[0] - want).abs() < 1e-12 * want && m0[1] == 0.0);
        let near = stokeslet([1e-3 * sigma, 0.0, 0.0], sigma);
        assert!((near[0] - want).abs() < 1e-6 * want);
    }

    /// The anisotropic self-mobility of equal widths is the isotropic one (1e-8), and a
    /// wider direction moves less along... every direction (it spreads the force further).
    #[test]
    fn anisotropic_reduces_to_isotropic() {
        let m = anisotropic_self_mobility([3.0; 3]);
        let want = stokeslet([0.0; 3], 3.0)[0];
        for x in m {
            assert!((x / want - 1.0).abs() < 1e-8, "{x} vs {want}");
        }
        let w = anisotropic_self_mobility([6.0, 3.0, 3.0]);
        assert!(w.iter().all(|&x| x < want));
    }
}
