//! fiberflow-flow
