//! fiberflow-viewer
