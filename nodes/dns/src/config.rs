//! Flow-solver configuration (TOML), validated up front with errors that name the key.

use crate::error::DnsError;
use serde::{Deserialize, Serialize};

/// How the mean flow is driven (paper eq. 13, term E ê1).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case", tag = "kind")]
pub enum Forcing {
    /// Constant mean pressure gradient E = u_tau²/h: Re_tau is fixed by construction.
    PressureGradient,
    /// Constant flow rate: the bulk velocity (in units of u_tau) is held at this value.
    FlowRate {
        /// Bulk velocity U_b / u_tau, ≥ 0 (0 holds the fluid at no net flow).
        bulk_velocity: f64,
    },
}

/// Initial condition of a fresh run.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case", tag = "kind")]
pub enum InitialField {
    /// Fluid at rest.
    Rest,
    /// Laminar Poiseuille profile with the given centreline velocity (units of u_tau).
    Laminar {
        /// Centreline velocity / u_tau.
        centre_velocity: f64,
    },
    /// Reichardt turbulent mean profile plus streamwise vortices, streaks and noise,
    /// strong enough to trigger transition at Re_tau = 150.
    Turbulent {
        /// Strength of the perturbations relative to the default, in 0..=2.
        amplitude: f64,
        /// Seed of the noise (same seed, same field).
        seed: u64,
    },
}

/// Everything the DNS needs to run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct DnsConfig {
    /// Cells along x (streamwise, periodic): an even integer in 4..=4096.
    pub nx: usize,
    /// Cells along y (wall-normal, stretched towards the walls): 4..=4096.
    pub ny: usize,
    /// Cells along z (spanwise, periodic): an even integer in 4..=4096.
    pub nz: usize,
    /// Box length in x, units of h (default 2π).
    #[serde(default = "default_lx")]
    pub lx: f64,
    /// Box length in z, units of h (default π).
    #[serde(default = "default_lz")]
    pub lz: f64,
    /// Friction Reynolds number u_tau h / ν, in 1..=1e5.
    #[serde(default = "default_re_tau")]
    pub re_tau: f64,
    /// Wall distance of the first cell centre in wall units (None: uniform grid).
    #[serde(default = "default_y1_plus")]
    pub y1_plus: Option<f64>,
    /// Target Courant sum per step, in (0, 1.73] (RK3 stability).
    #[serde(default = "default_cfl")]
    pub cfl: f64,
    /// Upper bound on the time step, in viscous units.
    #[serde(default = "default_dt_max_plus")]
    pub dt_max_plus: f64,
    /// Fixed time step in viscous units (overrides the adaptive one).
    #[serde(default)]
    pub dt_fixed_plus: Option<f64>,
    /// Crank–Nicolson for wall-normal diffusion.
    #[serde(default = "default_true")]
    pub implicit_y: bool,
    /// How the mean flow is driven (default: constant pressure gradient).
    #[serde(default = "default_forcing")]
    pub forcing: Forcing,
    /// Check max |div u| every this many steps (a full pass over the field).
    #[serde(default = "default_check_every")]
    pub check_every_steps: u64,
    /// The field a run without a restart starts from (default: turbulent).
    #[serde(default = "default_init")]
    pub init: InitialField,
}

fn default_lx() -> f64 {
    2.0 * std::f64::consts::PI
}
fn default_lz() -> f64 {
    std::f64::consts::PI
}
fn default_re_tau() -> f64 {
    150.0
}
fn default_y1_plus() -> Option<f64> {
    Some(0.33)
}
fn default_cfl() -> f64 {
    1.2
}
fn default_dt_max_plus() -> f64 {
    1.0
}
fn default_true() -> bool {
    true
}
fn default_check_every() -> u64 {
    10
}
fn default_forcing() -> Forcing {
    Forcing::PressureGradient
}
fn default_init() -> InitialField {
    InitialField::Turbulent {
        amplitude: 0.25,
        seed: 1,
    }
}

impl DnsConfig {
    /// The paper's coarse grid: 64×64×64 on 2πh × 2h × πh.
    pub fn coarse() -> Self {
        Self::with_cells(64, 64, 64)
    }

    /// The paper's fine grid: 192×64×64.
    pub fn fine() -> Self {
        Self::with_cells(192, 64, 64)
    }

    pub fn with_cells(nx: usize, ny: usize, nz: usize) -> Self {
        Self {
            nx,
            ny,
            nz,
            lx: default_lx(),
            lz: default_lz(),
            re_tau: default_re_tau(),
            y1_plus: default_y1_plus(),
            cfl: default_cfl(),
            dt_max_plus: default_dt_max_plus(),
            dt_fixed_plus: None,
            implicit_y: true,
            forcing: default_forcing(),
            check_every_steps: default_check_every(),
            init: default_init(),
        }
    }

    /// Checks every value; the error names the key and the allowed range.
    pub fn validate(&self) -> Result<(), DnsError> {
        let bad = |key: &str, range: &str, v: String| {
            Err(DnsError::Config(format!(
                "flow.{key} must be {range} (got {v})"
            )))
        };
        for (key, n) in [("nx", self.nx), ("nz", self.nz)] {
            if n < 4 || n % 2 != 0 || n > 4096 {
                return bad(key, "an even integer in 4..=4096", n.to_string());
            }
        }
        if self.ny < 4 || self.ny > 4096 {
            return bad("ny", "an integer in 4..=4096", self.ny.to_string());
        }
        if !(self.lx > 0.0 && self.lx.is_finite()) {
            return bad("lx", "positive and finite", self.lx.to_string());
        }
        if !(self.lz > 0.0 && self.lz.is_finite()) {
            return bad("lz", "positive and finite", self.lz.to_string());
        }
        if !(self.re_tau >= 1.0 && self.re_tau <= 1e5) {
            return bad("re_tau", "in 1..=1e5", self.re_tau.to_string());
        }
        if let Some(y1) = self.y1_plus {
            if !(y1 > 0.0 && y1.is_finite()) {
                return bad("y1_plus", "positive", y1.to_string());
            }
        }
        if !(self.cfl > 0.0 && self.cfl <= crate::timestep::RK3_CFL_LIMIT) {
            return bad("cfl", "in (0, 1.73] (RK3 stability)", self.cfl.to_string());
        }
        if !(self.dt_max_plus > 0.0 && self.dt_max_plus.is_finite()) {
            return bad("dt_max_plus", "positive", self.dt_max_plus.to_string());
        }
        if let Some(dt) = self.dt_fixed_plus {
            if !(dt > 0.0 && dt.is_finite()) {
                return bad("dt_fixed_plus", "positive", dt.to_string());
            }
        }
        if self.check_every_steps == 0 {
            return bad("check_every_steps", ">= 1", "0".into());
        }
        if let Forcing::FlowRate { bulk_velocity } = self.forcing {
            // 0 holds the fluid at no net flow (e.g. a settling test in still fluid)
            if !(bulk_velocity >= 0.0 && bulk_velocity.is_finite()) {
                return bad(
                    "forcing.bulk_velocity",
                    ">= 0 and finite",
                    bulk_velocity.to_string(),
                );
            }
        }
        if let InitialField::Turbulent { amplitude, .. } = self.init {
            if !(0.0..=2.0).contains(&amplitude) {
                return bad("init.amplitude", "in 0..=2", amplitude.to_string());
            }
        }
        Ok(())
    }

    /// Kinematic viscosity in outer units (h = u_tau = 1).
    pub fn nu(&self) -> f64 {
        1.0 / self.re_tau
    }
}
