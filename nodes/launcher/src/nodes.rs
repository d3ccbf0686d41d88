//! `fiberflow node`: runs one node (flow, fiber group, recorder) on a bus. The launcher
//! calls the same function in threads (inproc) or in child processes (zenoh).

use crate::launchfile::{FiberScheduling, LaunchFile};
use anyhow::{bail, Context, Result};
use fiberflow_bus::zenoh_bus::{AccessControl, TlsFiles, ZenohBus, ZenohMode, ZenohSettings};
use fiberflow_bus::{inproc::InprocBus, BusHandle, Inbox, Transport};
use fiberflow_flow::serve::RunInfo;
use fiberflow_messages::Lifecycle;
use fiberflow_messages::{NodeRole, FLOW_NODE, RECORDER_NODE};
use fiberflow_recorder::RunMetadata;
use serde::{Deserialize, Serialize};
use sha2::Digest;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

/// Everything a node process needs (written by the launcher as `<out>/config/<node>.toml`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct NodeSpec {
    /// "flow", "recorder", or a fibre group name.
    pub node: String,
    /// Further fibre nodes this process runs, as threads on the same bus
    /// (`run.fiber_processes`).
    #[serde(default)]
    pub co_nodes: Vec<String>,
    pub launch: LaunchFile,
    pub launch_file_name: String,
    pub launch_text: String,
    pub transport: Transport,
    #[serde(default)]
    pub zenoh_listen: Vec<String>,
    #[serde(default)]
    pub zenoh_connect: Vec<String>,
    /// Where this node writes the endpoint its zenoh session got (the flow node of a
    /// loopback run listens on port 0; the launcher reads the port here and hands it to
    /// the other nodes, so no port is ever chosen and then released).
    #[serde(default)]
    pub zenoh_endpoint_file: Option<PathBuf>,
    /// Multi-host runs: the `[[network.hosts]]` entry this node runs on.
    #[serde(default)]
    pub host: Option<String>,
    pub out_dir: PathBuf,
    /// First coupling step: 0, or the checkpoint step the run resumes from.
    #[serde(default)]
    pub start_step: u64,
    /// The checkpoint folder to resume from (its step is `start_step`).
    #[serde(default)]
    pub resume_dir: Option<PathBuf>,
    /// The recorder's segment: 0 writes `run.mcap`, n writes `run-n.mcap` after the
    /// earlier segments.
    #[serde(default)]
    pub segment: u32,
}

impl NodeSpec {
    /// A spec for the in-process bus, no node named yet, starting at step 0 (tests).
    #[cfg(test)]
    pub(crate) fn inproc(launch: LaunchFile, launch_text: String, out_dir: PathBuf) -> Self {
        Self {
            node: String::new(),
            co_nodes: vec![],
            launch,
            launch_file_name: "analytic-shear.toml".into(),
            launch_text,
            transport: Transport::Inproc,
            zenoh_listen: vec![],
            zenoh_connect: vec![],
            zenoh_endpoint_file: None,
            host: None,
            out_dir,
            start_step: 0,
            resume_dir: None,
            segment: 0,
        }
    }

    /// Where this run's coupled checkpoints go (None: checkpoints are off).
    pub fn checkpoint_root(&self) -> Option<PathBuf> {
        (self.launch.run.checkpoint_every_steps() > 0)
            .then(|| fiberflow_messages::checkpoints::root(&self.out_dir))
    }
}

/// Every topic a run uses (iceoryx2 has no wildcard subscriptions).
pub fn run_topics(lf: &LaunchFile) -> Vec<String> {
    let t = fiberflow_messages::topics::Topics::new(&lf.run.id);
    let mut v = vec![t.announce(), t.flow_status(), t.flow_profiles()];
    for name in fiberflow_messages::topics::FLOW_SLICE_NAMES {
        v.push(t.flow_slice(name));
    }
    for n in [FLOW_NODE, RECORDER_NODE, "launcher"] {
        v.push(t.heartbeat(n));
    }
    for g in lf.groups() {
        v.push(t.fiber_state(&g));
        v.push(t.fiber_metrics(&g));
    }
    // a launch file that does not build has no fibre nodes to open topics for (the
    // launcher refuses it before any node starts)
    for p in lf.pieces().unwrap_or_default() {
        v.push(t.heartbeat(&p.node()));
        v.push(p.samples_topic(&t));
        // the pieces that touch exchange their free steps and the parts of the contact
        // solve: shards of a group with contact, groups of a suspension
        let contact = lf
            .fibers
            .iter()
            .any(|f| f.group == p.group && f.contact.is_some());
        let in_suspension = lf.suspensions.iter().any(|s| s.groups.contains(&p.group));
        if contact && (p.shards > 1 || in_suspension) {
            v.push(t.contact_free_step(&p.group, p.first_fiber));
            v.push(t.contact_solved(&p.group, p.first_fiber));
        }
    }
    v
}

/// zenoh settings of a node: a loopback peer, or on a multi-host run the router (flow
/// node) or a client, over mutual TLS with access control.
pub fn zenoh_settings(spec: &NodeSpec) -> Result<ZenohSettings> {
    let mut s = ZenohSettings {
        listen: spec.zenoh_listen.clone(),
        connect: spec.zenoh_connect.clone(),
        ..ZenohSettings::default()
    };
    let (Some(net), Some(host)) = (&spec.launch.network, &spec.host) else {
        return Ok(s);
    };
    let h = spec.launch.host(host)?;
    let path = |p: &Path| p.to_string_lossy().to_string();
    s.tls = Some(TlsFiles {
        root_ca_certificate: path(&net.root_ca_certificate),
        certificate: path(&h.certificate),
        private_key: path(&h.private_key),
        mutual: true,
    });
    s.access = Some(AccessControl {
        key_prefix: fiberflow_messages::topics::Topics::new(&spec.launch.run.id).prefix(),
        common_names: net.allowed_common_names.clone(),
    });
    if NodeRole::Flow.is(&spec.node) {
        s.mode = ZenohMode::Router;
        s.listen = vec![net.listen.clone().unwrap_or_else(|| net.rendezvous.clone())];
        s.connect = vec![];
    } else {
        s.mode = ZenohMode::Client;
        s.listen = vec![];
        s.connect = vec![net.rendezvous.clone()];
    }
    Ok(s)
}

/// The file (in the run folder's `logs/`) the flow node writes once it has served the
/// run's last step: a flow node killed after it (while it stays up as a multi-host run's
/// router) has finished the run, and the launcher does not restart it.
pub const FLOW_DONE_MARKER: &str = "flow.done";

/// Does the flow node of a multi-host run live on another host than the spec's?
pub fn flow_elsewhere(spec: &NodeSpec) -> Result<bool> {
    let (Some(_), Some(host)) = (&spec.launch.network, &spec.host) else {
        return Ok(false);
    };
    Ok(!spec
        .launch
        .host(host)?
        .nodes
        .iter()
        .any(|n| NodeRole::Flow.is(n)))
}

/// The fibre nodes (and the recorder) of a multi-host run that live on other hosts than
/// the spec's, each with its host (none on one host).
pub fn remote_pieces(spec: &NodeSpec) -> Result<Vec<(String, String)>> {
    let (Some(net), Some(host)) = (&spec.launch.network, &spec.host) else {
        return Ok(vec![]);
    };
    let mut out = Vec::new();
    let recorder = spec.launch.recorder.enabled.then(|| "recorder".to_string());
    let nodes = spec
        .launch
        .pieces()?
        .iter()
        .map(|p| p.node())
        .collect::<Vec<_>>();
    for node in nodes.into_iter().chain(recorder) {
        if let Some(h) = net
            .hosts
            .iter()
            .find(|h| &h.name != host && h.nodes.contains(&node))
        {
            out.push((node, h.name.clone()));
        }
    }
    Ok(out)
}

pub fn digest(text: &str) -> String {
    let h = sha2::Sha256::digest(text.as_bytes());
    h.iter().map(|b| format!("{b:02x}")).collect()
}

/// Opens the bus for a spec (inproc is only possible inside the launcher).
pub fn open_bus(spec: &NodeSpec) -> Result<BusHandle> {
    let t = spec.transport;
    match t {
        Transport::Zenoh => {
            let s = zenoh_settings(spec)?;
            let bus = ZenohBus::open(&s).context("opening zenoh session")?;
            if let Some(path) = &spec.zenoh_endpoint_file {
                write_endpoint(path, &bus.listening_endpoints())?;
            }
            Ok(Arc::new(bus))
        }
        Transport::Inproc => Ok(Arc::new(InprocBus::new())),
        Transport::Iceoryx2 => Ok(Arc::new(
            fiberflow_bus::iceoryx2_bus::Iceoryx2Bus::open(
                &spec.launch.run.id,
                run_topics(&spec.launch),
            )
            .context("opening iceoryx2 shared-memory bus")?,
        )),
    }
}

/// Writes the first of a session's listening endpoints to `path` (a temporary file renamed
/// into place, so a reader sees all of it or nothing).
fn write_endpoint(path: &Path, endpoints: &[String]) -> Result<()> {
    let first = endpoints
        .first()
        .context("the zenoh session listens on no endpoint")?;
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, first).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

/// Runs the node named in the spec until the run ends.
///
/// Long (≈110 lines): one arm per kind of node, each its set-up and serve call.
pub fn run_node(spec: &NodeSpec, bus: BusHandle, stop: Arc<AtomicBool>) -> Result<()> {
    let lf = &spec.launch;
    let groups = lf.groups();
    let pieces = lf.pieces()?;
    let fiber_nodes: Vec<String> = pieces.iter().map(|p| p.node()).collect();
    match NodeRole::of(&spec.node) {
        NodeRole::Flow => {
            let mut expected = fiber_nodes.clone();
            if lf.recorder.enabled {
                expected.push("recorder".into());
            }
            let info = RunInfo {
                run_id: lf.run.id.clone(),
                config_digest: digest(&spec.launch_text),
                groups,
                expected_nodes: expected,
                steps: lf.run.steps,
                box_plus: lf.box_plus(),
                step_timeout_s: lf.run.step_timeout_s,
                liveness_s: lf.run.liveness_s,
                start_step: spec.start_step,
                resume_dir: spec.resume_dir.clone(),
                checkpoint_every: lf.run.checkpoint_every_steps(),
                checkpoint_root: spec.checkpoint_root(),
                pieces,
                step_times: Some(spec.out_dir.join("logs").join("flow-steps.csv")),
                two_way: lf.run.coupling == crate::launchfile::Coupling::TwoWay,
                remote_pieces: remote_pieces(spec)?,
                stop: in_process_stop(spec, &stop).map(fiberflow_flow::run::Stop),
            };
            // on a multi-host run the flow node is the zenoh router: everything the other
            // nodes send after its last step (final states, DONE) passes through it, so it
            // stays up until every node has said DONE
            let router = lf.network.is_some() && spec.host.is_some();
            let hb_topic = format!(
                "{}/control/heartbeat/**",
                fiberflow_messages::topics::Topics::new(&lf.run.id).prefix()
            );
            let mut hb = if router {
                Some(Inbox::new(bus.subscribe(&hb_topic)?))
            } else {
                None
            };
            let expected_done = info.expected_nodes.clone();
            // the nodes on other hosts find the flow node (their router) gone by its silence
            let _alive = if router {
                Some(fiberflow_bus::pulse::Pulse::alive(
                    bus.clone(),
                    fiberflow_messages::topics::Topics::new(&lf.run.id).heartbeat("flow"),
                    "flow".into(),
                )?)
            } else {
                None
            };
            let s = fiberflow_flow::serve::serve(&lf.flow, bus.clone(), &info, |_| {})?;
            tracing::info!(steps = s.steps, dropped = s.drops.total(), "flow node done");
            // the run's last step is served (what a test times a kill by; the launcher
            // goes by the run being complete, [`crate::hosts::RUN_COMPLETE_MARKER`])
            let marker = spec.out_dir.join("logs").join(FLOW_DONE_MARKER);
            if let Err(e) = std::fs::write(&marker, format!("{}\n", s.steps)) {
                tracing::warn!(error = %e, "could not write {}", marker.display());
            }
            report_drops("flow", &s.drops);
            if let Some(hb) = hb.as_mut() {
                linger_until_done(hb, &expected_done, lf.run.liveness_s, lf.run.step_timeout_s)?;
                crate::hosts::mark_complete(&spec.out_dir)?;
                crate::hosts::say_complete(&bus, spec)?;
            }
        }
        NodeRole::Recorder => {
            let mut meta = RunMetadata {
                run_id: lf.run.id.clone(),
                launch_file_name: spec.launch_file_name.clone(),
                launch_text: spec.launch_text.clone(),
                software_version: env!("CARGO_PKG_VERSION").into(),
                git_commit: option_env!("FIBERFLOW_GIT_COMMIT")
                    .unwrap_or("unknown")
                    .into(),
                transport: Some(spec.transport),
                ..Default::default()
            };
            meta.node_configs
                .insert("flow".into(), toml::to_string(&lf.flow).unwrap_or_default());
            for f in &lf.fibers {
                meta.node_configs
                    .insert(f.group.clone(), toml::to_string(f).unwrap_or_default());
            }
            let mut expect = fiber_nodes.clone();
            expect.push("flow".into());
            let name = fiberflow_messages::segments::segment_name(spec.segment);
            let path = spec.out_dir.join(&name);
            let previous_segments = if spec.segment == 0 {
                vec![]
            } else {
                fiberflow_messages::segments::segment_paths(&spec.out_dir)?
                    .into_iter()
                    .filter(|p| p.file_name().is_some_and(|n| n != name.as_str()))
                    .collect()
            };
            let plan = fiberflow_recorder::RecordPlan {
                groups: groups.clone(),
                steps: lf.run.steps,
                checkpoint_every: lf.run.checkpoint_every_steps(),
                checkpoint_root: spec.checkpoint_root(),
                start_step: spec.start_step,
                previous_segments,
                pieces: pieces
                    .iter()
                    .map(|p| (p.group.clone(), p.first_fiber))
                    .collect(),
                nodes: fiber_nodes.clone(),
                states_every_steps: lf.recorder.states_every_steps,
                samples: lf.recorder.samples,
                compression: lf.recorder.compression,
            };
            let cpu_from = fiberflow_bus::usage::process_cpu_s();
            let s =
                fiberflow_recorder::record(bus, &lf.run.id, &path, &meta, &expect, &plan, stop)?;
            tracing::info!(messages = s.messages, decimated = s.decimated, path = %s.path.display(), "recording finished");
            tracing::info!(
                writing_s = format!("{:.3}", s.busy_s),
                cpu_s = format!("{:.3}", fiberflow_bus::usage::process_cpu_s() - cpu_from),
                "where the recorder's time went"
            );
            report_drops("recorder", &s.drops);
        }
        NodeRole::Fiber => {
            run_fiber_nodes(spec, std::slice::from_ref(&spec.node), &pieces, bus, &stop)?
        }
    }
    Ok(())
}

/// Runs fibre nodes of the launch file (`pieces`: its fibre nodes) until the run ends
/// (`fiberflow_fiber::serve::serve_many`: small groups stepped in turn on this thread,
/// large ones a thread each).
/// The launcher's stop flag for the nodes of an in-process run (set when one of them
/// failed, or on Ctrl-C): their waits end at once. Separate processes are stopped by the
/// launcher instead.
fn in_process_stop(spec: &NodeSpec, stop: &Arc<AtomicBool>) -> Option<Arc<AtomicBool>> {
    (spec.transport == Transport::Inproc).then(|| stop.clone())
}

fn run_fiber_nodes(
    spec: &NodeSpec,
    names: &[String],
    pieces: &[fiberflow_messages::pieces::Piece],
    bus: BusHandle,
    stop: &Arc<AtomicBool>,
) -> Result<()> {
    let lf = &spec.launch;
    let mut nodes = Vec::new();
    for node in names {
        let Some(p) = pieces.iter().find(|p| &p.node() == node) else {
            let all: Vec<String> = pieces.iter().map(|p| p.node()).collect();
            bail!(
                "node {node:?} is neither flow, recorder nor a fibre node of the launch file ({})",
                all.join(", ")
            );
        };
        let Some(cfg) = lf.fibers.iter().find(|f| f.group == p.group) else {
            bail!("fibre node {node:?} has no group in the launch file");
        };
        nodes.push((cfg, p.index));
    }
    let ck = fiberflow_fiber::serve::RunSettings {
        start_step: spec.start_step,
        resume_dir: spec.resume_dir.clone(),
        every: lf.run.checkpoint_every_steps(),
        root: spec.checkpoint_root(),
        config_digest: digest(&spec.launch_text),
        full_states_every: lf.recorder.states_every_steps,
        two_way: lf.run.coupling == crate::launchfile::Coupling::TwoWay,
        flow_elsewhere: flow_elsewhere(spec)?,
        flow_liveness_s: lf.run.liveness_s,
        suspensions: (0..lf.suspensions.len())
            .map(|i| lf.suspension_members(i))
            .collect::<Result<_>>()?,
    };
    let served = fiberflow_fiber::serve::serve_many(
        &nodes,
        bus,
        &lf.run.id,
        lf.box_plus(),
        lf.run.step_timeout_s,
        &ck,
        in_process_stop(spec, stop),
    )?;
    for (node, drops) in &served {
        report_drops(node, drops);
    }
    Ok(())
}

/// Runs the spec's node and its co-nodes until the run ends, all on `bus`: fibre nodes
/// only through `serve_many` (small groups in turn on this thread), others each on a
/// thread of its own. The first failure returns at once, naming its node: the process then
/// exits and takes its other nodes with it, as separate processes would be stopped by the
/// launcher, instead of leaving them to wait out the step timeout.
pub(crate) fn run_nodes(spec: &NodeSpec, bus: BusHandle, stop: Arc<AtomicBool>) -> Result<()> {
    if spec.co_nodes.is_empty() {
        return run_node(spec, bus, stop).with_context(|| format!("node {} failed", spec.node));
    }
    let names: Vec<String> = std::iter::once(spec.node.clone())
        .chain(spec.co_nodes.iter().cloned())
        .collect();
    // fibre nodes only (the launcher's `fibers-i` processes): `serve_many` runs them all
    // (the pieces are built once: each build places every fibre of every group)
    if let Ok(pieces) = spec.launch.pieces() {
        if names.iter().all(|n| pieces.iter().any(|p| &p.node() == n)) {
            return run_fiber_nodes(spec, &names, &pieces, bus, &stop)
                .with_context(|| format!("fibre nodes {} failed", names.join(", ")));
        }
    }
    let tasks: Vec<crate::panics::Task> = names
        .iter()
        .map(|name| {
            let mut s = spec.clone();
            s.node = name.clone();
            s.co_nodes.clear();
            let (bus, stop) = (bus.clone(), stop.clone());
            let task: Box<dyn FnOnce() -> Result<()> + Send> = Box::new(move || {
                run_node(&s, bus, stop).with_context(|| format!("node {} failed", s.node))
            });
            (name.clone(), task)
        })
        .collect();
    crate::panics::first_failure(tasks)
}

/// Waits until every node in `expected` has sent a DONE or FAILED heartbeat. A node
/// silent for `liveness_s` (killed after its last step, say, or the recorder while it
/// finishes) is lost ([`fiberflow_flow::FlowError::PeerLost`]: the launcher restarts the
/// run from its newest complete checkpoint); one still beating but not done after
/// `timeout_s` is an error.
fn linger_until_done(
    hb: &mut Inbox,
    expected: &[String],
    liveness_s: f64,
    timeout_s: f64,
) -> Result<()> {
    use fiberflow_messages::Heartbeat;
    use std::time::{Duration, Instant};
    let t0 = Instant::now();
    let mut waiting: std::collections::BTreeMap<String, Instant> =
        expected.iter().map(|n| (n.clone(), t0)).collect();
    while !waiting.is_empty() {
        if let Some((_, h)) = hb.recv::<Heartbeat>(Duration::from_millis(100)) {
            if h.state == Lifecycle::Done || h.state == Lifecycle::Failed {
                waiting.remove(&h.node);
            } else if let Some(seen) = waiting.get_mut(&h.node) {
                *seen = Instant::now();
            }
        }
        let silent: Vec<&str> = waiting
            .iter()
            .filter(|(_, seen)| seen.elapsed().as_secs_f64() > liveness_s)
            .map(|(n, _)| n.as_str())
            .collect();
        if !silent.is_empty() {
            return Err(fiberflow_flow::FlowError::PeerLost(format!(
                "{} went silent for {liveness_s} s (run.liveness_s) after the run's last step, before saying DONE",
                silent.join(", ")
            ))
            .into());
        }
        if t0.elapsed().as_secs_f64() > timeout_s {
            let missing: Vec<&str> = waiting.keys().map(|n| n.as_str()).collect();
            bail!(
                "{} did not say DONE within {timeout_s:.0} s (run.step_timeout_s) of the run's last step",
                missing.join(", ")
            );
        }
    }
    Ok(())
}

/// Prints drop counts as `dropped <node> <topic> <count>` lines (parsed by tests).
fn report_drops(node: &str, d: &fiberflow_bus::DropCounter) {
    for (topic, n) in &d.by_topic {
        println!("dropped {node} {topic} {n}");
    }
}

/// The exit status `fiberflow node` ends with after `e`: the flow node's
/// [`fiberflow_flow::error::PEER_LOST_EXIT`] when it failed because another node was lost
/// (the launcher may restart the run for it), else 1.
pub fn node_exit_code(e: &anyhow::Error) -> i32 {
    let lost = e.chain().any(|c| {
        matches!(
            c.downcast_ref::<fiberflow_flow::FlowError>(),
            Some(fiberflow_flow::FlowError::PeerLost(_))
        )
    });
    if lost {
        fiberflow_flow::error::PEER_LOST_EXIT
    } else {
        1
    }
}

/// `fiberflow node --spec FILE`.
pub fn node_cmd(spec_path: &Path) -> Result<()> {
    let text = std::fs::read_to_string(spec_path)
        .with_context(|| format!("reading {}", spec_path.display()))?;
    let spec: NodeSpec =
        toml::from_str(&text).with_context(|| format!("parsing {}", spec_path.display()))?;
    // a panic on any thread ends this node at once (status 101), for the restart policy
    crate::panics::end_process_on_panic();
    let stop = Arc::new(AtomicBool::new(false));
    // the recorder finishes its file on SIGTERM/SIGINT; the other nodes hold nothing that
    // a signal could leave half-written, so they keep the default action and stop at once
    if NodeRole::Recorder.is(&spec.node) {
        signal_hook::flag::register(signal_hook::consts::SIGTERM, stop.clone())
            .context("installing SIGTERM handler")?;
        signal_hook::flag::register(signal_hook::consts::SIGINT, stop.clone())
            .context("installing SIGINT handler")?;
    }
    let fiber_node = NodeRole::Fiber.is(&spec.node);
    if fiber_node && spec.launch.run.fiber_scheduling == FiberScheduling::Idle {
        // before the bus and the thread pool start their threads, which inherit it
        crate::scheduling::run_in_idle_time()?;
        tracing::info!(
            "running under SCHED_IDLE, in the time the flow node leaves free (run.fiber_scheduling)"
        );
    }
    let bus = open_bus(&spec)?;
    let result = run_nodes(&spec, bus.clone(), stop);
    if spec.transport == Transport::Zenoh {
        // a node's last words (final state, DONE) are queued in the zenoh session, which
        // drops its queues when the process exits: give them time to leave
        std::thread::sleep(std::time::Duration::from_millis(300));
    }
    drop(bus);
    result
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::launchfile::LaunchFile;

    /// Nodes sharing a process: one that fails returns its error at once, naming it, while
    /// the other still waits for a run announcement that never comes (an hour here: a
    /// process that waited for all its nodes would hang this test).
    #[test]
    fn a_failing_co_node_ends_its_process_at_once() {
        let file = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../launch/validation/analytic-shear.toml");
        let (lf, text) = LaunchFile::load_with(&file, &["run.step_timeout_s=3600".into()]).unwrap();
        let waiting = lf.fiber_nodes().unwrap()[0].clone();
        let out = std::env::temp_dir().join(format!("ff-co-nodes-{}", std::process::id()));
        let spec = NodeSpec {
            node: waiting,
            co_nodes: vec!["nope".into()],
            ..NodeSpec::inproc(lf, text, out.clone())
        };
        let bus: BusHandle = Arc::new(InprocBus::new());
        let e = run_nodes(&spec, bus, Arc::new(AtomicBool::new(false))).unwrap_err();
        let msg = format!("{e:#}");
        assert!(msg.contains("node nope failed"), "{msg}");
        assert!(
            msg.contains("neither flow, recorder nor a fibre node"),
            "{msg}"
        );
        std::fs::remove_dir_all(&out).ok();
    }
}
