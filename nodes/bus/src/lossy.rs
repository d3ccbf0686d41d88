//! Fault injection for tests: a bus that loses chosen publishes (as a congested or broken
//! link would) and passes everything else to the bus it wraps.

use crate::{Bus, BusError, BusHandle, Subscription};
use std::collections::HashMap;
use std::sync::Mutex;

/// Decides whether a publish is lost: (topic, 1-based count of publishes on that topic so
/// far, payload).
type Rule = Box<dyn Fn(&str, usize, &[u8]) -> bool + Send + Sync>;

/// Loses the publishes its rules pick and passes everything else on.
pub struct LossyBus {
    inner: BusHandle,
    rules: Vec<Rule>,
    counts: Mutex<HashMap<String, usize>>,
    lost: Mutex<Vec<String>>,
}

impl LossyBus {
    /// Loses the `nth` (1-based) publish on each topic ending in `suffix`, for every rule.
    pub fn new(inner: BusHandle, rules: &[(&str, usize)]) -> Self {
        let rules = rules
            .iter()
            .map(|(suffix, nth)| {
                let (suffix, nth) = (suffix.to_string(), *nth);
                Box::new(move |topic: &str, n: usize, _: &[u8]| {
                    topic.ends_with(suffix.as_str()) && n == nth
                }) as Rule
            })
            .collect();
        Self::with_rules(inner, rules)
    }

    /// Loses the first publish on a topic ending in `suffix` whose payload `pick` selects.
    pub fn first_matching(
        inner: BusHandle,
        suffix: &str,
        pick: impl Fn(&[u8]) -> bool + Send + Sync + 'static,
    ) -> Self {
        let suffix = suffix.to_string();
        let done = std::sync::atomic::AtomicBool::new(false);
        let rule = Box::new(move |topic: &str, _: usize, payload: &[u8]| {
            topic.ends_with(suffix.as_str())
                && pick(payload)
                && !done.swap(true, std::sync::atomic::Ordering::SeqCst)
        }) as Rule;
        Self::with_rules(inner, vec![rule])
    }

    fn with_rules(inner: BusHandle, rules: Vec<Rule>) -> Self {
        Self {
            inner,
            rules,
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
        if self.rules.iter().any(|lose| lose(topic, n, payload)) {
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

    fn publish_together(
        &self,
        publish: &mut dyn FnMut() -> Result<(), BusError>,
    ) -> Result<(), BusError> {
        self.inner.publish_together(publish)
    }
}
