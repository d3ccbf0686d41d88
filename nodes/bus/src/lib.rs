//! Bus plumbing placeholder (being written).
#[derive(Debug, thiserror::Error)]
pub enum BusError {
    #[error("{0}")]
    Other(String),
}
