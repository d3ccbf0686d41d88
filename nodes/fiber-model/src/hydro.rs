//! Segment hydrodynamics (paper Appendix A): the Cox-equivalent prolate spheroid
//! (eq. 21–22), Kim & Karrila resistance functions (eq. 28, with the corrected Y^C),
//! viscous resistance tensors (eq. 25–27) and the linearised inertial cross-flow drag
//! (eq. 29–31, with the strain-torque sign made physical).

use nalgebra::{Matrix3, Vector3};

/// The five resistance functions of a prolate spheroid of eccentricity e (eq. 28).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ResistanceFunctions {
    pub xa: f64,
    pub ya: f64,
    pub xc: f64,
    pub yc: f64,
    pub yh: f64,
}

/// Power series in e of the three denominators of eq. 28, each divided by e³, for small
/// e where the closed forms cancel catastrophically. L = 2 Σ e^(2k+1)/(2k+1).
fn series(e: f64) -> (f64, f64, f64) {
    // d1 = -2e + (1+e²)L, d2 = 2e + (3e²-1)L, d3 = 2e - (1-e²)L
    let (mut d1, mut d2, mut d3) = (0.0, 0.0, 0.0);
    let e2 = e * e;
    let mut p = 1.0; // e^(2k+1) / e³ for k = 1
    for k in 1..80 {
        let a = 2.0 / (2 * k + 1) as f64;
        let b = 2.0 / (2 * k - 1) as f64;
        d1 += (a + b) * p;
        d2 += (-a + 3.0 * b) * p;
        d3 += (-a + b) * p;
        p *= e2;
        if p < 1e-18 {
            break;
        }
    }
    (d1, d2, d3)
}

impl ResistanceFunctions {
    /// Eq. 28 for eccentricity `e` in [0, 1). Y^C uses the denominator −2e + (1+e²)L
    /// (Kim & Karrila); the paper prints −2e − (1+e²)L, which is negative.
    pub fn of_eccentricity(e: f64) -> Self {
        let e3 = e * e * e;
        let (d1, d2, d3) = if e < 0.5 {
            series(e)
        } else {
            let l = ((1.0 + e) / (1.0 - e)).ln();
            (
                (-2.0 * e + (1.0 + e * e) * l) / e3,
                (2.0 * e + (3.0 * e * e - 1.0) * l) / e3,
                (2.0 * e - (1.0 - e * e) * l) / e3,
            )
        };
        Self {
            xa: 8.0 / 3.0 / d1,
            ya: 16.0 / 3.0 / d2,
            xc: 4.0 / 3.0 * (1.0 - e * e) / d3,
            yc: 4.0 / 3.0 * (2.0 - e * e) / d1,
            yh: 4.0 / 3.0 * e * e / d1,
        }
    }
}

/// Cox's equivalent aspect ratio of a cylinder of aspect ratio r_c (eq. 21).
pub fn cox_equivalent_aspect_ratio(rc: f64) -> f64 {
    1.24 * rc / rc.ln().sqrt()
}

/// Geometry-only hydrodynamic description of a segment (fixed over a run).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SegmentShape {
    pub length: f64,
    pub diameter: f64,
    /// Equivalent spheroid aspect ratio r_e and eccentricity e.
    pub aspect_equivalent: f64,
    pub eccentricity: f64,
    pub coeffs: ResistanceFunctions,
}

impl SegmentShape {
    /// Major axis a = l, minor axis b from eq. 22, e = sqrt(1 - b²/a²). Requires l > d.
    pub fn new(length: f64, diameter: f64) -> Self {
        let re = cox_equivalent_aspect_ratio(length / diameter);
        let e = (1.0 - 1.0 / (re * re)).max(0.0).sqrt();
        Self {
            length,
            diameter,
            aspect_equivalent: re,
            eccentricity: e,
            coeffs: ResistanceFunctions::of_eccentricity(e),
        }
    }
}

/// Resistance tensors of one segment at one instant (eq. 4: F = A·(v-ṙ),
/// T = C·(Ω-ω) + H:G, with H:G returned as a vector).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Resistance {
    pub a: Matrix3<f64>,
    pub c: Matrix3<f64>,
    /// Strain torque H:G (viscous + inertial).
    pub h_g: Vector3<f64>,
}

/// Which drag contributions are active.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DragModel {
    /// Dynamic viscosity η.
    pub viscosity: f64,
    /// Fluid density ρ.
    pub fluid_density: f64,
    /// Cross-flow drag coefficient C_D (1 in the paper); 0 disables the inertial part.
    pub drag_coefficient: f64,
}

/// An operator that is axisymmetric about a unit axis ẑ: `perp` I + (`par` − `perp`) ẑẑᵀ.
/// Every resistance, inertia and mobility tensor of a segment has this form.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Axisymmetric {
    pub perp: f64,
    pub par: f64,
}

impl Axisymmetric {
    /// The operator applied to `v` for axis `z` (no matrix formed).
    #[inline]
    pub fn apply(&self, z: &Vector3<f64>, v: &Vector3<f64>) -> Vector3<f64> {
        self.perp * v + (self.par - self.perp) * z.dot(v) * z
    }

    /// Its inverse (both eigenvalues nonzero).
    #[inline]
    pub fn inverse(&self) -> Option<Axisymmetric> {
        let ok = |x: f64| x != 0.0 && x.is_finite();
        (ok(self.perp) && ok(self.par)).then(|| Axisymmetric {
            perp: 1.0 / self.perp,
            par: 1.0 / self.par,
        })
    }

    /// The matrix for axis `z`.
    pub fn matrix(&self, z: &Vector3<f64>) -> Matrix3<f64> {
        self.perp * Matrix3::identity() + (self.par - self.perp) * (z * z.transpose())
    }
}

/// Eq. 25–27 and 29–31 in axisymmetric form: translational `a` and rotational `c`
/// resistance, and the strain torque H:G.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisymmetricResistance {
    pub a: Axisymmetric,
    pub c: Axisymmetric,
    pub h_g: Vector3<f64>,
}

/// Evaluates eq. 25–27 and 29–31 for axis `z`, strain rate `g` and cross-flow speed
/// `v_perp`: viscous A^v = 3πηl (Y^A I + (X^A − Y^A) ẑẑ), C^v = πηl³ (Y^C I + (X^C − Y^C) ẑẑ),
/// H^v:G = πηl³ Y^H ẑ × (Gẑ); the linearised inertial drag adds ½ C_D ρ d |v⊥| l and
/// C_D ρ d |v⊥| l³/24 across the axis only, and its strain torque in the viscous sense.
pub fn resistance_axisymmetric(
    shape: &SegmentShape,
    drag: &DragModel,
    z: &Vector3<f64>,
    g: &Matrix3<f64>,
    v_perp: f64,
) -> AxisymmetricResistance {
    let l = shape.length;
    let k = &shape.coeffs;
    let mu = drag.viscosity;
    let l3 = l * l * l;
    let pi = std::f64::consts::PI;
    let cd_rho_d = drag.drag_coefficient * drag.fluid_density * shape.diameter * v_perp;
    let zxgz = z.cross(&(g * z));
    AxisymmetricResistance {
        a: Axisymmetric {
            perp: 3.0 * pi * mu * l * k.ya + 0.5 * cd_rho_d * l,
            par: 3.0 * pi * mu * l * k.xa,
        },
        c: Axisymmetric {
            perp: pi * mu * l3 * k.yc + cd_rho_d * l3 / 24.0,
            par: pi * mu * l3 * k.xc,
        },
        h_g: (pi * mu * l3 * k.yh + cd_rho_d * l3 / 24.0) * zxgz,
    }
}

/// [`resistance_axisymmetric`] as matrices.
pub fn resistance(
    shape: &SegmentShape,
    drag: &DragModel,
    z: &Vector3<f64>,
    g: &Matrix3<f64>,
    v_perp: f64,
) -> Resistance {
    let r = resistance_axisymmetric(shape, drag, z, g, v_perp);
    Resistance {
        a: r.a.matrix(z),
        c: r.c.matrix(z),
        h_g: r.h_g,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Sphere limit e -> 0: X^A, Y^A, X^C, Y^C -> 1 and Y^H -> 0, with error O(e²)
    /// (tolerance 2e²: 2e-6 at e = 1e-3, 2e-12 at e = 1e-6).
    #[test]
    fn sphere_limit() {
        for e in [1e-3, 1e-6] {
            let r = ResistanceFunctions::of_eccentricity(e);
            for (name, v) in [("XA", r.xa), ("YA", r.ya), ("XC", r.xc), ("YC", r.yc)] {
                assert!((v - 1.0).abs() < 2.0 * e * e, "{name}({e}) = {v}");
            }
            assert!(r.yh.abs() < 2.0 * e * e, "YH = {}", r.yh);
        }
    }

    /// Series and closed forms agree where both are accurate (e = 0.5, rel 1e-12).
    #[test]
    fn series_matches_closed_form() {
        let e: f64 = 0.5;
        let (s1, s2, s3) = series(e);
        let l = ((1.0 + e) / (1.0 - e)).ln();
        let e3 = e.powi(3);
        let c1 = (-2.0 * e + (1.0 + e * e) * l) / e3;
        let c2 = (2.0 * e + (3.0 * e * e - 1.0) * l) / e3;
        let c3 = (2.0 * e - (1.0 - e * e) * l) / e3;
        for (s, c) in [(s1, c1), (s2, c2), (s3, c3)] {
            assert!(((s - c) / c).abs() < 1e-12, "{s} vs {c}");
        }
    }

    /// Slender limit (Kim & Karrila asymptotics, with ε = 1/ln(2 r_e) ...): for large r_e,
    /// X^A ≈ (4/3)/(2 ln 2r_e - 1), Y^A ≈ (8/3)/(2 ln 2r_e + 1), X^C -> 0, Y^C ≈ (2/3)/(2 ln 2r_e - 1);
    /// within 1% at r_e = 1000.
    #[test]
    fn slender_limit() {
        let re: f64 = 1000.0;
        let e = (1.0 - 1.0 / (re * re)).sqrt();
        let r = ResistanceFunctions::of_eccentricity(e);
        let l = (2.0 * re).ln();
        let xa = 4.0 / 3.0 / (2.0 * l - 1.0);
        let ya = 8.0 / 3.0 / (2.0 * l + 1.0);
        let yc = 2.0 / 3.0 / (2.0 * l - 1.0);
        assert!((r.xa / xa - 1.0).abs() < 0.01, "XA {} vs {xa}", r.xa);
        assert!((r.ya / ya - 1.0).abs() < 0.01, "YA {} vs {ya}", r.ya);
        assert!((r.yc / yc - 1.0).abs() < 0.01, "YC {} vs {yc}", r.yc);
        assert!(r.xc < 1e-4, "XC {}", r.xc);
        // Y^H/Y^C -> (e²)/(2-e²) -> 1 for a needle
        assert!((r.yh / r.yc - e * e / (2.0 - e * e)).abs() < 1e-12);
    }

    /// Y^C as printed in the paper would be negative: ours is positive for all e.
    #[test]
    fn yc_is_positive() {
        for i in 1..100 {
            let e = i as f64 / 100.0;
            assert!(ResistanceFunctions::of_eccentricity(e).yc > 0.0);
        }
    }

    /// Pure strain (stretching along ê1): both the viscous and the inertial strain torque
    /// turn a segment at 30° towards the stretching axis (negative ê3 torque).
    #[test]
    fn strain_torque_turns_towards_stretching() {
        let shape = SegmentShape::new(3.0, 0.232);
        let th = 30f64.to_radians();
        let z = Vector3::new(th.cos(), th.sin(), 0.0);
        let g = Matrix3::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0);
        let viscous = DragModel {
            viscosity: 1.0,
            fluid_density: 1.0,
            drag_coefficient: 0.0,
        };
        let r = resistance(&shape, &viscous, &z, &g, 0.0);
        assert!(r.h_g.z < 0.0, "viscous strain torque {}", r.h_g.z);
        let inertial = DragModel {
            viscosity: 0.0,
            fluid_density: 1.0,
            drag_coefficient: 1.0,
        };
        let r = resistance(&shape, &inertial, &z, &g, 2.0);
        assert!(r.h_g.z < 0.0, "inertial strain torque {}", r.h_g.z);
        // and its size is the integral of the cross-flow drag: C_D ρ d l³ v⊥/24 |ẑ×Gẑ|
        let want = 0.232 * 27.0 * 2.0 / 24.0 * z.cross(&(g * z)).z;
        assert!((r.h_g.z - want).abs() < 1e-12);
    }

    /// The closed forms the step uses agree with the matrices: apply = matrix · v and
    /// inverse = matrix inverse (1e-12 relative), for axes in every direction.
    #[test]
    fn axisymmetric_forms_match_the_matrices() {
        let op = Axisymmetric {
            perp: 3.7,
            par: 0.02,
        };
        let inv = op.inverse().unwrap();
        for k in 0..50 {
            let t = k as f64 * 0.37;
            let z = Vector3::new(
                t.sin() * (2.0 * t).cos(),
                t.cos(),
                t.sin() * (2.0 * t).sin(),
            )
            .normalize();
            let v = Vector3::new(1.0, -2.0 + t, 0.5 * t);
            let m = op.matrix(&z);
            assert!((op.apply(&z, &v) - m * v).norm() <= 1e-12 * (m * v).norm());
            let mi = m.try_inverse().unwrap();
            assert!((inv.matrix(&z) - mi).norm() <= 1e-12 * mi.norm());
        }
        assert!(Axisymmetric {
            perp: 0.0,
            par: 1.0
        }
        .inverse()
        .is_none());
    }
}
