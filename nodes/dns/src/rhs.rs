//! Explicit right-hand side of the momentum equations (paper eq. 13): energy-conserving
//! second-order central convection in divergence form on the staggered grid, plus the
//! viscous terms that are not treated implicitly.

use crate::field::Velocity;
use crate::grid::Grid;

/// Computes the explicit terms for one interior k-plane (`k` in 1..=nz) into the plane
/// slices `ru`, `rv`, `rw` (each `px*py` long). With `implicit_y`, y-diffusion is left out.
pub fn plane_rhs(
    g: &Grid,
    vel: &Velocity,
    nu: f64,
    implicit_y: bool,
    k: usize,
    ru: &mut [f64],
    rv: &mut [f64],
    rw: &mut [f64],
) {
    let (px, nx, ny) = (g.px, g.nx, g.ny);
    let plane = g.plane();
    let (u, v, w) = (&vel.u, &vel.v, &vel.w);
    let dxi = 1.0 / g.dx;
    let dzi = 1.0 / g.dz;
    let dxi2 = dxi * dxi;
    let dzi2 = dzi * dzi;
    let y_visc = if implicit_y { 0.0 } else { 1.0 };
    let c = k * plane;
    for j in 1..=ny {
        let dyfi = 1.0 / g.dyf[j];
        let dycp = 1.0 / g.dyc[j];
        let dycm = 1.0 / g.dyc[j - 1];
        let row = c + j * px;
        let (jp, jm, kp, km) = (px, px, plane, plane);
        for i in 1..=nx {
            let n = row + i;
            let lo = j * px + i;
            // ---- u at (i+1/2, j, k)
            let u0 = u[n];
            let uuip = 0.25 * (u[n + 1] + u0) * (u[n + 1] + u0);
            let uuim = 0.25 * (u0 + u[n - 1]) * (u0 + u[n - 1]);
            let uvjp = 0.25 * (u[n + jp] + u0) * (v[n + 1] + v[n]);
            let uvjm = 0.25 * (u0 + u[n - jm]) * (v[n + 1 - jm] + v[n - jm]);
            let uwkp = 0.25 * (u[n + kp] + u0) * (w[n + 1] + w[n]);
            let uwkm = 0.25 * (u0 + u[n - km]) * (w[n + 1 - km] + w[n - km]);
            let conv_u = (uuip - uuim) * dxi + (uvjp - uvjm) * dyfi + (uwkp - uwkm) * dzi;
            let diff_u = (u[n + 1] - 2.0 * u0 + u[n - 1]) * dxi2
                + (u[n + kp] - 2.0 * u0 + u[n - km]) * dzi2
                + y_visc * ((u[n + jp] - u0) * dycp - (u0 - u[n - jm]) * dycm) * dyfi;
            ru[lo] = nu * diff_u - conv_u;
            // ---- w at (i, j, k+1/2)
            let w0 = w[n];
            let uwip = 0.25 * (w[n + 1] + w0) * (u[n + kp] + u[n]);
            let uwim = 0.25 * (w0 + w[n - 1]) * (u[n + kp - 1] + u[n - 1]);
            let vwjp = 0.25 * (w[n + jp] + w0) * (v[n + kp] + v[n]);
            let vwjm = 0.25 * (w0 + w[n - jm]) * (v[n + kp - jm] + v[n - jm]);
            let wwkp = 0.25 * (w[n + kp] + w0) * (w[n + kp] + w0);
            let wwkm = 0.25 * (w0 + w[n - km]) * (w0 + w[n - km]);
            let conv_w = (uwip - uwim) * dxi + (vwjp - vwjm) * dyfi + (wwkp - wwkm) * dzi;
            let diff_w = (w[n + 1] - 2.0 * w0 + w[n - 1]) * dxi2
                + (w[n + kp] - 2.0 * w0 + w[n - km]) * dzi2
                + y_visc * ((w[n + jp] - w0) * dycp - (w0 - w[n - jm]) * dycm) * dyfi;
            rw[lo] = nu * diff_w - conv_w;
        }
        if j < ny {
            // ---- v at (i, j+1/2 face j, k): interior faces 1..ny-1
            let dyci = 1.0 / g.dyc[j];
            let dyfp = 1.0 / g.dyf[j + 1];
            let dyfm = 1.0 / g.dyf[j];
            for i in 1..=nx {
                let n = row + i;
                let lo = j * px + i;
                let v0 = v[n];
                let uvip = 0.25 * (v[n + 1] + v0) * (u[n + jp] + u[n]);
                let uvim = 0.25 * (v0 + v[n - 1]) * (u[n + jp - 1] + u[n - 1]);
                let vvjp = 0.25 * (v[n + jp] + v0) * (v[n + jp] + v0);
                let vvjm = 0.25 * (v0 + v[n - jm]) * (v0 + v[n - jm]);
                let vwkp = 0.25 * (v[n + kp] + v0) * (w[n + jp] + w[n]);
                let vwkm = 0.25 * (v0 + v[n - km]) * (w[n + jp - km] + w[n - km]);
                let conv_v = (uvip - uvim) * dxi + (vvjp - vvjm) * dyci + (vwkp - vwkm) * dzi;
                let diff_v = (v[n + 1] - 2.0 * v0 + v[n - 1]) * dxi2
                    + (v[n + kp] - 2.0 * v0 + v[n - km]) * dzi2
                    + y_visc * ((v[n + jp] - v0) * dyfp - (v0 - v[n - jm]) * dyfm) * dyci;
                rv[lo] = nu * diff_v - conv_v;
            }
        } else {
            for i in 1..=nx {
                rv[j * px + i] = 0.0;
            }
        }
    }
}

/// Applies ν ∂²/∂y² to a cell-centred-in-y tangential field on one k-plane,
/// adding `scale * ν Lyy f` to `out` (plane-local indices).
pub fn add_lyy_tangential(g: &Grid, f: &[f64], k: usize, scale: f64, out: &mut [f64]) {
    let (px, nx, ny) = (g.px, g.nx, g.ny);
    let c = k * g.plane();
    for j in 1..=ny {
        let a = scale / (g.dyc[j - 1] * g.dyf[j]);
        let b = scale / (g.dyc[j] * g.dyf[j]);
        for i in 1..=nx {
            let n = c + j * px + i;
            out[j * px + i] += a * (f[n - px] - f[n]) + b * (f[n + px] - f[n]);
        }
    }
}

/// Applies `scale * ∂²/∂y²` to v (faces) on one k-plane, adding into `out`.
pub fn add_lyy_normal(g: &Grid, f: &[f64], k: usize, scale: f64, out: &mut [f64]) {
    let (px, nx, ny) = (g.px, g.nx, g.ny);
    let c = k * g.plane();
    for j in 1..ny {
        let a = scale / (g.dyf[j] * g.dyc[j]);
        let b = scale / (g.dyf[j + 1] * g.dyc[j]);
        for i in 1..=nx {
            let n = c + j * px + i;
            out[j * px + i] += a * (f[n - px] - f[n]) + b * (f[n + px] - f[n]);
        }
    }
}
