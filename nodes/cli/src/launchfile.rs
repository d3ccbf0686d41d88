//! Launch files (TOML): one run — its flow node, fibre groups and recorder — checked up
//! front with errors that name the key.

use anyhow::{bail, Context, Result};
use fiberflow_fiber::FiberNodeConfig;
use fiberflow_flow::{FlowNodeConfig, FlowSource};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// `[run]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunSection {
    pub id: String,
    /// Number of coupling steps.
    pub steps: u64,
    /// Coupling (fibre and flow) time step, viscous units.
    pub dt_plus: f64,
    /// Channel box in wall units; default 2πh × 2h × πh at the DNS Re_tau (or 150).
    #[serde(default)]
    pub box_plus: Option<[f64; 3]>,
    /// Seconds any node waits for a peer's message of one step.
    #[serde(default = "default_step_timeout")]
    pub step_timeout_s: f64,
    /// Default transport when `--transport` is not given.
    #[serde(default = "default_transport")]
    pub transport: String,
    /// Run the analysis after the run (and write the .rrd scene).
    #[serde(default)]
    pub analyze: bool,
}

fn default_step_timeout() -> f64 {
    120.0
}
fn default_transport() -> String {
    "zenoh".into()
}

/// `[recorder]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecorderSection {
    #[serde(default = "default_true")]
    pub enabled: bool,
}

fn default_true() -> bool {
    true
}

impl Default for RecorderSection {
    fn default() -> Self {
        Self { enabled: true }
    }
}

/// The whole launch file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LaunchFile {
    pub run: RunSection,
    pub flow: FlowNodeConfig,
    #[serde(default)]
    pub fibers: Vec<FiberNodeConfig>,
    #[serde(default)]
    pub recorder: RecorderSection,
}

impl LaunchFile {
    /// Reads, resolves relative paths against the file's folder, and validates.
    pub fn load(path: &Path) -> Result<(Self, String)> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("reading launch file {}", path.display()))?;
        let mut lf: LaunchFile = toml::from_str(&text)
            .with_context(|| format!("parsing launch file {}", path.display()))?;
        let base = path
            .parent()
            .map(Path::to_path_buf)
            .unwrap_or_else(|| PathBuf::from("."));
        let fix = |p: &mut PathBuf| {
            if p.is_relative() {
                *p = base.join(&*p);
            }
        };
        if let FlowSource::Dns {
            restart: Some(r), ..
        } = &mut lf.flow.source
        {
            fix(r);
        }
        if let Some(sp) = lf.flow.spinup.as_mut() {
            if let Some(r) = sp.restart.as_mut() {
                fix(r);
            }
        }
        lf.flow.dt_plus = lf.run.dt_plus;
        lf.flow.steps = lf.run.steps;
        lf.validate()?;
        Ok((lf, text))
    }

    pub fn validate(&self) -> Result<()> {
        let r = &self.run;
        if r.id.is_empty()
            || !r
                .id
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
        {
            bail!(
                "run.id must be a non-empty name of [A-Za-z0-9_-] (got {:?})",
                r.id
            );
        }
        if r.steps == 0 || r.steps > 100_000_000 {
            bail!("run.steps must be in 1..=1e8 (got {})", r.steps);
        }
        if !(r.step_timeout_s > 0.0 && r.step_timeout_s <= 3600.0) {
            bail!(
                "run.step_timeout_s must be in (0, 3600] (got {})",
                r.step_timeout_s
            );
        }
        self.flow.validate()?;
        let mut names = std::collections::BTreeSet::new();
        for f in &self.fibers {
            f.build(self.box_plus())
                .map_err(|e| anyhow::anyhow!("{e}"))?;
            if !names.insert(f.group.clone()) {
                bail!("fibers: group name {:?} is used twice", f.group);
            }
            if ["flow", "recorder", "launcher"].contains(&f.group.as_str()) {
                bail!(
                    "fibers[{}].group: the names flow, recorder and launcher are reserved",
                    f.group
                );
            }
        }
        Ok(())
    }

    /// The channel box in wall units.
    pub fn box_plus(&self) -> [f64; 3] {
        if let Some(b) = self.run.box_plus {
            return b;
        }
        let (re, lx, lz) = match &self.flow.source {
            FlowSource::Dns { dns, .. } => (dns.re_tau, dns.lx, dns.lz),
            FlowSource::Analytic { .. } => {
                (150.0, 2.0 * std::f64::consts::PI, std::f64::consts::PI)
            }
        };
        [lx * re, 2.0 * re, lz * re]
    }

    pub fn groups(&self) -> Vec<String> {
        self.fibers.iter().map(|f| f.group.clone()).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write_launch(dir: &Path, flow_extra: &str) -> PathBuf {
        let text = format!(
            "[run]\nid = \"t\"\nsteps = 10\ndt_plus = 0.25\n\n[flow]\n{flow_extra}\n\n\
             [flow.source]\nkind = \"analytic\"\nflow = {{ kind = \"simple_shear\", shear_rate = 0.1 }}\n"
        );
        let p = dir.join("t.toml");
        std::fs::write(&p, text).unwrap();
        p
    }

    #[test]
    fn interpolation_key_parses_and_bad_values_are_named() {
        let dir = std::env::temp_dir().join(format!("ff-lf-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let (lf, _) =
            LaunchFile::load(&write_launch(&dir, "interpolation = \"tricubic\"")).unwrap();
        assert_eq!(
            lf.flow.interpolation,
            fiberflow_dns::sample::Interpolation::Tricubic
        );
        let (lf, _) = LaunchFile::load(&write_launch(&dir, "")).unwrap();
        assert_eq!(
            lf.flow.interpolation,
            fiberflow_dns::sample::Interpolation::Trilinear
        );
        let err = LaunchFile::load(&write_launch(&dir, "interpolation = \"quintic\"")).unwrap_err();
        let msg = format!("{err:#}");
        assert!(
            msg.contains("interpolation") && msg.contains("tricubic"),
            "{msg}"
        );
        std::fs::remove_dir_all(&dir).ok();
    }
}
