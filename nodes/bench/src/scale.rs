//! `fiberflow-bench scale`: the scale benchmark. Runs the fine-grid flow alone and carrying
//! increasing numbers of fibres, over each transport, configurations interleaved (A B C …
//! A B C …) so slow drifts of a shared machine hit every configuration alike; reads each
//! node's own "where … time went" log line and prints, per configuration, the wall time per
//! coupling step split into its stages (medians over the repeats, with min–max of the
//! step wall), and the CPU time all processes of a run used (on a saturated machine the
//! wall follows the CPU, not the transport).
//!
//! The paired ratios and the tables are [`crate::scale_tables`]. Size (≈ 700 lines before
//! the tests): the configurations, the rounds and the log lines it reads change together
//! whenever a measurement changes.

use crate::scale_tables::{compared_table, table};
use anyhow::{bail, Context, Result};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

/// What the benchmark runs.
#[derive(Debug, Clone)]
pub struct BenchOptions {
    /// Launch file with the flow and six fibre groups (`placement.per_layer` is set per
    /// configuration); 0 fibres runs `flow_only` instead.
    pub fibers_file: PathBuf,
    pub flow_only_file: PathBuf,
    /// Total fibre counts (multiples of 30: six groups of five layers).
    pub fibers: Vec<u64>,
    pub transports: Vec<String>,
    /// Coupling steps per run; `None`: the launch files' `run.steps` (they must agree).
    pub steps: Option<u64>,
    pub repeats: usize,
    /// Record (states every 10 steps, metrics every step, no samples).
    pub record: bool,
    pub out: PathBuf,
    /// Fibre counts also run over two launchers on this machine ([`TWO_LAUNCHERS`]).
    pub two_launchers: Vec<u64>,
    /// The `[network]` launch file for those runs (hosts `head` and `worker`; its
    /// certificates are made with `launch/multi-host/make-certs.sh` if missing).
    pub two_launchers_file: PathBuf,
    /// A launch-file key whose values are compared, run by run (`--compare`).
    pub compare: Option<Compare>,
    /// Run each transport's configurations of a round at once, in turns of this many
    /// milliseconds (`--slice-ms`; see [`crate::slicing`]).
    pub slice_ms: Option<u64>,
}

/// `--compare KEY=V1,V2,…`: every fibre configuration runs once per value, in turn within
/// each round; the flow-only runs take the first value. KEY is a launch-file key, or
/// `env:NAME` for an environment variable of the launcher and its nodes.
#[derive(Debug, Clone, PartialEq)]
pub struct Compare {
    pub key: String,
    pub values: Vec<String>,
}

impl std::str::FromStr for Compare {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let (key, values) = s.split_once('=').ok_or_else(|| {
            format!("{s:?} is not KEY=V1,V2,… (e.g. run.fiber_scheduling=idle,normal)")
        })?;
        let values: Vec<String> = values.split(',').map(str::to_string).collect();
        if key.is_empty() || key == "env:" || values.iter().any(String::is_empty) {
            return Err(format!("{s:?}: the key and every value must be non-empty"));
        }
        // runs are told apart by their value: a repeated one would pool two
        // configurations' runs into one row
        for (i, v) in values.iter().enumerate() {
            if let Some(j) = values[..i].iter().position(|x| x == v) {
                return Err(format!(
                    "{s:?}: value {v:?} is given twice (values {} and {}); for a control \
                     that changes nothing, compare an environment variable nothing reads \
                     (e.g. env:FF_CONTROL=1,2)",
                    j + 1,
                    i + 1
                ));
            }
        }
        Ok(Self {
            key: key.to_string(),
            values,
        })
    }
}

/// One configuration of a round.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Config {
    pub(crate) fibers: u64,
    /// The transport, or [`TWO_LAUNCHERS`].
    pub(crate) transport: String,
    /// The compared key's setting (`key=value`), if any.
    pub(crate) setting: Option<String>,
    /// The row's name: the transport, and the setting when one is compared.
    pub(crate) label: String,
    /// The label of the flow-only runs this configuration is compared with.
    pub(crate) baseline: String,
}

/// The configurations of one round, in the order of the first round: each transport's
/// flow-only run followed by the runs compared with it (the two-launcher runs with
/// zenoh's), so that a run and its baseline run next to each other. Later rounds take
/// them in [`round_order`].
fn configurations(o: &BenchOptions) -> Vec<Config> {
    let settings: Vec<Option<String>> = match &o.compare {
        Some(c) => c
            .values
            .iter()
            .map(|v| Some(format!("{}={v}", c.key)))
            .collect(),
        None => vec![None],
    };
    let label = |t: &str, s: &Option<String>| match s {
        Some(s) => format!("{t}, {s}"),
        None => t.to_string(),
    };
    let runs = o
        .fibers
        .iter()
        .flat_map(|&n| o.transports.iter().map(move |t| (n, t.clone())))
        .chain(
            o.two_launchers
                .iter()
                .map(|&n| (n, TWO_LAUNCHERS.to_string())),
        );
    let mut v = Vec::new();
    for (n, t) in runs {
        // the flow alone has no setting to compare: it runs with the first
        let these = if n == 0 {
            &settings[..1]
        } else {
            &settings[..]
        };
        for s in these {
            v.push(Config {
                fibers: n,
                label: label(&t, s),
                baseline: label(baseline_of(&t), &settings[0]),
                transport: t.clone(),
                setting: s.clone(),
            });
        }
    }
    // grouped by baseline, in the order the transports were given (stable: within a
    // group the flow alone first, then by fibre count); runs without a flow-only run of
    // their own keep their place at the end
    let block = |c: &Config| {
        o.transports
            .iter()
            .position(|t| label(t, &settings[0]) == c.baseline)
            .unwrap_or(o.transports.len())
    };
    v.sort_by_key(|c| (block(c), c.fibers > 0));
    v
}

/// The order of round `r` (0-based): the first round's order, reversed in every other
/// round. A run and its baseline are neighbours either way, and which of them runs first
/// alternates (A B, B A, …), so a host that drifts, or a run that slows the next one,
/// moves the paired ratios up in one round and down in the next instead of all one way.
fn round_order<T>(configs: &[T], r: usize) -> Vec<&T> {
    let mut v: Vec<&T> = configs.iter().collect();
    if r % 2 == 1 {
        v.reverse();
    }
    v
}

/// A compared setting (`key=value`) as the launcher takes it.
#[derive(Debug, PartialEq)]
enum Setting<'a> {
    /// A launch-file key: `--set key=value`.
    Key(&'a str),
    /// `env:NAME=value`: an environment variable of the launcher (and so of its nodes).
    Env(&'a str, &'a str),
}

impl<'a> Setting<'a> {
    fn of(setting: &'a str) -> Self {
        match setting
            .strip_prefix("env:")
            .and_then(|kv| kv.split_once('='))
        {
            Some((name, value)) => Setting::Env(name, value),
            None => Setting::Key(setting),
        }
    }
}

/// The launcher of one run: `fiberflow launch FILE --out DIR ARGS --set …`, with the
/// compared setting as one more `--set` or as an environment variable.
fn launcher(
    exe: &Path,
    file: &Path,
    dir: &Path,
    args: &[String],
    sets: &[String],
    setting: Option<&str>,
) -> Command {
    let mut c = Command::new(exe);
    c.arg("launch").arg(file).arg("--out").arg(dir).args(args);
    for s in sets {
        c.arg("--set").arg(s);
    }
    match setting.map(Setting::of) {
        Some(Setting::Key(kv)) => {
            c.arg("--set").arg(kv);
        }
        Some(Setting::Env(name, value)) => {
            c.env(name, value);
        }
        None => {}
    }
    c
}

/// The transports a run can be benchmarked over (`inproc`: every node a thread of the
/// launcher's process, the bus in memory — what the process boundary costs).
const TRANSPORTS: [&str; 3] = ["iceoryx2", "zenoh", "inproc"];

/// The configuration label of a run over two launchers on loopback: zenoh with mutual
/// TLS through the flow node's router, as if on two hosts; its flow-only pair is zenoh's.
pub const TWO_LAUNCHERS: &str = "zenoh, two launchers";

/// The transport whose flow-only runs a configuration is compared with.
fn baseline_of(transport: &str) -> &str {
    if transport == TWO_LAUNCHERS {
        "zenoh"
    } else {
        transport
    }
}

/// One run's figures, seconds.
#[derive(Debug, Clone, Default)]
pub(crate) struct Figures {
    /// Whole process, from start to exit.
    pub(crate) process_s: f64,
    /// CPU time (user + system) of the launcher and every node it ran.
    pub(crate) cpu_s: f64,
    /// CPU time of the flow node, every fibre node and the recorder during the steps
    /// (each from its own timing line).
    pub(crate) nodes_cpu_s: f64,
    /// The flow node's loop, wall clock from its first step to its last (its stages and
    /// what lies between them); from logs without it, the sum of the stages.
    pub(crate) loop_s: f64,
    pub(crate) field_step_s: f64,
    pub(crate) sampling_s: f64,
    /// Flow node encoding + publishing samples, plus the groups' mean encoding +
    /// publishing of states and metrics.
    pub(crate) flow_publish_s: f64,
    pub(crate) group_publish_s: f64,
    /// The groups' mean fibre step.
    pub(crate) fiber_step_s: f64,
    /// The flow node waiting for states (fibre step + transport on the groups' side).
    pub(crate) waiting_s: f64,
    pub(crate) recording_s: f64,
}

/// `key="value"` or `key=value` pairs of a log line.
fn fields(line: &str) -> BTreeMap<String, f64> {
    line.split_whitespace()
        .filter_map(|w| {
            let (k, v) = w.split_once('=')?;
            Some((k.to_string(), v.trim_matches('"').parse().ok()?))
        })
        .collect()
}

/// Reads the per-stage lines every node logged into `<out>/logs/` of each of `outs` (one
/// per launcher of the run).
/// `one_process`: every node ran in one process (`inproc`), so each node's `cpu_s` is the
/// whole process's and the flow node's alone counts (its loop spans the others').
fn read_figures(outs: &[PathBuf], process_s: f64, one_process: bool) -> Result<Figures> {
    let mut f = Figures {
        process_s,
        ..Default::default()
    };
    let mut groups = 0.0;
    let mut entries = Vec::new();
    for out in outs {
        let logs = out.join("logs");
        let dir =
            std::fs::read_dir(&logs).with_context(|| format!("reading {}", logs.display()))?;
        entries.extend(dir.flatten());
    }
    for e in entries {
        let text = std::fs::read_to_string(e.path()).unwrap_or_default();
        // fibre nodes sharing a process (`run.fiber_processes`) share a log, and each
        // one's `cpu_s` is their process's: counted once, the largest
        let mut fiber_process_cpu_s: f64 = 0.0;
        for line in text.lines() {
            let v = fields(line);
            let g = |k: &str| v.get(k).copied().unwrap_or(0.0);
            let flow_line = line.contains("where the flow node's time went");
            let group_line = line.contains("where the group's time went");
            if group_line && !one_process {
                fiber_process_cpu_s = fiber_process_cpu_s.max(g("cpu_s"));
            } else if flow_line || (!one_process && line.contains("time went")) {
                f.nodes_cpu_s += g("cpu_s");
            }
            if flow_line {
                f.field_step_s = g("field_step_s");
                f.sampling_s = g("sampling_s");
                f.flow_publish_s = g("encoding_and_publishing_s");
                f.waiting_s = g("waiting_for_states_s");
                f.loop_s = v
                    .get("loop_s")
                    .copied()
                    .unwrap_or(f.field_step_s + f.sampling_s + f.flow_publish_s + f.waiting_s);
            } else if line.contains("where the group's time went") {
                groups += 1.0;
                f.fiber_step_s += g("fiber_step_s");
                f.group_publish_s += g("encoding_and_publishing_s");
            } else if line.contains("where the recorder's time went") {
                f.recording_s = g("writing_s");
            }
        }
        f.nodes_cpu_s += fiber_process_cpu_s;
    }
    if f.loop_s == 0.0 {
        let dirs: Vec<String> = outs.iter().map(|o| o.display().to_string()).collect();
        bail!("{}: the flow node logged no timing line", dirs.join(", "));
    }
    if groups > 0.0 {
        f.fiber_step_s /= groups;
        f.group_publish_s /= groups;
    }
    Ok(f)
}

pub(crate) fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        return f64::NAN;
    }
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// The steps every run takes: `--steps`, or else the `run.steps` shared by the fibre
/// file and the flow-only file (`files`: each file with its `run.steps`), so that a
/// coupled run and its baseline always run alike.
fn steps_per_run(given: Option<u64>, files: &[(&Path, u64)]) -> Result<u64> {
    if let Some(s) = given {
        return Ok(s);
    }
    let Some(&(first, steps)) = files.first() else {
        bail!("no launch file to take run.steps from: pass --steps");
    };
    if let Some((other, s)) = files.iter().find(|(_, s)| *s != steps) {
        bail!(
            "run.steps is {steps} in {} but {s} in {}: pass --steps, or give both files the same run.steps",
            first.display(),
            other.display()
        );
    }
    Ok(steps)
}

/// The scale benchmark. Long (≈140 lines): its rounds of alternating runs in order (a
/// benchmark harness, not part of the product binary).
pub fn run(o: &BenchOptions) -> Result<()> {
    if o.fibers.iter().any(|n| n % 30 != 0) {
        bail!("--fibers: every count must be a multiple of 30 (six groups of five layers)");
    }
    let mut files = Vec::new();
    for f in [&o.fibers_file, &o.flow_only_file] {
        let (lf, _) = fiberflow_launcher::launchfile::LaunchFile::load_with(f, &[])?;
        files.push((f.as_path(), lf.run.steps));
    }
    let steps = steps_per_run(o.steps, &files)?;
    if steps == 0 || o.repeats == 0 {
        bail!("--steps and --repeats must be >= 1");
    }
    if let Some(t) = o
        .transports
        .iter()
        .find(|t| !TRANSPORTS.contains(&t.as_str()))
    {
        bail!(
            "--transports: {t:?} is not one of {}",
            TRANSPORTS.join(", ")
        );
    }
    let exe = fiberflow_exe()?;
    std::fs::create_dir_all(&o.out).with_context(|| format!("creating {}", o.out.display()))?;
    if o.two_launchers.iter().any(|n| *n == 0 || n % 60 != 0) {
        bail!("--two-launchers: every count must be a positive multiple of 60 (six groups of five layers, two shards)");
    }
    let configs = configurations(o);
    let baselines: BTreeMap<String, String> = configs
        .iter()
        .map(|c| (c.label.clone(), c.baseline.clone()))
        .collect();
    if !o.two_launchers.is_empty() {
        ensure_certificates(&o.two_launchers_file)?;
    }
    let total = configs.len() * o.repeats;
    let bar = fiberflow_launcher::progress::bar(total as u64, "runs");
    let mut results: BTreeMap<(u64, String), Vec<Figures>> = BTreeMap::new();
    let numbered: Vec<(usize, &Config)> = configs.iter().enumerate().collect();
    for r in 0..o.repeats {
        let order = round_order(&numbered, r);
        match o.slice_ms {
            None => {
                for &(i, c) in order {
                    bar.set_message(format!("{} fibres, {}", c.fibers, c.label));
                    let cpu0 = fiberflow_bus::usage::children_cpu_s();
                    let run = start_run(o, &exe, steps, c, i, r)?;
                    let mut failed = None;
                    for mut child in run.launchers {
                        let st = child.wait().context("waiting for fiberflow launch")?;
                        if !st.success() {
                            failed = Some(st);
                        }
                    }
                    let wall = run.t0.elapsed().as_secs_f64();
                    // each launcher waits for its nodes, so their CPU is in its children's
                    // usage
                    let cpu = fiberflow_bus::usage::children_cpu_s() - cpu0;
                    if let Some(st) = failed {
                        bail!(
                            "{} fibres over {} failed ({st}); logs in {}",
                            c.fibers,
                            c.label,
                            run.out.display()
                        );
                    }
                    let mut f = read_figures(&run.dirs, wall, c.transport == "inproc")?;
                    f.cpu_s = cpu;
                    results
                        .entry((c.fibers, c.label.clone()))
                        .or_default()
                        .push(f);
                    bar.inc(1);
                }
            }
            Some(ms) => {
                // each transport's runs (its flow alone and what is compared with it) at
                // once, in turns
                for block in order.chunk_by(|a, b| a.1.baseline == b.1.baseline) {
                    bar.set_message(format!(
                        "{}: {} runs in turns",
                        block[0].1.baseline,
                        block.len()
                    ));
                    let mut started = Vec::new();
                    for &(i, c) in block {
                        started.push((c, start_run(o, &exe, steps, c, *i, r)?));
                    }
                    let mut sliced: Vec<crate::slicing::SlicedRun> = Vec::new();
                    let mut meta = Vec::new();
                    for (c, run) in started {
                        sliced.push(crate::slicing::SlicedRun::new(run.launchers));
                        meta.push((c, run.out, run.dirs));
                    }
                    crate::slicing::run_in_turns(
                        &mut sliced,
                        std::time::Duration::from_millis(ms),
                    )?;
                    if let Some(((c, out, _), s)) =
                        meta.iter().zip(&sliced).find(|(_, s)| s.failed.is_some())
                    {
                        let st = s.failed.map(|st| st.to_string()).unwrap_or_default();
                        bail!(
                            "{} fibres over {} failed ({st}); logs in {}",
                            c.fibers,
                            c.label,
                            out.display()
                        );
                    }
                    for ((c, out, dirs), s) in meta.iter().zip(&sliced) {
                        let path = out.join("pauses.csv");
                        std::fs::write(&path, crate::slicing::pauses_csv(&s.pauses))
                            .with_context(|| format!("writing {}", path.display()))?;
                        let mut f = read_figures(dirs, f64::NAN, c.transport == "inproc")?;
                        f.cpu_s = s.cpu_s;
                        apply_clean_steps(&mut f, dirs, &s.pauses, steps)?;
                        results
                            .entry((c.fibers, c.label.clone()))
                            .or_default()
                            .push(f);
                        bar.inc(1);
                    }
                }
            }
        }
    }
    bar.finish_and_clear();
    let mut table = table(&results, &baselines, steps);
    if let Some(c) = &o.compare {
        table.push('\n');
        table.push_str(&compared_table(&results, &configs, c));
    }
    println!("{table}");
    let path = o.out.join("bench-scale.md");
    std::fs::write(&path, &table).with_context(|| format!("writing {}", path.display()))?;
    println!("written to {}", path.display());
    Ok(())
}

/// A run under way: its folder, its launchers' folders and the launchers.
struct Started {
    out: PathBuf,
    dirs: Vec<PathBuf>,
    launchers: Vec<std::process::Child>,
    t0: Instant,
}

/// The `fiberflow` binary beside this one (`cargo build --release --workspace` builds both).
fn fiberflow_exe() -> Result<PathBuf> {
    let me = std::env::current_exe().context("locating the fiberflow-bench executable")?;
    let exe = me.with_file_name("fiberflow");
    if !exe.is_file() {
        bail!(
            "{} not found: build it beside fiberflow-bench (cargo build --release --workspace)",
            exe.display()
        );
    }
    Ok(exe)
}

/// Starts configuration `c` (number `i`) of round `r`: one launcher, or head and worker.
fn start_run(
    o: &BenchOptions,
    exe: &Path,
    steps: u64,
    c: &Config,
    i: usize,
    r: usize,
) -> Result<Started> {
    let (n, transport) = (&c.fibers, &c.transport);
    let two = transport == TWO_LAUNCHERS;
    let out = o.out.join(if two {
        format!("{n}-two-launchers-{i}-{r}")
    } else {
        format!("{n}-{transport}-{i}-{r}")
    });
    let file = if two {
        &o.two_launchers_file
    } else if *n == 0 {
        &o.flow_only_file
    } else {
        &o.fibers_file
    };
    let sets = run_sets(o.record, steps, c, i, r);
    // (launcher arguments, its output folder): one launcher, or head and worker
    let launchers: Vec<(Vec<String>, PathBuf)> = if two {
        ["head", "worker"]
            .iter()
            .map(|h| {
                let dir = out.join(h);
                (vec!["--host".into(), h.to_string()], dir)
            })
            .collect()
    } else {
        vec![(vec!["--transport".into(), transport.clone()], out.clone())]
    };
    let t0 = Instant::now();
    let mut children = Vec::new();
    for (args, dir) in &launchers {
        let mut cmd = launcher(exe, file, dir, args, &sets, c.setting.as_deref());
        // the launcher's own messages, and with `inproc` every node's timing line, go to
        // its standard error: kept beside the nodes' logs (not named *.log, which a fresh
        // launch clears)
        let logs = dir.join("logs");
        std::fs::create_dir_all(&logs).with_context(|| format!("creating {}", logs.display()))?;
        let stderr_path = logs.join("launcher.stderr");
        let stderr = std::fs::File::create(&stderr_path)
            .with_context(|| format!("creating {}", stderr_path.display()))?;
        let child = cmd
            .stdout(std::process::Stdio::null())
            .stderr(stderr)
            .spawn()
            .context("running fiberflow launch")?;
        children.push(child);
    }
    Ok(Started {
        out,
        dirs: launchers.into_iter().map(|(_, d)| d).collect(),
        launchers: children,
        t0,
    })
}

/// The `--set`s of configuration `c` (number `i`) in round `r`.
fn run_sets(record: bool, steps: u64, c: &Config, i: usize, r: usize) -> Vec<String> {
    let n = c.fibers;
    // a run id of its own: runs alive at once (`--slice-ms`) on one host must not share
    // topics (over iceoryx2 a topic is a service of the host, found by name)
    let id: String = format!("bench-{n}-{}-{i}-{r}", c.transport)
        .chars()
        .map(|ch| {
            if ch.is_ascii_alphanumeric() || ch == '-' {
                ch
            } else {
                '_'
            }
        })
        .collect();
    let mut sets = vec![
        format!("run.id={id}"),
        format!("run.steps={steps}"),
        "run.analyze=false".into(),
        "run.checkpoint_every_plus=0".into(),
    ];
    if n > 0 {
        for g in 1..=6 {
            sets.push(format!("fibers.case{g}.placement.per_layer={}", n / 30));
        }
    }
    if record {
        sets.extend(
            [
                "recorder.enabled=true",
                "recorder.states_every_steps=10",
                "recorder.samples=false",
            ]
            .map(String::from),
        );
    } else {
        sets.push("recorder.enabled=false".into());
    }
    sets
}

/// A time-sliced run's flow-node stages from its per-step times, over the steps no pause
/// touched (scaled to `steps`, as the whole-run figures are); the stages that only the
/// nodes' end-of-run walls give (pauses inflate them) and the process wall become NaN.
fn apply_clean_steps(
    f: &mut Figures,
    dirs: &[PathBuf],
    pauses: &[(u128, u128)],
    steps: u64,
) -> Result<()> {
    let Some(path) = dirs
        .iter()
        .map(|d| d.join("logs").join("flow-steps.csv"))
        .find(|p| p.exists())
    else {
        bail!("no logs/flow-steps.csv in {dirs:?}: the flow node wrote no per-step times");
    };
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    // a signal reaches a process within microseconds; 1 ms either side is ample
    let c = crate::slicing::clean_steps(&text, pauses, 1_000_000)
        .with_context(|| path.display().to_string())?;
    let n = steps as f64;
    f.loop_s = c.wall_s * n;
    f.field_step_s = c.field_step_s * n;
    f.sampling_s = c.sampling_s * n;
    f.waiting_s = c.waiting_s * n;
    f.flow_publish_s = c.publishing_s * n;
    f.fiber_step_s = f64::NAN;
    f.group_publish_s = f64::NAN;
    f.recording_s = f64::NAN;
    f.process_s = f64::NAN;
    Ok(())
}

/// Makes the certificates a two-launcher file names (its `network.root_ca_certificate`
/// and the host certificates beside it) with `launch/multi-host/make-certs.sh` (from the
/// repository root, where the benchmark runs) if the CA is missing.
fn ensure_certificates(file: &Path) -> Result<()> {
    let (lf, _) = fiberflow_launcher::launchfile::LaunchFile::load_with(file, &[])?;
    let Some(network) = lf.network else {
        bail!(
            "{}: a two-launcher file needs a [network] table",
            file.display()
        );
    };
    let ca = &network.root_ca_certificate;
    if ca.exists() {
        return Ok(());
    }
    let certs = ca.parent().unwrap_or(Path::new("."));
    let script = Path::new("launch/multi-host/make-certs.sh");
    let st = Command::new(script)
        .arg(certs)
        .args(["head=localhost", "worker=localhost"])
        .stdout(std::process::Stdio::null())
        .status()
        .with_context(|| format!("running {} (needs openssl)", script.display()))?;
    if !st.success() {
        bail!("{} failed ({st})", script.display());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scale_tables::*;

    /// Runs with these loop times and nothing else.
    fn runs(loop_s: &[f64]) -> Vec<Figures> {
        loop_s
            .iter()
            .map(|&loop_s| Figures {
                loop_s,
                ..Default::default()
            })
            .collect()
    }

    /// Every run of a benchmark has a run id of its own (runs in turns are alive at
    /// once), and a valid one.
    #[test]
    fn runs_have_run_ids_of_their_own() {
        let o = options(&[0, 300], &["iceoryx2", "zenoh"], Some("env:X=1,2"));
        let mut o = o;
        o.two_launchers = vec![600];
        let configs = configurations(&o);
        let mut ids = std::collections::BTreeSet::new();
        for r in 0..2 {
            for (i, c) in configs.iter().enumerate() {
                let sets = run_sets(false, 20, c, i, r);
                let id = sets[0].strip_prefix("run.id=").unwrap().to_string();
                assert!(
                    id.chars()
                        .all(|ch| ch.is_ascii_alphanumeric() || ch == '-' || ch == '_'),
                    "{id}"
                );
                assert!(ids.insert(id.clone()), "{id} twice");
            }
        }
        assert_eq!(ids.len(), 2 * configs.len());
    }

    /// Ratios pair each run with the flow-only run of its own round.
    #[test]
    fn ratios_pair_runs_of_the_same_round() {
        // round by round 1.1, 0.9, 1.02: the medians of the columns (11/10) would say 1.1
        let (m, lo, hi, _) = paired_ratios(&runs(&[11.0, 18.0, 10.2]), &runs(&[10.0, 20.0, 10.0]));
        assert!((m - 1.02).abs() < 1e-12, "median {m}");
        assert!((lo - 0.9).abs() < 1e-12 && (hi - 1.1).abs() < 1e-12);
    }

    /// The serial-coupling column: each run's sampling, handing over and waiting over its
    /// round's flow-only step; stages print with decimals where they are small.
    #[test]
    fn serial_coupling_share_pairs_runs_of_the_same_round() {
        let run = |loop_s, sampling_s, flow_publish_s, waiting_s| Figures {
            loop_s,
            sampling_s,
            flow_publish_s,
            waiting_s,
            ..Default::default()
        };
        // rounds, less the flow alone's 0.01 s of publishing: 0.3 / 10 = 3%,
        // 0.1 / 20 = 0.5%, 0.2 / 10 = 2%
        let coupled = [
            run(10.5, 0.1, 0.11, 0.1),
            run(21.0, 0.05, 0.03, 0.03),
            run(10.3, 0.1, 0.06, 0.05),
        ];
        let alone = [
            run(10.0, 0.0, 0.01, 0.0),
            run(20.0, 0.0, 0.01, 0.0),
            run(10.0, 0.0, 0.01, 0.0),
        ];
        let (m, lo, hi) = paired_serial_share(&coupled, &alone);
        assert!(
            (m - 0.02).abs() < 1e-12 && (lo - 0.005).abs() < 1e-12 && (hi - 0.03).abs() < 1e-12
        );
        let mut results = BTreeMap::new();
        results.insert((0, "iceoryx2".to_string()), alone.to_vec());
        results.insert((300, "iceoryx2".to_string()), coupled.to_vec());
        let md = table(&results, &BTreeMap::new(), 100);
        let row = md.lines().find(|l| l.starts_with("| 300 |")).expect("row");
        // 2.0% (0.5–3.0); sampling 0.1 s / 100 steps = 1.0 ms, waiting 0.5–1 ms
        assert!(row.contains("| 2.0 (0.5–3.0) |"), "{row}");
        assert!(row.contains("| 1.0 | 0.60 | 0.50 |"), "{row}");
        let alone_row = md.lines().find(|l| l.starts_with("| 0 |")).expect("row");
        assert!(alone_row.contains("| 0.0 (0.0–0.0) |"), "{alone_row}");
        assert_eq!(
            md.lines().nth(1).map(|l| l.matches('|').count()),
            row.matches('|').count().into(),
            "as many columns as the header"
        );
        assert_eq!(
            (
                stage_ms(0.423),
                stage_ms(4.23),
                stage_ms(42.34),
                stage_ms(142.3),
                stage_ms(f64::NAN)
            ),
            (
                "0.42".into(),
                "4.2".into(),
                "42.3".into(),
                "142".into(),
                "—".into()
            )
        );
    }

    /// The interval of the median ratio: one point when every round agrees; otherwise
    /// inside the rounds' range, around the median, and narrower with more rounds that
    /// scatter alike.
    #[test]
    fn median_ratio_interval_resamples_the_rounds() {
        let (_, _, _, same) = paired_ratios(&runs(&[1.05; 5]), &runs(&[1.0; 5]));
        assert!((same.lo - 1.05).abs() < 1e-12 && (same.hi - 1.05).abs() < 1e-12);
        let spread = |n: usize| {
            let r: Vec<f64> = (0..n)
                .map(|i| 0.95 + 0.1 * (i % 11) as f64 / 10.0)
                .collect();
            let (m, lo, hi, ci) = paired_ratios(&runs(&r), &runs(&vec![1.0; n]));
            assert!(
                lo <= ci.lo && ci.lo <= m && m <= ci.hi && ci.hi <= hi,
                "{ci:?}"
            );
            ci.hi - ci.lo
        };
        let (few, many) = (spread(11), spread(110));
        assert!(many < 0.6 * few, "{few} {many}");
    }

    /// `--compare`: each compared value's runs over the first value's runs of the same
    /// rounds, per fibre count and transport, with the count of rounds it won; the flow
    /// alone and the first value get no row.
    #[test]
    fn compared_values_pair_round_by_round_with_the_first() {
        let o = options(
            &[0, 300],
            &["iceoryx2", "zenoh"],
            Some("run.fiber_scheduling=idle,normal"),
        );
        let configs = configurations(&o);
        let mut results = BTreeMap::new();
        for c in &configs {
            // four rounds: the coupled runs 5% slower than the flow alone, and normal over
            // idle 0.98, 0.99, 1.01, 0.97 over iceoryx2, 1.02 every round over zenoh (so a
            // table taken against the flow-only runs would read otherwise)
            let walls: Vec<f64> = (0..4)
                .map(|r| {
                    let base = 30.0 + r as f64;
                    let idle = 1.05 * base;
                    match (c.fibers, c.transport.as_str(), c.setting.as_deref()) {
                        (0, _, _) => base,
                        (300, "iceoryx2", Some("run.fiber_scheduling=normal")) => {
                            idle * [0.98, 0.99, 1.01, 0.97][r]
                        }
                        (300, "zenoh", Some("run.fiber_scheduling=normal")) => idle * 1.02,
                        _ => idle,
                    }
                })
                .collect();
            results.insert((c.fibers, c.label.clone()), runs(&walls));
        }
        let md = compared_table(&results, &configs, o.compare.as_ref().unwrap());
        let rows: Vec<&str> = md.lines().skip(2).collect();
        assert_eq!(rows.len(), 2, "{md}");
        assert!(md
            .lines()
            .next()
            .unwrap()
            .contains("over run.fiber_scheduling=idle"));
        assert!(
            rows[0].starts_with(
                "| 300 | iceoryx2, run.fiber_scheduling=normal | 0.985 (0.970–1.010) |"
            ),
            "{}",
            rows[0]
        );
        assert!(rows[0].ends_with("| 3 of 4 |"), "{}", rows[0]);
        assert!(
            rows[1].starts_with(
                "| 300 | zenoh, run.fiber_scheduling=normal | 1.020 (1.020–1.020) | 1.020–1.020 |"
            ),
            "{}",
            rows[1]
        );
        assert!(rows[1].ends_with("| 0 of 4 |"), "{}", rows[1]);
    }

    /// Without `--steps` every run takes the launch files' shared `run.steps` (150 in the
    /// shipped scale files); files that disagree are an error naming both and the key;
    /// `--steps` wins.
    #[test]
    fn runs_take_the_launch_files_steps_unless_told() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../launch/bench");
        let shipped: Vec<(PathBuf, u64)> = ["scale-1e4.toml", "scale-flow-only.toml"]
            .iter()
            .map(|f| {
                let p = dir.join(f);
                let (lf, _) =
                    fiberflow_launcher::launchfile::LaunchFile::load_with(&p, &[]).unwrap();
                (p, lf.run.steps)
            })
            .collect();
        let files: Vec<(&Path, u64)> = shipped.iter().map(|(p, s)| (p.as_path(), *s)).collect();
        assert_eq!(steps_per_run(None, &files).unwrap(), 150);
        assert_eq!(steps_per_run(Some(20), &files).unwrap(), 20);
        let (a, b) = (Path::new("a.toml"), Path::new("b.toml"));
        let e = steps_per_run(None, &[(a, 150), (b, 20)])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("run.steps")
                && e.contains("a.toml")
                && e.contains("b.toml")
                && e.contains("--steps"),
            "{e}"
        );
        assert_eq!(steps_per_run(Some(30), &[(a, 150), (b, 20)]).unwrap(), 30);
    }

    fn options(fibers: &[u64], transports: &[&str], compare: Option<&str>) -> BenchOptions {
        BenchOptions {
            fibers_file: "f.toml".into(),
            flow_only_file: "0.toml".into(),
            fibers: fibers.to_vec(),
            transports: transports.iter().map(|t| t.to_string()).collect(),
            steps: Some(20),
            repeats: 1,
            record: false,
            out: "out".into(),
            two_launchers: vec![],
            two_launchers_file: "two.toml".into(),
            compare: compare.map(|c| c.parse().unwrap()),
            slice_ms: None,
        }
    }

    /// `--compare`: each fibre configuration once per value, in turn; the flow alone once
    /// per transport with the first value, and every run compared with that.
    #[test]
    fn compared_values_run_in_turn_against_one_flow_only_run() {
        let o = options(
            &[0, 300],
            &["iceoryx2", "zenoh"],
            Some("run.fiber_scheduling=idle,normal"),
        );
        let got: Vec<(u64, String, Option<String>, String)> = configurations(&o)
            .into_iter()
            .map(|c| (c.fibers, c.label, c.setting, c.baseline))
            .collect();
        let idle = "run.fiber_scheduling=idle";
        let normal = "run.fiber_scheduling=normal";
        let row = |n, t: &str, s: &str, b: &str| {
            (
                n,
                format!("{t}, {s}"),
                Some(s.to_string()),
                format!("{b}, {idle}"),
            )
        };
        assert_eq!(
            got,
            vec![
                row(0, "iceoryx2", idle, "iceoryx2"),
                row(300, "iceoryx2", idle, "iceoryx2"),
                row(300, "iceoryx2", normal, "iceoryx2"),
                row(0, "zenoh", idle, "zenoh"),
                row(300, "zenoh", idle, "zenoh"),
                row(300, "zenoh", normal, "zenoh"),
            ]
        );
        // without --compare the rows are the transports, as before
        let plain: Vec<String> = configurations(&options(&[0, 300], &["zenoh"], None))
            .into_iter()
            .map(|c| format!("{} {} {}", c.fibers, c.label, c.baseline))
            .collect();
        assert_eq!(plain, ["0 zenoh zenoh", "300 zenoh zenoh"]);
        for bad in [
            "run.fiber_scheduling",
            "=idle",
            "run.fiber_scheduling=idle,",
            "env:=1,2",
            "run.fiber_scheduling=idle,normal,idle",
        ] {
            assert!(bad.parse::<Compare>().is_err(), "{bad}");
        }
        let twice = "env:X=1,2,1".parse::<Compare>().unwrap_err();
        assert!(
            twice.contains("\"1\" is given twice (values 1 and 3)") && twice.contains("env:"),
            "{twice}"
        );
        // an environment variable instead of a launch key
        let env: Vec<Option<String>> = configurations(&options(
            &[0, 300],
            &["zenoh"],
            Some("env:RAYON_NUM_THREADS=2,1"),
        ))
        .into_iter()
        .map(|c| c.setting)
        .collect();
        let settings: Vec<Setting> = env.iter().flatten().map(|s| Setting::of(s)).collect();
        assert_eq!(
            settings,
            [
                Setting::Env("RAYON_NUM_THREADS", "2"),
                Setting::Env("RAYON_NUM_THREADS", "2"),
                Setting::Env("RAYON_NUM_THREADS", "1"),
            ]
        );
        assert_eq!(Setting::of(idle), Setting::Key(idle));
        // … and so the launcher gets a `--set` or an environment variable
        let sets = ["run.steps=20".to_string()];
        let args = |c: &Command| -> Vec<String> {
            c.get_args().map(|a| a.to_string_lossy().into()).collect()
        };
        let envs = |c: &Command| -> Vec<(String, String)> {
            c.get_envs()
                .filter_map(|(k, v)| Some((k.to_str()?.into(), v?.to_str()?.into())))
                .collect()
        };
        let (exe, file, dir) = (Path::new("ff"), Path::new("f.toml"), Path::new("out"));
        let keyed = launcher(exe, file, dir, &[], &sets, Some(idle));
        assert_eq!(
            args(&keyed),
            [
                "launch",
                "f.toml",
                "--out",
                "out",
                "--set",
                "run.steps=20",
                "--set",
                idle
            ]
        );
        assert!(envs(&keyed).is_empty());
        let env = launcher(exe, file, dir, &[], &sets, Some("env:RAYON_NUM_THREADS=1"));
        assert_eq!(
            args(&env),
            ["launch", "f.toml", "--out", "out", "--set", "run.steps=20"]
        );
        assert_eq!(envs(&env), [("RAYON_NUM_THREADS".into(), "1".into())]);
    }

    /// Each transport's flow-only run is followed by the runs compared with it (the
    /// two-launcher runs by zenoh's), and every other round runs the list backwards: a run
    /// and its baseline stay neighbours, and which runs first alternates.
    #[test]
    fn runs_sit_next_to_their_baseline_and_rounds_alternate() {
        let o = BenchOptions {
            two_launchers: vec![600],
            ..options(&[0, 300, 60000], &["iceoryx2", "zenoh", "inproc"], None)
        };
        let configs = configurations(&o);
        let names: Vec<String> = configs
            .iter()
            .map(|c| format!("{} {}", c.fibers, c.label))
            .collect();
        assert_eq!(
            names,
            [
                "0 iceoryx2",
                "300 iceoryx2",
                "60000 iceoryx2",
                "0 zenoh",
                "300 zenoh",
                "60000 zenoh",
                format!("600 {TWO_LAUNCHERS}").as_str(),
                "0 inproc",
                "300 inproc",
                "60000 inproc",
            ]
        );
        // every run after its own baseline's flow-only run and before the next one's
        for (k, c) in configs.iter().enumerate() {
            let base = configs
                .iter()
                .rposition(|b| b.fibers == 0 && b.label == c.baseline)
                .expect("a flow-only run for every baseline");
            assert!(base <= k, "{names:?}");
            assert!(
                configs[base..=k]
                    .iter()
                    .all(|x| x.fibers > 0 || x.label == c.baseline),
                "{names:?}"
            );
        }
        let first: Vec<usize> = round_order(&[1, 2, 3], 0).into_iter().copied().collect();
        let second: Vec<usize> = round_order(&[1, 2, 3], 1).into_iter().copied().collect();
        let third: Vec<usize> = round_order(&[1, 2, 3], 2).into_iter().copied().collect();
        assert_eq!(
            (first, second, third),
            (vec![1, 2, 3], vec![3, 2, 1], vec![1, 2, 3])
        );
    }

    /// A two-launcher run is compared with zenoh's flow-only run of the same round.
    #[test]
    fn two_launchers_pair_with_zenohs_flow_only_runs() {
        let run = |loop_s| Figures {
            loop_s,
            ..Default::default()
        };
        let mut results = BTreeMap::new();
        results.insert((0, "iceoryx2".to_string()), vec![run(1.0)]);
        results.insert((0, "zenoh".to_string()), vec![run(2.0)]);
        results.insert((300, TWO_LAUNCHERS.to_string()), vec![run(3.0)]);
        let o = options(&[0, 300], &["iceoryx2", "zenoh"], None);
        let o = BenchOptions {
            fibers: vec![0],
            two_launchers: vec![300],
            ..o
        };
        let baselines = configurations(&o)
            .into_iter()
            .map(|c| (c.label, c.baseline))
            .collect();
        let md = table(&results, &baselines, 20);
        let row = md
            .lines()
            .find(|l| l.contains(TWO_LAUNCHERS))
            .expect("a row for the two-launcher run");
        assert!(row.contains("| 1.500 (1.500–1.500) |"), "{row}");
    }

    /// The log lines the nodes write, under one launcher's folder or several, are what the
    /// benchmark reads.
    #[test]
    fn reads_the_nodes_timing_lines() {
        let dir = std::env::temp_dir().join(format!("ff-bench-{}", std::process::id()));
        let logs = dir.join("logs");
        std::fs::create_dir_all(&logs).unwrap();
        std::fs::write(
            logs.join("flow.log"),
            "2026-01-01T00:00:00Z  INFO fiberflow_flow::coupling: where the flow node's time went steps=20 waiting_for_states_s=\"1.000\" sampling_s=\"2.000\" encoding_and_publishing_s=\"0.500\" field_step_s=\"4.000\" cpu_s=\"10.000\"\n",
        )
        .unwrap();
        // the second group's node ran under another launcher (a two-launcher run)
        let worker = dir.join("worker");
        std::fs::create_dir_all(worker.join("logs")).unwrap();
        for (g, s, logs) in [
            ("case1", "1.000", logs.clone()),
            ("case2", "3.000", worker.join("logs")),
        ] {
            std::fs::write(
                logs.join(format!("{g}.log")),
                format!("x INFO fiberflow_fiber::serve: where the group's time went steps=20 waiting_for_samples_s=\"9.0\" fiber_step_s=\"{s}\" encoding_and_publishing_s=\"0.250\" cpu_s=\"2.000\"\n"),
            )
            .unwrap();
        }
        std::fs::write(
            logs.join("recorder.log"),
            "x INFO fiberflow::nodes: where the recorder's time went writing_s=\"0.125\" cpu_s=\"0.500\"\n",
        )
        .unwrap();
        let f = read_figures(&[dir.clone(), worker], 12.0, false).unwrap();
        assert_eq!(f.loop_s, 7.5);
        assert_eq!((f.fiber_step_s, f.group_publish_s), (2.0, 0.25));
        assert_eq!((f.recording_s, f.process_s), (0.125, 12.0));
        // the flow node, both groups and the recorder
        assert_eq!(f.nodes_cpu_s, 14.5);
        // a flow node that logs its loop's wall: that, not the sum of the stages, is the
        // step wall (statistics and status lie between the stages)
        std::fs::write(
            logs.join("flow.log"),
            "x INFO fiberflow_flow::coupling: where the flow node's time went steps=20 waiting_for_states_s=\"1.000\" sampling_s=\"2.000\" encoding_and_publishing_s=\"0.500\" field_step_s=\"4.000\" loop_s=\"7.750\" cpu_s=\"10.000\"\n",
        )
        .unwrap();
        let f = read_figures(std::slice::from_ref(&dir), 12.0, false).unwrap();
        assert_eq!((f.loop_s, f.field_step_s), (7.75, 4.0));
        // every node a thread of one process: the flow node's cpu_s (the process's) alone
        let f = read_figures(std::slice::from_ref(&dir), 12.0, true).unwrap();
        assert_eq!(f.nodes_cpu_s, 10.0);
        // two groups in one process (`run.fiber_processes`): one log, each line's cpu_s the
        // process's, counted once (the larger); the stages still average over the groups
        std::fs::remove_file(logs.join("case1.log")).unwrap();
        let line = |g: &str, s: &str, cpu: &str| {
            format!("x INFO fiberflow_fiber::serve: where the group's time went group={g} steps=20 fiber_step_s=\"{s}\" encoding_and_publishing_s=\"0.250\" cpu_s=\"{cpu}\"\n")
        };
        std::fs::write(
            logs.join("fibers-1.log"),
            line("case1", "1.000", "2.000") + &line("case2", "3.000", "2.250"),
        )
        .unwrap();
        let f = read_figures(std::slice::from_ref(&dir), 12.0, false).unwrap();
        assert_eq!(f.nodes_cpu_s, 10.0 + 2.25 + 0.5);
        assert_eq!(f.fiber_step_s, 2.0);
        std::fs::remove_dir_all(&dir).ok();
    }
}
