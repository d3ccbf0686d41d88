//! Analytic flows served by the flow node in place of the DNS: the test flows of the fibre
//! model (uniform, simple shear, Poiseuille, solid-body rotation, pure strain). Wall units.

use serde::{Deserialize, Serialize};

/// A steady analytic velocity field v(r) with its gradient.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum AnalyticFlow {
    /// v = U.
    Uniform {
        /// U, wall units.
        velocity: [f64; 3],
    },
    /// v = S x2 ê1 (shear rate S).
    SimpleShear {
        /// S, wall units (u_tau²/ν).
        shear_rate: f64,
    },
    /// v = Uc (1 - (x2/h)²) ê1 between walls at x2 = ±h.
    Poiseuille {
        /// Uc, wall units.
        centre_velocity: f64,
        /// h, wall units.
        half_height: f64,
    },
    /// v = Ω × (r - c).
    SolidBodyRotation {
        /// Ω, wall units.
        angular_velocity: [f64; 3],
        /// c, wall units.
        #[serde(default)]
        centre: [f64; 3],
    },
    /// v = E (x1, -x2, 0): stretching along ê1, compression along ê2.
    PureStrain {
        /// E, wall units.
        rate: f64,
    },
}

impl AnalyticFlow {
    /// Velocity and gradient `grad[3a+b] = ∂v_a/∂x_b` at `r`.
    pub fn sample(&self, r: [f64; 3]) -> ([f64; 3], [f64; 9]) {
        match *self {
            AnalyticFlow::Uniform { velocity } => (velocity, [0.0; 9]),
            AnalyticFlow::SimpleShear { shear_rate } => {
                let mut g = [0.0; 9];
                g[1] = shear_rate;
                ([shear_rate * r[1], 0.0, 0.0], g)
            }
            AnalyticFlow::Poiseuille {
                centre_velocity,
                half_height,
            } => {
                let y = r[1] / half_height;
                let mut g = [0.0; 9];
                g[1] = -2.0 * centre_velocity * y / half_height;
                ([centre_velocity * (1.0 - y * y), 0.0, 0.0], g)
            }
            AnalyticFlow::SolidBodyRotation {
                angular_velocity: w,
                centre: c,
            } => {
                let d = [r[0] - c[0], r[1] - c[1], r[2] - c[2]];
                let v = [
                    w[1] * d[2] - w[2] * d[1],
                    w[2] * d[0] - w[0] * d[2],
                    w[0] * d[1] - w[1] * d[0],
                ];
                // ∂v_a/∂x_b = ε_{a c b} ω_c
                let g = [0.0, -w[2], w[1], w[2], 0.0, -w[0], -w[1], w[0], 0.0];
                (v, g)
            }
            AnalyticFlow::PureStrain { rate } => {
                let mut g = [0.0; 9];
                g[0] = rate;
                g[4] = -rate;
                ([rate * r[0], -rate * r[1], 0.0], g)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each analytic gradient equals the central difference of its velocity (tol 1e-9).
    #[test]
    fn gradients_match_finite_differences() {
        let flows = [
            AnalyticFlow::Uniform {
                velocity: [1.0, 2.0, 3.0],
            },
            AnalyticFlow::SimpleShear { shear_rate: 0.7 },
            AnalyticFlow::Poiseuille {
                centre_velocity: 3.0,
                half_height: 2.0,
            },
            AnalyticFlow::SolidBodyRotation {
                angular_velocity: [0.3, -0.2, 0.5],
                centre: [1.0, 0.0, -1.0],
            },
            AnalyticFlow::PureStrain { rate: 0.4 },
        ];
        let r = [0.3, -0.4, 0.8];
        let h = 1e-5;
        for f in flows {
            let (_, g) = f.sample(r);
            for b in 0..3 {
                let mut rp = r;
                let mut rm = r;
                rp[b] += h;
                rm[b] -= h;
                let (vp, _) = f.sample(rp);
                let (vm, _) = f.sample(rm);
                for a in 0..3 {
                    let fd = (vp[a] - vm[a]) / (2.0 * h);
                    assert!(
                        (fd - g[3 * a + b]).abs() < 1e-9,
                        "{f:?} d{a}/d{b}: {fd} vs {}",
                        g[3 * a + b]
                    );
                }
            }
        }
        // solid-body rotation has zero strain and vorticity 2Ω
        let w = [0.3, -0.2, 0.5];
        let (_, g) = AnalyticFlow::SolidBodyRotation {
            angular_velocity: w,
            centre: [0.0; 3],
        }
        .sample(r);
        for a in 0..3 {
            for b in 0..3 {
                assert!((g[3 * a + b] + g[3 * b + a]).abs() < 1e-15);
            }
        }
        assert!(((g[7] - g[5]) - 2.0 * w[0]).abs() < 1e-15);
    }
}
