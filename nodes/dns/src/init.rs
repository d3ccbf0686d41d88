//! Initial fields: rest, laminar Poiseuille, or a turbulent mean profile with structured
//! perturbations (streamwise vortices + streaks + noise) that trigger transition.

use crate::config::InitialField;
use crate::field::Velocity;
use crate::grid::Grid;

/// Deterministic SplitMix64 generator: same seed, same field, on every machine.
#[derive(Debug, Clone)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [-1, 1).
    pub fn symmetric(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    }
}

/// Reichardt's composite mean profile U+(y+), a good turbulent starting profile.
pub fn reichardt(y_plus: f64) -> f64 {
    let kappa = 0.41;
    (1.0 + kappa * y_plus).ln() / kappa
        + 7.8 * (1.0 - (-y_plus / 11.0).exp() - y_plus / 11.0 * (-y_plus / 3.0).exp())
}

/// Fills `vel` (interior points; halos are refreshed by the caller).
pub fn fill(g: &Grid, re_tau: f64, init: &InitialField, vel: &mut Velocity) {
    *vel = Velocity::zeros(g);
    match *init {
        InitialField::Rest => {}
        InitialField::Laminar { centre_velocity } => {
            for k in 1..=g.nz {
                for j in 1..=g.ny {
                    let y = g.yc[j];
                    for i in 1..=g.nx {
                        vel.u[g.idx(i, j, k)] = centre_velocity * (1.0 - y * y);
                    }
                }
            }
        }
        InitialField::Turbulent { amplitude, seed } => {
            turbulent(g, re_tau, amplitude, seed, vel);
        }
    }
}

fn turbulent(g: &Grid, re_tau: f64, amp: f64, seed: u64, vel: &mut Velocity) {
    use std::f64::consts::PI;
    let mut rng = SplitMix64::new(seed);
    // spanwise wavelength near 100 wall units, streamwise about two per box
    let n_span = ((g.lz * re_tau / 100.0).round()).max(1.0);
    let beta = 2.0 * PI * n_span / g.lz;
    let alpha = 2.0 * PI * 2.0 / g.lx;
    let phase_x = PI * rng.symmetric();
    let ub = 15.0;
    for k in 1..=g.nz {
        let zc = (k as f64 - 0.5) * g.dz;
        let zf = k as f64 * g.dz;
        for j in 1..=g.ny {
            let y = g.yc[j];
            let yw = 1.0 - y.abs();
            let mean = reichardt(yw * re_tau);
            let yfv = g.yf[j];
            for i in 1..=g.nx {
                let xc = (i as f64 - 0.5) * g.dx;
                let xf = i as f64 * g.dx;
                let n = g.idx(i, j, k);
                let modx = 1.0 + 0.5 * (alpha * xf + phase_x).sin();
                // streaks: low/high-speed bands that vanish at the walls and centreline
                let streak = amp * ub * (1.0 - y * y) * y.abs() * 2.0 * (beta * zc).cos() * modx;
                vel.u[n] = mean + streak + 0.3 * amp * ub * rng.symmetric() * (1.0 - y * y);
                // streamwise vortices from ψ = A (1-y²)² sin(βz) (1 + 0.5 sin αx):
                // v = ∂ψ/∂z, w = -∂ψ/∂y
                let modc = 1.0 + 0.5 * (alpha * xc + phase_x).sin();
                let a = amp * ub / beta * 2.0;
                let s = 1.0 - yfv * yfv;
                vel.v[n] = if j < g.ny {
                    a * s * s * beta * (beta * zc).cos() * modc
                        + 0.3 * amp * ub * rng.symmetric() * s
                } else {
                    0.0
                };
                let sc = 1.0 - y * y;
                vel.w[n] = a * 4.0 * y * sc * (beta * zf).sin() * modc
                    + 0.3 * amp * ub * rng.symmetric() * sc;
            }
        }
    }
}
