//! fiberflow-analysis
