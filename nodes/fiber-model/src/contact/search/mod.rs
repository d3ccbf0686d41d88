//! Which pairs of segments may touch: a cell list over every segment's mid-step centre,
//! built once per step and asked again, after each round of corrections, only around the
//! fibres that moved.
//!
//! The cost grows with the segments (one pass to place them, one to sort them by cell)
//! and with the pairs near each other, not with the fibres a step's contacts touch: the
//! solve copies out only the fibres of its candidate pairs ([`super::resolve_segments`]).
//!
//! The parts: [`segments`] what the search reads, [`cells`] the cell list and its cheap
//! test of two points, [`pairs`] the exact tests of a pair; this file the search of a step
//! (rebuild, the pairs, around the fibres that moved).

mod cells;
mod pairs;
mod segments;

use super::geometry::image_shift;
use super::Candidate;
use crate::fiber::Fiber;
use cells::{fold, CellList, Entry, Point};
use nalgebra::Vector3;
use pairs::{fresh_pair, pair, slack, Pose};
use rayon::prelude::*;
pub(crate) use segments::{Segments, Slices};

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
        let fibers = offsets.len().saturating_sub(1);
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
        let mut runs = Vec::with_capacity(fibers.div_ceil(RUN));
        let mut rest = self.points.as_mut_slice();
        for first in (0..fibers).step_by(RUN) {
            let last = (first + RUN).min(fibers);
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
                    let mut fiber = none;
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
                            fiber = join(
                                fiber,
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
                    ext = join(ext, fiber);
                    if thrown {
                        wild.push(k as u32);
                    } else {
                        bulk = join(bulk, fiber);
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
            let k = sorted[slot].fiber as usize;
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
            if pa.fiber == pb.fiber && order[a].abs_diff(order[b]) < 2 {
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
        fibers: &[Fiber],
        before: &[Fiber],
        corrected: &[bool],
        moved: &[usize],
    ) -> Vec<Candidate> {
        let period = &self.period;
        // a corrected segment at the start of the step and now: centre, axis, half
        // length, radius
        let poses = |k: usize, i: usize| -> (Pose, Pose) {
            let p = &fibers[k].props[i];
            let (h, r) = (0.5 * p.shape.length, 0.5 * p.shape.diameter);
            let (was, now) = (&before[k].segments[i], &fibers[k].segments[i]);
            ((was.r, was.z, h, r), (now.r, now.z, h, r))
        };
        // the corrected fibres' segments, in their own small list by where they are now
        let here: Vec<(usize, usize)> = (0..fibers.len())
            .filter(|&k| corrected[k])
            .flat_map(|k| (0..fibers[k].len()).map(move |i| (k, i)))
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
                for i in 0..fibers[q].len() {
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
                            let kb = pb.fiber as usize;
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
mod tests;
