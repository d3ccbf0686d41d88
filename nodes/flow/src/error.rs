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
    /// A node of the run went silent or sent nothing within the step timeout (a lost
    /// process, host or link): not this node's fault, so a restart can mend it.
    #[error("{0}")]
    PeerLost(String),
}

/// The exit status of a flow-node process that failed because another node was lost
/// ([`FlowError::PeerLost`]; EX_TEMPFAIL): the launcher restarts the run even before a
/// newer checkpoint, as for a node killed by a signal.
pub const PEER_LOST_EXIT: i32 = 75;

pub(crate) fn io_err(path: &std::path::Path) -> impl FnOnce(std::io::Error) -> FlowError + '_ {
    move |source| FlowError::Io {
        path: path.display().to_string(),
        source,
    }
}
