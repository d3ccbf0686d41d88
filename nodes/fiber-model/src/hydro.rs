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

/// Evaluates eq. 25–27 and 29–31 for axis `z`, strain rate `g` and cross-flow speed `v_perp`.
pub fn resistance(
    shape: &SegmentShape,
    drag: &DragModel,
    z: &Vector3<f64>,
    g: &Matrix3<f64>,
    v_perp: f64,
) -> Resistance {
    let l = shape.length;
    let k = &shape.coeffs;
    let zz = z * z.transpose();
    let id = Matrix3::identity();
    let mu = drag.viscosity;
    let l3 = l * l * l;
    // eq. 25, 26
    let av = 3.0 * std::f64::consts::PI * mu * l * (k.ya * id + (k.xa - k.ya) * zz);
    let cv = std::f64::consts::PI * mu * l3 * (k.yc * id + (k.xc - k.yc) * zz);
    // eq. 27: H^v:G = -πηl³Y^H (Gẑ)×ẑ = πηl³Y^H ẑ×(Gẑ)
    let gz = g * z;
    let zxgz = z.cross(&gz);
    let hv_g = std::f64::consts::PI * mu * l3 * k.yh * zxgz;
    // eq. 29–31, linearised with v_perp; strain torque in the same sense as the viscous one
    let cd_rho_d = drag.drag_coefficient * drag.fluid_density * shape.diameter * v_perp;
    let perp = id - zz;
    let ai = 0.5 * cd_rho_d * l * perp;
    let ci = cd_rho_d * l3 / 24.0 * perp;
    let hi_g = cd_rho_d * l3 / 24.0 * zxgz;
    Resistance {
        a: av + ai,
        c: cv + ci,
        h_g: hv_g + hi_g,
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
}
