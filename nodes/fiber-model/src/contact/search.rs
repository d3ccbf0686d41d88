//! Which pairs of segments may touch: a cell list over every segment's mid-step centre,
//! built once per step and asked again, after each round of corrections, only around the
//! fibres that moved.
//!
//! The cost grows with the segments (one pass to place them, one to sort them by cell)
//! and with the pairs near each other, not with the fibres a step's contacts touch: the
//! solve copies out only the fibres of its candidate pairs ([`super::resolve_segments`]).

use super::geometry::{closest_points, image_shift};
use super::Candidate;
use crate::fibre::{Fibre, SegmentProps};
use nalgebra::Vector3;
use rayon::prelude::*;

/// The segments of a suspension as the contact step reads them, at the start of the step
/// and after its free step, fibre by fibre.
pub(crate) trait Segments: Sync {
    /// First flat (fibre-major) index of each fibre's segments, plus the total.
    fn offsets(&self) -> &[usize];
    /// Properties of segment `i` of fibre `k`.
    fn props(&self, k: usize, i: usize) -> &SegmentProps;
    /// Centre and axis of segment `i` of fibre `k` at the start of the step.
    fn start(&self, k: usize, i: usize) -> (Vector3<f64>, Vector3<f64>);
    /// Centre and axis of segment `i` of fibre `k` after the free step.
    fn end(&self, k: usize, i: usize) -> (Vector3<f64>, Vector3<f64>);
    /// Fibre `k` at the start of the step (centres, axes and normals are what the solve
    /// reads of it).
    fn start_fibre(&self, k: usize) -> Fibre;
    /// Fibre `k` after the free step.
    fn end_fibre(&self, k: usize) -> Fibre;
}

/// [`Segments`] over two slices of fibres: at the start of the step and after it.
pub(crate) struct Slices<'a> {
    pub before: &'a [Fibre],
    pub after: &'a [Fibre],
    offsets: Vec<usize>,
}

impl<'a> Slices<'a> {
    pub(crate) fn new(before: &'a [Fibre], after: &'a [Fibre]) -> Self {
        Self {
            before,
            after,
            offsets: super::offsets(after),
        }
    }
}

impl Segments for Slices<'_> {
    fn offsets(&self) -> &[usize] {
        &self.offsets
    }
    fn props(&self, k: usize, i: usize) -> &SegmentProps {
        &self.after[k].props[i]
    }
    fn start(&self, k: usize, i: usize) -> (Vector3<f64>, Vector3<f64>) {
        let s = &self.before[k].segments[i];
        (s.r, s.z)
    }
    fn end(&self, k: usize, i: usize) -> (Vector3<f64>, Vector3<f64>) {
        let s = &self.after[k].segments[i];
        (s.r, s.z)
    }
    fn start_fibre(&self, k: usize) -> Fibre {
        self.before[k].clone()
    }
    fn end_fibre(&self, k: usize) -> Fibre {
        self.after[k].clone()
    }
}

/// A segment in the cell list's order, with what the tests of a pair read.
#[derive(Debug, Clone, Copy)]
struct Entry {
    /// Centre and axis at the start of the step.
    start: Vector3<f64>,
    axis: Vector3<f64>,
    /// Displacement of the centre over the free step.
    shift: Vector3<f64>,
    /// The most any point of the segment moved relative to its centre: h |Δẑ| (plus a pad).
    turn: f64,
    /// Half length and radius.
    half: f64,
    radius: f64,
    fibre: u32,
    segment: u32,
}

impl Entry {
    /// Segment `i` of fibre `k` of `s`, `pad` added to its turn.
    fn of<S: Segments>(s: &S, k: usize, i: usize, pad: f64) -> Self {
        let (r0, z0) = s.start(k, i);
        let (r1, z1) = s.end(k, i);
        let p = s.props(k, i);
        let half = 0.5 * p.shape.length;
        Entry {
            start: r0,
            axis: z0,
            shift: r1 - r0,
            turn: half * (z1 - z0).norm() + pad,
            half,
            radius: 0.5 * p.shape.diameter,
            fibre: k as u32,
            segment: i as u32,
        }
    }

    /// Centre at the middle of the step (start + half the displacement).
    fn mid(&self) -> Vector3<f64> {
        self.start + self.shift * 0.5
    }

    fn key(&self) -> (usize, usize) {
        (self.fibre as usize, self.segment as usize)
    }
}

/// What the pair scan's first tests read of a segment, 48 bytes in the order of the cells
/// (the 104-byte [`Entry`] is made again only for the pairs that pass): its mid-step
/// centre (folded into the box along the periodic directions), its displacement over the
/// step, its axis at the start, its half length, `rho` (its radius plus its turn) and its
/// fibre. In single precision, `rho` rounded out so that every pair [`pair`] may keep
/// passes [`Point::near`].
#[derive(Debug, Clone, Copy, Default)]
#[repr(C, align(16))]
struct Point {
    mid: [f32; 3],
    half: f32,
    shift: [f32; 3],
    rho: f32,
    axis: [f32; 3],
    fibre: u32,
}

impl Point {
    /// The point of entry `e` (its `rho` without the margin of the whole step's
    /// coordinates, which [`Point::near`] adds).
    fn of(e: &Entry, period: &[Option<f64>; 3]) -> Self {
        let m = e.mid();
        Point {
            mid: std::array::from_fn(|k| match period[k] {
                Some(p) => fold(m[k], p) as f32,
                None => m[k] as f32,
            }),
            half: e.half as f32,
            shift: std::array::from_fn(|k| e.shift[k] as f32),
            rho: ((e.radius + e.turn) * (1.0 + 1e-4) + 1e-4 * (e.half + e.shift.norm())) as f32,
            axis: std::array::from_fn(|k| e.axis[k] as f32),
            fibre: e.fibre,
        }
    }

    /// Whether segments `self` and `other` may come within reach in the step, by
    /// necessary conditions on what [`pair`] tests exactly: their mid-step centres within
    /// `first` (nine pairs in ten fail here), then their start segments — widened by their
    /// radii, their turns, their relative displacement and `margin2` — by the projections
    /// of the line between their centres onto itself, onto each axis and onto the normal
    /// of both axes (left out for axes within about half a degree of parallel, where it
    /// would be rounding). Nearest image along the directions whose
    /// `period` is not zero. Written so that a non-finite point passes nothing.
    #[inline(always)]
    fn near(&self, other: &Point, first2: f32, margin2: f32, period: &[f32; 3]) -> bool {
        let mut d = [0.0_f32; 3];
        for k in 0..3 {
            let mut x = other.mid[k] - self.mid[k];
            let p = period[k];
            // folded coordinates are within one period of each other: one wrap at most
            if x > 0.5 * p && p > 0.0 {
                x -= p;
            } else if x < -0.5 * p {
                x += p;
            }
            d[k] = x;
        }
        let dot = |u: &[f32; 3], v: &[f32; 3]| u[0] * v[0] + u[1] * v[1] + u[2] * v[2];
        if !(dot(&d, &d) < first2) {
            return false;
        }
        // the start centres: mid-step centre less half the displacement
        let ds: [f32; 3] = std::array::from_fn(|k| other.shift[k] - self.shift[k]);
        let d: [f32; 3] = std::array::from_fn(|k| d[k] - 0.5 * ds[k]);
        let rho = self.rho + other.rho + margin2 + dot(&ds, &ds).sqrt();
        let reach = self.half + other.half + rho;
        if !(dot(&d, &d) < reach * reach) {
            return false;
        }
        let (za, zb) = (&self.axis, &other.axis);
        let cos = dot(za, zb).abs();
        if !(dot(&d, za).abs() < self.half + other.half * cos + rho) {
            return false;
        }
        if !(dot(&d, zb).abs() < other.half + self.half * cos + rho) {
            return false;
        }
        let n = [
            za[1] * zb[2] - za[2] * zb[1],
            za[2] * zb[0] - za[0] * zb[2],
            za[0] * zb[1] - za[1] * zb[0],
        ];
        let nn = dot(&n, &n);
        if nn > 1e-4 {
            let across = dot(&d, &n);
            return across * across < rho * rho * nn;
        }
        true
    }
}

/// A dense cell list: cells of side at least `cell` (fewer along a periodic direction so
/// they tile the period), entries sorted by cell (counting sort). Rebuilt in place, so a
/// list kept from step to step allocates nothing once it has grown.
#[derive(Debug, Default)]
struct CellList {
    dims: [usize; 3],
    side: [f64; 3],
    lo: [f64; 3],
    periodic: [bool; 3],
    /// First entry of each cell (plus the total).
    start: Vec<u32>,
    /// Offsets to the cells around a cell (itself and its 26 neighbours, each cell once)
    /// and the difference of their ids away from any edge.
    around: Vec<([i64; 3], i64)>,
    /// Each point's cell and plane of cells across x, and the points by plane (the sort's
    /// first level).
    ids: Vec<u32>,
    planes: Vec<u32>,
    by_plane: Vec<u32>,
}

impl CellList {
    /// Places the `n` points `point(i)` (within `bounds` along each direction) and writes
    /// their indices in the order of the cells to `order`.
    fn rebuild(
        &mut self,
        n: usize,
        point: impl Fn(usize) -> Vector3<f64> + Sync,
        bounds: [(f64, f64); 3],
        cell: [f64; 3],
        period: &[Option<f64>; 3],
        order: &mut Vec<u32>,
    ) {
        let mut cell = cell.map(|c| c.max(1e-9));
        let (dims, side, lo, periodic) = loop {
            let mut dims = [1usize; 3];
            let mut side = cell;
            let mut lo = [0.0; 3];
            let mut periodic = [false; 3];
            for k in 0..3 {
                match period[k] {
                    Some(p) => {
                        dims[k] = ((p / cell[k]).floor() as usize).max(1);
                        side[k] = p / dims[k] as f64;
                        periodic[k] = true;
                    }
                    None => {
                        let (mn, mx) = bounds[k];
                        lo[k] = if mn.is_finite() { mn } else { 0.0 };
                        dims[k] = if mx.is_finite() {
                            ((mx - lo[k]) / cell[k]).floor() as usize + 1
                        } else {
                            1
                        };
                    }
                }
            }
            // a sparse cloud spread far apart gets larger cells, not a huge grid
            if dims.iter().product::<usize>() > 8 * n + 64 {
                cell = cell.map(|c| 2.0 * c);
                continue;
            }
            break (dims, side, lo, periodic);
        };
        self.dims = dims;
        self.side = side;
        self.lo = lo;
        self.periodic = periodic;
        self.around = self
            .offsets()
            .into_iter()
            .map(|o| {
                let d = (o[0] * dims[1] as i64 + o[1]) * dims[2] as i64 + o[2];
                (o, d)
            })
            .collect();
        let (mut ids, mut planes) = (
            std::mem::take(&mut self.ids),
            std::mem::take(&mut self.planes),
        );
        // the plane is kept beside the id: taking it from the id is an integer division
        // per point, twice, in the serial first level
        (0..n)
            .into_par_iter()
            .with_min_len(4096)
            .map(|i| {
                let c = self.coords(&point(i));
                (self.id(&c) as u32, c[0] as u32)
            })
            .unzip_into_vecs(&mut ids, &mut planes);
        // counting sort in two levels: the points by plane of cells across x (few
        // counters), then each plane's points by cell, planes in parallel (each plane's
        // counters and slots its own)
        let plane = dims[1] * dims[2];
        let cells = dims[0] * plane;
        let mut first = vec![0usize; dims[0] + 1];
        for &x in &planes {
            first[x as usize + 1] += 1;
        }
        for x in 0..dims[0] {
            first[x + 1] += first[x];
        }
        let mut by_plane = std::mem::take(&mut self.by_plane);
        by_plane.clear();
        by_plane.resize(n, 0);
        let mut next = first.clone();
        for (i, &x) in planes.iter().enumerate() {
            let x = x as usize;
            by_plane[next[x]] = i as u32;
            next[x] += 1;
        }
        order.clear();
        order.resize(n, 0);
        let start = &mut self.start;
        start.clear();
        start.resize(cells + 1, 0);
        start[cells] = n as u32;
        let mut parts = Vec::with_capacity(dims[0]);
        let (mut starts, mut slots) = (&mut start[..cells], order.as_mut_slice());
        for x in 0..dims[0] {
            let (s_head, s_tail) = std::mem::take(&mut starts).split_at_mut(plane);
            let (o_head, o_tail) = std::mem::take(&mut slots).split_at_mut(first[x + 1] - first[x]);
            parts.push((x, s_head, o_head));
            starts = s_tail;
            slots = o_tail;
        }
        let (id_of, members_of) = (&ids, &by_plane);
        parts.into_par_iter().for_each(|(x, starts, slots)| {
            let members = &members_of[first[x]..first[x + 1]];
            let base = x * plane;
            for &i in members {
                starts[id_of[i as usize] as usize - base] += 1;
            }
            let mut sum = first[x] as u32;
            for s in starts.iter_mut() {
                let count = *s;
                *s = sum;
                sum += count;
            }
            // each cell's first slot, relative to the plane's, as a cursor
            let offset = first[x] as u32;
            let mut cursor: Vec<u32> = starts.iter().map(|&s| s - offset).collect();
            for &i in members {
                let c = id_of[i as usize] as usize - base;
                slots[cursor[c] as usize] = i;
                cursor[c] += 1;
            }
        });
        self.by_plane = by_plane;
        self.ids = ids;
        self.planes = planes;
    }

    /// The cell coordinates of `r`, clamped to the grid (clamping keeps points within a
    /// cell's side of each other in neighbouring cells).
    fn coords(&self, r: &Vector3<f64>) -> [i64; 3] {
        std::array::from_fn(|k| {
            let x = if self.periodic[k] {
                fold(r[k], self.side[k] * self.dims[k] as f64)
            } else {
                r[k] - self.lo[k]
            };
            // truncation, not `floor` (a call into the C library on the baseline x86-64
            // target): the two differ only below zero, where both clamp to cell 0
            ((x / self.side[k]) as i64).clamp(0, self.dims[k] as i64 - 1)
        })
    }

    fn id(&self, c: &[i64; 3]) -> usize {
        (c[0] as usize * self.dims[1] + c[1] as usize) * self.dims[2] + c[2] as usize
    }

    fn coords_of(&self, id: usize) -> [i64; 3] {
        let z = id % self.dims[2];
        let y = (id / self.dims[2]) % self.dims[1];
        let x = id / (self.dims[1] * self.dims[2]);
        [x as i64, y as i64, z as i64]
    }

    /// Away from every edge: all 26 neighbours are `id + difference`.
    fn inner(&self, c: &[i64; 3]) -> bool {
        (0..3).all(|k| c[k] >= 1 && c[k] + 1 < self.dims[k] as i64)
    }

    /// Offsets to the cells around a cell (itself and its 26 neighbours), each cell once:
    /// along a periodic direction of one or two cells, −1 and +1 are the same cell.
    fn offsets(&self) -> Vec<[i64; 3]> {
        let along = |k: usize| -> Vec<i64> {
            match (self.periodic[k], self.dims[k]) {
                (true, 1) => vec![0],
                (true, 2) => vec![0, 1],
                _ => vec![-1, 0, 1],
            }
        };
        let mut out = Vec::with_capacity(27);
        for &dx in &along(0) {
            for &dy in &along(1) {
                for &dz in &along(2) {
                    out.push([dx, dy, dz]);
                }
            }
        }
        out
    }

    /// The cell at `offset` from cell coordinates `c` (None beyond a non-periodic edge).
    fn neighbour(&self, c: &[i64; 3], offset: &[i64; 3]) -> Option<usize> {
        let mut n = [0i64; 3];
        for k in 0..3 {
            // offsets are −1, 0 or +1: one wrap at most
            let m = self.dims[k] as i64;
            n[k] = c[k] + offset[k];
            if n[k] < 0 || n[k] >= m {
                if !self.periodic[k] {
                    return None;
                }
                n[k] -= n[k].signum() * m;
            }
        }
        Some(self.id(&n))
    }

    /// Every cell around cell `id` (itself included), each once.
    fn cells_around(&self, id: usize, mut visit: impl FnMut(usize)) {
        let c = self.coords_of(id);
        if self.inner(&c) {
            for &(_, d) in &self.around {
                visit((id as i64 + d) as usize);
            }
        } else {
            for (o, _) in &self.around {
                if let Some(n) = self.neighbour(&c, o) {
                    visit(n);
                }
            }
        }
    }

    /// The slots of every cell that may hold points within `radius[k]` of `r` along each
    /// direction k (the cells the box r ± radius touches, each once), as runs along z:
    /// the cells of one column along z are contiguous in the sorted entries, so a run is
    /// read with two lookups instead of two per cell (at most two runs a column across a
    /// periodic edge).
    fn runs_within(
        &self,
        r: &Vector3<f64>,
        radius: [f64; 3],
        mut visit: impl FnMut(std::ops::Range<usize>),
    ) {
        // the cells along direction k as at most two ranges of cell coordinates
        let along = |k: usize| -> [Option<(i64, i64)>; 2] {
            let n = self.dims[k] as i64;
            let x = if self.periodic[k] {
                r[k].rem_euclid(self.side[k] * self.dims[k] as f64)
            } else {
                r[k] - self.lo[k]
            };
            let lo = ((x - radius[k]) / self.side[k]).floor();
            let hi = ((x + radius[k]) / self.side[k]).floor();
            if !(lo.is_finite() && hi.is_finite()) {
                return [None, None];
            }
            let (lo, hi) = (lo as i64, hi as i64);
            if self.periodic[k] {
                if hi - lo + 1 >= n {
                    [Some((0, n - 1)), None]
                } else {
                    let (a, b) = (lo.rem_euclid(n), hi.rem_euclid(n));
                    if a <= b {
                        [Some((a, b)), None]
                    } else {
                        [Some((a, n - 1)), Some((0, b))]
                    }
                }
            } else if lo.max(0) <= hi.min(n - 1) {
                [Some((lo.max(0), hi.min(n - 1))), None]
            } else {
                [None, None]
            }
        };
        let (xs, ys, zs) = (along(0), along(1), along(2));
        for (x0, x1) in xs.into_iter().flatten() {
            for x in x0..=x1 {
                for (y0, y1) in ys.into_iter().flatten() {
                    for y in y0..=y1 {
                        for (z0, z1) in zs.into_iter().flatten() {
                            let (a, b) = (self.id(&[x, y, z0]), self.id(&[x, y, z1]));
                            visit(self.start[a] as usize..self.start[b + 1] as usize);
                        }
                    }
                }
            }
        }
    }
}

/// `x.rem_euclid(period)`, bit for bit, without the floating remainder (a call into the C
/// library on the baseline x86-64 target) for a point within one period of the box.
#[inline(always)]
fn fold(x: f64, period: f64) -> f64 {
    if (0.0..period).contains(&x) {
        x
    } else if x < 0.0 && x > -period {
        // rem_euclid: x % period is x itself here, then + period
        x + period
    } else if x >= period && x < 2.0 * period {
        // the remainder is exact: x − period
        x - period
    } else {
        x.rem_euclid(period)
    }
}

/// A segment's centre, axis, half length and radius.
type Pose = (Vector3<f64>, Vector3<f64>, f64, f64);

/// A little slack on the necessary conditions the search tests before the exact one, so
/// rounding in them never drops a pair the exact test would keep.
fn slack(limit: f64) -> f64 {
    limit * (1.0 + 1e-9) + 1e-12
}

/// The candidate pair of segments a and b (a before b in fibre-major order) from their
/// ends and axes at the moment the pair's side is taken, if their centre-lines come within
/// their contact distance plus `skin` (the old pairs' rule of [`Search::pairs`], the fresh
/// ones' of [`Search::around`] with no skin).
#[allow(clippy::too_many_arguments)]
fn candidate(
    a: (usize, usize),
    b: (usize, usize),
    (ra, za, ha, rad_a): Pose,
    (rb, zb, hb, rad_b): Pose,
    skin: f64,
    period: &[Option<f64>; 3],
) -> Option<Candidate> {
    let reach = rad_a + rad_b;
    let shift = image_shift(&ra, &rb, period);
    let between = rb + shift - ra;
    let limit = ha + hb + rad_a + rad_b + skin;
    // written so that a non-finite position keeps no pair (every comparison with NaN fails)
    if !(between.dot(&between) < limit * limit) {
        return None;
    }
    let (pa0, pa1) = (ra - za * ha, ra + za * ha);
    let (qb0, qb1) = (rb - zb * hb + shift, rb + zb * hb + shift);
    let (s, t) = closest_points(&pa0, &pa1, &qb0, &qb1);
    let v = (pa0 + (pa1 - pa0) * s) - (qb0 + (qb1 - qb0) * t);
    let dist = v.norm();
    if !(dist < reach + skin) {
        return None;
    }
    let normal0 = if dist > 1e-12 * reach {
        v / dist
    } else {
        // centre-lines meeting: any direction across both axes
        let z = za.cross(&zb);
        if z.norm() > 1e-12 {
            z.normalize()
        } else {
            Vector3::y()
        }
    };
    Some(Candidate {
        a,
        b,
        shift,
        normal0,
        reach,
        impulse: Vector3::zeros(),
        at: None,
        joined: false,
    })
}

/// How a segment moved from one pose to another: its centre's displacement, and the most
/// any of its points moved relative to the centre (h |Δẑ|).
fn motion((was, now): &(Pose, Pose)) -> (Vector3<f64>, f64) {
    (now.0 - was.0, now.2 * (now.1 - was.1).norm())
}

/// Most moments at which [`fresh_pair`] looks along a pair's way (enough for a relative
/// motion of 2048 contact distances within the step).
const MAX_WAY_MOMENTS: u32 = 4096;

/// A pair found after a round of corrections ([`Search::around`]), segments a and b each
/// at the start of the step and now, if it overlaps now: centre-lines closer than the
/// contact distance by more than 10⁻⁶ of it. Its side: where they are now, unless their
/// centre-lines came within half a contact distance of each other somewhere on the
/// straight way from the start to now — then they may have been pushed through each
/// other, and the pair keeps the side it had at the start (an overlap deeper than d to
/// undo). The way is looked at often enough that no passage closer than a quarter contact
/// distance falls between two looks, however far the pair moved. A pair far apart at the
/// start whose closest points merely turned keeps its side where it is.
fn fresh_pair(
    a: (usize, usize),
    pa: (Pose, Pose),
    b: (usize, usize),
    pb: (Pose, Pose),
    period: &[Option<f64>; 3],
) -> Option<Candidate> {
    let (a, b, pa, pb) = if a < b {
        (a, b, pa, pb)
    } else {
        (b, a, pb, pa)
    };
    let ((da, ta), (db, tb)) = (motion(&pa), motion(&pb));
    let skin = (da - db).norm() + ta + tb;
    let mut c = candidate(a, b, pa.0, pb.0, skin, period)?;
    let ends = |p: &Pose, shift: Vector3<f64>| (p.0 - p.1 * p.2 + shift, p.0 + p.1 * p.2 + shift);
    let separation = |(p0, p1): (Vector3<f64>, Vector3<f64>),
                      (q0, q1): (Vector3<f64>, Vector3<f64>)| {
        let (u, v) = closest_points(&p0, &p1, &q0, &q1);
        (p0 + (p1 - p0) * u) - (q0 + (q1 - q0) * v)
    };
    let zero = Vector3::zeros();
    let w = separation(ends(&pa.1, zero), ends(&pb.1, c.shift));
    let dist = w.norm();
    if !(dist < c.reach * (1.0 - 1e-6)) {
        return None;
    }
    let (a0, a1) = (ends(&pa.0, zero), ends(&pa.1, zero));
    let (b0, b1) = (ends(&pb.0, c.shift), ends(&pb.1, c.shift));
    let lerp = |x: (Vector3<f64>, Vector3<f64>), y: (Vector3<f64>, Vector3<f64>), t: f64| {
        (x.0 + (y.0 - x.0) * t, x.1 + (y.1 - x.1) * t)
    };
    // the separation changes by at most `skin` over the way, so moments 1/n apart with
    // n ≥ 2 skin / reach find every passage closer than a quarter contact distance
    let n = ((2.0 * skin / c.reach).ceil() as u32).clamp(16, MAX_WAY_MOMENTS);
    let passed = (0..=n).any(|k| {
        let t = f64::from(k) / f64::from(n);
        separation(lerp(a0, a1, t), lerp(b0, b1, t)).norm() < 0.5 * c.reach
    });
    // passed close: the side at the start (in `c`); else where they are now
    if !passed && dist > 1e-12 * c.reach {
        c.normal0 = w / dist;
    }
    Some(c)
}

/// The candidate pair of two segments in the step ([`Search::pairs`]): segments of
/// different fibres, or non-adjacent segments of one fibre (adjacent ones share a joint),
/// whose mid-step centres are close enough for them to touch at some
/// moment of the step — within (l_a + l_b)/2 + (d_a + d_b)/2 + |Δr_a − Δr_b|/2 + turn_a +
/// turn_b, and along each direction k within the same with |Δr_a,k − Δr_b,k|/2, necessary
/// conditions — and whose centre-lines at the start are within their
/// contact distance plus the skin |Δr_a − Δr_b| + turn_a + turn_b ([`candidate`]).
/// `first` is a bound on the first distance that every pair's exceeds.
fn pair(ea: &Entry, eb: &Entry, first: f64, period: &[Option<f64>; 3]) -> Option<Candidate> {
    if ea.fibre == eb.fibre && ea.segment.abs_diff(eb.segment) < 2 {
        return None;
    }
    let (ea, eb) = if ea.key() < eb.key() {
        (ea, eb)
    } else {
        (eb, ea)
    };
    let (ma, mb) = (ea.mid(), eb.mid());
    let between = mb + image_shift(&ma, &mb, period) - ma;
    let d2 = between.dot(&between);
    if !(d2 < first * first) {
        return None;
    }
    let relative = (ea.shift - eb.shift).norm();
    let reach = ea.half + eb.half + ea.radius + eb.radius + ea.turn + eb.turn;
    let mid_limit = slack(reach + 0.5 * relative);
    if !(d2 < mid_limit * mid_limit) {
        return None;
    }
    // and along each direction with the relative displacement along it (what lets the
    // cells be narrower across a mean flow than along it)
    if !(0..3).all(|k| between[k].abs() < slack(reach + 0.5 * (ea.shift[k] - eb.shift[k]).abs())) {
        return None;
    }
    candidate(
        ea.key(),
        eb.key(),
        (ea.start, ea.axis, ea.half, ea.radius),
        (eb.start, eb.axis, eb.half, eb.radius),
        relative + ea.turn + eb.turn,
        period,
    )
}

/// A fibre with a segment whose ends turned by more than this share of its half length
/// in the step (|Δẑ| > 0.2) is searched around on its own: rarer than one fibre in a
/// thousand in a channel, and one thrown about would otherwise widen every cell.
const WILD_TURN: f64 = 0.2;

/// The cell list of one step over every segment's mid-step centre. Kept from step to step
/// (by the group) for its allocations; [`Search::rebuild`] places the step's segments.
#[derive(Debug, Default)]
pub(crate) struct Search {
    cells: CellList,
    /// The `pad` of the last rebuild (the entries are made again from the segments where
    /// the exact tests need them).
    pad: f64,
    /// Every segment's [`Point`], fibre-major, then in the order of the cells.
    points: Vec<Point>,
    sorted: Vec<Point>,
    /// The segments' fibre-major indices in the order of the cells.
    order: Vec<u32>,
    /// What [`Point`]s fold by along each direction (0: not periodic), and the margin
    /// for their rounding.
    period32: [f32; 3],
    margin: f64,
    /// Centre of the box of all the step's displacements: |Δr − this| ≤ `spread` for
    /// every segment.
    centre_shift: Vector3<f64>,
    spread: f64,
    /// Half the box's extent along each direction: |Δr_k − centre_shift_k| ≤
    /// `spread_along[k]` (a mean flow along x spreads the displacements along x alone).
    spread_along: Vector3<f64>,
    longest: f64,
    widest: f64,
    most_turn: f64,
    /// The same of the fibres not [`Self::wild`], which the cells are sized for.
    bulk_spread: f64,
    bulk_spread_along: Vector3<f64>,
    bulk_most_turn: f64,
    /// Fibres with a segment that turned by more than [`WILD_TURN`] in the step (a fibre
    /// thrown about by the flow or by last step's contact), ascending: each is searched
    /// around on its own, so that it does not widen every cell.
    wild: Vec<u32>,
    period: [Option<f64>; 3],
    /// Where the contact solves that used this search spent their time, summed.
    pub(crate) spent: super::ContactTime,
}

/// Only working memory: a copy starts empty (the next step rebuilds it).
impl Clone for Search {
    fn clone(&self) -> Self {
        Self::default()
    }
}

impl Search {
    /// Places every segment of `s` by its mid-step centre; `pad` is added to every
    /// segment's turn (a skin that finds pairs within it, for [`super::touching`]).
    pub(crate) fn new<S: Segments>(s: &S, period: &[Option<f64>; 3], pad: f64) -> Self {
        let mut search = Self::default();
        search.rebuild(s, period, pad);
        search
    }

    /// [`Self::new`] in the memory of an earlier step.
    pub(crate) fn rebuild<S: Segments>(&mut self, s: &S, period: &[Option<f64>; 3], pad: f64) {
        let offsets = s.offsets();
        let fibres = offsets.len().saturating_sub(1);
        let total = offsets.last().copied().unwrap_or(0);
        // every point is written below (the runs cover every fibre): the memory of the
        // last step is only cleared when the count changed
        if self.points.len() != total {
            self.points.clear();
            self.points.resize(total, Point::default());
        }
        self.pad = pad;
        // runs of fibres, each writing its own contiguous share
        const RUN: usize = 512;
        let mut runs = Vec::with_capacity(fibres.div_ceil(RUN));
        let mut rest = self.points.as_mut_slice();
        for first in (0..fibres).step_by(RUN) {
            let last = (first + RUN).min(fibres);
            let (head, tail) =
                std::mem::take(&mut rest).split_at_mut(offsets[last] - offsets[first]);
            runs.push((first, last, head));
            rest = tail;
        }
        // the segments' extents (what the cells' size and the grid's bounds are taken
        // from) in the same pass: min and max are exact, so the threads' order does not
        // change them
        #[derive(Clone, Copy)]
        struct Extent {
            lo: Vector3<f64>,
            hi: Vector3<f64>,
            mid_lo: Vector3<f64>,
            mid_hi: Vector3<f64>,
            half: f64,
            radius: f64,
            turn: f64,
        }
        let none = Extent {
            lo: Vector3::repeat(f64::INFINITY),
            hi: Vector3::repeat(f64::NEG_INFINITY),
            mid_lo: Vector3::repeat(f64::INFINITY),
            mid_hi: Vector3::repeat(f64::NEG_INFINITY),
            half: 0.0,
            radius: 0.0,
            turn: 0.0,
        };
        let join = |a: Extent, b: Extent| Extent {
            lo: a.lo.inf(&b.lo),
            hi: a.hi.sup(&b.hi),
            mid_lo: a.mid_lo.inf(&b.mid_lo),
            mid_hi: a.mid_hi.sup(&b.mid_hi),
            half: a.half.max(b.half),
            radius: a.radius.max(b.radius),
            turn: a.turn.max(b.turn),
        };
        // (all fibres, the fibres not wild, the wild ones)
        let none3 = || (none, none, Vec::new());
        let (ext, bulk, wild) = runs
            .into_par_iter()
            .map(|(first, last, out)| {
                let base = offsets[first];
                let (mut ext, mut bulk, mut wild) = none3();
                for k in first..last {
                    let mut fibre = none;
                    let mut thrown = false;
                    for i in 0..offsets[k + 1] - offsets[k] {
                        let e = Entry::of(s, k, i, pad);
                        out[offsets[k] + i - base] = Point::of(&e, period);
                        // a segment gone non-finite has no extent (it makes no pairs)
                        let finite = e.start.iter().chain(e.shift.iter()).all(|x| x.is_finite())
                            && e.turn.is_finite();
                        if finite {
                            let m = e.mid();
                            thrown |= e.turn - pad > WILD_TURN * e.half;
                            fibre = join(
                                fibre,
                                Extent {
                                    lo: e.shift,
                                    hi: e.shift,
                                    mid_lo: m,
                                    mid_hi: m,
                                    half: e.half,
                                    radius: e.radius,
                                    turn: e.turn,
                                },
                            );
                        }
                    }
                    ext = join(ext, fibre);
                    if thrown {
                        wild.push(k as u32);
                    } else {
                        bulk = join(bulk, fibre);
                    }
                }
                (ext, bulk, wild)
            })
            .reduce(none3, |a, mut b| {
                let mut wild = a.2;
                wild.append(&mut b.2);
                (join(a.0, b.0), join(a.1, b.1), wild)
            });
        self.wild = wild;
        (
            self.bulk_spread,
            self.bulk_spread_along,
            self.bulk_most_turn,
        ) = if bulk.lo.iter().all(|x| x.is_finite()) {
            (
                0.5 * (bulk.hi - bulk.lo).norm(),
                0.5 * (bulk.hi - bulk.lo),
                bulk.turn,
            )
        } else {
            (0.0, Vector3::zeros(), 0.0)
        };
        (self.centre_shift, self.spread, self.spread_along) = if total == 0 {
            (Vector3::zeros(), 0.0, Vector3::zeros())
        } else {
            (
                0.5 * (ext.lo + ext.hi),
                0.5 * (ext.hi - ext.lo).norm(),
                0.5 * (ext.hi - ext.lo),
            )
        };
        (self.longest, self.widest, self.most_turn) = (2.0 * ext.half, 2.0 * ext.radius, ext.turn);
        self.period = *period;
        // a pair [`pair`] keeps has mid-step centres within (l_a + l_b)/2 + D + turn_a +
        // turn_b + |Δr_a,k − Δr_b,k|/2 of each other along each direction k (their closest
        // approach is at most half their relative displacement away from the middle of the
        // step), and |Δr_a,k − Δr_b,k|/2 ≤ spread_along[k]: the cells are that wide along
        // k. In a channel the mean flow spreads the displacements along x: cells narrower
        // across it than along it hold fewer segments than cubes of the widest side
        // (the fibres not wild: the wild ones are searched around on their own)
        let reach = self.longest + self.widest + 2.0 * self.bulk_most_turn;
        let side: [f64; 3] = std::array::from_fn(|k| reach + self.bulk_spread_along[k]);
        // single precision rounds each coordinate by at most 2⁻²⁴ of its size, each axis
        // component by 2⁻²⁴: a margin of 4 × 10⁻⁶ of the largest coordinate (on the cells,
        // on `first` and on the sum of two `rho`s), with the points' own (10⁻⁴ of `rho`, of
        // the half length and of the displacement: the distance of the lines is only
        // tested where their normal is longer than 0.01), keeps every pair [`pair`] keeps,
        // the tests' own rounding included (test
        // `single_precision_tests_keep_pairs_just_within_reach`)
        let largest = (0..3)
            .map(|k| match period[k] {
                Some(p) => p.abs(),
                None => {
                    ext.mid_lo[k].abs().max(ext.mid_hi[k].abs())
                        + self.spread
                        + self.centre_shift.norm()
                }
            })
            .fold(0.0_f64, f64::max);
        self.margin = if largest.is_finite() {
            4e-6 * largest + 1e-9
        } else {
            0.0
        };
        self.period32 = std::array::from_fn(|k| period[k].map_or(0.0, |p| p as f32));
        let points = &self.points;
        let bounds = std::array::from_fn(|k| (ext.mid_lo[k], ext.mid_hi[k]));
        self.cells.rebuild(
            total,
            |i| Vector3::from(points[i].mid.map(f64::from)),
            bounds,
            side.map(|x| slack(x) + 2.0 * self.margin),
            period,
            &mut self.order,
        );
        let (sorted, order, points) = (&mut self.sorted, &self.order, &self.points);
        order
            .par_iter()
            .with_min_len(4096)
            .map(|&g| points[g as usize])
            .collect_into_vec(sorted);
    }

    /// Every pair of segments that may come within their contact distance in the step
    /// ([`pair`]), in (fibre, segment) order; the side each pair is on is taken at the
    /// start. Cells are at least as wide as the largest mid-step distance of a pair, so
    /// a pair's cells are neighbours (test
    /// `the_cell_list_finds_every_pair_the_exact_test_keeps`).
    pub(crate) fn pairs<S: Segments>(&self, s: &S) -> Vec<Candidate> {
        // the scan finds the pairs of two fibres not wild (the cells are sized for them);
        // pairs with a segment of a wild fibre are found around it below
        let first =
            slack(self.longest + self.widest + self.bulk_spread + 2.0 * self.bulk_most_turn);
        let cells = &self.cells;
        let period = &self.period;
        // the scan's tests read the sorted points alone (less than half the memory of
        // their entries), in whatever order the scan meets the two; [`pair`] then tests
        // the few that pass exactly, on entries made from the segments
        let (sorted, order, period32, pad) = (&self.sorted, &self.order, &self.period32, self.pad);
        let offsets = s.offsets();
        let entry = |slot: usize| {
            let k = sorted[slot].fibre as usize;
            Entry::of(s, k, order[slot] as usize - offsets[k], pad)
        };
        // the exact tests (at 10⁵ fibres ≈ 4 × 10³ of the 2.5 × 10⁶ pairs the scan meets)
        let exact = |a: usize, b: usize, out: &mut Vec<Candidate>| {
            out.extend(pair(&entry(a), &entry(b), first, period));
        };
        // `first` in single precision, rounded out as the points' margins are
        let first32 = (first * (1.0 + 1e-4) + 2.0 * self.margin) as f32;
        let first2 = first32 * first32;
        let margin2 = (2.0 * self.margin) as f32;
        let test = |a: usize, b: usize, out: &mut Vec<Candidate>| {
            let (pa, pb) = (&sorted[a], &sorted[b]);
            // neighbours along one fibre (a quarter of the pairs the scan meets) share a
            // joint, not a contact: their indices are next to each other in fibre-major order
            if pa.fibre == pb.fibre && order[a].abs_diff(order[b]) < 2 {
                return;
            }
            if pa.near(pb, first2, margin2, period32) {
                exact(a, b, out);
            }
        };
        let [nx, ny, nz] = cells.dims;
        let start = &cells.start;
        let at = |x: usize, y: usize, z: usize| (x * ny + y) * nz + z;
        // one plane of cells across x at a time: away from the edges, the cells after a
        // cell in id order among its neighbours are the rest of its own column along z
        // (its next cell) and three cells of four neighbouring columns, contiguous in
        // the sorted entries; at an edge every neighbour is looked up
        let plane = |x: usize| -> Vec<Candidate> {
            let mut out = Vec::new();
            for y in 0..ny {
                for z in 0..nz {
                    let id = at(x, y, z);
                    let here = start[id] as usize..start[id + 1] as usize;
                    if here.is_empty() {
                        continue;
                    }
                    let inner =
                        x >= 1 && x + 1 < nx && y >= 1 && y + 1 < ny && z >= 1 && z + 1 < nz;
                    if inner {
                        let next = start[id + 2] as usize;
                        for a in here.clone() {
                            for b in a + 1..next {
                                test(a, b, &mut out);
                            }
                        }
                        for (cx, cy) in [(x, y + 1), (x + 1, y - 1), (x + 1, y), (x + 1, y + 1)] {
                            let column = at(cx, cy, z);
                            let range = start[column - 1] as usize..start[column + 2] as usize;
                            for a in here.clone() {
                                for b in range.clone() {
                                    test(a, b, &mut out);
                                }
                            }
                        }
                    } else {
                        cells.cells_around(id, |n| {
                            // each pair of cells once, and each pair within a cell once
                            if n < id {
                                return;
                            }
                            for a in here.clone() {
                                let from = if n == id { a + 1 } else { start[n] as usize };
                                for b in from..start[n + 1] as usize {
                                    test(a, b, &mut out);
                                }
                            }
                        });
                    }
                }
            }
            out
        };
        let mut out: Vec<Candidate> = (0..nx).into_par_iter().flat_map_iter(plane).collect();
        // around every segment of a wild fibre, every segment whose mid-step centre may be
        // within reach along each direction (a pair with a mid-step distance beyond the
        // cells' reach has a segment of a wild fibre)
        let first_all = slack(self.longest + self.widest + self.spread + 2.0 * self.most_turn);
        let wild: Vec<Candidate> = self
            .wild
            .par_iter()
            .flat_map_iter(|&k| {
                let k = k as usize;
                let mut found = Vec::new();
                for i in 0..offsets[k + 1] - offsets[k] {
                    let ew = Entry::of(s, k, i, pad);
                    let mid = ew.mid();
                    let radius: [f64; 3] = std::array::from_fn(|a| {
                        slack(
                            ew.half
                                + ew.radius
                                + ew.turn
                                + 0.5 * self.longest
                                + 0.5 * self.widest
                                + self.most_turn
                                + 0.5
                                    * ((ew.shift[a] - self.centre_shift[a]).abs()
                                        + self.spread_along[a]),
                        ) + 2.0 * self.margin
                    });
                    cells.runs_within(&mid, radius, |run| {
                        for slot in run {
                            found.extend(pair(&ew, &entry(slot), first_all, period));
                        }
                    });
                }
                found
            })
            .collect();
        out.extend(wild);
        // the pairs are unique once the wild fibres' are merged, so this order is the
        // same whatever the threads did
        out.par_sort_unstable_by_key(|c| (c.a, c.b));
        out.dedup_by_key(|c| (c.a, c.b));
        out
    }

    /// Pairs with a segment of a fibre in `moved` (ascending: the fibres a round of
    /// corrections moved) that overlap now, in (fibre, segment) order, each once. As the
    /// step's pairs do, a pair keeps the side it was on at the start of the step, with the
    /// fibres' whole motion since (free step and corrections) as the skin: a correction
    /// that pushed a fibre through another (in a crowded floc they can be larger than a
    /// diameter; a locked island moves from where it started) is an overlap deeper than
    /// d, not a pair on the other side. `fibres` and `before` hold the fibres the solve
    /// has corrected (`corrected[k]`) now and at the start; every other fibre is where
    /// the free step left it.
    ///
    /// A pair that overlaps now has centres within h_a + h_b + r_a + r_b of each other
    /// now, whatever either did in the step, so that is all the search asks ([`fresh_pair`]
    /// then decides each pair): the fibres no round has corrected are found in the step's
    /// list by their mid-step centres, half their displacement from where they are now.
    pub(crate) fn around<S: Segments>(
        &self,
        s: &S,
        fibres: &[Fibre],
        before: &[Fibre],
        corrected: &[bool],
        moved: &[usize],
    ) -> Vec<Candidate> {
        let period = &self.period;
        // a corrected segment at the start of the step and now: centre, axis, half
        // length, radius
        let poses = |k: usize, i: usize| -> (Pose, Pose) {
            let p = &fibres[k].props[i];
            let (h, r) = (0.5 * p.shape.length, 0.5 * p.shape.diameter);
            let (was, now) = (&before[k].segments[i], &fibres[k].segments[i]);
            ((was.r, was.z, h, r), (now.r, now.z, h, r))
        };
        // the corrected fibres' segments, in their own small list by where they are now
        let here: Vec<(usize, usize)> = (0..fibres.len())
            .filter(|&k| corrected[k])
            .flat_map(|k| (0..fibres[k].len()).map(move |i| (k, i)))
            .collect();
        let centres: Vec<Vector3<f64>> = here.iter().map(|&(k, i)| poses(k, i).1 .0).collect();
        let mut near = CellList::default();
        let mut order = Vec::new();
        let bounds = std::array::from_fn(|k| {
            centres
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), r| {
                    (a.min(r[k]), b.max(r[k]))
                })
        });
        near.rebuild(
            centres.len(),
            |i| centres[i],
            bounds,
            [slack(self.longest + self.widest); 3],
            period,
            &mut order,
        );
        // the pair of segments a and b (each at the start and now), oriented, if it
        // overlaps now on its side at the start
        let mut out: Vec<Candidate> = moved
            .par_iter()
            .flat_map_iter(|&q| {
                let mut found = Vec::new();
                for i in 0..fibres[q].len() {
                    let pq = poses(q, i);
                    let (now_q, hq, rq) = (pq.1 .0, pq.1 .2, pq.1 .3);
                    // fibres no round has moved, in the step's list by their mid-step
                    // centre: where they are now less half their displacement, which is
                    // within spread_along[k] of half the centre of all displacements
                    // along each direction k (the points' own rounding as the cells')
                    let from = now_q - self.centre_shift * 0.5;
                    let radius: [f64; 3] = std::array::from_fn(|k| {
                        slack(
                            hq + rq
                                + 0.5 * self.longest
                                + 0.5 * self.widest
                                + 0.5 * self.spread_along[k],
                        ) + 2.0 * self.margin
                    });
                    // where it is now in single precision, folded as the points are, for a
                    // first test on the points (read one after another in the cells'
                    // order) before the segment's own numbers are read: the point's centre
                    // now is its mid-step centre plus half its displacement, rounded within
                    // the step's margin along each direction
                    let now32: [f32; 3] = std::array::from_fn(|k| match period[k] {
                        Some(p) => fold(now_q[k], p) as f32,
                        None => now_q[k] as f32,
                    });
                    let (reach32, margin32) = ((hq + rq) as f32, (4.0 * self.margin) as f32);
                    self.cells.runs_within(&from, radius, |run| {
                        for slot in run {
                            let pb = &self.sorted[slot];
                            let kb = pb.fibre as usize;
                            if kb == q || corrected[kb] {
                                continue;
                            }
                            let mut d2 = 0.0_f32;
                            for k in 0..3 {
                                let mut x = pb.mid[k] + 0.5 * pb.shift[k] - now32[k];
                                let p = self.period32[k];
                                if x > 0.5 * p && p > 0.0 {
                                    x -= p;
                                } else if x < -0.5 * p {
                                    x += p;
                                }
                                d2 += x * x;
                            }
                            let lim = (reach32 + pb.half + pb.rho) * (1.0 + 1e-4) + margin32;
                            if !(d2 < lim * lim) {
                                continue;
                            }
                            let ib = self.order[slot] as usize - s.offsets()[kb];
                            let (rb, zb) = s.end(kb, ib);
                            let d = rb + image_shift(&now_q, &rb, period) - now_q;
                            let p = s.props(kb, ib);
                            let (hb, radb) = (0.5 * p.shape.length, 0.5 * p.shape.diameter);
                            let limit = slack(hq + rq + hb + radb);
                            if !(d.dot(&d) < limit * limit) {
                                continue;
                            }
                            let (ra, za) = s.start(kb, ib);
                            found.extend(fresh_pair(
                                (q, i),
                                pq,
                                (kb, ib),
                                ((ra, za, hb, radb), (rb, zb, hb, radb)),
                                period,
                            ));
                        }
                    });
                    // the corrected fibres, by where they are now
                    let radius = slack(hq + rq + 0.5 * self.longest + 0.5 * self.widest);
                    near.runs_within(&now_q, [radius; 3], |run| {
                        for &j in &order[run] {
                            let (kb, ib) = here[j as usize];
                            if kb != q || ib.abs_diff(i) >= 2 {
                                found.extend(fresh_pair(
                                    (q, i),
                                    pq,
                                    (kb, ib),
                                    poses(kb, ib),
                                    period,
                                ));
                            }
                        }
                    });
                }
                found
            })
            .collect();
        out.par_sort_unstable_by_key(|c| (c.a, c.b));
        out.dedup_by_key(|c| (c.a, c.b));
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The cell coordinates fold without the library remainder and truncate instead of
    /// `floor`: the same bits and the same cells as the library's, inside the box, one
    /// period either side, on the edges and far away.
    #[test]
    fn folding_is_the_remainder_and_cells_are_the_floor() {
        let period = 942.477_796_076_938;
        let mut xs = vec![
            0.0,
            -0.0,
            period,
            -period,
            2.0 * period,
            -1e-300,
            1e-300,
            period - 1e-13,
            -period + 1e-13,
            5.5 * period,
            -7.25 * period,
            f64::NAN,
            f64::INFINITY,
        ];
        let mut rng = Rng(7);
        for _ in 0..100_000 {
            xs.push((rng.next() * 6.0 - 3.0) * period);
        }
        for &x in &xs {
            let (got, want) = (fold(x, period), x.rem_euclid(period));
            assert!(
                got.to_bits() == want.to_bits() || (got.is_nan() && want.is_nan()),
                "{x}: {got} against {want}"
            );
        }
        let cells = CellList {
            dims: [283, 91, 141],
            side: [period / 283.0, 3.3, 471.2 / 141.0],
            lo: [0.0, -150.0, 0.0],
            periodic: [true, false, true],
            ..Default::default()
        };
        for w in xs.windows(3) {
            let r = Vector3::new(w[0], w[1] / period * 200.0, w[2] / 2.0);
            let want: [i64; 3] = std::array::from_fn(|k| {
                let x = if cells.periodic[k] {
                    r[k].rem_euclid(cells.side[k] * cells.dims[k] as f64)
                } else {
                    r[k] - cells.lo[k]
                };
                ((x / cells.side[k]).floor() as i64).clamp(0, cells.dims[k] as i64 - 1)
            });
            assert_eq!(cells.coords(&r), want, "{r:?}");
        }
    }
    use crate::contact::geometry;

    /// A small deterministic generator (xorshift64*), uniform in [0, 1).
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> f64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
        }
        fn vector(&mut self, scale: f64) -> Vector3<f64> {
            Vector3::new(self.next() - 0.5, self.next() - 0.5, self.next() - 0.5) * 2.0 * scale
        }
    }

    const PERIOD: [Option<f64>; 3] = [Some(24.0), None, Some(18.0)];

    /// `n` seven-segment fibres (l = 3, d = 0.8) at random in a box periodic in x and z,
    /// and the same fibres after a step: each moved by the shift `motion` gives it (from
    /// its index and centre) and each segment jittered and turned by up to the turn it
    /// gives.
    fn moved_fibres(
        seed: u64,
        n: usize,
        motion: impl Fn(usize, &Vector3<f64>, &mut Rng) -> (Vector3<f64>, f64),
    ) -> (Vec<Fibre>, Vec<Fibre>) {
        let mut rng = Rng(seed);
        let mut before = Vec::new();
        let mut after = Vec::new();
        for k in 0..n {
            let centre = Vector3::new(
                24.0 * rng.next(),
                12.0 * rng.next() - 6.0,
                18.0 * rng.next(),
            );
            let axis = rng.vector(1.0).normalize();
            let f = Fibre::straight(centre, axis, &[3.0; 7], &[0.8; 7], 1000.0).unwrap();
            let mut g = f.clone();
            let (shift, turn) = motion(k, &centre, &mut rng);
            for s in g.segments.iter_mut() {
                s.r += shift + rng.vector(0.05);
                s.z = (s.z + rng.vector(turn)).normalize();
            }
            before.push(f);
            after.push(g);
        }
        (before, after)
    }

    /// 60 fibres: most moved by up to 0.3, every tenth by up to 4 (a large spread of
    /// displacements), each segment turned by up to 0.1 (bending).
    fn start_and_end(seed: u64) -> (Vec<Fibre>, Vec<Fibre>) {
        moved_fibres(seed, 60, |k, _, rng| {
            (rng.vector(if k % 10 == 0 { 4.0 } else { 0.3 }), 0.1)
        })
    }

    /// 150 fibres moved by a mean flow along x that grows across y (from 0 to 6 over the
    /// box's 12, as near a wall) and by up to 0.15 along each direction besides; with
    /// `thrown`, every 25th fibre is instead thrown by up to 6 along each direction and its
    /// segments turned far (wild fibres, searched around on their own).
    fn in_a_mean_flow(seed: u64, thrown: bool) -> (Vec<Fibre>, Vec<Fibre>) {
        moved_fibres(seed, 150, |k, centre, rng| {
            if thrown && k.is_multiple_of(25) {
                (rng.vector(6.0), 1.0)
            } else {
                let flow = Vector3::new(0.5 * (centre.y + 6.0), 0.0, 0.0);
                (flow + rng.vector(0.15), 0.1)
            }
        })
    }

    fn same(a: &[Candidate], b: &[Candidate]) -> bool {
        a.len() == b.len()
            && a.iter().zip(b).all(|(x, y)| {
                x.a == y.a
                    && x.b == y.b
                    && x.shift == y.shift
                    && x.normal0 == y.normal0
                    && x.reach.to_bits() == y.reach.to_bits()
            })
    }

    /// The step's search over `before` → `after`, what its scan finds and what a test of
    /// every pair keeps.
    fn scanned(before: &[Fibre], after: &[Fibre]) -> (Search, Vec<Candidate>, Vec<Candidate>) {
        let s = Slices::new(before, after);
        let search = Search::new(&s, &PERIOD, 0.0);
        let found = search.pairs(&s);
        let expected = all_pairs(&s, &search);
        (search, found, expected)
    }

    /// Each trial k's pair of fibres 2k and 2k + 1 is among `expected`.
    fn assert_every_trial_kept(expected: &[Candidate], trials: usize) {
        for k in 0..trials {
            assert!(
                expected
                    .iter()
                    .any(|c| c.a == (2 * k, 0) && c.b == (2 * k + 1, 0)),
                "the exact test dropped trial {k}"
            );
        }
    }

    fn assert_found(seed: u64, found: &[Candidate], expected: &[Candidate]) {
        assert!(
            same(found, expected),
            "seed {seed}: {} found, {} expected",
            found.len(),
            expected.len()
        );
    }

    /// Every pair of segments of different fibres, and of non-adjacent segments of one
    /// fibre, by [`pair`] alone (no cell list).
    fn all_pairs<S: Segments>(s: &S, search: &Search) -> Vec<Candidate> {
        let offsets = s.offsets();
        let e: Vec<Entry> = (0..offsets.len() - 1)
            .flat_map(|k| (0..offsets[k + 1] - offsets[k]).map(move |i| (k, i)))
            .map(|(k, i)| Entry::of(s, k, i, search.pad))
            .collect();
        let mut out = Vec::new();
        for (n, ea) in e.iter().enumerate() {
            for eb in &e[n + 1..] {
                out.extend(pair(ea, eb, f64::INFINITY, &search.period));
            }
        }
        out
    }

    /// Every pair of segments (of different fibres, or non-adjacent ones of one fibre),
    /// one of them `moved`, that may have
    /// come within reach between `was` (the start of the step) and `now` (skin: their
    /// relative motion and turns) and overlaps now on the side it was on in `was`.
    fn all_overlaps(was: &[Fibre], now: &[Fibre], moved: &[usize]) -> Vec<Candidate> {
        all_overlaps_in(was, now, moved, &PERIOD)
    }

    /// [`all_overlaps`] in a box of `period`.
    fn all_overlaps_in(
        was: &[Fibre],
        now: &[Fibre],
        moved: &[usize],
        period: &[Option<f64>; 3],
    ) -> Vec<Candidate> {
        let segs: Vec<(usize, usize)> = (0..now.len())
            .flat_map(|k| (0..now[k].len()).map(move |i| (k, i)))
            .collect();
        let pose = |f: &[Fibre], k: usize, i: usize| {
            let (s, p) = (&f[k].segments[i], &f[k].props[i]);
            (s.r, s.z, 0.5 * p.shape.length, 0.5 * p.shape.diameter)
        };
        let mut out = Vec::new();
        for (n, &(ka, ia)) in segs.iter().enumerate() {
            for &(kb, ib) in &segs[n + 1..] {
                if (ka == kb && ia.abs_diff(ib) < 2)
                    || !(moved.contains(&ka) || moved.contains(&kb))
                {
                    continue;
                }
                out.extend(fresh_pair(
                    (ka, ia),
                    (pose(was, ka, ia), pose(now, ka, ia)),
                    (kb, ib),
                    (pose(was, kb, ib), pose(now, kb, ib)),
                    period,
                ));
            }
        }
        out
    }

    /// A pair pushed through each other keeps its side at the start (an overlap deeper
    /// than d); a pair that was far apart and only turned into touch takes its side where
    /// it is now.
    #[test]
    fn a_pair_pushed_through_keeps_its_side_and_one_that_turned_takes_its_own() {
        let seg = |r: Vector3<f64>, z: Vector3<f64>| (r, z, 1.5, 0.116);
        // b along z at the origin; a along x, 0.3 above, pushed to 0.1 below
        let b = seg(Vector3::zeros(), Vector3::z());
        let c = fresh_pair(
            (0, 0),
            (
                seg(Vector3::new(0.0, 0.3, 0.0), Vector3::x()),
                seg(Vector3::new(0.0, -0.1, 0.0), Vector3::x()),
            ),
            (1, 0),
            (b, b),
            &[None; 3],
        )
        .unwrap();
        assert!(c.normal0.y > 0.99, "{:?}", c.normal0);
        // a along x, its end 2 to the side of b and 1 below, moved so its end meets b from
        // above: never closer than 0.17 on the way (the side at the start, from b to a's
        // end, points down)
        let c = fresh_pair(
            (0, 0),
            (
                seg(Vector3::new(3.5, -1.0, 0.0), Vector3::x()),
                seg(Vector3::new(1.5, 0.2, 0.0), Vector3::x()),
            ),
            (1, 0),
            (b, b),
            &[None; 3],
        )
        .unwrap();
        assert!(c.normal0.y > 0.99, "{:?}", c.normal0);
    }

    /// A segment pushed fast through another within one step (40 d across, ending 0.6 d
    /// on the far side) passes it between any 17 evenly spaced moments of its way; the
    /// way is looked at often enough for its motion, so the pair keeps its start side.
    #[test]
    fn a_pair_pushed_fast_through_keeps_its_side_however_far_it_moved() {
        let d = 0.232;
        let seg = |r: Vector3<f64>, z: Vector3<f64>| (r, z, 1.5, 0.5 * d);
        let b = seg(Vector3::zeros(), Vector3::z());
        let (from, to) = (40.0 * d, -0.6 * d);
        // at 17 moments the closest is 15/16 of the way: still above half a diameter
        let at = |t: f64| from + (to - from) * t;
        assert!(at(15.0 / 16.0) > 0.5 * d && at(1.0).abs() > 0.5 * d);
        let c = fresh_pair(
            (0, 0),
            (
                seg(Vector3::new(0.0, from, 0.0), Vector3::x()),
                seg(Vector3::new(0.0, to, 0.0), Vector3::x()),
            ),
            (1, 0),
            (b, b),
            &[None; 3],
        )
        .unwrap();
        assert!(c.normal0.y > 0.99, "took the far side: {:?}", c.normal0);
    }

    /// Pairs placed just within reach (centre-lines 10⁻⁶ of a contact distance closer than
    /// it) in the fine-grid box, where single precision rounds a coordinate by up to
    /// 3 × 10⁻⁵ (a third of them by its far x face, a third by its far z face), crossing,
    /// skew and parallel, at rest and moving together by up to 3 wall units: the scan's
    /// single-precision tests keep every one, as the exact test does.
    #[test]
    fn single_precision_tests_keep_pairs_just_within_reach() {
        let period = [Some(942.48), None, Some(471.24)];
        let (half, d) = (1.5, 0.232);
        let mut rng = Rng(7);
        let (mut before, mut after) = (Vec::new(), Vec::new());
        let trials = 400;
        for k in 0..trials {
            let ca = Vector3::new(
                if k % 3 == 0 {
                    942.47
                } else {
                    942.48 * rng.next()
                },
                290.0 * (rng.next() - 0.5),
                if k % 3 == 1 {
                    471.235
                } else {
                    471.24 * rng.next()
                },
            );
            let za = rng.vector(1.0).normalize();
            let p = ca + za * (0.9 * half * (2.0 * rng.next() - 1.0));
            // the common normal, and b's axis across it: parallel to a's every fourth time
            let across = za.cross(&rng.vector(1.0)).normalize();
            let angle = std::f64::consts::PI * rng.next();
            let zb = if k % 4 == 0 {
                za
            } else {
                (za * angle.cos() + across.cross(&za) * angle.sin()).normalize()
            };
            let q = p + across * (d * (1.0 - 1e-6));
            let cb = q - zb * (0.9 * half * (2.0 * rng.next() - 1.0));
            let shift = if k % 2 == 0 {
                Vector3::zeros()
            } else {
                rng.vector(3.0)
            };
            for (c, z) in [(ca, za), (cb, zb)] {
                let f = Fibre::straight(c, z, &[2.0 * half], &[d], 1000.0).unwrap();
                let mut g = f.clone();
                g.segments[0].r += shift;
                before.push(f);
                after.push(g);
            }
        }
        let s = Slices::new(&before, &after);
        let search = Search::new(&s, &period, 0.0);
        let found = search.pairs(&s);
        let expected = all_pairs(&s, &search);
        assert_every_trial_kept(&expected, trials);
        assert!(
            same(&found, &expected),
            "{} found, {} expected",
            found.len(),
            expected.len()
        );
    }

    #[test]
    fn the_cell_list_finds_every_pair_the_exact_test_keeps() {
        for seed in [1, 2, 3] {
            let (before, after) = start_and_end(seed);
            let (search, found, expected) = scanned(&before, &after);
            // the case is a real one: many pairs, some across a periodic boundary, and
            // displacements spread far wider than a diameter
            assert!(expected.len() > 100, "{} pairs", expected.len());
            assert!(expected.iter().any(|c| c.shift != Vector3::zeros()));
            assert!(search.spread > 2.0, "spread {}", search.spread);
            assert_found(seed, &found, &expected);
        }
    }

    /// In a mean flow along x the cells are narrower across the flow than along it, and
    /// the scan still finds every pair the exact test keeps, among them pairs whose
    /// displacements differ by more than their contact distance.
    #[test]
    fn cells_narrower_across_a_mean_flow_find_every_pair() {
        for seed in [7, 8, 9] {
            let (before, after) = in_a_mean_flow(seed, false);
            let (search, found, expected) = scanned(&before, &after);
            assert!(expected.len() > 100, "{} pairs", expected.len());
            let apart = |c: &Candidate| {
                (after[c.a.0].segments[c.a.1].r - before[c.a.0].segments[c.a.1].r)
                    - (after[c.b.0].segments[c.b.1].r - before[c.b.0].segments[c.b.1].r)
            };
            assert!(expected.iter().any(|c| apart(c).x.abs() > 1.0));
            let along = search.spread_along;
            assert!(along.x > 2.5 && along.y < 0.3 && along.z < 0.3, "{along:?}");
            assert!(search.wild.is_empty());
            let side = search.cells.side;
            assert!(
                side[0] > side[1] + 2.0 && side[0] > side[2] + 2.0,
                "{side:?}"
            );
            assert_found(seed, &found, &expected);
        }
    }

    /// Fibres thrown about (displaced and turned far beyond the others) are searched
    /// around on their own: the cells keep the size the others need, and the scan and
    /// the wild fibres' search together find every pair the exact test keeps, among them
    /// pairs of a wild fibre beyond the cells' reach and pairs of two wild fibres' segments.
    #[test]
    fn wild_fibres_are_searched_on_their_own_and_every_pair_is_found() {
        for seed in [13, 14, 15, 16] {
            let (before, after) = in_a_mean_flow(seed, true);
            let s = Slices::new(&before, &after);
            let search = Search::new(&s, &PERIOD, 0.0);
            assert_eq!(search.wild, [0, 25, 50, 75, 100, 125]);
            assert!(search.bulk_most_turn < 0.5 * search.most_turn);
            assert!(
                search.bulk_spread_along.y < 0.3 && search.spread_along.y > 1.0,
                "{:?} {:?}",
                search.bulk_spread_along,
                search.spread_along
            );
            let side = search.cells.side;
            assert!(side[1] < 5.0 && side[2] < 5.0, "{side:?}");
            let found = search.pairs(&s);
            let expected = all_pairs(&s, &search);
            let wild = |c: &Candidate| c.a.0.is_multiple_of(25) || c.b.0.is_multiple_of(25);
            assert!(expected.iter().filter(|c| wild(c)).count() > 10);
            assert_found(seed, &found, &expected);
        }
    }

    /// After a round of corrections, the search around the moved fibres finds exactly the
    /// overlaps a test of every pair finds, each on the side it was on at the start of
    /// the step (some corrections here push fibres through others), also in a mean flow.
    #[test]
    fn the_search_around_moved_fibres_finds_every_overlap_they_make() {
        let cases = [4, 5, 6].map(|seed| (seed, start_and_end(seed)));
        // and in a mean flow, where the step's cells are narrower across the flow
        let sheared = [10, 11, 12].map(|seed| (seed, in_a_mean_flow(seed, seed == 12)));
        for (seed, (before, after)) in cases.into_iter().chain(sheared) {
            let s = Slices::new(&before, &after);
            let search = Search::new(&s, &PERIOD, 0.0);
            // a third of the fibres corrected in earlier rounds (pushed by up to 1.5),
            // half of those again in this round (pushed by up to 1, and turned)
            let mut rng = Rng(seed + 100);
            let mut was = after.clone();
            let corrected: Vec<bool> = (0..was.len()).map(|k| k % 3 == 0).collect();
            for (k, f) in was.iter_mut().enumerate() {
                if corrected[k] {
                    let push = rng.vector(1.5);
                    f.segments.iter_mut().for_each(|s| s.r += push);
                }
            }
            let moved: Vec<usize> = (0..was.len()).filter(|k| k % 6 == 0).collect();
            let mut now = was.clone();
            for &k in &moved {
                let push = rng.vector(1.0);
                for s in now[k].segments.iter_mut() {
                    s.r += push;
                    s.z = (s.z + rng.vector(0.05)).normalize();
                }
            }
            let found = search.around(&s, &now, &before, &corrected, &moved);
            // every fibre not corrected is where the free step left it
            let now: Vec<Fibre> = (0..now.len())
                .map(|k| {
                    if corrected[k] {
                        now[k].clone()
                    } else {
                        after[k].clone()
                    }
                })
                .collect();
            let mut expected = all_overlaps(&before, &now, &moved);
            expected.sort_by_key(|c| (c.a, c.b));
            assert!(expected.len() > 10, "{} overlaps", expected.len());
            // some of them crossed in the round: deeper than a diameter on their old side
            assert!(
                expected.iter().any(|c| geometry(&now, c).2 < -c.reach),
                "no pair crossed"
            );
            assert_found(seed, &found, &expected);
        }
    }

    /// The search after a round in single precision, at its edge: a corrected fibre
    /// pushed to 2 × 10⁻⁶ of a contact distance inside one that the free step left where
    /// it is (crossing, skew, parallel, and end to end on one line, where the centres are
    /// as far apart as the first test allows; an overlap counts from 10⁻⁶), in the fine-grid
    /// box, by its far x and z faces where single precision rounds a coordinate by up to
    /// 3 × 10⁻⁵, the unmoved one at rest or moved by up to 3 wall units in the step: every
    /// such overlap is found, as a test of every pair finds it. (The segments' own
    /// margins, 10⁻⁴ of their sizes, exceed the rounding there: a first test made 3 × 10⁻⁴
    /// tighter lost the 60 end-to-end pairs, one 10⁻⁵ tighter none.)
    #[test]
    fn the_search_around_keeps_overlaps_just_within_reach_in_single_precision() {
        let period = [Some(942.48), None, Some(471.24)];
        let (xp, zp) = (period[0].unwrap_or(0.0), period[2].unwrap_or(0.0));
        let (half, d) = (1.5, 0.232);
        let mut rng = Rng(17);
        let (mut before, mut after, mut now) = (Vec::new(), Vec::new(), Vec::new());
        let trials = 300;
        for k in 0..trials {
            // the unmoved fibre: where the free step left it
            let ca = Vector3::new(
                if k % 3 == 0 {
                    xp - 0.01
                } else {
                    xp * rng.next()
                },
                290.0 * (rng.next() - 0.5),
                if k % 3 == 1 {
                    zp - 0.005
                } else {
                    zp * rng.next()
                },
            );
            let za = rng.vector(1.0).normalize();
            let shift = if k % 2 == 0 {
                Vector3::zeros()
            } else {
                rng.vector(3.0)
            };
            let a0 = Fibre::straight(ca, za, &[2.0 * half], &[d], 1000.0).unwrap();
            let mut a1 = a0.clone();
            a1.segments[0].r += shift;
            // the corrected one, now 10⁻⁶ d inside it
            let p = a1.segments[0].r + za * (0.9 * half * (2.0 * rng.next() - 1.0));
            let across = za.cross(&rng.vector(1.0)).normalize();
            let angle = std::f64::consts::PI * rng.next();
            let zb = if k % 4 == 0 {
                za
            } else {
                (za * angle.cos() + across.cross(&za) * angle.sin()).normalize()
            };
            let (cb, zb, across) = if k % 5 == 2 {
                // end to end along one line: the centres as far apart as an overlap allows,
                // at the bound of the first single-precision test
                let end = a1.segments[0].r + za * half;
                let q = end + za * (d * (1.0 - 2e-6));
                (q + za * half, za, za)
            } else {
                let q = p + across * (d * (1.0 - 2e-6));
                (q - zb * (0.9 * half * (2.0 * rng.next() - 1.0)), zb, across)
            };
            let b_now = Fibre::straight(cb, zb, &[2.0 * half], &[d], 1000.0).unwrap();
            // it came there from the same side, three contact distances out
            let mut b0 = b_now.clone();
            b0.segments[0].r += across * (3.0 * d);
            before.extend([a0, b0.clone()]);
            after.extend([a1.clone(), b0]);
            now.extend([a1, b_now]);
        }
        let s = Slices::new(&before, &after);
        let search = Search::new(&s, &period, 0.0);
        let corrected: Vec<bool> = (0..now.len()).map(|k| k % 2 == 1).collect();
        let moved: Vec<usize> = (0..now.len()).filter(|k| k % 2 == 1).collect();
        let found = search.around(&s, &now, &before, &corrected, &moved);
        let mut expected = all_overlaps_in(&before, &now, &moved, &period);
        expected.sort_by_key(|c| (c.a, c.b));
        assert_every_trial_kept(&expected, trials);
        assert_found(17, &found, &expected);
    }

    /// The conditions of [`pair`] are necessary: two segments that come within their
    /// contact distance at any moment of the step (centres moving straight, axes turning
    /// from start to end) are a candidate pair, whatever their motion.
    #[test]
    fn a_pair_that_touches_within_the_step_is_a_candidate() {
        let mut rng = Rng(7);
        let (mut touching, mut kept) = (0, 0);
        for _ in 0..20000 {
            let f = |rng: &mut Rng, k: u32| {
                let r0 = rng.vector(2.5);
                let z0 = rng.vector(1.0).normalize();
                let shift = rng.vector(3.0);
                let z1 = (z0 + rng.vector(0.6)).normalize();
                (k, r0, z0, shift, z1)
            };
            let (a, b) = (f(&mut rng, 0), f(&mut rng, 1));
            let (half, radius) = (1.5, 0.116);
            let entry = |(k, r0, z0, shift, z1): (
                u32,
                Vector3<f64>,
                Vector3<f64>,
                Vector3<f64>,
                Vector3<f64>,
            )| Entry {
                start: r0,
                axis: z0,
                shift,
                turn: half * (z1 - z0).norm(),
                half,
                radius,
                fibre: k,
                segment: 0,
            };
            let at = |(_, r0, z0, shift, z1): (
                u32,
                Vector3<f64>,
                Vector3<f64>,
                Vector3<f64>,
                Vector3<f64>,
            ),
                      t: f64| {
                let r = r0 + shift * t;
                let z = (z0 + (z1 - z0) * t).normalize();
                (r - z * half, r + z * half)
            };
            let touches = (0..=200).any(|n| {
                let t = n as f64 / 200.0;
                let ((p0, p1), (q0, q1)) = (at(a, t), at(b, t));
                let (s, u) = closest_points(&p0, &p1, &q0, &q1);
                ((p0 + (p1 - p0) * s) - (q0 + (q1 - q0) * u)).norm() < 2.0 * radius
            });
            let found = pair(&entry(a), &entry(b), f64::INFINITY, &[None; 3]).is_some();
            touching += usize::from(touches);
            kept += usize::from(found);
            assert!(
                !touches || found,
                "a touching pair was not kept: {a:?} {b:?}"
            );
        }
        // many touch, and the test keeps more than those (a bound, not the answer)
        assert!(touching > 500, "{touching} touching");
        assert!(kept > touching, "{kept} kept");
    }

    /// A fibre whose state went non-finite makes no pairs (every comparison with NaN
    /// fails), instead of pairing with every other segment; the others' pairs stay.
    #[test]
    fn a_fibre_gone_non_finite_makes_no_pairs() {
        let (before, mut after) = start_and_end(1);
        let s = Slices::new(&before, &after);
        let clean = Search::new(&s, &PERIOD, 0.0).pairs(&s);
        after[3].segments[2].r.x = f64::NAN;
        let s = Slices::new(&before, &after);
        let found = Search::new(&s, &PERIOD, 0.0).pairs(&s);
        let without: Vec<Candidate> = clean
            .into_iter()
            .filter(|c| c.a != (3, 2) && c.b != (3, 2))
            .collect();
        assert!(!without.is_empty());
        assert!(
            same(&found, &without),
            "{} found, {} expected",
            found.len(),
            without.len()
        );
    }
}
