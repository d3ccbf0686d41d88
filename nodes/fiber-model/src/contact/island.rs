//! Islands: fibres joined by candidate pairs, solved together by the sweeps, and the
//! lock that moves an island as one body when its sweeps jam (docs/contact.md, "The
//! method", 5 and 6).

use super::geometry::*;
use super::sweep::*;
use super::{Candidate, ContactParams};
use crate::fiber::{Fiber, Segment, SegmentProps};
use nalgebra::{Matrix3, Vector3};

/// Fibres joined by candidate pairs, solved together: its fibres (ascending) and its pairs
/// (indices into the candidates, in their order).
#[derive(Debug, Clone, Default)]
pub(super) struct Island {
    pub(super) fibers: Vec<usize>,
    pub(super) pairs: Vec<usize>,
}

/// The islands of the pairs of `cands` that are `live` among `n` fibres, ordered by their
/// lowest fibre.
pub(super) fn islands(n: usize, cands: &[Candidate], live: &[bool]) -> Vec<Island> {
    let mut parent: Vec<usize> = (0..n).collect();
    fn root(parent: &mut [usize], mut a: usize) -> usize {
        while parent[a] != a {
            parent[a] = parent[parent[a]];
            a = parent[a];
        }
        a
    }
    for c in cands.iter().zip(live).filter_map(|(c, &l)| l.then_some(c)) {
        let (ra, rb) = (root(&mut parent, c.a.0), root(&mut parent, c.b.0));
        if ra != rb {
            parent[ra.max(rb)] = ra.min(rb);
        }
    }
    // the root is the island's lowest fibre
    let mut index: std::collections::BTreeMap<usize, Island> = std::collections::BTreeMap::new();
    for (i, c) in cands.iter().enumerate().filter(|(i, _)| live[*i]) {
        let r = root(&mut parent, c.a.0);
        let isl = index.entry(r).or_default();
        isl.pairs.push(i);
        isl.fibers.push(c.a.0);
        isl.fibers.push(c.b.0);
    }
    index
        .into_values()
        .map(|mut isl| {
            isl.fibers.sort_unstable();
            isl.fibers.dedup();
            isl
        })
        .collect()
}

/// What solving one island gave: its fibres and pairs after the sweeps (pairs with their
/// global fibre indices), the sweeps and impulses used, and whether it had to be locked.
pub(super) struct Solved {
    pub(super) fibers: Vec<Fiber>,
    pub(super) pairs: Vec<Candidate>,
    pub(super) sweeps: u32,
    pub(super) applied: usize,
    pub(super) locked: bool,
}

/// Solves one island on copies of its fibres. If the sweeps cannot separate it (a fibre
/// pinched inside a coiled one: separating it needs the coil to bend, which a rigid
/// response cannot) or they ran away ([`ran_away`]), the island is locked: it moves over
/// the step as one rigid body from where its fibres started, with the momentum they came
/// to this round with ([`lock`]), so no two of its fibres end closer than they started.
pub(super) fn solve_island(
    fibers: &[Fiber],
    before: &[Fiber],
    cands: &[Candidate],
    isl: &Island,
    fixed: &[bool],
    params: &ContactParams,
    dt: f64,
) -> Solved {
    let local = |k: usize| isl.fibers.binary_search(&k).unwrap_or(0);
    let mut mine: Vec<Fiber> = isl.fibers.iter().map(|&k| fibers[k].clone()).collect();
    let held: Vec<bool> = isl
        .fibers
        .iter()
        .map(|&k| fixed.get(k).copied().unwrap_or(false))
        .collect();
    let mut pairs: Vec<Candidate> = isl
        .pairs
        .iter()
        .map(|&i| {
            let mut c = cands[i];
            c.a.0 = local(c.a.0);
            c.b.0 = local(c.b.0);
            c
        })
        .collect();
    let came = mine.clone();
    let (mut sweeps, mut applied) = sweep(&mut mine, &mut pairs, &held, params.sweeps, params, dt);
    let deepest = |mine: &[Fiber], pairs: &[Candidate]| {
        pairs
            .iter()
            .map(|c| geometry(mine, c).2 / c.reach)
            .fold(0.0_f64, f64::min)
    };
    let mut gap_left = deepest(&mine, &pairs);
    // the sweeps act at the material points and along the normal where each pair first
    // touched; once its fibres have turned, the closest points can still overlap while
    // those points are apart. Sweep again from the closest points before locking
    // (test `contact::tests::an_island_by_the_wall_is_parted_or_locked_keeping_every_pair_on_its_side`)
    for _ in 0..REFRESHES {
        if gap_left >= -LOCK_GAP || sweeps >= params.sweeps {
            break;
        }
        let (more, more_applied) = sweep(
            &mut mine,
            &mut pairs,
            &held,
            params.sweeps - sweeps,
            params,
            dt,
        );
        if more_applied == 0 {
            break;
        }
        sweeps += more;
        applied += more_applied;
        gap_left = deepest(&mine, &pairs);
    }
    let ran = sweeps >= params.sweeps && ran_away(&came, &mine, &pairs, dt);
    let locked = gap_left < -LOCK_GAP || ran;
    if locked {
        let start: Vec<&Fiber> = isl.fibers.iter().map(|&k| &before[k]).collect();
        mine = lock(&start, &came, &held, &images(mine.len(), &pairs), dt);
        // a locked island that went through a wall moves back from it as one body
        if let Some(hh) = params.wall_half_height {
            let shift = mine
                .iter()
                .map(|f| crate::step::wall_shift(f, hh))
                .fold(0.0_f64, |a, b| if b.abs() > a.abs() { b } else { a });
            mine.iter_mut()
                .for_each(|f| crate::step::shift_from_wall(f, shift));
        }
        // a rigid motion from a start without overlaps crosses no pair of the island: each
        // pair's side is where the lock put it (one taken after an earlier round's push
        // may point the other way)
        for c in pairs.iter_mut() {
            c.impulse = Vector3::zeros();
            take_side(&mine, c);
        }
    }
    for c in pairs.iter_mut() {
        c.a.0 = isl.fibers[c.a.0];
        c.b.0 = isl.fibers[c.b.0];
    }
    Solved {
        fibers: mine,
        pairs,
        sweeps,
        applied,
        locked,
    }
}

/// How many times an island's sweeps start again from the pairs' closest points before
/// it is locked.
const REFRESHES: usize = 4;

/// An island whose sweeps leave a pair closer than this fraction of its contact distance
/// is locked.
pub(super) const LOCK_GAP: f64 = 0.005;

/// Kinetic energy of `fibres` in their centre-of-mass frame (segments' translation and
/// spin) and their total mass.
pub(super) fn internal_energy(fibers: &[Fiber]) -> (f64, f64) {
    let seg = || fibers.iter().flat_map(|f| f.segments.iter().zip(&f.props));
    let mass: f64 = seg().map(|(_, p)| p.mass).sum();
    if mass <= 0.0 {
        return (0.0, 0.0);
    }
    let v = seg().fold(Vector3::zeros(), |a, (s, p)| a + s.v * p.mass) / mass;
    let e = seg()
        .map(|(s, p)| {
            let u = s.v - v;
            0.5 * (p.mass * u.dot(&u) + s.w.dot(&(p.inertia(&s.z) * s.w)))
        })
        .sum();
    (e, mass)
}

/// Whether the sweeps over an island ran away: contact impulses are inelastic (they stop
/// fibres moving into each other and stop sliding) apart from the part that closes the
/// overlaps within the step, so sweeps that raise the island's kinetic energy about its
/// centre of mass by more than moving all of it by its deepest overlap within Δt would
/// are taken as jammed. That happens where no rigid response of the fibres separates
/// them: a fibre's end wedged in another's bent joint with friction above the wedge's
/// tan α (the normal impulses squeeze, friction holds, and the impulses grow sweep after
/// sweep; test `contact::tests::an_end_wedged_in_a_bent_joint_slides_out_below_tan_alpha_and_jams_above`).
/// Only sweeps that did not converge are judged so: a flexible fibre's segments do not
/// move as a rigid body, so a converged rigid response can leave the energy a little
/// higher (test `contact::tests::an_island_whose_sweeps_converge_is_not_locked`).
/// A jammed island is locked, from the momentum it came with.
pub(super) fn ran_away(came: &[Fiber], now: &[Fiber], pairs: &[Candidate], dt: f64) -> bool {
    let (before, mass) = internal_energy(came);
    let (after, _) = internal_energy(now);
    let deepest = pairs
        .iter()
        .map(|c| (-geometry(came, c).2).max(0.0))
        .fold(0.0_f64, f64::max);
    let closing = 0.5 * mass * (deepest / dt).powi(2);
    !(after <= before + closing)
}

/// Periodic shifts that put the `n` fibres of an island beside each other: each pair's
/// second fibre is shifted by the pair's shift plus the first's (a tree of the pairs from
/// fibre 0; an island that wraps the whole period keeps the first shift found).
pub(super) fn images(n: usize, pairs: &[Candidate]) -> Vec<Vector3<f64>> {
    let mut shift: Vec<Option<Vector3<f64>>> = vec![None; n];
    if n > 0 {
        shift[0] = Some(Vector3::zeros());
    }
    let mut grown = true;
    while grown {
        grown = false;
        for c in pairs {
            match (shift[c.a.0], shift[c.b.0]) {
                (Some(sa), None) => {
                    shift[c.b.0] = Some(sa + c.shift);
                    grown = true;
                }
                (None, Some(sb)) => {
                    shift[c.a.0] = Some(sb - c.shift);
                    grown = true;
                }
                _ => {}
            }
        }
    }
    shift
        .into_iter()
        .map(|s| s.unwrap_or_else(Vector3::zeros))
        .collect()
}

/// The island `now` (as it came to this round of the solve: the impulses between its own
/// fibres add nothing to its momentum) moved as one rigid body over the step from `start`
/// (its fibres at the start of the step; fibre k seen at its periodic image `image[k]`):
/// the centre of mass moves with the island's momentum, the island turns with its angular
/// momentum about it (about the start's inertia tensor), every segment with the island's
/// velocity field. Momentum is kept exactly; distances between its fibres are those at
/// the start. With a fixed fibre in it, the island stays where it
/// started, at rest.
pub(super) fn lock(
    start: &[&Fiber],
    now: &[Fiber],
    held: &[bool],
    image: &[Vector3<f64>],
    dt: f64,
) -> Vec<Fiber> {
    let mut out: Vec<Fiber> = start.iter().map(|f| (*f).clone()).collect();
    let mut now = now.to_vec();
    for ((o, n), s) in out.iter_mut().zip(now.iter_mut()).zip(image) {
        o.segments.iter_mut().for_each(|g| g.r += s);
        n.segments.iter_mut().for_each(|g| g.r += s);
    }
    let segments = |fs: &[Fiber]| -> Vec<(Segment, SegmentProps)> {
        fs.iter()
            .flat_map(|f| f.segments.iter().copied().zip(f.props.iter().copied()))
            .collect()
    };
    for (o, n) in out.iter_mut().zip(&now) {
        for (so, sn) in o.segments.iter_mut().zip(&n.segments) {
            so.f = sn.f;
            so.v = Vector3::zeros();
            so.w = Vector3::zeros();
        }
    }
    let back = |mut out: Vec<Fiber>| {
        for (o, s) in out.iter_mut().zip(image) {
            o.segments.iter_mut().for_each(|g| g.r -= s);
        }
        out
    };
    if held.iter().any(|&h| h) {
        return back(out);
    }
    let was = segments(&out);
    let is = segments(&now);
    let mass: f64 = is.iter().map(|(_, p)| p.mass).sum();
    let com0 = was
        .iter()
        .fold(Vector3::zeros(), |a, (s, p)| a + s.r * p.mass)
        / mass;
    let com = is
        .iter()
        .fold(Vector3::zeros(), |a, (s, p)| a + s.r * p.mass)
        / mass;
    let momentum = is
        .iter()
        .fold(Vector3::zeros(), |a, (s, p)| a + s.v * p.mass);
    let spin = is.iter().fold(Vector3::zeros(), |a, (s, p)| {
        a + (s.r - com).cross(&s.v) * p.mass + p.inertia(&s.z) * s.w
    });
    let inertia = was.iter().fold(Matrix3::zeros(), |a, (s, p)| {
        let rho = s.r - com0;
        a + p.inertia(&s.z) + p.mass * (rho.dot(&rho) * Matrix3::identity() - rho * rho.transpose())
    });
    let v = momentum / mass;
    let omega = inertia
        .try_inverse()
        .map_or_else(Vector3::zeros, |i| i * spin);
    let phi = omega * dt;
    let com1 = com0 + v * dt;
    for f in out.iter_mut() {
        for s in f.segments.iter_mut() {
            let rho = rotate_vector(&(s.r - com0), &phi);
            s.r = com1 + rho;
            s.z = rotate_vector(&s.z, &phi).normalize();
            s.n = rotate_vector(&s.n, &phi).normalize();
            s.v = v + omega.cross(&rho);
            s.w = omega;
        }
    }
    back(out)
}
