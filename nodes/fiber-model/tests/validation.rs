//! Validation of the fibre model against analytic limits (tolerances stated per test).

use fiberflow_fiber_model::cases::{paper_diameter_plus, relaxation_time_plus};
use fiberflow_fiber_model::fiber::Fiber;
use fiberflow_fiber_model::hydro::cox_equivalent_aspect_ratio;
use fiberflow_fiber_model::metrics::metrics;
use fiberflow_fiber_model::step::{step, step_with_loads, FluidSample, ModelParams};
use fiberflow_fiber_model::DragModel;
use nalgebra::{Matrix3, Vector3};
use std::f64::consts::PI;

fn params(cd: f64) -> ModelParams {
    ModelParams {
        drag: DragModel {
            viscosity: 1.0,
            fluid_density: 1.0,
            drag_coefficient: cd,
        },
        gravity: Vector3::zeros(),
        bending_stiffness: 0.0,
        twisting_stiffness: 0.0,
        tikhonov: 0.0,
        wall_half_height: None,
    }
}

fn shear(s: f64) -> impl Fn(&Vector3<f64>) -> FluidSample {
    move |r| FluidSample {
        vel: Vector3::new(s * r.y, 0.0, 0.0),
        grad: Matrix3::new(0.0, s, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
    }
}

fn samples(f: &Fiber, flow: &dyn Fn(&Vector3<f64>) -> FluidSample) -> Vec<FluidSample> {
    f.segments.iter().map(|s| flow(&s.r)).collect()
}

fn straight(n: usize, l: f64, d: f64, rho: f64, axis: Vector3<f64>) -> Fiber {
    Fiber::straight(Vector3::zeros(), axis, &vec![l; n], &vec![d; n], rho).unwrap()
}

/// A segment released at rest in uniform flow relaxes with τ = m/(3πηl X^A) along and
/// m/(3πηl Y^A) across its axis: after t = τ the velocity is 1 − e⁻¹ of the fluid's
/// (tolerance 1e-3 with Δt = τ/2000; implicit Euler). Case 1 has τ_s+ = 13.5.
#[test]
fn relaxation_in_uniform_flow() {
    let d = paper_diameter_plus();
    let tau_s = relaxation_time_plus(3.0, d, 1150.0);
    assert!((tau_s - 13.5).abs() < 1e-6, "τ_s+ = {tau_s}");
    for (axis, across) in [(Vector3::x(), false), (Vector3::y(), true)] {
        let mut f = straight(1, 3.0, d, 1150.0, axis);
        let k = f.props[0].shape.coeffs;
        let coeff = if across { k.ya } else { k.xa };
        let tau = f.props[0].mass / (3.0 * PI * 3.0 * coeff);
        let u = 1.0;
        let flow = |_: &Vector3<f64>| FluidSample {
            vel: Vector3::new(u, 0.0, 0.0),
            grad: Matrix3::zeros(),
        };
        let dt = tau / 2000.0;
        for _ in 0..2000 {
            let smp = samples(&f, &flow);
            step(&params(0.0), &mut f, &smp, dt).unwrap();
        }
        let v = f.segments[0].v.x;
        assert!(
            (v - (1.0 - (-1.0f64).exp())).abs() < 1e-3,
            "v(τ) = {v} (across = {across})"
        );
    }
}

/// Solid-body rotation: straight and bent fibres rotate rigidly with the fluid; joints never
/// separate (gap <= 1e-12 L) and the contour length is conserved to 1e-12 relative over
/// 10^5 steps; the shape (end-to-end distance) changes by < 1e-5 relative (the only
/// deformation is the physical centrifugal straightening, proportional to the density and
/// made negligible here by a light fibre).
#[test]
fn solid_body_rotation_is_rigid() {
    let omega = Vector3::new(0.0, 0.0, 0.05);
    let flow = move |r: &Vector3<f64>| FluidSample {
        vel: omega.cross(r),
        grad: Matrix3::new(0.0, -omega.z, 0.0, omega.z, 0.0, 0.0, 0.0, 0.0, 0.0),
    };
    for bent in [false, true] {
        let mut f = straight(7, 3.0, 0.232, 1e-5, Vector3::new(1.0, 0.2, 0.3));
        if bent {
            for (i, s) in f.segments.iter_mut().enumerate() {
                let a = 0.3 * i as f64;
                s.z = Vector3::new(a.cos(), a.sin(), 0.2).normalize();
            }
            f.rechain();
        }
        let total: f64 = f.props.iter().map(|p| p.shape.length).sum();
        let e2e0 = metrics(&f).end_to_end;
        for _ in 0..100_000 {
            let smp = samples(&f, &flow);
            step(&params(1.0), &mut f, &smp, 0.01).unwrap();
        }
        assert!(
            f.max_joint_gap() <= 1e-12 * total,
            "gap {}",
            f.max_joint_gap()
        );
        let j = f.joints();
        let contour: f64 = j.windows(2).map(|w| (w[1] - w[0]).norm()).sum();
        assert!(((contour - total) / total).abs() < 1e-12);
        let e2e = metrics(&f).end_to_end;
        assert!(
            ((e2e - e2e0) / e2e0).abs() < 1e-5,
            "end-to-end {e2e0} -> {e2e}"
        );
        // angular velocity equals the fluid's (light fibre, tiny lag)
        for s in &f.segments {
            assert!((s.w - omega).norm() < 1e-3 * omega.norm(), "ω = {:?}", s.w);
        }
    }
}

/// Pure strain: a single segment at 45° turns towards the stretching axis ê1 with only
/// viscous drag and with the inertial drag added.
#[test]
fn pure_strain_aligns_with_stretching() {
    let e = 0.1;
    let flow = move |r: &Vector3<f64>| FluidSample {
        vel: Vector3::new(e * r.x, -e * r.y, 0.0),
        grad: Matrix3::new(e, 0.0, 0.0, 0.0, -e, 0.0, 0.0, 0.0, 0.0),
    };
    for cd in [0.0, 1.0] {
        let mut f = straight(1, 3.0, 0.232, 1.0, Vector3::new(1.0, 1.0, 0.0));
        for _ in 0..2000 {
            let smp = samples(&f, &flow);
            step(&params(cd), &mut f, &smp, 0.01).unwrap();
        }
        let z = f.segments[0].z;
        assert!(z.x.abs() > 0.8, "cd = {cd}: ẑ = {z:?}");
    }
}

/// The segment length l whose Cox-equivalent spheroid has aspect ratio `re` (d = 1).
fn length_for_re(re: f64) -> f64 {
    let (mut lo, mut hi) = (1.7, 1e4);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if cox_equivalent_aspect_ratio(mid) < re {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Time for the in-plane angle of `orient(f)` to turn by 2π in simple shear S = 1.
fn measure_period(
    f: &mut Fiber,
    p: &ModelParams,
    dt: f64,
    t_max: f64,
    orient: impl Fn(&Fiber) -> Vector3<f64>,
    mut each: impl FnMut(&Fiber),
) -> f64 {
    let flow = shear(1.0);
    let angle = |z: Vector3<f64>| z.y.atan2(z.x);
    let start = angle(orient(f));
    let mut prev = start;
    let mut turned = 0.0;
    let mut t = 0.0;
    while t < t_max {
        let smp = samples(f, &flow);
        step(p, f, &smp, dt).unwrap();
        t += dt;
        each(f);
        let a = angle(orient(f));
        let mut da = a - prev;
        if da > PI {
            da -= 2.0 * PI;
        }
        if da < -PI {
            da += 2.0 * PI;
        }
        let before = turned;
        turned += da;
        prev = a;
        if turned.abs() >= 2.0 * PI {
            // linear interpolation of the crossing inside this step
            let frac = (2.0 * PI - before.abs()) / (turned.abs() - before.abs());
            return t - dt + frac * dt;
        }
    }
    f64::NAN
}

/// Jeffery orbits (inertia negligible): a single segment (N = 1) has the period
/// 2π(r_e + 1/r_e)/S of its own spheroid within 0.5% for r_e = 5, 10, 20.
#[test]
fn jeffery_period_single_segment() {
    for re in [5.0, 10.0, 20.0] {
        let l = length_for_re(re);
        let mut f = straight(1, l, 1.0, 1e-6, Vector3::new(1.0, 0.0, 0.0));
        let expected = 2.0 * PI * (re + 1.0 / re);
        let period = measure_period(
            &mut f,
            &params(0.0),
            2e-3,
            3.0 * expected,
            |f| f.segments[0].z,
            |_| {},
        );
        let rel = (period - expected).abs() / expected;
        assert!(
            rel < 0.005,
            "r_e = {re}: period {period}, Jeffery {expected}, rel {rel:e}"
        );
    }
}

/// A stiff chain (N = 7, large bending stiffness) rotates as a rigid body (σ² < 1e-4
/// throughout) with a period far above a single segment's and within 25% of the
/// whole-fibre Cox value (measured: 13% slower, because the chain has no hydrodynamic
/// interaction between segments, so each carries the full drag of an isolated segment); a fully
/// flexible chain started with a 1° kink does not stay straight (σ² > 1e-2 at some time).
/// Prints the stiff-chain period beside the whole-fibre Cox value.
#[test]
fn stiff_and_flexible_chains_in_shear() {
    let d = 0.232;
    let l = 3.0;
    let mut stiff_p = params(0.0);
    stiff_p.bending_stiffness = 200.0;
    let mut f = straight(7, l, d, 1e-3, Vector3::new(1.0, 0.0, 0.0));
    let mut max_s2: f64 = 0.0;
    let period = measure_period(
        &mut f,
        &stiff_p,
        1e-3,
        2000.0,
        |f| metrics(f).orientation,
        |f| max_s2 = max_s2.max(metrics(f).sigma2),
    );
    let re_seg = cox_equivalent_aspect_ratio(l / d);
    let re_whole = cox_equivalent_aspect_ratio(7.0 * l / d);
    let t_seg = 2.0 * PI * (re_seg + 1.0 / re_seg);
    let t_whole = 2.0 * PI * (re_whole + 1.0 / re_whole);
    println!(
        "stiff chain N=7: period S·T = {period:.1}; single segment (r_e = {re_seg:.2}) {t_seg:.1}; \
         whole fibre Cox (r_e = {re_whole:.2}) {t_whole:.1}; max σ² = {max_s2:.2e}"
    );
    assert!(max_s2 < 1e-4, "stiff chain bent: σ² = {max_s2}");
    assert!(
        period > 3.0 * t_seg,
        "period {period} vs single segment {t_seg}"
    );
    assert!(
        (period / t_whole - 1.0).abs() < 0.25,
        "period {period} vs whole fibre {t_whole}"
    );

    let mut g = straight(7, l, d, 1e-3, Vector3::new(1.0, 0.0, 0.0));
    let kink = 1f64.to_radians();
    g.segments[6].z = Vector3::new(kink.cos(), kink.sin(), 0.0);
    g.rechain();
    let mut max_flex: f64 = 0.0;
    let _ = measure_period(
        &mut g,
        &params(0.0),
        1e-3,
        400.0,
        |f| metrics(f).orientation,
        |f| max_flex = max_flex.max(metrics(f).sigma2),
    );
    assert!(
        max_flex > 1e-2,
        "flexible chain stayed straight: max σ² = {max_flex}"
    );
}

/// First-order convergence in Δt of the positions (observed order within 0.8..1.2) on a
/// smooth case: a bent, inertial fibre in simple shear with inertial drag.
#[test]
fn first_order_in_time() {
    let run = |dt: f64| {
        let mut f = straight(5, 3.0, 0.232, 1150.0, Vector3::new(0.3, 1.0, 0.2));
        let flow = shear(0.1);
        let steps = (20.0 / dt).round() as usize;
        for _ in 0..steps {
            let smp = samples(&f, &flow);
            step(&params(1.0), &mut f, &smp, dt).unwrap();
        }
        f.segments.iter().map(|s| s.r).collect::<Vec<_>>()
    };
    let a = run(0.04);
    let b = run(0.02);
    let c = run(0.01);
    let diff = |x: &[Vector3<f64>], y: &[Vector3<f64>]| {
        x.iter()
            .zip(y)
            .map(|(p, q)| (p - q).norm())
            .fold(0.0, f64::max)
    };
    let order = (diff(&a, &b) / diff(&b, &c)).log2();
    assert!((0.8..1.2).contains(&order), "observed order {order}");
}

/// Momentum balance of a free fibre over one step: Σ m Δṙ = Δt Σ (F^h + F^w) and
/// Σ [r × m Δṙ + Δt G_i + I Δω] = Δt Σ [r × F + T^h], to round-off (relative 1e-10),
/// with G_i the step's gyroscopic term (`Loads::gyroscopic`, → ω×(Iω) as Δt → 0); with
/// inertial drag, gravity, bending and twisting stiffness on.
#[test]
fn momentum_balance() {
    let mut p = params(1.0);
    p.gravity = Vector3::new(0.0, -0.01, 0.0);
    p.bending_stiffness = 5.0;
    p.twisting_stiffness = 3.0;
    let mut f = straight(7, 3.0, 0.232, 1150.0, Vector3::new(1.0, 0.4, -0.2));
    for (i, s) in f.segments.iter_mut().enumerate() {
        let a = 0.2 * i as f64;
        s.z = Vector3::new(a.cos(), a.sin(), 0.3).normalize();
        s.n = (Vector3::new(0.0, 0.1 * i as f64, 1.0)
            - s.z * s.z.dot(&Vector3::new(0.0, 0.1 * i as f64, 1.0)))
        .normalize();
        s.v = Vector3::new(0.1 * i as f64, -0.05, 0.02);
        s.w = Vector3::new(0.01, 0.02 * i as f64, -0.03);
    }
    f.rechain();
    let flow = |r: &Vector3<f64>| FluidSample {
        vel: Vector3::new(0.3 * r.y + 1.0, 0.1 * r.z, -0.05 * r.x),
        grad: Matrix3::new(0.0, 0.3, 0.0, 0.0, 0.0, 0.1, -0.05, 0.0, 0.0),
    };
    let dt = 0.05;
    let before = f.clone();
    let smp = samples(&f, &flow);
    let loads = step_with_loads(&p, &mut f, &smp, dt).unwrap();
    let mut dp = Vector3::zeros();
    let mut fsum = Vector3::zeros();
    let mut dl = Vector3::zeros();
    let mut tsum = Vector3::zeros();
    for i in 0..f.len() {
        let (s0, s1, pr) = (before.segments[i], f.segments[i], before.props[i]);
        let i0 = pr.inertia(&s0.z);
        dp += pr.mass * (s1.v - s0.v);
        fsum += dt * loads.force[i];
        dl +=
            s0.r.cross(&(pr.mass * (s1.v - s0.v))) + dt * loads.gyroscopic[i] + i0 * (s1.w - s0.w);
        tsum += dt * (s0.r.cross(&loads.force[i]) + loads.torque[i]);
    }
    let rel = (dp - fsum).norm() / fsum.norm().max(dp.norm());
    assert!(rel < 1e-10, "linear momentum: {dp:?} vs {fsum:?}");
    let rel = (dl - tsum).norm() / tsum.norm().max(dl.norm());
    assert!(rel < 1e-10, "angular momentum: {dl:?} vs {tsum:?}");
}

/// A slender segment spinning about its axis and tumbling (the regime that made the
/// paper's implicit İ·ω_n term unstable) stays bounded: |ω| never exceeds 10 × its start.
#[test]
fn slender_segment_rotation_is_stable() {
    let mut f = straight(7, 3.0, 0.232, 1150.0, Vector3::new(0.3, 1.0, 0.2));
    for s in f.segments.iter_mut() {
        s.w = Vector3::new(0.5, -0.7, 0.9);
    }
    let flow = |r: &Vector3<f64>| FluidSample {
        vel: Vector3::new(r.y, 0.0, 0.0),
        grad: Matrix3::new(0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
    };
    for _ in 0..2000 {
        let smp = samples(&f, &flow);
        step(&params(1.0), &mut f, &smp, 0.25).unwrap();
        for s in &f.segments {
            assert!(s.w.norm() < 10.0 * 1.3, "ω blew up: {:?}", s.w);
        }
    }
}

/// Kinetic energy, translational and rotational, of a fibre.
fn kinetic_energy(f: &Fiber) -> f64 {
    f.segments
        .iter()
        .zip(&f.props)
        .map(|(s, p)| 0.5 * p.mass * s.v.norm_squared() + 0.5 * s.w.dot(&(p.inertia(&s.z) * s.w)))
        .sum()
}

/// A case-1 fibre, slightly bent (segments ±0.05 rad off x), spinning fast about its own
/// axis (ω = 44 about x: what one frictional contact left a fibre with in the channel,
/// docs/contact.md) in still fluid only loses energy: at Δt = 0.2, 0.02 and 0.002 no
/// step's kinetic energy exceeds the step before's (relative 1e-12), over 200 steps. With
/// the gyroscopic term taken explicitly it grew 5 × 10⁷-fold in 10 steps at Δt = 0.2
/// and 68-fold over 100 steps at 0.02.
#[test]
fn fast_axial_spin_does_not_feed_tumbling() {
    for dt in [0.2, 0.02, 0.002] {
        let mut f = straight(7, 3.0, 0.232, 1150.0, Vector3::x());
        for (i, s) in f.segments.iter_mut().enumerate() {
            let a: f64 = if i % 2 == 0 { 0.05 } else { -0.05 };
            s.z = Vector3::new(a.cos(), a.sin(), 0.0);
            s.n = Vector3::z();
            s.w = Vector3::new(44.0, 0.0, 0.0);
        }
        f.rechain();
        let still = vec![FluidSample::at_rest(); f.len()];
        let mut e = kinetic_energy(&f);
        for k in 0..200 {
            step(&params(1.0), &mut f, &still, dt).unwrap();
            let now = kinetic_energy(&f);
            assert!(
                now <= e * (1.0 + 1e-12),
                "Δt {dt}, step {k}: kinetic energy {e:.6e} -> {now:.6e}"
            );
            e = now;
        }
    }
}

/// One segment in vacuum (no fluid force), spinning about its axis and tumbling (ω∥ Δt =
/// 8.8): the step keeps ω∥, |ω⊥| and the kinetic energy to round-off (relative 1e-10)
/// over 1000 steps, as torque-free motion of an axisymmetric body does.
#[test]
fn torque_free_segment_keeps_its_spin() {
    let mut p = params(0.0);
    p.drag.viscosity = 0.0;
    let mut f = straight(1, 3.0, 0.232, 1150.0, Vector3::new(0.3, 1.0, 0.2));
    let z = f.segments[0].z;
    let across = z.cross(&Vector3::x()).normalize();
    f.segments[0].w = 44.0 * z + 0.7 * across;
    let e0 = kinetic_energy(&f);
    let none = vec![FluidSample::at_rest(); 1];
    for _ in 0..1000 {
        step(&p, &mut f, &none, 0.2).unwrap();
    }
    let s = f.segments[0];
    let w_par = s.w.dot(&s.z);
    let w_perp = (s.w - w_par * s.z).norm();
    assert!((w_par / 44.0 - 1.0).abs() < 1e-10, "ω∥ {w_par}");
    assert!((w_perp / 0.7 - 1.0).abs() < 1e-10, "|ω⊥| {w_perp}");
    assert!((kinetic_energy(&f) / e0 - 1.0).abs() < 1e-10);
}

/// Twisting stiffness: a fibre with one end segment twisted by 30° about its axis (in
/// quiescent fluid) untwists — every joint's twist falls below 1% of the start — while with
/// k_t = 0 the twist stays exactly where it was; bending is unaffected (σ² stays 0).
#[test]
fn twisting_stiffness_relaxes_twist() {
    let build = || {
        let mut f = straight(7, 3.0, 0.232, 1150.0, Vector3::new(0.0, 1.0, 0.0));
        let last = f.segments.len() - 1;
        let s = &mut f.segments[last];
        s.n = fiberflow_fiber_model::step::rotate(&s.n, &(s.z * 30f64.to_radians()));
        f
    };
    let still = |_: &Vector3<f64>| FluidSample::at_rest();
    for kt in [0.0, 2.0] {
        let mut p = params(0.0);
        p.twisting_stiffness = kt;
        let mut f = build();
        let t0 = f.twist(5);
        assert!(
            (t0 - 30f64.to_radians()).abs() < 1e-12,
            "initial twist {t0}"
        );
        for _ in 0..20_000 {
            let smp = samples(&f, &still);
            step(&p, &mut f, &smp, 0.05).unwrap();
        }
        let worst = (0..6).map(|k| f.twist(k).abs()).fold(0.0, f64::max);
        if kt == 0.0 {
            assert!(
                (f.twist(5) - t0).abs() < 1e-12,
                "free joint changed twist: {}",
                f.twist(5)
            );
        } else {
            assert!(worst < 0.01 * t0, "twist left: {worst}");
        }
        assert!(
            metrics(&f).sigma2 < 1e-20,
            "bending appeared: {}",
            metrics(&f).sigma2
        );
    }
}

/// Wall contact: a fibre pushed towards a wall never leaves |x2| <= H.
#[test]
fn wall_contact_keeps_fiber_inside() {
    let mut p = params(1.0);
    p.wall_half_height = Some(20.0);
    let mut f = straight(7, 3.0, 0.232, 1150.0, Vector3::new(0.0, 1.0, 0.0));
    let flow = |_: &Vector3<f64>| FluidSample {
        vel: Vector3::new(0.5, -2.0, 0.0),
        grad: Matrix3::zeros(),
    };
    for _ in 0..5000 {
        let smp = samples(&f, &flow);
        step(&p, &mut f, &smp, 0.05).unwrap();
        for j in f.joints() {
            assert!(j.y >= -20.0 - 1e-9, "end at y = {}", j.y);
        }
    }
}

/// Invalid fibres give a named error.
#[test]
fn invalid_input_is_named() {
    let e = Fiber::straight(Vector3::zeros(), Vector3::x(), &[], &[], 1.0).unwrap_err();
    assert!(e.to_string().contains("segments"), "{e}");
    let e = Fiber::straight(Vector3::zeros(), Vector3::x(), &[0.1], &[0.2], 1.0).unwrap_err();
    assert!(e.to_string().contains("length"), "{e}");
    let e = Fiber::straight(Vector3::zeros(), Vector3::x(), &[3.0], &[0.2], -1.0).unwrap_err();
    assert!(e.to_string().contains("density"), "{e}");
    let e = Fiber::straight(Vector3::zeros(), Vector3::x(), &[3.0], &[f64::NAN], 1.0).unwrap_err();
    assert!(e.to_string().contains("diameter"), "{e}");
}

/// The dense Tikhonov path with a tiny parameter agrees with the block-Thomas solve.
#[test]
fn tikhonov_agrees_with_exact_solve() {
    let mut a = straight(7, 3.0, 0.232, 1150.0, Vector3::new(0.2, 1.0, 0.1));
    let mut b = a.clone();
    let flow = shear(0.1);
    let mut pt = params(1.0);
    pt.tikhonov = 1e-14;
    for _ in 0..100 {
        let s = samples(&a, &flow);
        step(&params(1.0), &mut a, &s, 0.05).unwrap();
        let s = samples(&b, &flow);
        step(&pt, &mut b, &s, 0.05).unwrap();
    }
    for (x, y) in a.segments.iter().zip(&b.segments) {
        assert!((x.r - y.r).norm() < 1e-8, "{:?} vs {:?}", x.r, y.r);
    }
}
