//! Fault injection for tests: a bus whose subscribers take a fixed time over every
//! message (a slow disk behind a recorder, a busy host), and which reports how many
//! messages waited in one at most.

use crate::{Bus, BusError, BusHandle, Outgoing, Subscription};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// Passes publishes on; each subscription is fed `delay` per message by a thread of its
/// own, from the wrapped bus's queue.
pub struct SlowBus {
    inner: BusHandle,
    delay: Duration,
    /// The most messages that waited in one subscription's queue.
    deepest: Arc<AtomicUsize>,
}

impl SlowBus {
    pub fn new(inner: BusHandle, delay: Duration) -> Self {
        Self {
            inner,
            delay,
            deepest: Arc::new(AtomicUsize::new(0)),
        }
    }

    /// The most messages that ever waited in one of this bus's subscriptions.
    pub fn deepest_backlog(&self) -> usize {
        self.deepest.load(Ordering::SeqCst)
    }
}

impl Bus for SlowBus {
    fn publish(&self, topic: &str, payload: &[u8]) -> Result<(), BusError> {
        self.inner.publish(topic, payload)
    }

    fn publish_message(&self, topic: &str, msg: &dyn Outgoing) -> Result<(), BusError> {
        self.inner.publish_message(topic, msg)
    }

    fn subscribe(&self, pattern: &str) -> Result<Subscription, BusError> {
        let inner = self.inner.subscribe(pattern)?;
        let (tx, rx) = std::sync::mpsc::sync_channel(0);
        let (delay, deepest) = (self.delay, self.deepest.clone());
        std::thread::Builder::new()
            .name("slow-bus".into())
            .spawn(move || {
                let inner = inner;
                let mut waiting = std::collections::VecDeque::new();
                loop {
                    // everything the wrapped queue holds now waits here
                    while let Ok(m) = inner.rx.try_recv() {
                        waiting.push_back(m);
                    }
                    deepest.fetch_max(waiting.len(), Ordering::SeqCst);
                    let next = match waiting.pop_front() {
                        Some(m) => m,
                        None => match inner.rx.recv() {
                            Ok(m) => m,
                            Err(_) => return,
                        },
                    };
                    std::thread::sleep(delay);
                    if tx.send(next).is_err() {
                        return;
                    }
                }
            })
            .map_err(|e| BusError::Transport(format!("slow bus thread: {e}")))?;
        Ok(Subscription::new(rx, None))
    }

    fn name(&self) -> &'static str {
        "slow"
    }
}
