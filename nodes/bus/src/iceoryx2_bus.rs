//! iceoryx2 transport: zero-copy shared memory between processes of one host.
//!
//! The ports are of the thread-safe iceoryx2 service variant, so a caller publishes from
//! its own thread — no hand-off to a bus thread and no waiting for one to wake up — and
//! then wakes the processes that subscribe to the topic: each process has its own wake-up
//! event (named by its iceoryx2 node id), and the publisher reads the topic's subscribers'
//! node ids from the service and notifies only their events. One receive thread per
//! process blocks on its event and drains the subscribers into the callers' channels.
//! (Waking every process of the run at every publish would schedule every receive thread
//! onto the busy cores at each message.) iceoryx2 has no wildcard subscriptions, so the bus is given the run's
//! topic list and a pattern subscribes to every matching topic. Publishers use
//! back-pressure (retry until delivered), so lockstep messages are never lost.
//!
//! No copies on the way: [`Bus::publish_message`] encodes straight into the loaned shared
//! memory, and a received message reaches the caller still in it ([`Payload::shared`]),
//! up to [`HELD_MAX`] per subscriber at a time; beyond that (a caller queueing messages)
//! the receive thread copies, so it never stalls on memory the caller holds.

use crate::{matches, Bus, BusError, Envelope, Outgoing, Payload, Subscription};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::sample::Sample;
use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::mpsc::{channel, Sender};
use std::sync::{Arc, Mutex};
use std::time::Duration;

type Svc = ipc_threadsafe::Service;
type PubSub = iceoryx2::service::port_factory::publish_subscribe::PortFactory<Svc, [u8], ()>;
type BytePublisher = Publisher<Svc, [u8], ()>;
/// A subscriber with its topic, the caller's channel and how many of its samples the
/// caller holds.
type Route = (
    String,
    Subscriber<Svc, [u8], ()>,
    Sender<Envelope>,
    Arc<AtomicUsize>,
);

/// Samples a subscriber may lend out at once (the service's limit).
const BORROWED_MAX: usize = 8;
/// Received samples handed to the caller in shared memory per subscriber at most; the
/// rest are copied, so a receive never exceeds [`BORROWED_MAX`].
pub const HELD_MAX: usize = BORROWED_MAX - 2;

/// A received sample handed over in place: its bytes stay in the publisher's shared
/// memory until the caller drops it.
struct Lent {
    sample: Sample<Svc, [u8], ()>,
    held: Arc<AtomicUsize>,
}

impl AsRef<[u8]> for Lent {
    fn as_ref(&self) -> &[u8] {
        self.sample.payload()
    }
}

impl Drop for Lent {
    fn drop(&mut self) {
        self.held.fetch_sub(1, Ordering::SeqCst);
    }
}

/// The longest the receive thread sleeps without a notification (a safety net only).
const IDLE_WAIT: Duration = Duration::from_millis(50);

struct Shared {
    node: Node<Svc>,
    topics: Vec<String>,
    services: Mutex<HashMap<String, PubSub>>,
    /// A publisher per topic, each behind its own lock: threads of one process that
    /// publish on different topics (fibre nodes sharing a process) encode and send at
    /// the same time; the map's lock is held only to find or create one.
    publishers: Mutex<HashMap<String, Arc<Mutex<BytePublisher>>>>,
    subscribers: Mutex<Vec<Route>>,
    /// Notifiers of the wake-up events of the processes (node ids) this one has woken.
    notifiers: Mutex<HashMap<u128, Notifier<Svc>>>,
    run_id: String,
    stop: AtomicBool,
}

/// A bus over iceoryx2 shared memory.
pub struct Iceoryx2Bus {
    shared: Arc<Shared>,
    thread: Mutex<Option<std::thread::JoinHandle<()>>>,
}

fn terr<E: std::fmt::Debug>(e: E) -> BusError {
    BusError::Transport(format!("iceoryx2: {e:?}"))
}

fn lock_err<T>(_: T) -> BusError {
    BusError::Transport("iceoryx2 bus lock poisoned".into())
}

/// The wake-up event service of the process whose iceoryx2 node has id `node`.
fn wake_name(run_id: &str, node: u128) -> Result<ServiceName, BusError> {
    format!("fiberflow/{run_id}/_wake/{node:032x}")
        .as_str()
        .try_into()
        .map_err(terr)
}

impl Shared {
    /// Notifies the wake-up event of process `node` (opened once); a process that is
    /// gone is skipped (its event no longer exists).
    fn wake(&self, node: u128) -> Result<(), BusError> {
        let mut notifiers = self.notifiers.lock().map_err(lock_err)?;
        if let std::collections::hash_map::Entry::Vacant(e) = notifiers.entry(node) {
            let opened = self
                .node
                .service_builder(&wake_name(&self.run_id, node)?)
                .event()
                .open()
                .ok()
                .and_then(|s| s.notifier_builder().create().ok());
            match opened {
                Some(n) => {
                    e.insert(n);
                }
                None => return Ok(()),
            }
        }
        if let Some(n) = notifiers.get(&node) {
            // a failed wake-up only delays the receiver to its idle poll (IDLE_WAIT)
            if let Err(e) = n.notify() {
                tracing::debug!(error = ?e, "iceoryx2 wake-up failed");
            }
        }
        Ok(())
    }

    /// Runs `f` on the service of `topic`, opened or created once per process.
    fn with_service<R>(
        &self,
        topic: &str,
        f: impl FnOnce(&PubSub) -> Result<R, BusError>,
    ) -> Result<R, BusError> {
        let mut services = self.services.lock().map_err(lock_err)?;
        if !services.contains_key(topic) {
            let name: ServiceName = topic.try_into().map_err(terr)?;
            let s = self
                .node
                .service_builder(&name)
                .publish_subscribe::<[u8]>()
                .subscriber_max_buffer_size(256)
                .subscriber_max_borrowed_samples(BORROWED_MAX)
                .history_size(0)
                .enable_safe_overflow(false)
                .max_publishers(4)
                .max_subscribers(16)
                .max_nodes(32)
                .open_or_create()
                .map_err(terr)?;
            services.insert(topic.to_string(), s);
        }
        let s = services
            .get(topic)
            .ok_or_else(|| BusError::Transport("iceoryx2 service vanished".into()))?;
        f(s)
    }
}

impl Iceoryx2Bus {
    /// Opens the bus for a run; `topics` are every topic the run uses.
    pub fn open(run_id: &str, topics: Vec<String>) -> Result<Self, BusError> {
        // iceoryx2's own log says "no config file was loaded" at warning level on every
        // healthy start; only errors reach the terminal (IOX2_LOG_LEVEL overrides)
        set_log_level_from_env_or(LogLevel::Error);
        let node = NodeBuilder::new().create::<Svc>().map_err(terr)?;
        // stale shared memory of crashed earlier runs is removed before anything is opened
        let _ = Node::<Svc>::list(Config::global_config(), |state| {
            if let NodeState::Dead(dead) = state {
                let _ = dead.try_remove_stale_resources();
            }
            CallbackProgression::Continue
        });
        // this process's wake-up event: notified by whoever publishes to a topic it
        // subscribes to
        let own = node.id().value();
        let wake = node
            .service_builder(&wake_name(run_id, own)?)
            .event()
            .max_nodes(64)
            .max_listeners(2)
            .max_notifiers(64)
            .open_or_create()
            .map_err(terr)?;
        let listener: Listener<Svc> = wake.listener_builder().create().map_err(terr)?;
        let shared = Arc::new(Shared {
            node,
            topics,
            services: Mutex::new(HashMap::new()),
            publishers: Mutex::new(HashMap::new()),
            subscribers: Mutex::new(Vec::new()),
            notifiers: Mutex::new(HashMap::new()),
            run_id: run_id.to_string(),
            stop: AtomicBool::new(false),
        });
        let sh = shared.clone();
        let thread = std::thread::Builder::new()
            .name("iceoryx2-receive".into())
            .spawn(move || receive_loop(&sh, &listener))
            .map_err(|e| BusError::Transport(e.to_string()))?;
        Ok(Self {
            shared,
            thread: Mutex::new(Some(thread)),
        })
    }
}

/// Drains every subscriber, then sleeps until the run's next publish.
fn receive_loop(sh: &Shared, listener: &Listener<Svc>) {
    // a subscriber that cannot receive (e.g. cannot map a publisher's memory) is reported
    // once per topic: its messages would otherwise vanish without a trace
    let mut failing = std::collections::HashSet::new();
    while !sh.stop.load(Ordering::SeqCst) {
        if let Ok(subs) = sh.subscribers.lock() {
            for (topic, s, tx, held) in subs.iter() {
                loop {
                    match s.receive() {
                        Ok(Some(sample)) => {
                            let payload = if held.fetch_add(1, Ordering::SeqCst) < HELD_MAX {
                                let held = held.clone();
                                Payload::shared(Box::new(Lent { sample, held }))
                            } else {
                                held.fetch_sub(1, Ordering::SeqCst);
                                Payload::from(sample.payload().to_vec())
                            };
                            let _ = tx.send((topic.clone(), payload));
                        }
                        Ok(None) => break,
                        Err(e) => {
                            if failing.insert(topic.clone()) {
                                tracing::warn!(topic = %topic, error = ?e, "iceoryx2 receive failed");
                            }
                            break;
                        }
                    }
                }
            }
        }
        let _ = listener.timed_wait(|_| {}, IDLE_WAIT);
    }
}

impl Iceoryx2Bus {
    /// Runs `f` with this process's publisher on `topic` (created once).
    fn with_publisher<R>(
        &self,
        topic: &str,
        f: impl FnOnce(&BytePublisher) -> Result<R, BusError>,
    ) -> Result<R, BusError> {
        let publisher = {
            let mut pubs = self.shared.publishers.lock().map_err(lock_err)?;
            if !pubs.contains_key(topic) {
                let p = self.shared.with_service(topic, |s| {
                    s.publisher_builder()
                        .initial_max_slice_len(4096)
                        .allocation_strategy(AllocationStrategy::PowerOfTwo)
                        .backpressure_strategy(BackpressureStrategy::RetryUntilDelivered)
                        .create()
                        .map_err(terr)
                })?;
                pubs.insert(topic.to_string(), Arc::new(Mutex::new(p)));
            }
            pubs.get(topic)
                .cloned()
                .ok_or_else(|| BusError::Transport("publisher vanished".into()))?
        };
        let p = publisher.lock().map_err(lock_err)?;
        f(&p)
    }

    /// Wakes the processes subscribed to `topic`, each once (inside
    /// [`Bus::publish_together`] on this thread: at its end).
    fn wake_subscribers(&self, topic: &str) -> Result<(), BusError> {
        let mut nodes: Vec<u128> = Vec::new();
        self.shared.with_service(topic, |s| {
            s.dynamic_config().list_subscribers(|d| {
                let id = d.node_id.value();
                if !nodes.contains(&id) {
                    nodes.push(id);
                }
                CallbackProgression::Continue
            });
            Ok(())
        })?;
        let deferred = HELD_WAKES.with(|held| {
            let mut held = held.borrow_mut();
            match held.as_mut() {
                Some(h) => {
                    for n in &nodes {
                        if !h.contains(n) {
                            h.push(*n);
                        }
                    }
                    true
                }
                None => false,
            }
        });
        if !deferred {
            for node in nodes {
                self.shared.wake(node)?;
            }
        }
        Ok(())
    }
}

thread_local! {
    /// Inside [`Bus::publish_together`]: the processes to wake when it ends.
    static HELD_WAKES: std::cell::RefCell<Option<Vec<u128>>> = const { std::cell::RefCell::new(None) };
}

impl Drop for Iceoryx2Bus {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::SeqCst);
        let _ = self.shared.wake(self.shared.node.id().value());
        if let Ok(mut t) = self.thread.lock() {
            if let Some(h) = t.take() {
                let _ = h.join();
            }
        }
    }
}

impl Bus for Iceoryx2Bus {
    fn publish(&self, topic: &str, payload: &[u8]) -> Result<(), BusError> {
        self.with_publisher(topic, |p| {
            let sample = p.loan_slice_uninit(payload.len()).map_err(terr)?;
            sample.write_from_slice(payload).send().map_err(terr)
        })?;
        self.wake_subscribers(topic)
    }

    /// Encoded straight into the loaned shared memory, not zeroed first (at scale the
    /// samples are tens of MB a step).
    fn publish_message(&self, topic: &str, msg: &dyn Outgoing) -> Result<(), BusError> {
        self.with_publisher(topic, |p| {
            let mut sample = p.loan_slice_uninit(msg.len()).map_err(terr)?;
            let payload = sample.payload_mut();
            let (at, len) = (payload.as_ptr() as *const u8, payload.len());
            let initialised = msg
                .write_uninit(payload)
                .is_some_and(|b| std::ptr::eq(b.as_ptr(), at) && b.len() == len);
            if !initialised {
                return Err(crate::unwritable(topic));
            }
            // SAFETY: the message handed back a `&mut [u8]` over exactly the loaned
            // payload, and safe code can hold one only over initialised bytes
            let sample = unsafe { sample.assume_init() };
            sample.send().map_err(terr)
        })?;
        self.wake_subscribers(topic)
    }

    fn publish_together(
        &self,
        publish: &mut dyn FnMut() -> Result<(), BusError>,
    ) -> Result<(), BusError> {
        // nested: the outer call wakes
        let outer = HELD_WAKES.with(|held| {
            let mut held = held.borrow_mut();
            let outer = held.is_none();
            if outer {
                *held = Some(Vec::new());
            }
            outer
        });
        let result = publish();
        if !outer {
            return result;
        }
        // every message sent before the failure is woken for too
        let nodes = HELD_WAKES.with(|held| held.borrow_mut().take().unwrap_or_default());
        for node in nodes {
            self.shared.wake(node)?;
        }
        result
    }

    fn subscribe(&self, pattern: &str) -> Result<Subscription, BusError> {
        let (tx, rx) = channel();
        let mut new = Vec::new();
        for t in self.shared.topics.iter().filter(|t| matches(pattern, t)) {
            let s = self
                .shared
                .with_service(t, |s| s.subscriber_builder().create().map_err(terr))?;
            new.push((t.clone(), s, tx.clone(), Arc::new(AtomicUsize::new(0))));
        }
        self.shared
            .subscribers
            .lock()
            .map_err(lock_err)?
            .extend(new);
        Ok(Subscription::new(rx, None))
    }

    fn name(&self) -> &'static str {
        "iceoryx2"
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::Counting;
    use crate::zenoh_bus::{ZenohBus, ZenohSettings};
    use crate::BusHandle;

    fn run_id(name: &str) -> String {
        format!("test-{name}-{}", std::process::id())
    }

    /// Two buses of one run, as two processes would open them (the receiver, the sender),
    /// and the receiver's subscription to `topic`.
    fn receiver_and_sender(name: &str, topic: &str) -> (Iceoryx2Bus, Iceoryx2Bus, Subscription) {
        let topics = vec![topic.to_string()];
        let id = run_id(name);
        let rx = Iceoryx2Bus::open(&id, topics.clone()).unwrap();
        let tx = Iceoryx2Bus::open(&id, topics).unwrap();
        let sub = rx.subscribe(topic).unwrap();
        (rx, tx, sub)
    }

    /// Inside `publish_together` messages go out at once but their wake-ups are held, one
    /// per subscribing process, until the outermost call ends (also when it fails); every
    /// message arrives, in order.
    #[test]
    fn publishing_together_wakes_each_process_once_at_the_end() {
        let (rx, tx, sub) = receiver_and_sender("together", "t/tog");
        let held = || HELD_WAKES.with(|h| h.borrow().clone());
        tx.publish_together(&mut || {
            tx.publish("t/tog", &[1])?;
            tx.publish("t/tog", &[2])?;
            assert_eq!(held(), Some(vec![rx.shared.node.id().value()]));
            tx.publish_together(&mut || tx.publish("t/tog", &[3]))?;
            assert_eq!(held().map(|h| h.len()), Some(1), "the inner call woke");
            Ok(())
        })
        .unwrap();
        assert_eq!(held(), None);
        let failed = tx.publish_together(&mut || {
            tx.publish("t/tog", &[4])?;
            Err(BusError::Transport("refused".into()))
        });
        assert!(failed.is_err());
        assert_eq!(held(), None, "a failed call left wake-ups held");
        for want in 1..=4u8 {
            let (_, p) = sub.rx.recv_timeout(Duration::from_secs(10)).unwrap();
            assert_eq!(&p[..], &[want]);
        }
    }

    /// Messages written straight into the loaned memory arrive with their bytes, still in
    /// the publisher's memory, while the caller holds fewer than `HELD_MAX` of them;
    /// beyond that they arrive copied (nothing stalls), and once the caller lets go they
    /// arrive in place again.
    #[test]
    fn messages_arrive_in_place_up_to_the_held_limit() {
        let (_rx, tx, sub) = receiver_and_sender("held", "t/big");
        let recv = || {
            let (t, p) = sub.rx.recv_timeout(Duration::from_secs(10)).unwrap();
            assert_eq!(t, "t/big");
            p
        };
        let count = HELD_MAX + 3;
        for i in 0..count {
            let m = Counting {
                first: i as u8,
                n: 100_000 + i,
            };
            tx.publish_message("t/big", &m).unwrap();
        }
        let held: Vec<Payload> = (0..count).map(|_| recv()).collect();
        for (i, p) in held.iter().enumerate() {
            assert_eq!(p.len(), 100_000 + i);
            assert!(p.iter().enumerate().all(|(j, &b)| b == (i + j) as u8));
            assert_eq!(p.is_shared(), i < HELD_MAX, "message {i}");
        }
        drop(held);
        tx.publish("t/big", &[7, 8, 9]).unwrap();
        let p = recv();
        assert_eq!(&p[..], &[7, 8, 9]);
        assert!(p.is_shared());
    }

    /// Over every transport a message that writes its own bytes arrives as the same bytes
    /// published as a slice; one that cannot write them is an error, and nothing goes out.
    #[test]
    fn written_messages_equal_published_bytes_on_every_transport() {
        let topics = vec!["w/a".to_string()];
        let buses: Vec<BusHandle> = vec![
            Arc::new(crate::inproc::InprocBus::new()),
            Arc::new(ZenohBus::open(&ZenohSettings::default()).unwrap()),
            Arc::new(Iceoryx2Bus::open(&run_id("written"), topics).unwrap()),
        ];
        for bus in buses {
            let sub = bus.subscribe("w/a").unwrap();
            std::thread::sleep(Duration::from_millis(300));
            let m = Counting { first: 3, n: 5000 };
            bus.publish_message("w/a", &m).unwrap();
            let refused = bus.publish_message("w/a", &Counting { first: 0, n: 0 });
            assert!(refused.is_err(), "{}", bus.name());
            let want: Vec<u8> = (0..5000).map(|j| (3 + j) as u8).collect();
            bus.publish("w/a", &want).unwrap();
            let a = sub.rx.recv_timeout(Duration::from_secs(5)).unwrap().1;
            let b = sub.rx.recv_timeout(Duration::from_secs(5)).unwrap().1;
            assert_eq!(&a[..], &want[..], "{}", bus.name());
            assert_eq!(&b[..], &want[..], "{}", bus.name());
            let extra = sub.rx.recv_timeout(Duration::from_millis(300));
            assert!(
                extra.is_err(),
                "{}: the refused message went out",
                bus.name()
            );
        }
    }

    /// Hands back other memory than the loan it was given: initialised and of the right
    /// length, but not the loan's.
    struct Elsewhere(usize);

    impl Outgoing for Elsewhere {
        fn len(&self) -> usize {
            self.0
        }
        fn write(&self, out: &mut [u8]) -> bool {
            out.fill(1);
            true
        }
        fn write_uninit<'a>(
            &self,
            _out: &'a mut [std::mem::MaybeUninit<u8>],
        ) -> Option<&'a mut [u8]> {
            Some(Box::leak(vec![1u8; self.0].into_boxed_slice()))
        }
    }

    /// A message is written into the loan without the loan being zeroed first: a bulk
    /// message (its own writer) and one with only a plain `write` (through a buffer)
    /// arrive as their encoded bytes; a message that hands back any memory but the loan's
    /// is refused, and nothing goes out.
    #[test]
    fn loans_count_as_written_only_when_handed_back() {
        let (_rx, tx, sub) = receiver_and_sender("loan", "t/loan");
        let recv = |wait_s| {
            sub.rx
                .recv_timeout(Duration::from_secs_f64(wait_s))
                .map(|(_, p)| p)
        };
        let samples = fiberflow_messages::FlowSamples {
            schema_version: fiberflow_messages::SCHEMA_VERSION,
            group: "case1".into(),
            step: 4,
            t_plus: 0.8,
            first_fiber: 0,
            group_fibers: 3,
            velocity: (0..30_000).map(|i| i as f64 * 0.5).collect(),
            velocity_gradient: (0..90_000).map(|i| -(i as f64)).collect(),
        };
        let want = fiberflow_messages::encode(&samples);
        // the loans are recycled: earlier bytes in them must not show through
        for _ in 0..3 {
            tx.publish_message("t/loan", &crate::Encode(samples.clone()))
                .unwrap();
            assert!(recv(10.0).unwrap()[..] == want[..]);
            let m = Counting {
                first: 9,
                n: 70_001,
            };
            tx.publish_message("t/loan", &m).unwrap();
            assert_eq!(&recv(10.0).unwrap()[..], &m.bytes()[..]);
        }
        assert!(tx.publish_message("t/loan", &Elsewhere(1000)).is_err());
        assert!(
            recv(0.5).is_err(),
            "a message that did not write its loan went out"
        );
    }
}
