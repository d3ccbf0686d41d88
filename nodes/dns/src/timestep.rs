//! Time-step control and health checks: CFL and viscous limits, blow-up detection.

use crate::field::Velocity;
use crate::grid::Grid;
use rayon::prelude::*;

/// RK3 convective stability bound on the Courant sum (Wray's scheme: √3).
pub const RK3_CFL_LIMIT: f64 = 1.732;

/// Maximum over the grid of `|u|/dx + |v|/dy + |w|/dz` (cell-centred velocities).
pub fn max_courant_rate(g: &Grid, vel: &Velocity) -> f64 {
    let (px, nx, ny) = (g.px, g.nx, g.ny);
    let plane = g.plane();
    (1..=g.nz)
        .into_par_iter()
        .map(|k| {
            let c = k * plane;
            let mut m: f64 = 0.0;
            for j in 1..=ny {
                let dyfi = 1.0 / g.dyf[j];
                for i in 1..=nx {
                    let n = c + j * px + i;
                    let uc = 0.5 * (vel.u[n] + vel.u[n - 1]).abs();
                    let vc = 0.5 * (vel.v[n] + vel.v[n - px]).abs();
                    let wc = 0.5 * (vel.w[n] + vel.w[n - plane]).abs();
                    let r = uc / g.dx + vc * dyfi + wc / g.dz;
                    // NaN propagates through max as the other operand; catch it explicitly
                    m = if r.is_nan() { f64::INFINITY } else { m.max(r) };
                }
            }
            m
        })
        .reduce(|| 0.0, f64::max)
}

/// Viscous stability limit of the explicit part of the diffusion for RK3.
pub fn viscous_dt_limit(g: &Grid, nu: f64, implicit_y: bool) -> f64 {
    let dymin = g.dyf[1..=g.ny]
        .iter()
        .cloned()
        .fold(f64::INFINITY, f64::min);
    let mut s = 1.0 / (g.dx * g.dx) + 1.0 / (g.dz * g.dz);
    if !implicit_y {
        s += 1.0 / (dymin * dymin);
    }
    // RK3 stability on the negative real axis extends to 2.51; 4ν s is the spectral radius
    2.51 / (4.0 * nu * s)
}
