//! Projection: divergence of the predicted velocity and its pressure correction
//! (fractional step, paper eq. 14 enforced to round-off).

use crate::field::Velocity;
use crate::grid::Grid;
use rayon::prelude::*;

/// Writes `div(u) * scale` into the padded cell-centred array `out` (interior only).
pub fn divergence(g: &Grid, vel: &Velocity, scale: f64, out: &mut [f64]) {
    let (px, nx, ny) = (g.px, g.nx, g.ny);
    let plane = g.plane();
    out.par_chunks_mut(plane)
        .enumerate()
        .filter(|(k, _)| *k >= 1 && *k <= g.nz)
        .for_each(|(k, p)| {
            for j in 1..=ny {
                divergence_row(g, vel, scale, k, j, &mut p[j * px + 1..j * px + 1 + nx]);
            }
        });
}

/// `div(u) * scale` along interior row (j, k) (padded indices) into `out` (nx values).
#[inline]
pub fn divergence_row(g: &Grid, vel: &Velocity, scale: f64, k: usize, j: usize, out: &mut [f64]) {
    let (px, nx, plane) = (g.px, g.nx, g.plane());
    let dxi = 1.0 / g.dx;
    let dzi = 1.0 / g.dz;
    let dyfi = 1.0 / g.dyf[j];
    let n0 = k * plane + j * px;
    // u from i-1..=nx, the others from 1..=nx: whole-row slices, no index arithmetic
    let u = &vel.u[n0..n0 + nx + 1];
    let v = &vel.v[n0 + 1..n0 + 1 + nx];
    let vs = &vel.v[n0 - px + 1..n0 - px + 1 + nx];
    let w = &vel.w[n0 + 1..n0 + 1 + nx];
    let wb = &vel.w[n0 - plane + 1..n0 - plane + 1 + nx];
    for (i, o) in out[..nx].iter_mut().enumerate() {
        let d = (u[i + 1] - u[i]) * dxi + (v[i] - vs[i]) * dyfi + (w[i] - wb[i]) * dzi;
        *o = d * scale;
    }
}

/// Largest |div u| over interior cells.
pub fn max_divergence(g: &Grid, vel: &Velocity) -> f64 {
    let (px, nx, ny) = (g.px, g.nx, g.ny);
    let plane = g.plane();
    (1..=g.nz)
        .into_par_iter()
        .map(|k| {
            let c = k * plane;
            let mut m: f64 = 0.0;
            for j in 1..=ny {
                for i in 1..=nx {
                    let n = c + j * px + i;
                    let d = (vel.u[n] - vel.u[n - 1]) / g.dx
                        + (vel.v[n] - vel.v[n - px]) / g.dyf[j]
                        + (vel.w[n] - vel.w[n - plane]) / g.dz;
                    m = m.max(d.abs());
                }
            }
            m
        })
        .reduce(|| 0.0, f64::max)
}

/// Subtracts `scale * grad(phi)` from the velocity (interior points; halo of phi must be
/// current).
pub fn project(g: &Grid, vel: &mut Velocity, phi: &[f64], scale: f64) {
    let (px, nx, ny) = (g.px, g.nx, g.ny);
    let plane = g.plane();
    let sx = scale / g.dx;
    let sz = scale / g.dz;
    let Velocity { u, v, w } = vel;
    u.par_chunks_mut(plane)
        .zip(v.par_chunks_mut(plane))
        .zip(w.par_chunks_mut(plane))
        .enumerate()
        .filter(|(k, _)| *k >= 1 && *k <= g.nz)
        .for_each(|(k, ((pu, pv), pw))| {
            let c = k * plane;
            for j in 1..=ny {
                let sy = scale / g.dyc[j];
                let (l, n) = (j * px + 1, c + j * px + 1);
                let p = &phi[n..n + nx + 1];
                let pn = &phi[n + px..n + px + nx];
                let pf = &phi[n + plane..n + plane + nx];
                for ((i, x), pi) in pu[l..l + nx].iter_mut().enumerate().zip(&p[..nx]) {
                    *x -= sx * (p[i + 1] - pi);
                }
                for ((x, pi), f) in pw[l..l + nx].iter_mut().zip(&p[..nx]).zip(pf) {
                    *x -= sz * (f - pi);
                }
                if j < ny {
                    for ((x, pi), q) in pv[l..l + nx].iter_mut().zip(&p[..nx]).zip(pn) {
                        *x -= sy * (q - pi);
                    }
                }
            }
        });
}
