//! Errors of the DNS library.

/// Everything that can go wrong in the flow solver.
#[derive(Debug, thiserror::Error)]
pub enum DnsError {
    /// A configuration value is out of range; the message names the key.
    #[error("invalid flow configuration: {0}")]
    Config(String),
    /// The solution blew up (NaN, CFL above the limit, divergence too large).
    #[error("flow solver blew up at step {step} (t+ = {t_plus:.3}): {reason}")]
    BlowUp {
        step: u64,
        t_plus: f64,
        reason: String,
    },
    /// A point the sampler cannot place (a non-finite coordinate).
    #[error("sample point {0}")]
    Point(String),
    /// Checkpoint file problems.
    #[error("checkpoint {path}: {reason}")]
    Checkpoint { path: String, reason: String },
    #[error("i/o error on {path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
}
