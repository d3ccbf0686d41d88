//! `fiberflow launch`: runs a whole experiment from a launch file. Owns its children: one
//! process group, SIGINT/SIGTERM forwarded with escalation, per-node logs under the run's
//! folder, the log path printed when a node dies, no orphans.
//!
//! The supervision of the node processes (start, watch, stop, roll back, restart) is
//! [`crate::supervise`]; launch files, checkpoints, node specs and the run lock are in
//! their own modules.

use crate::launchfile::LaunchFile;
use crate::nodes::{run_nodes, NodeSpec};
use crate::progress::t_plus_bar;
use crate::supervise::{checkpoint_watcher, process_spec, processes, supervise_restarts};
use anyhow::{bail, Context, Result};
use fiberflow_bus::{BusHandle, Inbox, Transport};
use fiberflow_messages::topics::Topics;
use fiberflow_messages::FlowStatus;
use fiberflow_messages::NodeRole;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// Result of a launched run.
pub struct LaunchOutcome {
    pub out_dir: PathBuf,
    pub mcap: Option<PathBuf>,
    pub launch: Option<LaunchFile>,
}

/// What `fiberflow launch` was asked for besides the file.
#[derive(Debug, Clone, Default)]
pub struct LaunchOptions {
    pub out: Option<PathBuf>,
    pub transport: Option<Transport>,
    pub host: Option<String>,
    /// `--set KEY=VALUE` overrides.
    pub sets: Vec<String>,
    /// `--resume DIR`: continue the run in DIR from its newest complete checkpoint.
    pub resume: Option<PathBuf>,
}

pub fn launch(file: &Path, opts: LaunchOptions) -> Result<LaunchOutcome> {
    let LaunchOptions {
        out,
        transport,
        host,
        sets,
        resume,
    } = opts;
    if let Some(done) = launch_spinup_file(file, &out, &sets, resume.is_some())? {
        return Ok(done);
    }
    let (lf, text) = LaunchFile::load_with(file, &sets)?;
    let out_dir = run_folder(&lf, resume.as_deref(), out)?;
    // nothing in the folder is touched before its lock is ours: a live run there (a second
    // launch with the same --out, or --resume of a run still going) is refused
    if resume.is_some() && !out_dir.is_dir() {
        bail!("--resume {}: no such run folder", out_dir.display());
    }
    std::fs::create_dir_all(&out_dir).with_context(|| format!("creating {}", out_dir.display()))?;
    let _folder_lock = crate::run_lock::FolderLock::acquire(&out_dir)?;
    let digest = crate::nodes::digest(&text);
    if resume.is_some() {
        same_configuration(&out_dir, &digest)?;
    }
    std::fs::create_dir_all(out_dir.join("logs"))
        .with_context(|| format!("creating {}", out_dir.display()))?;
    std::fs::create_dir_all(out_dir.join("config"))?;
    if lf.flow.spinup.is_some() {
        crate::spinup_cmd::run_config(&lf.flow, &out_dir)?;
        return Ok(LaunchOutcome {
            out_dir,
            mcap: None,
            launch: Some(lf),
        });
    }
    if resume.is_none() {
        // a fresh run: what an earlier run left in this folder is not part of it
        clear_previous_run(&out_dir)?;
    }
    std::fs::write(out_dir.join("launch.toml"), &text)
        .with_context(|| format!("writing {}", out_dir.join("launch.toml").display()))?;
    let transport = transport.unwrap_or(lf.run.transport);
    let stop = Arc::new(AtomicBool::new(false));
    signal_hook::flag::register(signal_hook::consts::SIGINT, stop.clone())?;
    signal_hook::flag::register(signal_hook::consts::SIGTERM, stop.clone())?;
    let nodes = nodes_here(&lf, host.as_deref(), transport)?;
    let records_here = nodes.iter().any(|n| NodeRole::Recorder.is(n));
    let launch_file_name = file
        .file_name()
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or_default();
    let mut base = NodeSpec {
        node: String::new(),
        launch: lf.clone(),
        launch_file_name,
        launch_text: text,
        transport,
        zenoh_listen: vec![],
        zenoh_connect: vec![],
        zenoh_endpoint_file: None,
        co_nodes: vec![],
        host: host.clone(),
        out_dir: out_dir.clone(),
        start_step: 0,
        resume_dir: None,
        segment: 0,
    };
    let role = crate::hosts::Role::of(&base)?;
    let pieces = role.pieces(&nodes);
    if resume.is_some() {
        let next = if crate::hosts::known_complete(&out_dir) {
            for s in crate::coupled::finish_segments(&out_dir)? {
                println!("finished the interrupted segment {}", s.display());
            }
            crate::hosts::Next::Complete
        } else {
            role.roll_back(&mut base, &pieces, &digest, &stop)?
        };
        if next == crate::hosts::Next::Complete {
            crate::hosts::tell_workers_complete(&base, role)?;
            println!(
                "the run in {} is complete: nothing to resume",
                out_dir.display()
            );
            return finish_launch(lf, &out_dir, records_here);
        }
        let segment = if records_here {
            format!(
                " (segment {})",
                fiberflow_messages::segments::segment_name(base.segment)
            )
        } else {
            String::new()
        };
        println!(
            "resuming {} from step {}{segment}",
            out_dir.display(),
            base.start_step
        );
    }
    let _run_lock = iceoryx2_run_lock(transport, &lf.run.id, &stop)?;
    println!(
        "run {} ({} steps, dt+ = {}), transport {transport}, output {}",
        lf.run.id,
        lf.run.steps,
        lf.run.dt_plus,
        out_dir.display()
    );
    for line in crate::loading::describe(&lf, &crate::loading::loading(&lf)?) {
        println!("{line}");
    }
    let watcher = checkpoint_watcher(&base, role, pieces.clone(), digest.clone());
    let interrupted = stop.clone();
    let result = match transport {
        Transport::Inproc => run_inproc(&base, &nodes, stop),
        Transport::Zenoh | Transport::Iceoryx2 => {
            supervise_restarts(&mut base, role, &nodes, &pieces, &digest, stop)
        }
    };
    watcher.stop();
    if result.is_err() && interrupted.load(Ordering::SeqCst) && transport != Transport::Inproc {
        // what was recorded is finished and the checkpoints are kept: say how to go on
        let on_host = host.map(|h| format!(" --host {h}")).unwrap_or_default();
        bail!(
            "interrupted; {} keeps the recording and its checkpoints: continue the run with \
             `fiberflow launch {}{on_host} --resume {}` (and the same --set options)",
            out_dir.display(),
            file.display(),
            out_dir.display()
        );
    }
    result?;
    finish_launch(lf, &out_dir, records_here)
}

/// What a launch ends with once the run is complete: the summary of a recording here.
fn finish_launch(lf: LaunchFile, out_dir: &Path, records_here: bool) -> Result<LaunchOutcome> {
    let mcap = (lf.recorder.enabled && records_here).then(|| out_dir.to_path_buf());
    if let Some(m) = &mcap {
        after_the_run(&lf, m, out_dir)?;
    }
    Ok(LaunchOutcome {
        out_dir: out_dir.to_path_buf(),
        mcap,
        launch: Some(lf),
    })
}

/// Over iceoryx2 the run's topics are services of this host, found by name: a second live
/// run with this id would mix with it, so it waits for the id's lock (`run_lock`).
fn iceoryx2_run_lock(
    transport: Transport,
    id: &str,
    stop: &AtomicBool,
) -> Result<Option<crate::run_lock::RunLock>> {
    Ok(if transport == Transport::Iceoryx2 {
        let id = id.to_string();
        Some(crate::run_lock::RunLock::acquire_in(
            &crate::run_lock::default_dir(),
            &id,
            stop,
            || {
                println!(
                    "waiting: a run with the id {id:?} is live on this host over iceoryx2 \
                     (its topics are the host's; set run.id to run both at once)"
                )
            },
        )?)
    } else {
        None
    })
}

/// A resume must run the configuration the run in `out_dir` was launched with (its
/// `launch.toml`'s digest).
fn same_configuration(out_dir: &Path, digest: &str) -> Result<()> {
    let saved = out_dir.join("launch.toml");
    let before = std::fs::read_to_string(&saved).with_context(|| {
        format!(
            "--resume {}: no launch.toml there (not a run folder?)",
            out_dir.display()
        )
    })?;
    if crate::nodes::digest(&before) != digest {
        bail!(
            "--resume {}: the run was launched with another configuration ({}); pass the same launch file and --set options",
            out_dir.display(),
            saved.display()
        );
    }
    Ok(())
}

/// A spin-up file (only a `[flow]` table with `[flow.spinup]`) runs the spin-up; None for
/// a coupled launch file.
fn launch_spinup_file(
    file: &Path,
    out: &Option<PathBuf>,
    sets: &[String],
    resuming: bool,
) -> Result<Option<LaunchOutcome>> {
    // a spin-up file has only a [flow] table with [flow.spinup]
    let raw =
        std::fs::read_to_string(file).with_context(|| format!("reading {}", file.display()))?;
    let value: toml::Value =
        toml::from_str(&raw).with_context(|| format!("parsing {}", file.display()))?;
    if value.get("run").is_none() && value.get("flow").and_then(|f| f.get("spinup")).is_some() {
        if !sets.is_empty() || resuming {
            bail!("--set and --resume are for coupled launch files, not spin-up files");
        }
        let stem = file
            .file_stem()
            .map(|s| s.to_string_lossy().to_string())
            .unwrap_or_else(|| "spinup".into());
        let out = out
            .clone()
            .unwrap_or_else(|| PathBuf::from("recordings").join(stem));
        crate::spinup_cmd::run(file, &out)?;
        return Ok(Some(LaunchOutcome {
            out_dir: out,
            mcap: None,
            launch: None,
        }));
    }
    Ok(None)
}

/// The run folder: `--resume DIR`, `--out DIR` (they must agree), or `recordings/<run id>`.
fn run_folder(lf: &LaunchFile, resume: Option<&Path>, out: Option<PathBuf>) -> Result<PathBuf> {
    Ok(match (resume, out) {
        (Some(r), Some(o)) if r != o.as_path() => bail!(
            "--resume {} and --out {} name different folders",
            r.display(),
            o.display()
        ),
        (Some(r), _) => r.to_path_buf(),
        (None, o) => o.unwrap_or_else(|| PathBuf::from("recordings").join(lf.run.default_folder())),
    })
}

/// The nodes this launcher runs: the flow node, every fibre node and the recorder, or a
/// multi-host launch file's share for `--host`.
fn nodes_here(lf: &LaunchFile, host: Option<&str>, transport: Transport) -> Result<Vec<String>> {
    let mut nodes = vec!["flow".to_string()];
    nodes.extend(lf.fiber_nodes()?);
    if lf.recorder.enabled {
        nodes.push("recorder".into());
    }
    match (&lf.network, host) {
        (Some(net), None) => bail!(
            "this launch file spans several hosts ({}): pass --host NAME",
            net.host_names()
        ),
        (Some(_), Some(h)) => {
            if transport != Transport::Zenoh {
                bail!("multi-host runs use zenoh (got --transport {transport})");
            }
            let mine = &lf.host(h)?.nodes;
            nodes.retain(|n| mine.contains(n));
        }
        (None, Some(_)) => bail!("--host is only for launch files with a [network] section"),
        (None, None) => {}
    }
    Ok(nodes)
}

/// After the run: names the recording's segments, and with `run.analyze` writes the
/// analysis (two-way: what the fibres did to the flow) and the Rerun scene.
fn after_the_run(lf: &LaunchFile, m: &Path, out_dir: &Path) -> Result<()> {
    let segs = fiberflow_messages::segments::segment_paths(m)?;
    let names: Vec<String> = segs
        .iter()
        .filter_map(|p| p.file_name().map(|n| n.to_string_lossy().to_string()))
        .collect();
    println!("recording: {} ({})", m.display(), names.join(", "));
    if lf.run.analyze {
        let table = crate::analyze::fibers(
            m,
            &out_dir.join("analysis"),
            &fiberflow_analysis::coiling::DEFAULT_THRESHOLDS,
        )?;
        println!("{table}");
        // two-way: what the fibres did to the flow (against nothing: `fiberflow analyze
        // --unladen` compares with another run)
        if lf.run.coupling == crate::launchfile::Coupling::TwoWay {
            if let Some(md) = crate::analyze::modulation(
                std::slice::from_ref(&m.to_path_buf()),
                &[],
                0.0,
                10,
                &out_dir.join("analysis"),
            )? {
                println!("{md}");
            }
        }
        let rrd = out_dir.join("run.rrd");
        let s = fiberflow_viewer::view(
            m,
            &fiberflow_viewer::Sink::Save(rrd.clone()),
            &fiberflow_viewer::ViewOptions::default(),
        )
        .with_context(|| format!("writing {}", rrd.display()))?;
        println!(
            "Rerun scene: {} ({} of {} fibres shown, {} coiling events, {} flow slices; rerun {})",
            rrd.display(),
            s.shown,
            s.fibers,
            s.events,
            s.slices,
            rrd.display()
        );
    }
    Ok(())
}

/// Progress bar fed by flow status messages.
pub(crate) fn progress_thread(
    bus: BusHandle,
    lf: &LaunchFile,
    finished: Arc<AtomicBool>,
) -> Result<std::thread::JoinHandle<()>> {
    let t = Topics::new(&lf.run.id);
    let mut inbox = Inbox::new(bus.subscribe(&t.flow_status())?);
    let total = lf.run.steps as f64 * lf.run.dt_plus;
    Ok(std::thread::spawn(move || {
        // the session must outlive the subscription: a zenoh session closed here would
        // leave the other peers trying to reach a vanished peer (and the bar without data)
        let _bus = bus;
        let pb = t_plus_bar(total);
        while !finished.load(Ordering::SeqCst) {
            if let Some((_, s)) = inbox.recv::<FlowStatus>(Duration::from_millis(100)) {
                pb.set_position((s.t_plus * 100.0) as u64);
                let re = if s.re_tau.is_finite() && s.re_tau > 0.0 {
                    format!(" Re_tau {:.1}", s.re_tau)
                } else {
                    String::new()
                };
                pb.set_message(format!("{:.2} / {:.1}{re}", s.t_plus, total));
            }
        }
        pb.finish();
    }))
}

fn run_inproc(base: &NodeSpec, nodes: &[String], stop: Arc<AtomicBool>) -> Result<()> {
    let bus: BusHandle = Arc::new(fiberflow_bus::inproc::InprocBus::new());
    run_inproc_on(bus, base, nodes, stop)
}

/// Runs `nodes` as threads of this process on `bus`, grouped as the node processes of
/// a launch would be (`run.fiber_processes`: the fibre nodes of one group stepped in
/// turn on one thread).
fn run_inproc_on(
    bus: BusHandle,
    base: &NodeSpec,
    nodes: &[String],
    stop: Arc<AtomicBool>,
) -> Result<()> {
    let finished = Arc::new(AtomicBool::new(false));
    let prog = progress_thread(bus.clone(), &base.launch, finished.clone())?;
    let mut handles = Vec::new();
    let (done_tx, done_rx) = std::sync::mpsc::channel();
    for (n, members) in processes(nodes, base.launch.run.fiber_processes) {
        let spec = process_spec(base, &members);
        let (bus, stop, done) = (bus.clone(), stop.clone(), done_tx.clone());
        handles.push(
            std::thread::Builder::new()
                .name(format!("node-{n}"))
                .spawn(move || {
                    // a panic is this process's failure at once, like an error
                    let what = format!("node process {}", spec.node);
                    let r = crate::panics::catching(&what, || run_nodes(&spec, bus, stop.clone()));
                    if r.is_err() {
                        // the others' waits end at once (not after the step timeout)
                        stop.store(true, Ordering::SeqCst);
                    }
                    let _ = done.send(r);
                })?,
        );
    }
    drop(done_tx);
    let mut failure = None;
    let mut ended = 0;
    while let Ok(r) = done_rx.recv() {
        ended += 1;
        if let Err(e) = r {
            // the first failure stops the others that watch for it (the recorder closes
            // its file), as the launcher stops a failed run's processes; the error names
            // its node
            stop.store(true, Ordering::SeqCst);
            failure = failure.or(Some(format!("{e:#}")));
        }
    }
    if ended < handles.len() {
        failure = failure.or(Some("a node thread panicked".to_string()));
    }
    for h in handles {
        let _ = h.join();
    }
    finished.store(true, Ordering::SeqCst);
    let _ = prog.join();
    if let Some(f) = failure {
        bail!(f);
    }
    Ok(())
}

/// Removes what an earlier run left in `out_dir`: its later recording segments, its
/// checkpoints and its node logs (`run.mcap` itself is rewritten by the recorder). The
/// logs go because a node appends to its log (a restarted node's lines follow those of
/// the one that died), so a fresh run would otherwise carry an unrelated run's lines,
/// and `bench-scale`, which sums every timing line, would count both (the flow node's
/// per-step times go too: they describe the run that wrote them).
fn clear_previous_run(out_dir: &Path) -> Result<()> {
    if let Ok(logs) = std::fs::read_dir(out_dir.join("logs")) {
        for e in logs.flatten() {
            let p = e.path();
            if p.extension().is_some_and(|x| x == "log")
                || p.ends_with("flow-steps.csv")
                || p.ends_with(crate::hosts::RUN_COMPLETE_MARKER)
            {
                std::fs::remove_file(&p).with_context(|| format!("removing {}", p.display()))?;
            }
        }
    }
    if let Ok(segs) = fiberflow_messages::segments::segment_paths(out_dir) {
        for s in segs.iter().filter(|p| !p.ends_with("run.mcap")) {
            std::fs::remove_file(s).with_context(|| format!("removing {}", s.display()))?;
        }
    }
    let ck = fiberflow_messages::checkpoints::root(out_dir);
    if ck.exists() {
        std::fs::remove_dir_all(&ck).with_context(|| format!("removing {}", ck.display()))?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use fiberflow_bus::lossy::LossyBus;
    use std::collections::BTreeMap;

    fn run_on(bus: BusHandle, out: &Path) -> BTreeMap<(String, u64), Vec<u8>> {
        recorded_states(&run_launch_on(bus, out))
    }

    /// Every recorded state by (topic, step); panics on a lean one (never recorded).
    fn recorded_states(mcap_bytes: &[u8]) -> BTreeMap<(String, u64), Vec<u8>> {
        recorded(mcap_bytes, "/state")
            .into_iter()
            .map(|(topic, bytes)| {
                let s: fiberflow_messages::FiberGroupState =
                    fiberflow_messages::decode(&bytes).unwrap();
                assert!(!s.is_lean(), "a lean state was recorded");
                ((topic, s.step), bytes)
            })
            .collect()
    }

    /// Every recorded message on a topic ending in `suffix`, in log order.
    fn recorded(mcap_bytes: &[u8], suffix: &str) -> Vec<(String, Vec<u8>)> {
        mcap::MessageStream::new(mcap_bytes)
            .unwrap()
            .map(|m| m.unwrap())
            .filter(|m| m.channel.topic.ends_with(suffix))
            .map(|m| (m.channel.topic.clone(), m.data.to_vec()))
            .collect()
    }

    /// Runs the 30-step analytic-shear launch on `bus`; returns the recording's bytes.
    fn run_launch_on(bus: BusHandle, out: &Path) -> Vec<u8> {
        run_launch_with(bus, out, &[])
    }

    /// The same with more `--set` overrides.
    fn run_launch_with(bus: BusHandle, out: &Path, sets: &[&str]) -> Vec<u8> {
        let file = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../launch/validation/analytic-shear.toml");
        let mut all = vec!["run.steps=30".to_string()];
        all.extend(sets.iter().map(|s| s.to_string()));
        let (lf, text) = LaunchFile::load_with(&file, &all).unwrap();
        std::fs::create_dir_all(out.join("config")).unwrap();
        let base = NodeSpec::inproc(lf.clone(), text, out.to_path_buf());
        let mut nodes = vec!["flow".to_string()];
        nodes.extend(lf.fiber_nodes().unwrap());
        nodes.push("recorder".into());
        run_inproc_on(bus, &base, &nodes, Arc::new(AtomicBool::new(false))).unwrap();
        std::fs::read(out.join("run.mcap")).unwrap()
    }

    /// A bus whose publishes on one topic fail after the first `after` (a node whose
    /// transport broke: it returns an error mid-run), after hanging for `hang` (a node
    /// whose loop is stuck in a call while its process lives).
    struct BreaksAfter {
        inner: BusHandle,
        topic: String,
        after: usize,
        hang: std::time::Duration,
        count: std::sync::atomic::AtomicUsize,
    }

    impl fiberflow_bus::Bus for BreaksAfter {
        fn publish(&self, topic: &str, payload: &[u8]) -> Result<(), fiberflow_bus::BusError> {
            if topic == self.topic && self.count.fetch_add(1, Ordering::SeqCst) >= self.after {
                std::thread::sleep(self.hang);
                return Err(fiberflow_bus::BusError::Transport(
                    "broken on purpose".into(),
                ));
            }
            self.inner.publish(topic, payload)
        }
        fn subscribe(
            &self,
            pattern: &str,
        ) -> Result<fiberflow_bus::Subscription, fiberflow_bus::BusError> {
            self.inner.subscribe(pattern)
        }
        fn name(&self) -> &'static str {
            "breaks-after"
        }
    }

    /// The analytic-shear launch in process with `sets` (a 60 s step timeout, 4000 steps,
    /// no recorder) on a bus whose 21st publish of `stiff`'s state hangs for `hang` and
    /// then fails; returns the run's error and how long it took.
    fn breaking_run(name: &str, sets: &[&str], hang: std::time::Duration) -> (String, f64) {
        let dir = std::env::temp_dir().join(format!("ff-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(dir.join("config")).unwrap();
        let file = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../launch/validation/analytic-shear.toml");
        let sets: Vec<String> = [
            "run.steps=4000",
            "run.step_timeout_s=60",
            "recorder.enabled=false",
        ]
        .iter()
        .chain(sets)
        .map(|s| s.to_string())
        .collect();
        let (lf, text) = LaunchFile::load_with(&file, &sets).unwrap();
        let base = NodeSpec::inproc(lf.clone(), text, dir.clone());
        let bus: BusHandle = Arc::new(BreaksAfter {
            inner: Arc::new(fiberflow_bus::inproc::InprocBus::new()),
            topic: fiberflow_messages::topics::Topics::new(&lf.run.id).fiber_state("stiff"),
            after: 20,
            hang,
            count: Default::default(),
        });
        let mut nodes = vec!["flow".to_string()];
        nodes.extend(lf.fiber_nodes().unwrap());
        let t0 = std::time::Instant::now();
        let r = run_inproc_on(bus, &base, &nodes, Arc::new(AtomicBool::new(false)));
        let e = format!("{:#}", r.expect_err("the run fails"));
        std::fs::remove_dir_all(&dir).ok();
        (e, t0.elapsed().as_secs_f64())
    }

    /// An in-process run (analytic shear, step timeout 60 s) whose fibre node `stiff`
    /// fails at its 21st state: the run ends within seconds with its error, not after the
    /// other nodes' step timeout (the launcher's stop flag ends the flow and fibre nodes'
    /// waits).
    #[test]
    fn a_failed_in_process_run_stops_at_once() {
        let (e, took_s) = breaking_run("inproc-fail", &[], std::time::Duration::ZERO);
        assert!(
            e.contains("stiff") && e.contains("broken on purpose"),
            "{e}"
        );
        assert!(took_s < 15.0, "took {took_s:.1} s");
    }

    /// An in-process run whose fibre nodes' loop hangs (stuck for 15 s in a publish of
    /// `stiff`'s state at its 21st step) while the process and its pulse thread live: the
    /// loop stops stamping its watch, the pulse stops, and the flow node finds the nodes
    /// silent after `run.liveness_s` (3 s) and ends the run naming them — before, the pulse
    /// beat on and the run waited for the stuck call.
    #[test]
    fn a_fiber_node_whose_loop_hangs_is_found_silent() {
        let (e, _) = breaking_run(
            "inproc-hang",
            &["run.liveness_s=3"],
            std::time::Duration::from_secs(15),
        );
        assert!(e.contains("silent") && e.contains("stiff"), "{e}");
    }

    /// A recorder that takes 4 ms over every message (a slow disk) holds the run back
    /// instead of letting messages pile up in its queue: the flow node keeps at most
    /// `RECORDER_LAG_STEPS` steps ahead of it, so the recorder's queue never holds more than
    /// a few steps' messages (without the hold the analytic run, thousands of steps a
    /// second, would leave all of them waiting), and every state is recorded.
    #[test]
    fn a_slow_recorder_slows_the_run_and_its_queue_stays_short() {
        use fiberflow_messages::lifecycle::RECORDER_LAG_STEPS;
        let dir = std::env::temp_dir().join(format!("ff-slow-rec-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(dir.join("config")).unwrap();
        let file = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../launch/validation/analytic-shear.toml");
        let steps = 60;
        let (lf, text) = LaunchFile::load_with(&file, &[format!("run.steps={steps}")]).unwrap();
        let base = NodeSpec::inproc(lf.clone(), text, dir.clone());
        let bus: BusHandle = Arc::new(fiberflow_bus::inproc::InprocBus::new());
        let slow = Arc::new(fiberflow_bus::slow::SlowBus::new(
            bus.clone(),
            std::time::Duration::from_millis(4),
        ));
        let recorder = {
            let (slow, base): (BusHandle, _) = (slow.clone(), base.clone());
            std::thread::spawn(move || {
                run_inproc_on(
                    slow,
                    &base,
                    &["recorder".to_string()],
                    Arc::new(AtomicBool::new(false)),
                )
            })
        };
        let mut nodes = vec!["flow".to_string()];
        nodes.extend(lf.fiber_nodes().unwrap());
        run_inproc_on(bus, &base, &nodes, Arc::new(AtomicBool::new(false))).unwrap();
        recorder.join().unwrap().unwrap();
        let bytes = std::fs::read(dir.join("run.mcap")).unwrap();
        let states = recorded_states(&bytes);
        assert_eq!(
            states.len(),
            2 * (steps as usize + 1),
            "two groups, steps 0..={steps}"
        );
        let all = recorded(&bytes, "");
        let per_step = all.len() as f64 / steps as f64;
        let deepest = slow.deepest_backlog();
        eprintln!(
            "{} messages recorded ({per_step:.1} per step); deepest queue {deepest}",
            all.len()
        );
        assert!(
            deepest as f64 <= (RECORDER_LAG_STEPS + 3) as f64 * per_step,
            "the recorder's queue held {deepest} messages, {per_step:.1} per step"
        );
        std::fs::remove_dir_all(&dir).ok();
    }

    /// A fresh run in a used folder starts with empty logs, checkpoints and segments;
    /// other files stay.
    #[test]
    fn a_fresh_run_clears_what_an_earlier_run_left() {
        let dir = std::env::temp_dir().join(format!("ff-clear-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(dir.join("logs")).unwrap();
        std::fs::write(dir.join("logs/flow.log"), "old timing line\n").unwrap();
        std::fs::write(dir.join("logs/notes.txt"), "mine").unwrap();
        std::fs::write(dir.join("logs/flow-steps.csv"), "old steps\n").unwrap();
        let ck = fiberflow_messages::checkpoints::root(&dir);
        std::fs::create_dir_all(ck.join("step-10")).unwrap();
        clear_previous_run(&dir).unwrap();
        assert!(!dir.join("logs/flow.log").exists(), "old log left");
        assert!(
            !dir.join("logs/flow-steps.csv").exists(),
            "old per-step times left"
        );
        assert!(!ck.exists(), "old checkpoints left");
        assert!(
            dir.join("logs/notes.txt").exists(),
            "a non-log file removed"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// The flow node's DONE is lost in transit: the flow node, hearing nothing from the
    /// recorder, sends it again; the recorder records it and confirms (FINISHING), so the
    /// run ends on the DONE and not on the recorder's no-DONE fallback.
    #[test]
    fn a_lost_done_is_sent_again_until_the_recorder_confirms() {
        use fiberflow_messages::{Heartbeat, Lifecycle};
        let dir = std::env::temp_dir().join(format!("ff-lost-done-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let is_done = |b: &[u8]| {
            fiberflow_messages::decode::<Heartbeat>(b).is_ok_and(|h| h.state == Lifecycle::Done)
        };
        let lossy = Arc::new(LossyBus::first_matching(
            Arc::new(fiberflow_bus::inproc::InprocBus::new()),
            "/heartbeat/flow",
            is_done,
        ));
        let bytes = run_launch_on(lossy.clone(), &dir);
        assert_eq!(lossy.lost().len(), 1, "{:?}", lossy.lost());
        let beats = |node: &str, state: Lifecycle| {
            recorded(&bytes, &format!("/heartbeat/{node}"))
                .iter()
                .map(|(_, b)| fiberflow_messages::decode::<Heartbeat>(b).unwrap())
                .filter(|h| h.state == state && h.step == 30)
                .count()
        };
        assert_eq!(
            beats("flow", Lifecycle::Done),
            1,
            "the resent DONE is recorded"
        );
        assert!(
            beats("recorder", Lifecycle::Finishing) >= 1,
            "and confirmed"
        );
        std::fs::remove_dir_all(&dir).ok();
    }

    /// With `recorder.states_every_steps = 4` the fibre nodes send lean states (centres only)
    /// at the other steps (and complete ones at the recorded steps, counted on the bus):
    /// the run is the same bit for bit — the recorded states of steps 0, 4, …, 28 and the
    /// last (30) are those of the run with every state complete.
    #[test]
    fn lean_states_between_recorded_steps_change_no_bit() {
        let dir = std::env::temp_dir().join(format!("ff-lean-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let all = run_on(
            Arc::new(fiberflow_bus::inproc::InprocBus::new()),
            &dir.join("all"),
        );
        let bus: BusHandle = Arc::new(fiberflow_bus::inproc::InprocBus::new());
        let mut sent =
            fiberflow_bus::Inbox::new(bus.subscribe("fiberflow/analytic-shear/fibers/**").unwrap());
        let bytes = run_launch_with(bus, &dir.join("lean"), &["recorder.states_every_steps=4"]);
        let (mut lean_sent, mut full_sent) = (0, 0);
        while let Some((topic, b)) = sent.recv_raw(std::time::Duration::ZERO) {
            if topic.ends_with("/state") {
                let s: fiberflow_messages::FiberGroupState =
                    fiberflow_messages::decode(&b).unwrap();
                let kept = s.step.is_multiple_of(4) || s.step == 30;
                assert_eq!(s.is_lean(), !kept, "step {}", s.step);
                if s.is_lean() {
                    lean_sent += 1;
                } else {
                    full_sent += 1;
                }
            }
        }
        // step 0 goes out twice (again with the fluid's velocity, a fluid-velocity start)
        assert_eq!((lean_sent, full_sent), (2 * 22, 2 * 10));
        let lean = recorded_states(&bytes);
        let want: BTreeMap<_, _> = all
            .into_iter()
            .filter(|((_, k), _)| k % 4 == 0 || *k == 30)
            .collect();
        assert_eq!(want.len(), 2 * 9, "two groups, steps 0, 4, …, 28, 30");
        assert!(lean == want, "recorded states differ");
        std::fs::remove_dir_all(&dir).ok();
    }

    /// Two losses of the same node's samples with a 12 s step timeout: the first is
    /// repaired by a resend after 5 s; that long wait must not push the next resend
    /// deadline past the timeout (it did: three times the longest wait, 15 s), so the
    /// second loss is repaired too and the run ends with a lossless run's states.
    #[test]
    fn a_repaired_loss_does_not_delay_the_next_resend() {
        let lost = repaired_run(
            "lossy2",
            &[("/flow/samples/case1", 5), ("/flow/samples/case1", 12)],
            &["run.step_timeout_s=12"],
        );
        assert_eq!(lost.len(), 2, "{lost:?}");
    }

    /// The two fibre nodes stepped in turn on one thread (`run.fiber_processes = 1`, as
    /// the scale launches run them) and the second one's state lost (its 10th, step 8):
    /// the flow node answers no node before it holds every state, so the first node's
    /// samples never come; when they are late it sends the later node's state again with
    /// its own, and the run ends with the states of a lossless run, bit for bit. (Before,
    /// only the waiting node's own state went out again, and the run stopped at its step
    /// timeout, as a paper-size benchmark over zenoh once did.)
    #[test]
    fn a_lost_state_of_a_node_stepped_later_on_its_thread_is_sent_again() {
        let lost = repaired_run(
            "lossy-turn",
            &[("/fibers/stiff/state", 10)],
            &["run.fiber_processes=1", "run.step_timeout_s=12"],
        );
        assert_eq!(lost, ["fiberflow/analytic-shear/fibers/stiff/state"]);
    }

    /// A transport that loses a fibre node's samples (step 4 of `case1`) and a state
    /// (step 9 of `stiff`): the waiting node sends its state again and says it waits, the
    /// flow node sends the samples again, and the run ends with the states of a lossless
    /// run, bit for bit, every step recorded.
    #[test]
    fn lost_samples_and_states_are_sent_again() {
        let lost = repaired_run(
            "lossy",
            &[("/flow/samples/case1", 5), ("/fibers/stiff/state", 10)],
            &[],
        );
        assert_eq!(lost.len(), 2, "{lost:?}");
    }

    /// Runs the launch on a lossless bus and again on one that loses `losses`, with
    /// `sets`; asserts that the lossy run recorded the lossless run's states bit for bit
    /// (two groups, steps 0..=30), and returns the topics of what was lost.
    fn repaired_run(tag: &str, losses: &[(&str, usize)], sets: &[&str]) -> Vec<String> {
        let dir = std::env::temp_dir().join(format!("ff-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let clean = run_on(
            Arc::new(fiberflow_bus::inproc::InprocBus::new()),
            &dir.join("clean"),
        );
        let lossy = Arc::new(LossyBus::new(
            Arc::new(fiberflow_bus::inproc::InprocBus::new()),
            losses,
        ));
        let bytes = run_launch_with(lossy.clone(), &dir.join("lossy"), sets);
        let repaired = recorded_states(&bytes);
        assert_eq!(clean.len(), 2 * 31, "two groups, steps 0..=30");
        assert!(clean == repaired, "states differ after the resends");
        std::fs::remove_dir_all(&dir).ok();
        lossy.lost()
    }

    /// Contact across two shards of 3000 fibres on a transport that loses shard 1's free
    /// step of step 4 and its part of the solve of step 9: the waiting piece sends its free
    /// step again, the first piece answers it with the part again (or sends its parts
    /// again while it waits for samples), and the run records the lossless run's states,
    /// bit for bit, every step of both shards.
    #[test]
    fn lost_contact_messages_are_sent_again() {
        let dir = std::env::temp_dir().join(format!("ff-lossy-contact-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let sets = [
            "fibers.stiff.contact={ friction = 0.5 }",
            "fibers.stiff.shards=2",
            "fibers.stiff.placement={ kind = \"random\", count = 3000, seed = 3, band_plus = [130.0, 170.0] }",
        ];
        let by_piece = |bytes: &[u8]| -> BTreeMap<(String, u64, u32), Vec<u8>> {
            recorded(bytes, "/state")
                .into_iter()
                .map(|(topic, b)| {
                    let s: fiberflow_messages::FiberGroupState =
                        fiberflow_messages::decode(&b).unwrap();
                    ((topic, s.step, s.first_fiber), b)
                })
                .collect()
        };
        let clean = by_piece(&run_launch_with(
            Arc::new(fiberflow_bus::inproc::InprocBus::new()),
            &dir.join("clean"),
            &sets,
        ));
        let lossy = Arc::new(LossyBus::new(
            Arc::new(fiberflow_bus::inproc::InprocBus::new()),
            &[
                ("/contact/stiff/1500", 5),
                ("/contact/stiff/1500/solved", 10),
            ],
        ));
        let repaired = by_piece(&run_launch_with(lossy.clone(), &dir.join("lossy"), &sets));
        assert_eq!(
            clean.len(),
            31 * 3,
            "case1 and two shards of stiff, steps 0..=30"
        );
        assert!(clean == repaired, "states differ after the resends");
        assert_eq!(
            lossy.lost(),
            [
                "fiberflow/analytic-shear/contact/stiff/1500",
                "fiberflow/analytic-shear/contact/stiff/1500/solved"
            ]
        );
        std::fs::remove_dir_all(&dir).ok();
    }
}
