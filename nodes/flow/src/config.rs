//! Flow-node configuration: which flow it serves and how it runs.

use crate::analytic::AnalyticFlow;
use crate::error::FlowError;
use crate::spinup::SpinupConfig;
use fiberflow_dns::sample::Interpolation;
use fiberflow_dns::DnsConfig;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// Where the velocity samples come from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum FlowSource {
    /// An analytic flow (wall units), for tests and model validation.
    Analytic {
        /// Which analytic flow.
        flow: AnalyticFlow,
    },
    /// The channel DNS, optionally from a checkpoint.
    Dns {
        /// The grid, box and driving of the DNS.
        dns: DnsConfig,
        /// Start from this flow checkpoint (`flow.ckpt` of a spin-up or a run; relative
        /// to the launch file) instead of `dns.init`.
        #[serde(default)]
        restart: Option<PathBuf>,
        /// The restart field is on another grid of the same box: interpolate it
        /// (tricubic) onto this one and project, at start (as `spinup.regrid` does).
        #[serde(default)]
        regrid: bool,
    },
}

/// The whole flow-node configuration (the `[flow]` table of a launch file).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct FlowNodeConfig {
    pub source: FlowSource,
    /// Run a standalone spin-up instead of serving fibre groups.
    #[serde(default)]
    pub spinup: Option<SpinupConfig>,
    /// Serve this many coupling steps (fibre time step `dt_plus` each). A launch file
    /// sets it from `run.steps` (giving it under `[flow]` is an error).
    #[serde(default)]
    pub steps: u64,
    /// Coupling time step in viscous units (the fibre groups use the same), in (0, 10].
    /// A launch file sets it from `run.dt_plus` (giving it under `[flow]` is an error).
    #[serde(default = "default_dt")]
    pub dt_plus: f64,
    /// DNS steps per coupling step, each of `dt_plus / field_steps`, in 1..=16 (DNS
    /// only): the fibres and the flow node's per-fibre stages (sampling, spreading, the
    /// self-induced correction) run once per coupling step, so a coupling step longer than
    /// the DNS's Courant limit costs the field's steps, not the fibres' (docs/two-way.md,
    /// "Field steps per coupling step").
    #[serde(default = "default_field_steps")]
    pub field_steps: u32,
    /// Seconds to wait for every expected fibre group to announce itself, in (0, 3600].
    #[serde(default = "default_join_timeout")]
    pub join_timeout_s: f64,
    /// Publish a status message every this many coupling steps, ≥ 1.
    #[serde(default = "default_status_every")]
    pub status_every_steps: u64,
    /// Publish running flow statistics (FlowProfiles) every this many coupling steps
    /// (a statistics sample is taken every `status_every_steps` steps).
    #[serde(default = "default_profiles_every")]
    pub profiles_every_steps: u64,
    /// How DNS velocity and gradient are interpolated to fibre positions:
    /// `"trilinear"` (default) or `"tricubic"`.
    #[serde(default)]
    pub interpolation: Interpolation,
    /// Publish the flow slices for viewers (u' at `streaks_y_plus` and a cross-section)
    /// every this many coupling steps, 0 = never (DNS only).
    #[serde(default = "default_slices_every")]
    pub slices_every_steps: u64,
    /// Height of the wall-parallel slice above the lower wall, wall units (the nearest
    /// row of cell centres is taken).
    #[serde(default = "default_streaks_y_plus")]
    pub streaks_y_plus: f64,
    /// Two-way coupling: remove each fibre's own disturbance from its samples
    /// (`"history"`, the default: unsteady Stokes memories, `crate::self_induced`) or
    /// leave it (`"none"`).
    #[serde(default)]
    pub self_induced: SelfInduced,
    /// The run's realisation (docs/realisations.md): 0 starts from the source's field as
    /// it is; i ≥ 1 adds realisation i's seeded divergence-free disturbance to a DNS
    /// field at the start (`fiberflow_dns::perturb`; a resumed run reads its checkpoint).
    /// A launch file sets it from `run.realisation` (giving it under `[flow]` is an error).
    #[serde(default)]
    pub realisation: u32,
}

/// The seed realisation i's flow disturbance is drawn from (`realisation_seed(this, i)`).
pub const FLOW_DISTURBANCE_SEED: u64 = 0x5EED_F10E;

/// `flow.self_induced`: how the samples of a two-way run treat each fibre's own
/// disturbance of the flow.
#[derive(
    Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "kebab-case")]
pub enum SelfInduced {
    #[default]
    History,
    None,
}

fn default_dt() -> f64 {
    0.01
}
fn default_field_steps() -> u32 {
    1
}
fn default_join_timeout() -> f64 {
    30.0
}
fn default_profiles_every() -> u64 {
    100
}
fn default_status_every() -> u64 {
    10
}
fn default_slices_every() -> u64 {
    10
}
fn default_streaks_y_plus() -> f64 {
    15.0
}

impl FlowNodeConfig {
    pub fn validate(&self) -> Result<(), FlowError> {
        if let FlowSource::Dns {
            dns,
            restart,
            regrid,
        } = &self.source
        {
            dns.validate()?;
            if !(self.streaks_y_plus > 0.0 && self.streaks_y_plus <= dns.re_tau) {
                return Err(FlowError::Config(format!(
                    "flow.streaks_y_plus must be in (0, {}] (wall units above the lower wall, up to the centreline; got {})",
                    dns.re_tau, self.streaks_y_plus
                )));
            }
            if *regrid && restart.is_none() {
                return Err(FlowError::Config(
                    "flow.source.regrid = true needs flow.source.restart (the field to move onto this grid)".into(),
                ));
            }
        }
        if let Some(s) = &self.spinup {
            s.validate()?;
        }
        if !(self.dt_plus > 0.0 && self.dt_plus.is_finite() && self.dt_plus <= 10.0) {
            return Err(FlowError::Config(format!(
                "flow.dt_plus must be in (0, 10] (got {})",
                self.dt_plus
            )));
        }
        if !(1..=16).contains(&self.field_steps) {
            return Err(FlowError::Config(format!(
                "flow.field_steps must be in 1..=16 (got {})",
                self.field_steps
            )));
        }
        if self.field_steps > 1 && !matches!(self.source, FlowSource::Dns { .. }) {
            return Err(FlowError::Config(format!(
                "flow.field_steps = {} needs flow.source.kind = \"dns\" (an analytic flow has no field steps): leave it at 1",
                self.field_steps
            )));
        }
        if !(self.join_timeout_s > 0.0 && self.join_timeout_s <= 3600.0) {
            return Err(FlowError::Config(format!(
                "flow.join_timeout_s must be in (0, 3600] (got {})",
                self.join_timeout_s
            )));
        }
        if self.profiles_every_steps == 0 {
            return Err(FlowError::Config(
                "flow.profiles_every_steps must be >= 1 (got 0)".into(),
            ));
        }
        if self.status_every_steps == 0 {
            return Err(FlowError::Config(
                "flow.status_every_steps must be >= 1 (got 0)".into(),
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A valid DNS flow configuration on a 16³ grid.
    pub(crate) fn dns_config() -> FlowNodeConfig {
        FlowNodeConfig {
            source: FlowSource::Dns {
                dns: DnsConfig::with_cells(16, 16, 16),
                restart: None,
                regrid: false,
            },
            spinup: None,
            steps: 10,
            dt_plus: 0.2,
            field_steps: 1,
            join_timeout_s: 30.0,
            status_every_steps: 10,
            profiles_every_steps: 100,
            interpolation: Interpolation::Trilinear,
            slices_every_steps: 10,
            streaks_y_plus: 15.0,
            self_induced: SelfInduced::History,
            realisation: 0,
        }
    }

    #[test]
    fn regrid_needs_a_restart_field() {
        let src = |regrid, restart: Option<&str>| {
            let mut c = dns_config();
            c.source = FlowSource::Dns {
                dns: DnsConfig::with_cells(16, 16, 16),
                restart: restart.map(PathBuf::from),
                regrid,
            };
            c
        };
        assert!(src(true, Some("a.ckpt")).validate().is_ok());
        assert!(src(false, None).validate().is_ok());
        let e = src(true, None).validate().unwrap_err().to_string();
        assert!(
            e.contains("flow.source.regrid") && e.contains("flow.source.restart"),
            "{e}"
        );
    }

    /// `flow.field_steps` outside 1..=16, or above 1 on an analytic flow, is refused
    /// naming the key and its range.
    #[test]
    fn field_steps_must_be_in_range_and_need_the_dns() {
        let cfg = |m: u32| FlowNodeConfig {
            field_steps: m,
            ..dns_config()
        };
        assert!(cfg(1).validate().is_ok() && cfg(16).validate().is_ok());
        for bad in [0, 17] {
            let e = cfg(bad).validate().unwrap_err().to_string();
            assert!(
                e.contains("flow.field_steps") && e.contains("1..=16"),
                "{e}"
            );
        }
        let mut a = cfg(2);
        a.source = FlowSource::Analytic {
            flow: crate::analytic::AnalyticFlow::SimpleShear { shear_rate: 1.0 },
        };
        let e = a.validate().unwrap_err().to_string();
        assert!(e.contains("flow.field_steps") && e.contains("dns"), "{e}");
    }

    #[test]
    fn streaks_height_must_lie_in_the_lower_half() {
        let cfg = |y: f64| FlowNodeConfig {
            streaks_y_plus: y,
            ..dns_config()
        };
        assert!(cfg(15.0).validate().is_ok());
        for bad in [0.0, -3.0, 1e4, f64::NAN] {
            let e = cfg(bad).validate().unwrap_err().to_string();
            assert!(
                e.contains("flow.streaks_y_plus") && e.contains("(0, "),
                "{e}"
            );
        }
    }
}
