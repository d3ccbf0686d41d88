//! fiberflow-bus
