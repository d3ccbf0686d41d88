//! In-process bus: channels between threads of one process (tests, `--transport inproc`).

use crate::{matches, Bus, BusError, Envelope, Subscription};
use std::sync::mpsc::{channel, Sender};
use std::sync::Mutex;

/// Fan-out of every publish to the matching subscribers.
#[derive(Default)]
pub struct InprocBus {
    subs: Mutex<Vec<(String, Sender<Envelope>)>>,
}

impl InprocBus {
    pub fn new() -> Self {
        Self::default()
    }
}

impl Bus for InprocBus {
    fn publish(&self, topic: &str, payload: &[u8]) -> Result<(), BusError> {
        let mut subs = self
            .subs
            .lock()
            .map_err(|_| BusError::Transport("inproc bus lock poisoned".into()))?;
        // drop subscribers whose receiver is gone
        subs.retain(|(pattern, tx)| {
            if matches(pattern, topic) {
                tx.send((topic.to_string(), payload.to_vec().into()))
                    .is_ok()
            } else {
                true
            }
        });
        Ok(())
    }

    fn subscribe(&self, pattern: &str) -> Result<Subscription, BusError> {
        let (tx, rx) = channel();
        self.subs
            .lock()
            .map_err(|_| BusError::Transport("inproc bus lock poisoned".into()))?
            .push((pattern.to_string(), tx));
        Ok(Subscription::new(rx, None))
    }

    fn name(&self) -> &'static str {
        "inproc"
    }
}
