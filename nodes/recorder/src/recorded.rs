//! Which steps a run folder's segments already hold (what a resumed recording continues
//! from).

use crate::recover;
use fiberflow_messages::sanity;
use fiberflow_messages::topics::kind_of;
use std::collections::{BTreeMap, BTreeSet};
use std::path::PathBuf;

/// Steps below the newest by more than this count as recorded without being remembered.
pub const RECORDED_WINDOW_STEPS: u64 = 10_000;

/// The step-stamped messages already recorded, per topic and slice (first fibre of a
/// sharded group's piece): every step within [`RECORDED_WINDOW_STEPS`] of the newest
/// exactly, and everything older as recorded. A topic's messages arrive in step order
/// (a node resends only the step it waits on; a resumed run's earlier segments hold a
/// prefix of each topic's steps), so this is the set of every recorded step for any run,
/// while memory grows with the topics, not the steps: a set of every (topic, step) grew
/// by ≈ 2 MB/s over a 10⁶-step run (docs/architecture.md).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Recorded {
    by_slice: BTreeMap<(String, u32), (u64, BTreeSet<u64>)>,
}

impl Recorded {
    /// Whether step `k` of `topic` (slice `first`) is recorded already.
    pub fn contains(&self, topic: &str, k: u64, first: u32) -> bool {
        self.by_slice
            .get(&(topic.to_string(), first))
            .is_some_and(|(newest, steps)| {
                k.saturating_add(RECORDED_WINDOW_STEPS) < *newest || steps.contains(&k)
            })
    }

    /// Marks step `k` recorded; false if it was already.
    pub fn insert(&mut self, topic: &str, k: u64, first: u32) -> bool {
        if self.contains(topic, k, first) {
            return false;
        }
        let (newest, steps) = self
            .by_slice
            .entry((topic.to_string(), first))
            .or_insert((k, BTreeSet::new()));
        steps.insert(k);
        if k > *newest {
            *newest = k;
            let floor = newest.saturating_sub(RECORDED_WINDOW_STEPS);
            if steps.first().is_some_and(|&f| f < floor) {
                *steps = steps.split_off(&floor);
            }
        }
        true
    }

    /// Steps remembered exactly, over every topic and slice.
    pub fn remembered(&self) -> usize {
        self.by_slice.values().map(|(_, s)| s.len()).sum()
    }
}

/// Every step-stamped message in `segments` (a damaged tail ends a file).
pub fn recorded_steps(segments: &[PathBuf]) -> Recorded {
    let mut seen = Recorded::default();
    for p in segments {
        // streamed (recordings reach gigabytes); a damaged tail ends the file
        let _ = recover::for_each_message(p, |topic, data| {
            let Some(kind) = kind_of(topic) else {
                return;
            };
            if let Ok(sanity::Stamp {
                step: Some(step),
                first_fiber,
                ..
            }) = sanity::check_payload(kind, data)
            {
                seen.insert(topic, step, first_fiber);
            }
        });
    }
    seen
}
