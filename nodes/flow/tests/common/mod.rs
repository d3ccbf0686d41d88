//! Helpers shared by the flow crate's integration tests and examples.
pub mod settling;
