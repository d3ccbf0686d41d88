//! Projection: divergence of the predicted velocity and its pressure correction
//! (fractional step, paper eq. 14 enforced to round-off).

use crate::field::Velocity;
use crate::grid::Grid;
use rayon::prelude::*;

/// Writes `div(u) * scale` into the padded cell-centred array `out` (interior only).
pub fn divergence(g: &Grid, vel: &Velocity, scale: f64, out: &mut [f64]) {
    let (px, nx, ny) = (g.px, g.nx, g.ny);
    let plane = g.plane();
    let dxi = 1.0 / g.dx;
    let dzi = 1.0 / g.dz;
    out.par_chunks_mut(plane)
        .enumerate()
        .filter(|(k, _)| *k >= 1 && *k <= g.nz)
        .for_each(|(k, p)| {
            let c = k * plane;
            for j in 1..=ny {
                let dyfi = 1.0 / g.dyf[j];
                for i in 1..=nx {
                    let n = c + j * px + i;
                    let d = (vel.u[n] - vel.u[n - 1]) * dxi
                        + (vel.v[n] - vel.v[n - px]) * dyfi
                        + (vel.w[n] - vel.w[n - plane]) * dzi;
                    p[j * px + i] = d * scale;
                }
            }
        });
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
                for i in 1..=nx {
                    let l = j * px + i;
                    let n = c + l;
                    pu[l] -= sx * (phi[n + 1] - phi[n]);
                    pw[l] -= sz * (phi[n + plane] - phi[n]);
                    if j < ny {
                        pv[l] -= sy * (phi[n + px] - phi[n]);
                    }
                }
            }
        });
}
