//! A node's pulse: a thread that says every [`PULSE_PERIOD`] that each node of this
//! process is alive (a RUNNING heartbeat with its step), whatever the node is doing — a
//! long fibre step, a wait for samples, a long write. The fibre nodes show the step they
//! work on, the recorder the step it has recorded through. The flow node takes a node
//! silent for `run.liveness_s` as gone (a hung process, a host or link that vanished) and
//! fails the step at once, naming it, instead of waiting out the step timeout
//! (docs/architecture.md, "Runs that survive").

use crate::BusHandle;
use fiberflow_messages::{encode, lifecycle, Heartbeat, SCHEMA_VERSION};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// How often each node's pulse goes out.
pub const PULSE_PERIOD: Duration = Duration::from_secs(1);

/// What a node shows in its pulse: the step it works on and the messages it dropped.
#[derive(Debug, Default)]
pub struct Beat {
    pub step: AtomicU64,
    pub dropped: AtomicU64,
}

/// The pulse thread of one process; stops (and is joined) when dropped.
pub struct Pulse {
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Pulse {
    /// Starts pulsing for `nodes`: (heartbeat topic, node name, what it shows).
    pub fn start(bus: BusHandle, nodes: Vec<(String, String, Arc<Beat>)>) -> std::io::Result<Self> {
        let stop = Arc::new(AtomicBool::new(false));
        let halt = stop.clone();
        let thread = std::thread::Builder::new()
            .name("pulse".into())
            .spawn(move || {
                while !halt.load(Ordering::Relaxed) {
                    for (topic, node, beat) in &nodes {
                        let hb = Heartbeat {
                            schema_version: SCHEMA_VERSION,
                            node: node.clone(),
                            state: lifecycle::RUNNING,
                            step: beat.step.load(Ordering::Relaxed),
                            dropped: beat.dropped.load(Ordering::Relaxed),
                        };
                        if let Err(e) = bus.publish(topic, &encode(&hb)) {
                            tracing::warn!(error = %e, node, "pulse not sent");
                        }
                    }
                    // short sleeps, so a finished node's pulse stops at once
                    let mut slept = Duration::ZERO;
                    while slept < PULSE_PERIOD && !halt.load(Ordering::Relaxed) {
                        std::thread::sleep(Duration::from_millis(50));
                        slept += Duration::from_millis(50);
                    }
                }
            })?;
        Ok(Self {
            stop,
            thread: Some(thread),
        })
    }
}

impl Drop for Pulse {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::inproc::InprocBus;

    /// The pulse says RUNNING with the node's current step about once a second, and stops
    /// when dropped.
    #[test]
    fn pulses_carry_the_step_and_stop_when_dropped() {
        let bus: BusHandle = Arc::new(InprocBus::new());
        let sub = bus.subscribe("p/hb/**").unwrap();
        let beat = Arc::new(Beat::default());
        beat.step.store(7, Ordering::Relaxed);
        let pulse = Pulse::start(
            bus.clone(),
            vec![("p/hb/a".into(), "a".into(), beat.clone())],
        )
        .unwrap();
        let (topic, first) = sub.rx.recv_timeout(Duration::from_secs(5)).unwrap();
        assert_eq!(topic, "p/hb/a");
        let hb: Heartbeat = fiberflow_messages::decode(&first).unwrap();
        assert_eq!(
            (hb.node.as_str(), hb.state, hb.step),
            ("a", lifecycle::RUNNING, 7)
        );
        beat.step.store(8, Ordering::Relaxed);
        let (_, next) = sub.rx.recv_timeout(Duration::from_secs(5)).unwrap();
        let hb: Heartbeat = fiberflow_messages::decode(&next).unwrap();
        assert_eq!(hb.step, 8);
        drop(pulse);
        while sub.rx.try_recv().is_ok() {}
        assert!(sub.rx.recv_timeout(Duration::from_millis(1500)).is_err());
    }
}
