//! fiberflow-messages
