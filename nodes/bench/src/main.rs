//! `fiberflow-bench`: whole-run benchmarks of fiberflow, kept out of the product binary.
//! `scale` runs the fine-grid flow alone and carrying increasing fibre counts, over each
//! transport, in alternating rounds, and reports wall per coupling step with paired
//! ratios (docs/performance.md). It starts the `fiberflow` binary that sits beside it
//! (`cargo build --release --workspace` builds both).

mod contact;
mod scale;
mod scale_tables;
mod slicing;
mod stages;

use anyhow::Result;
use clap::{Parser, Subcommand};
use std::path::PathBuf;

#[derive(Parser, Debug)]
#[command(
    name = "fiberflow-bench",
    version,
    about = "Whole-run benchmarks of fiberflow (alternating rounds, paired ratios)"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand, Debug)]
#[allow(clippy::large_enum_variant)] // parsed once
enum Cmd {
    /// Scale benchmark: the fine-grid flow alone and carrying increasing fibre counts, over
    /// each transport, interleaved; prints wall per coupling step split into stages.
    Scale {
        /// Total fibre counts, multiples of 30 (0 = the flow alone).
        #[arg(long, value_delimiter = ',', default_value = "0,300,3000,30000,60000")]
        fibers: Vec<u64>,
        /// Transports to compare: iceoryx2, zenoh, inproc (every node a thread of one
        /// process).
        #[arg(long, value_delimiter = ',', default_value = "iceoryx2,zenoh")]
        transports: Vec<String>,
        /// Coupling steps per run [default: the launch files' run.steps, 150 in the
        /// shipped ones; the two files must agree].
        #[arg(long)]
        steps: Option<u64>,
        /// Runs per configuration: rounds of every configuration, each run beside its
        /// flow-only baseline, every other round in reverse order.
        #[arg(long, default_value_t = 2)]
        repeats: usize,
        /// Leave the recorder off (default: on, states every 10 steps, no samples).
        #[arg(long)]
        no_record: bool,
        /// Launch file with six fibre groups.
        #[arg(long, default_value = "launch/bench/scale-1e4.toml")]
        fibers_file: PathBuf,
        /// Launch file of the flow alone.
        #[arg(long, default_value = "launch/bench/scale-flow-only.toml")]
        flow_only_file: PathBuf,
        /// Fibre counts (multiples of 60) also run over two launchers on this machine, as
        /// if on two hosts (zenoh with mutual TLS; compared with zenoh's flow-only runs).
        #[arg(long, value_delimiter = ',')]
        two_launchers: Vec<u64>,
        /// The `[network]` launch file of those runs (hosts head and worker).
        #[arg(long, default_value = "launch/bench/scale-3e5-two-launchers.toml")]
        two_launchers_file: PathBuf,
        /// Where the runs and bench-scale.md go.
        #[arg(long, default_value = "recordings/bench-scale")]
        out: PathBuf,
        /// Compare the values of one launch-file key, run by run: KEY=V1,V2,… (e.g.
        /// run.fiber_scheduling=idle,normal), or of an environment variable of the
        /// launcher and its nodes: env:NAME=V1,V2,… The flow-only runs take the first value.
        #[arg(long, value_name = "KEY=V1,V2")]
        compare: Option<scale::Compare>,
        /// Run each transport's configurations of a round at once, in turns of this many
        /// milliseconds (the others stopped meanwhile), and take each run's step wall
        /// from the steps no pause touched: every configuration sees the same host, so a
        /// difference of 1–3% shows where whole runs scatter by ±10%. Stage walls of the
        /// fibre nodes and the recorder, which pauses inflate, are not reported then.
        #[arg(long, value_name = "MS", value_parser = clap::value_parser!(u64).range(50..=10_000))]
        slice_ms: Option<u64>,
    },
    /// The fibre step of one group of case-1 fibres at random in the fine-grid box, with
    /// fibre–fibre contact off and on in alternating rounds; prints ms per step and ratios.
    Contact {
        /// Fibres in the group.
        #[arg(long, default_value_t = 100_000)]
        fibers: usize,
        /// Steps per round.
        #[arg(long, default_value_t = 5)]
        steps: usize,
        /// Rounds (each: off and on, the order alternating).
        #[arg(long, default_value_t = 6)]
        rounds: usize,
        /// Steps at the start of each round left out of its figures: the first step of a
        /// group allocates the contact search's memory, which a run pays once.
        #[arg(long, default_value_t = 1)]
        warmup: usize,
        /// Friction coefficient of the runs with contact.
        #[arg(long, default_value_t = 0.5)]
        friction: f64,
        /// Fibres in a band 1–31 wall units from the lower wall, in a near-wall shear
        /// (u+ = y+ up to 15) with wall-normal sweeps of amplitude 1.5 towards and away
        /// from the wall, instead of the whole box in a gentle shear.
        #[arg(long)]
        near_wall: bool,
    },
    /// The flow node's per-fibre stages (sampling, spreading, the self-induced correction)
    /// at scale, each beside a floor kernel doing its irreducible work with trivial
    /// arithmetic, in alternating rounds on each thread count; prints a table.
    Stages {
        /// Fibres (seven segments each, at random in the fine grid's channel).
        #[arg(long, default_value_t = 100_000, value_parser = clap::value_parser!(u64).range(1..=2_000_000))]
        fibers: u64,
        /// Timed rounds (after one warm-up round).
        #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u64).range(1..=1000))]
        rounds: u64,
        /// Thread counts to compare.
        #[arg(long, value_delimiter = ',', default_value = "1,2")]
        threads: Vec<usize>,
    },
}

fn main() -> Result<()> {
    // the allocator's settings of the `fiberflow` process (nodes/cli: buffers of several MB
    // kept in the heap instead of fresh pages each step), so that the stages measure here
    // what they cost in the flow node
    // SAFETY: mallopt only tunes the allocator; called before any thread starts
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 1 << 30);
    }
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .with_writer(std::io::stderr)
        .init();
    match Cli::parse().cmd {
        Cmd::Scale {
            fibers,
            transports,
            steps,
            repeats,
            no_record,
            fibers_file,
            flow_only_file,
            two_launchers,
            two_launchers_file,
            out,
            compare,
            slice_ms,
        } => scale::run(&scale::BenchOptions {
            fibers_file,
            flow_only_file,
            two_launchers,
            two_launchers_file,
            fibers,
            transports,
            steps,
            repeats,
            record: !no_record,
            out,
            compare,
            slice_ms,
        }),
        Cmd::Contact {
            fibers,
            steps,
            rounds,
            warmup,
            friction,
            near_wall,
        } => contact::run_contact(&contact::ContactOptions {
            fibers,
            near_wall,
            steps,
            rounds,
            warmup,
            friction,
        }),
        Cmd::Stages {
            fibers,
            rounds,
            threads,
        } => stages::run_stages(&stages::StagesOptions {
            fibers: fibers as usize,
            rounds: rounds as usize,
            threads,
        }),
    }
}
