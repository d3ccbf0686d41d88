//! The implicit fibre step (paper eq. 5, 7, 8, 11, 12), derived in dimensional form.
//!
//! With P_i = (m/Δt δ + A_i)⁻¹ and Q_i = (I_i/Δt + C_i)⁻¹ (all at n−1), eliminating
//! the velocities from eq. 5 and 7,
//!   ṙ_i = P_i (s̃_i + Y_i − Y_{i−1}),   ω_i = Q_i (b̃_i + (l_i/2) [ẑ_i]× (Y_i + Y_{i−1})),
//! where Y_k is the force that segment k+1 exerts on segment k (the paper's X_{k+2}),
//! s̃_i = m/Δt ṙ_{i,n−1} + A_i v(r_i) + F^w_i and
//! b̃_i = I_i/Δt ω*_i + C_i Ω + H_i:G + M^b_i (ω* below),
//! turns the connectivity condition (eq. 8) into a block-tridiagonal system for Y_0..Y_{N−2}
//! (paper eq. 9–10, Appendix B — re-derived here: the first "I*" in b* and C_z* is İ, and
//! no extra scaling r_p is needed in f64 with consistent units):
//!   (P_k + W_k) Y_{k−1} + (W_k + W_{k+1} − P_k − P_{k+1}) Y_k + (P_{k+1} + W_{k+1}) Y_{k+1}
//!     = −(P_{k+1} s̃_{k+1} − P_k s̃_k + h_k Z_k Q_k b̃_k + h_{k+1} Z_{k+1} Q_{k+1} b̃_{k+1}),
//! with Z = [ẑ]×, h = l/2 and W = h² Z Q Z.
//!
//! Deviation from eq. 7, on purpose: the paper writes the rate of change of the inertia as
//! İ_{n−1}·ω_n (implicit in ω_n). For a slender segment I∥/I⊥ ≈ 1.5 (d/l)² ≈ 0.01, and the
//! term I⊥ ẑ·(ω_{n−1} × ω_n) it adds to the axial equation is not balanced by I∥/Δt: the
//! axial spin is then amplified every step and the fibre blows up in turbulence. We use the
//! exact gyroscopic term ω × (Iω) = İω = (I⊥ − I∥) ω∥ ẑ × ω⊥; its axial component
//! vanishes identically for an axisymmetric segment. It is a precession of ω⊥ about ẑ at
//! the rate (1 − I∥/I⊥) ω∥, taken here over the step as an exact-norm (Cayley) rotation of
//! ω_{n−1} into ω* ([`precessed`]): I/Δt ω* = I/Δt ω_{n−1} − ω × (Iω) + O(Δt). Taken
//! explicitly, as before, it multiplied |ω⊥| by √(1 + (ω∥ Δt)²) every step: harmless
//! while ω∥ Δt ≪ 1, but a frictional contact spins a segment about its axis (I∥ ≈ I⊥/170
//! for these segments) to ω∥ Δt ≈ 9, and the fibre then whipped and folded
//! (docs/contact.md). The scheme stays first order.

use crate::error::FiberError;
use crate::fiber::Fiber;
use crate::hydro::{resistance_axisymmetric, Axisymmetric, AxisymmetricResistance, DragModel};
use nalgebra::{DMatrix, DVector, Matrix3, Vector3};

/// Fluid velocity and velocity gradient at a segment centre: `grad[(a, b)] = ∂v_a/∂x_b`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FluidSample {
    pub vel: Vector3<f64>,
    pub grad: Matrix3<f64>,
}

impl FluidSample {
    pub fn at_rest() -> Self {
        Self {
            vel: Vector3::zeros(),
            grad: Matrix3::zeros(),
        }
    }
    /// Strain rate G = (∇v + ∇vᵀ)/2.
    pub fn strain(&self) -> Matrix3<f64> {
        0.5 * (self.grad + self.grad.transpose())
    }
    /// Fluid angular velocity Ω = (∇ × v)/2.
    pub fn rotation(&self) -> Vector3<f64> {
        let g = &self.grad;
        0.5 * Vector3::new(
            g[(2, 1)] - g[(1, 2)],
            g[(0, 2)] - g[(2, 0)],
            g[(1, 0)] - g[(0, 1)],
        )
    }
}

/// The fluid at a group's segments, in segment order, as the step reads it: decoded
/// samples, or a samples message's arrays read where they arrived (nothing copied first).
#[derive(Debug, Clone, Copy)]
pub enum Fluid<'a> {
    Decoded(&'a [FluidSample]),
    /// Little-endian `f64`s: `velocity` 3 per segment, `gradient` 9 per segment with
    /// ∂v_a/∂x_b at 3a + b (row by row). Lengths that disagree count as the shorter.
    Wire {
        velocity: &'a [u8],
        gradient: &'a [u8],
    },
}

impl<'a> Fluid<'a> {
    /// Segments held.
    pub fn len(&self) -> usize {
        match self {
            Fluid::Decoded(s) => s.len(),
            Fluid::Wire { velocity, gradient } => (velocity.len() / 24).min(gradient.len() / 72),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Segments `from..to` (within [`Self::len`]).
    pub fn range(&self, from: usize, to: usize) -> Fluid<'a> {
        match *self {
            Fluid::Decoded(s) => Fluid::Decoded(&s[from..to]),
            Fluid::Wire { velocity, gradient } => Fluid::Wire {
                velocity: &velocity[24 * from..24 * to],
                gradient: &gradient[72 * from..72 * to],
            },
        }
    }

    /// Segment `i`'s sample (`i` < [`Self::len`]).
    #[inline(always)]
    pub fn at(&self, i: usize) -> FluidSample {
        match self {
            Fluid::Decoded(s) => s[i],
            Fluid::Wire { velocity, gradient } => {
                let (v, g) = (
                    &velocity[24 * i..24 * i + 24],
                    &gradient[72 * i..72 * i + 72],
                );
                let x = |b: &[u8], k: usize| {
                    let mut a = [0u8; 8];
                    a.copy_from_slice(&b[8 * k..8 * k + 8]);
                    f64::from_le_bytes(a)
                };
                FluidSample {
                    vel: Vector3::new(x(v, 0), x(v, 1), x(v, 2)),
                    grad: Matrix3::new(
                        x(g, 0),
                        x(g, 1),
                        x(g, 2),
                        x(g, 3),
                        x(g, 4),
                        x(g, 5),
                        x(g, 6),
                        x(g, 7),
                        x(g, 8),
                    ),
                }
            }
        }
    }

    /// The samples as a slice: the decoded ones themselves, or the wire's decoded into `buf`.
    pub fn decoded<'b>(&self, buf: &'b mut Vec<FluidSample>) -> &'b [FluidSample]
    where
        'a: 'b,
    {
        match *self {
            Fluid::Decoded(s) => s,
            Fluid::Wire { .. } => {
                buf.clear();
                buf.extend((0..self.len()).map(|i| self.at(i)));
                buf
            }
        }
    }
}

impl<'a> From<&'a [FluidSample]> for Fluid<'a> {
    fn from(s: &'a [FluidSample]) -> Self {
        Fluid::Decoded(s)
    }
}

impl<'a> From<&'a Vec<FluidSample>> for Fluid<'a> {
    fn from(s: &'a Vec<FluidSample>) -> Self {
        Fluid::Decoded(s)
    }
}

/// Physical parameters shared by every fibre of a group.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ModelParams {
    pub drag: DragModel,
    /// Gravitational acceleration (body force F^w = (m − ρ_f V) g); zero in the paper.
    pub gravity: Vector3<f64>,
    /// Joint bending stiffness k_b: restoring moment k_b ẑ_i × ẑ_{i+1} (0 = fully flexible).
    pub bending_stiffness: f64,
    /// Joint twisting stiffness k_t: restoring moment −k_t φ t about the joint's mean axis t
    /// for a twist angle φ (0 = free to twist). Explicit, like the bending moment.
    pub twisting_stiffness: f64,
    /// Relative Tikhonov parameter (0 = exact block-Thomas solve).
    pub tikhonov: f64,
    /// Walls at x2 = ±wall_half_height (None: unbounded).
    pub wall_half_height: Option<f64>,
}

/// Hydrodynamic loads at the new velocities (for diagnostics and balance checks).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Loads {
    /// F^h_i + F^w_i per segment.
    pub force: Vec<Vector3<f64>>,
    /// T^h_i per segment.
    pub torque: Vec<Vector3<f64>>,
    /// The gyroscopic term as the step takes it, I (ω_{n−1} − ω*)/Δt per segment, with ω*
    /// the precessed ω_{n−1} ([`precessed`]); → ω × (I ω) = İ ω as Δt → 0.
    pub gyroscopic: Vec<Vector3<f64>>,
}

/// Advances one fibre by Δt. `fluid[i]` is the sample at segment i's centre at t_{n−1}.
pub fn step(
    p: &ModelParams,
    f: &mut Fiber,
    fluid: &[FluidSample],
    dt: f64,
) -> Result<(), FiberError> {
    step_inner(p, f, fluid, dt, None)
}

/// [`step`] that also returns the loads at the new velocities.
pub fn step_with_loads(
    p: &ModelParams,
    f: &mut Fiber,
    fluid: &[FluidSample],
    dt: f64,
) -> Result<Loads, FiberError> {
    let mut loads = Loads::default();
    step_inner(p, f, fluid, dt, Some(&mut loads))?;
    Ok(loads)
}

/// Segments per fibre kept on the stack (longer fibres use the heap); small, because every
/// buffer is initialised at this size on each step.
const MAX_STACK: usize = 16;

/// Long (≈180 lines) on purpose: it is one implicit step, eqs. 10–16 assembled and solved
/// as one system, and reads top to bottom like the paper's algorithm.
fn step_inner(
    p: &ModelParams,
    f: &mut Fiber,
    fluid: &[FluidSample],
    dt: f64,
    mut loads: Option<&mut Loads>,
) -> Result<(), FiberError> {
    let n = f.len();
    if fluid.len() != n {
        return Err(FiberError::SampleCount {
            expected: n,
            got: fluid.len(),
        });
    }
    // per-segment quantities (small vectors: stack for typical N). Every tensor of a
    // segment is axisymmetric about its axis ẑ, so P and Q are inverted in closed form
    // and W = h² Z Q Z = h² q⊥ (ẑẑᵀ − I).
    let mut pa: smallvec_like::Buf<Axisymmetric> = smallvec_like::Buf::new(n);
    let mut qa: smallvec_like::Buf<Axisymmetric> = smallvec_like::Buf::new(n);
    let mut pm: smallvec_like::Buf<Matrix3<f64>> = smallvec_like::Buf::new(n);
    let mut w: smallvec_like::Buf<Matrix3<f64>> = smallvec_like::Buf::new(n);
    let mut ps: smallvec_like::Buf<Vector3<f64>> = smallvec_like::Buf::new(n);
    let mut qb: smallvec_like::Buf<Vector3<f64>> = smallvec_like::Buf::new(n);
    let mut zqb: smallvec_like::Buf<Vector3<f64>> = smallvec_like::Buf::new(n);
    let mut res: smallvec_like::Buf<Option<AxisymmetricResistance>> = smallvec_like::Buf::new(n);
    let mut ra: smallvec_like::Buf<Axisymmetric> = smallvec_like::Buf::new(n);
    let mut gyro: smallvec_like::Buf<Vector3<f64>> = smallvec_like::Buf::new(n);
    let id = Matrix3::<f64>::identity();
    for i in 0..n {
        let s = f.segments[i];
        let pr = f.props[i];
        let fl = &fluid[i];
        let g = fl.strain();
        let omega = fl.rotation();
        let rel = fl.vel - s.v;
        let v_perp = (rel - s.z * s.z.dot(&rel)).norm();
        let r = resistance_axisymmetric(&pr.shape, &p.drag, &s.z, &g, v_perp);
        let volume = pr.mass / f.density;
        let fw = (pr.mass - p.drag.fluid_density * volume) * p.gravity;
        let m_dt = pr.mass / dt;
        let pinv = Axisymmetric {
            perp: m_dt + r.a.perp,
            par: m_dt + r.a.par,
        }
        .inverse()
        .ok_or(FiberError::Singular { fiber: 0 })?;
        let s_t = m_dt * s.v + r.a.apply(&s.z, &fl.vel) + fw;
        let inertia = Axisymmetric {
            perp: pr.inertia_perp,
            par: pr.inertia_axial,
        };
        let i_w = inertia.apply(
            &s.z,
            &precessed(&s.z, &s.w, pr.inertia_axial / pr.inertia_perp, dt),
        );
        let qinv = Axisymmetric {
            perp: inertia.perp / dt + r.c.perp,
            par: inertia.par / dt + r.c.par,
        }
        .inverse()
        .ok_or(FiberError::Singular { fiber: 0 })?;
        let mut bend = Vector3::zeros();
        if p.bending_stiffness != 0.0 {
            if i + 1 < n {
                bend += p.bending_stiffness * s.z.cross(&f.segments[i + 1].z);
            }
            if i > 0 {
                bend += p.bending_stiffness * s.z.cross(&f.segments[i - 1].z);
            }
        }
        if p.twisting_stiffness != 0.0 {
            // joint k twist φ_k: +k_t φ t on segment k, −k_t φ t on segment k+1
            let mean_axis = |a: &Vector3<f64>, b: &Vector3<f64>| {
                let t = a + b;
                let nt = t.norm();
                if nt > 1e-12 {
                    t / nt
                } else {
                    *a
                }
            };
            if i + 1 < n {
                let t = mean_axis(&s.z, &f.segments[i + 1].z);
                bend += p.twisting_stiffness * f.twist(i) * t;
            }
            if i > 0 {
                let t = mean_axis(&f.segments[i - 1].z, &s.z);
                bend -= p.twisting_stiffness * f.twist(i - 1) * t;
            }
        }
        let b_t = i_w / dt + r.c.apply(&s.z, &omega) + r.h_g + bend;
        let h = 0.5 * pr.shape.length;
        let zz = s.z * s.z.transpose();
        pa[i] = pinv;
        qa[i] = qinv;
        ra[i] = r.a;
        pm[i] = pinv.matrix(&s.z);
        w[i] = (h * h * qinv.perp) * (zz - id);
        ps[i] = pinv.apply(&s.z, &s_t);
        qb[i] = qinv.apply(&s.z, &b_t);
        zqb[i] = h * s.z.cross(&qb[i]);
        if loads.is_some() {
            res[i] = Some(r);
            gyro[i] = (inertia.apply(&s.z, &s.w) - i_w) / dt;
        }
    }
    // joint forces Y_0..Y_{n-2}
    let nj = n.saturating_sub(1);
    let mut y: smallvec_like::Buf<Vector3<f64>> = smallvec_like::Buf::new(nj);
    if nj > 0 {
        let lower = |k: usize| pm[k] + w[k];
        let diag = |k: usize| w[k] + w[k + 1] - pm[k] - pm[k + 1];
        let upper = |k: usize| pm[k + 1] + w[k + 1];
        let rhs = |k: usize| -(ps[k + 1] - ps[k] + zqb[k] + zqb[k + 1]);
        if p.tikhonov > 0.0 {
            solve_dense_tikhonov(nj, &lower, &diag, &upper, &rhs, p.tikhonov, &mut y)?;
        } else {
            // block Thomas; each pivot block is inverted once
            let mut dinv: smallvec_like::Buf<Matrix3<f64>> = smallvec_like::Buf::new(nj);
            let mut rp: smallvec_like::Buf<Vector3<f64>> = smallvec_like::Buf::new(nj);
            let singular = || FiberError::Singular { fiber: 0 };
            dinv[0] = diag(0).try_inverse().ok_or_else(singular)?;
            rp[0] = rhs(0);
            for k in 1..nj {
                let m = lower(k) * dinv[k - 1];
                dinv[k] = (diag(k) - m * upper(k - 1))
                    .try_inverse()
                    .ok_or_else(singular)?;
                rp[k] = rhs(k) - m * rp[k - 1];
            }
            y[nj - 1] = dinv[nj - 1] * rp[nj - 1];
            for k in (0..nj - 1).rev() {
                y[k] = dinv[k] * (rp[k] - upper(k) * y[k + 1]);
            }
        }
    }
    // velocities (eq. 5, 7) and positions (eq. 11, 12)
    if let Some(l) = loads.as_deref_mut() {
        l.force.clear();
        l.torque.clear();
        l.gyroscopic.clear();
    }
    for i in 0..n {
        let yi = if i < nj { y[i] } else { Vector3::zeros() };
        let ym = if i > 0 { y[i - 1] } else { Vector3::zeros() };
        let h = 0.5 * f.props[i].shape.length;
        let s = &mut f.segments[i];
        let v_new = ps[i] + pa[i].apply(&s.z, &(yi - ym));
        let w_new = qb[i] + qa[i].apply(&s.z, &(h * s.z.cross(&(yi + ym))));
        if let (Some(l), Some(r)) = (loads.as_deref_mut(), res[i]) {
            let pr = f.props[i];
            let volume = pr.mass / f.density;
            let fw = (pr.mass - p.drag.fluid_density * volume) * p.gravity;
            l.force.push(r.a.apply(&s.z, &(fluid[i].vel - v_new)) + fw);
            l.torque
                .push(r.c.apply(&s.z, &(fluid[i].rotation() - w_new)) + r.h_g);
            l.gyroscopic.push(gyro[i]);
        }
        s.f = ra[i].apply(&s.z, &(fluid[i].vel - v_new));
        s.v = v_new;
        s.w = w_new;
    }
    if !f
        .segments
        .iter()
        .all(|s| s.v.iter().chain(s.w.iter()).all(|x| x.is_finite()))
    {
        return Err(FiberError::Singular { fiber: 0 });
    }
    for s in f.segments.iter_mut() {
        s.r += dt * s.v;
        let (z, n) = rotate_pair(&s.z, &s.n, &(dt * s.w));
        s.z = z;
        s.n = (n - s.z * s.z.dot(&n)).normalize();
    }
    f.rechain();
    if let Some(hh) = p.wall_half_height {
        wall_contact(f, hh);
    }
    Ok(())
}

/// ω with its part across the axis turned about the axis by one step's gyroscopic
/// precession, angle −(1 − I∥/I⊥) ω∥ Δt, as the Cayley (implicit-midpoint) rotation:
/// I⊥ dω⊥/dt = −ω × (I ω) = −(I⊥ − I∥) ω∥ ẑ × ω⊥ taken over the step with ẑ and ω∥
/// held. To first order this is the explicit term, I ω* = I ω − Δt ω × (I ω); unlike it,
/// it keeps |ω⊥| exactly, so a segment spinning fast about its own axis (a frictional
/// contact sets one spinning, docs/contact.md) does not feed its tumbling: explicitly,
/// each step multiplied |ω⊥| by √(1 + (ω∥ Δt)²).
pub fn precessed(
    z: &Vector3<f64>,
    w: &Vector3<f64>,
    axial_over_perp: f64,
    dt: f64,
) -> Vector3<f64> {
    let w_par = z.dot(w);
    let w_perp = w - z * w_par;
    // tan of half the angle
    let c = (axial_over_perp - 1.0) * w_par * (0.5 * dt);
    let cc = c * c;
    let turned = (w_perp * (1.0 - cc) + z.cross(w) * (2.0 * c)) / (1.0 + cc);
    z * w_par + turned
}

/// Rotates `z` by the rotation vector `phi` (Rodrigues) and renormalises. To first order
/// this is eq. 12, ẑ_n = ẑ + Δt ω × ẑ; unlike eq. 12 it is an exact rotation, so a fibre in
/// solid-body rotation keeps its shape over any number of steps.
pub fn rotate(z: &Vector3<f64>, phi: &Vector3<f64>) -> Vector3<f64> {
    let angle = phi.norm();
    let out = if angle < 1e-300 {
        *z
    } else {
        let k = phi / angle;
        let (s, c) = crate::lanes::sin_cos1(angle);
        z * c + k.cross(z) * s + k * (k.dot(z) * (1.0 - c))
    };
    out / out.norm()
}

/// [`rotate`] of an axis and its material normal by the same rotation vector (one sine
/// and cosine for both; the same bits as two calls).
pub fn rotate_pair(
    z: &Vector3<f64>,
    n: &Vector3<f64>,
    phi: &Vector3<f64>,
) -> (Vector3<f64>, Vector3<f64>) {
    let angle = phi.norm();
    if angle < 1e-300 {
        return (z / z.norm(), n / n.norm());
    }
    let k = phi / angle;
    let (s, c) = crate::lanes::sin_cos1(angle);
    let turn = |v: &Vector3<f64>| {
        let out = v * c + k.cross(v) * s + k * (k.dot(v) * (1.0 - c));
        out / out.norm()
    };
    (turn(z), turn(n))
}

/// Frictionless, inelastic wall contact: if a segment end leaves |x2| <= H, the whole fibre
/// is translated back along ê2 (so joints stay closed) and wall-ward ê2 velocities are zeroed.
pub fn wall_contact(f: &mut Fiber, half_height: f64) {
    let shift = wall_shift(f, half_height);
    shift_from_wall(f, shift);
}

/// How far along ê2 fibre `f` must move to bring every segment end back within |x2| <= H
/// (0 when it is inside).
pub fn wall_shift(f: &Fiber, half_height: f64) -> f64 {
    // the joints' x2 (as Fibre::joints computes them, without allocating)
    let (mut ymin, mut ymax) = (f64::INFINITY, f64::NEG_INFINITY);
    for (s, p) in f.segments.iter().zip(&f.props) {
        let h = 0.5 * p.shape.length;
        let lo = s.r.y - h * s.z.y;
        (ymin, ymax) = (ymin.min(lo), ymax.max(lo));
    }
    if let (Some(s), Some(p)) = (f.segments.last(), f.props.last()) {
        let hi = s.r.y + 0.5 * p.shape.length * s.z.y;
        (ymin, ymax) = (ymin.min(hi), ymax.max(hi));
    }
    if ymax > half_height {
        half_height - ymax
    } else if ymin < -half_height {
        -half_height - ymin
    } else {
        0.0
    }
}

/// Moves `f` by `shift` along ê2 away from a wall and zeroes its segments' velocities
/// towards that wall (nothing when `shift` is 0).
pub fn shift_from_wall(f: &mut Fiber, shift: f64) {
    if shift == 0.0 {
        return;
    }
    for s in f.segments.iter_mut() {
        s.v.y = if shift < 0.0 {
            s.v.y.min(0.0)
        } else {
            s.v.y.max(0.0)
        };
        s.r.y += shift;
    }
}

#[allow(clippy::too_many_arguments)]
fn solve_dense_tikhonov(
    nj: usize,
    lower: &dyn Fn(usize) -> Matrix3<f64>,
    diag: &dyn Fn(usize) -> Matrix3<f64>,
    upper: &dyn Fn(usize) -> Matrix3<f64>,
    rhs: &dyn Fn(usize) -> Vector3<f64>,
    lambda: f64,
    y: &mut smallvec_like::Buf<Vector3<f64>>,
) -> Result<(), FiberError> {
    let dim = 3 * nj;
    let mut a = DMatrix::<f64>::zeros(dim, dim);
    let mut b = DVector::<f64>::zeros(dim);
    for k in 0..nj {
        a.fixed_view_mut::<3, 3>(3 * k, 3 * k).copy_from(&diag(k));
        if k > 0 {
            a.fixed_view_mut::<3, 3>(3 * k, 3 * (k - 1))
                .copy_from(&lower(k));
        }
        if k + 1 < nj {
            a.fixed_view_mut::<3, 3>(3 * k, 3 * (k + 1))
                .copy_from(&upper(k));
        }
        b.fixed_view_mut::<3, 1>(3 * k, 0).copy_from(&rhs(k));
    }
    let x =
        crate::dense::tikhonov_solve(&a, &b, lambda).ok_or(FiberError::Singular { fiber: 0 })?;
    for k in 0..nj {
        y[k] = Vector3::new(x[3 * k], x[3 * k + 1], x[3 * k + 2]);
    }
    Ok(())
}

/// A tiny fixed-capacity buffer: on the stack up to MAX_STACK entries, heap beyond.
mod smallvec_like {
    use super::MAX_STACK;
    use std::ops::{Index, IndexMut};

    pub enum Buf<T: Copy + Default> {
        Stack([T; MAX_STACK], usize),
        Heap(Vec<T>),
    }

    impl<T: Copy + Default> Buf<T> {
        pub fn new(n: usize) -> Self {
            if n <= MAX_STACK {
                Buf::Stack([T::default(); MAX_STACK], n)
            } else {
                Buf::Heap(vec![T::default(); n])
            }
        }
    }

    impl<T: Copy + Default> Index<usize> for Buf<T> {
        type Output = T;
        fn index(&self, i: usize) -> &T {
            match self {
                Buf::Stack(a, n) => &a[..*n][i],
                Buf::Heap(v) => &v[i],
            }
        }
    }

    impl<T: Copy + Default> IndexMut<usize> for Buf<T> {
        fn index_mut(&mut self, i: usize) -> &mut T {
            match self {
                Buf::Stack(a, n) => &mut a[..*n][i],
                Buf::Heap(v) => &mut v[i],
            }
        }
    }
}
