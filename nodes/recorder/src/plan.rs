//! What the recorder is told of a run beyond its topics, and how it compresses.

use std::path::PathBuf;

/// What the recorder needs to know of the run beyond its topics.
#[derive(Debug, Clone, Default)]
pub struct RecordPlan {
    /// Fibre groups of the run.
    pub groups: Vec<String>,
    /// (group, first fibre) of every fibre node (empty: one per group).
    pub pieces: Vec<(String, u32)>,
    /// Fibre node names (a group's name, or `<group>.<i>` for a shard).
    pub nodes: Vec<String>,
    /// Coupling steps of the run.
    pub steps: u64,
    /// Coupled checkpoints: every this many steps (0 = never) under `checkpoint_root`.
    pub checkpoint_every: u64,
    pub checkpoint_root: Option<PathBuf>,
    /// The step the run (re)starts from.
    pub start_step: u64,
    /// Segments recorded before this one: what they hold is not written again, so the
    /// segments together hold every step-stamped message exactly once.
    pub previous_segments: Vec<PathBuf>,
    /// Full states (and their PointCloud2) every this many steps, plus the first and the
    /// last step (0 counts as 1).
    pub states_every_steps: u64,
    /// Record the flow samples.
    pub samples: bool,
    /// How the file's chunks are compressed.
    pub compression: ChunkCompression,
}

/// `[recorder] compression`: how the MCAP chunks are compressed. zstd (level 1) makes the
/// smallest files; lz4 costs the recorder a fraction of zstd's CPU; none writes the
/// messages as they are (the costs: docs/history/performance.md, "From the code's
/// comments"). Rerun, Foxglove and the Python `mcap` reader open all three.
#[derive(
    Debug,
    Clone,
    Copy,
    Default,
    PartialEq,
    Eq,
    serde::Serialize,
    serde::Deserialize,
    schemars::JsonSchema,
)]
#[serde(rename_all = "lowercase")]
pub enum ChunkCompression {
    #[default]
    Zstd,
    Lz4,
    None,
}

/// The zstd level of the chunks (1, the fastest; mcap's default would be 3).
const ZSTD_LEVEL: u32 = 1;

/// The MCAP writer's options of a recording: chunks of 4 MB compressed as `compression`
/// says, written in file order.
pub fn write_options(compression: ChunkCompression, software_version: &str) -> mcap::WriteOptions {
    mcap::WriteOptions::new()
        .compression(compression.mcap())
        // zstd's fastest level: the numbers in these files are mostly mantissas that no
        // level compresses much
        .compression_level(ZSTD_LEVEL)
        .chunk_size(Some(4 * 1024 * 1024))
        // each chunk is built in memory and written after its header, in file order
        .disable_seeking(true)
        .profile("ros2")
        .library(format!("fiberflow {software_version}"))
}

impl ChunkCompression {
    fn mcap(self) -> Option<mcap::Compression> {
        match self {
            Self::Zstd => Some(mcap::Compression::Zstd),
            Self::Lz4 => Some(mcap::Compression::Lz4),
            Self::None => None,
        }
    }
}

impl RecordPlan {
    /// Is a state of step `k` recorded?
    pub fn keeps_state(&self, k: u64) -> bool {
        k.is_multiple_of(self.states_every_steps.max(1)) || k == self.steps
    }
}
