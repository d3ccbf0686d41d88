//! A fibre touching itself answers the contact sweeps as a chain: its segments, each a
//! rigid body, hinged at ball joints (docs/contact.md, "A fibre touching itself").

use super::sweep::{cross_matrix, rigid_motion, At, Rigid};
use super::Candidate;
use crate::fiber::Fiber;
use nalgebra::{Matrix3, Vector3};
use std::ops::Range;

/// Where the sweeps cut each fibre (the first segment after each cut): a rigid response
/// cannot part two points of one body, so a fibre with a pair of its own non-adjacent
/// segments answers as its segments hinged at every joint (a first version cut it once,
/// between the pair: a push near that hinge then swung the whole rigid arm, and its far
/// end flew off faster than the pair had closed).
pub(super) fn cuts(fibers: &[Fiber], pairs: &[Candidate]) -> Vec<Vec<usize>> {
    let mut out = vec![Vec::new(); fibers.len()];
    for c in pairs.iter().filter(|c| c.a.0 == c.b.0) {
        let k = c.a.0;
        if out[k].is_empty() {
            out[k] = (1..fibers[k].len()).collect();
        }
    }
    out
}

/// A fibre cut into rigid pieces hinged at ball joints. An impulse on a piece moves it
/// and, through the joint impulses Λ that keep every joint's two sides moving together,
/// the others: A Λ = −b, b the joints' relative velocity changes the impulse alone makes
/// and A (block tridiagonal, 3 × 3 blocks: a joint impulse moves the two pieces it joins)
/// the same per unit joint impulse, solved by block elimination along the chain.
pub(super) struct Chain {
    /// Each piece: its segments and rigid body.
    pub(super) pieces: Vec<(Range<usize>, Rigid)>,
    /// The elimination of A: for each joint k, (D'_k)⁻¹ and L_(k−1) (D'_(k−1))⁻¹, with
    /// D'_k = D_k − L_(k−1) (D'_(k−1))⁻¹ U_(k−1); and the blocks U_k above the diagonal.
    pivots: Vec<(Matrix3<f64>, Matrix3<f64>)>,
    upper: Vec<Matrix3<f64>>,
    pub(super) fixed: bool,
}

impl Chain {
    pub(super) fn of(f: &Fiber, cuts: &[usize], fixed: bool) -> Self {
        let mut bounds = vec![0];
        bounds.extend_from_slice(cuts);
        bounds.push(f.len());
        let pieces: Vec<(Range<usize>, Rigid)> = bounds
            .windows(2)
            .map(|w| (w[0]..w[1], Rigid::of_piece(f, w[0]..w[1], fixed)))
            .collect();
        let mut chain = Self {
            pieces,
            pivots: Vec::new(),
            upper: Vec::new(),
            fixed,
        };
        if fixed {
            return chain;
        }
        // velocity change at x of piece p per unit impulse at y on it
        let m = |p: usize, x: &Vector3<f64>, y: &Vector3<f64>| {
            let r = &chain.pieces[p].1;
            Matrix3::identity() * r.inv_mass
                - cross_matrix(&(x - r.com)) * r.inv_inertia * cross_matrix(&(y - r.com))
        };
        let joints = chain.pieces.len() - 1;
        let q: Vec<Vector3<f64>> = (0..joints).map(|k| chain.joint(f, k)).collect();
        let mut pivots: Vec<(Matrix3<f64>, Matrix3<f64>)> = Vec::with_capacity(joints);
        let mut upper: Vec<Matrix3<f64>> = Vec::with_capacity(joints);
        for k in 0..joints {
            let mut d = m(k, &q[k], &q[k]) + m(k + 1, &q[k], &q[k]);
            let mut factor = Matrix3::zeros();
            if k > 0 {
                // A[k][k−1]: joint k−1's impulse on piece k
                let lower = -m(k, &q[k], &q[k - 1]);
                factor = lower * pivots[k - 1].0;
                d -= factor * upper[k - 1];
            }
            pivots.push((d.try_inverse().unwrap_or_else(Matrix3::zeros), factor));
            // A[k][k+1]: joint k+1's impulse on piece k+1
            upper.push(if k + 1 < joints {
                -m(k + 1, &q[k], &q[k + 1])
            } else {
                Matrix3::zeros()
            });
        }
        chain.pivots = pivots;
        chain.upper = upper;
        chain
    }

    /// Λ with A Λ = −b.
    fn joint_impulses(&self, b: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        let n = b.len();
        let mut y = Vec::with_capacity(n);
        for k in 0..n {
            let prev = if k == 0 {
                Vector3::zeros()
            } else {
                self.pivots[k].1 * y[k - 1]
            };
            y.push(-b[k] - prev);
        }
        let mut x = vec![Vector3::zeros(); n];
        for k in (0..n).rev() {
            let next = if k + 1 < n {
                self.upper[k] * x[k + 1]
            } else {
                Vector3::zeros()
            };
            x[k] = self.pivots[k].0 * (y[k] - next);
        }
        x
    }

    /// The joint before piece `k + 1`: the start of its first segment.
    fn joint(&self, f: &Fiber, k: usize) -> Vector3<f64> {
        let i = self.pieces[k + 1].0.start;
        let s = &f.segments[i];
        s.r - s.z * (0.5 * f.props[i].shape.length)
    }

    fn piece_of(&self, i: usize) -> usize {
        self.pieces
            .partition_point(|(r, _)| r.end <= i)
            .min(self.pieces.len() - 1)
    }

    /// Adds the impulse `j` at `point` on piece `p` to the pieces' velocity changes.
    fn add(
        &self,
        change: &mut [(Vector3<f64>, Vector3<f64>)],
        p: usize,
        point: &Vector3<f64>,
        j: &Vector3<f64>,
    ) {
        let r = &self.pieces[p].1;
        change[p].0 += j * r.inv_mass;
        change[p].1 += r.inv_inertia * (point - r.com).cross(j);
    }

    pub(super) fn velocity(
        &self,
        change: &[(Vector3<f64>, Vector3<f64>)],
        p: usize,
        point: &Vector3<f64>,
    ) -> Vector3<f64> {
        let (dv, dw) = &change[p];
        dv + dw.cross(&(point - self.pieces[p].1.com))
    }

    /// The pieces' velocity changes (linear, angular) under `pushes` (segment, point,
    /// impulse), joint impulses included; with `closing` = Some(Δt), the joint impulses
    /// also close what the joints have opened by the end of the step.
    pub(super) fn response(
        &self,
        f: &Fiber,
        pushes: &[(usize, Vector3<f64>, Vector3<f64>)],
        closing: Option<f64>,
    ) -> Vec<(Vector3<f64>, Vector3<f64>)> {
        let mut change = vec![(Vector3::zeros(), Vector3::zeros()); self.pieces.len()];
        if self.fixed {
            return change;
        }
        for (i, point, j) in pushes {
            self.add(&mut change, self.piece_of(*i), point, j);
        }
        let joints = self.pieces.len() - 1;
        let b: Vec<Vector3<f64>> = (0..joints)
            .map(|k| {
                let q = self.joint(f, k);
                let mut u = self.velocity(&change, k, &q) - self.velocity(&change, k + 1, &q);
                if let Some(dt) = closing {
                    let i = self.pieces[k + 1].0.start;
                    let before = &f.segments[i - 1];
                    let end = before.r + before.z * (0.5 * f.props[i - 1].shape.length);
                    u += (end - q) / dt;
                }
                u
            })
            .collect();
        for (k, lambda) in self.joint_impulses(&b).iter().enumerate() {
            let q = self.joint(f, k);
            self.add(&mut change, k, &q, lambda);
            self.add(&mut change, k + 1, &q, &(-lambda));
        }
        change
    }

    /// The change of Σ sign·velocity over the points `at` per unit impulse applied as
    /// sign·J at the points `by` (segment, point, sign).
    pub(super) fn mobility(
        &self,
        f: &Fiber,
        by: &[(usize, Vector3<f64>, f64)],
        at: &[(usize, Vector3<f64>, f64)],
    ) -> Matrix3<f64> {
        let mut w = Matrix3::zeros();
        for e in 0..3 {
            let unit = Vector3::ith(e, 1.0);
            let pushes: Vec<_> = by.iter().map(|&(i, p, s)| (i, p, unit * s)).collect();
            let change = self.response(f, &pushes, None);
            let u = at.iter().fold(Vector3::zeros(), |acc, &(i, p, s)| {
                acc + self.velocity(&change, self.piece_of(i), &p) * s
            });
            w.set_column(e, &u);
        }
        w
    }

    /// Moves each piece by the rigid motion its velocity change makes over the step; the
    /// joints the turns of earlier pushes opened (to second order) close too.
    pub(super) fn apply(&mut self, f: &mut Fiber, pushes: &[(At, Vector3<f64>)], dt: f64) {
        let pushes: Vec<_> = pushes.iter().map(|&((i, p), j)| (i, p, j)).collect();
        let change = self.response(f, &pushes, Some(dt));
        for ((range, r), (dv, dw)) in self.pieces.iter_mut().zip(change) {
            rigid_motion(&mut f.segments[range.clone()], &mut r.com, &dv, &dw, dt);
        }
    }
}
