//! [`Tables::sample4`] with AVX2: four points, one per vector lane. Every lane runs the
//! one-point path's floating-point operations in its order (the periodic brackets, then
//! `acc += (wx * wy * wz) * x` over the corners from +0), and no fused multiply-add is
//! enabled, so each point gets the bits of [`Tables::sample`]
//! (test `four_at_once_sample_like_one_at_a_time`). The y brackets (a table lookup and a
//! short search per node list) stay scalar, lane by lane.

use super::{Tables, LANES};
use crate::grid::Grid;
use crate::sample::{Hx, Nodes, Sample, Sampler, LOCATION};
use std::arch::x86_64::*;

/// Four points' brackets: per location kind, the lower node of each lane and the lanes'
/// fractions (x and z by [`Hx`], y by node list).
struct Brackets4 {
    xi: [[usize; LANES]; 2],
    xf: [__m256d; 2],
    zi: [[usize; LANES]; 2],
    zf: [__m256d; 2],
    yi: [[usize; LANES]; 3],
    yf: [__m256d; 3],
}

/// Velocity and gradient at four points (outer units), each bit for bit
/// [`Tables::sample`].
///
/// # Safety
/// The CPU must support AVX2.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn sample4(
    t: &Tables,
    smp: &Sampler,
    g: &Grid,
    p: [[f64; 3]; LANES],
) -> [Sample; LANES] {
    let Some(b) = brackets4(smp, g, &p) else {
        // a point outside the periodic fast path (beyond one box length)
        return p.map(|q| t.sample(smp, g, q));
    };
    let d = &t.data;
    let [u] = interp4::<1>(t, &d[0], &b, 0);
    let [v] = interp4::<1>(t, &d[1], &b, 1);
    let [w] = interp4::<1>(t, &d[2], &b, 2);
    let [g0, g4, g8] = interp4::<3>(t, &d[3], &b, 3);
    let [g1] = interp4::<1>(t, &d[4], &b, 4);
    let [g2, g6] = interp4::<2>(t, &d[5], &b, 5);
    let [g3] = interp4::<1>(t, &d[6], &b, 6);
    let [g5] = interp4::<1>(t, &d[7], &b, 8);
    let [g7] = interp4::<1>(t, &d[8], &b, 10);
    let mut q = [[0.0; LANES]; 12];
    for (slot, x) in q
        .iter_mut()
        .zip([u, v, w, g0, g1, g2, g3, g4, g5, g6, g7, g8])
    {
        // SAFETY: `slot` holds four f64.
        unsafe { _mm256_storeu_pd(slot.as_mut_ptr(), x) };
    }
    let sample = |l: usize| Sample {
        vel: [q[0][l], q[1][l], q[2][l]],
        grad: [
            q[3][l], q[4][l], q[5][l], q[6][l], q[7][l], q[8][l], q[9][l], q[10][l], q[11][l],
        ],
    };
    [sample(0), sample(1), sample(2), sample(3)]
}

/// The brackets of [`Sampler::brackets`] for four points, or `None` when a lane's x or z
/// is outside [-l, 2l) (where the one-point path calls `rem_euclid`).
#[target_feature(enable = "avx2")]
unsafe fn brackets4(smp: &Sampler, g: &Grid, p: &[[f64; 3]; LANES]) -> Option<Brackets4> {
    let x = _mm256_setr_pd(p[0][0], p[1][0], p[2][0], p[3][0]);
    let z = _mm256_setr_pd(p[0][2], p[1][2], p[2][2], p[3][2]);
    let [xc, xf] = [Hx::Centre, Hx::Face].map(|h| periodic4(x, g.dx, g.nx, h));
    let [zc, zf] = [Hx::Centre, Hx::Face].map(|h| periodic4(z, g.dz, g.nz, h));
    let (xc, xf, zc, zf) = (xc?, xf?, zc?, zf?);
    let [y0, y1, y2] = &smp.lookup;
    let ((y0, f0), (y1, f1), (y2, f2)) = (y4(y0, p), y4(y1, p), y4(y2, p));
    Some(Brackets4 {
        xi: [xc.0, xf.0],
        xf: [xc.1, xf.1],
        zi: [zc.0, zf.0],
        zf: [zc.1, zf.1],
        yi: [y0, y1, y2],
        yf: [
            _mm256_loadu_pd(f0.as_ptr()),
            _mm256_loadu_pd(f1.as_ptr()),
            _mm256_loadu_pd(f2.as_ptr()),
        ],
    })
}

/// The four points' brackets on one y node list (scalar, lane by lane).
#[inline(always)]
fn y4(nodes: &Nodes, p: &[[f64; 3]; LANES]) -> ([usize; LANES], [f64; LANES]) {
    let b = [
        nodes.bracket(p[0][1]),
        nodes.bracket(p[1][1]),
        nodes.bracket(p[2][1]),
        nodes.bracket(p[3][1]),
    ];
    (
        [b[0].0, b[1].0, b[2].0, b[3].0],
        [b[0].1, b[1].1, b[2].1, b[3].1],
    )
}

/// `periodic_bracket` lane by lane, for x in [-l, 2l) (`None` otherwise): the same
/// remainder (`rem_euclid_fast`'s three exact cases), division, floor, wrap and clamp.
#[target_feature(enable = "avx2")]
unsafe fn periodic4(x: __m256d, d: f64, n: usize, h: Hx) -> Option<([usize; LANES], __m256d)> {
    let l = d * n as f64;
    let (lv, zero) = (_mm256_set1_pd(l), _mm256_setzero_pd());
    let inside = _mm256_and_pd(
        _mm256_cmp_pd::<_CMP_GE_OQ>(x, zero),
        _mm256_cmp_pd::<_CMP_LT_OQ>(x, lv),
    );
    let below = _mm256_and_pd(
        _mm256_cmp_pd::<_CMP_LT_OQ>(x, zero),
        _mm256_cmp_pd::<_CMP_GT_OQ>(x, _mm256_set1_pd(-l)),
    );
    let above = _mm256_and_pd(
        _mm256_cmp_pd::<_CMP_GE_OQ>(x, lv),
        _mm256_cmp_pd::<_CMP_LT_OQ>(x, _mm256_set1_pd(2.0 * l)),
    );
    if _mm256_movemask_pd(_mm256_or_pd(_mm256_or_pd(inside, below), above)) != 0b1111 {
        return None;
    }
    let r = _mm256_blendv_pd(x, _mm256_add_pd(x, lv), below);
    let r = _mm256_blendv_pd(r, _mm256_sub_pd(x, lv), above);
    let shift = match h {
        Hx::Centre => 0.5,
        Hx::Face => 0.0,
    };
    let s = _mm256_add_pd(_mm256_div_pd(r, _mm256_set1_pd(d)), _mm256_set1_pd(shift));
    let m = _mm256_floor_pd(s);
    let f = _mm256_sub_pd(s, m);
    let nv = _mm256_set1_pd(n as f64);
    let one = _mm256_set1_pd(1.0);
    let m = _mm256_blendv_pd(m, _mm256_add_pd(m, nv), _mm256_cmp_pd::<_CMP_LT_OQ>(m, one));
    let m = _mm256_blendv_pd(m, _mm256_sub_pd(m, nv), _mm256_cmp_pd::<_CMP_GT_OQ>(m, nv));
    // finite here, so the clamp is two ordered selects
    let f = _mm256_blendv_pd(f, zero, _mm256_cmp_pd::<_CMP_LT_OQ>(f, zero));
    let f = _mm256_blendv_pd(f, one, _mm256_cmp_pd::<_CMP_GT_OQ>(f, one));
    let mut idx = [0i32; LANES];
    // SAFETY: `idx` holds four i32; m is a whole number in 0..=n.
    unsafe { _mm_storeu_si128(idx.as_mut_ptr().cast(), _mm256_cvttpd_epi32(m)) };
    Some((idx.map(|i| i as usize), f))
}

/// [`Tables::interp`] at four points, one per lane.
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn interp4<const W: usize>(
    t: &Tables,
    data: &[f64],
    b: &Brackets4,
    q: usize,
) -> [__m256d; W] {
    let (hx, vy, hz) = LOCATION[q];
    let (hx, vy, hz) = (hx as usize, vy as usize, hz as usize);
    let (fx, fy, fz) = (b.xf[hx], b.yf[vy], b.zf[hz]);
    let one = _mm256_set1_pd(1.0);
    let (gx, gy, gz) = (
        _mm256_sub_pd(one, fx),
        _mm256_sub_pd(one, fy),
        _mm256_sub_pd(one, fz),
    );
    // each lane's 2 × 2 × 2 nodes lie in one window of the table, checked once
    let win = [
        window::<W>(t, data, b, (hx, vy, hz), 0),
        window::<W>(t, data, b, (hx, vy, hz), 1),
        window::<W>(t, data, b, (hx, vy, hz), 2),
        window::<W>(t, data, b, (hx, vy, hz), 3),
    ];
    let mut acc = [_mm256_setzero_pd(); W];
    for (dj, wy) in [(0, gy), (1, fy)] {
        for (dk, wz) in [(0, gz), (1, fz)] {
            let row = (t.px * dj + t.plane * dk) * W;
            for (n, wx) in [gx, fx].into_iter().enumerate() {
                let wgt = _mm256_mul_pd(_mm256_mul_pd(wx, wy), wz);
                for (m, a) in acc.iter_mut().enumerate() {
                    let c = row + n * W + m;
                    // SAFETY: c <= (px + plane) W + 2W - 1, below each window's length.
                    let x = unsafe {
                        _mm256_setr_pd(
                            *win[0].get_unchecked(c),
                            *win[1].get_unchecked(c),
                            *win[2].get_unchecked(c),
                            *win[3].get_unchecked(c),
                        )
                    };
                    *a = _mm256_add_pd(*a, _mm256_mul_pd(wgt, x));
                }
            }
        }
    }
    acc
}

/// The part of a table that holds lane `l`'s 2 × 2 × 2 nodes of a location
/// `(hx, vy, hz)`: from its lower corner, `(px + plane + 2) W` values.
#[inline(always)]
fn window<'a, const W: usize>(
    t: &Tables,
    data: &'a [f64],
    b: &Brackets4,
    (hx, vy, hz): (usize, usize, usize),
    l: usize,
) -> &'a [f64] {
    let (i0, j0, k0) = (b.xi[hx][l], b.yi[vy][l], b.zi[hz][l]);
    let start = (i0 + t.px * j0 + t.plane * k0) * W;
    &data[start..start + (t.px + t.plane + 2) * W]
}
