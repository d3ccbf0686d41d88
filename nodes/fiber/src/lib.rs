//! fiberflow-fiber
