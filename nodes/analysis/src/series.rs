//! The per-step, per-fibre series a recording yields for one group: what the fibre
//! analysis and the coiling onsets both read.

/// Per-step, per-fibre metrics of one group.
#[derive(Debug, Clone, Default)]
pub struct GroupSeries {
    pub t_plus: Vec<f64>,
    /// [step][fibre] centre of mass.
    pub com: Vec<Vec<[f64; 3]>>,
    pub z1: Vec<Vec<f64>>,
    pub sigma2: Vec<Vec<f64>>,
    pub layer: Vec<u8>,
    pub density_ratio: f64,
    pub segment_length: f64,
    /// Contacts and flocs of each recorded full state ([`crate::flocs`]).
    pub flocs: Vec<crate::flocs::FlocRow>,
}
