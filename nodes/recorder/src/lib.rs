//! The recorder: subscribes to everything under a run's prefix and writes a chunked,
//! zstd-compressed, indexed MCAP with ros2msg schemas, storing payloads as received;
//! derives a `sensor_msgs/PointCloud2` channel per fibre group and a `sensor_msgs/Image`
//! channel per flow slice for generic viewers;
//! flushes a chunk at least every second so a killed recorder loses at most that much.
//!
//! This file is the recorder's loop (its session: the open segment, what it holds back,
//! its flush clock); the file it writes is [`writer`], what it is told of the run
//! [`plan`], what a run folder already holds [`recorded`]; the derived channels
//! (pointcloud, image), the O_DIRECT sink (direct) and recovery live in their own files.
//! Size (≈ 660 lines before the tests): the session — what it holds back until a step is
//! whole, when it starts a segment, how it ends — is one state machine over one open file.

pub mod direct;
pub mod image;
mod plan;
pub mod pointcloud;
mod recorded;
pub mod recover;
pub mod ros;
mod writer;

use fiberflow_messages::NodeRole;
pub use plan::{write_options, ChunkCompression, RecordPlan};
pub use recorded::{recorded_steps, Recorded, RECORDED_WINDOW_STEPS};
pub use writer::t_plus_to_nanos;
use writer::{open_recording, Out};

use fiberflow_bus::pulse::{Beat, Pulse, Watch};
use fiberflow_bus::{BusHandle, DropCounter, Inbox};
use fiberflow_messages::pieces::Tiles;
use fiberflow_messages::topics::{kind_of, Topics};
use fiberflow_messages::Kind;
use fiberflow_messages::Lifecycle;
use fiberflow_messages::{
    checkpoints, decode, encode, sanity, schema, FiberGroupState, Heartbeat, SCHEMA_VERSION,
};
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

#[derive(Debug, thiserror::Error)]
pub enum RecorderError {
    #[error("mcap error on {path}: {source}")]
    Mcap {
        path: String,
        #[source]
        source: mcap::McapError,
    },
    #[error("i/o error on {path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error(transparent)]
    Bus(#[from] fiberflow_bus::BusError),
}

/// Provenance written into the file (MCAP metadata and attachments).
#[derive(Debug, Clone, Default)]
pub struct RunMetadata {
    pub run_id: String,
    pub launch_file_name: String,
    pub launch_text: String,
    /// Node name -> resolved configuration (TOML).
    pub node_configs: BTreeMap<String, String>,
    pub software_version: String,
    pub git_commit: String,
    /// The run's transport (None: not said, as in tests that write a file directly).
    pub transport: Option<fiberflow_bus::Transport>,
}

/// What was recorded.
#[derive(Debug, Clone, Default)]
pub struct RecordSummary {
    pub messages: u64,
    pub by_topic: BTreeMap<String, u64>,
    pub drops: DropCounter,
    pub path: PathBuf,
    /// Step-stamped messages that an earlier segment already holds (not written again).
    pub already_recorded: u64,
    /// States left out by the plan (`states_every_steps`; samples are not subscribed to when the
    /// plan leaves them out).
    pub decimated: u64,
    /// Wall seconds spent checking, encoding and writing messages (the rest is waiting).
    pub busy_s: f64,
}

/// How long the recorder waits, after the flow node's DONE, for anything more to arrive.
const QUIET_AFTER_FLOW_DONE: Duration = Duration::from_secs(3);
/// How long it waits after every fibre node's last state when no DONE came.
const QUIET_AFTER_LAST_STATES: Duration = Duration::from_secs(10);

/// The recorder's running state between messages.
struct Session<'a> {
    out: Out,
    topics: Topics,
    summary: RecordSummary,
    drops: DropCounter,
    sim_nanos: u64,
    /// Step-stamped messages already in this or an earlier segment.
    seen: Recorded,
    /// Each fibre node's state of step 0 (by topic and first fibre), held until its next
    /// state: a fluid-velocity start sends step 0 twice (positions first, then with the
    /// fluid's velocity); the last wins.
    held_first: BTreeMap<(String, u32), Vec<u8>>,
    /// Newest state and samples step per fibre node, by (group, first fibre) (for the
    /// checkpoint commit).
    state_step: BTreeMap<(String, u32), u64>,
    samples_step: BTreeMap<(String, u32), u64>,
    /// Slices of sharded groups' states, until a step's slices make the whole group (its
    /// PointCloud2 shows the whole group).
    tiles: Tiles<FiberGroupState>,
    /// Newest flow status step.
    status_step: Option<u64>,
    plan: &'a RecordPlan,
    next_checkpoint: Option<u64>,
    /// The newest checkpoint whose messages are on disk (`recorder.ckpt` written).
    committed: Option<u64>,
}

impl Session<'_> {
    /// Validates, de-duplicates and writes one message.
    fn handle(&mut self, topic: &str, bytes: &[u8]) -> Result<(), RecorderError> {
        let Some(kind) = kind_of(topic) else {
            self.drops
                .drop_one(topic, "topic carries no known message type");
            return Ok(());
        };
        let is_state = kind == Kind::FiberGroupState;
        let is_samples = kind == Kind::FlowSamples;
        // states the plan leaves out are read no further than their header (a state is tens
        // of MB at scale): they only mark their node's progress. (Without samples in the
        // plan the recorder does not subscribe to them.)
        if is_state && self.plan.states_every_steps > 1 {
            let h = match fiberflow_messages::peek_group_header(bytes) {
                Ok(h) => h,
                Err(e) => {
                    self.drops.drop_one(topic, &e.to_string());
                    return Ok(());
                }
            };
            if !self.plan.keeps_state(h.step) {
                let stamp = sanity::Stamp {
                    step: Some(h.step),
                    owner: Some(h.group.clone()),
                    first_fiber: h.first_fiber,
                };
                if let Err(why) = self.belongs(topic, &stamp) {
                    self.drops.drop_one(topic, &why);
                    return Ok(());
                }
                let e = self
                    .state_step
                    .entry((h.group, h.first_fiber))
                    .or_insert(h.step);
                *e = (*e).max(h.step);
                self.summary.decimated += 1;
                return self.maybe_commit();
            }
        }
        // a state is decoded once: its checks, its stamp, the timeline and the PointCloud2
        let checked = if is_state {
            sanity::check_state(bytes).map(|s| {
                let stamp = sanity::Stamp {
                    step: Some(s.step),
                    owner: Some(s.group.clone()),
                    first_fiber: s.first_fiber,
                };
                (stamp, Some(s))
            })
        } else {
            sanity::check_payload(kind, bytes).map(|s| (s, None))
        };
        let (stamp, state) = match checked {
            Ok(c) => c,
            Err(why) => {
                self.drops.drop_one(topic, &why);
                return Ok(());
            }
        };
        if state.as_ref().is_some_and(|s| s.is_lean()) {
            self.drops.drop_one(
                topic,
                "lean state (centres only) at a step the plan records",
            );
            return Ok(());
        }
        if let Err(why) = self.belongs(topic, &stamp) {
            self.drops.drop_one(topic, &why);
            return Ok(());
        }
        let step = stamp.step;
        if kind == Kind::FlowStatus {
            self.status_step = self.status_step.max(step);
        }
        if let Some(k) = step {
            if let Some(g) = &stamp.owner {
                if is_state || is_samples {
                    let map = if is_state {
                        &mut self.state_step
                    } else {
                        &mut self.samples_step
                    };
                    let e = map.entry((g.clone(), stamp.first_fiber)).or_insert(k);
                    *e = (*e).max(k);
                }
            }
            let slice = (topic.to_string(), stamp.first_fiber);
            if is_state && k == 0 && !self.seen.contains(topic, 0, slice.1) {
                self.held_first.insert(slice, bytes.to_vec());
                return Ok(());
            }
            if is_state {
                if let Some(first) = self.held_first.remove(&slice) {
                    let held = sanity::check_state(&first).ok();
                    self.write_new(topic, kind, Some(0), slice.1, &first, held)?;
                }
            }
        }
        self.write_new(topic, kind, step, stamp.first_fiber, bytes, state)?;
        self.maybe_commit()
    }

    /// The step through which every piece's state has come in (None before each piece's
    /// first state).
    fn recorded_through(&self) -> Option<u64> {
        let pieces = self.plan.pieces.len().max(self.plan.groups.len());
        if pieces == 0 || self.state_step.len() < pieces {
            return None;
        }
        self.state_step.values().min().copied()
    }

    /// Does a message that decoded and checked belong to this run? Its step must lie in
    /// the run, its group be one of the run's and named by its topic, a heartbeat come from
    /// one of the run's nodes.
    fn belongs(&self, topic: &str, stamp: &sanity::Stamp) -> Result<(), String> {
        if stamp.step.is_some_and(|k| k > self.plan.steps) {
            return Err(format!("step beyond the run's {} steps", self.plan.steps));
        }
        let Some(owner) = &stamp.owner else {
            return Ok(());
        };
        if topic.ends_with("/control/announce") {
            if owner != &self.topics.run {
                return Err(format!("announcement of another run {owner:?}"));
            }
            return Ok(());
        }
        if self.plan.groups.is_empty() {
            return Ok(());
        }
        let parts: Vec<&str> = topic.split('/').collect();
        let named = match parts.get(2) {
            Some(&"fibers") => parts.get(3),
            Some(&"flow") | Some(&"control") => parts.get(4),
            _ => None,
        };
        if named.is_none_or(|n| n != owner) {
            return Err(format!("message of {owner:?} on another's topic"));
        }
        // groups own their data topics; fibre nodes (a group, or a shard `<group>.<i>`)
        // send the heartbeats
        let known = self.plan.groups.iter().any(|g| g == owner)
            || self.plan.nodes.iter().any(|n| n == owner)
            || ["flow", "recorder", "launcher"].contains(&owner.as_str());
        if !known {
            return Err(format!("{owner:?} is not part of this run"));
        }
        Ok(())
    }

    /// Writes unless this (topic, step, slice) is already recorded (`first`: the slice's
    /// first fibre, 0 for a whole group or a message of no group); `st` is the decoded
    /// state of a state message (for the timeline and, once its group is complete, the
    /// group's PointCloud2).
    fn write_new(
        &mut self,
        topic: &str,
        kind: Kind,
        step: Option<u64>,
        first: u32,
        bytes: &[u8],
        st: Option<FiberGroupState>,
    ) -> Result<(), RecorderError> {
        if let Some(k) = step {
            if !self.seen.insert(topic, k, first) {
                self.summary.already_recorded += 1;
                return Ok(());
            }
        }
        if let Some(s) = &st {
            self.sim_nanos = self.sim_nanos.max(t_plus_to_nanos(s.t_plus));
        }
        let c = self.out.channel(topic, kind.type_name())?;
        self.out.write(c, self.sim_nanos, bytes)?;
        self.summary.messages += 1;
        *self.summary.by_topic.entry(topic.to_string()).or_insert(0) += 1;
        if kind == Kind::FlowSlice {
            // checked before it got here
            if let Ok(sl) = decode::<fiberflow_messages::FlowSlice>(bytes) {
                let img = image::encode(&image::from_slice(&sl));
                let c = self
                    .out
                    .channel(&self.topics.flow_slice_image(&sl.name), schema::IMAGE_NAME)?;
                self.out.write(c, self.sim_nanos, &img)?;
            }
        }
        if let Some(s) = st {
            if let Some(whole) = self.tiles.add_slice(s) {
                let pc = pointcloud::from_state(&whole);
                let ptopic = self.topics.fiber_points(&whole.group);
                let c = self.out.channel(&ptopic, schema::POINT_CLOUD2_NAME)?;
                self.out.write(c, self.sim_nanos, &pc)?;
            }
        }
        Ok(())
    }

    /// The recorder's share of checkpoint c: once every group's state and samples of
    /// step c+1 have arrived, everything of steps <= c is in (each node publishes in step
    /// order); flush and fsync the segment and say so in `recorder.ckpt`.
    fn maybe_commit(&mut self) -> Result<(), RecorderError> {
        let Some(root) = self.plan.checkpoint_root.clone() else {
            return Ok(());
        };
        while let Some(c) = self.next_checkpoint {
            let pieces: Vec<(String, u32)> = if self.plan.pieces.is_empty() {
                self.plan.groups.iter().map(|g| (g.clone(), 0)).collect()
            } else {
                self.plan.pieces.clone()
            };
            let past = |m: &BTreeMap<(String, u32), u64>| {
                pieces.iter().all(|p| m.get(p).is_some_and(|&s| s > c))
            };
            // the flow node's messages of steps <= c are in once one of a later step is:
            // its samples, or (without fibre groups, or samples not recorded) its status
            let flow_past = if self.plan.groups.is_empty() || !self.plan.samples {
                self.status_step.is_some_and(|s| s > c)
            } else {
                past(&self.samples_step)
            };
            let ready = flow_past && (self.plan.groups.is_empty() || past(&self.state_step));
            if !ready {
                return Ok(());
            }
            let t0 = Instant::now();
            self.out.w.flush().map_err(self.out.err())?;
            let io = |path: &Path| {
                let path = path.display().to_string();
                move |source| RecorderError::Io { path, source }
            };
            let file = Path::new(&self.out.path);
            std::fs::File::open(file)
                .and_then(|f| f.sync_all())
                .map_err(io(file))?;
            let dir = checkpoints::step_dir(&root, c);
            std::fs::create_dir_all(&dir).map_err(io(&dir))?;
            let seg = file
                .file_name()
                .map(|n| n.to_string_lossy().to_string())
                .unwrap_or_default();
            let text = format!("segment = {seg:?}\nstep = {c}\n");
            let piece = checkpoints::piece(&dir, "recorder");
            checkpoints::write_atomic(&piece, text.as_bytes()).map_err(io(&piece))?;
            tracing::info!(
                step = c,
                ms = t0.elapsed().as_millis() as u64,
                "checkpoint written (segment flushed to disk)"
            );
            self.committed = Some(c);
            let next = c + self.plan.checkpoint_every;
            self.next_checkpoint = (next < self.plan.steps).then_some(next);
        }
        Ok(())
    }

    /// Writes what is still held (a group whose only state is step 0).
    fn release_held(&mut self) -> Result<(), RecorderError> {
        for ((topic, first), bytes) in std::mem::take(&mut self.held_first) {
            let st = sanity::check_state(&bytes).ok();
            self.write_new(&topic, Kind::FiberGroupState, Some(0), first, &bytes, st)?;
        }
        Ok(())
    }
}

/// Records until every node in `expect_done` has reported DONE (or FAILED), or `stop` is set.
/// Announces itself as node `recorder` until the run starts.
pub fn record(
    bus: BusHandle,
    run_id: &str,
    path: &Path,
    meta: &RunMetadata,
    expect_done: &[String],
    plan: &RecordPlan,
    stop: Arc<AtomicBool>,
) -> Result<RecordSummary, RecorderError> {
    let t = Topics::new(run_id);
    let out = open_recording(path, meta, plan)?;
    let seen = recorded_steps(&plan.previous_segments);
    let patterns = subscriptions(&t, plan.samples);
    let mut inbox = Inbox::new(fiberflow_bus::subscribe_any(bus.as_ref(), &patterns)?);
    let next_checkpoint = (plan.checkpoint_every > 0)
        .then(|| (plan.start_step / plan.checkpoint_every + 1) * plan.checkpoint_every)
        .filter(|&c| c < plan.steps);
    let mut sess = Session {
        out,
        topics: t.clone(),
        summary: RecordSummary {
            path: path.to_path_buf(),
            ..Default::default()
        },
        drops: DropCounter::default(),
        sim_nanos: 0,
        seen,
        held_first: BTreeMap::new(),
        state_step: BTreeMap::new(),
        samples_step: BTreeMap::new(),
        tiles: Tiles::default(),
        status_step: None,
        plan,
        next_checkpoint,
        committed: None,
    };
    let mut done: BTreeSet<String> = BTreeSet::new();
    let expected: BTreeSet<String> = expect_done.iter().cloned().collect();
    let mut started = false;
    let mut last_flush = Instant::now();
    let mut last_hb = Instant::now() - Duration::from_secs(1);
    let mut finish_at: Option<Instant> = None;
    // once the flow node is DONE the run is over: a DONE lost in transit must not keep the
    // recorder open, so it also finishes after QUIET_AFTER_FLOW_DONE without any message
    let mut flow_done = false;
    let mut last_message = Instant::now();
    // the recorder's pulse says it is alive and how far it has recorded; the flow node
    // keeps the run at most RECORDER_LAG_STEPS ahead of it
    let beat = Arc::new(Beat::default());
    beat.step.store(plan.start_step, Ordering::Relaxed);
    let mut reported = plan.start_step;
    let mut said_committed: Option<u64> = None;
    // stopped (a signal, or the launcher after a failure) rather than run to its end
    let mut stopped = false;
    let watch = Arc::new(Watch::default());
    let _pulse = Pulse::start(
        bus.clone(),
        vec![(
            t.heartbeat("recorder"),
            "recorder".into(),
            beat.clone(),
            watch.clone(),
        )],
    )
    .map_err(|source| RecorderError::Io {
        path: "the recorder's pulse thread".into(),
        source,
    })?;
    loop {
        watch.touch();
        if stop.load(Ordering::SeqCst) {
            // what has already arrived is still recorded (`finish`)
            tracing::info!("recorder stopping on signal");
            stopped = true;
            break;
        }
        if let Some(f) = finish_at {
            if Instant::now() > f {
                break;
            }
        }
        if !started && last_hb.elapsed() > Duration::from_millis(200) {
            let hb = own_heartbeat(Lifecycle::Ready, 0, sess.drops.total());
            bus.publish(&t.heartbeat("recorder"), &encode(&hb))?;
            last_hb = Instant::now();
        }
        if last_flush.elapsed() >= Duration::from_millis(500) {
            sess.out.w.flush().map_err(sess.out.err())?;
            last_flush = Instant::now();
        }
        let Some((topic, bytes)) = inbox.recv_raw(Duration::from_millis(50)) else {
            // every fibre node's state of the last step is in: the run is over even if the
            // flow node's DONE was lost in transit
            let last_states_in = !plan.groups.is_empty()
                && sess.state_step.len() >= plan.pieces.len().max(plan.groups.len())
                && sess.state_step.values().all(|&k| k == plan.steps);
            if (flow_done || (last_states_in && last_message.elapsed() > QUIET_AFTER_LAST_STATES))
                && finish_at.is_none()
                && last_message.elapsed() > QUIET_AFTER_FLOW_DONE
            {
                let missing: Vec<_> = expected.difference(&done).cloned().collect();
                tracing::warn!(nodes = %missing.join(", "), "no DONE from these nodes; finishing after the flow node's DONE");
                break;
            }
            continue;
        };
        let kind = kind_of(&topic);
        // heartbeats (a flow node repeating its DONE) are not data still arriving
        if kind != Some(Kind::Heartbeat) {
            last_message = Instant::now();
        }
        let busy_from = Instant::now();
        match kind {
            Some(Kind::RunAnnouncement) => {
                started |= schema::validate(Kind::RunAnnouncement.type_name(), &bytes).is_ok()
            }
            Some(Kind::Heartbeat) => {
                if let Ok(hb) = decode::<Heartbeat>(&bytes) {
                    // a node is done when it says so at the run's last step (the launcher
                    // stops the recorder when a node fails; a stray heartbeat must not)
                    if hb.state == Lifecycle::Done && hb.step == plan.steps {
                        if NodeRole::Flow.is(&hb.node) {
                            // the flow node sends its DONE until it hears this
                            flow_done = true;
                            let ack =
                                own_heartbeat(Lifecycle::Finishing, plan.steps, sess.drops.total());
                            bus.publish(&t.heartbeat("recorder"), &encode(&ack))?;
                        }
                        done.insert(hb.node);
                        if expected.is_subset(&done) && finish_at.is_none() {
                            finish_at = Some(Instant::now() + Duration::from_millis(500));
                        }
                    }
                }
            }
            _ => {}
        }
        sess.handle(&topic, &bytes)?;
        if let Some(k) = sess.recorded_through() {
            beat.step.fetch_max(k, Ordering::Relaxed);
            // said at once (not only by the pulse), every REPORT_EVERY_STEPS: the flow node
            // may be waiting for it. It stays up to RECORDER_LAG_STEPS ahead, so a report
            // that is a step old never holds a run the recorder keeps up with, and the
            // recording (which keeps the recorder's heartbeats too) gets half as many
            if k >= reported + REPORT_EVERY_STEPS {
                let hb = own_heartbeat(Lifecycle::Running, k, sess.drops.total());
                bus.publish(&t.heartbeat("recorder"), &encode(&hb))?;
                reported = k;
                // said again with every report, in case one was lost
                said_committed = None;
            }
        }
        // a head whose recorder is on another host completes a checkpoint only on this
        if let Some(c) = sess.committed.filter(|&c| said_committed != Some(c)) {
            let hb = own_heartbeat(Lifecycle::Committed, c, sess.drops.total());
            bus.publish(&t.heartbeat("recorder"), &encode(&hb))?;
            said_committed = Some(c);
        }
        sess.summary.busy_s += busy_from.elapsed().as_secs_f64();
    }
    finish(sess, &mut inbox, &bus, &t, stopped)
}

/// How long a finishing recorder keeps taking the messages that already arrived.
pub const STOP_DRAIN: Duration = Duration::from_secs(2);

/// Handles every message already in `inbox` until none arrives for 50 ms (at most for
/// `limit`: the run may still be sending); returns how many.
fn drain(inbox: &mut Inbox, sess: &mut Session, limit: Duration) -> Result<u64, RecorderError> {
    let until = Instant::now() + limit;
    let mut n = 0;
    while Instant::now() < until {
        // a message may still be on its way from the transport to the inbox
        let Some((topic, bytes)) = inbox.recv_raw(Duration::from_millis(50)) else {
            break;
        };
        sess.handle(&topic, &bytes)?;
        n += 1;
    }
    Ok(n)
}

/// The topics the recorder subscribes to: everything of the run, or everything but the
/// flow's samples (at scale as large as the states, and every copy to the recorder costs).
/// Never the shards' contact exchange (`contact/**`: each piece's free step, internal to
/// a step).
fn subscriptions(t: &Topics, samples: bool) -> Vec<String> {
    let mut v = vec![
        format!("{}/control/**", t.prefix()),
        t.flow_status(),
        t.flow_profiles(),
        format!("{}/flow/slices/**", t.prefix()),
        format!("{}/fibers/**", t.prefix()),
    ];
    if samples {
        v.push(format!("{}/flow/samples/**", t.prefix()));
    }
    v
}

/// Writes what is still queued and held, the drop counts, and the MCAP footer; then tells
/// the run that the file is complete.
fn finish(
    mut sess: Session<'_>,
    inbox: &mut Inbox,
    bus: &BusHandle,
    t: &Topics,
    stopped: bool,
) -> Result<RecordSummary, RecorderError> {
    // what already arrived is kept, also when stopped (a Ctrl-C must not lose it)
    let kept = drain(inbox, &mut sess, STOP_DRAIN)?;
    tracing::info!(messages = kept, "recorded what had arrived before the end");
    if stopped {
        // a held state of step 0 may still have been replaced (a fluid-velocity start
        // sends it twice): the run's restart records step 0 again, and this one, written
        // now, would be taken for it
        let n = sess.held_first.len();
        if n > 0 {
            tracing::info!(
                states = n,
                "stopped at step 0: its held states are left to the restart"
            );
        }
    } else {
        sess.release_held()?;
    }
    let mut drops = sess.drops.clone();
    for (k, v) in &inbox.drops.by_topic {
        *drops.by_topic.entry(k.clone()).or_insert(0) += v;
    }
    let mut drops_meta = BTreeMap::new();
    for (k, v) in &drops.by_topic {
        drops_meta.insert(k.clone(), v.to_string());
    }
    let mut out = sess.out;
    out.w
        .write_metadata(&mcap::records::Metadata {
            name: "fiberflow.drops".into(),
            metadata: drops_meta,
        })
        .map_err(out.err())?;
    out.w.finish().map_err(out.err())?;
    let mut summary = sess.summary;
    summary.drops = drops;
    // the file is complete: tell the run (a zenoh router waits for this before closing)
    let hb = own_heartbeat(Lifecycle::Done, 0, summary.drops.total());
    if let Err(e) = bus.publish(&t.heartbeat("recorder"), &encode(&hb)) {
        tracing::warn!(error = %e, "could not announce the finished recording");
    }
    Ok(summary)
}

/// How often (in recorded steps) the recorder says at once how far it has recorded; the
/// flow node holds the run when it would get more than
/// [`fiberflow_messages::lifecycle::RECORDER_LAG_STEPS`] ahead.
const REPORT_EVERY_STEPS: u64 = 2;

/// A heartbeat of the recorder itself.
fn own_heartbeat(state: Lifecycle, step: u64, dropped: u64) -> Heartbeat {
    Heartbeat {
        schema_version: SCHEMA_VERSION,
        node: "recorder".into(),
        state,
        step,
        dropped,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fiberflow_bus::inproc::InprocBus;
    use fiberflow_messages::fuzz::{random_payload, Rng, KINDS};

    type RecordResult = Result<RecordSummary, RecorderError>;

    /// Runs `record` on a thread (the run's only expected node is "flow") and waits for
    /// its first heartbeat on `hb`.
    fn start_recorder(
        bus: &BusHandle,
        run: &'static str,
        path: &Path,
        plan: RecordPlan,
        hb: &mut Inbox,
    ) -> std::thread::JoinHandle<RecordResult> {
        let (b2, p2) = (bus.clone(), path.to_path_buf());
        let h = std::thread::spawn(move || {
            record(
                b2,
                run,
                &p2,
                &RunMetadata::default(),
                &["flow".to_string()],
                &plan,
                Arc::new(AtomicBool::new(false)),
            )
        });
        assert!(hb.recv::<Heartbeat>(Duration::from_secs(10)).is_some());
        h
    }

    /// An in-process bus on which `count` garbage messages on `topic` are waiting as
    /// soon as a subscription to it is made.
    struct Waiting {
        inner: InprocBus,
        topic: String,
        count: u64,
    }

    impl fiberflow_bus::Bus for Waiting {
        fn publish(&self, topic: &str, payload: &[u8]) -> Result<(), fiberflow_bus::BusError> {
            self.inner.publish(topic, payload)
        }
        fn subscribe(
            &self,
            pattern: &str,
        ) -> Result<fiberflow_bus::Subscription, fiberflow_bus::BusError> {
            let sub = self.inner.subscribe(pattern)?;
            if fiberflow_bus::matches(pattern, &self.topic) {
                for i in 0..self.count {
                    self.inner.publish(&self.topic, &[i as u8, 1, 2])?;
                }
            }
            Ok(sub)
        }
        fn name(&self) -> &'static str {
            "waiting"
        }
    }

    /// A recorder told to stop (Ctrl-C) first takes what already arrived: 10⁴ garbage
    /// messages wait in its subscription and the stop is set before it starts; every one
    /// is counted as a drop (with the drain taken out it counted none).
    #[test]
    fn a_stopped_recorder_keeps_what_already_arrived() {
        let t = Topics::new("st");
        let n = 10_000u64;
        let bus: BusHandle = Arc::new(Waiting {
            inner: InprocBus::new(),
            topic: t.flow_status(),
            count: n,
        });
        let path = std::env::temp_dir().join(format!("ff-rec-stop-{}.mcap", std::process::id()));
        let plan = RecordPlan {
            groups: vec!["case1".into()],
            steps: 400,
            ..Default::default()
        };
        let stop = Arc::new(AtomicBool::new(true));
        let s = record(
            bus,
            "st",
            &path,
            &RunMetadata::default(),
            &["flow".to_string()],
            &plan,
            stop,
        )
        .expect("recorder failed");
        assert_eq!(s.drops.total(), n);
        std::fs::remove_file(&path).ok();
    }

    /// A group in two shards: each step's metrics (and samples) come as two slices on one
    /// topic, and the recorder keeps both (it kept the first slice of each step only,
    /// taking every message but a state for the whole group); a slice sent again is kept
    /// once.
    #[test]
    fn both_shards_metrics_and_samples_of_a_step_are_recorded() {
        use fiberflow_messages::{FiberGroupMetrics, FlowSamples};
        let bus: BusHandle = Arc::new(InprocBus::new());
        let t = Topics::new("shm");
        let path = std::env::temp_dir().join(format!("ff-rec-shm-{}.mcap", std::process::id()));
        let mut hb = Inbox::new(bus.subscribe(&t.heartbeat("recorder")).unwrap());
        let plan = RecordPlan {
            groups: vec!["g".into()],
            nodes: vec!["g.0".into(), "g.1".into()],
            steps: 3,
            samples: true,
            ..Default::default()
        };
        let h = start_recorder(&bus, "shm", &path, plan, &mut hb);
        for k in 0..=3u64 {
            for first in [0u32, 1] {
                let m = FiberGroupMetrics {
                    schema_version: SCHEMA_VERSION,
                    group: "g".into(),
                    step: k,
                    t_plus: k as f64 * 0.25,
                    first_fiber: first,
                    group_fibers: 2,
                    centre_of_mass: vec![first as f64; 3],
                    z1: vec![1.0],
                    sigma2: vec![0.0],
                    end_to_end: vec![3.0],
                    mean_abs_z1: 1.0,
                    mean_sigma2: 0.0,
                };
                let s = FlowSamples {
                    schema_version: SCHEMA_VERSION,
                    group: "g".into(),
                    step: k,
                    t_plus: k as f64 * 0.25,
                    first_fiber: first,
                    group_fibers: 2,
                    velocity: vec![0.0; 3],
                    velocity_gradient: vec![0.0; 9],
                };
                let st = format!("{}/{first}", t.flow_samples("g"));
                // the second shard's metrics sent twice (a resend)
                for _ in 0..=first {
                    bus.publish(&t.fiber_metrics("g"), &encode(&m)).unwrap();
                }
                bus.publish(&st, &encode(&s)).unwrap();
            }
        }
        let done = Heartbeat {
            schema_version: SCHEMA_VERSION,
            node: "flow".into(),
            state: Lifecycle::Done,
            step: 3,
            dropped: 0,
        };
        bus.publish(&t.heartbeat("flow"), &encode(&done)).unwrap();
        let s = h
            .join()
            .expect("recorder panicked")
            .expect("recorder failed");
        assert_eq!(s.already_recorded, 4, "the resent slices");
        let bytes = std::fs::read(&path).unwrap();
        let mut metrics = BTreeSet::new();
        let mut samples = BTreeSet::new();
        for m in mcap::MessageStream::new(&bytes).unwrap() {
            let m = m.unwrap();
            if m.channel.topic == t.fiber_metrics("g") {
                let x = decode::<FiberGroupMetrics>(&m.data).unwrap();
                assert!(metrics.insert((x.step, x.first_fiber)), "recorded twice");
            } else if m.channel.topic.starts_with(&t.flow_samples("g")) {
                let x = decode::<FlowSamples>(&m.data).unwrap();
                assert!(samples.insert((x.step, x.first_fiber)), "recorded twice");
            }
        }
        let want: BTreeSet<(u64, u32)> = (0..=3).flat_map(|k| [(k, 0), (k, 1)]).collect();
        assert_eq!(metrics, want);
        assert_eq!(samples, want);
        std::fs::remove_file(&path).ok();
    }

    /// A recorder stopped (a signal, or the launcher after a failure) while it holds a
    /// group's state of step 0 — which a fluid-velocity start sends twice, the second
    /// replacing the first — does not write it: the run's restart records step 0 again,
    /// and the held one would be taken for it (a chaos trial recorded the first version so).
    #[test]
    fn a_stopped_recorder_leaves_a_held_step_zero_to_the_restart() {
        let bus: BusHandle = Arc::new(InprocBus::new());
        let t = Topics::new("held");
        let path = std::env::temp_dir().join(format!("ff-rec-held-{}.mcap", std::process::id()));
        let mut hb = Inbox::new(bus.subscribe(&t.heartbeat("recorder")).unwrap());
        let plan = RecordPlan {
            groups: vec!["g".into()],
            steps: 10,
            ..Default::default()
        };
        let stop = Arc::new(AtomicBool::new(false));
        let (b2, p2, s2) = (bus.clone(), path.clone(), stop.clone());
        let h = std::thread::spawn(move || {
            record(
                b2,
                "held",
                &p2,
                &RunMetadata::default(),
                &["flow".to_string()],
                &plan,
                s2,
            )
        });
        assert!(hb.recv::<Heartbeat>(Duration::from_secs(10)).is_some());
        bus.publish(&t.fiber_state("g"), &encode(&tidy_state("g", 0)))
            .unwrap();
        std::thread::sleep(Duration::from_millis(300));
        stop.store(true, Ordering::SeqCst);
        h.join()
            .expect("recorder panicked")
            .expect("recorder failed");
        let bytes = std::fs::read(&path).unwrap();
        let states = mcap::MessageStream::new(&bytes)
            .unwrap()
            .filter(|m| {
                m.as_ref()
                    .is_ok_and(|m| m.channel.topic == t.fiber_state("g"))
            })
            .count();
        assert_eq!(states, 0, "the held step 0 was written");
        std::fs::remove_file(&path).ok();
    }

    fn topic_for(t: &Topics, kind: Kind, group: &str) -> String {
        match kind {
            Kind::RunAnnouncement => t.announce(),
            Kind::FlowStatus => t.flow_status(),
            Kind::FlowProfiles => t.flow_profiles(),
            Kind::FlowSamples => t.flow_samples(group),
            Kind::FlowSlice => t.flow_slice("streaks"),
            Kind::FiberGroupState => t.fiber_state(group),
            Kind::FiberGroupMetrics => t.fiber_metrics(group),
            _ => t.heartbeat(group),
        }
    }

    /// The recorded steps: out of order within the window exactly as a set, older steps as
    /// recorded, and memory bounded by the window however many steps pass.
    #[test]
    fn recorded_steps_are_exact_within_the_window_and_bounded() {
        let mut r = Recorded::default();
        assert!(!r.contains("t", 0, 0));
        assert!(r.insert("t", 5, 0));
        assert!(r.insert("t", 3, 0), "an older step not yet recorded");
        assert!(!r.insert("t", 3, 0) && !r.insert("t", 5, 0));
        assert!(!r.contains("t", 4, 0) && r.insert("t", 4, 0));
        assert!(r.insert("t", 5, 1), "another slice");
        assert!(r.insert("u", 5, 0), "another topic");
        for k in 6..200_000u64 {
            assert!(r.insert("t", k, 0));
        }
        assert!(
            r.contains("t", 7, 0),
            "far below the newest counts as recorded"
        );
        assert!(!r.contains("t", 200_000, 0));
        assert!(r.remembered() <= RECORDED_WINDOW_STEPS as usize + 3);
    }

    /// 10^5 random messages of every type (valid CDR, random lengths and values) through
    /// the recorder's handler on a live in-process bus: it never panics, drops at least
    /// every message the checks refuse, and what it writes all passes the checks.
    #[test]
    fn recorder_survives_random_structured_messages() {
        let bus: BusHandle = Arc::new(InprocBus::new());
        let t = Topics::new("fz");
        let groups = vec!["case1".to_string(), "case2".to_string()];
        let path = std::env::temp_dir().join(format!("ff-rec-fuzz-{}.mcap", std::process::id()));
        let mut hb = Inbox::new(bus.subscribe(&t.heartbeat("recorder")).unwrap());
        let plan = RecordPlan {
            groups: groups.clone(),
            steps: 400,
            ..Default::default()
        };
        let h = start_recorder(&bus, "fz", &path, plan, &mut hb);
        let mut r = Rng::new(11);
        let mut refused = 0u64;
        let names = [
            groups[0].clone(),
            groups[1].clone(),
            "flow".into(),
            "x".into(),
        ];
        for i in 0..100_000usize {
            let ty = KINDS[i % KINDS.len()];
            if ty == Kind::FiberFreeStep || ty == Kind::FiberContactSolved {
                // the shards' contact exchange: the recorder does not subscribe to it
                continue;
            }
            let b = random_payload(ty, &mut r, &groups);
            if sanity::check_payload(ty, &b).is_err() {
                refused += 1;
            }
            bus.publish(&topic_for(&t, ty, &names[i % names.len()]), &b)
                .unwrap();
        }
        let done = Heartbeat {
            schema_version: SCHEMA_VERSION,
            node: "flow".into(),
            state: Lifecycle::Done,
            step: 400,
            dropped: 0,
        };
        bus.publish(&t.heartbeat("flow"), &encode(&done)).unwrap();
        let s = h
            .join()
            .expect("recorder panicked")
            .expect("recorder failed");
        assert!(
            refused > 50_000,
            "the generator should mostly make nonsense ({refused})"
        );
        assert!(
            s.drops.total() >= refused,
            "{} dropped, {refused} refused",
            s.drops.total()
        );
        let bytes = std::fs::read(&path).unwrap();
        let mut written = 0;
        let (mut slices, mut images) = (0, 0);
        for m in mcap::MessageStream::new(&bytes).unwrap() {
            let m = m.unwrap();
            if let Some(ty) = kind_of(&m.channel.topic) {
                assert!(
                    sanity::check_payload(ty, &m.data).is_ok(),
                    "{}",
                    m.channel.topic
                );
                written += 1;
                slices += usize::from(ty == Kind::FlowSlice);
            }
            if m.channel.topic == t.flow_slice_image("streaks") {
                let img: image::Image = cdr::deserialize(&m.data).unwrap();
                assert_eq!(img.data.len(), (img.step * img.height) as usize);
                assert!(img.width >= 1 && img.height >= 1);
                images += 1;
            }
        }
        assert!(written > 1000, "only {written} sensible messages recorded");
        // every slice recorded got its image, and only those
        assert!(
            slices > 0 && images == slices,
            "{slices} slices, {images} images"
        );
        std::fs::remove_file(&path).ok();
    }

    fn tidy_state(group: &str, step: u64) -> FiberGroupState {
        FiberGroupState {
            schema_version: SCHEMA_VERSION,
            group: group.into(),
            step,
            t_plus: step as f64 * 0.25,
            first_fiber: 0,
            group_fibers: 1,
            segments_per_fiber: vec![2],
            segment_length: vec![3.0],
            diameter: vec![0.2],
            density_ratio: vec![800.0],
            layer: vec![0],
            centre: vec![0.0, 1.0, 2.0, 3.0, 1.0, 2.0],
            axis: vec![1.0, 0.0, 0.0, 1.0, 0.0, 0.0],
            velocity: vec![0.0; 6],
            angular_velocity: vec![0.0; 6],
            hydro_force: vec![],
            contact_segment: vec![],
            contact_force: vec![],
            contacts: vec![],
        }
    }

    /// The same states recorded with each `[recorder] compression`: each file's chunks
    /// carry that compression, `inspect` reads it whole, and all three hold the same
    /// messages byte for byte.
    #[test]
    fn every_compression_records_the_same_messages() {
        let runs: [(&'static str, ChunkCompression, &str); 3] = [
            ("cz", ChunkCompression::Zstd, "zstd"),
            ("cl", ChunkCompression::Lz4, "lz4"),
            ("cn", ChunkCompression::None, ""),
        ];
        let mut read_back = Vec::new();
        for (run, compression, name) in runs {
            let bus: BusHandle = Arc::new(InprocBus::new());
            let t = Topics::new(run);
            let path =
                std::env::temp_dir().join(format!("ff-rec-{run}-{}.mcap", std::process::id()));
            let mut hb = Inbox::new(bus.subscribe(&t.heartbeat("recorder")).unwrap());
            let plan = RecordPlan {
                groups: vec!["g".into()],
                steps: 5,
                compression,
                ..Default::default()
            };
            let h = start_recorder(&bus, run, &path, plan, &mut hb);
            for k in 0..=5u64 {
                bus.publish(&t.fiber_state("g"), &encode(&tidy_state("g", k)))
                    .unwrap();
            }
            let done = Heartbeat {
                schema_version: SCHEMA_VERSION,
                node: "flow".into(),
                state: Lifecycle::Done,
                step: 5,
                dropped: 0,
            };
            bus.publish(&t.heartbeat("flow"), &encode(&done)).unwrap();
            h.join()
                .expect("recorder panicked")
                .expect("recorder failed");
            let bytes = std::fs::read(&path).unwrap();
            let mut kinds = std::collections::BTreeSet::new();
            for rec in mcap::read::LinearReader::new(&bytes).unwrap() {
                if let mcap::records::Record::Chunk { header, .. } = rec.unwrap() {
                    kinds.insert(header.compression);
                }
            }
            assert_eq!(
                kinds.into_iter().collect::<Vec<_>>(),
                vec![name.to_string()]
            );
            let inspection = crate::recover::inspect(&path).unwrap();
            assert!(inspection.damage.is_none(), "{:?}", inspection.damage);
            let states: Vec<Vec<u8>> = mcap::MessageStream::new(&bytes)
                .unwrap()
                .map(|m| m.unwrap())
                .filter(|m| m.channel.topic == t.fiber_state("g"))
                .map(|m| m.data.into_owned())
                .collect();
            assert_eq!(states.len(), 6, "{name}");
            assert_eq!(
                inspection.channels[&t.fiber_state("g")].1,
                6,
                "{name}: inspect counts"
            );
            read_back.push(states);
            std::fs::remove_file(&path).ok();
        }
        assert!(read_back[0] == read_back[1] && read_back[0] == read_back[2]);
    }

    /// `states_every_steps = 4`, `samples = false` over 10 steps, states lean where the plan
    /// leaves them out: complete states (and PointCloud2) of steps 0, 4, 8 and the last
    /// step 10 only, a lean state at a recorded step dropped and counted, no samples,
    /// metrics every step, and the plan written into the file's metadata; its checkpoints
    /// of steps 4 and 8 are committed and said (COMMITTED heartbeats).
    #[test]
    fn decimated_recording_keeps_every_kth_state_and_the_last() {
        use fiberflow_messages::{FiberGroupMetrics, FlowSamples};
        let bus: BusHandle = Arc::new(InprocBus::new());
        let t = Topics::new("dec");
        let path = std::env::temp_dir().join(format!("ff-rec-dec-{}.mcap", std::process::id()));
        let mut hb = Inbox::new(bus.subscribe(&t.heartbeat("recorder")).unwrap());
        let ck_root = std::env::temp_dir().join(format!("ff-rec-dec-ck-{}", std::process::id()));
        let plan = RecordPlan {
            groups: vec!["g".into()],
            steps: 10,
            states_every_steps: 4,
            samples: false,
            checkpoint_every: 4,
            checkpoint_root: Some(ck_root.clone()),
            ..Default::default()
        };
        let h = start_recorder(&bus, "dec", &path, plan, &mut hb);
        for k in 0..=10u64 {
            // as a fibre node sends them: lean (centres only) where the plan leaves the
            // state out; at step 8 a stray lean state comes first and is dropped
            let full = tidy_state("g", k);
            let mut lean = full.clone();
            lean.axis.clear();
            lean.velocity.clear();
            lean.angular_velocity.clear();
            if k == 8 || !(k % 4 == 0 || k == 10) {
                bus.publish(&t.fiber_state("g"), &encode(&lean)).unwrap();
            }
            if k % 4 == 0 || k == 10 {
                bus.publish(&t.fiber_state("g"), &encode(&full)).unwrap();
            }
            let m = FiberGroupMetrics {
                schema_version: SCHEMA_VERSION,
                group: "g".into(),
                step: k,
                t_plus: k as f64 * 0.25,
                first_fiber: 0,
                group_fibers: 1,
                centre_of_mass: vec![0.0; 3],
                z1: vec![1.0],
                sigma2: vec![0.0],
                end_to_end: vec![3.0],
                mean_abs_z1: 1.0,
                mean_sigma2: 0.0,
            };
            bus.publish(&t.fiber_metrics("g"), &encode(&m)).unwrap();
            if k > 0 {
                // the flow node's status of step k (published after its samples of k - 1)
                let st = fiberflow_messages::FlowStatus {
                    schema_version: SCHEMA_VERSION,
                    step: k,
                    t_plus: k as f64 * 0.25,
                    dt_plus: 0.25,
                    cfl: 0.5,
                    max_divergence: 0.0,
                    bulk_velocity: 15.0,
                    re_tau: 150.0,
                    pressure_gradient: 1.0,
                    fiber_force_plus: vec![],
                };
                bus.publish(&t.flow_status(), &encode(&st)).unwrap();
            }
            if k < 10 {
                let s = FlowSamples {
                    schema_version: SCHEMA_VERSION,
                    group: "g".into(),
                    step: k,
                    t_plus: k as f64 * 0.25,
                    first_fiber: 0,
                    group_fibers: 1,
                    velocity: vec![0.0; 6],
                    velocity_gradient: vec![0.0; 18],
                };
                bus.publish(&t.flow_samples("g"), &encode(&s)).unwrap();
            }
        }
        let done = Heartbeat {
            schema_version: SCHEMA_VERSION,
            node: "flow".into(),
            state: Lifecycle::Done,
            step: 10,
            dropped: 0,
        };
        bus.publish(&t.heartbeat("flow"), &encode(&done)).unwrap();
        let s = h
            .join()
            .expect("recorder panicked")
            .expect("recorder failed");
        assert_eq!(s.drops.total(), 1, "{:?}", s.drops);
        assert_eq!(s.drops.by_topic.get(&t.fiber_state("g")), Some(&1));
        // 7 lean states left out; the samples are not even subscribed to
        assert_eq!(s.decimated, 7);
        let bytes = std::fs::read(&path).unwrap();
        let mut state_steps = Vec::new();
        let (mut points, mut metrics, mut samples) = (0, 0, 0);
        for m in mcap::MessageStream::new(&bytes).unwrap() {
            let m = m.unwrap();
            let topic = m.channel.topic.as_str();
            if topic == t.fiber_state("g") {
                state_steps.push(decode::<FiberGroupState>(&m.data).unwrap().step);
            } else if topic == t.fiber_points("g") {
                points += 1;
            } else if topic == t.fiber_metrics("g") {
                metrics += 1;
            } else if topic == t.flow_samples("g") {
                samples += 1;
            }
        }
        assert_eq!(state_steps, vec![0, 4, 8, 10]);
        assert_eq!((points, metrics, samples), (4, 11, 0));
        let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
        let idx = summary
            .metadata_indexes
            .iter()
            .find(|i| i.name == "fiberflow.recording")
            .expect("recording plan in the metadata");
        let meta = mcap::read::metadata(&bytes, idx).unwrap();
        assert_eq!(meta.metadata["states_every_steps"], "4");
        assert_eq!(meta.metadata["samples"], "false");
        // the recorder's share of checkpoints 4 and 8 is committed without samples (the
        // flow node's status of a later step stands in for them), and said on the bus
        for c in [4u64, 8] {
            let piece = checkpoints::piece(&checkpoints::step_dir(&ck_root, c), "recorder");
            let text = std::fs::read_to_string(&piece).expect("recorder checkpoint piece");
            assert!(text.contains(&format!("step = {c}")), "{text}");
        }
        let mut committed = BTreeSet::new();
        while let Some((_, b)) = hb.recv::<Heartbeat>(Duration::ZERO) {
            if b.state == Lifecycle::Committed {
                committed.insert(b.step);
            }
        }
        assert_eq!(committed, BTreeSet::from([4, 8]));
        std::fs::remove_dir_all(&ck_root).ok();
        std::fs::remove_file(&path).ok();
    }
}
