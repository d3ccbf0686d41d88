//! The flow node's share of a coupled checkpoint (DESIGN §3): the DNS field at the
//! checkpoint step in the solver's own format (`flow.ckpt`), plus `flow-extra.bin` with
//! what the solver's checkpoint does not hold but the run reads on (the running statistics
//! published as FlowProfiles, the last divergence check). An analytic flow has no state:
//! its `flow.ckpt` only names the step.

use crate::error::{io_err, FlowError};
use fiberflow_dns::stats::RunningStats;
use fiberflow_dns::Solver;
use fiberflow_messages::checkpoints::piece;
use std::path::Path;

const ANALYTIC_MAGIC: &[u8; 8] = b"FFANALYT";

fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), FlowError> {
    fiberflow_messages::checkpoints::write_atomic(path, bytes).map_err(io_err(path))
}

/// Writes the DNS share into `dir` (the extra file first: `flow.ckpt` marks completion).
pub fn write_dns(
    dir: &Path,
    solver: &Solver,
    stats: Option<&RunningStats>,
) -> Result<(), FlowError> {
    std::fs::create_dir_all(dir).map_err(io_err(dir))?;
    let mut extra = Vec::new();
    extra.extend_from_slice(&solver.last_divergence().to_le_bytes());
    if let Some(s) = stats {
        extra.extend_from_slice(&s.to_bytes());
    }
    write_atomic(&dir.join("flow-extra.bin"), &extra)?;
    solver.write_checkpoint(&piece(dir, "flow"))?;
    sync_dir(dir);
    Ok(())
}

/// Restores the DNS share from `dir`; returns the running statistics if there were any.
pub fn read_dns(dir: &Path, solver: &mut Solver) -> Result<Option<RunningStats>, FlowError> {
    solver.read_checkpoint(&piece(dir, "flow"))?;
    let p = dir.join("flow-extra.bin");
    let b = std::fs::read(&p).map_err(io_err(&p))?;
    let bad = |reason: &str| FlowError::Protocol(format!("{}: {reason}", p.display()));
    let d: [u8; 8] = b
        .get(..8)
        .and_then(|x| x.try_into().ok())
        .ok_or_else(|| bad("too short"))?;
    solver.set_last_divergence(f64::from_le_bytes(d));
    if b.len() == 8 {
        return Ok(None);
    }
    RunningStats::from_bytes(&solver.grid, &b[8..])
        .map(Some)
        .ok_or_else(|| bad("running statistics do not fit the grid"))
}

/// Writes the analytic flow's (stateless) share.
pub fn write_analytic(dir: &Path, step: u64) -> Result<(), FlowError> {
    std::fs::create_dir_all(dir).map_err(io_err(dir))?;
    let mut b = ANALYTIC_MAGIC.to_vec();
    b.extend_from_slice(&step.to_le_bytes());
    write_atomic(&piece(dir, "flow"), &b)
}

/// Checks the analytic share belongs to `step`.
pub fn read_analytic(dir: &Path, step: u64) -> Result<(), FlowError> {
    let p = piece(dir, "flow");
    let b = std::fs::read(&p).map_err(io_err(&p))?;
    let ok = b.len() == 16 && &b[..8] == ANALYTIC_MAGIC && b[8..] == step.to_le_bytes();
    if !ok {
        return Err(FlowError::Protocol(format!(
            "{} is not the analytic flow's checkpoint of step {step}",
            p.display()
        )));
    }
    Ok(())
}

fn sync_dir(dir: &Path) {
    if let Ok(d) = std::fs::File::open(dir) {
        let _ = d.sync_all();
    }
}
