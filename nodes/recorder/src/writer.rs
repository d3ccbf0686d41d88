//! The recording's file: an MCAP segment opened with the run's metadata and provenance,
//! its schema and channel tables, and messages written at their simulation time.

use crate::{direct, write_options, RecordPlan, RecorderError, RunMetadata};
use fiberflow_messages::{schema, SCHEMA_VERSION};
use std::collections::{BTreeMap, HashMap};
use std::path::Path;

/// Simulation time in nanoseconds on the MCAP timeline: 1 t+ = 1 s.
pub fn t_plus_to_nanos(t_plus: f64) -> u64 {
    (t_plus.max(0.0) * 1e9).round() as u64
}

pub(crate) struct Out {
    pub(crate) w: mcap::Writer<direct::RecordingFile>,
    pub(crate) path: String,
    pub(crate) schemas: HashMap<&'static str, u16>,
    pub(crate) channels: HashMap<String, u16>,
    pub(crate) seq: u32,
}

impl Out {
    pub(crate) fn err(&self) -> impl Fn(mcap::McapError) -> RecorderError + '_ {
        move |source| RecorderError::Mcap {
            path: self.path.clone(),
            source,
        }
    }

    pub(crate) fn channel(
        &mut self,
        topic: &str,
        type_name: &'static str,
    ) -> Result<u16, RecorderError> {
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

    pub(crate) fn write(
        &mut self,
        channel: u16,
        log_time: u64,
        data: &[u8],
    ) -> Result<(), RecorderError> {
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

/// Creates the MCAP file at `path` (and its folder) with the run's provenance and the
/// recording plan as metadata.
pub(crate) fn open_recording(
    path: &Path,
    meta: &RunMetadata,
    plan: &RecordPlan,
) -> Result<Out, RecorderError> {
    let pstr = path.display().to_string();
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|source| RecorderError::Io {
            path: pstr.clone(),
            source,
        })?;
    }
    let file = direct::RecordingFile::create(path).map_err(|source| RecorderError::Io {
        path: pstr.clone(),
        source,
    })?;
    let opts = write_options(plan.compression, &meta.software_version);
    let w = opts.create(file).map_err(|source| RecorderError::Mcap {
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
    let mut rec = BTreeMap::new();
    rec.insert(
        "states_every_steps".to_string(),
        plan.states_every_steps.max(1).to_string(),
    );
    rec.insert("samples".to_string(), plan.samples.to_string());
    out.w
        .write_metadata(&mcap::records::Metadata {
            name: "fiberflow.recording".into(),
            metadata: rec,
        })
        .map_err(out.err())?;
    Ok(out)
}

pub(crate) fn write_provenance(out: &mut Out, meta: &RunMetadata) -> Result<(), RecorderError> {
    let mut m = BTreeMap::new();
    m.insert("run_id".to_string(), meta.run_id.clone());
    m.insert(
        "software_version".to_string(),
        meta.software_version.clone(),
    );
    m.insert("git_commit".to_string(), meta.git_commit.clone());
    m.insert("schema_version".to_string(), SCHEMA_VERSION.to_string());
    m.insert(
        "transport".to_string(),
        meta.transport.map(|t| t.to_string()).unwrap_or_default(),
    );
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
