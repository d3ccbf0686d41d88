//! The segments of a suspension as the contact search reads them.

use crate::fiber::{Fiber, SegmentProps};
use nalgebra::Vector3;

/// The segments of a suspension as the contact step reads them, at the start of the step
/// and after its free step, fibre by fibre.
pub(crate) trait Segments: Sync {
    /// First flat (fibre-major) index of each fibre's segments, plus the total.
    fn offsets(&self) -> &[usize];
    /// Properties of segment `i` of fibre `k`.
    fn props(&self, k: usize, i: usize) -> &SegmentProps;
    /// Centre and axis of segment `i` of fibre `k` at the start of the step.
    fn start(&self, k: usize, i: usize) -> (Vector3<f64>, Vector3<f64>);
    /// Centre and axis of segment `i` of fibre `k` after the free step.
    fn end(&self, k: usize, i: usize) -> (Vector3<f64>, Vector3<f64>);
    /// Fibre `k` at the start of the step (centres, axes and normals are what the solve
    /// reads of it).
    fn start_fiber(&self, k: usize) -> Fiber;
    /// Fibre `k` after the free step.
    fn end_fiber(&self, k: usize) -> Fiber;
}

/// [`Segments`] over two slices of fibres: at the start of the step and after it.
pub(crate) struct Slices<'a> {
    pub before: &'a [Fiber],
    pub after: &'a [Fiber],
    offsets: Vec<usize>,
}

impl<'a> Slices<'a> {
    pub(crate) fn new(before: &'a [Fiber], after: &'a [Fiber]) -> Self {
        Self {
            before,
            after,
            offsets: crate::contact::offsets(after),
        }
    }
}

impl Segments for Slices<'_> {
    fn offsets(&self) -> &[usize] {
        &self.offsets
    }
    fn props(&self, k: usize, i: usize) -> &SegmentProps {
        &self.after[k].props[i]
    }
    fn start(&self, k: usize, i: usize) -> (Vector3<f64>, Vector3<f64>) {
        let s = &self.before[k].segments[i];
        (s.r, s.z)
    }
    fn end(&self, k: usize, i: usize) -> (Vector3<f64>, Vector3<f64>) {
        let s = &self.after[k].segments[i];
        (s.r, s.z)
    }
    fn start_fiber(&self, k: usize) -> Fiber {
        self.before[k].clone()
    }
    fn end_fiber(&self, k: usize) -> Fiber {
        self.after[k].clone()
    }
}
