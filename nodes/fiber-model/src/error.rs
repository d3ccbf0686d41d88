//! Errors of the fibre model.

#[derive(Debug, thiserror::Error)]
pub enum FiberError {
    /// A configuration value is out of range; the message names the key.
    #[error("invalid fibre configuration: {0}")]
    Config(String),
    /// The joint-force system could not be solved (singular or non-finite).
    #[error("joint-force system is singular or non-finite for fibre {fiber}")]
    Singular { fiber: usize },
    /// The fluid samples do not match the segments.
    #[error("expected {expected} fluid samples, got {got}")]
    SampleCount { expected: usize, got: usize },
}
