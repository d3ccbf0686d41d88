//! Two-way coupling's feedback stage: point forces (the fibres' reaction on the fluid)
//! spread onto the staggered grid as a body force per unit mass, staggered like the
//! velocity it forces (`docs/two-way.md`).
//!
//! Kernel: the three-point Roma–Peskin function φ in grid-index space, one factor per
//! direction (support ±1.5 cells, so 27 nodes per component). In x and z the grid is
//! uniform; in y the point's fractional index between the two nodes around it is used, so
//! the kernel follows the tanh stretching. φ's weights over the integer shifts sum to 1 and
//! have zero first moment for every offset, so a force is spread without a net shift.
//! Near a wall the nodes outside the fluid (ghost cells of u and w, and v's wall faces,
//! where v = 0 holds) get nothing and the remaining weights are renormalised to sum to 1:
//! a segment next to a wall puts its whole force into the fluid.
//!
//! Conservation: node n of component c receives the acceleration `F_c w_n / (ρ V_n)`, with
//! `V_n` the node's control volume (the one the discrete momentum Σ u V uses), so
//! Σ_n a_n V_n = F_c to round-off, for every point (test `every_point_spreads_its_whole_force`).
//!
//! Determinism: every k-plane of the result is written by one thread, which adds the points'
//! shares in the order of the list it is given; the flow node passes the points in a fixed
//! global order (group, fibre, segment), so the bits depend neither on the shard count nor
//! on the thread count (test `spreading_is_independent_of_the_thread_count`).

use crate::field::Velocity;
use crate::grid::Grid;
use rayon::prelude::*;

/// Three-point Roma–Peskin kernel φ(r), r in grid spacings.
#[inline]
pub fn roma_peskin(r: f64) -> f64 {
    let a = r.abs();
    if a <= 0.5 {
        (1.0 + (1.0 - 3.0 * a * a).sqrt()) / 3.0
    } else if a <= 1.5 {
        let b = 1.0 - a;
        (5.0 - 3.0 * a - (1.0 - 3.0 * b * b).max(0.0).sqrt()) / 6.0
    } else {
        0.0
    }
}

/// Nodes of one direction that a point touches: first padded index and up to three
/// weights (those of nodes outside the fluid already zero), summing to 1.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Stencil {
    first: isize,
    w: [f64; 3],
}

/// Periodic direction: nodes at `(i + shift) * d` (shift 0 for a face-centred component,
/// −0.5 for a cell-centred one, in padded index i = 1..=n); `x` in outer units.
fn periodic(x: f64, d: f64, n: usize, shift: f64) -> Stencil {
    // fractional node index of x, in [0, n)
    let s = (x / d - shift).rem_euclid(n as f64);
    let nearest = s.round();
    let w = [-1.0, 0.0, 1.0].map(|o| roma_peskin(s - (nearest + o)));
    let sum = w[0] + w[1] + w[2];
    Stencil {
        // padded index of node `nearest - 1` (node m sits at padded index m); wrapped by
        // the caller
        first: nearest as isize - 1,
        w: w.map(|x| x / sum),
    }
}

/// Wall-normal direction: nodes at `pos[lo..=hi]` (the component's interior nodes, padded
/// indices), stretched; `y` in outer units within [pos[lo-1], pos[hi+1]].
fn wall_normal(y: f64, pos: &[f64], lo: usize, hi: usize) -> Stencil {
    // the node interval [pos[j], pos[j+1]] holding y (j may be a ghost/wall index)
    let mut j = match pos[lo..=hi].partition_point(|&p| p <= y) {
        0 => lo - 1,
        m => lo + m - 1,
    };
    j = j.min(hi);
    let t = ((y - pos[j]) / (pos[j + 1] - pos[j])).clamp(0.0, 1.0);
    let s = j as f64 + t;
    let nearest = s.round() as isize;
    let mut w = [0.0; 3];
    for (o, wo) in w.iter_mut().enumerate() {
        let m = nearest - 1 + o as isize;
        if m >= lo as isize && m <= hi as isize {
            *wo = roma_peskin(s - m as f64);
        }
    }
    let sum = w[0] + w[1] + w[2];
    Stencil {
        first: nearest - 1,
        w: w.map(|x| x / sum),
    }
}

/// Where a point force lands for each component: x, y and z stencils of u, v and w.
#[derive(Debug, Clone, Copy)]
struct PointStencils {
    x: [Stencil; 3],
    y: [Stencil; 3],
    z: [Stencil; 3],
}

fn stencils(g: &Grid, p: [f64; 3]) -> PointStencils {
    let y = p[1].clamp(-1.0, 1.0);
    // u: x faces, y centres, z centres; v: x centres, y faces, z centres; w: x centres,
    // y centres, z faces
    PointStencils {
        x: [
            periodic(p[0], g.dx, g.nx, 0.0),
            periodic(p[0], g.dx, g.nx, -0.5),
            periodic(p[0], g.dx, g.nx, -0.5),
        ],
        y: [
            wall_normal(y, &g.yc, 1, g.ny),
            wall_normal(y, &g.yf, 1, g.ny - 1),
            wall_normal(y, &g.yc, 1, g.ny),
        ],
        z: [
            periodic(p[2], g.dz, g.nz, -0.5),
            periodic(p[2], g.dz, g.nz, -0.5),
            periodic(p[2], g.dz, g.nz, 0.0),
        ],
    }
}

/// Padded index 1..=n of node m (any integer) of a periodic direction with n nodes, where
/// node index n ≡ 0.
#[inline]
fn wrap(m: isize, n: usize) -> usize {
    let r = m.rem_euclid(n as isize) as usize;
    if r == 0 {
        n
    } else {
        r
    }
}

/// Control volume of the node at padded y index j of component c (0 u, 1 v, 2 w).
#[inline]
fn volume(g: &Grid, c: usize, j: usize) -> f64 {
    let dy = if c == 1 { g.dyc[j] } else { g.dyf[j] };
    g.dx * dy * g.dz
}

/// The fibres' body force per unit mass on the grid (dense, staggered like the velocity),
/// and which of its rows hold anything: per component and padded k-plane, the padded y
/// rows the last spreading wrote, ascending. Clearing and adding visit only those rows, so
/// a few hundred fibres cost what they touch, not the whole field (`docs/two-way.md`, "Cost").
#[derive(Debug, Clone)]
pub struct BodyForce {
    /// Node accelerations (outer units), zero outside [`Self::rows`].
    pub field: Velocity,
    rows: [Vec<Vec<u32>>; 3],
}

impl BodyForce {
    /// No force anywhere.
    pub fn zeros(g: &Grid) -> Self {
        Self {
            field: Velocity::zeros(g),
            rows: std::array::from_fn(|_| vec![Vec::new(); g.nz + 2]),
        }
    }

    /// The padded y rows of plane `k` of component `c` (0 u, 1 v, 2 w) that may hold a
    /// non-zero value, ascending.
    pub fn rows(&self, c: usize, k: usize) -> &[u32] {
        &self.rows[c][k]
    }
}

/// Spreads point forces onto `out` (overwritten; halos left zero). `points[i]` is a
/// position in outer units (x, z any real, y within the walls) and `forces[i]` the force
/// *on the fluid* there, in outer units (ρ = 1): node accelerations are added in the
/// order of the list.
pub fn spread(g: &Grid, points: &[[f64; 3]], forces: &[[f64; 3]], out: &mut BodyForce) {
    let stencils: Vec<PointStencils> = points.par_iter().map(|&p| stencils(g, p)).collect();
    let plane = g.plane();
    let nz = g.nz;
    let BodyForce { field, rows } = out;
    let Velocity { u, v, w } = field;
    for (c, (field, rows)) in [u, v, w].into_iter().zip(rows.iter_mut()).enumerate() {
        // each plane's points, in the list's order (so the sums are those of one pass)
        let mut by_plane: Vec<Vec<(usize, usize)>> = vec![Vec::new(); nz + 2];
        for (n, (st, f)) in stencils.iter().zip(forces).enumerate() {
            if f[c] == 0.0 {
                continue;
            }
            let sz = &st.z[c];
            for oz in 0..3 {
                if sz.w[oz] != 0.0 {
                    by_plane[wrap(sz.first + oz as isize, nz)].push((n, oz));
                }
            }
        }
        field
            .par_chunks_mut(plane)
            .zip(rows.par_iter_mut())
            .zip(by_plane.par_iter())
            .for_each(|((pl, touched), points)| {
                // the rows the last spreading wrote go back to zero
                for &j in touched.iter() {
                    let r = j as usize * g.px;
                    pl[r..r + g.px].iter_mut().for_each(|x| *x = 0.0);
                }
                touched.clear();
                // the rows this spreading writes, marked (then listed in order: a sort of
                // the ≈ 3 rows per point took as long as the spreading at 10⁵ fibres)
                let mut marked = vec![false; pl.len() / g.px];
                for &(n, oz) in points {
                    let st = &stencils[n];
                    let fc = forces[n][c];
                    let wz = st.z[c].w[oz];
                    let (sx, sy) = (&st.x[c], &st.y[c]);
                    for (oy, &wy) in sy.w.iter().enumerate() {
                        if wy == 0.0 {
                            continue;
                        }
                        let j = (sy.first + oy as isize) as usize;
                        marked[j] = true;
                        let scale = fc * wz * wy / volume(g, c, j);
                        for (ox, &wx) in sx.w.iter().enumerate() {
                            let i = wrap(sx.first + ox as isize, g.nx);
                            pl[i + g.px * j] += scale * wx;
                        }
                    }
                }
                touched.extend(
                    marked
                        .iter()
                        .enumerate()
                        .filter(|(_, &m)| m)
                        .map(|(j, _)| j as u32),
                );
            });
    }
}

/// Σ a V of one component over the interior (its momentum rate, outer units).
pub fn total(g: &Grid, f: &[f64], c: usize) -> f64 {
    let jmax = if c == 1 { g.ny - 1 } else { g.ny };
    let mut s = 0.0;
    for k in 1..=g.nz {
        for j in 1..=jmax {
            let vol = volume(g, c, j);
            for i in 1..=g.nx {
                s += f[g.idx(i, j, k)] * vol;
            }
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid() -> Grid {
        Grid::new(16, 24, 12, 2.0, 1.0, 150.0, Some(0.33)).unwrap()
    }

    /// φ's weights over the integer shifts sum to 1 and have zero first moment for any
    /// offset (to 1e-15).
    #[test]
    fn kernel_moments() {
        for i in 0..=100 {
            let s = i as f64 / 100.0 - 0.5;
            let w: Vec<f64> = (-2..=2).map(|m| roma_peskin(s - m as f64)).collect();
            let sum: f64 = w.iter().sum();
            let first: f64 = (-2..=2).zip(&w).map(|(m, x)| (s - m as f64) * x).sum();
            assert!((sum - 1.0).abs() < 1e-15, "sum {sum} at {s}");
            assert!(first.abs() < 1e-15, "first moment {first} at {s}");
        }
    }

    /// Every point, in the interior, next to a wall, on a wall and across the periodic
    /// seams, puts exactly its force into the fluid: Σ a V = F per component to 1e-14
    /// relative.
    #[test]
    fn every_point_spreads_its_whole_force() {
        let g = grid();
        let mut out = BodyForce::zeros(&g);
        let y1 = g.yc[1];
        for p in [
            [0.3, 0.1, 0.4],
            [1.999, -0.999, 0.999],
            [0.0, 0.5 * (g.yf[0] + y1), 0.0],
            [-0.01, -1.0, 1.3],
            [0.77, 1.0, -0.2],
            [5.1, 0.5 * (g.yf[g.ny - 1] + g.yf[g.ny]), 0.5],
        ] {
            let f = [1.25, -0.75, 2.5];
            spread(&g, &[p], &[f], &mut out);
            for c in 0..3 {
                let t = total(&g, [&out.field.u, &out.field.v, &out.field.w][c], c);
                assert!(
                    (t - f[c]).abs() < 1e-14 * f[c].abs(),
                    "{p:?} c{c}: {t} vs {}",
                    f[c]
                );
            }
        }
    }

    /// A point force is spread symmetrically: its centroid (Σ a V x / Σ a V) is the point
    /// itself in x and z (zero first moment), away from the walls (1e-12).
    #[test]
    fn spread_force_is_centred_on_the_point() {
        let g = grid();
        let mut out = BodyForce::zeros(&g);
        let p = [0.913, 0.05, 0.377];
        spread(&g, &[p], &[[1.0, 0.0, 0.0]], &mut out);
        let (mut sx, mut sz) = (0.0, 0.0);
        for k in 1..=g.nz {
            for j in 1..=g.ny {
                for i in 1..=g.nx {
                    let a = out.field.u[g.idx(i, j, k)] * volume(&g, 0, j);
                    sx += a * (i as f64 * g.dx);
                    sz += a * ((k as f64 - 0.5) * g.dz);
                }
            }
        }
        assert!((sx - p[0]).abs() < 1e-12, "x centroid {sx}");
        assert!((sz - p[2]).abs() < 1e-12, "z centroid {sz}");
    }

    /// Spreading again clears what the last spreading wrote: forces at one set of points and
    /// then at another give the bits of the second set spread onto a fresh field, and the
    /// touched rows cover every non-zero node.
    #[test]
    fn spreading_again_leaves_nothing_of_the_last_points() {
        let g = grid();
        let first: Vec<[f64; 3]> = vec![[0.3, -0.99, 0.1], [1.7, 0.2, 0.8], [0.0, 0.999, 0.5]];
        let second: Vec<[f64; 3]> = vec![[1.1, 0.5, 0.3]];
        let f = [1.0, -2.0, 0.5];
        let mut reused = BodyForce::zeros(&g);
        spread(&g, &first, &[f; 3], &mut reused);
        spread(&g, &second, &[f], &mut reused);
        let mut fresh = BodyForce::zeros(&g);
        spread(&g, &second, &[f], &mut fresh);
        for c in 0..3 {
            let [a, b] = [&reused, &fresh].map(|o| [&o.field.u, &o.field.v, &o.field.w][c]);
            assert!(a
                .iter()
                .zip(b.iter())
                .all(|(p, q)| p.to_bits() == q.to_bits()));
            for k in 0..g.nz + 2 {
                for j in 0..g.ny + 2 {
                    let row = &a[k * g.plane() + j * g.px..k * g.plane() + (j + 1) * g.px];
                    if row.iter().any(|x| *x != 0.0) {
                        assert!(reused.rows(c, k).contains(&(j as u32)), "c{c} k{k} j{j}");
                    }
                }
            }
        }
    }

    /// The same points give the same bits on one thread and on four.
    #[test]
    fn spreading_is_independent_of_the_thread_count() {
        let g = grid();
        let mut seed = 7u64;
        let mut rnd = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        let pts: Vec<[f64; 3]> = (0..500)
            .map(|_| [2.0 * rnd(), 2.0 * rnd() - 1.0, rnd()])
            .collect();
        let fs: Vec<[f64; 3]> = (0..500)
            .map(|_| [rnd() - 0.5, rnd() - 0.5, rnd()])
            .collect();
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let mut out = BodyForce::zeros(&g);
            pool.install(|| spread(&g, &pts, &fs, &mut out));
            out
        };
        let (a, b) = (run(1), run(4));
        for (x, y) in [
            (&a.field.u, &b.field.u),
            (&a.field.v, &b.field.v),
            (&a.field.w, &b.field.w),
        ] {
            assert!(x
                .iter()
                .zip(y.iter())
                .all(|(p, q)| p.to_bits() == q.to_bits()));
        }
    }
}
