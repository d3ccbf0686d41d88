//! fiberflow-fiber-model
