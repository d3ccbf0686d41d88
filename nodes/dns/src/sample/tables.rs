//! Per-step tables for sampling many points: the twelve trilinear quantities (u, v, w and
//! the nine staggered differences of the velocity gradient) evaluated once at their own
//! nodes, quantities that share nodes interleaved. A point then reads 8 stored values per
//! quantity instead of forming differences and wall cases at every corner of every point.
//!
//! Each stored value is the very corner expression the direct sampler evaluates
//! ([`Corners::value`]), and the corners are summed in the same order, so a table sample has
//! the same bits as [`Sampler::sample`] (test `tables_sample_like_the_direct_sampler`).
//! Filling costs a pass over the grid, so it pays only when the points are many.

use super::{Brackets, Sample, Sampler, LOCATION};

#[cfg(target_arch = "x86_64")]
mod avx2;
use crate::field::Velocity;
use crate::grid::Grid;
use rayon::prelude::*;

/// Points sampled together by [`Tables::sample4`].
pub const LANES: usize = 4;

/// The tables' node kinds: quantities (index into vel ++ grad) sharing one location.
const KINDS: [&[usize]; 9] = [
    &[0],
    &[1],
    &[2],
    &[3, 7, 11],
    &[4],
    &[5, 9],
    &[6],
    &[8],
    &[10],
];

/// The trilinear quantities of one field at their nodes, over the padded grid (the x and z
/// halos hold the periodic copies of the first interior column and plane).
#[derive(Debug, Clone, Default)]
pub struct Tables {
    /// Per kind, `KINDS[kind].len()` values per padded node, interleaved.
    data: [Vec<f64>; 9],
    px: usize,
    plane: usize,
}

impl Tables {
    /// Empty tables; [`Tables::fill`] sizes them.
    pub fn new() -> Self {
        Self::default()
    }

    /// Evaluates every quantity of `vel` at its nodes (reusing the allocation).
    pub fn fill(&mut self, smp: &Sampler, g: &Grid, vel: &Velocity) {
        let c = smp.corners(g, vel);
        self.px = g.px;
        self.plane = g.plane();
        for (kind, data) in KINDS.iter().zip(self.data.iter_mut()) {
            data.resize(g.padded_len() * kind.len(), 0.0);
        }
        // one pass over the planes for all nine kinds: a plane's inputs (three planes of
        // u, v and w, ≈ 0.9 MB on the fine grid) are read from memory once, not once per
        // kind, and the pool forks once instead of nine times
        let rows: [usize; 9] =
            std::array::from_fn(|kind| smp.nodes(LOCATION[KINDS[kind][0]].1).len());
        let (nx, nz, px) = (g.nx, g.nz, g.px);
        let plane = g.plane();
        let mut kinds: Vec<_> = self
            .data
            .iter_mut()
            .zip(KINDS)
            .map(|(d, q)| d.chunks_mut(plane * q.len()))
            .collect();
        let mut planes: Vec<[&mut [f64]; 9]> = (0..nz + 2)
            .map(|_| std::array::from_fn(|kind| kinds[kind].next().unwrap_or_default()))
            .collect();
        planes
            .par_iter_mut()
            .enumerate()
            .filter(|(k, _)| (1..=nz).contains(k))
            .for_each(|(k, [p0, p1, p2, p3, p4, p5, p6, p7, p8])| {
                fill_rows::<1>(p0, rows[0], nx, px, k, |i, j, k| [c.value::<0>(i, j, k)]);
                fill_rows::<1>(p1, rows[1], nx, px, k, |i, j, k| [c.value::<1>(i, j, k)]);
                fill_rows::<1>(p2, rows[2], nx, px, k, |i, j, k| [c.value::<2>(i, j, k)]);
                fill_rows::<3>(p3, rows[3], nx, px, k, |i, j, k| {
                    [
                        c.value::<3>(i, j, k),
                        c.value::<7>(i, j, k),
                        c.value::<11>(i, j, k),
                    ]
                });
                fill_rows::<1>(p4, rows[4], nx, px, k, |i, j, k| [c.value::<4>(i, j, k)]);
                fill_rows::<2>(p5, rows[5], nx, px, k, |i, j, k| {
                    [c.value::<5>(i, j, k), c.value::<9>(i, j, k)]
                });
                fill_rows::<1>(p6, rows[6], nx, px, k, |i, j, k| [c.value::<6>(i, j, k)]);
                fill_rows::<1>(p7, rows[7], nx, px, k, |i, j, k| [c.value::<8>(i, j, k)]);
                fill_rows::<1>(p8, rows[8], nx, px, k, |i, j, k| [c.value::<10>(i, j, k)]);
            });
        // the periodic halo plane nz + 1: a copy of plane 1
        for (kind, data) in self.data.iter_mut().enumerate() {
            let w = KINDS[kind].len();
            data.copy_within(plane * w..2 * plane * w, (nz + 1) * plane * w);
        }
    }

    /// Velocity and gradient at `p` (outer units), bit for bit [`Sampler::sample`]'s
    /// trilinear answer for the field the tables were filled from.
    /// A point with a non-finite coordinate reads no memory and gives a NaN sample.
    pub fn sample(&self, smp: &Sampler, g: &Grid, p: [f64; 3]) -> Sample {
        if !super::finite_point(p) {
            return Sample::NAN;
        }
        let b = smp.brackets(g, p);
        let d = &self.data;
        let [u] = self.interp::<1>(&d[0], &b, 0);
        let [v] = self.interp::<1>(&d[1], &b, 1);
        let [w] = self.interp::<1>(&d[2], &b, 2);
        let [g0, g4, g8] = self.interp::<3>(&d[3], &b, 3);
        let [g1] = self.interp::<1>(&d[4], &b, 4);
        let [g2, g6] = self.interp::<2>(&d[5], &b, 5);
        let [g3] = self.interp::<1>(&d[6], &b, 6);
        let [g5] = self.interp::<1>(&d[7], &b, 8);
        let [g7] = self.interp::<1>(&d[8], &b, 10);
        Sample {
            vel: [u, v, w],
            grad: [g0, g1, g2, g3, g4, g5, g6, g7, g8],
        }
    }

    /// [`Tables::sample`] at four points at once, the same bits point by point. With AVX2
    /// the interpolation runs one point per vector lane, every lane doing the one-point
    /// path's operations in its order (no fused multiply-add), so no result changes
    /// (test `four_at_once_sample_like_one_at_a_time`); otherwise one point at a time.
    pub fn sample4(&self, smp: &Sampler, g: &Grid, p: [[f64; 3]; LANES]) -> [Sample; LANES] {
        if !p.iter().all(|&q| super::finite_point(q)) {
            return p.map(|q| self.sample(smp, g, q));
        }
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2") {
                // SAFETY: the running CPU supports AVX2 (checked just above).
                return unsafe { avx2::sample4(self, smp, g, p) };
            }
        }
        p.map(|q| self.sample(smp, g, q))
    }

    /// Trilinear interpolation of the `W` quantities of one kind located like quantity
    /// `q`: the direct sampler's corner order and weights (`wx * wy * wz * value`).
    #[inline(always)]
    fn interp<const W: usize>(&self, data: &[f64], b: &Brackets, q: usize) -> [f64; W] {
        let (hx, vy, hz) = LOCATION[q];
        let (i0, _, fx) = b.x[hx as usize];
        let (k0, _, fz) = b.z[hz as usize];
        let (j0, fy) = b.y[vy as usize];
        let mut acc = [0.0; W];
        for (jj, wy) in [(j0, 1.0 - fy), (j0 + 1, fy)] {
            for (kk, wz) in [(k0, 1.0 - fz), (k0 + 1, fz)] {
                let row = (i0 + self.px * jj + self.plane * kk) * W;
                let pair = &data[row..row + 2 * W];
                for (n, wx) in [1.0 - fx, fx].into_iter().enumerate() {
                    let wgt = wx * wy * wz;
                    for (a, x) in acc.iter_mut().zip(&pair[n * W..(n + 1) * W]) {
                        *a += wgt * x;
                    }
                }
            }
        }
        acc
    }
}

/// Fills plane `k` of one kind's table (`p`, `W` values per node): `value(i, j, k)` at
/// the interior nodes of each of its `rows` y nodes, then the periodic halo column
/// `nx + 1` (a copy of column 1). The halo plane is copied by the caller.
#[inline(always)]
fn fill_rows<const W: usize>(
    p: &mut [f64],
    rows: usize,
    nx: usize,
    px: usize,
    k: usize,
    value: impl Fn(usize, usize, usize) -> [f64; W],
) {
    for j in 0..rows {
        let row = &mut p[j * px * W..(j + 1) * px * W];
        for i in 1..=nx {
            row[i * W..(i + 1) * W].copy_from_slice(&value(i, j, k));
        }
        row.copy_within(W..2 * W, (nx + 1) * W);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sample::Interpolation;
    use crate::{DnsConfig, InitialField, Solver};

    /// A small turbulent field (seeded), its trilinear sampler and its filled tables.
    fn field_and_tables(seed: u64) -> (Solver, Sampler, Tables) {
        let mut cfg = DnsConfig::with_cells(12, 10, 8);
        cfg.init = InitialField::Turbulent {
            amplitude: 0.3,
            seed,
        };
        let s = Solver::new(cfg).unwrap();
        let smp = Sampler::with_scheme(&s.grid, Interpolation::Trilinear);
        let mut t = Tables::new();
        t.fill(&smp, &s.grid, &s.vel);
        (s, smp, t)
    }

    /// 20,000 random points over three box lengths in x and z and beyond the walls.
    fn random_points(g: &Grid, seed: u64) -> Vec<[f64; 3]> {
        let mut rnd = crate::sample::tests::uniform(seed);
        (0..20_000)
            .map(|_| {
                [
                    rnd() * 3.0 * g.lx - g.lx,
                    rnd() * 2.2 - 1.1,
                    rnd() * 3.0 * g.lz - g.lz,
                ]
            })
            .collect()
    }

    /// A point with a NaN or infinite coordinate (each place, each kind) reads no memory:
    /// every sampler gives a NaN sample, alone or among finite points, and `try_sample`
    /// refuses it with an error naming the point; before the check such a point reached
    /// the unchecked reads with a wrapped index.
    #[test]
    fn non_finite_points_are_refused_without_reading_memory() {
        let (s, smp, t) = field_and_tables(3);
        let g = &s.grid;
        let tri = Sampler::with_scheme(g, Interpolation::Tricubic);
        for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            for a in 0..3 {
                let mut p = [0.3, 0.1, 0.2];
                p[a] = bad;
                for sm in [
                    smp.sample(g, &s.vel, p),
                    tri.sample(g, &s.vel, p),
                    t.sample(&smp, g, p),
                    t.sample4(
                        &smp,
                        g,
                        [[0.1, 0.0, 0.1], p, [0.2, 0.5, 0.3], [0.4, -0.5, 0.1]],
                    )[1],
                ] {
                    assert!(sm.vel.iter().chain(&sm.grad).all(|x| x.is_nan()), "{p:?}");
                }
                let e = smp.try_sample(g, &s.vel, p).unwrap_err().to_string();
                assert!(e.contains("non-finite"), "{e}");
                // the finite neighbours in the same group of four still get their answer
                let four = t.sample4(
                    &smp,
                    g,
                    [[0.1, 0.0, 0.1], p, [0.2, 0.5, 0.3], [0.4, -0.5, 0.1]],
                );
                assert_eq!(four[0], t.sample(&smp, g, [0.1, 0.0, 0.1]));
            }
        }
        assert!(smp.try_sample(g, &s.vel, [0.3, 0.1, 0.2]).is_ok());
    }

    /// Random points all over the channel, on and beyond the walls, and on the periodic
    /// seams: the tables give the direct sampler's velocity and gradient bit for bit.
    #[test]
    fn tables_sample_like_the_direct_sampler() {
        let (s, smp, t) = field_and_tables(7);
        let g = &s.grid;
        let mut pts = random_points(g, 0x9e37_79b9_7f4a_7c15);
        // seams and walls exactly
        for (a, b) in [(0.0, -1.0), (g.lx, 1.0), (g.dx * g.nx as f64, 0.0)] {
            pts.push([a, b, g.lz]);
            pts.push([a, b, 0.0]);
            pts.push([g.dx * 0.5, b, g.dz * (g.nz as f64 - 0.5)]);
        }
        for p in pts {
            let (a, b) = (smp.sample(g, &s.vel, p), t.sample(&smp, g, p));
            let bits = |s: &Sample| {
                s.vel
                    .iter()
                    .chain(&s.grad)
                    .map(|v| v.to_bits())
                    .collect::<Vec<_>>()
            };
            assert_eq!(bits(&a), bits(&b), "point {p:?}");
        }
    }

    /// Four points at once give, lane by lane, the one-point bits: random points all over
    /// and beyond the channel, the seams and walls exactly, and the same point in several
    /// lanes.
    #[test]
    fn four_at_once_sample_like_one_at_a_time() {
        let (s, smp, t) = field_and_tables(11);
        let g = &s.grid;
        let mut pts = random_points(g, 0x2545_f491_4f6c_dd1d);
        for (a, b) in [(0.0, -1.0), (g.lx, 1.0), (g.dx * g.nx as f64, 0.0)] {
            pts.extend([[a, b, g.lz], [a, b, 0.0], [g.dx * 0.5, b, g.dz * 3.5]]);
        }
        pts.extend([pts[7]; 5]);
        // beyond one box length (the one-point path's `rem_euclid`), and ±l, 2l exactly
        for (x, z) in [(5.5 * g.lx, 0.3), (0.2, -4.25 * g.lz), (-g.lx, 2.0 * g.lz)] {
            pts.extend([
                [x, 0.1, z],
                [0.1, -0.3, 0.2],
                [g.lx, 0.5, -g.lz],
                [x, 1.0, z],
            ]);
        }
        let bits =
            |s: &Sample| -> Vec<u64> { s.vel.iter().chain(&s.grad).map(|v| v.to_bits()).collect() };
        for four in pts.chunks_exact(LANES) {
            let p: [[f64; 3]; LANES] = std::array::from_fn(|l| four[l]);
            let got = t.sample4(&smp, g, p);
            for (q, s4) in p.iter().zip(&got) {
                assert_eq!(bits(s4), bits(&t.sample(&smp, g, *q)), "point {q:?}");
            }
        }
    }
}
