//! Topic names: slash paths under `fiberflow/<run>/`, identical to Rerun entity paths and
//! (with `/` kept) to iceoryx2 service names.

use crate::kind::Kind;

/// The flow slices the flow node publishes: the wall-parallel plane of u' near the lower
/// wall and the y–z cross-section at x = 0.
/// The flow slices: u' near the wall, u' across the channel, and (two-way runs only) the
/// fibres' streamwise force on the fluid in the streaks' plane.
pub const FLOW_SLICE_NAMES: [&str; 3] = ["streaks", "cross_section", "fiber_force"];

/// Topic builder for one run.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Topics {
    pub run: String,
}

impl Topics {
    pub fn new(run: &str) -> Self {
        Self {
            run: run.to_string(),
        }
    }
    pub fn prefix(&self) -> String {
        format!("fiberflow/{}", self.run)
    }
    pub fn announce(&self) -> String {
        format!("fiberflow/{}/control/announce", self.run)
    }
    pub fn heartbeat(&self, node: &str) -> String {
        format!("fiberflow/{}/control/heartbeat/{node}", self.run)
    }
    pub fn flow_status(&self) -> String {
        format!("fiberflow/{}/flow/status", self.run)
    }
    pub fn flow_profiles(&self) -> String {
        format!("fiberflow/{}/flow/profiles", self.run)
    }
    /// A flow slice for viewers (`name` one of [`FLOW_SLICE_NAMES`]).
    pub fn flow_slice(&self, name: &str) -> String {
        format!("fiberflow/{}/flow/slices/{name}", self.run)
    }
    /// The recorder's `sensor_msgs/Image` rendering of a flow slice (not on the bus).
    pub fn flow_slice_image(&self, name: &str) -> String {
        format!("fiberflow/{}/flow/slices/{name}/image", self.run)
    }
    pub fn flow_samples(&self, group: &str) -> String {
        format!("fiberflow/{}/flow/samples/{group}", self.run)
    }
    pub fn fiber_state(&self, group: &str) -> String {
        format!("fiberflow/{}/fibers/{group}/state", self.run)
    }
    pub fn fiber_metrics(&self, group: &str) -> String {
        format!("fiberflow/{}/fibers/{group}/metrics", self.run)
    }
    /// One piece's free step, for the contact solve of its group's other pieces
    /// ([`crate::FiberFreeStep`]; outside `fibers/` so that the recorder, which records
    /// `fibers/**`, does not subscribe to it).
    pub fn contact_free_step(&self, group: &str, first_fiber: u32) -> String {
        format!("fiberflow/{}/contact/{group}/{first_fiber}", self.run)
    }
    /// What the contact solve did to one piece ([`crate::FiberContactSolved`], from the
    /// suspension's first piece; not recorded, as [`Self::contact_free_step`]).
    pub fn contact_solved(&self, group: &str, first_fiber: u32) -> String {
        format!(
            "fiberflow/{}/contact/{group}/{first_fiber}/solved",
            self.run
        )
    }
    /// PointCloud2 channel the recorder derives for viewers (not published on the bus).
    pub fn fiber_points(&self, group: &str) -> String {
        format!("fiberflow/{}/fibers/{group}/points", self.run)
    }
}

/// Which kind of message a topic carries (by its path shape), for decoders and the
/// recorder.
pub fn kind_of(topic: &str) -> Option<Kind> {
    let parts: Vec<&str> = topic.split('/').collect();
    if parts.len() < 4 || parts[0] != "fiberflow" {
        return None;
    }
    match (parts[2], parts.len()) {
        ("control", 4) if parts[3] == "announce" => Some(Kind::RunAnnouncement),
        ("control", 5) if parts[3] == "heartbeat" => Some(Kind::Heartbeat),
        ("flow", 4) if parts[3] == "status" => Some(Kind::FlowStatus),
        ("flow", 4) if parts[3] == "profiles" => Some(Kind::FlowProfiles),
        ("flow", 5) if parts[3] == "slices" => Some(Kind::FlowSlice),
        // flow/samples/<group>, or flow/samples/<group>/<shard> for a sharded group
        ("flow", 5 | 6) if parts[3] == "samples" => Some(Kind::FlowSamples),
        ("fibers", 5) if parts[4] == "state" => Some(Kind::FiberGroupState),
        ("fibers", 5) if parts[4] == "metrics" => Some(Kind::FiberGroupMetrics),
        ("contact", 5) => Some(Kind::FiberFreeStep),
        ("contact", 6) if parts[5] == "solved" => Some(Kind::FiberContactSolved),
        _ => None,
    }
}
