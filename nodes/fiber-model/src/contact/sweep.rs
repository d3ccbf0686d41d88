//! The sweeps' impulses (steps 2 and 3 of [`super`]): one pair's impulse with Coulomb
//! friction, projected Gauss–Seidel over an island's pairs, how a fibre answers them (as
//! one rigid body, or hinged where it touches itself), and the walls as contacts of the
//! sweeps (docs/contact.md, "The method", 2–4 and 8).

use super::chain::{cuts, Chain};
use super::geometry::*;
use super::{Candidate, ContactParams};
use crate::fiber::{Fiber, Segment};
use crate::lanes::sin_cos1;
use nalgebra::{Matrix3, Vector3};
use std::ops::Range;

/// A fibre seen as one rigid body: what an impulse does to it.
#[derive(Debug, Clone, Copy)]
pub(super) struct Rigid {
    pub(super) inv_mass: f64,
    pub(super) com: Vector3<f64>,
    /// Inverse inertia tensor about the centre of mass (zero for a fixed fibre).
    pub(super) inv_inertia: Matrix3<f64>,
}

impl Rigid {
    #[cfg(test)]
    pub(super) fn of(f: &Fiber, fixed: bool) -> Self {
        Self::of_piece(f, 0..f.len(), fixed)
    }

    /// Segments `piece` of `f` as one rigid body.
    pub(super) fn of_piece(f: &Fiber, piece: Range<usize>, fixed: bool) -> Self {
        let (segments, props) = (&f.segments[piece.clone()], &f.props[piece]);
        let mass: f64 = props.iter().map(|p| p.mass).sum();
        let com = segments
            .iter()
            .zip(props)
            .fold(Vector3::zeros(), |acc, (s, p)| acc + s.r * p.mass)
            / mass;
        if fixed {
            return Self {
                inv_mass: 0.0,
                com,
                inv_inertia: Matrix3::zeros(),
            };
        }
        let mut inertia = Matrix3::zeros();
        for (s, p) in segments.iter().zip(props) {
            let rho = s.r - com;
            inertia += p.inertia(&s.z)
                + p.mass * (rho.dot(&rho) * Matrix3::identity() - rho * rho.transpose());
        }
        Self {
            inv_mass: 1.0 / mass,
            com,
            inv_inertia: inertia.try_inverse().unwrap_or_else(Matrix3::zeros),
        }
    }

    /// Velocity change at `point` per unit impulse there: W = (1/M) 1 − [ρ]× I⁻¹ [ρ]×.
    pub(super) fn mobility(&self, point: &Vector3<f64>) -> Matrix3<f64> {
        let x = cross_matrix(&(point - self.com));
        Matrix3::identity() * self.inv_mass - x * self.inv_inertia * x
    }
}

/// [v]× such that [v]× u = v × u.
pub(super) fn cross_matrix(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// Velocity of the material point `point` of segment `i`: v + ω × (point − r).
pub(super) fn point_velocity(f: &Fiber, i: usize, point: &Vector3<f64>) -> Vector3<f64> {
    let s = &f.segments[i];
    s.v + s.w.cross(&(point - s.r))
}

/// Rodrigues rotation of `v` by the rotation vector `phi` (no renormalisation).
pub(super) fn rotate_vector(v: &Vector3<f64>, phi: &Vector3<f64>) -> Vector3<f64> {
    let angle = phi.norm();
    if angle < 1e-300 {
        return *v;
    }
    let k = phi / angle;
    let (s, c) = sin_cos1(angle);
    v * c + k.cross(v) * s + k * (k.dot(v) * (1.0 - c))
}

/// The pair's new total impulse on a (−J on b) over the step, from its total so far
/// `acc` (projected Gauss–Seidel, normal then tangential as in Catto's sequential
/// impulses): the normal part closes the gap by the end of the step and never pulls
/// (J_n ≥ 0); the tangential part then stops the sliding, held to |J_t| ≤ μ J_n (the pair
/// slides when sticking would need more). `w` maps an impulse to the change of the
/// relative velocity at the contact, `u` is that velocity, `gap` the separation minus
/// contact distance (the motion already in `u` made it, so closing it needs a normal
/// velocity change of −gap/Δt).
pub(super) fn impulse(
    acc: &Vector3<f64>,
    w: &Matrix3<f64>,
    u: &Vector3<f64>,
    normal: &Vector3<f64>,
    gap: f64,
    dt: f64,
    mu: f64,
) -> Vector3<f64> {
    let acc_n = acc.dot(normal);
    let jn = acc_n.max(0.0) + (-gap / (dt * normal.dot(&(w * normal)))).max(0.0);
    let mut total = normal * jn;
    if mu > 0.0 && jn > 0.0 {
        // the sliding velocity once the normal change is in
        let acc_t = acc - normal * acc_n;
        let u = u + w * (normal * (jn - acc_n));
        let ut = u - normal * u.dot(normal);
        // the tangential change that stops it, in a basis of the tangent plane
        let t1 = if normal.x.abs() < 0.9 {
            normal.cross(&Vector3::x()).normalize()
        } else {
            normal.cross(&Vector3::y()).normalize()
        };
        let t2 = normal.cross(&t1);
        let k = nalgebra::Matrix2::new(
            t1.dot(&(w * t1)),
            t1.dot(&(w * t2)),
            t2.dot(&(w * t1)),
            t2.dot(&(w * t2)),
        );
        let stop = k
            .try_inverse()
            .map(|k_inv| k_inv * nalgebra::Vector2::new(-ut.dot(&t1), -ut.dot(&t2)))
            .unwrap_or_else(nalgebra::Vector2::zeros);
        let mut jt = acc_t + t1 * stop.x + t2 * stop.y;
        let limit = mu * jn;
        if jt.norm() > limit {
            jt *= limit / jt.norm();
        }
        total += jt;
    }
    total
}

/// Gauss–Seidel sweeps over one island: `fibres` are its fibres and `cands` its pairs
/// (indices into `fibres`), in their fixed (fibre, segment) order. Each pair closer than
/// 10⁻⁶ of its contact distance gets its impulse from the state the pairs before it left,
/// applied at once to both fibres ([`Body`]: rigid, or hinged at every joint when it
/// touches itself). A pair is looked at again only when one of its fibres moved since it
/// was last looked at. Stops when a sweep applies nothing or `max_sweeps` ran out;
/// returns the sweeps used and the impulses applied.
pub(super) fn sweep(
    fibers: &mut [Fiber],
    cands: &mut [Candidate],
    fixed: &[bool],
    max_sweeps: u32,
    params: &ContactParams,
    dt: f64,
) -> (u32, usize) {
    for c in cands.iter_mut() {
        c.at = None;
    }
    let cuts = cuts(fibers, cands);
    let mut bodies: Vec<Body> = fibers
        .iter()
        .enumerate()
        .map(|(k, f)| Body::of(f, &cuts[k], fixed[k]))
        .collect();
    // the sweep in which each fibre last moved (pairs of fibres that did not move since
    // they were last looked at are skipped)
    let mut moved = vec![0u32; fibers.len()];
    let mut used = 0;
    let mut applied = 0;
    for sweep in 1..=max_sweeps.max(1) {
        let mut this_sweep = 0;
        for c in cands.iter_mut() {
            let (sa, sb) = (c.a.0, c.b.0);
            if sweep > 1 && moved[sa] + 1 < sweep && moved[sb] + 1 < sweep {
                continue;
            }
            let (point, normal, gap) = geometry_at(fibers, c);
            // a pair that has not touched yet in this round needs an overlap to act
            if c.at.is_none() {
                if gap >= -1e-6 * c.reach {
                    continue;
                }
                let (_, _, _, s, t) = closest(fibers, c);
                c.at = Some((s, t, normal));
            }
            let point_b = point - c.shift;
            let a = (c.a.1, point);
            let b = (c.b.1, point_b);
            let w = if sa == sb {
                bodies[sa].pair_mobility(&fibers[sa], a, b)
            } else {
                bodies[sa].mobility(&fibers[sa], a) + bodies[sb].mobility(&fibers[sb], b)
            };
            let u = point_velocity(&fibers[sa], c.a.1, &point)
                - point_velocity(&fibers[sb], c.b.1, &point_b);
            let total = impulse(&c.impulse, &w, &u, &normal, gap, dt, params.friction);
            let j = total - c.impulse;
            // converged: the change would move the contact by less than 10⁻⁷ d
            if (w * j).norm() * dt <= 1e-7 * c.reach {
                continue;
            }
            c.impulse = total;
            let wall = params.wall_half_height;
            if sa == sb {
                push(
                    &mut fibers[sa],
                    &mut bodies[sa],
                    &[(a, j), (b, -j)],
                    dt,
                    wall,
                );
            } else {
                push(&mut fibers[sa], &mut bodies[sa], &[(a, j)], dt, wall);
                push(&mut fibers[sb], &mut bodies[sb], &[(b, -j)], dt, wall);
            }
            moved[sa] = sweep;
            moved[sb] = sweep;
            this_sweep += 1;
        }
        if this_sweep == 0 {
            break;
        }
        used = sweep;
        applied += this_sweep;
        // the moved fibres' inertia turned with them
        for (k, f) in fibers.iter().enumerate() {
            if moved[k] == sweep {
                bodies[k] = Body::of(f, &cuts[k], fixed[k]);
            }
        }
    }
    // a cut fibre's pieces turned about their joints: the joints opened to second order
    // in the turns (their velocities match); the joint impulses close them (each time to
    // second order in what is left), and what they leave is closed along the chain
    for (k, f) in fibers.iter_mut().enumerate() {
        if let Body::Chain(chain) = &mut bodies[k] {
            for _ in 0..4 {
                if f.max_joint_gap() <= 1e-9 * f.props[0].shape.diameter {
                    break;
                }
                chain.apply(f, &[], dt);
            }
            f.rechain();
        }
    }
    (used, applied)
}

/// A point of a fibre the sweeps push: its segment and where.
pub(super) type At = (usize, Vector3<f64>);

/// How a fibre answers the sweeps' impulses: as one rigid body, or, cut for its own
/// contacts ([`cuts`]), as rigid pieces hinged at ball joints.
pub(super) enum Body {
    Rigid(Rigid),
    Chain(Chain),
}

impl Body {
    pub(super) fn of(f: &Fiber, cuts: &[usize], fixed: bool) -> Self {
        if cuts.is_empty() {
            Body::Rigid(Rigid::of_piece(f, 0..f.len(), fixed))
        } else {
            Body::Chain(Chain::of(f, cuts, fixed))
        }
    }

    /// Velocity change at a point per unit impulse there.
    pub(super) fn mobility(&self, f: &Fiber, (i, point): At) -> Matrix3<f64> {
        match self {
            Body::Rigid(r) => r.mobility(&point),
            Body::Chain(c) => c.mobility(f, &[(i, point, 1.0)], &[(i, point, 1.0)]),
        }
    }

    /// Change of the relative velocity of point `a` against point `b` (of this fibre) per
    /// unit impulse on `a` (its opposite on `b`).
    pub(super) fn pair_mobility(&self, f: &Fiber, (ia, a): At, (ib, b): At) -> Matrix3<f64> {
        match self {
            Body::Rigid(r) => {
                let (xa, xb) = (cross_matrix(&(a - r.com)), cross_matrix(&(b - r.com)));
                -(xa - xb) * r.inv_inertia * (xa - xb)
            }
            Body::Chain(c) => {
                let ends = [(ia, a, 1.0), (ib, b, -1.0)];
                c.mobility(f, &ends, &ends)
            }
        }
    }
}

/// Gives fibre `f` (answering as `body`) the impulses `pushes` (each at a point): its
/// velocities change, and it moves over the step by Δt times that change (a rigid motion
/// of the fibre, or of each piece of a cut one, about its centre of mass); then, with
/// walls at ±`wall`, the walls push back any end it drove through them
/// ([`hold_off_walls`]).
pub(super) fn push(
    f: &mut Fiber,
    body: &mut Body,
    pushes: &[(At, Vector3<f64>)],
    dt: f64,
    wall: Option<f64>,
) {
    match body {
        Body::Rigid(r) => {
            if r.inv_mass == 0.0 {
                return;
            }
            for ((_, point), j) in pushes {
                move_by(f, r, point, j, dt);
            }
        }
        Body::Chain(c) => {
            if c.fixed {
                return;
            }
            c.apply(f, pushes, dt);
        }
    }
    if let Some(hh) = wall {
        hold_off_walls(f, body, hh, dt);
    }
}

/// Segments of one rigid body (centre of mass `com`) given the velocity change `dv`,
/// `dw`: their velocities change, and they move over the step by Δt times that change
/// (turned about the centre of mass by Δt dw, which moves by Δt dv).
pub(super) fn rigid_motion(
    segments: &mut [Segment],
    com: &mut Vector3<f64>,
    dv: &Vector3<f64>,
    dw: &Vector3<f64>,
    dt: f64,
) {
    let phi = dw * dt;
    for s in segments.iter_mut() {
        let rho = s.r - *com;
        s.v += dv + dw.cross(&rho);
        s.w += dw;
        s.r = *com + dv * dt + rotate_vector(&rho, &phi);
        s.z = rotate_vector(&s.z, &phi).normalize();
        s.n = rotate_vector(&s.n, &phi).normalize();
    }
    *com += dv * dt;
}

/// The walls at x2 = ±`hh` as contacts of the sweeps: the joint deepest beyond a wall gets
/// the impulse along the wall's normal that brings it back onto the wall by the end of the
/// step (through the fibre's mobility at that joint, so it turns the fibre as a push at
/// that point would), until no joint is beyond; what 8 such pushes leave, the model's wall
/// contact moves back along x2. A shift alone (the first version) let a push at one end
/// of a fibre lying on the wall turn it into the wall sweep after sweep, adding energy that
/// no shift took back.
pub(super) fn hold_off_walls(f: &mut Fiber, body: &mut Body, hh: f64, dt: f64) {
    for _ in 0..8 {
        let Some((at, normal, depth)) = deepest_beyond_wall(f, hh) else {
            return;
        };
        let m = normal.dot(&(body.mobility(f, at) * normal));
        if !(m > 0.0) {
            break;
        }
        let j = normal * (depth / (dt * m));
        match body {
            Body::Rigid(r) => move_by(f, r, &at.1, &j, dt),
            Body::Chain(c) => c.apply(f, &[(at, j)], dt),
        }
    }
    let shift = crate::step::wall_shift(f, hh);
    crate::step::shift_from_wall(f, shift);
    match body {
        Body::Rigid(r) => r.com.y += shift,
        Body::Chain(c) => c.pieces.iter_mut().for_each(|(_, r)| r.com.y += shift),
    }
}

/// The joint of `f` deepest beyond a wall at x2 = ±`hh`: the joint (with a segment it
/// ends), the wall's normal into the channel and the depth (None when every joint is
/// inside).
pub(super) fn deepest_beyond_wall(f: &Fiber, hh: f64) -> Option<(At, Vector3<f64>, f64)> {
    let mut deepest: Option<(At, Vector3<f64>, f64)> = None;
    let mut look = |i: usize, p: Vector3<f64>| {
        let (depth, normal) = if p.y < -hh {
            (-hh - p.y, Vector3::y())
        } else if p.y > hh {
            (p.y - hh, -Vector3::y())
        } else {
            return;
        };
        if deepest.is_none_or(|(_, _, d)| depth > d) {
            deepest = Some(((i, p), normal, depth));
        }
    };
    for (i, (s, p)) in f.segments.iter().zip(&f.props).enumerate() {
        look(i, s.r - s.z * (0.5 * p.shape.length));
    }
    if let (Some(s), Some(p)) = (f.segments.last(), f.props.last()) {
        look(f.len() - 1, s.r + s.z * (0.5 * p.shape.length));
    }
    deepest
}

/// The rigid motion of a whole fibre under the impulse `j` at `point` ([`push`]).
pub(super) fn move_by(
    f: &mut Fiber,
    r: &mut Rigid,
    point: &Vector3<f64>,
    j: &Vector3<f64>,
    dt: f64,
) {
    if r.inv_mass == 0.0 {
        return;
    }
    let dv = j * r.inv_mass;
    let dw = r.inv_inertia * (point - r.com).cross(j);
    rigid_motion(&mut f.segments, &mut r.com, &dv, &dw, dt);
}
