//! iceoryx2 transport: zero-copy shared memory between processes of one host.
//!
//! iceoryx2 ports are owned by one thread, so a bus thread owns the node, one publisher per
//! topic and the subscribers; callers talk to it through channels. The thread blocks on an
//! iceoryx2 event (every publish notifies the run's wake-up event), with a 1 ms timeout to
//! pick up local commands — it never busy-spins. iceoryx2 has no wildcard subscriptions, so
//! the bus is given the run's topic list and a pattern subscribes to every matching topic.
//! Publishers use back-pressure (retry until delivered), so lockstep messages are never lost.

use crate::{matches, Bus, BusError, Envelope, Subscription};
use iceoryx2::prelude::*;
use std::collections::HashMap;
use std::sync::mpsc::{channel, Receiver, Sender};
use std::sync::Mutex;
use std::time::Duration;

enum Cmd {
    Publish(String, Vec<u8>, Sender<Result<(), String>>),
    Subscribe(String, Sender<Envelope>, Sender<Result<(), String>>),
    Stop,
}

/// A bus over iceoryx2 shared memory.
pub struct Iceoryx2Bus {
    tx: Mutex<Sender<Cmd>>,
    thread: Mutex<Option<std::thread::JoinHandle<()>>>,
}

fn terr<E: std::fmt::Debug>(e: E) -> String {
    format!("{e:?}")
}

impl Iceoryx2Bus {
    /// Opens the bus for a run; `topics` are every topic the run uses.
    pub fn open(run_id: &str, topics: Vec<String>) -> Result<Self, BusError> {
        // iceoryx2's own log says "no config file was loaded" at warning level on every
        // healthy start; only errors reach the terminal (IOX2_LOG_LEVEL overrides)
        set_log_level_from_env_or(LogLevel::Error);
        let (tx, rx) = channel();
        let (ready_tx, ready_rx) = channel();
        let run = run_id.to_string();
        let thread = std::thread::Builder::new()
            .name("iceoryx2-bus".into())
            .spawn(move || {
                if let Err(e) = bus_thread(&run, topics, rx, &ready_tx) {
                    let _ = ready_tx.send(Err(e));
                }
            })
            .map_err(|e| BusError::Transport(e.to_string()))?;
        match ready_rx.recv_timeout(Duration::from_secs(20)) {
            Ok(Ok(())) => {}
            Ok(Err(e)) => return Err(BusError::Transport(format!("iceoryx2: {e}"))),
            Err(_) => {
                return Err(BusError::Transport(
                    "iceoryx2 bus thread did not start".into(),
                ))
            }
        }
        Ok(Self {
            tx: Mutex::new(tx),
            thread: Mutex::new(Some(thread)),
        })
    }

    fn send(&self, cmd: Cmd) -> Result<(), BusError> {
        self.tx
            .lock()
            .map_err(|_| BusError::Transport("iceoryx2 bus lock poisoned".into()))?
            .send(cmd)
            .map_err(|_| BusError::Transport("iceoryx2 bus thread has stopped".into()))
    }
}

impl Drop for Iceoryx2Bus {
    fn drop(&mut self) {
        let _ = self.send(Cmd::Stop);
        if let Ok(mut t) = self.thread.lock() {
            if let Some(h) = t.take() {
                let _ = h.join();
            }
        }
    }
}

impl Bus for Iceoryx2Bus {
    fn publish(&self, topic: &str, payload: &[u8]) -> Result<(), BusError> {
        let (ack_tx, ack_rx) = channel();
        self.send(Cmd::Publish(topic.to_string(), payload.to_vec(), ack_tx))?;
        ack_rx
            .recv()
            .map_err(|_| BusError::Transport("iceoryx2 bus thread has stopped".into()))?
            .map_err(BusError::Transport)
    }

    fn subscribe(&self, pattern: &str) -> Result<Subscription, BusError> {
        let (tx, rx) = channel();
        let (ack_tx, ack_rx) = channel();
        self.send(Cmd::Subscribe(pattern.to_string(), tx, ack_tx))?;
        ack_rx
            .recv()
            .map_err(|_| BusError::Transport("iceoryx2 bus thread has stopped".into()))?
            .map_err(BusError::Transport)?;
        Ok(Subscription::new(rx, None))
    }

    fn name(&self) -> &'static str {
        "iceoryx2"
    }
}

type PubSub =
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, [u8], ()>;

fn service(node: &Node<ipc::Service>, topic: &str) -> Result<PubSub, String> {
    let name: ServiceName = topic.try_into().map_err(terr)?;
    node.service_builder(&name)
        .publish_subscribe::<[u8]>()
        .subscriber_max_buffer_size(256)
        .history_size(0)
        .enable_safe_overflow(false)
        .max_publishers(4)
        .max_subscribers(16)
        .max_nodes(32)
        .open_or_create()
        .map_err(terr)
}

fn bus_thread(
    run: &str,
    topics: Vec<String>,
    rx: Receiver<Cmd>,
    ready: &Sender<Result<(), String>>,
) -> Result<(), String> {
    let node = NodeBuilder::new().create::<ipc::Service>().map_err(terr)?;
    // stale shared memory of crashed earlier runs is removed before anything is opened
    let _ = Node::<ipc::Service>::list(Config::global_config(), |state| {
        if let NodeState::Dead(dead) = state {
            let _ = dead.try_remove_stale_resources();
        }
        CallbackProgression::Continue
    });
    let wake_name: ServiceName = format!("fiberflow/{run}/_wake")
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
    let listener = wake.listener_builder().create().map_err(terr)?;
    let notifier = wake.notifier_builder().create().map_err(terr)?;
    let mut services: HashMap<String, PubSub> = HashMap::new();
    let mut publishers = HashMap::new();
    let mut subscribers = Vec::new();
    let _ = ready.send(Ok(()));
    loop {
        // local commands first
        loop {
            match rx.try_recv() {
                Ok(Cmd::Stop) | Err(std::sync::mpsc::TryRecvError::Disconnected) => return Ok(()),
                Ok(Cmd::Publish(topic, data, ack)) => {
                    let r = (|| -> Result<(), String> {
                        if !publishers.contains_key(&topic) {
                            if !services.contains_key(&topic) {
                                services.insert(topic.clone(), service(&node, &topic)?);
                            }
                            let p = services[&topic]
                                .publisher_builder()
                                .initial_max_slice_len(4096)
                                .allocation_strategy(AllocationStrategy::PowerOfTwo)
                                .backpressure_strategy(BackpressureStrategy::RetryUntilDelivered)
                                .create()
                                .map_err(terr)?;
                            publishers.insert(topic.clone(), p);
                        }
                        let p = &publishers[&topic];
                        let sample = p.loan_slice_uninit(data.len()).map_err(terr)?;
                        let sample = sample.write_from_slice(&data);
                        sample.send().map_err(terr)?;
                        notifier.notify().map_err(terr)?;
                        Ok(())
                    })();
                    let _ = ack.send(r);
                }
                Ok(Cmd::Subscribe(pattern, tx, ack)) => {
                    let r = (|| -> Result<(), String> {
                        for t in topics.iter().filter(|t| matches(&pattern, t)) {
                            if !services.contains_key(t) {
                                services.insert(t.clone(), service(&node, t)?);
                            }
                            let s = services[t].subscriber_builder().create().map_err(terr)?;
                            subscribers.push((t.clone(), s, tx.clone()));
                        }
                        Ok(())
                    })();
                    let _ = ack.send(r);
                }
                Err(std::sync::mpsc::TryRecvError::Empty) => break,
            }
        }
        // deliver everything that arrived
        for (topic, s, tx) in &subscribers {
            while let Ok(Some(sample)) = s.receive() {
                let _ = tx.send((topic.clone(), sample.payload().to_vec()));
            }
        }
        // block on the wake-up event (1 ms timeout to serve local commands)
        let _ = listener.timed_wait(|_| {}, Duration::from_millis(1));
    }
}
