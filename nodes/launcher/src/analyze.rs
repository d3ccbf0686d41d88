//! `analyze` (fibres, and what the fibres do to the flow) and `flow-report`.

use anyhow::{Context, Result};
use std::path::{Path, PathBuf};

/// Fibre analysis; writes `summary.md` and returns the table.
pub fn fibers(mcap: &Path, out: &Path, coil_thresholds: &[f64]) -> Result<String> {
    if coil_thresholds.is_empty() || !coil_thresholds.iter().all(|t| *t > 0.0 && t.is_finite()) {
        anyhow::bail!("--coil-thresholds must be positive numbers (got {coil_thresholds:?})");
    }
    let a = fiberflow_analysis::fibers::analyse(mcap, out, coil_thresholds)
        .with_context(|| format!("analysing {}", mcap.display()))?;
    let table = fiberflow_analysis::fibers::summary_table(&a.summaries);
    let md = format!(
        "# Fibre analysis of {}\n\n\
         MSD_23 slope: least squares of log MSD against log lag over the fit window.\n\
         Ramp time: first time <|z1|> covers 1 - 1/e of the way from its initial value to its mean over the last 10% of the run.\n\
         Brackets: 95% bootstrap intervals over the fibres of a case (or of a layer), {} resamples with a fixed seed.\n\n\
         {table}\n\
         ## Coiling onsets\n\n\
         First t+ at which a fibre's sigma^2 reaches each threshold (linear interpolation between recorded steps); \
         the share of the case's (or layer's) fibres that reach it, and the median onset with its quartiles over those that do. \
         Per fibre: coiling_onsets.csv.\n\n\
         {}\n\
         Figures: msd23.png, abs_z1.png, sigma2.png and per case <case>_abs_z1_layers.png, \
         <case>_signed_z1_near_wall.png, <case>_trajectories_x3x2.png.\n",
        mcap.display(),
        fiberflow_analysis::bootstrap::REPLICATES,
        a.coiling_table
    );
    std::fs::write(out.join("summary.md"), &md)
        .with_context(|| format!("writing {}", out.display()))?;
    println!("analysis written to {}", out.display());
    Ok(table)
}

/// [`fibers`], or None when the recording holds no fibre state (a flow part,
/// `scripts/flow_part.py`: the flow's statistics and the fibres' mass only).
pub fn fibers_if_any(mcap: &Path, out: &Path, coil_thresholds: &[f64]) -> Result<Option<String>> {
    match fibers(mcap, out, coil_thresholds) {
        Ok(table) => Ok(Some(table)),
        Err(e)
            if matches!(
                e.downcast_ref::<fiberflow_analysis::AnalysisError>(),
                Some(fiberflow_analysis::AnalysisError::NoFiberStates(_))
            ) =>
        {
            Ok(None)
        }
        Err(e) => Err(e),
    }
}

/// The flow modulation of `runs` (one run, or realisations of it) against `unladen`
/// (none, one, or realisations of the unladen flow), statistics from `transient_plus` on
/// in `batches` batches per run; `None` when the runs recorded no flow status.
pub fn modulation(
    runs: &[PathBuf],
    unladen: &[PathBuf],
    transient_plus: f64,
    batches: usize,
    out: &Path,
) -> Result<Option<String>> {
    use fiberflow_analysis::modulation::{read_flow, report};
    if !(transient_plus >= 0.0 && transient_plus.is_finite()) {
        anyhow::bail!("--transient-plus must be >= 0 (got {transient_plus})");
    }
    if batches < 2 {
        anyhow::bail!("--batches must be >= 2 (got {batches})");
    }
    let read =
        |p: &PathBuf| read_flow(p).with_context(|| format!("reading the flow of {}", p.display()));
    let ours = runs.iter().map(read).collect::<Result<Vec<_>>>()?;
    let Some(first) = ours.first() else {
        anyhow::bail!("no run to analyse");
    };
    if ours.iter().all(|r| r.status.is_empty()) {
        return Ok(None);
    }
    for (p, r) in runs.iter().zip(&ours) {
        if r.status.is_empty() {
            anyhow::bail!(
                "{}: no flow status recorded (a realisation without statistics)",
                p.display()
            );
        }
    }
    let base = unladen.iter().map(read).collect::<Result<Vec<_>>>()?;
    for (p, b) in runs.iter().zip(&ours).chain(unladen.iter().zip(&base)) {
        if b.box_plus != first.box_plus {
            anyhow::bail!(
                "{}: its channel box {:?} is not the first run's {:?}",
                p.display(),
                b.box_plus,
                first.box_plus
            );
        }
    }
    let md = report(&ours, &base, transient_plus, batches, out)
        .with_context(|| format!("writing the flow modulation into {}", out.display()))?;
    Ok(Some(md))
}

/// Flow validation report against the reference data.
pub fn flow(stats: &Path, reference: &Path, out: &Path) -> Result<String> {
    let refs = vec![
        fiberflow_analysis::reference::mkm(reference)?,
        fiberflow_analysis::reference::hoyas_jimenez(&reference.join("HJ_Re180.prof"))?,
    ];
    let md = fiberflow_analysis::flow_validation::report(stats, &refs, out)?;
    std::fs::write(out.join("flow_validation.md"), &md)?;
    Ok(md)
}
