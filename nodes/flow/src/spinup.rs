//! DNS spin-up: integrate from an initial field (or a checkpoint) to developed turbulence,
//! accumulate statistics over a trailing window, write checkpoints, statistics CSV and a
//! step history. Progress goes to a caller-supplied callback (the CLI draws a bar).

use crate::error::{io_err, FlowError};
use fiberflow_dns::stats::{wall_re_tau, Profiles, RunningStats};
use fiberflow_dns::{DnsConfig, Solver, StepReport};
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::{Path, PathBuf};

/// What a spin-up run does.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct SpinupConfig {
    /// Integrate this many viscous time units (from the start or the restart time).
    pub duration_plus: f64,
    /// Accumulate statistics over the last this-many viscous units (0 = none).
    #[serde(default)]
    pub stats_window_plus: f64,
    /// Take a statistics sample every this-many steps.
    #[serde(default = "default_stats_every")]
    pub stats_every_steps: u64,
    /// Write a checkpoint every this-many viscous units (and always at the end).
    #[serde(default = "default_ck_every")]
    pub checkpoint_every_plus: f64,
    /// Start from this checkpoint instead of the initial field.
    #[serde(default)]
    pub restart: Option<PathBuf>,
    /// The restart checkpoint may be on another grid (same box): interpolate it
    /// (tricubic) onto this one and project. Off by default, so a grid mismatch is an error.
    #[serde(default)]
    pub regrid: bool,
}

fn default_stats_every() -> u64 {
    5
}
fn default_ck_every() -> f64 {
    100.0
}

impl SpinupConfig {
    pub fn validate(&self) -> Result<(), FlowError> {
        if !(self.duration_plus > 0.0 && self.duration_plus.is_finite()) {
            return Err(FlowError::Config(format!(
                "spinup.duration_plus must be positive (got {})",
                self.duration_plus
            )));
        }
        if !(self.stats_window_plus >= 0.0 && self.stats_window_plus <= self.duration_plus) {
            return Err(FlowError::Config(format!(
                "spinup.stats_window_plus must be in 0..=duration_plus (got {})",
                self.stats_window_plus
            )));
        }
        if self.stats_every_steps == 0 {
            return Err(FlowError::Config(
                "spinup.stats_every_steps must be >= 1 (got 0)".into(),
            ));
        }
        if !(self.checkpoint_every_plus > 0.0) {
            return Err(FlowError::Config(format!(
                "spinup.checkpoint_every_plus must be positive (got {})",
                self.checkpoint_every_plus
            )));
        }
        Ok(())
    }
}

/// Where a spin-up writes and what it found.
#[derive(Debug, Clone)]
pub struct SpinupSummary {
    pub checkpoint: PathBuf,
    pub profiles: Option<Profiles>,
    pub steps: u64,
    pub t_plus: f64,
    pub wall_seconds: f64,
}

/// Progress callback: every step's report plus the instantaneous wall Re_tau (every 20 steps).
pub type Progress<'a> = dyn FnMut(&StepReport, Option<f64>) + 'a;

/// Runs the spin-up, writing `flow.ckpt`, `history.csv` and `stats.csv` into `out_dir`.
pub fn run(
    dns: &DnsConfig,
    sp: &SpinupConfig,
    out_dir: &Path,
    progress: &mut Progress<'_>,
) -> Result<SpinupSummary, FlowError> {
    sp.validate()?;
    std::fs::create_dir_all(out_dir).map_err(io_err(out_dir))?;
    let mut solver = Solver::new(dns.clone())?;
    if let Some(r) = &sp.restart {
        if sp.regrid {
            solver.read_checkpoint_regridded(r)?;
        } else {
            solver.read_checkpoint(r)?;
        }
        tracing::info!(path = %r.display(), t_plus = solver.t_plus(), "restarted from checkpoint");
    }
    let ck_path = out_dir.join("flow.ckpt");
    let hist_path = out_dir.join("history.csv");
    let mut hist =
        std::io::BufWriter::new(std::fs::File::create(&hist_path).map_err(io_err(&hist_path))?);
    writeln!(
        hist,
        "step,t_plus,dt_plus,cfl,max_divergence,bulk_velocity,forcing,re_tau_wall"
    )
    .map_err(io_err(&hist_path))?;
    let t0 = solver.t_plus();
    let t_end = t0 + sp.duration_plus;
    let stats_from = t_end - sp.stats_window_plus;
    let mut stats = RunningStats::new(&solver.grid);
    let mut next_ck = t0 + sp.checkpoint_every_plus;
    let started = std::time::Instant::now();
    let mut steps = 0u64;
    while solver.t_plus() < t_end - 1e-9 {
        let rep = solver.step()?;
        steps += 1;
        let re = if rep.step % 20 == 0 {
            Some(wall_re_tau(&solver.grid, &solver.vel, dns.re_tau))
        } else {
            None
        };
        if let Some(re_tau) = re {
            writeln!(
                hist,
                "{},{:.4},{:.5},{:.4},{:.3e},{:.5},{:.5},{:.3}",
                rep.step,
                rep.t_plus,
                rep.dt_plus,
                rep.cfl,
                rep.max_divergence,
                rep.bulk_velocity,
                rep.forcing,
                re_tau
            )
            .map_err(io_err(&hist_path))?;
        }
        if sp.stats_window_plus > 0.0
            && rep.t_plus >= stats_from
            && rep.step % sp.stats_every_steps == 0
        {
            stats.add(&solver.grid, &solver.vel, rep.t_plus);
        }
        if rep.t_plus >= next_ck {
            solver.write_checkpoint(&ck_path)?;
            hist.flush().map_err(io_err(&hist_path))?;
            next_ck += sp.checkpoint_every_plus;
        }
        progress(&rep, re);
    }
    solver.write_checkpoint(&ck_path)?;
    hist.flush().map_err(io_err(&hist_path))?;
    let profiles = if stats.samples > 0 {
        let p = stats.profiles(&solver.grid, dns.re_tau);
        let csv = out_dir.join("stats.csv");
        std::fs::write(&csv, p.to_csv()).map_err(io_err(&csv))?;
        Some(p)
    } else {
        None
    };
    Ok(SpinupSummary {
        checkpoint: ck_path,
        profiles,
        steps,
        t_plus: solver.t_plus(),
        wall_seconds: started.elapsed().as_secs_f64(),
    })
}
