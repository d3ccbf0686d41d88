//! Message types of the fiberflow bus, their ROS 2 `.msg` definitions, topic names and the
//! CDR codec. One encoding on the wire and in MCAP: the recorder stores bytes as received.
//! No transport dependency.

mod bulk;
pub use bulk::SamplesView;
pub mod checkpoints;
pub mod codec;
pub mod echo;
pub mod fuzz;
pub mod kind;
pub mod palette;
pub mod pieces;
pub mod reading;
pub mod role;
pub mod sanity;
pub mod schema;
pub mod segments;
pub mod topics;
pub mod types;

pub use codec::{
    decode, decode_state_into, encode, encode_into, encode_into_uninit, encoded_len,
    peek_group_header, DecodeError, GroupHeader, Message,
};
pub use kind::Kind;
pub use role::{NodeRole, FLOW_NODE, RECORDER_NODE};
pub use types::*;

/// Version of every message layout and field name in this crate (the `.msg` schemas);
/// bumped on any change a reader could see.
pub const SCHEMA_VERSION: u32 = 5;

/// The oldest version this build still reads: schema 3 differs from 4 only in
/// `FiberGroupState`, which then has no contact arrays (read as empty, and written back
/// without them, so a version-3 message keeps its layout); schema 4 differs from 5 only in
/// a field's name (`FlowStatus.fibre_force_plus`, now `fiber_force_plus`: the same bytes).
pub const OLDEST_READABLE_SCHEMA: u32 = 3;

/// Whether this build reads messages of schema `version`.
pub fn readable_schema(version: u32) -> bool {
    (OLDEST_READABLE_SCHEMA..=SCHEMA_VERSION).contains(&version)
}
