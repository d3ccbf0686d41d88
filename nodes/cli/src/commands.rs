//! The bodies of the `fiberflow` commands that do more than call one library function.

use anyhow::{Context, Result};
use fiberflow_launcher::{analyze, keys, launch};
use std::path::{Path, PathBuf};

/// `fiberflow launch`: runs the launch file and says where to look.
pub fn launch_cmd(file: &Path, opts: launch::LaunchOptions) -> Result<()> {
    let o =
        launch::launch(file, opts).with_context(|| format!("launch {} failed", file.display()))?;
    if let (Some(lf), Some(m)) = (&o.launch, &o.mcap) {
        let rrd = m.join("run.rrd");
        let how = if rrd.exists() {
            format!("rerun {}", rrd.display())
        } else {
            format!("fiberflow view {} --spawn", m.display())
        };
        println!(
            "run {} finished: {} (view: {how})",
            lf.run.id,
            o.out_dir.display()
        );
    }
    Ok(())
}

/// `fiberflow export`: the recording as Parquet tables, with a bar over its steps.
pub fn export_cmd(mcap: &Path, out: Option<PathBuf>, what: Option<&[String]>) -> Result<()> {
    let out = out.unwrap_or_else(|| {
        if mcap.is_dir() {
            mcap.join("export")
        } else {
            mcap.parent().unwrap_or(Path::new(".")).join("export")
        }
    });
    let tables = fiberflow_export::tables_named(what)?;
    let bar = fiberflow_launcher::progress::bar(0, "steps");
    let summary = fiberflow_export::export(mcap, &out, &tables, |p| {
        if let Some(n) = p.steps {
            bar.set_length(n);
        }
        bar.set_position(p.step);
    })
    .with_context(|| format!("export of {} failed", mcap.display()))?;
    bar.finish_and_clear();
    for (path, rows) in &summary.files {
        println!("{rows:>12} rows  {}", path.display());
    }
    if summary.dropped > 0 || summary.repeated > 0 || summary.incomplete > 0 {
        println!(
            "left out: {} messages that failed their checks, {} repeated, {} incomplete sharded steps",
            summary.dropped, summary.repeated, summary.incomplete
        );
    }
    for d in &summary.damaged {
        println!("read up to damage: {d}");
    }
    Ok(())
}

/// `fiberflow analyze`: the fibre analysis and, for a two-way run, the flow's modulation.
pub fn analyze_cmd(
    runs: &[PathBuf],
    out: Option<PathBuf>,
    coil_thresholds: &[f64],
    unladen: &[PathBuf],
    transient_plus: f64,
    batches: usize,
) -> Result<()> {
    let folder_of = |p: &Path| -> PathBuf {
        if p.is_dir() {
            p.to_path_buf()
        } else {
            p.parent().unwrap_or(Path::new(".")).to_path_buf()
        }
    };
    let [one] = runs else {
        // realisations: each run's fibres in its own folder, the flow pooled
        let out = out.unwrap_or_else(|| realisations_folder(&folder_of(&runs[0])));
        for r in runs {
            let table = analyze::fibers_if_any(r, &folder_of(r).join("analysis"), coil_thresholds)?;
            println!("{}:\n{}", r.display(), fiber_table_or_why(table));
        }
        match analyze::modulation(runs, unladen, transient_plus, batches, &out)? {
            Some(md) => println!("{md}"),
            None => anyhow::bail!("the realisations recorded no flow status"),
        }
        return Ok(());
    };
    let out = out.unwrap_or_else(|| folder_of(one).join("analysis"));
    let table = analyze::fibers_if_any(one, &out, coil_thresholds)?;
    println!("{}", fiber_table_or_why(table));
    if let Some(md) = analyze::modulation(
        std::slice::from_ref(one),
        unladen,
        transient_plus,
        batches,
        &out,
    )? {
        println!("{md}");
    }
    Ok(())
}

/// The fibre analysis's table, or why a recording has none (a flow part).
fn fiber_table_or_why(table: Option<String>) -> String {
    table.unwrap_or_else(|| "no fibre states (a flow part): its flow only".into())
}

/// Where the pooled analysis of realisations goes: beside the first, named for it without
/// its `-r<i>` (`recordings/two-way-r1` → `recordings/two-way-realisations`).
fn realisations_folder(first: &Path) -> PathBuf {
    let name = first
        .file_name()
        .map(|n| n.to_string_lossy().to_string())
        .unwrap_or_else(|| "run".into());
    let stem = match name.rsplit_once("-r") {
        Some((s, i)) if !i.is_empty() && i.chars().all(|c| c.is_ascii_digit()) => s.to_string(),
        _ => name,
    };
    first
        .parent()
        .unwrap_or(Path::new("."))
        .join(format!("{stem}-realisations"))
}

/// `fiberflow view`: the Rerun scene of a recording, saved, spawned or streamed.
pub fn view_cmd(
    mcap: &Path,
    save: Option<PathBuf>,
    spawn: bool,
    connect: Option<String>,
    every: u64,
    per_case: usize,
    most_coiled: usize,
    coil_thresholds: Vec<f64>,
    contacts: bool,
) -> Result<()> {
    let sink = match (save, spawn, connect) {
        (Some(p), false, None) => fiberflow_viewer::Sink::Save(p),
        (None, _, Some(u)) => fiberflow_viewer::Sink::Connect(u),
        (None, _, None) => fiberflow_viewer::Sink::Spawn,
        _ => anyhow::bail!("choose one of --save, --spawn, --connect"),
    };
    let opts = fiberflow_viewer::ViewOptions {
        every,
        sampling: fiberflow_viewer::select::Sampling {
            per_case,
            most_coiled,
        },
        coil_thresholds,
        contacts,
    };
    let s = fiberflow_viewer::view(mcap, &sink, &opts)
        .with_context(|| format!("viewing {}", mcap.display()))?;
    tracing::info!(
        groups = s.groups,
        fibers = s.fibers,
        shown = s.shown,
        coiling_events = s.events,
        flow_slices = s.slices,
        contact_states = s.contact_states,
        floc_fibers = s.floc_fibers,
        "scene written"
    );
    Ok(())
}

/// `fiberflow keys`: the launch-file key reference, printed or written into a file.
pub fn keys_cmd(write: Option<PathBuf>) -> Result<()> {
    match write {
        Some(file) => {
            let changed = keys::write_into(&file)?;
            println!(
                "{}: {}",
                file.display(),
                if changed {
                    "updated"
                } else {
                    "already up to date"
                }
            );
        }
        None => print!("{}", keys::markdown()?),
    }
    Ok(())
}

/// `fiberflow flow-report`: DNS statistics against the reference data.
pub fn flow_report_cmd(stats: &Path, reference: &Path, out: Option<PathBuf>) -> Result<()> {
    let out = out.unwrap_or_else(|| {
        stats
            .parent()
            .unwrap_or(std::path::Path::new("."))
            .join("validation")
    });
    println!("{}", analyze::flow(stats, reference, &out)?);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn realisations_go_beside_the_first_without_its_index() {
        assert_eq!(
            realisations_folder(Path::new("recordings/two-way-r1")),
            PathBuf::from("recordings/two-way-realisations")
        );
        assert_eq!(
            realisations_folder(Path::new("recordings/run-rx")),
            PathBuf::from("recordings/run-rx-realisations")
        );
    }
}
