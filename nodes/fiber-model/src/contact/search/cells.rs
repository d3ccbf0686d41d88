//! The cell list: every segment placed by its mid-step centre in cells sized for the
//! step's longest segment and largest motion, sorted by cell, and the cheap necessary
//! test of two segments' points before the exact one.

use super::segments::Segments;
use nalgebra::Vector3;
use rayon::prelude::*;

/// A segment in the cell list's order, with what the tests of a pair read.
#[derive(Debug, Clone, Copy)]
pub(super) struct Entry {
    /// Centre and axis at the start of the step.
    pub(super) start: Vector3<f64>,
    pub(super) axis: Vector3<f64>,
    /// Displacement of the centre over the free step.
    pub(super) shift: Vector3<f64>,
    /// The most any point of the segment moved relative to its centre: h |Δẑ| (plus a pad).
    pub(super) turn: f64,
    /// Half length and radius.
    pub(super) half: f64,
    pub(super) radius: f64,
    pub(super) fiber: u32,
    pub(super) segment: u32,
}

impl Entry {
    /// Segment `i` of fibre `k` of `s`, `pad` added to its turn.
    pub(super) fn of<S: Segments>(s: &S, k: usize, i: usize, pad: f64) -> Self {
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
            fiber: k as u32,
            segment: i as u32,
        }
    }

    /// Centre at the middle of the step (start + half the displacement).
    pub(super) fn mid(&self) -> Vector3<f64> {
        self.start + self.shift * 0.5
    }

    pub(super) fn key(&self) -> (usize, usize) {
        (self.fiber as usize, self.segment as usize)
    }
}

/// What the pair scan's first tests read of a segment, 48 bytes in the order of the cells
/// (the 104-byte [`Entry`] is made again only for the pairs that pass): its mid-step
/// centre (folded into the box along the periodic directions), its displacement over the
/// step, its axis at the start, its half length, `rho` (its radius plus its turn) and its
/// fibre. In single precision, `rho` rounded out so that every pair [`super::pairs::pair`] may keep
/// passes [`Point::near`].
#[derive(Debug, Clone, Copy, Default)]
#[repr(C, align(16))]
pub(super) struct Point {
    pub(super) mid: [f32; 3],
    pub(super) half: f32,
    pub(super) shift: [f32; 3],
    pub(super) rho: f32,
    pub(super) axis: [f32; 3],
    pub(super) fiber: u32,
}

impl Point {
    /// The point of entry `e` (its `rho` without the margin of the whole step's
    /// coordinates, which [`Point::near`] adds).
    pub(super) fn of(e: &Entry, period: &[Option<f64>; 3]) -> Self {
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
            fiber: e.fiber,
        }
    }

    /// Whether segments `self` and `other` may come within reach in the step, by
    /// necessary conditions on what [`super::pairs::pair`] tests exactly: their mid-step centres within
    /// `first` (nine pairs in ten fail here), then their start segments — widened by their
    /// radii, their turns, their relative displacement and `margin2` — by the projections
    /// of the line between their centres onto itself, onto each axis and onto the normal
    /// of both axes (left out for axes within about half a degree of parallel, where it
    /// would be rounding). Nearest image along the directions whose
    /// `period` is not zero. Written so that a non-finite point passes nothing.
    #[inline(always)]
    pub(super) fn near(&self, other: &Point, first2: f32, margin2: f32, period: &[f32; 3]) -> bool {
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
pub(super) struct CellList {
    pub(super) dims: [usize; 3],
    pub(super) side: [f64; 3],
    pub(super) lo: [f64; 3],
    pub(super) periodic: [bool; 3],
    /// First entry of each cell (plus the total).
    pub(super) start: Vec<u32>,
    /// Offsets to the cells around a cell (itself and its 26 neighbours, each cell once)
    /// and the difference of their ids away from any edge.
    pub(super) around: Vec<([i64; 3], i64)>,
    /// Each point's cell and plane of cells across x, and the points by plane (the sort's
    /// first level).
    pub(super) ids: Vec<u32>,
    pub(super) planes: Vec<u32>,
    pub(super) by_plane: Vec<u32>,
}

impl CellList {
    /// Places the `n` points `point(i)` (within `bounds` along each direction) and writes
    /// their indices in the order of the cells to `order`.
    pub(super) fn rebuild(
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
    pub(super) fn coords(&self, r: &Vector3<f64>) -> [i64; 3] {
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

    pub(super) fn id(&self, c: &[i64; 3]) -> usize {
        (c[0] as usize * self.dims[1] + c[1] as usize) * self.dims[2] + c[2] as usize
    }

    pub(super) fn coords_of(&self, id: usize) -> [i64; 3] {
        let z = id % self.dims[2];
        let y = (id / self.dims[2]) % self.dims[1];
        let x = id / (self.dims[1] * self.dims[2]);
        [x as i64, y as i64, z as i64]
    }

    /// Away from every edge: all 26 neighbours are `id + difference`.
    pub(super) fn inner(&self, c: &[i64; 3]) -> bool {
        (0..3).all(|k| c[k] >= 1 && c[k] + 1 < self.dims[k] as i64)
    }

    /// Offsets to the cells around a cell (itself and its 26 neighbours), each cell once:
    /// along a periodic direction of one or two cells, −1 and +1 are the same cell.
    pub(super) fn offsets(&self) -> Vec<[i64; 3]> {
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
    pub(super) fn neighbour(&self, c: &[i64; 3], offset: &[i64; 3]) -> Option<usize> {
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
    pub(super) fn cells_around(&self, id: usize, mut visit: impl FnMut(usize)) {
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
    pub(super) fn runs_within(
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
pub(super) fn fold(x: f64, period: f64) -> f64 {
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
