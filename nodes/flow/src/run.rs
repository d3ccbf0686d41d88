//! What a run is, as every node is told it by the launcher, and what the flow node's loop
//! reports at its end.

use fiberflow_bus::DropCounter;
use fiberflow_messages::pieces::Piece;
use std::path::PathBuf;

/// Run-level facts the launcher hands to every node.
#[derive(Debug, Clone, PartialEq)]
pub struct RunInfo {
    pub run_id: String,
    pub config_digest: String,
    pub groups: Vec<String>,
    /// Nodes that must join before the run starts (groups and, if any, the recorder).
    pub expected_nodes: Vec<String>,
    pub steps: u64,
    pub box_plus: [f64; 3],
    /// Seconds to wait for a group's state at one step before giving up.
    pub step_timeout_s: f64,
    /// A fibre node not heard from (no heartbeat, no pulse) for this many seconds while
    /// its state is awaited is gone: the step fails at once, naming it (0: only the step
    /// timeout).
    pub liveness_s: f64,
    /// First coupling step: 0, or the step of the checkpoint the run resumes from.
    pub start_step: u64,
    /// The checkpoint folder the run resumes from (its step is `start_step`).
    pub resume_dir: Option<PathBuf>,
    /// Coupled checkpoints: every this many steps (0 = never) under this folder.
    pub checkpoint_every: u64,
    pub checkpoint_root: Option<PathBuf>,
    /// Every fibre node's share of its group (one piece per unsharded group): the flow
    /// node waits for a state of each at every step, samples each on its own.
    pub pieces: Vec<Piece>,
    /// Where every step's wall and stages go as CSV at the end of the run (None: kept
    /// nowhere).
    pub step_times: Option<PathBuf>,
    /// Two-way coupling: the fibres' forces of every state go back to the fluid.
    pub two_way: bool,
    /// Multi-host runs: the fibre nodes (and the recorder) on other hosts (node, host),
    /// whose checkpoints are written there; the flow node confirms them in its own
    /// ([`fiberflow_messages::checkpoints::REMOTE_PIECE`]).
    pub remote_pieces: Vec<(String, String)>,
    /// In-process runs: set by the launcher when another node of the run failed; the
    /// flow node's waits then end at once.
    pub stop: Option<Stop>,
}

/// A stop flag shared with the launcher (equal when it is the same flag).
#[derive(Debug, Clone)]
pub struct Stop(pub std::sync::Arc<std::sync::atomic::AtomicBool>);

impl Stop {
    pub fn is_set(&self) -> bool {
        self.0.load(std::sync::atomic::Ordering::SeqCst)
    }
}

impl PartialEq for Stop {
    fn eq(&self, other: &Self) -> bool {
        std::sync::Arc::ptr_eq(&self.0, &other.0)
    }
}

/// What the loop did.
#[derive(Debug, Clone, PartialEq)]
pub struct ServeSummary {
    pub steps: u64,
    pub drops: DropCounter,
}
