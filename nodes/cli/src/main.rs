//! `fiberflow`: the command-line front door (launch, node, replay, inspect, analyze, view).

mod progress;
mod spinup_cmd;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use std::path::PathBuf;

#[derive(Parser, Debug)]
#[command(name = "fiberflow", version, about = "Flexible fibres in DNS of turbulent channel flow")]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand, Debug)]
enum Cmd {
    /// Run a DNS spin-up from a flow configuration (TOML) and write checkpoint + statistics.
    Spinup {
        /// Flow configuration (a `[flow]` table with `source.kind = "dns"` and `[flow.spinup]`).
        config: PathBuf,
        /// Output directory.
        #[arg(long, default_value = "recordings/spinup")]
        out: PathBuf,
    },
}

fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    match cli.cmd {
        Cmd::Spinup { config, out } => spinup_cmd::run(&config, &out).context("spin-up failed"),
    }
}
