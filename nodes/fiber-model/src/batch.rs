//! Four fibres with the same number of segments stepped at once: [`crate::step`]'s
//! equations (paper eq. 5, 7–12) evaluated with one fibre per lane ([`crate::lanes`]),
//! structure of arrays across the four fibres, so the arithmetic runs in SIMD registers.
//! Lane by lane it performs exactly the floating-point operations of `step::step`, so each
//! fibre gets the same bits either way (test `batch_matches_the_scalar_step_bit_for_bit`).
//!
//! Not covered here (the group falls back to `step::step`): joint twisting stiffness, the
//! Tikhonov solve and the loads diagnostics.

use crate::fibre::Fibre;
use crate::lanes::{F4, LANES, M3, V3};
use crate::step::{wall_contact, FluidSample, ModelParams};
use nalgebra::Vector3;

/// Whether `fibres` can be stepped together under `p`: one to four fibres, all with the
/// same number of segments, no twisting stiffness, exact solve.
pub fn eligible(p: &ModelParams, fibres: &[Fibre]) -> bool {
    let Some(n) = fibres.first().map(Fibre::len) else {
        return false;
    };
    fibres.len() <= LANES
        && n > 0
        && fibres.iter().all(|f| f.len() == n)
        && p.twisting_stiffness == 0.0
        && p.tikhonov == 0.0
}

/// Per-segment working arrays of a batch, reused from batch to batch (grown when a longer
/// fibre comes, never shrunk; every entry read in a step was written earlier in it).
#[derive(Debug, Default)]
pub struct Scratch {
    seg: Vec<Kept>,
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
}

impl Scratch {
    fn prepare(&mut self, n: usize) {
        if self.seg.len() >= n {
            return;
        }
        self.seg.resize(n, Kept::default());
        for v in [&mut self.pa, &mut self.qa] {
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
        ] {
            v.resize(n, V3::default());
        }
    }
}

/// Steps `fibres` (see [`eligible`]) by `dt`; `fluid[l]` holds fibre l's samples. On a
/// singular or non-finite system, returns the index in `fibres` of the first fibre
/// affected (the fibres' states are then unspecified, as after a failed group step).
pub fn step(
    p: &ModelParams,
    fibres: &mut [Fibre],
    fluid: &[&[FluidSample]],
    dt: f64,
    scratch: &mut Scratch,
) -> Result<(), usize> {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked just above); `step_avx2` only enables
            // it for code generation and is otherwise the portable kernel.
            return unsafe { step_avx2(p, fibres, fluid, dt, scratch) };
        }
    }
    kernel(p, fibres, fluid, dt, scratch)
}

/// [`kernel`] compiled for AVX2 (four `f64` per register). Only the instruction set
/// changes: no fused multiply-add is enabled, so results are the same bits.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn step_avx2(
    p: &ModelParams,
    fibres: &mut [Fibre],
    fluid: &[&[FluidSample]],
    dt: f64,
    scratch: &mut Scratch,
) -> Result<(), usize> {
    kernel(p, fibres, fluid, dt, scratch)
}

/// What the second half of the step needs of a segment's old state.
#[derive(Debug, Clone, Copy, Default)]
struct Kept {
    z: V3,
    n: V3,
    half_length: F4,
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

/// One value per lane, `get` of each lane's item.
#[inline(always)]
fn of4<T>(items: &[&T; LANES], get: impl Fn(&T) -> f64) -> F4 {
    F4([get(items[0]), get(items[1]), get(items[2]), get(items[3])])
}

/// The lanes' vectors as one lane vector.
#[inline(always)]
fn of4v(v: &[&Vector3<f64>; LANES]) -> V3 {
    V3([
        F4([v[0].x, v[1].x, v[2].x, v[3].x]),
        F4([v[0].y, v[1].y, v[2].y, v[3].y]),
        F4([v[0].z, v[1].z, v[2].z, v[3].z]),
    ])
}

/// [`crate::step::rotate_pair`] per lane: the axis and the normal turned by the rotation
/// vector `phi` (Rodrigues, eq. 12 made exact) and renormalised.
#[inline(always)]
fn rotate_pair(z: V3, n: V3, phi: V3) -> (V3, V3) {
    let angle = phi.norm();
    let still = angle.lt(1e-300);
    let k = phi.unscale(angle);
    let (mut s, mut c) = (F4::default(), F4::default());
    for l in 0..LANES {
        (s.0[l], c.0[l]) = angle.0[l].sin_cos();
    }
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

#[inline(always)]
fn kernel(
    p: &ModelParams,
    fibres: &mut [Fibre],
    fluid: &[&[FluidSample]],
    dt: f64,
    scratch: &mut Scratch,
) -> Result<(), usize> {
    let used = fibres.len();
    let n = fibres.first().map_or(0, Fibre::len);
    if used == 0 || used > LANES || fluid.len() != used || n == 0 {
        return Err(0);
    }
    if fibres
        .iter()
        .zip(fluid)
        .any(|(f, s)| f.len() != n || s.len() != n)
    {
        return Err(0);
    }
    scratch.prepare(n);
    let Scratch {
        seg,
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
    } = scratch;
    // unused lanes repeat fibre 0
    let idx = [0, 1, 2, 3].map(|l| if l < used { l } else { 0 });
    let mut ok = [true; LANES];
    let pi = std::f64::consts::PI;
    let mu = p.drag.viscosity;
    let dt4 = F4::splat(dt);
    let half = F4::splat(0.5);
    let gravity = V3::splat([p.gravity.x, p.gravity.y, p.gravity.z]);
    let kb = F4::splat(p.bending_stiffness);
    let fs: &[Fibre] = fibres;
    let first = |l: usize| &fs[idx[l]].segments[0].z;
    let mut z_next = of4v(&[first(0), first(1), first(2), first(3)]);
    for i in 0..n {
        let seg_of = |l: usize| &fs[idx[l]].segments[i];
        let props_of = |l: usize| &fs[idx[l]].props[i];
        let fluid_of = |l: usize| &fluid[idx[l]][i];
        let sg = [seg_of(0), seg_of(1), seg_of(2), seg_of(3)];
        let pr = [props_of(0), props_of(1), props_of(2), props_of(3)];
        let fl = [fluid_of(0), fluid_of(1), fluid_of(2), fluid_of(3)];
        let gm = [&fl[0].grad, &fl[1].grad, &fl[2].grad, &fl[3].grad];
        let z = z_next;
        if i + 1 < n {
            let next = |l: usize| &fs[idx[l]].segments[i + 1].z;
            z_next = of4v(&[next(0), next(1), next(2), next(3)]);
        }
        let v = of4v(&[&sg[0].v, &sg[1].v, &sg[2].v, &sg[3].v]);
        let w = of4v(&[&sg[0].w, &sg[1].w, &sg[2].w, &sg[3].w]);
        let vel = of4v(&[&fl[0].vel, &fl[1].vel, &fl[2].vel, &fl[3].vel]);
        let gr =
            M3::from_fn(|a, b| F4([gm[0][(a, b)], gm[1][(a, b)], gm[2][(a, b)], gm[3][(a, b)]]));
        let mass = of4(&pr, |p| p.mass);
        let l = of4(&pr, |p| p.shape.length);
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
        let l3 = l * l * l;
        let cd_rho_d = F4::splat(p.drag.drag_coefficient * p.drag.fluid_density)
            * of4(&pr, |p| p.shape.diameter)
            * v_perp;
        let zxgz = z.cross(g.mul_v(z));
        let l3_24 = cd_rho_d * l3 / F4::splat(24.0);
        let pi_mu_l3 = F4::splat(pi * mu) * l3;
        let ra = Axi {
            perp: F4::splat(3.0 * pi * mu) * l * of4(&pr, |p| p.shape.coeffs.ya)
                + half * cd_rho_d * l,
            par: F4::splat(3.0 * pi * mu) * l * of4(&pr, |p| p.shape.coeffs.xa),
        };
        let rc = Axi {
            perp: pi_mu_l3 * of4(&pr, |p| p.shape.coeffs.yc) + l3_24,
            par: pi_mu_l3 * of4(&pr, |p| p.shape.coeffs.xc),
        };
        let h_g = zxgz.scale(pi_mu_l3 * of4(&pr, |p| p.shape.coeffs.yh) + l3_24);
        let volume = mass
            / F4([
                fs[idx[0]].density,
                fs[idx[1]].density,
                fs[idx[2]].density,
                fs[idx[3]].density,
            ]);
        let fw = gravity.scale(mass - F4::splat(p.drag.fluid_density) * volume);
        let m_dt = mass / dt4;
        let pinv = Axi {
            perp: m_dt + ra.perp,
            par: m_dt + ra.par,
        }
        .inverse(&mut ok);
        let s_t = v.scale(m_dt) + ra.apply(z, vel) + fw;
        let inertia = Axi {
            perp: of4(&pr, |p| p.inertia_perp),
            par: of4(&pr, |p| p.inertia_axial),
        };
        let i_w = inertia.apply(z, w);
        let gyroscopic = w.cross(i_w);
        let qinv = Axi {
            perp: inertia.perp / dt4 + rc.perp,
            par: inertia.par / dt4 + rc.par,
        }
        .inverse(&mut ok);
        let mut bend = V3::default();
        if p.bending_stiffness != 0.0 {
            if i + 1 < n {
                bend = bend + z.cross(z_next).scale(kb);
            }
            if i > 0 {
                bend = bend + z.cross(seg[i - 1].z).scale(kb);
            }
        }
        let b_t = i_w.unscale(dt4) - gyroscopic + rc.apply(z, omega) + h_g + bend;
        let h = half * l;
        let zz = M3::outer(z);
        seg[i] = Kept {
            z,
            n: of4v(&[&sg[0].n, &sg[1].n, &sg[2].n, &sg[3].n]),
            half_length: h,
        };
        pa[i] = pinv;
        qa[i] = qinv;
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
        let yi = if i < nj { y[i] } else { V3::default() };
        let ym = if i > 0 { y[i - 1] } else { V3::default() };
        v_new[i] = ps[i] + pa[i].apply(z, yi - ym);
        w_new[i] = qb[i] + qa[i].apply(z, z.cross(yi + ym).scale(seg[i].half_length));
    }
    for (l, good) in ok.iter_mut().enumerate().take(used) {
        *good = (0..n).all(|i| v_new[i].finite_in(l) && w_new[i].finite_in(l));
    }
    if let Some(l) = first_bad(&ok, used) {
        return Err(l);
    }
    // rotations (eq. 12), then back to the fibres: positions (eq. 11), re-chaining, walls
    for i in 0..n {
        let (z, nn) = rotate_pair(seg[i].z, seg[i].n, w_new[i].scale(dt4));
        let nn = (nn - z.scale(z.dot(nn))).normalize();
        for (l, f) in fibres.iter_mut().enumerate() {
            let at = |v: &V3| Vector3::new(v.0[0].0[l], v.0[1].0[l], v.0[2].0[l]);
            let s = &mut f.segments[i];
            s.v = at(&v_new[i]);
            s.w = at(&w_new[i]);
            s.r += dt * s.v;
            s.z = at(&z);
            s.n = at(&nn);
        }
    }
    for f in fibres.iter_mut() {
        f.rechain();
        if let Some(hh) = p.wall_half_height {
            wall_contact(f, hh);
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use crate::fibre::Fibre;
    use crate::group::FibreGroup;
    use crate::hydro::DragModel;
    use crate::step::{FluidSample, ModelParams};
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
    fn fibres(count: usize, segments: usize, seed: &mut u64) -> Vec<Fibre> {
        (0..count)
            .map(|k| {
                let y = match k % 3 {
                    0 => 149.0,
                    1 => -148.5,
                    _ => 100.0 * rnd(seed),
                };
                let axis = Vector3::new(rnd(seed), rnd(seed), rnd(seed) + 0.1);
                let lengths: Vec<f64> = (0..segments).map(|_| 3.0 + rnd(seed)).collect();
                let mut f = Fibre::straight(
                    Vector3::new(500.0 * rnd(seed), y, 200.0 * rnd(seed)),
                    axis,
                    &lengths,
                    &vec![0.232 + 0.05 * rnd(seed); segments],
                    1150.0 + 1150.0 * (k % 2) as f64,
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

    fn fluid(g: &FibreGroup, seed: &mut u64, still: bool) -> Vec<FluidSample> {
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

    fn bits(g: &FibreGroup) -> Vec<u64> {
        g.fibres
            .iter()
            .flat_map(|f| f.segments.iter())
            .flat_map(|s| [s.r, s.z, s.v, s.w, s.n])
            .flat_map(|v| [v.x, v.y, v.z])
            .map(f64::to_bits)
            .collect()
    }

    /// Batched (four fibres per SIMD pass, padded lanes for the remainder) and one fibre
    /// at a time give the same bits, step after step: with and without bending stiffness
    /// and gravity, for 1, 3 and 7 segments, with fibres at rest in still fluid (the
    /// zero-rotation branch) and fibres pushed back from the walls.
    #[test]
    fn batch_matches_the_scalar_step_bit_for_bit() {
        let mut seed = 7u64;
        for (segments, bending, gravity) in [
            (7, 0.0, 0.0),
            (7, 0.05, 9.81e-3),
            (3, 0.0, 0.0),
            (1, 0.0, 1e-3),
        ] {
            let fs = fibres(11, segments, &mut seed);
            let mut batched = FibreGroup::new(params(bending, gravity), fs.clone());
            let mut serial = batched.clone();
            let mut single = FibreGroup::new(params(bending, gravity), fs);
            for step in 0..25 {
                let still = step == 0 && gravity == 0.0;
                let fl = fluid(&batched, &mut seed, still);
                batched.step(&fl, 0.2).expect("batched step");
                serial.step_serial(&fl, 0.2).expect("serial batched step");
                single.step_serial_unbatched(&fl, 0.2).expect("scalar step");
                assert_eq!(bits(&batched), bits(&single), "N {segments}, step {step}");
                assert_eq!(bits(&serial), bits(&single), "N {segments}, step {step}");
            }
        }
    }

    /// A fibre whose system cannot be solved is named by its index in the group.
    #[test]
    fn a_non_finite_fibre_is_named() {
        let mut seed = 3u64;
        let mut g = FibreGroup::new(params(0.0, 0.0), fibres(6, 7, &mut seed));
        let mut fl = fluid(&g, &mut seed, false);
        fl[5 * 7 + 2].vel.x = f64::NAN;
        match g.step(&fl, 0.2) {
            Err(crate::FibreError::Singular { fibre }) => assert_eq!(fibre, 5),
            other => panic!("expected fibre 5 to fail, got {other:?}"),
        }
    }
}
