//! Four fibres with the same number of segments stepped at once: [`crate::step`]'s
//! equations (paper eq. 5, 7–12) evaluated with one fibre per lane ([`crate::lanes`]) on
//! the group's lane storage ([`LaneSeg`], structure of arrays across the four fibres), so
//! the arithmetic runs in SIMD registers and nothing is gathered. Lane by lane it performs
//! exactly the floating-point operations of `step::step`, so each fibre gets the same
//! bits either way (test `batch_matches_the_scalar_step_bit_for_bit`).
//!
//! Not covered here (the group falls back to `step::step`): joint twisting stiffness, the
//! Tikhonov solve and the loads diagnostics.

use crate::fiber::{Segment, SegmentProps};
use crate::lanes::{F4, LANES, M3, V3};
use crate::step::{Fluid, FluidSample, ModelParams};
use nalgebra::Vector3;

/// Whether the model's terms are all covered by the lane step: no twisting stiffness,
/// exact solve.
pub fn model_allows_lanes(p: &ModelParams) -> bool {
    p.twisting_stiffness == 0.0 && p.tikhonov == 0.0
}

/// Segment i of four fibres (one per lane): the state of [`Segment`], lane-major.
#[derive(Debug, Clone, Copy, Default)]
pub struct LaneSeg {
    pub r: V3,
    pub z: V3,
    pub v: V3,
    pub w: V3,
    pub n: V3,
    /// Hydrodynamic force of the last step ([`Segment::f`]).
    pub f: V3,
}

impl LaneSeg {
    /// The four segments in lanes 0..3.
    pub fn of(s: [Segment; LANES]) -> Self {
        let v = |f: fn(&Segment) -> Vector3<f64>| {
            let x = s.map(|seg| f(&seg));
            V3([0, 1, 2].map(|c| F4([x[0][c], x[1][c], x[2][c], x[3][c]])))
        };
        LaneSeg {
            r: v(|s| s.r),
            z: v(|s| s.z),
            v: v(|s| s.v),
            w: v(|s| s.w),
            n: v(|s| s.n),
            f: v(|s| s.f),
        }
    }

    /// The segment in lane `l`.
    pub fn get(&self, l: usize) -> Segment {
        let at = |v: &V3| Vector3::from(v.lane(l));
        Segment {
            r: at(&self.r),
            z: at(&self.z),
            v: at(&self.v),
            w: at(&self.w),
            n: at(&self.n),
            f: at(&self.f),
        }
    }

    /// Puts `s` into lane `l`.
    pub fn set(&mut self, l: usize, s: Segment) {
        for (dst, src) in [
            (&mut self.r, s.r),
            (&mut self.z, s.z),
            (&mut self.v, s.v),
            (&mut self.w, s.w),
            (&mut self.n, s.n),
            (&mut self.f, s.f),
        ] {
            for c in 0..3 {
                dst.0[c].0[l] = src[c];
            }
        }
    }
}

/// A segment's constants in the step, per lane, computed once from its properties with
/// exactly the operations `step::step` performs on them every step (so the bits match):
/// the parts of the resistance (`hydro::resistance_axisymmetric`) that do not depend on
/// the cross-flow speed, the buoyant mass and the inertia.
#[derive(Debug, Clone, Copy, Default)]
pub struct LaneConsts {
    mass: F4,
    length: F4,
    /// l³.
    l3: F4,
    /// C_D ρ_f d (times the cross-flow speed, the inertial drag per length).
    cd_rho_d: F4,
    /// 3πμ l Y^A and 3πμ l X^A.
    visc_perp: F4,
    visc_par: F4,
    /// πμ l³ Y^C, πμ l³ X^C and πμ l³ Y^H.
    rot_perp: F4,
    rot_par: F4,
    strain: F4,
    /// m − ρ_f m/ρ_s (gravity minus buoyancy per unit g).
    buoyant_mass: F4,
    inertia_perp: F4,
    inertia_axial: F4,
}

impl LaneConsts {
    /// The constants of four segments (`props[l]`, of a fibre of density `density[l]`).
    pub fn new(p: &ModelParams, props: [&SegmentProps; LANES], density: [f64; LANES]) -> Self {
        let of = |get: fn(&SegmentProps) -> f64| F4(props.map(get));
        let pi = std::f64::consts::PI;
        let mu = p.drag.viscosity;
        let mass = of(|p| p.mass);
        let l = of(|p| p.shape.length);
        let l3 = l * l * l;
        let pi_mu_l3 = F4::splat(pi * mu) * l3;
        LaneConsts {
            mass,
            length: l,
            l3,
            cd_rho_d: F4::splat(p.drag.drag_coefficient * p.drag.fluid_density)
                * of(|p| p.shape.diameter),
            visc_perp: F4::splat(3.0 * pi * mu) * l * of(|p| p.shape.coeffs.ya),
            visc_par: F4::splat(3.0 * pi * mu) * l * of(|p| p.shape.coeffs.xa),
            rot_perp: pi_mu_l3 * of(|p| p.shape.coeffs.yc),
            rot_par: pi_mu_l3 * of(|p| p.shape.coeffs.xc),
            strain: pi_mu_l3 * of(|p| p.shape.coeffs.yh),
            buoyant_mass: mass - F4::splat(p.drag.fluid_density) * (mass / F4(density)),
            inertia_perp: of(|p| p.inertia_perp),
            inertia_axial: of(|p| p.inertia_axial),
        }
    }
}

/// Per-segment working arrays of a block, reused from block to block (grown when a longer
/// fibre comes, never shrunk; every entry read in a step was written earlier in it).
#[derive(Debug, Default, Clone)]
pub struct Scratch {
    pa: Vec<Axi>,
    qa: Vec<Axi>,
    pm: Vec<M3>,
    wm: Vec<M3>,
    ps: Vec<V3>,
    qb: Vec<V3>,
    zqb: Vec<V3>,
    dinv: Vec<M3>,
    rp: Vec<V3>,
    y: Vec<V3>,
    v_new: Vec<V3>,
    w_new: Vec<V3>,
    /// Translational resistance A_i and the fluid velocity at each segment (the
    /// hydrodynamic force at the new velocity, [`crate::fiber::Segment::f`]).
    ra: Vec<Axi>,
    vel: Vec<V3>,
}

impl Scratch {
    fn prepare(&mut self, n: usize) {
        if self.pa.len() >= n {
            return;
        }
        for v in [&mut self.pa, &mut self.qa, &mut self.ra] {
            v.resize(n, Axi::default());
        }
        for v in [&mut self.pm, &mut self.wm, &mut self.dinv] {
            v.resize(n, M3::default());
        }
        for v in [
            &mut self.ps,
            &mut self.qb,
            &mut self.zqb,
            &mut self.rp,
            &mut self.y,
            &mut self.v_new,
            &mut self.w_new,
            &mut self.vel,
        ] {
            v.resize(n, V3::default());
        }
    }
}

/// Steps one block of the group's lane storage by `dt`: `seg` holds its segments,
/// `consts[i * stride]` segment i's constants, `fluid[l]` lane l's samples; lanes from
/// `used` on are padding (not checked). On a singular or non-finite system, returns the
/// first lane affected (the block's state is then unspecified, as after a failed group
/// step).
#[allow(clippy::too_many_arguments)]
pub fn step(
    p: &ModelParams,
    seg: &mut [LaneSeg],
    consts: &[LaneConsts],
    stride: usize,
    used: usize,
    fluid: &[Fluid<'_>; LANES],
    dt: f64,
    scratch: &mut Scratch,
) -> Result<(), usize> {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked just above); `step_avx2` only enables
            // it for code generation and is otherwise the portable kernel.
            return unsafe { step_avx2(p, seg, consts, stride, used, fluid, dt, scratch) };
        }
    }
    kernel(p, seg, consts, stride, used, fluid, dt, scratch)
}

/// [`kernel`] compiled for AVX2 (four `f64` per register). Only the instruction set
/// changes: no fused multiply-add is enabled, so results are the same bits.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[allow(clippy::too_many_arguments)]
unsafe fn step_avx2(
    p: &ModelParams,
    seg: &mut [LaneSeg],
    consts: &[LaneConsts],
    stride: usize,
    used: usize,
    fluid: &[Fluid<'_>; LANES],
    dt: f64,
    scratch: &mut Scratch,
) -> Result<(), usize> {
    kernel(p, seg, consts, stride, used, fluid, dt, scratch)
}
/// An axisymmetric operator per lane (see `hydro::Axisymmetric`).
#[derive(Debug, Clone, Copy, Default)]
struct Axi {
    perp: F4,
    par: F4,
}

impl Axi {
    /// perp v + ((par − perp) (z·v)) z.
    #[inline(always)]
    fn apply(self, z: V3, v: V3) -> V3 {
        v.scale(self.perp) + z.scale((self.par - self.perp) * z.dot(v))
    }

    /// 1/perp, 1/par; `ok[l]` is cleared where an eigenvalue is zero or not finite.
    #[inline(always)]
    fn inverse(self, ok: &mut [bool; LANES]) -> Axi {
        for (l, good) in ok.iter_mut().enumerate() {
            let (a, b) = (self.perp.0[l], self.par.0[l]);
            *good &= a != 0.0 && a.is_finite() && b != 0.0 && b.is_finite();
        }
        let one = F4::splat(1.0);
        Axi {
            perp: one / self.perp,
            par: one / self.par,
        }
    }

    /// perp I + (par − perp) z zᵀ.
    #[inline(always)]
    fn matrix(self, zz: &M3) -> M3 {
        let d = self.par - self.perp;
        M3::from_fn(|a, b| self.perp * M3::identity_at(a, b) + d * zz.0[a][b])
    }
}

/// The first lane (fibre index) where `ok` is false, among the `used` lanes.
fn first_bad(ok: &[bool; LANES], used: usize) -> Option<usize> {
    (0..used).find(|&l| !ok[l])
}

/// [`crate::step::rotate_pair`] per lane: the axis and the normal turned by the rotation
/// vector `phi` (Rodrigues, eq. 12 made exact) and renormalised.
#[inline(always)]
fn rotate_pair(z: V3, n: V3, phi: V3) -> (V3, V3) {
    let angle = phi.norm();
    let still = angle.lt(1e-300);
    let k = phi.unscale(angle);
    let (s, c) = crate::lanes::sin_cos(angle);
    let one_c = F4::splat(1.0) - c;
    (
        V3::select(still, unit(z), turn(z, k, s, c, one_c)),
        V3::select(still, unit(n), turn(n, k, s, c, one_c)),
    )
}

/// `v` turned about unit axis `k` by the angle of sine `s` and cosine `c`, renormalised.
#[inline(always)]
fn turn(v: V3, k: V3, s: F4, c: F4, one_c: F4) -> V3 {
    let out = v.scale(c) + k.cross(v).scale(s) + k.scale(k.dot(v) * one_c);
    out.unscale(out.norm())
}

/// `v / |v|`.
#[inline(always)]
fn unit(v: V3) -> V3 {
    v.unscale(v.norm())
}

/// Clears `ok` in the lanes where `det` is zero.
#[inline(always)]
fn nonzero(det: F4, ok: &mut [bool; LANES]) {
    for (l, good) in ok.iter_mut().enumerate() {
        *good &= det.0[l] != 0.0;
    }
}

/// Block-Thomas solve (step::step) of the joint-force system for Y_0..Y_{nj-1}, with
/// lower(k) = P_k + W_k, diag(k) = W_k + W_{k+1} − P_k − P_{k+1}, upper(k) = P_{k+1} +
/// W_{k+1} and rhs(k) = −(P_{k+1}s̃_{k+1} − P_k s̃_k + h_k Z_k Q_k b̃_k + h_{k+1} Z_{k+1}
/// Q_{k+1} b̃_{k+1}); each pivot block is inverted once.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn thomas(
    nj: usize,
    pm: &[M3],
    wm: &[M3],
    ps: &[V3],
    zqb: &[V3],
    dinv: &mut [M3],
    rp: &mut [V3],
    y: &mut [V3],
    ok: &mut [bool; LANES],
) {
    let (d0, det) = (wm[0] + wm[1] - pm[0] - pm[1]).inverse();
    nonzero(det, ok);
    dinv[0] = d0;
    rp[0] = -(ps[1] - ps[0] + zqb[0] + zqb[1]);
    for k in 1..nj {
        // lower(k) and upper(k - 1) are the same block, P_k + W_k
        let lower = pm[k] + wm[k];
        let upper_prev = lower;
        let m = lower.mul_m(dinv[k - 1]);
        let diag = wm[k] + wm[k + 1] - pm[k] - pm[k + 1];
        let (dk, det) = (diag - m.mul_m(upper_prev)).inverse();
        nonzero(det, ok);
        dinv[k] = dk;
        rp[k] = -(ps[k + 1] - ps[k] + zqb[k] + zqb[k + 1]) - m.mul_v(rp[k - 1]);
    }
    y[nj - 1] = dinv[nj - 1].mul_v(rp[nj - 1]);
    for k in (0..nj - 1).rev() {
        let upper = pm[k + 1] + wm[k + 1];
        y[k] = dinv[k].mul_v(rp[k] - upper.mul_v(y[k + 1]));
    }
}

/// Long (≈170 lines) on purpose: the step of `step_inner` written once over SIMD lanes
/// (one fibre per lane); split, the lanes would have to cross function boundaries.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn kernel(
    p: &ModelParams,
    seg: &mut [LaneSeg],
    consts: &[LaneConsts],
    stride: usize,
    used: usize,
    fluid: &[Fluid<'_>; LANES],
    dt: f64,
    scratch: &mut Scratch,
) -> Result<(), usize> {
    let n = seg.len();
    if used == 0 || used > LANES || n == 0 || consts.len() < 1 + (n - 1) * stride {
        return Err(0);
    }
    if fluid.iter().any(|s| s.len() != n) {
        return Err(0);
    }
    scratch.prepare(n);
    let Scratch {
        pa,
        qa,
        pm,
        wm,
        ps,
        qb,
        zqb,
        dinv,
        rp,
        y,
        v_new,
        w_new,
        ra: ra_all,
        vel: vel_all,
    } = scratch;
    let mut ok = [true; LANES];
    let dt4 = F4::splat(dt);
    let half = F4::splat(0.5);
    let (one, two) = (F4::splat(1.0), F4::splat(2.0));
    let gravity = V3::splat([p.gravity.x, p.gravity.y, p.gravity.z]);
    let kb = F4::splat(p.bending_stiffness);
    for i in 0..n {
        let c = &consts[i * stride];
        let s = &seg[i];
        let fl: [FluidSample; LANES] = std::array::from_fn(|l| fluid[l].at(i));
        let fl = [&fl[0], &fl[1], &fl[2], &fl[3]];
        let z = s.z;
        let (v, w) = (s.v, s.w);
        let lane = |x: &dyn Fn(&FluidSample) -> f64| F4([x(fl[0]), x(fl[1]), x(fl[2]), x(fl[3])]);
        let vel = V3([lane(&|f| f.vel.x), lane(&|f| f.vel.y), lane(&|f| f.vel.z)]);
        let gr = M3::from_fn(|a, b| lane(&|f| f.grad[(a, b)]));
        let (mass, l) = (c.mass, c.length);
        // strain rate and fluid rotation (FluidSample::strain, ::rotation)
        let g = M3::from_fn(|a, b| half * (gr.0[a][b] + gr.0[b][a]));
        let omega = V3([
            gr.0[2][1] - gr.0[1][2],
            gr.0[0][2] - gr.0[2][0],
            gr.0[1][0] - gr.0[0][1],
        ])
        .scale(half);
        let rel = vel - v;
        let v_perp = (rel - z.scale(z.dot(rel))).norm();
        // hydro::resistance_axisymmetric
        let cd_rho_d = c.cd_rho_d * v_perp;
        let zxgz = z.cross(g.mul_v(z));
        let l3_24 = cd_rho_d * c.l3 / F4::splat(24.0);
        let ra = Axi {
            perp: c.visc_perp + half * cd_rho_d * l,
            par: c.visc_par,
        };
        let rc = Axi {
            perp: c.rot_perp + l3_24,
            par: c.rot_par,
        };
        let h_g = zxgz.scale(c.strain + l3_24);
        let fw = gravity.scale(c.buoyant_mass);
        let m_dt = mass / dt4;
        let pinv = Axi {
            perp: m_dt + ra.perp,
            par: m_dt + ra.par,
        }
        .inverse(&mut ok);
        let s_t = v.scale(m_dt) + ra.apply(z, vel) + fw;
        let inertia = Axi {
            perp: c.inertia_perp,
            par: c.inertia_axial,
        };
        // step::precessed
        let w_par = z.dot(w);
        let w_perp = w - z.scale(w_par);
        let tan_half = (c.inertia_axial / c.inertia_perp - one) * w_par * (half * dt4);
        let tt = tan_half * tan_half;
        let turned = (w_perp.scale(one - tt) + z.cross(w).scale(two * tan_half)).unscale(one + tt);
        let i_w = inertia.apply(z, z.scale(w_par) + turned);
        let qinv = Axi {
            perp: inertia.perp / dt4 + rc.perp,
            par: inertia.par / dt4 + rc.par,
        }
        .inverse(&mut ok);
        let mut bend = V3::default();
        if p.bending_stiffness != 0.0 {
            if i + 1 < n {
                bend = bend + z.cross(seg[i + 1].z).scale(kb);
            }
            if i > 0 {
                bend = bend + z.cross(seg[i - 1].z).scale(kb);
            }
        }
        let b_t = i_w.unscale(dt4) + rc.apply(z, omega) + h_g + bend;
        let h = half * l;
        let zz = M3::outer(z);
        pa[i] = pinv;
        qa[i] = qinv;
        ra_all[i] = ra;
        vel_all[i] = vel;
        pm[i] = pinv.matrix(&zz);
        wm[i] = M3::from_fn(|a, b| zz.0[a][b] - M3::identity_at(a, b)).scale(h * h * qinv.perp);
        ps[i] = pinv.apply(z, s_t);
        qb[i] = qinv.apply(z, b_t);
        zqb[i] = z.cross(qb[i]).scale(h);
    }
    if let Some(l) = first_bad(&ok, used) {
        return Err(l);
    }
    // joint forces Y_0..Y_{n-2}: block Thomas, each pivot inverted once (step::step)
    let nj = n - 1;
    if nj > 0 {
        thomas(nj, pm, wm, ps, zqb, dinv, rp, y, &mut ok);
        if let Some(l) = first_bad(&ok, used) {
            return Err(l);
        }
    }
    // velocities (eq. 5, 7)
    for i in 0..n {
        let z = seg[i].z;
        let h = half * consts[i * stride].length;
        let yi = if i < nj { y[i] } else { V3::default() };
        let ym = if i > 0 { y[i - 1] } else { V3::default() };
        v_new[i] = ps[i] + pa[i].apply(z, yi - ym);
        w_new[i] = qb[i] + qa[i].apply(z, z.cross(yi + ym).scale(h));
    }
    // x − x is 0 for a finite x and NaN otherwise, and NaN survives the sum
    let mut spread = F4::default();
    for i in 0..n {
        for c in 0..3 {
            let (v, w) = (v_new[i].0[c], w_new[i].0[c]);
            #[allow(clippy::eq_op)] // x − x is the finiteness test
            {
                spread = spread + (v - v) + (w - w);
            }
        }
    }
    for (l, good) in ok.iter_mut().enumerate().take(used) {
        *good = spread.0[l] == 0.0;
    }
    if let Some(l) = first_bad(&ok, used) {
        return Err(l);
    }
    // positions (eq. 11) and rotations (eq. 12)
    for (i, s) in seg.iter_mut().enumerate() {
        // F^h at the new velocity, with the axis the step used (step::step)
        s.f = ra_all[i].apply(s.z, vel_all[i] - v_new[i]);
        let (z, nn) = rotate_pair(s.z, s.n, w_new[i].scale(dt4));
        let nn = (nn - z.scale(z.dot(nn))).normalize();
        s.v = v_new[i];
        s.w = w_new[i];
        s.r = s.r + s.v.scale(dt4);
        s.z = z;
        s.n = nn;
    }
    rechain(seg, consts, stride);
    if let Some(hh) = p.wall_half_height {
        wall_contact(seg, consts, stride, hh);
    }
    Ok(())
}

/// `Fiber::rechain` in every lane: segments re-chained outward from the middle one.
#[inline(always)]
fn rechain(seg: &mut [LaneSeg], consts: &[LaneConsts], stride: usize) {
    let n = seg.len();
    let m = (n - 1) / 2;
    let half = F4::splat(0.5);
    let h = |i: usize| half * consts[i * stride].length;
    for i in m + 1..n {
        let prev = seg[i - 1];
        seg[i].r = prev.r + prev.z.scale(h(i - 1)) + seg[i].z.scale(h(i));
    }
    for i in (0..m).rev() {
        let next = seg[i + 1];
        seg[i].r = next.r - next.z.scale(h(i + 1)) - seg[i].z.scale(h(i));
    }
}

/// `step::wall_contact` in every lane: a fibre whose end points leave |x2| <= H is moved
/// back along ê2 and its wall-ward ê2 velocities are zeroed.
#[inline(always)]
fn wall_contact(seg: &mut [LaneSeg], consts: &[LaneConsts], stride: usize, half_height: f64) {
    let n = seg.len();
    for l in 0..LANES {
        let (mut ymin, mut ymax) = (f64::INFINITY, f64::NEG_INFINITY);
        for (i, s) in seg.iter().enumerate() {
            let h = 0.5 * consts[i * stride].length.0[l];
            let lo = s.r.0[1].0[l] - h * s.z.0[1].0[l];
            (ymin, ymax) = (ymin.min(lo), ymax.max(lo));
        }
        let last = &seg[n - 1];
        let h = 0.5 * consts[(n - 1) * stride].length.0[l];
        let hi = last.r.0[1].0[l] + h * last.z.0[1].0[l];
        (ymin, ymax) = (ymin.min(hi), ymax.max(hi));
        let mut shift = 0.0;
        if ymax > half_height {
            shift = half_height - ymax;
            for s in seg.iter_mut() {
                s.v.0[1].0[l] = s.v.0[1].0[l].min(0.0);
            }
        } else if ymin < -half_height {
            shift = -half_height - ymin;
            for s in seg.iter_mut() {
                s.v.0[1].0[l] = s.v.0[1].0[l].max(0.0);
            }
        }
        if shift != 0.0 {
            for s in seg.iter_mut() {
                s.r.0[1].0[l] += shift;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use crate::fiber::Fiber;
    use crate::group::FiberGroup;
    use crate::hydro::DragModel;
    use crate::step::{Fluid, FluidSample, ModelParams};
    use nalgebra::{Matrix3, Vector3};

    /// A reproducible pseudo-random number in [-1, 1).
    fn rnd(seed: &mut u64) -> f64 {
        *seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((*seed >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    }

    fn params(bending: f64, gravity: f64) -> ModelParams {
        ModelParams {
            drag: DragModel {
                viscosity: 1.0 / 150.0,
                fluid_density: 1.0,
                drag_coefficient: 1.0,
            },
            gravity: Vector3::new(0.0, -gravity, 0.0),
            bending_stiffness: bending,
            twisting_stiffness: 0.0,
            tikhonov: 0.0,
            wall_half_height: Some(150.0),
        }
    }

    /// Fibres in every situation the step distinguishes: moving and spinning, at rest,
    /// and touching a wall (centres within a fibre length of x2 = ±150); segment lengths
    /// and diameters vary, so a change in the order of operations shows in the bits.
    fn fibers(count: usize, segments: usize, seed: &mut u64) -> Vec<Fiber> {
        fibers_of(count, &[segments], false, seed)
    }

    /// `count` fibres with `segments[k % len]` segments each; `alike`: every segment of
    /// every fibre has the same length, diameter and density (the group keeps one set of
    /// constants), else they vary.
    fn fibers_of(count: usize, segments: &[usize], alike: bool, seed: &mut u64) -> Vec<Fiber> {
        (0..count)
            .map(|k| {
                let segments = segments[k % segments.len()];
                let y = match k % 3 {
                    0 => 149.0,
                    1 => -148.5,
                    _ => 100.0 * rnd(seed),
                };
                let axis = Vector3::new(rnd(seed), rnd(seed), rnd(seed) + 0.1);
                let lengths: Vec<f64> = (0..segments)
                    .map(|_| if alike { 3.0 } else { 3.0 + rnd(seed) })
                    .collect();
                let diameter = if alike {
                    0.232
                } else {
                    0.232 + 0.05 * rnd(seed)
                };
                let density = if alike {
                    1150.0
                } else {
                    1150.0 + 1150.0 * (k % 2) as f64
                };
                let mut f = Fiber::straight(
                    Vector3::new(500.0 * rnd(seed), y, 200.0 * rnd(seed)),
                    axis,
                    &lengths,
                    &vec![diameter; segments],
                    density,
                )
                .expect("valid fibre");
                if k % 5 != 4 {
                    for s in &mut f.segments {
                        s.v = Vector3::new(rnd(seed), rnd(seed), rnd(seed));
                        s.w = 0.3 * Vector3::new(rnd(seed), rnd(seed), rnd(seed));
                    }
                }
                f
            })
            .collect()
    }

    fn fluid(g: &FiberGroup, seed: &mut u64, still: bool) -> Vec<FluidSample> {
        g.segment_centres()
            .iter()
            .map(|r| {
                if still {
                    return FluidSample::at_rest();
                }
                FluidSample {
                    vel: Vector3::new(0.1 * r.y + 10.0 + rnd(seed), rnd(seed), rnd(seed)),
                    grad: Matrix3::from_fn(|a, b| {
                        0.2 * rnd(seed) + if (a, b) == (0, 1) { 1.0 } else { 0.0 }
                    }),
                }
            })
            .collect()
    }

    fn bits(g: &FiberGroup) -> Vec<u64> {
        (0..g.len())
            .flat_map(|k| g.segments(k))
            .flat_map(|s| [s.r, s.z, s.v, s.w, s.n])
            .flat_map(|v| [v.x, v.y, v.z])
            .map(f64::to_bits)
            .collect()
    }

    /// Batched (four fibres per SIMD pass, padded lanes for the remainder) and one fibre
    /// at a time give the same bits, step after step: with and without bending stiffness
    /// and gravity, for 1, 3 and 7 segments, with fibres at rest in still fluid (the
    /// zero-rotation branch) and fibres pushed back from the walls; with constants per
    /// segment, with one set for the whole group (`alike`), and in groups mixing fibre
    /// lengths (blocks stepped fibre by fibre).
    #[test]
    fn batch_matches_the_scalar_step_bit_for_bit() {
        let mut seed = 7u64;
        for (segments, alike, bending, gravity) in [
            (&[7][..], false, 0.0, 0.0),
            (&[7], false, 0.05, 9.81e-3),
            (&[3], false, 0.0, 0.0),
            (&[1], false, 0.0, 1e-3),
            (&[7], true, 0.05, 9.81e-3),
            (&[5], true, 0.0, 0.0),
            (&[7, 7, 7, 7, 3, 7, 7, 7], true, 0.0, 0.0),
            (&[7, 7, 7, 7, 3, 7, 7, 7], false, 0.05, 0.0),
        ] {
            let fs = fibers_of(11, segments, alike, &mut seed);
            let mut batched = FiberGroup::new(params(bending, gravity), fs.clone());
            let mut serial = batched.clone();
            let mut single = FiberGroup::new(params(bending, gravity), fs);
            for step in 0..25 {
                let still = step == 0 && gravity == 0.0;
                let fl = fluid(&batched, &mut seed, still);
                batched.step_parallel(&fl, 0.2).expect("batched step");
                serial.step_serial(&fl, 0.2).expect("serial batched step");
                single.step_serial_unbatched(&fl, 0.2).expect("scalar step");
                assert_eq!(bits(&batched), bits(&single), "N {segments:?}, step {step}");
                assert_eq!(bits(&serial), bits(&single), "N {segments:?}, step {step}");
            }
        }
    }

    /// Samples read where a message holds them (`Fluid::Wire`: little-endian bytes, the
    /// gradient row by row) step a group to the same bits as the decoded samples: in
    /// lanes, fibre by fibre (a group mixing lengths), on the pool and on this thread, and
    /// when the fibres start at the fluid's velocity.
    #[test]
    fn samples_read_in_place_step_like_decoded_samples() {
        let mut seed = 11u64;
        for (count, segments) in [(9, &[7, 4][..]), (600, &[7][..])] {
            let fs = fibers_of(count, segments, false, &mut seed);
            let mut decoded = FiberGroup::new(params(0.05, 0.0), fs);
            let mut wire = decoded.clone();
            let fl = fluid(&decoded, &mut seed, false);
            let le = |xs: &mut dyn Iterator<Item = f64>| -> Vec<u8> {
                xs.flat_map(f64::to_le_bytes).collect()
            };
            let velocity = le(&mut fl.iter().flat_map(|f| [f.vel.x, f.vel.y, f.vel.z]));
            let gradient = le(&mut fl
                .iter()
                .flat_map(|f| (0..9).map(move |i| f.grad[(i / 3, i % 3)])));
            let w = Fluid::Wire {
                velocity: &velocity,
                gradient: &gradient,
            };
            assert_eq!(w.len(), fl.len());
            for (i, f) in fl.iter().enumerate() {
                assert_eq!(w.at(i), *f, "sample {i}");
            }
            decoded.set_velocity_to_fluid(&fl).expect("decoded start");
            wire.set_velocity_to_fluid(w).expect("wire start");
            assert_eq!(bits(&wire), bits(&decoded));
            for step in 0..3 {
                decoded.step(&fl, 0.2).expect("decoded step");
                if step % 2 == 0 {
                    wire.step(w, 0.2).expect("wire step");
                } else {
                    wire.step_serial(w, 0.2).expect("wire step here");
                }
                assert_eq!(bits(&wire), bits(&decoded), "{count} fibres, step {step}");
            }
            // the wrong number of samples is refused, not read past
            let short = w.range(0, fl.len() - 1);
            assert!(wire.step(short, 0.2).is_err());
        }
    }

    /// A fibre whose system cannot be solved is named by its index in the group.
    #[test]
    fn a_non_finite_fiber_is_named() {
        let mut seed = 3u64;
        let mut g = FiberGroup::new(params(0.0, 0.0), fibers(6, 7, &mut seed));
        let mut fl = fluid(&g, &mut seed, false);
        fl[5 * 7 + 2].vel.x = f64::NAN;
        match g.step(&fl, 0.2) {
            Err(crate::FiberError::Singular { fiber }) => assert_eq!(fiber, 5),
            other => panic!("expected fibre 5 to fail, got {other:?}"),
        }
    }

    /// The group's metrics, read from the lane storage, are those of each fibre.
    #[test]
    fn group_metrics_are_each_fibers_metrics() {
        let mut seed = 5u64;
        let mut g = FiberGroup::new(params(0.0, 0.0), fibers_of(9, &[7, 4], false, &mut seed));
        for _ in 0..3 {
            let fl = fluid(&g, &mut seed, false);
            g.step(&fl, 0.2).expect("step");
        }
        let ms = g.metrics();
        assert_eq!(ms.len(), 9);
        for (k, m) in ms.iter().enumerate() {
            assert_eq!(*m, crate::metrics::metrics(&g.fiber(k)), "fibre {k}");
        }
        assert!(ms.iter().any(|m| m.sigma2 > 0.0), "the fibres bent");
        // blocks of equally long fibres (read four at a time) with a partial last block,
        // one-segment fibres (σ² = 0), and a fibre folded back on itself (Σẑ_i = 0)
        for (count, segments) in [(9, &[7][..]), (6, &[1][..]), (7, &[2][..])] {
            let mut g = FiberGroup::new(
                params(0.0, 0.0),
                fibers_of(count, segments, false, &mut seed),
            );
            let fl = fluid(&g, &mut seed, false);
            g.step(&fl, 0.2).expect("step");
            if segments == [2] {
                let mut s = g.segment(5, 1);
                s.z = -g.segment(5, 0).z;
                g.set_segment(5, 1, s);
            }
            let ms = g.metrics();
            assert_eq!(ms.len(), count);
            for (k, m) in ms.iter().enumerate() {
                assert_eq!(
                    *m,
                    crate::metrics::metrics(&g.fiber(k)),
                    "{segments:?}: fibre {k}"
                );
            }
            if segments == [2] {
                assert_eq!(ms[5].orientation, Vector3::zeros(), "folded fibre");
            }
        }
        // a group large enough to be stepped and measured in parallel (and so a step on
        // the pool and one on this thread give the same bits)
        let big = fibers_of(600, &[7], true, &mut seed);
        let mut g = FiberGroup::new(params(0.0, 0.0), big);
        assert!(g.segment_count() >= crate::group::PARALLEL_MIN_SEGMENTS);
        let mut here = g.clone();
        let fl = fluid(&g, &mut seed, false);
        g.step(&fl, 0.2).expect("parallel step");
        here.step_serial(&fl, 0.2).expect("serial step");
        assert_eq!(bits(&g), bits(&here));
        for (k, m) in g.metrics().iter().enumerate() {
            assert_eq!(*m, crate::metrics::metrics(&g.fiber(k)), "fibre {k}");
        }
    }

    /// A state message's arrays read in the lane storage are the fibres' segments in
    /// order, bit for bit (fibres of two lengths, so blocks of unequal fibres too): the
    /// centres alone, appended to what the arrays held, or all four vectors with `full`.
    #[test]
    fn state_arrays_are_each_fibers_segments_in_order() {
        let mut seed = 7u64;
        let mut g = FiberGroup::new(params(0.0, 0.0), fibers_of(9, &[7, 4], false, &mut seed));
        let fl = fluid(&g, &mut seed, false);
        g.step(&fl, 0.2).expect("step");
        let want = |f: fn(&crate::fiber::Segment) -> Vector3<f64>| -> Vec<u64> {
            (0..g.len())
                .flat_map(|k| g.segments(k).collect::<Vec<_>>())
                .flat_map(|s| {
                    let v = f(&s);
                    [v.x, v.y, v.z]
                })
                .map(f64::to_bits)
                .collect()
        };
        let bits_of = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        let (mut c, mut a, mut v, mut w) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        g.extend_state(true, &mut c, &mut a, &mut v, &mut w);
        assert_eq!(c.len(), 3 * g.segment_count());
        assert_eq!(bits_of(&c), want(|s| s.r));
        assert_eq!(bits_of(&a), want(|s| s.z));
        assert_eq!(bits_of(&v), want(|s| s.v));
        assert_eq!(bits_of(&w), want(|s| s.w));
        let (mut c, mut a, mut v, mut w) = (vec![-1.0], Vec::new(), Vec::new(), Vec::new());
        g.extend_state(false, &mut c, &mut a, &mut v, &mut w);
        assert_eq!(c[0], -1.0);
        assert_eq!(bits_of(&c[1..]), want(|s| s.r));
        assert!(a.is_empty() && v.is_empty() && w.is_empty());
    }

    /// Substeps with the fluid held: one is the plain step bit for bit; four are four plain
    /// steps of a quarter of the step with the same samples (the same bits of every state
    /// array), and each segment's force is the mean of the four steps' forces, so
    /// Σ_substeps f (Δt/4) — the impulse the fluid receives — is the force sent times Δt.
    #[test]
    fn substeps_are_plain_steps_with_the_mean_force() {
        let mut seed = 11u64;
        let mut one = FiberGroup::new(
            params(0.05, 9.81e-3),
            fibers_of(9, &[7, 4], false, &mut seed),
        );
        let mut plain = one.clone();
        let fl = fluid(&one, &mut seed, false);
        one.step_in_substeps(&fl, 0.2, 1).expect("one substep");
        plain.step(&fl, 0.2).expect("step");
        assert_eq!(bits(&one), bits(&plain));
        let forces = |g: &FiberGroup| {
            let mut f = Vec::new();
            g.extend_forces(&mut f);
            f
        };
        assert_eq!(forces(&one), forces(&plain));

        let mut sub = FiberGroup::new(
            params(0.05, 9.81e-3),
            fibers_of(9, &[7, 4], false, &mut seed),
        );
        let mut quarter = sub.clone();
        let fl = fluid(&sub, &mut seed, false);
        sub.step_in_substeps(&fl, 0.2, 4).expect("four substeps");
        let mut sum = vec![0.0; 3 * quarter.segment_count()];
        for _ in 0..4 {
            quarter.step(&fl, 0.05).expect("quarter step");
            for (acc, f) in sum.iter_mut().zip(forces(&quarter)) {
                *acc += f;
            }
        }
        assert_eq!(bits(&sub), bits(&quarter));
        let mean = forces(&sub);
        assert!(mean.iter().any(|f| *f != 0.0));
        for (m, s) in mean.iter().zip(&sum) {
            assert!(
                (m * 0.2 - s * 0.05).abs() <= 1e-12 * (1.0 + s.abs()),
                "{m} vs {s}"
            );
        }
        // the mean is not the last substep's force
        assert_ne!(mean, forces(&quarter));
    }
}
