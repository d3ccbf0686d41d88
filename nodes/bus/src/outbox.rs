//! A publisher on a thread of its own. [`Outbox::send`] hands a message over and returns at
//! once; the messages go out in the order they were handed over. A node's loop then goes
//! on computing while the transport copies the payload, notifies the subscribers and the
//! scheduler wakes them (on busy cores, waking the subscribers one by one would otherwise
//! hold the node's loop).

use crate::{BusError, BusHandle, Outgoing};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Instant;

/// One message, or several published together ([`Bus::publish_together`]).
enum Item {
    One(String, Arc<dyn Outgoing>),
    Together(Vec<(String, Arc<dyn Outgoing>)>),
}

/// Publishes in order on a background thread.
pub struct Outbox {
    tx: Option<SyncSender<Item>>,
    thread: Option<JoinHandle<Result<f64, BusError>>>,
}

impl Outbox {
    /// An outbox on `bus` holding at most `depth` hand-overs not yet published (`send` and
    /// `send_together` wait when it is full).
    pub fn new(bus: BusHandle, depth: usize) -> Result<Self, BusError> {
        let (tx, rx) = sync_channel(depth.max(1));
        let thread = std::thread::Builder::new()
            .name("outbox".into())
            .spawn(move || publish_loop(&bus, &rx))
            .map_err(|e| BusError::Transport(format!("outbox thread: {e}")))?;
        Ok(Self {
            tx: Some(tx),
            thread: Some(thread),
        })
    }

    /// Hands `payload` over for publishing on `topic` (a message not encoded yet is encoded
    /// on the outbox's thread, straight into the transport's buffer). Fails with the
    /// transport's error if an earlier publish failed (the outbox then publishes nothing
    /// more).
    pub fn send(&mut self, topic: String, payload: Arc<dyn Outgoing>) -> Result<(), BusError> {
        self.hand_over(Item::One(topic, payload))
    }

    /// Hands several messages over in one go; they go out in order inside
    /// [`Bus::publish_together`], so each subscribing process is woken once for all of them
    /// (a step's samples for the fibre nodes of one process), and this thread wakes the
    /// outbox's once.
    pub fn send_together(
        &mut self,
        messages: Vec<(String, Arc<dyn Outgoing>)>,
    ) -> Result<(), BusError> {
        if messages.is_empty() {
            return Ok(());
        }
        self.hand_over(Item::Together(messages))
    }

    fn hand_over(&mut self, item: Item) -> Result<(), BusError> {
        let sent = match &self.tx {
            Some(tx) => tx.send(item).is_ok(),
            None => false,
        };
        if sent {
            Ok(())
        } else {
            Err(self.failure())
        }
    }

    /// Publishes what is left, stops the thread and returns the seconds it spent publishing.
    pub fn finish(mut self) -> Result<f64, BusError> {
        self.tx = None;
        match self.thread.take().map(JoinHandle::join) {
            Some(Ok(r)) => r,
            Some(Err(_)) => Err(BusError::Transport("outbox thread panicked".into())),
            None => Ok(0.0),
        }
    }

    /// The error the thread stopped with (it only stops early on a failed publish).
    fn failure(&mut self) -> BusError {
        self.tx = None;
        match self.thread.take().map(JoinHandle::join) {
            Some(Ok(Err(e))) => e,
            Some(Err(_)) => BusError::Transport("outbox thread panicked".into()),
            _ => BusError::Transport("outbox closed".into()),
        }
    }
}

impl Drop for Outbox {
    /// Not joined: on an error path the thread may be blocked on a subscriber that is gone;
    /// it ends when its channel is drained (or with the process).
    fn drop(&mut self) {
        self.tx = None;
    }
}

fn publish_loop(bus: &BusHandle, rx: &Receiver<Item>) -> Result<f64, BusError> {
    let mut busy_s = 0.0;
    while let Ok(item) = rx.recv() {
        let t0 = Instant::now();
        match item {
            Item::One(topic, payload) => bus.publish_message(&topic, payload.as_ref())?,
            Item::Together(messages) => bus.publish_together(&mut || {
                for (topic, payload) in &messages {
                    bus.publish_message(topic, payload.as_ref())?;
                }
                Ok(())
            })?,
        }
        busy_s += t0.elapsed().as_secs_f64();
    }
    Ok(busy_s)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::inproc::InprocBus;
    use crate::Bus;
    use std::time::Duration;

    /// Messages go out in the order handed over, one by one or several together, all of
    /// them by `finish`.
    #[test]
    fn publishes_everything_in_order() {
        let bus: BusHandle = Arc::new(InprocBus::new());
        let sub = bus.subscribe("t/**").unwrap();
        let mut out = Outbox::new(bus.clone(), 4).unwrap();
        let msg = |i: u32| -> (String, Arc<dyn Outgoing>) {
            let topic = if i.is_multiple_of(2) { "t/a" } else { "t/b" };
            (topic.into(), Arc::new(i.to_le_bytes().to_vec()))
        };
        // one by one and in hand-overs of several, mixed
        let mut i = 0;
        while i < 100 {
            if i % 7 == 3 {
                let n = (100 - i).min(5);
                out.send_together((i..i + n).map(msg).collect()).unwrap();
                i += n;
            } else {
                let (t, p) = msg(i);
                out.send(t, p).unwrap();
                i += 1;
            }
        }
        out.send_together(Vec::new()).unwrap();
        assert!(out.finish().unwrap() >= 0.0);
        let got: Vec<u32> = (0..100)
            .map(|_| {
                let (_, p) = sub.rx.recv_timeout(Duration::from_secs(5)).unwrap();
                u32::from_le_bytes(p[..4].try_into().unwrap())
            })
            .collect();
        assert_eq!(got, (0..100).collect::<Vec<_>>());
        assert!(sub.rx.try_recv().is_err(), "nothing beyond what was sent");
    }

    struct Failing;
    impl Bus for Failing {
        fn publish(&self, _: &str, _: &[u8]) -> Result<(), BusError> {
            Err(BusError::Transport("link down".into()))
        }
        fn subscribe(&self, _: &str) -> Result<crate::Subscription, BusError> {
            Err(BusError::Transport("link down".into()))
        }
        fn name(&self) -> &'static str {
            "failing"
        }
    }

    /// A failed publish comes back to the caller (on a later send or finish) with the
    /// transport's own message, never lost.
    #[test]
    fn a_failed_publish_is_reported() {
        let mut out = Outbox::new(Arc::new(Failing), 2).unwrap();
        let mut err = None;
        for _ in 0..10 {
            if let Err(e) = out.send("t".into(), Arc::new(vec![1])) {
                err = Some(e);
                break;
            }
        }
        let err = match err {
            Some(e) => e,
            None => out.finish().unwrap_err(),
        };
        assert!(err.to_string().contains("link down"), "{err}");
    }

    /// Records, for each message published, the `publish_together` call it went out in
    /// (0: none).
    #[derive(Default)]
    struct Grouping {
        calls: std::sync::Mutex<(u32, Option<u32>, Vec<u32>)>,
    }
    impl Bus for Grouping {
        fn publish(&self, _: &str, _: &[u8]) -> Result<(), BusError> {
            let mut c = self.calls.lock().unwrap();
            let inside = c.1.unwrap_or(0);
            c.2.push(inside);
            Ok(())
        }
        fn subscribe(&self, _: &str) -> Result<crate::Subscription, BusError> {
            Err(BusError::Transport("not here".into()))
        }
        fn name(&self) -> &'static str {
            "grouping"
        }
        fn publish_together(
            &self,
            publish: &mut dyn FnMut() -> Result<(), BusError>,
        ) -> Result<(), BusError> {
            {
                let mut c = self.calls.lock().unwrap();
                c.0 += 1;
                c.1 = Some(c.0);
            }
            let r = publish();
            self.calls.lock().unwrap().1 = None;
            r
        }
    }

    /// Messages handed over together go out inside one `publish_together` (one wake-up
    /// of each subscribing process), those sent one by one outside any.
    #[test]
    fn messages_handed_over_together_are_published_together() {
        let bus = Arc::new(Grouping::default());
        let mut out = Outbox::new(bus.clone(), 4).unwrap();
        let m = || -> (String, Arc<dyn Outgoing>) { ("t".into(), Arc::new(vec![1u8])) };
        out.send_together(vec![m(), m(), m()]).unwrap();
        let (t, p) = m();
        out.send(t, p).unwrap();
        out.send_together(vec![m(), m()]).unwrap();
        out.finish().unwrap();
        let c = bus.calls.lock().unwrap();
        assert_eq!(c.2, vec![1, 1, 1, 0, 2, 2]);
    }
}
