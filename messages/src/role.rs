//! What a node of a run is, from its name: the one place a node's name is compared with
//! the names of the flow node and the recorder (every other node runs fibre groups).

/// The flow node's name in heartbeats, topics and launch plans.
pub const FLOW_NODE: &str = "flow";
/// The recorder's name.
pub const RECORDER_NODE: &str = "recorder";

/// The role of a node of a run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum NodeRole {
    /// The DNS and the coupling (`flow`).
    Flow,
    /// The recorder (`recorder`).
    Recorder,
    /// A node stepping fibre groups (any other name: the launch file refuses groups named
    /// after the other roles).
    Fiber,
}

impl NodeRole {
    /// The role of the node named `name`.
    pub fn of(name: &str) -> NodeRole {
        match name {
            FLOW_NODE => NodeRole::Flow,
            RECORDER_NODE => NodeRole::Recorder,
            _ => NodeRole::Fiber,
        }
    }

    /// Whether `name` is a node of this role.
    pub fn is(self, name: impl AsRef<str>) -> bool {
        NodeRole::of(name.as_ref()) == self
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The two fixed names name their roles; any other name is a fibre node.
    #[test]
    fn names_give_their_roles() {
        assert_eq!(NodeRole::of("flow"), NodeRole::Flow);
        assert_eq!(NodeRole::of("recorder"), NodeRole::Recorder);
        assert_eq!(NodeRole::of("case1"), NodeRole::Fiber);
        assert!(NodeRole::Recorder.is("recorder") && !NodeRole::Flow.is("recorder"));
    }
}
