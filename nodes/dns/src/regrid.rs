//! Restart on a different grid: a checkpoint's velocity is interpolated (tricubic, see
//! [`crate::sample`]) onto the staggered nodes of another grid over the same box, then
//! projected to be divergence-free by the caller. Used to move a developed field to a
//! finer or differently stretched grid without a new spin-up from scratch.

use crate::checkpoint::{self, CheckpointHeader};
use crate::error::DnsError;
use crate::field::Velocity;
use crate::grid::Grid;
use crate::sample::{Interpolation, Sampler};
use rayon::prelude::*;
use std::path::Path;

/// The grid a checkpoint was written on (tanh stretching recovered from its first width).
pub fn source_grid(h: &CheckpointHeader) -> Result<Grid, DnsError> {
    let y1_plus = 0.5 * h.dy_first * h.re_tau;
    Grid::new(h.nx, h.ny, h.nz, h.lx, h.lz, h.re_tau, Some(y1_plus))
}

/// Reads a checkpoint written on any grid over the same box and interpolates its velocity
/// onto `dst` (halos refreshed; not yet projected).
pub fn read_onto(path: &Path, dst: &Grid) -> Result<(Velocity, CheckpointHeader), DnsError> {
    let bytes = std::fs::read(path).map_err(|source| DnsError::Io {
        path: path.display().to_string(),
        source,
    })?;
    let err = |reason: String| DnsError::Checkpoint {
        path: path.display().to_string(),
        reason,
    };
    let h = checkpoint::read_header(&bytes)
        .ok_or_else(|| err("not a fiberflow DNS checkpoint".into()))?;
    if (h.lx - dst.lx).abs() > 1e-12 || (h.lz - dst.lz).abs() > 1e-12 {
        return Err(err(format!(
            "box {}h x {}h differs from the configured {}h x {}h; regridding keeps the box",
            h.lx, h.lz, dst.lx, dst.lz
        )));
    }
    let src = source_grid(&h)?;
    let mut src_vel = Velocity::zeros(&src);
    checkpoint::read(path, &src, &mut src_vel)?;
    src_vel.update_halos(&src);
    Ok((interpolate(&src, &src_vel, dst), h))
}

/// Tricubic interpolation of a velocity field onto another grid's staggered nodes.
pub fn interpolate(src: &Grid, vel: &Velocity, dst: &Grid) -> Velocity {
    let smp = Sampler::with_scheme(src, Interpolation::Tricubic);
    let mut out = Velocity::zeros(dst);
    let plane = dst.plane();
    let Velocity { u, v, w } = &mut out;
    u.par_chunks_mut(plane)
        .zip(v.par_chunks_mut(plane))
        .zip(w.par_chunks_mut(plane))
        .enumerate()
        .filter(|(k, _)| *k >= 1 && *k <= dst.nz)
        .for_each(|(k, ((pu, pv), pw))| {
            let (zc, zf) = ((k as f64 - 0.5) * dst.dz, k as f64 * dst.dz);
            for j in 1..=dst.ny {
                for i in 1..=dst.nx {
                    let (xc, xf) = ((i as f64 - 0.5) * dst.dx, i as f64 * dst.dx);
                    let l = j * dst.px + i;
                    pu[l] = smp.sample(src, vel, [xf, dst.yc[j], zc]).vel[0];
                    pw[l] = smp.sample(src, vel, [xc, dst.yc[j], zf]).vel[2];
                    pv[l] = if j < dst.ny {
                        smp.sample(src, vel, [xc, dst.yf[j], zc]).vel[1]
                    } else {
                        0.0
                    };
                }
            }
        });
    out.update_halos(dst);
    out
}
