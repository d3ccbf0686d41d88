//! The bus: one publish/subscribe trait, three transports (in-process channels, zenoh, and
//! iceoryx2 — see `Transport`), and the plumbing every node shares: decoding with drop
//! counting so garbage on a topic is dropped, counted and logged once, never a panic.

pub mod iceoryx2_bus;
pub mod inbox;
pub mod inproc;
pub mod lossy;
pub mod outbox;
pub mod pulse;
pub mod slow;
#[cfg(test)]
mod testing;
pub mod usage;
pub mod zenoh_bus;

pub use inbox::{DropCounter, Inbox};
pub use outbox::Outbox;

use std::mem::MaybeUninit;
use std::sync::mpsc::Receiver;
use std::sync::Arc;

/// Bus errors (connection and publish failures; never raised for bad input).
#[derive(Debug, thiserror::Error)]
pub enum BusError {
    #[error("transport error: {0}")]
    Transport(String),
    #[error("transport {0} is not available in this build")]
    Unavailable(String),
}

/// One received message: topic and raw payload.
pub type Envelope = (String, Payload);

/// A received message's bytes: owned, or still in the publisher's shared memory (iceoryx2)
/// until dropped, so that a large message is read where it was written, not copied first.
pub struct Payload(Held);

enum Held {
    Owned(Vec<u8>),
    Shared(Box<dyn AsRef<[u8]> + Send>),
}

impl Payload {
    /// Bytes that live in another owner's memory (released when the payload is dropped).
    pub fn shared(bytes: Box<dyn AsRef<[u8]> + Send>) -> Self {
        Self(Held::Shared(bytes))
    }

    /// True if the bytes were never copied out of the publisher's memory.
    pub fn is_shared(&self) -> bool {
        matches!(self.0, Held::Shared(_))
    }
}

impl From<Vec<u8>> for Payload {
    fn from(v: Vec<u8>) -> Self {
        Self(Held::Owned(v))
    }
}

impl std::ops::Deref for Payload {
    type Target = [u8];
    fn deref(&self) -> &[u8] {
        match &self.0 {
            Held::Owned(v) => v,
            Held::Shared(b) => (**b).as_ref(),
        }
    }
}

impl std::fmt::Debug for Payload {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "Payload({} bytes, shared: {})",
            self.len(),
            self.is_shared()
        )
    }
}

/// A message to publish that writes its own bytes (a message encoded on the publishing
/// thread straight into the transport's buffer, or bytes encoded already).
pub trait Outgoing: Send + Sync {
    /// How many bytes [`Outgoing::write`] writes.
    fn len(&self) -> usize;
    /// Writes exactly [`Outgoing::len`] bytes into `out` (that long); false if it cannot.
    fn write(&self, out: &mut [u8]) -> bool;
    /// Writes exactly [`Outgoing::len`] bytes into memory not initialised yet (a loan
    /// that then need not be zeroed first); `out`, initialised, or None if it cannot. The
    /// default writes into a zeroed buffer and copies.
    fn write_uninit<'a>(&self, out: &'a mut [MaybeUninit<u8>]) -> Option<&'a mut [u8]> {
        let mut buf = vec![0u8; out.len()];
        self.write(&mut buf).then(|| out.write_copy_of_slice(&buf))
    }
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

impl Outgoing for Vec<u8> {
    fn len(&self) -> usize {
        Vec::len(self)
    }
    fn write(&self, out: &mut [u8]) -> bool {
        let fits = out.len() == Vec::len(self);
        if fits {
            out.copy_from_slice(self);
        }
        fits
    }
    fn write_uninit<'a>(&self, out: &'a mut [MaybeUninit<u8>]) -> Option<&'a mut [u8]> {
        (out.len() == Vec::len(self)).then(|| out.write_copy_of_slice(self))
    }
}

/// A bus message encoded when it is published ([`fiberflow_messages::encode_into`]).
pub struct Encode<M>(pub M);

impl<M: fiberflow_messages::Message + Send + Sync> Outgoing for Encode<M> {
    fn len(&self) -> usize {
        fiberflow_messages::encoded_len(&self.0)
    }
    fn write(&self, out: &mut [u8]) -> bool {
        fiberflow_messages::encode_into(&self.0, out)
    }
    fn write_uninit<'a>(&self, out: &'a mut [MaybeUninit<u8>]) -> Option<&'a mut [u8]> {
        fiberflow_messages::encode_into_uninit(&self.0, out)
    }
}

/// A subscription delivers envelopes in arrival order per publisher.
pub struct Subscription {
    pub rx: Receiver<Envelope>,
    /// Keeps transport-side resources alive (e.g. the zenoh subscriber).
    _guard: Option<Box<dyn Send>>,
}

impl Subscription {
    pub fn new(rx: Receiver<Envelope>, guard: Option<Box<dyn Send>>) -> Self {
        Self { rx, _guard: guard }
    }
}

/// Publish/subscribe over slash topics. `pattern` is a topic, with `*` for any one
/// segment and an optional trailing `/**` ([`matches`]).
pub trait Bus: Send + Sync {
    fn publish(&self, topic: &str, payload: &[u8]) -> Result<(), BusError>;
    /// Publishes a message that writes its own bytes: over iceoryx2 straight into the
    /// loaned shared memory; elsewhere into one buffer that the transport then takes.
    fn publish_message(&self, topic: &str, msg: &dyn Outgoing) -> Result<(), BusError> {
        let mut buf = vec![0u8; msg.len()];
        if !msg.write(&mut buf) {
            return Err(unwritable(topic));
        }
        self.publish(topic, &buf)
    }
    fn subscribe(&self, pattern: &str) -> Result<Subscription, BusError>;
    /// Transport name for logs.
    fn name(&self) -> &'static str;
    /// Runs `publish`, whose messages from this thread go out as usual but wake each
    /// subscribing process once, at the end, instead of once per message (iceoryx2: a
    /// process's receive thread then drains them all in one wake-up). Transports
    /// without per-message wake-ups just run it.
    fn publish_together(
        &self,
        publish: &mut dyn FnMut() -> Result<(), BusError>,
    ) -> Result<(), BusError> {
        publish()
    }
}

/// The error of a message that did not write the bytes it announced (a bug, reported
/// rather than published half written).
pub(crate) fn unwritable(topic: &str) -> BusError {
    BusError::Transport(format!(
        "the message for {topic} did not write the length it announced"
    ))
}

/// One subscription over several patterns (one thread per pattern forwards into a shared
/// channel): each pattern's messages stay in order; messages of different patterns are
/// interleaved as they arrive. One pattern is a plain [`Bus::subscribe`].
pub fn subscribe_any(bus: &dyn Bus, patterns: &[String]) -> Result<Subscription, BusError> {
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::Arc;
    if let [one] = patterns {
        return bus.subscribe(one);
    }
    let (tx, rx) = std::sync::mpsc::channel();
    let stop = Arc::new(AtomicBool::new(false));
    for p in patterns {
        let sub = bus.subscribe(p)?;
        let (tx, stop) = (tx.clone(), stop.clone());
        std::thread::Builder::new()
            .name("bus-merge".into())
            .spawn(move || {
                // the whole subscription moves here: its guard keeps the transport's
                // subscriber alive (a closure would otherwise capture only `sub.rx`)
                let sub = sub;
                while !stop.load(Ordering::Relaxed) {
                    match sub.rx.recv_timeout(std::time::Duration::from_millis(200)) {
                        Ok(m) => {
                            if tx.send(m).is_err() {
                                break;
                            }
                        }
                        Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {}
                        Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => break,
                    }
                }
            })
            .map_err(|e| BusError::Transport(e.to_string()))?;
    }
    /// Stops the forwarding threads when the merged subscription is dropped.
    struct StopOnDrop(Arc<AtomicBool>);
    impl Drop for StopOnDrop {
        fn drop(&mut self) {
            self.0.store(true, Ordering::Relaxed);
        }
    }
    Ok(Subscription::new(rx, Some(Box::new(StopOnDrop(stop)))))
}

/// True if `topic` matches `pattern`: a `*` segment stands for any one segment, and a
/// trailing `/**` for any number of further segments, none included (zenoh's meaning of
/// both).
pub fn matches(pattern: &str, topic: &str) -> bool {
    let (head, rest) = match pattern.strip_suffix("/**") {
        Some(head) => (head, true),
        None => (pattern, false),
    };
    let mut t = topic.split('/');
    for p in head.split('/') {
        match t.next() {
            Some(seg) if p == seg || (p == "*" && !seg.is_empty()) => {}
            _ => return false,
        }
    }
    rest || t.next().is_none()
}

/// Which transport carries the bus (in launch files and node specs: `"inproc"`,
/// `"zenoh"`, `"iceoryx2"`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Transport {
    Inproc,
    Zenoh,
    Iceoryx2,
}

impl std::str::FromStr for Transport {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "inproc" => Ok(Transport::Inproc),
            "zenoh" => Ok(Transport::Zenoh),
            "iceoryx2" => Ok(Transport::Iceoryx2),
            other => Err(format!(
                "unknown transport {other:?} (allowed: inproc, zenoh, iceoryx2)"
            )),
        }
    }
}

impl std::fmt::Display for Transport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Transport::Inproc => "inproc",
            Transport::Zenoh => "zenoh",
            Transport::Iceoryx2 => "iceoryx2",
        })
    }
}

/// Shared handle to a bus.
pub type BusHandle = Arc<dyn Bus>;

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    /// Exact topics, `*` for one segment, a trailing `/**` for any further segments.
    #[test]
    fn patterns_match_like_zenoh_key_expressions() {
        let yes = [
            ("r/a", "r/a"),
            ("r/a/**", "r/a"),
            ("r/a/**", "r/a/b/c"),
            ("r/*/state", "r/case1/state"),
            ("r/*/**", "r/x/y"),
        ];
        let no = [
            ("r/a", "r/ab"),
            ("r/a", "r/a/b"),
            ("r/a/**", "r/ab"),
            ("r/*/state", "r/case1/metrics"),
            ("r/*/state", "r/state"),
            ("r/*/state", "r/a/b/state"),
            ("r/*/state", "r//state"),
        ];
        for (p, t) in yes {
            assert!(matches(p, t), "{p} should match {t}");
        }
        for (p, t) in no {
            assert!(!matches(p, t), "{p} should not match {t}");
        }
    }

    /// Messages of every pattern reach the merged subscription, in order per pattern, on a
    /// transport whose subscriptions hold a guard (zenoh) and on the in-process bus; others
    /// do not.
    #[test]
    fn subscribe_any_merges_patterns() {
        let buses: Vec<BusHandle> = vec![
            Arc::new(inproc::InprocBus::new()),
            Arc::new(
                zenoh_bus::ZenohBus::open(&zenoh_bus::ZenohSettings::default())
                    .expect("zenoh session on loopback"),
            ),
        ];
        for bus in buses {
            let pats = vec!["r/a/**".to_string(), "r/b".to_string()];
            let sub = subscribe_any(bus.as_ref(), &pats).unwrap();
            std::thread::sleep(Duration::from_millis(300));
            for i in 0..5u8 {
                bus.publish("r/a/x", &[i]).unwrap();
                bus.publish("r/b", &[10 + i]).unwrap();
                bus.publish("r/c", &[99]).unwrap();
            }
            let mut a = Vec::new();
            let mut b = Vec::new();
            while let Ok((t, p)) = sub.rx.recv_timeout(Duration::from_secs(3)) {
                match t.as_str() {
                    "r/a/x" => a.push(p[0]),
                    "r/b" => b.push(p[0]),
                    other => panic!("{other} is not subscribed"),
                }
                if a.len() + b.len() == 10 {
                    break;
                }
            }
            assert_eq!(a, vec![0, 1, 2, 3, 4], "{}", bus.name());
            assert_eq!(b, vec![10, 11, 12, 13, 14], "{}", bus.name());
        }
    }
}
