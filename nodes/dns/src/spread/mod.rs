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
//! Determinism: every k-plane of the result is written by one thread, which adds the shares
//! of the points whose stencil starts at that plane, then one plane before, then two, each
//! run in the order of the list it is given (the points are sorted by their first plane
//! with a stable counting sort, so that a plane reads its points one after another); the
//! flow node passes the points in a fixed global order (group, fibre, segment), so the bits
//! depend neither on the shard count nor on the thread count (test
//! `spreading_is_independent_of_the_thread_count`).

use crate::field::Velocity;
use crate::grid::Grid;
use crate::sample::Nodes;
use lanes::{Components, LANES};
use rayon::prelude::*;

mod lanes;

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

/// φ at the three nodes around a point, `t` its offset from the nearest node (|t| ≤ ½):
/// [φ(t + 1), φ(t), φ(t − 1)] for the nodes below, at and above. One square root serves
/// all three (1 − |r| = ∓t in φ's outer branch); the same values as [`roma_peskin`] to
/// round-off (test `three_weights_are_the_kernel`).
#[inline]
fn around(t: f64) -> [f64; 3] {
    let q = (1.0 - 3.0 * t * t).max(0.0).sqrt();
    [
        (2.0 - 3.0 * t - q) / 6.0,
        (1.0 + q) / 3.0,
        (2.0 + 3.0 * t - q) / 6.0,
    ]
}

/// `s.round()` for 0 ≤ s < 2⁵², the same bits, without a call into the C library (the
/// baseline x86-64 target has no rounding instruction): the integer part by conversion,
/// then up when the fraction (exact) is at least ½.
#[inline]
fn round_non_negative(s: f64) -> f64 {
    let whole = s as u64 as f64;
    if s - whole >= 0.5 {
        whole + 1.0
    } else {
        whole
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
    let s = fractional_index(x, d, n, shift);
    let nearest = round_non_negative(s);
    let w = around(s - nearest);
    let sum = w[0] + w[1] + w[2];
    Stencil {
        // padded index of node `nearest - 1` (node m sits at padded index m); wrapped by
        // the caller
        first: nearest as isize - 1,
        w: w.map(|x| x / sum),
    }
}

/// Wall-normal direction: the nodes of one of the component's lists (`nodes`: every node of
/// the list, ghosts and walls included, at its padded index), of which those at padded
/// indices `lo..=hi` are in the fluid; `y` in outer units within the list. The node
/// interval holding `y` comes from the list's bin table in a step or two (the bits of the
/// binary search it replaced, test `wall_normal_stencils_are_those_of_the_search`).
fn wall_normal(y: f64, nodes: &Nodes, lo: usize, hi: usize) -> Stencil {
    // the node interval [pos[j], pos[j+1]] holding y (j may be a ghost/wall index)
    let (j, t) = nodes.bracket(y);
    in_interval(j, t.clamp(0.0, 1.0), lo, hi)
}

/// The wall-normal stencil of a point a share `t` of the way along the node interval
/// from padded index `j`, the nodes outside `lo..=hi` given nothing.
fn in_interval(j: usize, t: f64, lo: usize, hi: usize) -> Stencil {
    let s = j as f64 + t;
    let nearest = round_non_negative(s);
    let mut w = around(s - nearest);
    let nearest = nearest as isize;
    for (o, wo) in w.iter_mut().enumerate() {
        let m = nearest - 1 + o as isize;
        if m < lo as isize || m > hi as isize {
            *wo = 0.0;
        }
    }
    let sum = w[0] + w[1] + w[2];
    Stencil {
        first: nearest - 1,
        w: w.map(|x| x / sum),
    }
}

/// The wall-normal node lists of the staggered components with their bin tables: cell
/// centres with their ghosts (`Grid::yc`, u and w) and faces (`Grid::yf`, v).
#[derive(Debug, Clone)]
struct Rows {
    centres: Nodes,
    faces: Nodes,
}

impl Rows {
    fn of(g: &Grid) -> Self {
        Self {
            centres: Nodes::new(g.yc.clone()),
            faces: Nodes::new(g.yf.clone()),
        }
    }
}

/// A point's stencils for u and for v: u on x faces, y and z centres; v on x centres, y
/// faces, z centres (the z stencil is the same).
#[inline(always)]
fn stencils_uv(g: &Grid, rows: &Rows, p: &[f64; 3]) -> [[Stencil; 3]; 2] {
    let y = p[1].clamp(-1.0, 1.0);
    let z = periodic(p[2], g.dz, g.nz, -0.5);
    [
        [
            periodic(p[0], g.dx, g.nx, 0.0),
            wall_normal(y, &rows.centres, 1, g.ny),
            z,
        ],
        [
            periodic(p[0], g.dx, g.nx, -0.5),
            wall_normal(y, &rows.faces, 1, g.ny - 1),
            z,
        ],
    ]
}

/// A point's stencils for w: x and y centres, z faces.
#[inline(always)]
fn stencils_w(g: &Grid, rows: &Rows, p: &[f64; 3]) -> [Stencil; 3] {
    let y = p[1].clamp(-1.0, 1.0);
    [
        periodic(p[0], g.dx, g.nx, -0.5),
        wall_normal(y, &rows.centres, 1, g.ny),
        periodic(p[2], g.dz, g.nz, 0.0),
    ]
}

/// The fractional node index of `x` in a periodic direction, in [0, n) (without the
/// library's remainder near the box).
#[inline(always)]
fn fractional_index(x: f64, d: f64, n: usize, shift: f64) -> f64 {
    crate::sample::rem_euclid_fast(x / d - shift, n as f64)
}

/// The padded z index (1..=n, wrapped) of the first plane a periodic stencil touches:
/// [`periodic`]'s `first`, without the weights.
#[inline(always)]
fn first_plane(x: f64, d: f64, n: usize, shift: f64) -> u32 {
    let nearest = round_non_negative(fractional_index(x, d, n, shift));
    wrap(nearest as isize - 1, n) as u32
}

/// Padded index 1..=n of node m (any integer) of a periodic direction with n nodes, where
/// node index n ≡ 0.
#[inline]
fn wrap(m: isize, n: usize) -> usize {
    let ni = n as isize;
    // a stencil's nodes lie within one node of the box: no division (tens of cycles a node)
    let r = if m >= 1 && m <= ni {
        m
    } else if m > ni && m <= 2 * ni {
        m - ni
    } else if m < 1 && m > -ni {
        m + ni
    } else {
        m.rem_euclid(ni) + if m.rem_euclid(ni) == 0 { ni } else { 0 }
    };
    r as usize
}

/// Control volume of the node at padded y index j of component c (0 u, 1 v, 2 w).
#[inline]
fn volume(g: &Grid, c: usize, j: usize) -> f64 {
    let dy = if c == 1 { g.dyc[j] } else { g.dyf[j] };
    g.dx * dy * g.dz
}

/// What the spreading of one component reads of a point, together (96 bytes; a plane's
/// points lie next to each other, [`spread`]): its x and y stencils, the force times each
/// z weight (the first factor of every node's share `f w_z w_y w_x / V`) and which z
/// offsets get a share (force and weight both non-zero).
#[derive(Debug, Clone, Copy, Default)]
struct Share {
    /// The padded x indices of the stencil's three nodes, wrapped.
    x_at: [u32; 3],
    y_first: i32,
    wx: [f64; 3],
    wy: [f64; 3],
    /// Bit `oz`: the plane at z offset `oz` from the first gets a share.
    z_mask: u8,
    fz: [f64; 3],
}

impl Share {
    /// The share of a point's force component `f` over the component's stencils `st`.
    #[inline(always)]
    fn new(g: &Grid, st: &[Stencil; 3], f: f64) -> Self {
        let [sx, sy, sz] = st;
        let mut z_mask = 0u8;
        if f != 0.0 {
            for (oz, &w) in sz.w.iter().enumerate() {
                if w != 0.0 {
                    z_mask |= 1 << oz;
                }
            }
        }
        // stencil indices are within one node of the padded grid (far below 2³¹)
        Share {
            x_at: std::array::from_fn(|ox| wrap(sx.first + ox as isize, g.nx) as u32),
            y_first: sy.first as i32,
            wx: sx.w,
            wy: sy.w,
            z_mask,
            fz: sz.w.map(|w| f * w),
        }
    }
}

/// The fibres' body force per unit mass on the grid (dense, staggered like the velocity),
/// and its non-zero nodes: per component and padded k-plane, (index within the plane,
/// value), each node once. Clearing visits only those nodes, and a field step adds only
/// them, so a few hundred fibres cost what they touch, not the whole field (at paper size
/// the touched rows covered nearly every row of the coarse grid: adding them in each
/// substep cost ≈ 10% of the step; `docs/history/two-way-cost.md`).
#[derive(Debug, Clone)]
pub struct BodyForce {
    /// Node accelerations (outer units), zero outside [`Self::entries`].
    pub field: Velocity,
    entries: [Vec<Vec<(u32, f64)>>; 3],
    /// Kept from one spreading to the next so that a step allocates nothing: each point's
    /// first z plane (padded, wrapped), the points in the order of those planes and where
    /// each plane's run starts (of u and v, which share them, and of w), per chunk of
    /// planes the shares of its last three runs, and per plane the bits of the nodes
    /// written.
    first_plane: [Vec<u32>; 2],
    order: [Vec<u32>; 2],
    run_start: [Vec<usize>; 2],
    windows: Vec<Window>,
    written: Vec<Vec<u64>>,
    rows: Rows,
}

/// The shares of three consecutive runs (slot = unwrapped plane index mod 3), per
/// component.
type Window = [[Vec<Share>; 3]; 3];

impl BodyForce {
    /// No force anywhere.
    pub fn zeros(g: &Grid) -> Self {
        Self {
            field: Velocity::zeros(g),
            entries: std::array::from_fn(|_| vec![Vec::new(); g.nz + 2]),
            first_plane: [Vec::new(), Vec::new()],
            order: [Vec::new(), Vec::new()],
            run_start: [Vec::new(), Vec::new()],
            windows: (0..g.nz.div_ceil(CHUNK_PLANES))
                .map(|_| Window::default())
                .collect(),
            written: vec![vec![0; g.plane().div_ceil(64)]; g.nz + 2],
            rows: Rows::of(g),
        }
    }

    /// The nodes of plane `k` of component `c` (0 u, 1 v, 2 w) that the last spreading
    /// wrote (in a dense plane, every fluid node), each once: (index within the plane,
    /// value of [`Self::field`] there). Every non-zero node is among them.
    pub fn entries(&self, c: usize, k: usize) -> &[(u32, f64)] {
        &self.entries[c][k]
    }
}

/// Interior z planes per chunk of the parallel pass. A chunk makes the shares of the runs
/// that reach its planes as it goes up, keeping the last three, so that they are read
/// from cache (the two runs below its first plane are made by the chunk below as well).
/// Fixed, though the bits would not depend on it: a node's shares come in the documented
/// order whatever the chunks.
const CHUNK_PLANES: usize = 16;

/// Spreads point forces onto `out` (overwritten; halos left zero). `points[i]` is a
/// position in outer units (x, z any real, y within the walls) and `forces[i]` the force
/// *on the fluid* there, in outer units (ρ = 1). A node adds its shares in a fixed order:
/// the points whose stencil starts at its own z plane, then those starting one plane
/// before, then two; each of these in the order of the list.
///
/// How: the points are sorted by their first plane (a stable counting sort: a run per
/// plane, in the list's order); chunks of planes go in parallel, each going up its planes,
/// making the shares of the run that starts at a plane (each point's stencils computed
/// once, u's and v's together) and then adding the plane's three runs to it.
pub fn spread(g: &Grid, points: &[[f64; 3]], forces: &[[f64; 3]], out: &mut BodyForce) {
    let BodyForce {
        field,
        entries,
        first_plane: firsts,
        order,
        run_start,
        windows,
        written,
        rows,
    } = out;
    let rows = &*rows;
    let (plane, nz) = (g.plane(), g.nz);
    // each point's first z plane: of u and v (z centres), of w (z faces)
    {
        let [fuv, fw] = &mut *firsts;
        points
            .par_iter()
            .with_min_len(4096)
            .map(|p| {
                (
                    first_plane(p[2], g.dz, nz, -0.5),
                    first_plane(p[2], g.dz, nz, 0.0),
                )
            })
            .unzip_into_vecs(fuv, fw);
    }
    // the points by first plane (a stable counting sort, so each plane's points keep the
    // list's order; u and v share theirs)
    let sort = |first: &[u32], order: &mut Vec<u32>, run_start: &mut Vec<usize>| {
        run_start.clear();
        run_start.resize(nz + 3, 0);
        for &k in first {
            run_start[k as usize + 1] += 1;
        }
        for k in 0..nz + 2 {
            run_start[k + 1] += run_start[k];
        }
        let mut next = run_start.clone();
        order.clear();
        order.resize(first.len(), 0);
        for (n, &k) in first.iter().enumerate() {
            order[next[k as usize]] = n as u32;
            next[k as usize] += 1;
        }
    };
    {
        let [ouv, ow] = &mut *order;
        let [ruv, rw] = &mut *run_start;
        rayon::join(|| sort(&firsts[0], ouv, ruv), || sort(&firsts[1], ow, rw));
    }
    // the shares of the run of (unwrapped) plane index `k`, in the list's order
    let make_shares = |k: isize, [su, sv, sw]: &mut [Vec<Share>; 3]| {
        let r = wrap(k, nz);
        su.clear();
        sv.clear();
        sw.clear();
        let runs = [0, 1].map(|o| &order[o][run_start[o][r]..run_start[o][r + 1]]);
        push_run(g, rows, runs[0], points, forces, Components::UV, [su, sv]);
        push_run(
            g,
            rows,
            runs[1],
            points,
            forces,
            Components::W,
            [sw, &mut Vec::new()],
        );
    };
    // 1 / the control volume of each row and component: a multiplication per node instead
    // of a division
    let per_volume: [Vec<f64>; 3] = std::array::from_fn(|c| {
        let jmax = if c == 1 { g.ny - 1 } else { g.ny };
        (0..g.ny + 2)
            .map(|j| {
                if (1..=jmax).contains(&j) {
                    1.0 / volume(g, c, j)
                } else {
                    0.0
                }
            })
            .collect()
    });
    // the interior planes of the three components with their node lists and bits (the
    // halo planes get nothing), in chunks
    let Velocity { u, v, w } = field;
    let [eu, ev, ew] = entries;
    let mut planes: Vec<_> = u
        .chunks_mut(plane)
        .zip(v.chunks_mut(plane))
        .zip(w.chunks_mut(plane))
        .zip(eu.iter_mut().zip(ev.iter_mut()).zip(ew.iter_mut()))
        .zip(written.iter_mut())
        .skip(1)
        .take(nz)
        .map(|((((pu, pv), pw), ((nu, nv), nw)), bits)| ([(pu, nu), (pv, nv), (pw, nw)], bits))
        .collect();
    planes
        .par_chunks_mut(CHUNK_PLANES)
        .zip(windows.par_iter_mut())
        .enumerate()
        .for_each(|(chunk, (planes, window))| {
            // the chunk's first interior plane index; the two runs below it first
            let a = 1 + chunk * CHUNK_PLANES;
            let slot = |k: isize| k.rem_euclid(3) as usize;
            for k in [a as isize - 2, a as isize - 1] {
                make_shares(k, &mut window[slot(k)]);
            }
            for (o, (pl, bits)) in planes.iter_mut().enumerate() {
                let k = (a + o) as isize;
                make_shares(k, &mut window[slot(k)]);
                for (c, (values, nodes)) in pl.iter_mut().enumerate() {
                    let runs: [&[Share]; 3] =
                        std::array::from_fn(|oz| &window[slot(k - oz as isize)][c][..]);
                    spread_plane(g, runs, &per_volume[c], values, nodes, bits);
                }
            }
        });
}

/// Pushes the shares of the points of `run` (indices into `points` and `forces`), in its
/// order, for `which` onto `out` (u or w, then v): [`lanes::LANES`] points at a time, each
/// block's points asked for two blocks ahead (they are read out of order), the one-point
/// path for a block that needs it.
fn push_run(
    g: &Grid,
    rows: &Rows,
    run: &[u32],
    points: &[[f64; 3]],
    forces: &[[f64; 3]],
    which: Components,
    out: [&mut Vec<Share>; 2],
) {
    let [first, second] = out;
    for (b, block) in run.chunks(LANES).enumerate() {
        for &m in run.iter().skip((b + 2) * LANES).take(LANES) {
            prefetch(&points[m as usize]);
            prefetch(&forces[m as usize]);
        }
        let n = block.len();
        let at = |l: usize| block[l.min(n - 1)] as usize;
        let job = lanes::Job {
            g,
            rows,
            points: std::array::from_fn(|l| points[at(l)]),
            forces: std::array::from_fn(|l| forces[at(l)]),
            n,
            which,
        };
        if lanes::push_shares(&job, [&mut *first, &mut *second]) {
            continue;
        }
        for (p, f) in job.points.iter().zip(&job.forces).take(n) {
            match which {
                Components::UV => {
                    let [u, v] = stencils_uv(g, rows, p);
                    first.push(Share::new(g, &u, f[0]));
                    second.push(Share::new(g, &v, f[1]));
                }
                Components::W => first.push(Share::new(g, &stencils_w(g, rows, p), f[2])),
            }
        }
    }
}

/// Asks for the cache line of `x` ahead of its use.
#[inline(always)]
fn prefetch<T>(x: &T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: a prefetch reads nothing and faults on no address
    unsafe {
        std::arch::x86_64::_mm_prefetch(x as *const T as *const i8, std::arch::x86_64::_MM_HINT_T0)
    }
}

/// One component of one plane `pl` of [`spread`]: clears the nodes the last spreading
/// wrote (`nodes`), adds the shares of the points whose stencil starts `oz` planes before
/// (`runs[oz]`), and lists the nodes written, each once (`written`: a bit per node, left
/// zero). A plane whose shares could write each of its fluid nodes (nine nodes a share)
/// is taken as dense: zeroed whole, added without keeping the bits, and every fluid node
/// listed (the nodes never written hold +0, which leaves any velocity but a −0 as it
/// was). Which planes are dense depends on the points alone, not on the threads.
fn spread_plane(
    g: &Grid,
    runs: [&[Share]; 3],
    per_volume: &[f64],
    pl: &mut [f64],
    nodes: &mut Vec<(u32, f64)>,
    written: &mut [u64],
) {
    let fluid_rows = per_volume.iter().filter(|v| **v != 0.0).count();
    let shares: usize = runs.iter().map(|r| r.len()).sum();
    if 9 * shares >= fluid_rows * g.nx {
        pl.iter_mut().for_each(|x| *x = 0.0);
        add_runs(g, runs, per_volume, pl, |_| {});
        nodes.clear();
        for (j, _) in per_volume.iter().enumerate().filter(|(_, v)| **v != 0.0) {
            for at in g.px * j + 1..=g.px * j + g.nx {
                nodes.push((at as u32, pl[at]));
            }
        }
        return;
    }
    // the nodes the last spreading wrote go back to zero
    for &(at, _) in nodes.iter() {
        pl[at as usize] = 0.0;
    }
    nodes.clear();
    add_runs(g, runs, per_volume, pl, |at| {
        // listed once, the first time it is written
        let (word, bit) = (at / 64, 1u64 << (at % 64));
        if written[word] & bit == 0 {
            written[word] |= bit;
            nodes.push((at as u32, 0.0));
        }
    });
    // their values; the bits go back to zero for the next component
    for (at, a) in nodes.iter_mut() {
        *a = pl[*at as usize];
        written[*at as usize / 64] = 0;
    }
}

/// Adds the shares of `runs[oz]` (points whose stencil starts `oz` planes before) to the
/// plane `pl`, in order, calling `wrote` with each node's index.
#[inline(always)]
fn add_runs(
    g: &Grid,
    runs: [&[Share]; 3],
    per_volume: &[f64],
    pl: &mut [f64],
    mut wrote: impl FnMut(usize),
) {
    for (oz, run) in runs.iter().enumerate() {
        for sh in run.iter() {
            if sh.z_mask & (1 << oz) == 0 {
                continue;
            }
            let fz = sh.fz[oz];
            for (oy, &wy) in sh.wy.iter().enumerate() {
                if wy == 0.0 {
                    continue;
                }
                let j = (sh.y_first as isize + oy as isize) as usize;
                let scale = fz * wy * per_volume[j];
                for (ox, &wx) in sh.wx.iter().enumerate() {
                    let at = sh.x_at[ox] as usize + g.px * j;
                    pl[at] += scale * wx;
                    wrote(at);
                }
            }
        }
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

    /// Reproducible uniform numbers in [0, 1) from `seed`.
    fn uniform(mut seed: u64) -> impl FnMut() -> f64 {
        move || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        }
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

    /// The three weights from one square root are φ at the three nodes to 1e-15, for
    /// offsets across [−½, ½].
    #[test]
    fn three_weights_are_the_kernel() {
        for i in 0..=1000 {
            let t = i as f64 / 1000.0 - 0.5;
            let w = around(t);
            for (o, wo) in w.iter().enumerate() {
                let r = t - (o as f64 - 1.0);
                assert!((wo - roma_peskin(r)).abs() < 1e-15, "t {t} o {o}");
            }
        }
    }

    /// The wall-normal stencils from the bin table are those of the binary search over the
    /// list's fluid nodes (the spreading's first way), bit for bit: random heights, every
    /// node, the walls and the floats next to each, for both lists on a stretched and a
    /// uniform grid.
    #[test]
    fn wall_normal_stencils_are_those_of_the_search() {
        fn searched(y: f64, pos: &[f64], lo: usize, hi: usize) -> Stencil {
            let mut j = match pos[lo..=hi].partition_point(|&p| p <= y) {
                0 => lo - 1,
                m => lo + m - 1,
            };
            j = j.min(hi);
            let t = ((y - pos[j]) / (pos[j + 1] - pos[j])).clamp(0.0, 1.0);
            in_interval(j, t, lo, hi)
        }
        let mut rnd = uniform(11);
        for g in [grid(), Grid::new(8, 64, 8, 2.0, 1.0, 150.0, None).unwrap()] {
            let rows = Rows::of(&g);
            let mut ys: Vec<f64> = (0..20_000).map(|_| 2.0 * rnd() - 1.0).collect();
            for &p in g.yf.iter().chain(&g.yc) {
                ys.extend([p, p.next_up(), p.next_down()]);
            }
            let bits = |s: Stencil| (s.first, s.w.map(f64::to_bits));
            for y in ys.into_iter().map(|y| y.clamp(-1.0, 1.0)) {
                assert_eq!(
                    bits(wall_normal(y, &rows.faces, 1, g.ny - 1)),
                    bits(searched(y, &g.yf, 1, g.ny - 1)),
                    "faces, y {y}"
                );
                assert_eq!(
                    bits(wall_normal(y, &rows.centres, 1, g.ny)),
                    bits(searched(y, &g.yc, 1, g.ny)),
                    "centres, y {y}"
                );
            }
        }
    }

    /// The wrapping without a division gives the padded index of the remainder for nodes
    /// near the box and far from it.
    #[test]
    fn wrapping_is_the_remainder() {
        for n in [1usize, 2, 16, 64] {
            for m in -5 * n as isize..5 * n as isize {
                let r = m.rem_euclid(n as isize) as usize;
                assert_eq!(wrap(m, n), if r == 0 { n } else { r }, "m {m} n {n}");
            }
        }
    }

    /// The rounding without the C library gives `round`'s bits, at halves and next to them.
    #[test]
    fn rounding_is_rounds() {
        let mut xs = vec![0.0, 0.5, 1.5, 2.5, 63.5, 64.0 - 1e-13, 0.49999999999999994];
        for i in 0..100_000 {
            xs.push(i as f64 * 0.000_731 * 64.0 / 73.1);
        }
        for x in xs {
            for y in [x, f64::from_bits(x.to_bits() + 1), x.next_down().max(0.0)] {
                assert_eq!(round_non_negative(y).to_bits(), y.round().to_bits(), "{y}");
            }
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
    /// entries list each written node once, with its value, every non-zero node among them.
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
                let plane = &a[k * g.plane()..(k + 1) * g.plane()];
                let mut listed = reused.entries(c, k).to_vec();
                listed.sort_by_key(|e| e.0);
                // each node once, with its value, and every non-zero node among them
                assert!(listed.windows(2).all(|w| w[0].0 < w[1].0), "c{c} k{k}");
                for &(at, x) in &listed {
                    assert_eq!(x.to_bits(), plane[at as usize].to_bits());
                }
                let nonzero = plane.iter().filter(|x| **x != 0.0).count();
                let listed_nonzero = listed.iter().filter(|e| e.1 != 0.0).count();
                assert_eq!(nonzero, listed_nonzero, "c{c} k{k}");
            }
        }
    }

    /// The spreading as the module's documentation states it, one node share at a time:
    /// per component and plane, the points whose stencil starts at the plane, one plane
    /// before, two, each in the list's order; every stencil computed on its own, where it
    /// is needed. [`spread`] gives its bits (test `spreading_gives_the_bits_of_the_plain_sum`).
    fn plain_spread(g: &Grid, points: &[[f64; 3]], forces: &[[f64; 3]]) -> Velocity {
        let rows = Rows::of(g);
        let mut out = Velocity::zeros(g);
        for c in 0..3 {
            let f = [&mut out.u, &mut out.v, &mut out.w][c].as_mut_slice();
            let jmax = if c == 1 { g.ny - 1 } else { g.ny };
            for k in 1..=g.nz {
                for oz in 0..3 {
                    for (p, force) in points.iter().zip(forces) {
                        let y = p[1].clamp(-1.0, 1.0);
                        let sx = periodic(p[0], g.dx, g.nx, if c == 0 { 0.0 } else { -0.5 });
                        let sy = if c == 1 {
                            wall_normal(y, &rows.faces, 1, g.ny - 1)
                        } else {
                            wall_normal(y, &rows.centres, 1, g.ny)
                        };
                        let sz = periodic(p[2], g.dz, g.nz, if c == 2 { 0.0 } else { -0.5 });
                        if wrap(sz.first, g.nz) != wrap(k as isize - oz as isize, g.nz)
                            || force[c] == 0.0
                            || sz.w[oz] == 0.0
                        {
                            continue;
                        }
                        for (oy, &wy) in sy.w.iter().enumerate() {
                            let j = (sy.first + oy as isize) as usize;
                            if wy == 0.0 || !(1..=jmax).contains(&j) {
                                continue;
                            }
                            let scale = force[c] * sz.w[oz] * wy * (1.0 / volume(g, c, j));
                            for (ox, &wx) in sx.w.iter().enumerate() {
                                let i = wrap(sx.first + ox as isize, g.nx);
                                f[i + g.px * j + g.plane() * k] += scale * wx;
                            }
                        }
                    }
                }
            }
        }
        out
    }

    /// [`spread`] (each point's stencils computed once, the shares sorted by plane, the
    /// planes in parallel) gives bit for bit the plain sum of [`plain_spread`]: 3000
    /// random points, a fifth of them within a cell of a wall, some on the periodic seams,
    /// some with a zero force component, spread twice into the same buffers; on a grid of
    /// 40 planes (chunks of 16, 16 and 8) and on one of 12 (a single chunk).
    #[test]
    fn spreading_gives_the_bits_of_the_plain_sum() {
        for g in [
            Grid::new(16, 24, 40, 2.0, 1.0, 150.0, Some(0.33)).unwrap(),
            grid(),
        ] {
            spreading_gives_the_bits_of_the_plain_sum_on(&g);
        }
    }

    fn spreading_gives_the_bits_of_the_plain_sum_on(g: &Grid) {
        let mut rnd = uniform(0x5eed);
        let mut pts: Vec<[f64; 3]> = (0..3000)
            .map(|n| {
                let y = if n % 5 == 0 {
                    (1.0 - 0.05 * rnd()) * if n % 2 == 0 { 1.0 } else { -1.0 }
                } else {
                    2.0 * rnd() - 1.0
                };
                [4.0 * rnd() - 1.0, y, 3.0 * rnd() - 1.0]
            })
            .collect();
        // box edges, and points beyond two box lengths (the one-point path's remainder)
        pts.extend([
            [0.0, 0.0, 0.0],
            [2.0, 0.5, 1.0],
            [-2.0, -1.0, -1.0],
            [1.0, 1.0, 0.5],
            [-0.0, 0.3, -0.0],
            [5.3, 0.1, 0.2],
            [-2.5, -0.3, 4.1],
        ]);
        let fs: Vec<[f64; 3]> = (0..pts.len())
            .map(|n| {
                let f = [rnd() - 0.5, rnd() - 0.5, rnd() - 0.5];
                if n % 7 == 0 {
                    [f[0], 0.0, f[2]]
                } else {
                    f
                }
            })
            .collect();
        // dense planes (every point), then sparse ones (a few), then both again
        let mut out = BodyForce::zeros(g);
        for n in [100, pts.len(), 7, 300] {
            let want = plain_spread(g, &pts[..n], &fs[..n]);
            spread(g, &pts[..n], &fs[..n], &mut out);
            for (c, (x, y)) in [
                (&out.field.u, &want.u),
                (&out.field.v, &want.v),
                (&out.field.w, &want.w),
            ]
            .into_iter()
            .enumerate()
            {
                let differ = x
                    .iter()
                    .zip(y.iter())
                    .filter(|(p, q)| p.to_bits() != q.to_bits())
                    .count();
                assert_eq!(
                    differ, 0,
                    "{n} points, component {c}: {differ} nodes differ"
                );
                assert!(y.iter().any(|v| *v != 0.0));
                // every node written is listed once with its value
                for k in 1..=g.nz {
                    let plane = &x[k * g.plane()..(k + 1) * g.plane()];
                    let listed = out.entries(c, k);
                    let mut at: Vec<u32> = listed.iter().map(|e| e.0).collect();
                    at.sort_unstable();
                    assert!(at.windows(2).all(|w| w[0] < w[1]), "{n} points, c{c} k{k}");
                    for &(at, v) in listed {
                        assert_eq!(v.to_bits(), plane[at as usize].to_bits());
                    }
                    let nonzero = plane.iter().filter(|v| **v != 0.0).count();
                    let listed_nonzero = listed.iter().filter(|e| e.1 != 0.0).count();
                    assert_eq!(nonzero, listed_nonzero, "{n} points, c{c} k{k}");
                }
            }
        }
    }

    /// The same points give the same bits on one thread and on four.
    #[test]
    fn spreading_is_independent_of_the_thread_count() {
        let g = grid();
        let mut rnd = uniform(7);
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
