//! Explicit right-hand side of the momentum equations (paper eq. 13): energy-conserving
//! second-order central convection in divergence form on the staggered grid, plus the
//! viscous terms that are not treated implicitly.

use crate::field::Velocity;
use crate::grid::Grid;

/// Computes the explicit terms for one interior k-plane (`k` in 1..=nz) into the plane
/// slices `ru`, `rv`, `rw` (each `px*py` long). With `implicit_y`, y-diffusion is left out.
/// On x86-64 CPUs with AVX2 the same code is run compiled for AVX2 (the arithmetic is the
/// same, no fused multiply-adds, so results are bitwise identical either way).
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
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the running CPU supports AVX2 (checked just above).
            unsafe { plane_rhs_avx2(g, vel, nu, implicit_y, k, ru, rv, rw) };
            return;
        }
    }
    plane_rhs_body(g, vel, nu, implicit_y, k, ru, rv, rw);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn plane_rhs_avx2(
    g: &Grid,
    vel: &Velocity,
    nu: f64,
    implicit_y: bool,
    k: usize,
    ru: &mut [f64],
    rv: &mut [f64],
    rw: &mut [f64],
) {
    plane_rhs_body(g, vel, nu, implicit_y, k, ru, rv, rw);
}

/// Long (≈120 lines) on purpose: one fused pass over a plane computing every term of the
/// momentum right-hand side; split, each term would read the plane again.
#[inline(always)]
fn plane_rhs_body(
    g: &Grid,
    vel: &Velocity,
    nu: f64,
    implicit_y: bool,
    k: usize,
    ru: &mut [f64],
    rv: &mut [f64],
    rw: &mut [f64],
) {
    // rows are `px = nx + 2` long; looping over 1..px-1 (= 1..=nx) lets the compiler
    // prove every i±1 access in bounds and vectorise
    let (px, nx, ny) = (g.px, g.nx, g.ny);
    let plane = g.plane();
    let (u, v, w) = (&vel.u, &vel.v, &vel.w);
    let dxi = 1.0 / g.dx;
    let dzi = 1.0 / g.dz;
    let dxi2 = dxi * dxi;
    let dzi2 = dzi * dzi;
    let y_visc = if implicit_y { 0.0 } else { 1.0 };
    let c = k * plane;
    // a padded row of one field at (j, k) shifted by `dj` rows and `dk` planes; whole-row
    // slices let the compiler drop bounds checks and vectorise the i loops
    #[inline(always)]
    fn shifted(f: &[f64], start: usize, px: usize, plane: usize, dj: isize, dk: isize) -> &[f64] {
        let s = (start as isize + dj * px as isize + dk * plane as isize) as usize;
        &f[s..s + px]
    }
    for j in 1..=ny {
        let dyfi = 1.0 / g.dyf[j];
        let dycp = 1.0 / g.dyc[j];
        let dycm = 1.0 / g.dyc[j - 1];
        let (uc, un, us, uf, ub) = (
            shifted(u, c + j * px, px, plane, 0, 0),
            shifted(u, c + j * px, px, plane, 1, 0),
            shifted(u, c + j * px, px, plane, -1, 0),
            shifted(u, c + j * px, px, plane, 0, 1),
            shifted(u, c + j * px, px, plane, 0, -1),
        );
        let (vc, vs, vf, vsf) = (
            shifted(v, c + j * px, px, plane, 0, 0),
            shifted(v, c + j * px, px, plane, -1, 0),
            shifted(v, c + j * px, px, plane, 0, 1),
            shifted(v, c + j * px, px, plane, -1, 1),
        );
        let (wc, wn, ws, wf, wb) = (
            shifted(w, c + j * px, px, plane, 0, 0),
            shifted(w, c + j * px, px, plane, 1, 0),
            shifted(w, c + j * px, px, plane, -1, 0),
            shifted(w, c + j * px, px, plane, 0, 1),
            shifted(w, c + j * px, px, plane, 0, -1),
        );
        let ru_row = &mut ru[j * px..(j + 1) * px];
        let rw_row = &mut rw[j * px..(j + 1) * px];
        for i in 1..px - 1 {
            // ---- u at (i+1/2, j, k)
            let u0 = uc[i];
            let uuip = 0.25 * (uc[i + 1] + u0) * (uc[i + 1] + u0);
            let uuim = 0.25 * (u0 + uc[i - 1]) * (u0 + uc[i - 1]);
            let uvjp = 0.25 * (un[i] + u0) * (vc[i + 1] + vc[i]);
            let uvjm = 0.25 * (u0 + us[i]) * (vs[i + 1] + vs[i]);
            let uwkp = 0.25 * (uf[i] + u0) * (wc[i + 1] + wc[i]);
            let uwkm = 0.25 * (u0 + ub[i]) * (wb[i + 1] + wb[i]);
            let conv_u = (uuip - uuim) * dxi + (uvjp - uvjm) * dyfi + (uwkp - uwkm) * dzi;
            let diff_u = (uc[i + 1] - 2.0 * u0 + uc[i - 1]) * dxi2
                + (uf[i] - 2.0 * u0 + ub[i]) * dzi2
                + y_visc * ((un[i] - u0) * dycp - (u0 - us[i]) * dycm) * dyfi;
            ru_row[i] = nu * diff_u - conv_u;
            // ---- w at (i, j, k+1/2)
            let w0 = wc[i];
            let uwip = 0.25 * (wc[i + 1] + w0) * (uf[i] + uc[i]);
            let uwim = 0.25 * (w0 + wc[i - 1]) * (uf[i - 1] + uc[i - 1]);
            let vwjp = 0.25 * (wn[i] + w0) * (vf[i] + vc[i]);
            let vwjm = 0.25 * (w0 + ws[i]) * (vsf[i] + vs[i]);
            let wwkp = 0.25 * (wf[i] + w0) * (wf[i] + w0);
            let wwkm = 0.25 * (w0 + wb[i]) * (w0 + wb[i]);
            let conv_w = (uwip - uwim) * dxi + (vwjp - vwjm) * dyfi + (wwkp - wwkm) * dzi;
            let diff_w = (wc[i + 1] - 2.0 * w0 + wc[i - 1]) * dxi2
                + (wf[i] - 2.0 * w0 + wb[i]) * dzi2
                + y_visc * ((wn[i] - w0) * dycp - (w0 - ws[i]) * dycm) * dyfi;
            rw_row[i] = nu * diff_w - conv_w;
        }
        let rv_row = &mut rv[j * px..(j + 1) * px];
        if j < ny {
            // ---- v at (i, j+1/2 face j, k): interior faces 1..ny-1
            let dyci = 1.0 / g.dyc[j];
            let dyfp = 1.0 / g.dyf[j + 1];
            let dyfm = 1.0 / g.dyf[j];
            let (vn, vb) = (
                shifted(v, c + j * px, px, plane, 1, 0),
                shifted(v, c + j * px, px, plane, 0, -1),
            );
            let wnb = shifted(w, c + j * px, px, plane, 1, -1);
            // The v control volume is the upper half of cell j plus the lower half of
            // cell j+1, so the mass flux through its x and z faces weights u and w by the
            // half-cell heights; a plain average would make convection produce energy on a
            // stretched grid (symmetry-preserving form, see the energy test).
            let wt_lo = 0.5 * g.dyf[j] / (0.5 * (g.dyf[j] + g.dyf[j + 1]));
            let wt_hi = 0.5 * g.dyf[j + 1] / (0.5 * (g.dyf[j] + g.dyf[j + 1]));
            for i in 1..px - 1 {
                let v0 = vc[i];
                let uvip = 0.5 * (vc[i + 1] + v0) * (wt_hi * un[i] + wt_lo * uc[i]);
                let uvim = 0.5 * (v0 + vc[i - 1]) * (wt_hi * un[i - 1] + wt_lo * uc[i - 1]);
                let vvjp = 0.25 * (vn[i] + v0) * (vn[i] + v0);
                let vvjm = 0.25 * (v0 + vs[i]) * (v0 + vs[i]);
                let vwkp = 0.5 * (vf[i] + v0) * (wt_hi * wn[i] + wt_lo * wc[i]);
                let vwkm = 0.5 * (v0 + vb[i]) * (wt_hi * wnb[i] + wt_lo * wb[i]);
                let conv_v = (uvip - uvim) * dxi + (vvjp - vvjm) * dyci + (vwkp - vwkm) * dzi;
                let diff_v = (vc[i + 1] - 2.0 * v0 + vc[i - 1]) * dxi2
                    + (vf[i] - 2.0 * v0 + vb[i]) * dzi2
                    + y_visc * ((vn[i] - v0) * dyfp - (v0 - vs[i]) * dyfm) * dyci;
                rv_row[i] = nu * diff_v - conv_v;
            }
        } else {
            rv_row[1..=nx].iter_mut().for_each(|x| *x = 0.0);
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
