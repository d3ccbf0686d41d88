//! fiberflow-recorder
