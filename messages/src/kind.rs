//! The kinds of message on the bus, as a type: what a topic carries ([`crate::topics::kind_of`])
//! and its ROS 2 type name (the MCAP schema name, [`Kind::type_name`]).

use crate::codec::Message;
use crate::types::*;

/// A kind of message the run's topics carry.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Kind {
    RunAnnouncement,
    Heartbeat,
    FlowStatus,
    FlowProfiles,
    FlowSlice,
    FlowSamples,
    FiberGroupState,
    FiberGroupMetrics,
    FiberFreeStep,
    FiberContactSolved,
}

impl Kind {
    /// Every kind.
    pub const ALL: [Kind; 10] = [
        Kind::RunAnnouncement,
        Kind::Heartbeat,
        Kind::FlowStatus,
        Kind::FlowProfiles,
        Kind::FlowSlice,
        Kind::FlowSamples,
        Kind::FiberGroupState,
        Kind::FiberGroupMetrics,
        Kind::FiberFreeStep,
        Kind::FiberContactSolved,
    ];

    /// The ROS 2 type name, e.g. `fiberflow_msgs/msg/FlowStatus` (the message type's
    /// [`Message::TYPE_NAME`]).
    pub const fn type_name(self) -> &'static str {
        match self {
            Kind::RunAnnouncement => RunAnnouncement::TYPE_NAME,
            Kind::Heartbeat => Heartbeat::TYPE_NAME,
            Kind::FlowStatus => FlowStatus::TYPE_NAME,
            Kind::FlowProfiles => FlowProfiles::TYPE_NAME,
            Kind::FlowSlice => FlowSlice::TYPE_NAME,
            Kind::FlowSamples => FlowSamples::TYPE_NAME,
            Kind::FiberGroupState => FiberGroupState::TYPE_NAME,
            Kind::FiberGroupMetrics => FiberGroupMetrics::TYPE_NAME,
            Kind::FiberFreeStep => FiberFreeStep::TYPE_NAME,
            Kind::FiberContactSolved => FiberContactSolved::TYPE_NAME,
        }
    }

    /// The kind whose type name is `name`.
    pub fn of_type_name(name: &str) -> Option<Kind> {
        Kind::ALL.into_iter().find(|k| k.type_name() == name)
    }
}

/// The type name, as schemas and logs spell it.
impl std::fmt::Display for Kind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.type_name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every kind's type name names it back, and each has a schema.
    #[test]
    fn type_names_round_trip() {
        for k in Kind::ALL {
            assert_eq!(Kind::of_type_name(k.type_name()), Some(k));
            assert!(!crate::schema::text(k.type_name()).is_empty(), "{k:?}");
        }
        assert_eq!(Kind::of_type_name("fiberflow_msgs/msg/Nope"), None);
    }
}
