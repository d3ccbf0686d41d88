//! Typed receiving with drop accounting: undecodable or wrong-version payloads are dropped,
//! counted per topic, and logged once per topic.

use crate::{Envelope, Subscription};
use fiberflow_messages::sanity::Sane;
use fiberflow_messages::Message;
use std::collections::BTreeMap;
use std::sync::mpsc::RecvTimeoutError;
use std::time::Duration;

/// Per-topic drop counts.
#[derive(Debug, Default, Clone, PartialEq)]
pub struct DropCounter {
    pub by_topic: BTreeMap<String, u64>,
}

impl DropCounter {
    /// Counts a drop; logs the first one per topic.
    pub fn drop_one(&mut self, topic: &str, reason: &str) {
        let c = self.by_topic.entry(topic.to_string()).or_insert(0);
        if *c == 0 {
            tracing::warn!(
                topic,
                reason,
                "dropping an undecodable or inconsistent message (further drops on this topic are counted silently)"
            );
        }
        *c += 1;
    }
    pub fn total(&self) -> u64 {
        self.by_topic.values().sum()
    }
}

/// A subscription plus a drop counter.
pub struct Inbox {
    pub sub: Subscription,
    pub drops: DropCounter,
}

impl Inbox {
    pub fn new(sub: Subscription) -> Self {
        Self {
            sub,
            drops: DropCounter::default(),
        }
    }

    /// Next raw envelope, or None on timeout / disconnect.
    pub fn recv_raw(&mut self, timeout: Duration) -> Option<Envelope> {
        match self.sub.rx.recv_timeout(timeout) {
            Ok(m) => Some(m),
            Err(RecvTimeoutError::Timeout) => None,
            // the transport went away: wait out the timeout instead of spinning callers
            Err(RecvTimeoutError::Disconnected) => {
                std::thread::sleep(timeout);
                None
            }
        }
    }

    /// Next message that decodes as `M` and passes its checks ([`Sane`]) within
    /// `timeout`; garbage and inconsistent messages are dropped and counted.
    pub fn recv<M: Message + Sane>(&mut self, timeout: Duration) -> Option<(String, M)> {
        let deadline = std::time::Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(std::time::Instant::now());
            let (topic, bytes) = self.recv_raw(left)?;
            match fiberflow_messages::decode::<M>(&bytes) {
                Ok(m) => match m.check() {
                    Ok(()) => return Some((topic, m)),
                    Err(why) => self.drops.drop_one(&topic, &format!("inconsistent: {why}")),
                },
                Err(e) => self.drops.drop_one(&topic, &e.to_string()),
            }
        }
    }
}
