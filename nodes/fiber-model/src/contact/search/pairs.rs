//! The exact tests of a pair of segments: whether their centre-lines come within their
//! contact distance over the step (with the old pairs' skin, or without for fresh ones).

use super::cells::Entry;
use crate::contact::geometry::{closest_points, image_shift};
use crate::contact::Candidate;
use nalgebra::Vector3;

/// A segment's centre, axis, half length and radius.
pub(super) type Pose = (Vector3<f64>, Vector3<f64>, f64, f64);

/// A little slack on the necessary conditions the search tests before the exact one, so
/// rounding in them never drops a pair the exact test would keep.
pub(super) fn slack(limit: f64) -> f64 {
    limit * (1.0 + 1e-9) + 1e-12
}

/// The candidate pair of segments a and b (a before b in fibre-major order) from their
/// ends and axes at the moment the pair's side is taken, if their centre-lines come within
/// their contact distance plus `skin` (the old pairs' rule of [`super::Search::pairs`], the fresh
/// ones' of [`super::Search::around`] with no skin).
#[allow(clippy::too_many_arguments)]
pub(super) fn candidate(
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
pub(super) fn motion((was, now): &(Pose, Pose)) -> (Vector3<f64>, f64) {
    (now.0 - was.0, now.2 * (now.1 - was.1).norm())
}

/// Most moments at which [`fresh_pair`] looks along a pair's way (enough for a relative
/// motion of 2048 contact distances within the step).
pub(super) const MAX_WAY_MOMENTS: u32 = 4096;

/// A pair found after a round of corrections ([`super::Search::around`]), segments a and b each
/// at the start of the step and now, if it overlaps now: centre-lines closer than the
/// contact distance by more than 10⁻⁶ of it. Its side: where they are now, unless their
/// centre-lines came within half a contact distance of each other somewhere on the
/// straight way from the start to now — then they may have been pushed through each
/// other, and the pair keeps the side it had at the start (an overlap deeper than d to
/// undo). The way is looked at often enough that no passage closer than a quarter contact
/// distance falls between two looks, however far the pair moved. A pair far apart at the
/// start whose closest points merely turned keeps its side where it is.
pub(super) fn fresh_pair(
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

/// The candidate pair of two segments in the step ([`super::Search::pairs`]): segments of
/// different fibres, or non-adjacent segments of one fibre (adjacent ones share a joint),
/// whose mid-step centres are close enough for them to touch at some
/// moment of the step — within (l_a + l_b)/2 + (d_a + d_b)/2 + |Δr_a − Δr_b|/2 + turn_a +
/// turn_b, and along each direction k within the same with |Δr_a,k − Δr_b,k|/2, necessary
/// conditions — and whose centre-lines at the start are within their
/// contact distance plus the skin |Δr_a − Δr_b| + turn_a + turn_b ([`candidate`]).
/// `first` is a bound on the first distance that every pair's exceeds.
pub(super) fn pair(
    ea: &Entry,
    eb: &Entry,
    first: f64,
    period: &[Option<f64>; 3],
) -> Option<Candidate> {
    if ea.fiber == eb.fiber && ea.segment.abs_diff(eb.segment) < 2 {
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
