//! Sampling of velocity and velocity gradient at arbitrary points (what the fibre nodes
//! need: v, G and Ω of paper eq. 4); periodic in x and z (positions are wrapped), wall
//! values enforced in y. Two schemes:
//!
//! - [`Interpolation::Trilinear`]: each quantity from its natural staggered location, the
//!   gradient from the solver's own staggered differences. Exact for fields that are
//!   multilinear between the nodes (uniform flow, simple shear); second order otherwise.
//! - [`Interpolation::Tricubic`]: 4×4×4-point Lagrange interpolation of u, v, w (the
//!   y-stencil uses the true, stretched node positions and the wall nodes, shifted
//!   one-sided at the walls); the gradient is the derivative of the same interpolant.
//!   Exact (value and gradient) for fields that are cubic in each direction; fourth order
//!   in the value, third in the gradient.
//!
//! Size: the two schemes share the staggered-location and wall handling that makes them
//! agree bit for bit on multilinear fields; the cell-ordered tables are in `sample/`.

use crate::error::DnsError;
use crate::field::Velocity;
use crate::grid::Grid;
use serde::{Deserialize, Serialize};

mod tables;
pub use tables::{Tables, LANES};

/// Interpolation scheme of the fibre-position sampler.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum Interpolation {
    /// Trilinear from the staggered locations (8 nodes per quantity).
    #[default]
    Trilinear,
    /// Tricubic Lagrange (64 nodes per component), gradient from the interpolant.
    Tricubic,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Hx {
    Centre,
    Face,
}

/// Where a node (i, jnode, k) sits in a field array, and the wall rows' spacings.
#[derive(Clone, Copy)]
struct Layout {
    px: usize,
    plane: usize,
    ny: usize,
    inv_lo: f64,
    inv_hi: f64,
}

impl Layout {
    #[inline(always)]
    fn at(self, i: usize, j: usize, k: usize) -> usize {
        i + self.px * j + self.plane * k
    }

    /// `f` at node (i, j, k), read without a bounds check (≈ 12% of a sample's time,
    /// bench `sample_4e5_points_by_cell/direct_one_point`). Every caller passes i ≤ nx + 1,
    /// j ≤ ny + 1 and k ≤ nz + 1 (bracket nodes, each read at most one node beyond, into
    /// the halos), and [`Sampler::corners`] checks that `f` holds the whole padded box.
    #[inline(always)]
    fn get(self, f: &[f64], i: usize, j: usize, k: usize) -> f64 {
        let at = self.at(i, j, k);
        debug_assert!(i < self.px && j < self.ny + 2 && at < f.len());
        // SAFETY: i < px, j < py = ny + 2 and k < pz give at < px · py · pz, the padded
        // length every field array has (checked where the Layout is made)
        unsafe { *f.get_unchecked(at) }
    }

    /// A cell-centre quantity on the centre node list (wall nodes hold the no-slip 0;
    /// `WALLS = false` when the caller knows `jn` is no wall node).
    #[inline(always)]
    fn centre_val<const WALLS: bool>(self, f: &[f64], i: usize, jn: usize, k: usize) -> f64 {
        if WALLS && (jn == 0 || jn == self.ny + 1) {
            0.0
        } else {
            self.get(f, i, jn, k)
        }
    }

    /// ∂f/∂y of a centre quantity on the mid node list (one-sided to the wall's 0;
    /// `WALLS = false` when the caller knows `jn` is no wall node).
    #[inline(always)]
    fn y_mid_deriv<const WALLS: bool>(
        self,
        f: &[f64],
        inv_dyc: &[f64],
        i: usize,
        jn: usize,
        k: usize,
    ) -> f64 {
        if WALLS && jn == 0 {
            self.get(f, i, 1, k) * self.inv_lo
        } else if WALLS && jn == self.ny {
            -self.get(f, i, self.ny, k) * self.inv_hi
        } else {
            (self.get(f, i, jn + 1, k) - self.get(f, i, jn, k)) * inv_dyc[jn]
        }
    }
}

use Hx::{Centre as C, Face as F};

/// Where each sampled quantity lives: (x location, y node list, z location) of u, v, w
/// and then of ∂v_a/∂x_b in the order of [`Sample::grad`]. The gradient sits where the
/// solver's staggered difference of the component naturally falls.
pub(crate) const LOCATION: [(Hx, Vy, Hx); 12] = [
    (F, Vy::Centre, C),
    (C, Vy::Face, C),
    (C, Vy::Centre, F),
    (C, Vy::Centre, C),
    (F, Vy::Mid, C),
    (F, Vy::Centre, F),
    (F, Vy::Face, C),
    (C, Vy::Centre, C),
    (C, Vy::Face, F),
    (F, Vy::Centre, F),
    (C, Vy::Mid, F),
    (C, Vy::Centre, C),
];

/// The trilinear scheme's value of each quantity at one of its nodes (i, jnode, k), with
/// i, k in 1..=n (the accessor may read one index either side: the halos hold periodic
/// copies). The direct sampler and the per-step tables both evaluate exactly these.
struct Corners<'a> {
    u: &'a [f64],
    v: &'a [f64],
    w: &'a [f64],
    lay: Layout,
    idx: f64,
    idz: f64,
    idyc: &'a [f64],
    idyf: &'a [f64],
}

impl Corners<'_> {
    /// Quantity `Q` (0..3 velocity, 3..12 gradient) at node (i, j, k).
    #[inline(always)]
    fn value<const Q: usize>(&self, i: usize, j: usize, k: usize) -> f64 {
        self.value_near::<Q, true>(i, j, k)
    }

    /// [`Self::value`]; with `WALLS = false` only for nodes whose y stencil touches no
    /// wall node (the wall cases' tests skipped: the same value).
    #[inline(always)]
    fn value_near<const Q: usize, const WALLS: bool>(&self, i: usize, j: usize, k: usize) -> f64 {
        let (lay, u, v, w) = (self.lay, self.u, self.v, self.w);
        let (idx, idz) = (self.idx, self.idz);
        match Q {
            0 => lay.centre_val::<WALLS>(u, i, j, k),
            1 => lay.get(v, i, j, k),
            2 => lay.centre_val::<WALLS>(w, i, j, k),
            // ∂u/∂x, ∂u/∂y, ∂u/∂z
            3 => {
                (lay.centre_val::<WALLS>(u, i, j, k) - lay.centre_val::<WALLS>(u, i - 1, j, k))
                    * idx
            }
            4 => lay.y_mid_deriv::<WALLS>(u, self.idyc, i, j, k),
            5 => {
                (lay.centre_val::<WALLS>(u, i, j, k + 1) - lay.centre_val::<WALLS>(u, i, j, k))
                    * idz
            }
            // ∂v/∂x, ∂v/∂y, ∂v/∂z
            6 => (lay.get(v, i + 1, j, k) - lay.get(v, i, j, k)) * idx,
            7 => {
                if WALLS && (j == 0 || j == lay.ny + 1) {
                    0.0
                } else {
                    (lay.get(v, i, j, k) - lay.get(v, i, j - 1, k)) * self.idyf[j]
                }
            }
            8 => (lay.get(v, i, j, k + 1) - lay.get(v, i, j, k)) * idz,
            // ∂w/∂x, ∂w/∂y, ∂w/∂z
            9 => {
                (lay.centre_val::<WALLS>(w, i + 1, j, k) - lay.centre_val::<WALLS>(w, i, j, k))
                    * idx
            }
            10 => lay.y_mid_deriv::<WALLS>(w, self.idyc, i, j, k),
            _ => {
                (lay.centre_val::<WALLS>(w, i, j, k) - lay.centre_val::<WALLS>(w, i, j, k - 1))
                    * idz
            }
        }
    }
}

/// A point's brackets: `x[Hx]`, `z[Hx]` = (lower node, upper node, fraction), `y[Vy]` =
/// (lower node, fraction).
struct Brackets {
    x: [(usize, usize, f64); 2],
    z: [(usize, usize, f64); 2],
    y: [(usize, f64); 3],
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Vy {
    /// Wall, cell centres 1..=ny, wall (ny+2 nodes).
    Centre,
    /// Faces 0..=ny.
    Face,
    /// Wall, midpoints of neighbouring centres 1..ny-1, wall (ny+1 nodes).
    Mid,
}

/// A velocity sample: `vel[a]` and `grad[3a+b] = ∂v_a/∂x_b`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Sample {
    pub vel: [f64; 3],
    pub grad: [f64; 9],
}

impl Sample {
    /// The answer at a point that has none (a non-finite coordinate).
    pub const NAN: Sample = Sample {
        vel: [f64::NAN; 3],
        grad: [f64::NAN; 9],
    };
}

/// Whether every coordinate is finite (the samplers' indices are only in range then).
#[inline(always)]
pub(crate) fn finite_point(p: [f64; 3]) -> bool {
    p[0].is_finite() && p[1].is_finite() && p[2].is_finite()
}

/// A sorted node list with a table that finds a point's bracket in a step or two: for
/// each of `bins` equal bins of the list's range, the node at or below the bin's start.
/// Gives exactly [`bracket`]'s answer (test `lookup_brackets_like_the_search`).
#[derive(Debug, Clone)]
pub(crate) struct Nodes {
    y: Vec<f64>,
    lo: f64,
    inv_bin: f64,
    first: Vec<u32>,
}

impl Nodes {
    pub(crate) fn new(y: Vec<f64>) -> Self {
        let n = y.len();
        let bins = 16 * n;
        let (lo, hi) = (y[0], y[n - 1]);
        let inv_bin = bins as f64 / (hi - lo);
        // the bin of a point is floor((y - lo) * inv_bin): for each bin the largest node
        // index j whose node lies in a bin at or before it (so nodes[j] <= any y in it)
        let mut first = vec![0u32; bins + 1];
        let mut j = 0usize;
        for (b, slot) in first.iter_mut().enumerate() {
            while j + 1 < n && (((y[j + 1] - lo) * inv_bin).floor() as usize) <= b {
                j += 1;
            }
            *slot = j as u32;
        }
        Self {
            y,
            lo,
            inv_bin,
            first,
        }
    }

    /// [`bracket`] of `y` in this list.
    #[inline(always)]
    pub(crate) fn bracket(&self, y: f64) -> (usize, f64) {
        let nodes = &self.y;
        let n = nodes.len();
        if !(y > nodes[0]) {
            return (0, 0.0);
        }
        if y >= nodes[n - 1] {
            return (n - 2, 1.0);
        }
        let bin = (((y - self.lo) * self.inv_bin) as usize).min(self.first.len() - 1);
        // start at most one node low (the bin's start may round either way), then step up
        let mut j = (self.first[bin] as usize).saturating_sub(1);
        while nodes[j + 1] <= y {
            j += 1;
        }
        while j > 0 && nodes[j] > y {
            j -= 1;
        }
        let j = j.min(n - 2);
        (j, (y - nodes[j]) / (nodes[j + 1] - nodes[j]))
    }
}

/// Node positions in y for each location kind, and the scheme.
#[derive(Debug, Clone)]
pub struct Sampler {
    centre: Vec<f64>,
    face: Vec<f64>,
    mid: Vec<f64>,
    /// The same lists with their bracket tables (trilinear).
    pub(crate) lookup: [Nodes; 3],
    scheme: Interpolation,
    /// 1/Δx, 1/Δz and 1/Δy per row (centre-to-centre `dyc`, face-to-face `dyf`): the
    /// trilinear gradients multiply instead of dividing at every corner.
    inv_dx: f64,
    inv_dz: f64,
    inv_dyc: Vec<f64>,
    inv_dyf: Vec<f64>,
}

impl Sampler {
    /// A trilinear sampler.
    pub fn new(g: &Grid) -> Self {
        Self::with_scheme(g, Interpolation::Trilinear)
    }

    /// A sampler with the given interpolation scheme.
    pub fn with_scheme(g: &Grid, scheme: Interpolation) -> Self {
        let ny = g.ny;
        let mut centre = Vec::with_capacity(ny + 2);
        centre.push(g.yf[0]);
        centre.extend_from_slice(&g.yc[1..=ny]);
        centre.push(g.yf[ny]);
        let face = g.yf.clone();
        let mut mid = Vec::with_capacity(ny + 1);
        mid.push(g.yf[0]);
        for j in 1..ny {
            mid.push(0.5 * (g.yc[j] + g.yc[j + 1]));
        }
        mid.push(g.yf[ny]);
        Self {
            lookup: [
                Nodes::new(centre.clone()),
                Nodes::new(face.clone()),
                Nodes::new(mid.clone()),
            ],
            centre,
            face,
            mid,
            scheme,
            inv_dx: 1.0 / g.dx,
            inv_dz: 1.0 / g.dz,
            inv_dyc: g.dyc.iter().map(|d| 1.0 / d).collect(),
            inv_dyf: g.dyf.iter().map(|d| 1.0 / d).collect(),
        }
    }

    pub fn scheme(&self) -> Interpolation {
        self.scheme
    }

    fn nodes(&self, y: Vy) -> &[f64] {
        match y {
            Vy::Centre => &self.centre,
            Vy::Face => &self.face,
            Vy::Mid => &self.mid,
        }
    }

    /// Samples velocity and gradient at `p` (x and z wrapped; y clamped to the channel). A
    /// point with a non-finite coordinate reads no memory and gives a NaN sample (the
    /// unchecked reads below need a finite point); [`Sampler::try_sample`] says so instead.
    pub fn sample(&self, g: &Grid, vel: &Velocity, p: [f64; 3]) -> Sample {
        if !finite_point(p) {
            return Sample::NAN;
        }
        match self.scheme {
            Interpolation::Trilinear => self.sample_trilinear(g, vel, p),
            Interpolation::Tricubic => self.sample_tricubic(g, vel, p),
        }
    }

    /// [`Sampler::sample`], refusing a point with a non-finite coordinate by name.
    pub fn try_sample(&self, g: &Grid, vel: &Velocity, p: [f64; 3]) -> Result<Sample, DnsError> {
        if !finite_point(p) {
            return Err(DnsError::Point(format!(
                "{p:?} has a non-finite coordinate"
            )));
        }
        Ok(self.sample(g, vel, p))
    }

    fn sample_tricubic(&self, g: &Grid, vel: &Velocity, p: [f64; 3]) -> Sample {
        let (px, plane, ny) = (g.px, g.plane(), g.ny);
        let at = |i: usize, j: usize, k: usize| i + px * j + plane * k;
        let mut s = Sample::default();
        // (component, x location, y nodes, z location)
        let comps: [(&[f64], Hx, Vy, Hx); 3] = [
            (&vel.u, Hx::Face, Vy::Centre, Hx::Centre),
            (&vel.v, Hx::Centre, Vy::Face, Hx::Centre),
            (&vel.w, Hx::Centre, Vy::Centre, Hx::Face),
        ];
        for (a, (f, hx, vy, hz)) in comps.into_iter().enumerate() {
            let sx = periodic_stencil(p[0], g.dx, g.nx, hx);
            let sz = periodic_stencil(p[2], g.dz, g.nz, hz);
            let sy = wall_stencil(self.nodes(vy), p[1]);
            // wall nodes of the centre lists hold the no-slip value 0; face lists store it
            let val = |i: usize, jn: usize, k: usize| -> f64 {
                if vy == Vy::Centre && (jn == 0 || jn == ny + 1) {
                    0.0
                } else {
                    f[at(i, jn, k)]
                }
            };
            let (mut v0, mut dx, mut dy, mut dz) = (0.0, 0.0, 0.0, 0.0);
            for c in 0..4 {
                let k = sz.idx[c];
                for b in 0..4 {
                    let j = sy.idx[b];
                    // x-contractions of one row: value and x-derivative
                    let (mut r, mut rx) = (0.0, 0.0);
                    for q in 0..4 {
                        let x = val(sx.idx[q], j, k);
                        r += sx.w[q] * x;
                        rx += sx.dw[q] * x;
                    }
                    v0 += sy.w[b] * sz.w[c] * r;
                    dx += sy.w[b] * sz.w[c] * rx;
                    dy += sy.dw[b] * sz.w[c] * r;
                    dz += sy.w[b] * sz.dw[c] * r;
                }
            }
            s.vel[a] = v0;
            s.grad[3 * a] = dx;
            s.grad[3 * a + 1] = dy;
            s.grad[3 * a + 2] = dz;
        }
        s
    }

    #[inline]
    fn sample_trilinear(&self, g: &Grid, vel: &Velocity, p: [f64; 3]) -> Sample {
        let b = self.brackets(g, p);
        // away from the walls (most points) no corner's y stencil reaches a wall node:
        // centre rows j, j + 1 within 1..=ny, mid rows within 1..ny, face rows above 0
        let (jc, jf, jm) = (b.y[0].0, b.y[1].0, b.y[2].0);
        if jc >= 1 && jc < g.ny && jm >= 1 && jm + 2 <= g.ny && jf >= 1 {
            self.trilinear_at::<false>(g, vel, &b)
        } else {
            self.trilinear_at::<true>(g, vel, &b)
        }
    }

    #[inline(always)]
    fn trilinear_at<const WALLS: bool>(&self, g: &Grid, vel: &Velocity, b: &Brackets) -> Sample {
        let c = self.corners(g, vel);
        let mut s = Sample::default();
        // each quantity from its own staggered nodes (`LOCATION`), one corner expression
        // per quantity (`Corners::value`), every call monomorphic so that all of it inlines
        macro_rules! q {
            ($q:literal) => {{
                let (hx, vy, hz) = LOCATION[$q];
                self.interp(b, hx, vy, hz, |i, j, k| c.value_near::<$q, WALLS>(i, j, k))
            }};
        }
        s.vel = [q!(0), q!(1), q!(2)];
        s.grad = [
            q!(3),
            q!(4),
            q!(5),
            q!(6),
            q!(7),
            q!(8),
            q!(9),
            q!(10),
            q!(11),
        ];
        s
    }

    /// The corner values of the trilinear scheme over this field.
    #[inline(always)]
    fn corners<'a>(&'a self, g: &Grid, vel: &'a Velocity) -> Corners<'a> {
        let ny = g.ny;
        // the unchecked reads of `Layout::get` rely on it: a field of another grid is a
        // caller's bug, stopped here as a bounds check would have stopped it
        let len = g.padded_len();
        assert!(
            vel.u.len() == len && vel.v.len() == len && vel.w.len() == len,
            "sampled field does not fit the sampler's grid"
        );
        Corners {
            u: &vel.u,
            v: &vel.v,
            w: &vel.w,
            lay: Layout {
                px: g.px,
                plane: g.plane(),
                ny,
                // wall rows: the half-cell distance from the first centre to the wall
                inv_lo: 1.0 / (g.yc[1] - g.yf[0]),
                inv_hi: 1.0 / (g.yf[ny] - g.yc[ny]),
            },
            idx: self.inv_dx,
            idz: self.inv_dz,
            idyc: &self.inv_dyc,
            idyf: &self.inv_dyf,
        }
    }

    /// The brackets of a point on every staggered location: x and z on centres and faces,
    /// y on the centre, face and mid node lists (computed once per point, used by all twelve
    /// interpolations of a sample).
    #[inline(always)]
    fn brackets(&self, g: &Grid, p: [f64; 3]) -> Brackets {
        let per = |x: f64, d: f64, n: usize, h: Hx| {
            let (m0, f) = periodic_bracket(x, d, n, h);
            (m0, if m0 == n { 1 } else { m0 + 1 }, f)
        };
        Brackets {
            x: [
                per(p[0], g.dx, g.nx, Hx::Centre),
                per(p[0], g.dx, g.nx, Hx::Face),
            ],
            z: [
                per(p[2], g.dz, g.nz, Hx::Centre),
                per(p[2], g.dz, g.nz, Hx::Face),
            ],
            y: [
                self.lookup[0].bracket(p[1]),
                self.lookup[1].bracket(p[1]),
                self.lookup[2].bracket(p[1]),
            ],
        }
    }

    /// Trilinear interpolation of a located quantity given by `val(i, jnode, k)`; the
    /// accessor may read one index either side of 1..=n (the halos hold periodic copies).
    #[inline(always)]
    fn interp(
        &self,
        b: &Brackets,
        hx: Hx,
        vy: Vy,
        hz: Hx,
        val: impl Fn(usize, usize, usize) -> f64,
    ) -> f64 {
        let (i0, i1, fx) = b.x[hx as usize];
        let (k0, k1, fz) = b.z[hz as usize];
        let (j0, fy) = b.y[vy as usize];
        let mut acc = 0.0;
        for (jj, wy) in [(j0, 1.0 - fy), (j0 + 1, fy)] {
            for (kk, wz) in [(k0, 1.0 - fz), (k1, fz)] {
                for (ii, wx) in [(i0, 1.0 - fx), (i1, fx)] {
                    acc += wx * wy * wz * val(ii, jj, kk);
                }
            }
        }
        acc
    }
}

/// `x.rem_euclid(l)` for `l > 0`, bit for bit, without the `fmod` call where it is not
/// needed: in [0, l) the remainder is x; in [-l, 0) it is x + l (what `rem_euclid` adds);
/// in [l, 2l) it is x - l, which is exact there (Sterbenz). Elsewhere `rem_euclid` itself
/// (test `fast_remainder_and_floor_are_bitwise_the_library_ones`).
/// (`fmod` and `floor` are library calls on the baseline x86-64 target: with the tables
/// they were a good part of sampling a point.)
#[inline(always)]
pub(crate) fn rem_euclid_fast(x: f64, l: f64) -> f64 {
    if (0.0..l).contains(&x) {
        x
    } else if x < 0.0 && x > -l {
        x + l
    } else if x >= l && x < 2.0 * l {
        x - l
    } else {
        x.rem_euclid(l)
    }
}

/// `s.floor()` for `0 < s < 4.5 × 10¹⁵`, by truncation (exact there); otherwise `floor`.
#[inline(always)]
fn floor_fast(s: f64) -> f64 {
    if s > 0.0 && s < 4.5e15 {
        (s as u64) as f64
    } else {
        s.floor()
    }
}

/// Lower node index in 1..=n and fraction for a periodic direction.
#[inline(always)]
fn periodic_bracket(x: f64, d: f64, n: usize, h: Hx) -> (usize, f64) {
    let l = d * n as f64;
    let shift = match h {
        Hx::Centre => 0.5,
        Hx::Face => 0.0,
    };
    // node m (1..=n) sits at (m - shift) d
    let s = rem_euclid_fast(x, l) / d + shift; // in [shift, n + shift)
    let mut m = floor_fast(s);
    let mut f = s - m;
    if m < 1.0 {
        m += n as f64;
    }
    if m > n as f64 {
        m -= n as f64;
    }
    if !(0.0..=1.0).contains(&f) {
        f = f.clamp(0.0, 1.0);
    }
    (m as usize, f)
}

/// A 4-point Lagrange stencil: node indices, weights and derivative weights (d/dx).
#[derive(Debug, Clone, Copy)]
struct Stencil {
    idx: [usize; 4],
    w: [f64; 4],
    dw: [f64; 4],
}

/// Cubic stencil in a periodic uniform direction: nodes m-1..m+2 around the bracket.
fn periodic_stencil(x: f64, d: f64, n: usize, h: Hx) -> Stencil {
    let (m, t) = periodic_bracket(x, d, n, h);
    let mut idx = [0; 4];
    for (o, slot) in idx.iter_mut().enumerate() {
        // node m + o - 1 wrapped into 1..=n
        *slot = (m + n + o - 2) % n + 1;
    }
    let offsets = [-1.0, 0.0, 1.0, 2.0];
    let (w, dw) = lagrange(&offsets, t);
    Stencil {
        idx,
        w,
        dw: dw.map(|v| v / d),
    }
}

/// Cubic stencil on a sorted, non-uniform node list, shifted one-sided at the ends and
/// clamped to the channel.
fn wall_stencil(nodes: &[f64], y: f64) -> Stencil {
    let n = nodes.len();
    let y = y.clamp(nodes[0], nodes[n - 1]);
    let (j, _) = bracket(nodes, y);
    let first = j.saturating_sub(1).min(n - 4);
    let idx = [first, first + 1, first + 2, first + 3];
    let pos = idx.map(|q| nodes[q]);
    let (w, dw) = lagrange(&pos, y);
    Stencil { idx, w, dw }
}

/// Lagrange weights and their derivatives for 4 distinct nodes at point `x`.
fn lagrange(nodes: &[f64; 4], x: f64) -> ([f64; 4], [f64; 4]) {
    let mut w = [0.0; 4];
    let mut dw = [0.0; 4];
    for a in 0..4 {
        let mut den = 1.0;
        for b in 0..4 {
            if b != a {
                den *= nodes[a] - nodes[b];
            }
        }
        let mut num = 1.0;
        let mut dnum = 0.0;
        for b in 0..4 {
            if b != a {
                // product rule: d(num·(x-x_b)) = dnum·(x-x_b) + num
                dnum = dnum * (x - nodes[b]) + num;
                num *= x - nodes[b];
            }
        }
        w[a] = num / den;
        dw[a] = dnum / den;
    }
    (w, dw)
}

/// Lower node index and fraction in a sorted node list (clamped to the ends).
fn bracket(nodes: &[f64], y: f64) -> (usize, f64) {
    let n = nodes.len();
    if y <= nodes[0] {
        return (0, 0.0);
    }
    if y >= nodes[n - 1] {
        return (n - 2, 1.0);
    }
    let j = nodes.partition_point(|&v| v <= y) - 1;
    let j = j.min(n - 2);
    (j, (y - nodes[j]) / (nodes[j + 1] - nodes[j]))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Uniform numbers in [0, 1) from a xorshift generator seeded with `seed` (the
    /// sampler's tests draw their random points from it).
    pub(super) fn uniform(seed: u64) -> impl FnMut() -> f64 {
        let mut x = seed;
        move || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    /// The fast remainder and floor give the library's bits: random values over ±5 periods
    /// and the edges (±0, ±l, 2l and their neighbours, huge, NaN, ±∞).
    #[test]
    fn fast_remainder_and_floor_are_bitwise_the_library_ones() {
        let mut rnd = uniform(0x2545_f491_4f6c_dd1d);
        let up = |v: f64| f64::from_bits(v.to_bits() + 1);
        let down = |v: f64| f64::from_bits(v.to_bits() - 1);
        for l in [2.0 * std::f64::consts::PI, 942.477_796_076_938, 1.0, 3.7e-3] {
            let mut xs: Vec<f64> = (0..200_000).map(|_| (rnd() - 0.5) * 10.0 * l).collect();
            for e in [0.0, -0.0, l, -l, 2.0 * l, -2.0 * l] {
                xs.extend([e, up(e.abs()), -up(e.abs())]);
                if e != 0.0 {
                    xs.extend([down(e.abs()), -down(e.abs())]);
                }
            }
            xs.extend([1e300, -1e300, f64::NAN, f64::INFINITY, f64::NEG_INFINITY]);
            for &v in &xs {
                let (got, want) = (rem_euclid_fast(v, l), v.rem_euclid(l));
                assert!(
                    got.to_bits() == want.to_bits() || (got.is_nan() && want.is_nan()),
                    "rem_euclid({v:e}, {l}) = {want:e}, fast {got:e}"
                );
                let s = v / l * 17.0;
                let (got, want) = (floor_fast(s), s.floor());
                assert!(
                    got.to_bits() == want.to_bits() || (got.is_nan() && want.is_nan()),
                    "floor({s:e}) = {want:e}, fast {got:e}"
                );
            }
        }
    }

    /// The table lookup gives the binary search's bracket for every y: random points, the
    /// nodes themselves, their neighbouring floats, and points beyond both ends.
    #[test]
    fn lookup_brackets_like_the_search() {
        for n in [4usize, 17, 66] {
            // wall-clustered nodes on [-1, 1], as the channel grid's
            let y: Vec<f64> = (0..n)
                .map(|j| (2.5 * (2.0 * j as f64 / (n - 1) as f64 - 1.0)).tanh() / 2.5f64.tanh())
                .collect();
            let table = Nodes::new(y.clone());
            let mut probes: Vec<f64> = y
                .iter()
                .flat_map(|&v| [v, v.next_up(), v.next_down()])
                .collect();
            probes.extend([-1.5, 1.5, -1.0 - 1e-17, 1.0 + 1e-17]);
            let mut rnd = uniform(0x2545_f491_4f6c_dd1d);
            for _ in 0..100_000 {
                probes.push(rnd() * 2.2 - 1.1);
            }
            for p in probes {
                let (a, b) = (table.bracket(p), bracket(&y, p));
                assert_eq!((a.0, a.1.to_bits()), (b.0, b.1.to_bits()), "n {n}, y {p}");
            }
        }
    }
}
