//! Per-fibre shape and orientation metrics (paper §4.3).

use crate::fiber::{Fiber, Segment, SegmentProps};
use nalgebra::Vector3;

/// Metrics of one fibre at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FiberMetrics {
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

/// The metrics of fibre `f`.
pub fn metrics(f: &Fiber) -> FiberMetrics {
    metrics_of(&f.segments, &f.props)
}

/// The metrics of the fibre whose segments are `segments`, with properties `props`.
pub fn metrics_of(segments: &[Segment], props: &[SegmentProps]) -> FiberMetrics {
    metrics_from(segments.iter().map(|s| (s.r, s.z)), props)
}

/// The metrics of the fibre whose segments' centres and axes `rz` yields, first to last,
/// with properties `props` (read where the segments are stored: nothing else is copied).
pub fn metrics_from(
    rz: impl Iterator<Item = (Vector3<f64>, Vector3<f64>)> + Clone,
    props: &[SegmentProps],
) -> FiberMetrics {
    let n = rz.clone().count();
    let mut com = Vector3::zeros();
    let mut mass = 0.0;
    let mut zs = Vector3::zeros();
    for ((r, z), p) in rz.clone().zip(props) {
        com += p.mass * r;
        mass += p.mass;
        zs += z;
    }
    com /= mass;
    let norm = zs.norm();
    let zhat = if norm > 0.0 {
        zs / norm
    } else {
        Vector3::zeros()
    };
    let sigma2 = if n > 1 {
        rz.clone()
            .map(|(_, z)| (z - zhat).norm_squared())
            .sum::<f64>()
            / (n - 1) as f64
    } else {
        0.0
    };
    // the free ends, as the first and last of `Fiber::joints`
    let end_to_end = match (rz.clone().next(), rz.last(), props.first(), props.last()) {
        (Some((ra, za)), Some((rb, zb)), Some(pa), Some(pb)) => {
            let start = ra - 0.5 * pa.shape.length * za;
            let end = rb + 0.5 * pb.shape.length * zb;
            (end - start).norm()
        }
        _ => 0.0,
    };
    FiberMetrics {
        centre_of_mass: com,
        orientation: zhat,
        z1: zhat.x,
        sigma2,
        end_to_end,
    }
}
