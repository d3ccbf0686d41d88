//! The spreading's stencils for [`LANES`] points at once: lane by lane the operations of
//! [`super::periodic`] and [`super::in_interval`], written as fixed-length loops over the
//! lanes so that they vectorise (AVX-512 or AVX2 where the processor has them, chosen at
//! run time). Square roots and divisions are correctly rounded in every lane and no fused
//! multiply-add is enabled, so every lane has the bits of the one-point path (test
//! `super::tests::spreading_gives_the_bits_of_the_plain_sum`, and
//! `lanes_are_the_one_point_stencils` below). The y brackets stay scalar, lane by lane.

use super::{Rows, Share, Stencil};
use crate::grid::Grid;

/// Points whose stencils are made together.
pub(super) const LANES: usize = 8;

/// Stencils of [`LANES`] points: first padded indices and weights, lane by lane.
struct Block {
    first: [isize; LANES],
    w: [[f64; LANES]; 3],
}

impl Block {
    fn stencil(&self, l: usize) -> Stencil {
        Stencil {
            first: self.first[l],
            w: [self.w[0][l], self.w[1][l], self.w[2][l]],
        }
    }
}

/// [`super::around`] and [`super::round_non_negative`] from the fractional node index `s`
/// of each lane: the nearest node and the three weights. `s.trunc()` stands for the
/// integer part by conversion (the same value for 0 ≤ s < 2⁵², and −0 where s is −0,
/// which changes no weight and no index).
#[inline(always)]
fn nearest_and_weights(s: &[f64; LANES]) -> ([f64; LANES], [[f64; LANES]; 3]) {
    let mut nearest = [0.0; LANES];
    let mut w = [[0.0; LANES]; 3];
    for l in 0..LANES {
        let whole = s[l].trunc();
        nearest[l] = if s[l] - whole >= 0.5 {
            whole + 1.0
        } else {
            whole
        };
        let t = s[l] - nearest[l];
        let q = (1.0 - 3.0 * t * t).max(0.0).sqrt();
        w[0][l] = (2.0 - 3.0 * t - q) / 6.0;
        w[1][l] = (1.0 + q) / 3.0;
        w[2][l] = (2.0 + 3.0 * t - q) / 6.0;
    }
    (nearest, w)
}

/// The weights divided by their sum, lane by lane.
#[inline(always)]
fn normalised(w: &mut [[f64; LANES]; 3]) {
    for l in 0..LANES {
        let sum = w[0][l] + w[1][l] + w[2][l];
        for wo in w.iter_mut() {
            wo[l] /= sum;
        }
    }
}

/// [`super::periodic`] for each lane's `x`, or `None` when a lane's fractional index lies
/// outside (−n, 2n) (where the one-point path calls the library's remainder).
#[inline(always)]
fn periodic(x: &[f64; LANES], d: f64, n: usize, shift: f64) -> Option<Block> {
    let l_box = n as f64;
    let mut s = [0.0; LANES];
    let mut outside = false;
    for l in 0..LANES {
        let v = x[l] / d - shift;
        // `rem_euclid_fast`'s three exact cases
        s[l] = if (0.0..l_box).contains(&v) {
            v
        } else if v < 0.0 && v > -l_box {
            v + l_box
        } else {
            v - l_box
        };
        // NaN fails the comparison too
        outside |= !(v > -l_box && v < 2.0 * l_box);
    }
    if outside {
        return None;
    }
    let (nearest, mut w) = nearest_and_weights(&s);
    normalised(&mut w);
    Some(Block {
        first: nearest.map(|m| m as isize - 1),
        w,
    })
}

/// [`super::wall_normal`] for each lane's `y` (already clamped to the channel).
#[inline(always)]
fn wall_normal(y: &[f64; LANES], nodes: &crate::sample::Nodes, lo: usize, hi: usize) -> Block {
    let mut s = [0.0; LANES];
    for l in 0..LANES {
        let (j, t) = nodes.bracket(y[l]);
        s[l] = j as f64 + t.clamp(0.0, 1.0);
    }
    let (nearest, mut w) = nearest_and_weights(&s);
    for (o, wo) in w.iter_mut().enumerate() {
        for l in 0..LANES {
            let m = nearest[l] - 1.0 + o as f64;
            if m < lo as f64 || m > hi as f64 {
                wo[l] = 0.0;
            }
        }
    }
    normalised(&mut w);
    Block {
        first: nearest.map(|m| m as isize - 1),
        w,
    }
}

/// Which components' shares a block of points makes: u and v (their runs are the same) or w.
#[derive(Clone, Copy)]
pub(super) enum Components {
    UV,
    W,
}

/// A block of up to [`LANES`] points to make shares of: `points[..n]` and their forces
/// (the other lanes padding), for `which`.
pub(super) struct Job<'a> {
    pub g: &'a Grid,
    pub rows: &'a Rows,
    pub points: [[f64; 3]; LANES],
    pub forces: [[f64; 3]; LANES],
    pub n: usize,
    pub which: Components,
}

/// Pushes the shares of `job`'s points onto `out[0]` (u or w) and `out[1]` (v). Returns
/// false, pushing nothing, when a lane needs the one-point path.
pub(super) fn push_shares(job: &Job<'_>, out: [&mut Vec<Share>; 2]) -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU supports AVX-512F (checked just above); the function only
            // lets the compiler use it for the same arithmetic
            return unsafe { push_shares_avx512(job, out) };
        }
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked just above); as above
            return unsafe { push_shares_avx2(job, out) };
        }
    }
    push_shares_lanes(job, out)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn push_shares_avx512(job: &Job<'_>, out: [&mut Vec<Share>; 2]) -> bool {
    push_shares_lanes(job, out)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn push_shares_avx2(job: &Job<'_>, out: [&mut Vec<Share>; 2]) -> bool {
    push_shares_lanes(job, out)
}

#[inline(always)]
fn push_shares_lanes(job: &Job<'_>, out: [&mut Vec<Share>; 2]) -> bool {
    let Job {
        g,
        rows,
        points,
        forces,
        n,
        which,
    } = job;
    let (g, n) = (*g, *n);
    let coord = |a: usize| -> [f64; LANES] { std::array::from_fn(|l| points[l][a]) };
    let (x, z) = (coord(0), coord(2));
    let y = coord(1).map(|y| y.clamp(-1.0, 1.0));
    let [first, second] = out;
    match which {
        Components::UV => {
            let (Some(xf), Some(xc), Some(zc)) = (
                periodic(&x, g.dx, g.nx, 0.0),
                periodic(&x, g.dx, g.nx, -0.5),
                periodic(&z, g.dz, g.nz, -0.5),
            ) else {
                return false;
            };
            let yc = wall_normal(&y, &rows.centres, 1, g.ny);
            let yf = wall_normal(&y, &rows.faces, 1, g.ny - 1);
            for l in 0..n {
                let u = [xf.stencil(l), yc.stencil(l), zc.stencil(l)];
                let v = [xc.stencil(l), yf.stencil(l), zc.stencil(l)];
                first.push(Share::new(g, &u, forces[l][0]));
                second.push(Share::new(g, &v, forces[l][1]));
            }
        }
        Components::W => {
            let (Some(xc), Some(zf)) = (
                periodic(&x, g.dx, g.nx, -0.5),
                periodic(&z, g.dz, g.nz, 0.0),
            ) else {
                return false;
            };
            let yc = wall_normal(&y, &rows.centres, 1, g.ny);
            for l in 0..n {
                let w = [xc.stencil(l), yc.stencil(l), zf.stencil(l)];
                first.push(Share::new(g, &w, forces[l][2]));
            }
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every lane's stencil is the one-point path's, bit for bit: periodic stencils of
    /// random coordinates over (−n, 2n) box lengths, the edges (±0, the box, twice the
    /// box less an ulp) and lanes that need the one-point path (then `None`); wall-normal
    /// stencils of random heights and the walls, on both node lists.
    #[test]
    fn lanes_are_the_one_point_stencils() {
        let g = Grid::new(16, 24, 12, 2.0, 1.0, 150.0, Some(0.33)).unwrap();
        let rows = Rows::of(&g);
        let mut rng = crate::init::SplitMix64::new(0x1a4e5);
        let same = |a: Stencil, b: Stencil| {
            a.first == b.first && a.w.iter().zip(b.w).all(|(x, y)| x.to_bits() == y.to_bits())
        };
        let edges = [
            0.0,
            -0.0,
            2.0,
            -2.0,
            4.0f64.next_down(),
            -2.0f64.next_down(),
            1.0,
        ];
        let (mut blocks, mut one_point) = (0, 0);
        for round in 0..2000 {
            let x: [f64; LANES] = std::array::from_fn(|l| {
                if round < edges.len() && l == 0 {
                    edges[round]
                } else {
                    3.0 * rng.symmetric() + 1.0
                }
            });
            for (d, n, shift) in [(g.dx, g.nx, 0.0), (g.dx, g.nx, -0.5), (g.dz, g.nz, -0.5)] {
                let needs_one_point = x.iter().any(|&v| {
                    let s = v / d - shift;
                    !(s > -(n as f64) && s < 2.0 * n as f64)
                });
                match periodic(&x, d, n, shift) {
                    Some(b) => {
                        assert!(!needs_one_point, "{x:?}");
                        blocks += 1;
                        for (l, &v) in x.iter().enumerate() {
                            assert!(same(b.stencil(l), super::super::periodic(v, d, n, shift)));
                        }
                    }
                    None => {
                        assert!(needs_one_point, "{x:?}");
                        one_point += 1;
                    }
                }
            }
            let y: [f64; LANES] = std::array::from_fn(|l| match (round, l) {
                (0, 0) => -1.0,
                (0, 1) => 1.0,
                _ => rng.symmetric(),
            });
            for (nodes, lo, hi) in [(&rows.centres, 1, g.ny), (&rows.faces, 1, g.ny - 1)] {
                let b = wall_normal(&y, nodes, lo, hi);
                for (l, &v) in y.iter().enumerate() {
                    assert!(same(
                        b.stencil(l),
                        super::super::wall_normal(v, nodes, lo, hi)
                    ));
                }
            }
        }
        assert!(
            blocks > 100 && one_point > 100,
            "{blocks} blocks, {one_point} one-point"
        );
    }
}
