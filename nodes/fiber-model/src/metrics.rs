//! Per-fibre shape and orientation metrics (paper §4.3).

use crate::fibre::Fibre;
use nalgebra::Vector3;

/// Metrics of one fibre at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FibreMetrics {
    /// Mass-weighted centre of mass (unwrapped).
    pub centre_of_mass: Vector3<f64>,
    /// Orientation ẑ = Σẑ_i / |Σẑ_i|.
    pub orientation: Vector3<f64>,
    /// z1 = ẑ·ê1, in [-1, 1].
    pub z1: f64,
    /// σ² = Σ|ẑ_i − ẑ|²/(N−1) (0 for N = 1): zero when straight, grows with coiling.
    pub sigma2: f64,
    /// Distance between the two free ends.
    pub end_to_end: f64,
}

pub fn metrics(f: &Fibre) -> FibreMetrics {
    let n = f.len();
    let mut com = Vector3::zeros();
    let mut mass = 0.0;
    let mut zs = Vector3::zeros();
    for (s, p) in f.segments.iter().zip(&f.props) {
        com += p.mass * s.r;
        mass += p.mass;
        zs += s.z;
    }
    com /= mass;
    let norm = zs.norm();
    let zhat = if norm > 0.0 {
        zs / norm
    } else {
        Vector3::zeros()
    };
    let sigma2 = if n > 1 {
        f.segments
            .iter()
            .map(|s| (s.z - zhat).norm_squared())
            .sum::<f64>()
            / (n - 1) as f64
    } else {
        0.0
    };
    let joints = f.joints();
    let end_to_end = match (joints.first(), joints.last()) {
        (Some(a), Some(b)) => (b - a).norm(),
        _ => 0.0,
    };
    FibreMetrics {
        centre_of_mass: com,
        orientation: zhat,
        z1: zhat.x,
        sigma2,
        end_to_end,
    }
}
