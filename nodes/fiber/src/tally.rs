//! What a fibre node counts over a run and logs at its end: where its wall time went, and
//! what the contact solve could not do (pairs left overlapping, fibres locked into one
//! body, fibres kept where they started).

use fiberflow_fiber_model::group::{FiberGroup, StepReport};

/// Wall seconds of a node over the run, by part of the step.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct StepTimes {
    /// Waiting for the samples (their check aside).
    pub waiting_s: f64,
    /// Checking the samples and stepping the fibres (contact included).
    pub stepping_s: f64,
    /// Encoding and publishing the state and the metrics.
    pub publishing_s: f64,
}

/// Steps whose contact solve did not fully succeed (docs/contact.md), logged as they come
/// (the first, then every 100th) and summed for the run's end.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct ContactTally {
    /// Steps whose solve left a pair closer than 0.99 d (the sweeps ran out).
    pub unresolved_steps: u64,
    /// Steps whose solve locked an island.
    pub locked_steps: u64,
    /// Steps whose solve kept fibres where they started, and how many in all.
    pub frozen_steps: u64,
    pub frozen_fibers: u64,
}

impl ContactTally {
    /// Counts what the contact solve of `group`'s step to `step` (its `report`) left
    /// undone, and says so.
    pub fn record(&mut self, node: &str, step: u64, group: &FiberGroup, report: &StepReport) {
        let Some(c) = group.contact() else {
            return;
        };
        let out = &report.contact;
        let d = group.props(0).first().map_or(0.0, |p| p.shape.diameter);
        if out.worst_gap < -0.01 * d {
            if self.unresolved_steps.is_multiple_of(100) {
                tracing::warn!(
                    node,
                    step,
                    worst_gap_over_d = out.worst_gap / d,
                    sweeps = out.sweeps,
                    max_sweeps = c.sweeps,
                    contacts = report.pairs,
                    steps_so_far = self.unresolved_steps + 1,
                    "contact left a pair closer than 0.99 d (raise fibers.contact.sweeps?)"
                );
            }
            self.unresolved_steps += 1;
        }
        if !out.locked.is_empty() {
            if self.locked_steps.is_multiple_of(100) {
                tracing::info!(
                    node,
                    step,
                    fibers = out.locked.len(),
                    steps_so_far = self.locked_steps + 1,
                    "contact locked fibres the sweeps could not separate (they moved as one body this step)"
                );
            }
            self.locked_steps += 1;
        }
        if !out.frozen.is_empty() {
            if self.frozen_steps.is_multiple_of(100) {
                tracing::info!(
                    node,
                    step,
                    fibers = out.frozen.len(),
                    steps_so_far = self.frozen_steps + 1,
                    "contact kept fibres where they started the step (still overlapping when the rounds ran out)"
                );
            }
            self.frozen_steps += 1;
            self.frozen_fibers += out.frozen.len() as u64;
        }
    }
}
