//! Fault injection for tests: a bus that loses chosen publishes (as a congested or broken
//! link would) and passes everything else to the bus it wraps.

use crate::{Bus, BusError, BusHandle, Subscription};
use std::collections::HashMap;
use std::sync::Mutex;

/// Loses the `nth` (1-based) publish on each topic ending in `suffix`, for every rule.
pub struct LossyBus {
    inner: BusHandle,
    rules: Vec<(String, usize)>,
    counts: Mutex<HashMap<String, usize>>,
    lost: Mutex<Vec<String>>,
}

impl LossyBus {
    pub fn new(inner: BusHandle, rules: &[(&str, usize)]) -> Self {
        Self {
            inner,
            rules: rules.iter().map(|(s, n)| (s.to_string(), *n)).collect(),
            counts: Mutex::new(HashMap::new()),
            lost: Mutex::new(Vec::new()),
        }
    }

    /// The topics of the publishes lost so far (one entry per loss).
    pub fn lost(&self) -> Vec<String> {
        self.lost.lock().map(|l| l.clone()).unwrap_or_default()
    }
}

fn poisoned() -> BusError {
    BusError::Transport("lossy bus lock poisoned".into())
}

impl Bus for LossyBus {
    fn publish(&self, topic: &str, payload: &[u8]) -> Result<(), BusError> {
        let n = {
            let mut c = self.counts.lock().map_err(|_| poisoned())?;
            let n = c.entry(topic.to_string()).or_insert(0);
            *n += 1;
            *n
        };
        if self
            .rules
            .iter()
            .any(|(suffix, nth)| topic.ends_with(suffix.as_str()) && *nth == n)
        {
            self.lost
                .lock()
                .map_err(|_| poisoned())?
                .push(topic.to_string());
            return Ok(());
        }
        self.inner.publish(topic, payload)
    }

    fn subscribe(&self, pattern: &str) -> Result<Subscription, BusError> {
        self.inner.subscribe(pattern)
    }

    fn name(&self) -> &'static str {
        "lossy"
    }
}
