//! The recorder: subscribes to everything under a run's prefix and writes a chunked,
//! zstd-compressed, indexed MCAP with ros2msg schemas, storing payloads as received;
//! derives a `sensor_msgs/PointCloud2` channel per fibre group for generic viewers;
//! flushes a chunk at least every second so a killed recorder loses at most that much.

pub mod pointcloud;
pub mod recover;

use fiberflow_bus::{BusHandle, DropCounter, Inbox};
use fiberflow_messages::topics::{type_of, Topics};
use fiberflow_messages::{
    decode, encode, lifecycle, schema, FiberGroupState, Heartbeat, SCHEMA_VERSION,
};
use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::io::BufWriter;
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
    pub transport: String,
}

/// What was recorded.
#[derive(Debug, Clone, Default)]
pub struct RecordSummary {
    pub messages: u64,
    pub by_topic: BTreeMap<String, u64>,
    pub drops: DropCounter,
    pub path: PathBuf,
}

struct Out {
    w: mcap::Writer<BufWriter<std::fs::File>>,
    path: String,
    schemas: HashMap<&'static str, u16>,
    channels: HashMap<String, u16>,
    seq: u32,
}

impl Out {
    fn err(&self) -> impl Fn(mcap::McapError) -> RecorderError + '_ {
        move |source| RecorderError::Mcap {
            path: self.path.clone(),
            source,
        }
    }

    fn channel(&mut self, topic: &str, type_name: &'static str) -> Result<u16, RecorderError> {
        if let Some(&c) = self.channels.get(topic) {
            return Ok(c);
        }
        let sid = match self.schemas.get(type_name) {
            Some(&s) => s,
            None => {
                let s = self
                    .w
                    .add_schema(type_name, "ros2msg", schema::text(type_name).as_bytes())
                    .map_err(|source| RecorderError::Mcap {
                        path: self.path.clone(),
                        source,
                    })?;
                self.schemas.insert(type_name, s);
                s
            }
        };
        let mut meta = BTreeMap::new();
        meta.insert("schema_version".to_string(), SCHEMA_VERSION.to_string());
        let c = self
            .w
            .add_channel(sid, topic, "cdr", &meta)
            .map_err(|source| RecorderError::Mcap {
                path: self.path.clone(),
                source,
            })?;
        self.channels.insert(topic.to_string(), c);
        Ok(c)
    }

    fn write(&mut self, channel: u16, log_time: u64, data: &[u8]) -> Result<(), RecorderError> {
        self.seq = self.seq.wrapping_add(1);
        // log time: simulation time (1 t+ = 1 s); publish time: wall clock of receipt
        let wall = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_nanos() as u64)
            .unwrap_or(0);
        let header = mcap::records::MessageHeader {
            channel_id: channel,
            sequence: self.seq,
            log_time,
            publish_time: wall,
        };
        let path = self.path.clone();
        self.w
            .write_to_known_channel(&header, data)
            .map_err(|source| RecorderError::Mcap { path, source })
    }
}

/// Simulation time in nanoseconds on the MCAP timeline: 1 t+ = 1 s.
pub fn t_plus_to_nanos(t_plus: f64) -> u64 {
    (t_plus.max(0.0) * 1e9).round() as u64
}

/// How long the recorder waits, after the flow node's DONE, for anything more to arrive.
const QUIET_AFTER_FLOW_DONE: Duration = Duration::from_secs(3);

/// Records until every node in `expect_done` has reported DONE (or FAILED), or `stop` is set.
/// Announces itself as node `recorder` until the run starts.
pub fn record(
    bus: BusHandle,
    run_id: &str,
    path: &Path,
    meta: &RunMetadata,
    expect_done: &[String],
    stop: Arc<AtomicBool>,
) -> Result<RecordSummary, RecorderError> {
    let t = Topics::new(run_id);
    let pstr = path.display().to_string();
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|source| RecorderError::Io {
            path: pstr.clone(),
            source,
        })?;
    }
    let file = std::fs::File::create(path).map_err(|source| RecorderError::Io {
        path: pstr.clone(),
        source,
    })?;
    let opts = mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Zstd))
        .chunk_size(Some(4 * 1024 * 1024))
        .profile("ros2")
        .library(format!("fiberflow {}", meta.software_version));
    let w = opts
        .create(BufWriter::new(file))
        .map_err(|source| RecorderError::Mcap {
            path: pstr.clone(),
            source,
        })?;
    let mut out = Out {
        w,
        path: pstr.clone(),
        schemas: HashMap::new(),
        channels: HashMap::new(),
        seq: 0,
    };
    write_provenance(&mut out, meta)?;
    let mut inbox = Inbox::new(bus.subscribe(&format!("{}/**", t.prefix()))?);
    let mut summary = RecordSummary {
        path: path.to_path_buf(),
        ..Default::default()
    };
    let mut done: BTreeSet<String> = BTreeSet::new();
    let expected: BTreeSet<String> = expect_done.iter().cloned().collect();
    let mut started = false;
    let mut last_flush = Instant::now();
    let mut last_hb = Instant::now() - Duration::from_secs(1);
    let mut sim_nanos: u64 = 0;
    let mut finish_at: Option<Instant> = None;
    // once the flow node is DONE the run is over: a DONE lost in transit must not keep the
    // recorder open, so it also finishes after QUIET_AFTER_FLOW_DONE without any message
    let mut flow_done = false;
    let mut last_message = Instant::now();
    loop {
        if stop.load(Ordering::SeqCst) {
            tracing::info!("recorder stopping on signal");
            break;
        }
        if let Some(f) = finish_at {
            if Instant::now() > f {
                break;
            }
        }
        if !started && last_hb.elapsed() > Duration::from_millis(200) {
            let hb = Heartbeat {
                schema_version: SCHEMA_VERSION,
                node: "recorder".into(),
                state: lifecycle::READY,
                step: 0,
                dropped: inbox.drops.total(),
            };
            bus.publish(&t.heartbeat("recorder"), &encode(&hb))?;
            last_hb = Instant::now();
        }
        if last_flush.elapsed() >= Duration::from_millis(500) {
            out.w.flush().map_err(out.err())?;
            last_flush = Instant::now();
        }
        let Some((topic, bytes)) = inbox.recv_raw(Duration::from_millis(50)) else {
            if flow_done && finish_at.is_none() && last_message.elapsed() > QUIET_AFTER_FLOW_DONE {
                let missing: Vec<_> = expected.difference(&done).cloned().collect();
                tracing::warn!(nodes = %missing.join(", "), "no DONE from these nodes; finishing after the flow node's DONE");
                break;
            }
            continue;
        };
        last_message = Instant::now();
        let Some(type_name) = type_of(&topic) else {
            inbox
                .drops
                .drop_one(&topic, "topic carries no known message type");
            continue;
        };
        if let Err(e) = schema::validate(type_name, &bytes) {
            inbox.drops.drop_one(&topic, &e.to_string());
            continue;
        }
        match type_name {
            "fiberflow_msgs/msg/RunAnnouncement" => started = true,
            "fiberflow_msgs/msg/Heartbeat" => {
                if let Ok(hb) = decode::<Heartbeat>(&bytes) {
                    if hb.state == lifecycle::DONE || hb.state == lifecycle::FAILED {
                        flow_done |= hb.node == "flow";
                        done.insert(hb.node);
                        if expected.is_subset(&done) && finish_at.is_none() {
                            finish_at = Some(Instant::now() + Duration::from_millis(500));
                        }
                    }
                }
            }
            _ => {}
        }
        let st = if type_name == "fiberflow_msgs/msg/FiberGroupState" {
            decode::<FiberGroupState>(&bytes).ok()
        } else {
            None
        };
        if let Some(s) = &st {
            sim_nanos = sim_nanos.max(t_plus_to_nanos(s.t_plus));
        }
        let c = out.channel(&topic, type_name)?;
        out.write(c, sim_nanos, &bytes)?;
        summary.messages += 1;
        *summary.by_topic.entry(topic.clone()).or_insert(0) += 1;
        if let Some(s) = st {
            let pc = pointcloud::from_state(&s);
            let ptopic = t.fiber_points(&s.group);
            let c = out.channel(&ptopic, schema::POINT_CLOUD2_NAME)?;
            out.write(c, sim_nanos, &pc)?;
        }
    }
    // drain what is already queued
    while let Ok((topic, bytes)) = inbox.sub.rx.try_recv() {
        if let Some(type_name) = type_of(&topic) {
            if schema::validate(type_name, &bytes).is_ok() {
                let c = out.channel(&topic, type_name)?;
                out.write(c, sim_nanos, &bytes)?;
                summary.messages += 1;
                continue;
            }
        }
        inbox.drops.drop_one(&topic, "undecodable");
    }
    let mut drops_meta = BTreeMap::new();
    for (k, v) in &inbox.drops.by_topic {
        drops_meta.insert(k.clone(), v.to_string());
    }
    out.w
        .write_metadata(&mcap::records::Metadata {
            name: "fiberflow.drops".into(),
            metadata: drops_meta,
        })
        .map_err(out.err())?;
    out.w.finish().map_err(out.err())?;
    summary.drops = inbox.drops.clone();
    // the file is complete: tell the run (a zenoh router waits for this before closing)
    let hb = Heartbeat {
        schema_version: SCHEMA_VERSION,
        node: "recorder".into(),
        state: lifecycle::DONE,
        step: 0,
        dropped: inbox.drops.total(),
    };
    if let Err(e) = bus.publish(&t.heartbeat("recorder"), &encode(&hb)) {
        tracing::warn!(error = %e, "could not announce the finished recording");
    }
    Ok(summary)
}

fn write_provenance(out: &mut Out, meta: &RunMetadata) -> Result<(), RecorderError> {
    let mut m = BTreeMap::new();
    m.insert("run_id".to_string(), meta.run_id.clone());
    m.insert(
        "software_version".to_string(),
        meta.software_version.clone(),
    );
    m.insert("git_commit".to_string(), meta.git_commit.clone());
    m.insert("schema_version".to_string(), SCHEMA_VERSION.to_string());
    m.insert("transport".to_string(), meta.transport.clone());
    m.insert("launch_file".to_string(), meta.launch_file_name.clone());
    out.w
        .write_metadata(&mcap::records::Metadata {
            name: "fiberflow.run".into(),
            metadata: m,
        })
        .map_err(out.err())?;
    let mut cfgs = BTreeMap::new();
    for (k, v) in &meta.node_configs {
        cfgs.insert(k.clone(), v.clone());
    }
    out.w
        .write_metadata(&mcap::records::Metadata {
            name: "fiberflow.node_configs".into(),
            metadata: cfgs,
        })
        .map_err(out.err())?;
    if !meta.launch_text.is_empty() {
        out.w
            .attach(&mcap::Attachment {
                log_time: 0,
                create_time: 0,
                name: meta.launch_file_name.clone(),
                media_type: "application/toml".into(),
                data: std::borrow::Cow::Borrowed(meta.launch_text.as_bytes()),
            })
            .map_err(out.err())?;
    }
    Ok(())
}
