//! Where two segments are closest, and which pairs are too close: the geometry the
//! contact solve and the checks of a recording share (docs/contact.md, "The method").

use super::search::{Search, Slices};
use super::Candidate;
use crate::fiber::Fiber;
use nalgebra::Vector3;
use rayon::prelude::*;

/// Closest points of segments p0–p1 and q0–q1: their parameters s, t ∈ [0, 1] along each
/// (Ericson, Real-Time Collision Detection §5.1.9). For parallel segments, the middle of
/// the overlap of their projections, so touching parallel fibres meet in the middle.
pub fn closest_points(
    p0: &Vector3<f64>,
    p1: &Vector3<f64>,
    q0: &Vector3<f64>,
    q1: &Vector3<f64>,
) -> (f64, f64) {
    let d1 = p1 - p0;
    let d2 = q1 - q0;
    let r = p0 - q0;
    let a = d1.dot(&d1);
    let e = d2.dot(&d2);
    let f = d2.dot(&r);
    if a <= f64::EPSILON && e <= f64::EPSILON {
        return (0.0, 0.0);
    }
    if a <= f64::EPSILON {
        return (0.0, (f / e).clamp(0.0, 1.0));
    }
    let c = d1.dot(&r);
    if e <= f64::EPSILON {
        return ((-c / a).clamp(0.0, 1.0), 0.0);
    }
    let b = d1.dot(&d2);
    let denom = a * e - b * b;
    if denom <= 1e-12 * a * e {
        // parallel: the middle of the overlap of q's projection onto p
        let sq0 = ((q0 - p0).dot(&d1) / a).clamp(0.0, 1.0);
        let sq1 = ((q1 - p0).dot(&d1) / a).clamp(0.0, 1.0);
        let s = 0.5 * (sq0 + sq1);
        let t = ((p0 + d1 * s - q0).dot(&d2) / e).clamp(0.0, 1.0);
        return (s, t);
    }
    let s0 = ((b * f - c * e) / denom).clamp(0.0, 1.0);
    let t0 = (b * s0 + f) / e;
    if t0 < 0.0 {
        ((-c / a).clamp(0.0, 1.0), 0.0)
    } else if t0 > 1.0 {
        (((b - c) / a).clamp(0.0, 1.0), 1.0)
    } else {
        (s0, t0)
    }
}

/// Offsets of each fibre's first segment in fibre-major order, plus the total.
pub(super) fn offsets(fibers: &[Fiber]) -> Vec<usize> {
    let mut o = Vec::with_capacity(fibers.len() + 1);
    let mut n = 0;
    for f in fibers {
        o.push(n);
        n += f.len();
    }
    o.push(n);
    o
}

/// Segment end points r ± (l/2) ẑ.
pub(super) fn ends(f: &Fiber, i: usize) -> (Vector3<f64>, Vector3<f64>) {
    let s = &f.segments[i];
    let h = 0.5 * f.props[i].shape.length;
    (s.r - s.z * h, s.r + s.z * h)
}

/// Nearest-image shift of `to` towards `from` along the periodic directions.
pub(super) fn image_shift(
    from: &Vector3<f64>,
    to: &Vector3<f64>,
    period: &[Option<f64>; 3],
) -> Vector3<f64> {
    let mut shift = Vector3::zeros();
    for k in 0..3 {
        if let Some(p) = period[k] {
            let d = from[k] - to[k];
            if d.abs() > 0.5 * p {
                shift[k] = (d / p).round() * p;
            }
        }
    }
    shift
}

/// Pairs of segments of different fibres whose centre-lines are closer than their contact
/// distance (d_a + d_b)/2: (fibre a, segment, fibre b, segment, distance), a before b. A
/// suspension with contact must start without any.
pub fn overlaps(
    fibers: &[Fiber],
    period: &[Option<f64>; 3],
) -> Vec<(usize, usize, usize, usize, f64)> {
    touching(fibers, period, 0.0)
}

/// Pairs of segments of different fibres whose centre-lines are closer than their contact
/// distance times (1 + `tolerance`): (fibre a, segment, fibre b, segment, distance), a
/// before b, in (fibre, segment) order. With a small tolerance, the pairs in contact.
pub fn touching(
    fibers: &[Fiber],
    period: &[Option<f64>; 3],
    tolerance: f64,
) -> Vec<(usize, usize, usize, usize, f64)> {
    // a skin as wide as the tolerance finds every pair within it
    let widest = fibers
        .iter()
        .flat_map(|f| f.props.iter())
        .map(|p| p.shape.diameter)
        .fold(0.0, f64::max);
    let segments = Slices::new(fibers, fibers);
    Search::new(&segments, period, 0.5 * tolerance * widest)
        .pairs(&segments)
        .iter()
        .filter(|c| c.a.0 != c.b.0)
        .filter_map(|c| {
            let distance = geometry(fibers, c).2 + c.reach;
            (distance < c.reach * (1.0 + tolerance))
                .then_some((c.a.0, c.a.1, c.b.0, c.b.1, distance))
        })
        .collect()
}

/// Pairs of non-adjacent segments of one fibre whose centre-lines are closer than their
/// contact distance times (1 + `tolerance`): (fibre, segment i, segment j > i + 1,
/// distance), in (fibre, i, j) order. A fibre folded through itself has such pairs
/// closer than d.
pub fn self_touching(fibers: &[Fiber], tolerance: f64) -> Vec<(usize, usize, usize, f64)> {
    fibers
        .par_iter()
        .enumerate()
        .flat_map_iter(|(k, f)| {
            let mut out = Vec::new();
            for i in 0..f.len() {
                for j in i + 2..f.len() {
                    let (pi, pj) = (&f.props[i].shape, &f.props[j].shape);
                    let reach = 0.5 * (pi.diameter + pj.diameter) * (1.0 + tolerance);
                    let far = 0.5 * (pi.length + pj.length) + reach;
                    if !((f.segments[i].r - f.segments[j].r).norm() < far) {
                        continue;
                    }
                    let ((p0, p1), (q0, q1)) = (ends(f, i), ends(f, j));
                    let (s, t) = closest_points(&p0, &p1, &q0, &q1);
                    let distance = ((p0 + (p1 - p0) * s) - (q0 + (q1 - q0) * t)).norm();
                    if distance < reach {
                        out.push((k, i, j, distance));
                    }
                }
            }
            out
        })
        .collect()
}

/// The state of a candidate at the end of the free step: contact point, normal (on a's
/// side) and separation minus contact distance (negative: too close, or crossed), and the
/// closest points' parameters along each segment.
pub(super) fn geometry(fibers: &[Fiber], c: &Candidate) -> (Vector3<f64>, Vector3<f64>, f64) {
    let (point, normal, gap, _, _) = closest(fibers, c);
    (point, normal, gap)
}

/// Sets the side the pair keeps (`normal0`, from b to a) to the side its segments are on
/// in `fibres`; left as it was when their centre-lines meet.
pub(super) fn take_side(fibers: &[Fiber], c: &mut Candidate) {
    let (pa0, pa1) = ends(&fibers[c.a.0], c.a.1);
    let (qb0, qb1) = ends(&fibers[c.b.0], c.b.1);
    let (qb0, qb1) = (qb0 + c.shift, qb1 + c.shift);
    let (s, t) = closest_points(&pa0, &pa1, &qb0, &qb1);
    let v = (pa0 + (pa1 - pa0) * s) - (qb0 + (qb1 - qb0) * t);
    if v.norm() > 1e-12 * c.reach {
        c.normal0 = v.normalize();
    }
}

pub(super) fn closest(
    fibers: &[Fiber],
    c: &Candidate,
) -> (Vector3<f64>, Vector3<f64>, f64, f64, f64) {
    let (pa0, pa1) = ends(&fibers[c.a.0], c.a.1);
    let (qb0, qb1) = ends(&fibers[c.b.0], c.b.1);
    let (qb0, qb1) = (qb0 + c.shift, qb1 + c.shift);
    let (s, t) = closest_points(&pa0, &pa1, &qb0, &qb1);
    let pa = pa0 + (pa1 - pa0) * s;
    let pb = qb0 + (qb1 - qb0) * t;
    let v = pa - pb;
    let dist = v.norm();
    let (normal, separation) = if dist > 1e-12 * c.reach {
        let side = if v.dot(&c.normal0) >= 0.0 { 1.0 } else { -1.0 };
        (v * (side / dist), side * dist)
    } else {
        (c.normal0, 0.0)
    };
    (0.5 * (pa + pb), normal, separation - c.reach, s, t)
}

/// [`geometry`] at the material points and normal the pair first acted at in this round
/// of sweeps (the separation along that normal), or the closest points if it has not.
pub(super) fn geometry_at(fibers: &[Fiber], c: &Candidate) -> (Vector3<f64>, Vector3<f64>, f64) {
    let Some((s, t, normal)) = c.at else {
        return geometry(fibers, c);
    };
    let (pa0, pa1) = ends(&fibers[c.a.0], c.a.1);
    let (qb0, qb1) = ends(&fibers[c.b.0], c.b.1);
    let pa = pa0 + (pa1 - pa0) * s;
    let pb = qb0 + (qb1 - qb0) * t + c.shift;
    (0.5 * (pa + pb), normal, (pa - pb).dot(&normal) - c.reach)
}
