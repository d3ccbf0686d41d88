//! Fibre–fibre contact: segments of different fibres, and non-adjacent segments of one
//! fibre, keep their centre-lines at least a diameter apart, with Coulomb friction
//! (coefficient μ, static and sliding) at the point where they touch (Lindström & Uesaka,
//! Phys. Fluids 2007, §II.C; Schmid, Switzer & Klingenberg, J. Rheol. 2000).
//!
//! A penalty spring stiff enough to hold 1% of d at the approach speeds of the channel is
//! far too stiff for an explicit force at Δt+ = 0.2 (docs/contact.md), so contact is a
//! velocity-level constraint applied after the joint solve of the step ([`resolve`]):
//!
//! 1. **Who may touch**: pairs of segments of different fibres (or non-adjacent segments
//!    of one fibre) whose centre-lines were within d + skin at the start of the step, the
//!    skin bounding how much closer any two of their points came in the step (their
//!    centres' relative displacement plus how far each end turned), so no pair can cross
//!    from one side to the other unseen. Each pair keeps the side it started on (the unit
//!    normal n₀ at the start); a pair that crossed in the free step has a negative
//!    separation.
//! 2. **Impulses**: for every pair closer than d at the end of the free step, the impulse J
//!    (on the first segment, −J on the second, both at the midpoint of the closest points)
//!    that brings the separation back to d by the end of the step and stops the sliding
//!    (static friction); if that needs |J_t| > μ J_n, the pair slides with |J_t| = μ J_n
//!    against the sliding direction. A fibre answers an impulse as one rigid body (its
//!    mass, centre of mass and inertia tensor), so its joints stay closed; its bending
//!    answers from the next step on through the joint solve. A fibre touching itself
//!    cannot answer so (a rigid body cannot part two of its own points): it answers as
//!    its segments, each rigid, hinged at ball joints (`Chain`; the joint impulses that
//!    keep the joints together solved along the chain), so it bends where it is pushed.
//! 3. **Sweeps**: projected Gauss–Seidel. The pairs are visited in a fixed (fibre,
//!    segment) order; each pair still closer than d gets its impulse from the state the
//!    pairs before it left, applied at once to both fibres (velocities, and the rigid
//!    motion of the fibre, or of each segment of a hinged one, that velocity change makes
//!    over the step); repeated until a sweep applies nothing or `sweeps` ran out. A pair
//!    is looked at again only when one of its fibres moved. The fixed order makes the
//!    result the same bits whatever the threads.
//!
//! Forces are equal and opposite and act at one point (a joint's too), so the contact
//! forces and torques of a step sum to zero; total momentum is unchanged (tests below).

mod chain;
pub mod exchange;
mod geometry;
mod island;
mod search;
mod sweep;

use crate::fiber::Fiber;
use geometry::*;
pub use geometry::{closest_points, overlaps, self_touching, touching};
use island::*;
pub(crate) use search::Search;
pub(crate) use search::Segments;
use search::Slices;

/// Most rounds of solving islands and searching for the pairs their corrections made.
const MAX_ROUNDS: usize = 12;

/// How far within its contact distance a pair may be left when the rounds run out (as a
/// share of it) before the backstop keeps its fibres where they started: the lock's
/// threshold (an island whose sweeps end closer than 0.995 d is locked). The next step's
/// solve starts by separating what is left.
const FREEZE_DEPTH: f64 = 0.005;
use nalgebra::Vector3;
use rayon::prelude::*;
use std::ops::Range;

/// Contact parameters (wall units).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContactParams {
    /// Coulomb friction coefficient μ ≥ 0 (static = sliding).
    pub friction: f64,
    /// Most Jacobi sweeps per step, ≥ 1 (they stop once no pair is closer than
    /// 10⁻⁶ of its contact distance).
    pub sweeps: u32,
    /// Periods of the box along x1, x2, x3 (None: not periodic); centres are unwrapped,
    /// pairs are found across periodic boundaries by the nearest image.
    pub period: [Option<f64>; 3],
    /// Walls at x2 = ±H (the model's wall contact, [`crate::step::wall_contact`]): a
    /// correction that pushes a fibre's end through a wall moves it back at once, so the
    /// sweeps separate fibres pressed together against a wall (the group sets it from
    /// its model's walls).
    pub wall_half_height: Option<f64>,
}

impl Default for ContactParams {
    fn default() -> Self {
        Self {
            friction: 0.0,
            sweeps: 100,
            period: [None; 3],
            wall_half_height: None,
        }
    }
}

/// Where contact's time went over the steps solved (wall-clock seconds, summed): what a
/// node logs at the end of its run (docs/history/contact-cost.md).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ContactTime {
    pub steps: u64,
    /// Placing the step's segments in the cell list.
    pub rebuild_s: f64,
    /// The scan for the step's candidate pairs.
    pub scan_s: f64,
    /// The rounds' gaps, islands and sweeps.
    pub sweeps_s: f64,
    /// The rounds' searches around the fibres a round moved.
    pub around_s: f64,
    /// Rounds over all steps.
    pub rounds: u64,
    /// Copying fibres out, the backstop for what still overlaps, and the step's contacts.
    pub rest_s: f64,
}

/// One contact of a step: the segments, where they touched, and the total impulse on the
/// first (the second received its opposite).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Contact {
    /// (fibre, segment) of the two segments, the first before the second in fibre order.
    pub a: (usize, usize),
    pub b: (usize, usize),
    /// The contact point in the first segment's frame (unwrapped as its centre is).
    pub point: Vector3<f64>,
    /// Periodic shift added to the second segment's coordinates to meet the first.
    pub shift: Vector3<f64>,
    /// Impulse on the first segment over the step (force × Δt).
    pub impulse: Vector3<f64>,
}

/// The contact load of one step on the segments of one piece of a suspension (what its
/// state message carries: `FiberGroupState.contact_segment`, `contact_force`,
/// `contacts`): the segments that touched, as fibre-major indices from the piece's first
/// segment, ascending; the force on each, the sum of its pairs' impulses (in the order of
/// [`Outcome::contacts`]) over Δt, 3 values; and how many pairs it was in.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SegmentLoad {
    pub segment: Vec<u32>,
    pub force: Vec<f64>,
    pub count: Vec<u32>,
}

impl SegmentLoad {
    /// The load of `contacts` on the fibres `own` of the solve's numbering (the piece's
    /// fibre k is the solve's `own.start + k`), whose segments start at `offsets[k]`
    /// (plus the total), over a step of `dt`. Every shard holds the same contacts in the
    /// same order, so a segment's sum has the same bits whatever the shards.
    pub fn of(contacts: &[Contact], own: Range<usize>, offsets: &[usize], dt: f64) -> Self {
        let flat = |(k, i): (usize, usize)| -> Option<usize> {
            own.contains(&k).then(|| offsets[k - own.start] + i)
        };
        // (segment, impulse on it): the first segment gets the impulse, the second its
        // opposite; a stable sort keeps the contacts' order within a segment
        let mut parts: Vec<(usize, Vector3<f64>)> = Vec::new();
        for c in contacts {
            parts.extend(flat(c.a).map(|s| (s, c.impulse)));
            parts.extend(flat(c.b).map(|s| (s, -c.impulse)));
        }
        parts.sort_by_key(|p| p.0);
        let mut load = Self::default();
        let mut i = 0;
        while i < parts.len() {
            let seg = parts[i].0;
            let mut sum = Vector3::zeros();
            let mut n = 0u32;
            while i < parts.len() && parts[i].0 == seg {
                sum += parts[i].1;
                n += 1;
                i += 1;
            }
            load.segment.push(seg as u32);
            load.force.extend_from_slice((sum / dt).as_slice());
            load.count.push(n);
        }
        load
    }
}

/// What [`resolve`] did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Outcome {
    /// Pairs that touched in the step, in (fibre, segment) order.
    pub contacts: Vec<Contact>,
    /// Candidate pairs examined (within reach at the start of the step).
    pub candidates: usize,
    /// Most sweeps any island used in one round.
    pub sweeps: u32,
    /// Smallest centre-line separation minus contact distance after the step (≥ 0 when
    /// every pair was separated; negative if the sweeps ran out), over the candidates.
    pub worst_gap: f64,
    /// Fibres the solve moved, ascending (a pair's impulses can cancel to zero after
    /// moving its fibres, so this is not the fibres of `contacts`).
    pub moved: Vec<usize>,
    /// Fibres of islands the sweeps could not separate, moved as one rigid body over the
    /// step instead (their pairs are not in `contacts`), ascending.
    pub locked: Vec<usize>,
    /// Fibres still closer than a contact distance to another when the rounds ran out,
    /// and those that then overlapped them: kept where they started the step, ascending.
    pub frozen: Vec<usize>,
}

impl Outcome {
    /// Per-segment contact force (impulse / Δt) and torque about the segment's centre, in
    /// the fibre-major order of `fibres`.
    pub fn segment_loads(
        &self,
        fibers: &[Fiber],
        dt: f64,
    ) -> (Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
        let offsets = offsets(fibers);
        let n = offsets.last().copied().unwrap_or(0);
        let mut force = vec![Vector3::zeros(); n];
        let mut torque = vec![Vector3::zeros(); n];
        for c in &self.contacts {
            let f = c.impulse / dt;
            let (ka, ia) = c.a;
            let (kb, ib) = c.b;
            let ra = fibers[ka].segments[ia].r;
            let rb = fibers[kb].segments[ib].r + c.shift;
            force[offsets[ka] + ia] += f;
            torque[offsets[ka] + ia] += (c.point - ra).cross(&f);
            force[offsets[kb] + ib] -= f;
            torque[offsets[kb] + ib] += (c.point - rb).cross(&(-f));
        }
        (force, torque)
    }
}

/// A pair that may touch in this step.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Candidate {
    a: (usize, usize),
    b: (usize, usize),
    /// Shift of b's coordinates to its image nearest a.
    shift: Vector3<f64>,
    /// The side a was on at the start of the step (unit, from b to a).
    normal0: Vector3<f64>,
    /// Contact distance (d_a + d_b)/2.
    reach: f64,
    impulse: Vector3<f64>,
    /// Where the pair touches while the sweeps run: the closest points' parameters along
    /// each segment and the normal when it first acted (so every impulse of the pair acts
    /// at the same material points, and taking one back undoes its torque too).
    at: Option<(f64, f64, Vector3<f64>)>,
    /// Whether the pair joined its fibres into an island in an earlier round of this
    /// step (it then keeps them in one island for the rest of the step).
    joined: bool,
}

/// Copies the fibres of candidate pairs into the solve's lists (now, at the start).
type Load<'a> = dyn FnMut(&[Candidate], &mut [Fiber], &mut [Fiber]) + 'a;

/// How far (as a share of its diameter) every point of a corrected fibre may move before
/// the rounds search around it again.
const SEARCH_SLACK: f64 = 1e-3;

/// Whether some point of `fibre` (fibre `k` of the step) is further than SEARCH_SLACK of
/// its segment's diameter from where it was at `at` (each segment's centre and axis; empty:
/// at the end of the free step): a segment's points move by at most |Δr| + (l/2) |Δẑ|.
fn moved_beyond<S: Segments>(
    s: &S,
    fiber: &Fiber,
    k: usize,
    at: &[(Vector3<f64>, Vector3<f64>)],
) -> bool {
    fiber
        .segments
        .iter()
        .zip(&fiber.props)
        .enumerate()
        .any(|(i, (g, p))| {
            let (r, z) = at.get(i).copied().unwrap_or_else(|| s.end(k, i));
            (g.r - r).norm() + 0.5 * p.shape.length * (g.z - z).norm()
                > SEARCH_SLACK * p.shape.diameter
        })
}

/// The backstop after the last round (section 9 of docs/contact.md): fibres of pairs
/// still closer than (1 − [`FREEZE_DEPTH`]) of their contact distance are kept where they
/// started the step (their centres, axes and normals; velocities as the solve left
/// them), and so, in turn, is every fibre that then comes that close to one of them. From
/// a start where no pair was that close, none is left so. Returns which fibres it froze.
#[allow(clippy::too_many_arguments)]
fn freeze_what_still_overlaps<S: Segments>(
    s: &S,
    search: &Search,
    cands: &mut Vec<Candidate>,
    fibers: &mut [Fiber],
    before: &[Fiber],
    moved: &mut [bool],
    load: &mut Load<'_>,
) -> Vec<bool> {
    let n = fibers.len();
    let mut frozen = vec![false; n];
    let overlapping = |cands: &[Candidate], fibers: &[Fiber]| {
        cands
            .iter()
            .any(|c| geometry(fibers, c).2 / c.reach < -FREEZE_DEPTH)
    };
    if !overlapping(cands, fibers) {
        return frozen;
    }
    // `load` copies fibres into both lists; the start is read from `before`, which the
    // caller owns, so fresh pairs' fibres are loaded into a scratch copy of it
    let mut start: Vec<Fiber> = before.to_vec();
    loop {
        let mut newly: Vec<usize> = cands
            .iter()
            .filter(|c| geometry(fibers, c).2 / c.reach < -FREEZE_DEPTH)
            .flat_map(|c| [c.a.0, c.b.0])
            .filter(|&k| !frozen[k])
            .collect();
        newly.sort_unstable();
        newly.dedup();
        if newly.is_empty() {
            return frozen;
        }
        for &k in &newly {
            frozen[k] = true;
            moved[k] = true;
            for (seg, was) in fibers[k].segments.iter_mut().zip(&start[k].segments) {
                (seg.r, seg.z, seg.n) = (was.r, was.z, was.n);
            }
        }
        // a pair both of whose fibres are kept at the start is on the side it is on there
        // (one found after a round took the side it had then, which corrections that
        // pushed it through may have turned)
        for c in cands.iter_mut().filter(|c| frozen[c.a.0] && frozen[c.b.0]) {
            take_side(fibers, c);
        }
        let fresh: Vec<Candidate> = search
            .around(s, fibers, &start, moved, &newly)
            .into_iter()
            .filter(|c| {
                cands
                    .binary_search_by_key(&(c.a, c.b), |x| (x.a, x.b))
                    .is_err()
            })
            .collect();
        load(&fresh, fibers, &mut start);
        cands.extend(fresh);
        cands.sort_by_key(|c| (c.a, c.b));
    }
}

/// Applies contact to `fibres` (the state after the free step; `before` the same fibres at
/// its start), with fibres `fixed[k]` immovable (a support). See the module's
/// documentation for the method.
pub fn resolve(
    fibers: &mut [Fiber],
    before: &[Fiber],
    fixed: &[bool],
    params: &ContactParams,
    dt: f64,
) -> Outcome {
    let mut search = Search::default();
    let (outcome, solved) =
        resolve_segments(&Slices::new(before, fibers), &mut search, fixed, params, dt);
    for &k in &outcome.moved {
        fibers[k] = solved[k].clone();
    }
    outcome
}

/// [`resolve`] on segments read where they are kept: only the fibres of candidate pairs
/// are copied out; `search` keeps its memory from step to step. Returns what it did and,
/// at the indices of `Outcome::moved`, the corrected fibres (every other entry is empty
/// or unchanged).
pub(crate) fn resolve_segments<S: Segments>(
    s: &S,
    search: &mut Search,
    fixed: &[bool],
    params: &ContactParams,
    dt: f64,
) -> (Outcome, Vec<Fiber>) {
    let n = s.offsets().len().saturating_sub(1);
    let mut spent = search.spent;
    let mut clock = std::time::Instant::now();
    let mut lap = |into: &mut f64| {
        let now = std::time::Instant::now();
        *into += (now - clock).as_secs_f64();
        clock = now;
    };
    search.rebuild(s, &params.period, 0.0);
    lap(&mut spent.rebuild_s);
    let mut cands = search.pairs(s);
    lap(&mut spent.scan_s);
    // the fibres the solve reads, copied out as pairs name them
    let empty = Fiber {
        segments: Vec::new(),
        props: Vec::new(),
        density: 0.0,
    };
    let mut fibers = vec![empty.clone(); n];
    let mut before = vec![empty; n];

    let mut loaded = vec![false; n];
    let mut load = |cands: &[Candidate], fibers: &mut [Fiber], before: &mut [Fiber]| {
        for c in cands {
            for k in [c.a.0, c.b.0] {
                if !loaded[k] {
                    loaded[k] = true;
                    fibers[k] = s.end_fiber(k);
                    before[k] = s.start_fiber(k);
                }
            }
        }
    };
    load(&cands, &mut fibers, &mut before);
    let mut outcome = Outcome {
        candidates: cands.len(),
        worst_gap: f64::INFINITY,
        ..Default::default()
    };
    let mut moved_fibers = vec![false; n];
    let mut locked = vec![false; n];
    // where each fibre's segments were when it was last searched around (empty: at the
    // end of the free step)
    let mut searched_at: Vec<Vec<(Vector3<f64>, Vector3<f64>)>> = vec![Vec::new(); n];
    lap(&mut spent.rest_s);
    for _round in 0..MAX_ROUNDS {
        spent.rounds += 1;
        // the pairs that overlap now or have pushed in this step, and the islands of
        // fibres they join (a floc, not every fibre within reach of another)
        let gaps: Vec<f64> = cands
            .par_iter()
            .with_min_len(1024)
            .map(|c| geometry(&fibers, c).2 / c.reach)
            .collect();
        if gaps.iter().all(|&g| g >= -1e-6) {
            break;
        }
        let live: Vec<bool> = cands
            .iter()
            .zip(&gaps)
            .map(|(c, &g)| g < -1e-6 || c.impulse != Vector3::zeros() || c.joined)
            .collect();
        for (c, &l) in cands.iter_mut().zip(&live) {
            c.joined |= l;
        }
        // islands are independent: solved in parallel, written back in order
        let isl = islands(n, &cands, &live);
        let solved: Vec<Solved> = isl
            .par_iter()
            .map(|i| solve_island(&fibers, &before, &cands, i, fixed, params, dt))
            .collect();
        let mut changed = false;
        let mut round_moved = Vec::new();
        for (i, s) in isl.iter().zip(solved) {
            outcome.sweeps = outcome.sweeps.max(s.sweeps);
            changed |= s.applied > 0 || s.locked;
            for (&k, f) in i.fibers.iter().zip(s.fibers) {
                locked[k] |= s.locked;
                if s.applied > 0 || s.locked {
                    moved_fibers[k] = true;
                    round_moved.push(k);
                }
                fibers[k] = f;
            }
            for (&n, c) in i.pairs.iter().zip(s.pairs) {
                cands[n] = c;
            }
        }
        lap(&mut spent.sweeps_s);
        if !changed {
            break;
        }
        // the corrections moved fibres: pairs they pushed together that were not
        // candidates join (their side is where they were at the start of the step).
        // A fibre whose every point moved less than SEARCH_SLACK of its diameter since it
        // was last searched around (or since the free step, which no candidate-less pair
        // ended closer than its contact distance) cannot have made an overlap deeper than
        // twice that with one also so moved: it waits until it has moved more (most of a
        // round's fibres move less than 10⁻³ d; what is left the next step separates)
        round_moved.sort_unstable();
        round_moved.retain(|&k| moved_beyond(s, &fibers[k], k, &searched_at[k]));
        for &k in &round_moved {
            searched_at[k] = fibers[k].segments.iter().map(|g| (g.r, g.z)).collect();
        }
        let fresh: Vec<Candidate> = search
            .around(s, &fibers, &before, &moved_fibers, &round_moved)
            .into_iter()
            .filter(|c| {
                cands
                    .binary_search_by_key(&(c.a, c.b), |x| (x.a, x.b))
                    .is_err()
            })
            .collect();
        load(&fresh, &mut fibers, &mut before);
        cands.extend(fresh);
        cands.sort_by_key(|c| (c.a, c.b));
        lap(&mut spent.around_s);
    }
    // a round that found nothing to do ends before its sweeps' lap
    lap(&mut spent.sweeps_s);
    let frozen = freeze_what_still_overlaps(
        s,
        search,
        &mut cands,
        &mut fibers,
        &before,
        &mut moved_fibers,
        &mut load,
    );
    outcome.moved = (0..n).filter(|&k| moved_fibers[k]).collect();
    outcome.locked = (0..n).filter(|&k| locked[k]).collect();
    outcome.frozen = (0..n).filter(|&k| frozen[k]).collect();
    outcome.candidates = cands.len();
    for c in &cands {
        let (point, _, gap) = geometry(&fibers, c);
        outcome.worst_gap = outcome.worst_gap.min(gap);
        if c.impulse != Vector3::zeros() {
            outcome.contacts.push(Contact {
                a: c.a,
                b: c.b,
                point,
                shift: c.shift,
                impulse: c.impulse,
            });
        }
    }
    lap(&mut spent.rest_s);
    spent.steps += 1;
    search.spent = spent;
    (outcome, fibers)
}

#[cfg(test)]
pub(crate) mod tests;
