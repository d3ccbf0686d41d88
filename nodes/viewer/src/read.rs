//! Reading a recording for the scene: every segment of a run in order, each message checked
//! (messages that fail their checks are skipped), sharded groups' slices merged back into
//! whole groups.

use crate::ViewerError;
use fiberflow_messages::pieces::Tiles;
use fiberflow_messages::sanity::Sane;
use fiberflow_messages::{
    decode, FiberGroupMetrics, FiberGroupState, FlowSlice, Kind, RunAnnouncement,
};
use std::path::Path;

/// One message the scene uses, whole.
#[derive(Debug)]
pub enum Item {
    Announce(RunAnnouncement),
    State(FiberGroupState),
    Metrics(FiberGroupMetrics),
    Slice(FlowSlice),
}

/// Calls `f` with every usable message of the recording at `mcap` (a file or run folder),
/// in recording order.
pub fn for_each(mcap: &Path, mut f: impl FnMut(Item)) -> Result<(), ViewerError> {
    let read_err = |p: &Path, e: String| ViewerError::Read {
        path: p.display().to_string(),
        reason: e,
    };
    let segs = fiberflow_messages::segments::segment_paths(mcap)
        .map_err(|e| read_err(mcap, e.to_string()))?;
    let mut states = Tiles::default();
    let mut metrics = Tiles::default();
    for seg in &segs {
        // streamed a chunk at a time; a recording cut short by a killed recorder ends
        // early, and what came before is used
        fiberflow_messages::reading::for_each_message(seg, |m| {
            let topic = m.topic;
            match fiberflow_messages::topics::kind_of(topic) {
                Some(Kind::FiberGroupState) => {
                    if let Ok(s) = decode::<FiberGroupState>(m.data) {
                        if s.check().is_ok() && !s.is_lean() {
                            if let Some(whole) = states.add_slice(s) {
                                f(Item::State(whole));
                            }
                        }
                    }
                }
                Some(Kind::FiberGroupMetrics) => {
                    if let Ok(s) = decode::<FiberGroupMetrics>(m.data) {
                        if s.check().is_ok() {
                            if let Some(whole) = metrics.add_slice(s) {
                                f(Item::Metrics(whole));
                            }
                        }
                    }
                }
                Some(Kind::RunAnnouncement) => {
                    if let Ok(a) = decode::<RunAnnouncement>(m.data) {
                        if a.check().is_ok() {
                            f(Item::Announce(a));
                        }
                    }
                }
                Some(Kind::FlowSlice) => {
                    if let Ok(s) = decode::<FlowSlice>(m.data) {
                        if s.check().is_ok() {
                            f(Item::Slice(s));
                        }
                    }
                }
                _ => {}
            }
        })
        .map_err(|e| read_err(seg, e.to_string()))?;
    }
    Ok(())
}

/// What the first pass learns about a group: enough to choose and lay out its fibres.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct GroupInfo {
    pub fibers: usize,
    /// Initial layer per fibre (from the first state).
    pub layer: Vec<u8>,
    /// σ² per fibre at the last step with metrics (or a state).
    pub final_sigma2: Vec<f64>,
    final_step: Option<u64>,
    /// Whether the final σ² came from metrics (states then no longer stand in).
    from_metrics: bool,
    /// Step of the group's last state.
    pub last_state_step: u64,
    /// Longest contour length N·l of the group's fibres, wall units.
    pub contour_plus: f64,
    /// Segment length, segments and density ratio of the first fibre, for the band label.
    pub segment_length: f64,
    pub segments: u32,
    pub density_ratio: f64,
}

impl GroupInfo {
    /// Takes in one whole message of this group.
    pub fn add(&mut self, item: &Item) {
        match item {
            Item::State(s) => {
                if self.layer.is_empty() {
                    self.fibers = s.segments_per_fiber.len();
                    self.layer = s.layer.clone();
                    self.contour_plus = s
                        .segments_per_fiber
                        .iter()
                        .zip(&s.segment_length)
                        .map(|(&n, &l)| n as f64 * l)
                        .fold(0.0, f64::max);
                    self.segment_length = s.segment_length.first().copied().unwrap_or(0.0);
                    self.segments = s.segments_per_fiber.first().copied().unwrap_or(0);
                    self.density_ratio = s.density_ratio.first().copied().unwrap_or(0.0);
                }
                self.last_state_step = self.last_state_step.max(s.step);
                // a state stands in for metrics only in a recording without metrics
                if !self.from_metrics && self.final_step.is_none_or(|k| s.step > k) {
                    let firsts = crate::shape::first_segments(s);
                    self.final_sigma2 = (0..s.segments_per_fiber.len())
                        .map(|f| crate::shape::shape(s, f, firsts[f]).sigma2)
                        .collect();
                    self.final_step = Some(s.step);
                }
            }
            Item::Metrics(m)
                if !self.from_metrics || self.final_step.is_none_or(|k| m.step >= k) =>
            {
                self.final_sigma2 = m.sigma2.clone();
                self.final_step = Some(m.step);
                self.from_metrics = true;
            }
            _ => {}
        }
    }
}
