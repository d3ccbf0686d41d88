//! iceoryx2 transport: zero-copy shared memory between processes of one host.
//!
//! The ports are of the thread-safe iceoryx2 service variant, so a caller publishes from
//! its own thread — no hand-off to a bus thread and no waiting for one to wake up — and
//! then notifies the run's wake-up event. One receive thread per process blocks on that
//! event (every publish in the run notifies it) and drains the subscribers into the
//! callers' channels. iceoryx2 has no wildcard subscriptions, so the bus is given the run's
//! topic list and a pattern subscribes to every matching topic. Publishers use
//! back-pressure (retry until delivered), so lockstep messages are never lost.

use crate::{matches, Bus, BusError, Envelope, Subscription};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{channel, Sender};
use std::sync::{Arc, Mutex};
use std::time::Duration;

type Svc = ipc_threadsafe::Service;
type PubSub = iceoryx2::service::port_factory::publish_subscribe::PortFactory<Svc, [u8], ()>;
type BytePublisher = Publisher<Svc, [u8], ()>;
/// A subscriber with its topic and the caller's channel.
type Route = (String, Subscriber<Svc, [u8], ()>, Sender<Envelope>);

/// The longest the receive thread sleeps without a notification (a safety net only).
const IDLE_WAIT: Duration = Duration::from_millis(50);

struct Shared {
    node: Node<Svc>,
    topics: Vec<String>,
    services: Mutex<HashMap<String, PubSub>>,
    publishers: Mutex<HashMap<String, BytePublisher>>,
    subscribers: Mutex<Vec<Route>>,
    notifier: Mutex<Notifier<Svc>>,
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

impl Shared {
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
        let wake_name: ServiceName = format!("fiberflow/{run_id}/_wake")
            .as_str()
            .try_into()
            .map_err(terr)?;
        let wake = node
            .service_builder(&wake_name)
            .event()
            .max_nodes(32)
            .max_listeners(32)
            .max_notifiers(32)
            .open_or_create()
            .map_err(terr)?;
        let listener: Listener<Svc> = wake.listener_builder().create().map_err(terr)?;
        let notifier = wake.notifier_builder().create().map_err(terr)?;
        let shared = Arc::new(Shared {
            node,
            topics,
            services: Mutex::new(HashMap::new()),
            publishers: Mutex::new(HashMap::new()),
            subscribers: Mutex::new(Vec::new()),
            notifier: Mutex::new(notifier),
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
            for (topic, s, tx) in subs.iter() {
                loop {
                    match s.receive() {
                        Ok(Some(sample)) => {
                            let _ = tx.send((topic.clone(), sample.payload().to_vec()));
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

impl Drop for Iceoryx2Bus {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::SeqCst);
        if let Ok(n) = self.shared.notifier.lock() {
            let _ = n.notify();
        }
        if let Ok(mut t) = self.thread.lock() {
            if let Some(h) = t.take() {
                let _ = h.join();
            }
        }
    }
}

impl Bus for Iceoryx2Bus {
    fn publish(&self, topic: &str, payload: &[u8]) -> Result<(), BusError> {
        {
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
                pubs.insert(topic.to_string(), p);
            }
            let p = pubs
                .get(topic)
                .ok_or_else(|| BusError::Transport("publisher vanished".into()))?;
            let sample = p.loan_slice_uninit(payload.len()).map_err(terr)?;
            let sample = sample.write_from_slice(payload);
            sample.send().map_err(terr)?;
        }
        self.shared
            .notifier
            .lock()
            .map_err(lock_err)?
            .notify()
            .map_err(terr)?;
        Ok(())
    }

    fn subscribe(&self, pattern: &str) -> Result<Subscription, BusError> {
        let (tx, rx) = channel();
        let mut new = Vec::new();
        for t in self.shared.topics.iter().filter(|t| matches(pattern, t)) {
            let s = self
                .shared
                .with_service(t, |s| s.subscriber_builder().create().map_err(terr))?;
            new.push((t.clone(), s, tx.clone()));
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
