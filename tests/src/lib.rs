//! fiberflow-e2e
