//! Analysis: turns recordings and flow statistics into the paper's figures and numbers
//! (CSV + PNG + a markdown summary). Paper §3.2 (flow validation) and §4 (fibres).

pub mod bootstrap;
pub mod coiling;
pub mod fibers;
pub mod flocs;
pub mod flow_validation;
pub mod modulation;
pub mod plot;
pub mod realisations;
pub mod reference;
pub mod series;

#[derive(Debug, thiserror::Error)]
pub enum AnalysisError {
    #[error("i/o error on {path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{0}")]
    Data(String),
    /// The recording holds no fibre state (a flow part, `scripts/flow_part.py`, or a run
    /// stopped before its first state): nothing for the fibre analysis.
    #[error("{0}: no fibre states recorded")]
    NoFiberStates(String),
    #[error("plot {path}: {reason}")]
    Plot { path: String, reason: String },
}

pub(crate) fn io_err(path: &std::path::Path) -> impl FnOnce(std::io::Error) -> AnalysisError + '_ {
    move |source| AnalysisError::Io {
        path: path.display().to_string(),
        source,
    }
}
