//! `fiberflow spinup`: standalone DNS spin-up with a progress bar.

use crate::progress::t_plus_bar;
use anyhow::{bail, Context, Result};
use fiberflow_flow::{FlowNodeConfig, FlowSource};
use serde::Deserialize;
use std::path::Path;

#[derive(Deserialize)]
struct File {
    flow: FlowNodeConfig,
}

/// Runs the spin-up described by a flow-node configuration.
pub fn run_config(flow: &FlowNodeConfig, out: &Path) -> Result<()> {
    let FlowSource::Dns { dns, .. } = &flow.source else {
        bail!("flow.source.kind must be \"dns\" for a spin-up");
    };
    let sp = flow.spinup.clone().context("[flow.spinup] is missing")?;
    spin(dns, &sp, out)
}

pub fn run(config: &Path, out: &Path) -> Result<()> {
    let text =
        std::fs::read_to_string(config).with_context(|| format!("reading {}", config.display()))?;
    let mut file: File =
        toml::from_str(&text).with_context(|| format!("parsing {}", config.display()))?;
    let base = config.parent().unwrap_or(Path::new("."));
    let Some(sp) = file.flow.spinup.as_mut() else {
        bail!("{}: [flow.spinup] is missing", config.display());
    };
    if let Some(r) = sp.restart.as_mut() {
        if r.is_relative() {
            *r = base.join(&*r);
        }
    }
    file.flow.validate()?;
    let FlowSource::Dns { dns, .. } = &file.flow.source else {
        bail!(
            "{}: flow.source.kind must be \"dns\" for a spin-up",
            config.display()
        );
    };
    let sp = file.flow.spinup.clone().context("spinup")?;
    spin(dns, &sp, out)
}

fn spin(
    dns: &fiberflow_dns::DnsConfig,
    sp: &fiberflow_flow::spinup::SpinupConfig,
    out: &Path,
) -> Result<()> {
    let pb = t_plus_bar(sp.duration_plus);
    let start = std::cell::Cell::new(f64::NAN);
    let mut last_re = f64::NAN;
    let summary = fiberflow_flow::spinup::run(dns, sp, out, &mut |rep, re| {
        if start.get().is_nan() {
            start.set(rep.t_plus - rep.dt_plus);
        }
        if let Some(r) = re {
            last_re = r;
        }
        pb.set_position(((rep.t_plus - start.get()) * 100.0) as u64);
        pb.set_message(format!(
            "{:.1} dt+ {:.3} CFL {:.2} Ub+ {:.2} Re_tau {:.1}",
            rep.t_plus, rep.dt_plus, rep.cfl, rep.bulk_velocity, last_re
        ));
    })?;
    pb.finish();
    println!(
        "spin-up: {} steps to t+ = {:.1} in {:.1} s ({:.3} s per t+); checkpoint {}",
        summary.steps,
        summary.t_plus,
        summary.wall_seconds,
        summary.wall_seconds / sp.duration_plus,
        summary.checkpoint.display()
    );
    if let Some(p) = &summary.profiles {
        println!(
            "statistics over {:.0} t+ ({} samples): Re_tau = {:.2}, Ub+ = {:.3}",
            p.t_plus_span, p.samples, p.re_tau, p.bulk_velocity
        );
    }
    Ok(())
}
