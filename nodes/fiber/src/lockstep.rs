//! The fibre node's side of the lockstep: the wait for its samples of a step, sending its
//! state again when they are late (a message lost in transit would otherwise stall the run
//! until the step timeout), with the flow node's restarts and the run's stop watched.

use crate::piece::ServedPiece;
use crate::serve::FiberNodeError;
use fiberflow_bus::BusError;
use fiberflow_messages::{Lifecycle, SamplesView};
use std::time::{Duration, Instant};

/// The shortest wait for samples after which the node sends its state again.
const RESEND_AFTER_MIN: Duration = Duration::from_secs(5);

/// How often a fibre node's wait for samples wakes (without samples): to stamp its watch
/// (the pulse beats only while the loop advances), look for a stop, and read the flow
/// node's heartbeats when it lives on another host.
const WAIT_POLL: Duration = Duration::from_millis(500);

/// Samples that arrived for a step and passed their checks: the payload (read in place
/// by the step) and how long the check took.
pub(crate) struct Arrived {
    pub payload: fiberflow_bus::Payload,
    pub checking: Duration,
    /// How long the node waited, the check aside.
    pub waited: Duration,
}

impl ServedPiece {
    /// Waits for the samples of step `k`, sending the state again when they are late, and
    /// the states `resend_others` sends (those of the nodes stepped after this one on its
    /// thread; it returns how many). Garbage, other pieces' and other steps' samples are
    /// dropped and counted.
    pub(crate) fn wait_for_samples(
        &mut self,
        k: u64,
        step_timeout: Duration,
        timeout_s: f64,
        resend_others: &mut dyn FnMut() -> Result<usize, BusError>,
    ) -> Result<Arrived, FiberNodeError> {
        use std::sync::atomic::Ordering;
        self.beat.step.store(k, Ordering::Relaxed);
        self.beat
            .dropped
            .store(self.samples_in.drops.total(), Ordering::Relaxed);
        let resend_cap = (step_timeout / 4).max(RESEND_AFTER_MIN);
        let wait_from = Instant::now();
        let mut resent = false;
        let mut resend_after = (3 * self.longest_wait).clamp(RESEND_AFTER_MIN, resend_cap);
        let mut resend_at = wait_from + resend_after;
        // the wait ends with the samples checked (checking counts as the fibre step); the
        // step reads them where they arrived (a transport's shared memory), not copied
        let (checking, payload) = loop {
            self.watch.touch();
            self.stopped()?;
            self.flow_restarted(k)?;
            let left = step_timeout.saturating_sub(wait_from.elapsed());
            if left.is_zero() {
                self.hb(Lifecycle::Failed, k)?;
                return Err(FiberNodeError::Protocol(format!(
                    "node {}: no flow samples for step {k} within {timeout_s:.0} s",
                    self.node
                )));
            }
            let now = Instant::now();
            if now >= resend_at {
                // our state or the samples were lost in transit: send the state again and
                // say we wait (the flow node resends samples it already served)
                self.publish_state(k)?;
                // a shard still waiting for our free step of the last step may have lost it
                if let Some(x) = &self.exchange {
                    x.resend(&self.bus)?;
                }
                let others = resend_others()?;
                self.hb(Lifecycle::Waiting, k)?;
                tracing::info!(
                    node = %self.node,
                    step = k,
                    waited_s = format!("{:.1}", wait_from.elapsed().as_secs_f64()),
                    also_resent = others,
                    "no samples yet: sending the state again"
                );
                resent = true;
                resend_after = (2 * resend_after).min(resend_cap);
                resend_at = now + resend_after;
            }
            let wait = left
                .min(resend_at.saturating_duration_since(now))
                .min(WAIT_POLL);
            let Some((topic, bytes)) = self.samples_in.recv_raw(wait) else {
                continue;
            };
            let view = match SamplesView::read(&bytes) {
                Ok(v) => v,
                Err(e) => {
                    self.samples_in.drops.drop_one(&topic, &e.to_string());
                    continue;
                }
            };
            let n = self.group.segment_count();
            let h = &view.header;
            let drops = &mut self.samples_in.drops;
            // the values' finiteness is checked while they are read, below
            if let Err(why) = view.check_shape() {
                drops.drop_one(&topic, &format!("inconsistent: {why}"));
            } else if h.group != self.name || h.first_fiber != self.piece.first_fiber {
                drops.drop_one(&topic, "samples for another group or shard");
            } else if h.step != k {
                drops.drop_one(&topic, "samples of another step");
            } else if view.len() != n {
                drops.drop_one(&topic, "samples for another number of segments");
            } else {
                let t0 = Instant::now();
                if view.values_finite() {
                    break (t0.elapsed(), bytes);
                }
                let why = view.check().err().unwrap_or_default();
                drops.drop_one(&topic, &format!("inconsistent: {why}"));
            }
        };
        // a wait that ended only after a resend says how long a loss took to repair, not
        // how long a healthy step takes: it must not stretch the next resend deadline
        let waited = wait_from.elapsed().saturating_sub(checking);
        if !resent {
            self.longest_wait = self.longest_wait.max(waited);
        }
        Ok(Arrived {
            payload,
            checking,
            waited,
        })
    }
}
