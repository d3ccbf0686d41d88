//! `fiberflow`: the command-line front door (launch, node, spinup, replay, inspect, inject).

mod commands;
mod recording;

use fiberflow_launcher::{launch, nodes, spinup_cmd};

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use std::path::PathBuf;

#[derive(Parser, Debug)]
#[command(
    name = "fiberflow",
    version,
    about = "Flexible fibres in DNS of turbulent channel flow"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand, Debug)]
enum Cmd {
    /// Run a whole experiment from a launch file (TOML).
    Launch {
        file: PathBuf,
        /// Output folder (default: recordings/<run id>, or recordings/<run id>-r<i> for run.realisation = i ≥ 1).
        #[arg(long)]
        out: Option<PathBuf>,
        /// inproc | zenoh | iceoryx2 (default: the launch file's run.transport).
        #[arg(long)]
        transport: Option<fiberflow_bus::Transport>,
        /// Multi-host launch files: run this host's nodes (a `[[network.hosts]]` name).
        #[arg(long)]
        host: Option<String>,
        /// Override a launch-file key (dotted path, TOML value), e.g.
        /// `--set run.steps=400 --set fibers.case1.density_ratio=2300`; repeatable.
        #[arg(long = "set", value_name = "KEY=VALUE")]
        sets: Vec<String>,
        /// Continue the run in this folder from its newest complete checkpoint (after
        /// Ctrl-C or a crash); give the same launch file and --set options.
        #[arg(long, value_name = "DIR")]
        resume: Option<PathBuf>,
    },
    /// Run one node from a spec written by the launcher.
    Node {
        #[arg(long)]
        spec: PathBuf,
    },
    /// Run a DNS spin-up from a flow configuration and write checkpoint + statistics.
    Spinup {
        config: PathBuf,
        #[arg(long, default_value = "recordings/spinup")]
        out: PathBuf,
    },
    /// Channels, message counts, metadata and integrity of a recording (a run folder or
    /// one .mcap segment).
    Inspect {
        mcap: PathBuf,
        /// Salvage a file whose writer was killed into <mcap>.recovered.mcap.
        #[arg(long)]
        recover: bool,
    },
    /// Republish a recording (a run folder or one .mcap) on the bus (zenoh) in its
    /// original order and timing.
    Replay {
        mcap: PathBuf,
        /// Playback speed (1 = one t+ per second of wall time); 0 = as fast as possible.
        #[arg(long, default_value_t = 1.0)]
        speed: f64,
        /// zenoh endpoint to connect to.
        #[arg(long)]
        connect: Vec<String>,
        /// zenoh endpoint to listen on (default: an ephemeral loopback port).
        #[arg(long)]
        listen: Vec<String>,
        /// Seconds to wait for a subscriber before replaying: of any recorded topic (then
        /// a moment for the rest of its declarations), or of every topic `--topics` picks
        /// (a session that reaches no peer in that time is tried once more, then it is
        /// an error).
        #[arg(long, default_value_t = 30.0)]
        wait_s: f64,
        /// Replay only the topics matching this key expression (repeatable), e.g.
        /// `--topics 'fiberflow/quick/fibers/case1/*'`.
        #[arg(long)]
        topics: Vec<String>,
    },
    /// Print what arrives on the bus (zenoh) under a topic pattern.
    Echo {
        /// Topic or prefix pattern, e.g. fiberflow/quick/** .
        pattern: String,
        #[arg(long)]
        connect: Vec<String>,
        #[arg(long)]
        listen: Vec<String>,
        /// Stop after this many messages.
        #[arg(long)]
        count: Option<u64>,
        /// Stop after this many seconds without a message (once one has come).
        #[arg(long, default_value_t = 10.0)]
        idle_s: f64,
        /// Stop if no first message comes within this many seconds.
        #[arg(long, default_value_t = 60.0)]
        wait_s: f64,
        /// Print each message's topic and size only (default: its decoded fields).
        #[arg(long)]
        raw: bool,
        /// Values shown of each long array (its length is always given).
        #[arg(long, default_value_t = 8)]
        array_items: usize,
    },
    /// Analysis of a recording (a run folder or one .mcap): the fibres' MSD, alignment and
    /// coiling, and what the fibres do to the flow (CSV, PNG, summary.md,
    /// flow_modulation.md). Several recordings are realisations of one run: their flow
    /// statistics are pooled (docs/realisations.md) and the fibres are analysed per run.
    Analyze {
        /// The run folder (or .mcap), or several realisations of one run.
        #[arg(required = true, num_args = 1..)]
        mcap: Vec<PathBuf>,
        /// Output folder (default: <run folder>/analysis; for realisations
        /// <first run folder without its -r<i>>-realisations).
        #[arg(long)]
        out: Option<PathBuf>,
        /// sigma^2 thresholds of the coiling-onset table.
        #[arg(long, value_delimiter = ',', default_value = "0.1,0.5,1.0")]
        coil_thresholds: Vec<f64>,
        /// An unladen (or one-way) run of the same flow to compare the flow statistics with
        /// (a run folder or one .mcap), or several realisations of it.
        #[arg(long, num_args = 1..)]
        unladen: Vec<PathBuf>,
        /// Flow statistics start at this t+ (the transient before it is left out).
        #[arg(long, default_value_t = 0.0)]
        transient_plus: f64,
        /// Batches of the flow statistics' batch means (95% intervals over them).
        #[arg(long, default_value_t = 10)]
        batches: usize,
    },
    /// A recording (a run folder or one .mcap) as Parquet tables for pandas, polars, R,
    /// MATLAB: states per segment, metrics per fibre, flow status, profiles, contacts
    /// (docs/export.md).
    Export {
        mcap: PathBuf,
        /// Output folder (default: <run folder>/export).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Tables to write, comma separated: states, metrics, flow, profiles, contacts
        /// (default: all).
        #[arg(long, value_delimiter = ',')]
        what: Option<Vec<String>>,
    },
    /// Show a recording (a run folder or one .mcap) in Rerun: channel box, fibres
    /// coloured by coiling, plots per case.
    View {
        mcap: PathBuf,
        /// Write an .rrd file instead of opening a viewer.
        #[arg(long)]
        save: Option<PathBuf>,
        /// Spawn a Rerun viewer (needs `rerun` 0.36.3 on PATH: pip install rerun-sdk==0.36.3).
        #[arg(long)]
        spawn: bool,
        /// Stream to a running viewer, e.g. rerun+http://127.0.0.1:9876/proxy.
        #[arg(long)]
        connect: Option<String>,
        /// Show fibre shapes every n-th step (0: one per whole t+; the series keep every step).
        #[arg(long, default_value_t = 0)]
        every: u64,
        /// Fibres per case in the stratified sample (a smaller case is shown whole).
        #[arg(long, default_value_t = 300)]
        per_case: usize,
        /// The most coiled fibres (largest final σ²) added per case.
        #[arg(long, default_value_t = 20)]
        most_coiled: usize,
        /// σ² thresholds of the coiling events, comma separated.
        #[arg(long, value_delimiter = ',', default_values_t = fiberflow_analysis::coiling::DEFAULT_THRESHOLDS)]
        coil_thresholds: Vec<f64>,
        /// Show where fibres touch (red points), the recorded contact forces (orange
        /// arrows) and the flocs in every shown state; a contact search over each group's
        /// fibres per state (docs/contact.md).
        #[arg(long)]
        contacts: bool,
    },
    /// Print every launch-file key with its type, default and meaning (Markdown), or
    /// refresh the generated block of a file with it (docs/launch-files.md).
    Keys {
        /// Replace the generated block of this file instead of printing.
        #[arg(long)]
        write: Option<PathBuf>,
    },
    /// Compare DNS statistics (stats.csv from a spin-up) with the reference DNS data.
    FlowReport {
        stats: PathBuf,
        /// Folder with the reference files (MKM_chan180.*, HJ_Re180.prof).
        #[arg(long)]
        reference: PathBuf,
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Publish random payloads on topics of a run (robustness testing).
    Inject {
        #[arg(long)]
        run: String,
        #[arg(long)]
        connect: Vec<String>,
        /// Topics relative to fiberflow/<run>/.
        #[arg(long, required = true)]
        topic: Vec<String>,
        #[arg(long, default_value_t = 10_000)]
        count: u64,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Valid CDR of each topic's message type that breaks a rule receivers check
        /// (inconsistent arrays, NaN, unknown names, impossible steps) instead of bytes.
        #[arg(long)]
        structured: bool,
        /// Seconds to wait for the run's subscribers before injecting (a session that
        /// reaches no peer in that time is tried once more, then it is an error).
        #[arg(long, default_value_t = 30.0)]
        wait_s: f64,
    },
}

/// What every command's process starts with: the allocator's settings, logging, the
/// named thread pool.
fn set_up_process() {
    // Every coupling step allocates and frees message buffers of several MB. glibc serves
    // such sizes with fresh mmap'd pages (page faults, the kernel zeroing them) and trims
    // its heap after each free; keep them in the heap instead, so a step reuses the last
    // step's memory (what it saves: docs/performance.md, "Allocator settings").
    // SAFETY: mallopt only tunes the allocator; called before any thread starts
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 1 << 30);
    }
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                // zenoh's session chatter is noise next to the run's own messages. Its
                // admin space warns when a peer's link event arrives after that peer's
                // transport is gone (a node exiting at the end of a run): a race in
                // zenoh's own bookkeeping that loses no data, so only its errors show.
                .unwrap_or_else(|_| {
                    tracing_subscriber::EnvFilter::new("info,zenoh=warn,zenoh::api::admin=error")
                }),
        )
        .with_writer(std::io::stderr)
        // colour on a terminal only: node logs are files
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .init();
    // the shared pool's threads named, so per-thread CPU (the flow node's timing line,
    // `top -H`, perf) tells the DNS and sampling work from the bus's threads
    if let Err(e) = rayon::ThreadPoolBuilder::new()
        .thread_name(|i| format!("compute-{i}"))
        .build_global()
    {
        tracing::debug!(error = %e, "the thread pool was already built");
    }
}

/// Argument parsing, then one call per command (the match is the dispatch table).
fn main() -> Result<()> {
    set_up_process();
    let cli = Cli::parse();
    // commands that print behave like other command-line tools when piped into `head`:
    // exit quietly on EPIPE. Not the launcher and its nodes: a peer closing a network
    // connection must surface as an error on that link, not kill the process
    if !matches!(cli.cmd, Cmd::Launch { .. } | Cmd::Node { .. }) {
        // SAFETY: resetting a signal disposition to its default before any thread starts
        unsafe {
            libc::signal(libc::SIGPIPE, libc::SIG_DFL);
        }
    }
    match cli.cmd {
        Cmd::Launch {
            file,
            out,
            transport,
            host,
            sets,
            resume,
        } => commands::launch_cmd(
            &file,
            launch::LaunchOptions {
                out,
                transport,
                host,
                sets,
                resume,
            },
        ),
        Cmd::Node { spec } => match nodes::node_cmd(&spec) {
            // a lost peer: a status the launcher restarts for (the error said first)
            Err(e) if nodes::node_exit_code(&e) != 1 => {
                eprintln!("Error: {e:?}");
                std::process::exit(nodes::node_exit_code(&e));
            }
            r => r,
        },
        Cmd::Spinup { config, out } => spinup_cmd::run(&config, &out).context("spin-up failed"),
        Cmd::Export { mcap, out, what } => commands::export_cmd(&mcap, out, what.as_deref()),
        Cmd::Inspect { mcap, recover } => recording::inspect_cmd(&mcap, recover),
        Cmd::Replay {
            mcap,
            speed,
            connect,
            listen,
            wait_s,
            topics,
        } => recording::replay_cmd(&mcap, speed, connect, listen, wait_s, &topics),
        Cmd::Echo {
            pattern,
            connect,
            listen,
            count,
            idle_s,
            wait_s,
            raw,
            array_items,
        } => recording::echo_cmd(
            &pattern,
            connect,
            listen,
            count,
            idle_s,
            wait_s,
            (!raw).then_some(array_items),
        ),
        Cmd::Analyze {
            mcap,
            out,
            coil_thresholds,
            unladen,
            transient_plus,
            batches,
        } => commands::analyze_cmd(
            &mcap,
            out,
            &coil_thresholds,
            &unladen,
            transient_plus,
            batches,
        ),
        Cmd::View {
            mcap,
            save,
            spawn,
            connect,
            every,
            per_case,
            most_coiled,
            coil_thresholds,
            contacts,
        } => commands::view_cmd(
            &mcap,
            save,
            spawn,
            connect,
            every,
            per_case,
            most_coiled,
            coil_thresholds,
            contacts,
        ),
        Cmd::Keys { write } => commands::keys_cmd(write),
        Cmd::FlowReport {
            stats,
            reference,
            out,
        } => commands::flow_report_cmd(&stats, &reference, out),
        Cmd::Inject {
            run,
            connect,
            topic,
            count,
            seed,
            structured,
            wait_s,
        } => recording::inject_cmd(&run, connect, &topic, count, seed, structured, wait_s),
    }
}
