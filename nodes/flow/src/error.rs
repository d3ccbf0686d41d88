//! Errors of the flow node.

#[derive(Debug, thiserror::Error)]
pub enum FlowError {
    #[error(transparent)]
    Dns(#[from] fiberflow_dns::DnsError),
    #[error("invalid flow-node configuration: {0}")]
    Config(String),
    #[error("i/o error on {path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error(transparent)]
    Bus(#[from] fiberflow_bus::BusError),
    #[error("{0}")]
    Protocol(String),
}

pub(crate) fn io_err(path: &std::path::Path) -> impl FnOnce(std::io::Error) -> FlowError + '_ {
    move |source| FlowError::Io {
        path: path.display().to_string(),
        source,
    }
}
