//! `analyze` (fibres, and what the fibres do to the flow) and `flow-report`.

use anyhow::{Context, Result};
use std::path::Path;

/// Fibre analysis; writes `summary.md` and returns the table.
pub fn fibres(mcap: &Path, out: &Path, coil_thresholds: &[f64]) -> Result<String> {
    if coil_thresholds.is_empty() || !coil_thresholds.iter().all(|t| *t > 0.0 && t.is_finite()) {
        anyhow::bail!("--coil-thresholds must be positive numbers (got {coil_thresholds:?})");
    }
    let a = fiberflow_analysis::fibres::analyse(mcap, out, coil_thresholds)
        .with_context(|| format!("analysing {}", mcap.display()))?;
    let table = fiberflow_analysis::fibres::summary_table(&a.summaries);
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

/// What the fibres do to the flow ([`fiberflow_analysis::modulation`]), against an
/// unladen run if given; `None` when the recording has no flow statistics (an analytic
/// flow).
pub fn modulation(
    mcap: &Path,
    unladen: Option<&Path>,
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
    let run = read_flow(mcap).with_context(|| format!("reading the flow of {}", mcap.display()))?;
    if run.status.is_empty() {
        return Ok(None);
    }
    let base = unladen
        .map(|u| read_flow(u).with_context(|| format!("reading the flow of {}", u.display())))
        .transpose()?;
    if let Some(b) = &base {
        if b.box_plus != run.box_plus {
            anyhow::bail!(
                "--unladen {}: its channel box {:?} is not this run's {:?}",
                unladen.map_or(String::new(), |u| u.display().to_string()),
                b.box_plus,
                run.box_plus
            );
        }
    }
    let md = report(&run, base.as_ref(), transient_plus, batches, out)
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
