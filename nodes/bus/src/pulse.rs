//! A node's pulse: a thread that says every [`PULSE_PERIOD`] that each node of this
//! process is alive (a RUNNING heartbeat with its step) — as long as the node's loop shows
//! it advances: the loop stamps its [`Watch`] as it goes (every wait for samples polls at
//! least twice a second, the recorder's loop twenty times), and a node whose loop has not
//! stamped for [`LOOP_STALE`] (deadlocked, spinning somewhere it should not, blocked in a
//! call that never returns) gets no pulse. The fibre nodes show the step they work on,
//! the recorder the step it has recorded through. The flow node takes a node silent for
//! `run.liveness_s` as gone (a hung loop or process, a host or link that vanished) and
//! fails the step at once, naming it, instead of waiting out the step timeout
//! (docs/architecture.md, "Runs that survive"). A single step that computes for longer
//! than `run.liveness_s` looks the same: the setting must allow for the longest step.

use crate::BusHandle;
use fiberflow_messages::Lifecycle;
use fiberflow_messages::{encode, Heartbeat, SCHEMA_VERSION};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};

/// How often each node's pulse goes out.
pub const PULSE_PERIOD: Duration = Duration::from_secs(1);

/// A node whose loop has not stamped its [`Watch`] for this long gets no pulse.
pub const LOOP_STALE: Duration = Duration::from_secs(2);

/// When a node's loop last showed that it advances (nanoseconds after this process's
/// first use of a watch, plus one; 0: not yet). Nodes stepped in turn on one thread share
/// one watch.
#[derive(Debug, Default)]
pub struct Watch(AtomicU64);

fn epoch() -> Instant {
    static EPOCH: OnceLock<Instant> = OnceLock::new();
    *EPOCH.get_or_init(Instant::now)
}

impl Watch {
    /// The loop advances: stamped now.
    pub fn touch(&self) {
        let t = epoch().elapsed().as_nanos() as u64 + 1;
        self.0.store(t, Ordering::Relaxed);
    }

    /// How long ago the loop last stamped (None: never).
    pub fn age(&self) -> Option<Duration> {
        match self.0.load(Ordering::Relaxed) {
            0 => None,
            t => Some(
                epoch()
                    .elapsed()
                    .saturating_sub(Duration::from_nanos(t - 1)),
            ),
        }
    }
}

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
    /// Starts pulsing for `nodes`: (heartbeat topic, node name, what it shows, the watch
    /// its loop stamps). Every watch counts as stamped now.
    pub fn start(
        bus: BusHandle,
        nodes: Vec<(String, String, Arc<Beat>, Arc<Watch>)>,
    ) -> std::io::Result<Self> {
        for (_, _, _, w) in &nodes {
            w.touch();
        }
        let stop = Arc::new(AtomicBool::new(false));
        let halt = stop.clone();
        let thread = std::thread::Builder::new()
            .name("pulse".into())
            .spawn(move || {
                while !halt.load(Ordering::Relaxed) {
                    for (topic, node, beat, watch) in &nodes {
                        if watch.age().is_none_or(|a| a > LOOP_STALE) {
                            // the loop is stuck: no pulse, so the flow node finds it silent
                            continue;
                        }
                        let hb = Heartbeat {
                            schema_version: SCHEMA_VERSION,
                            node: node.clone(),
                            state: Lifecycle::Running,
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

impl Pulse {
    /// A pulse that says only that the process lives and its link holds (a RUNNING
    /// heartbeat of `node` on `topic` every [`PULSE_PERIOD`], with no step): what the
    /// nodes on other hosts watch of a multi-host run's flow node, whose session is their
    /// router, to find it gone.
    pub fn alive(bus: BusHandle, topic: String, node: String) -> std::io::Result<Self> {
        let watch = Arc::new(Watch::default());
        let stamp = watch.clone();
        let pulse = Self::start(bus, vec![(topic, node, Arc::new(Beat::default()), watch)])?;
        let halt = pulse.stop.clone();
        std::thread::Builder::new()
            .name("alive".into())
            .spawn(move || {
                while !halt.load(Ordering::Relaxed) {
                    stamp.touch();
                    std::thread::sleep(Duration::from_millis(100));
                }
            })?;
        Ok(pulse)
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
        let watch = Arc::new(Watch::default());
        let pulse = Pulse::start(
            bus.clone(),
            vec![("p/hb/a".into(), "a".into(), beat.clone(), watch.clone())],
        )
        .unwrap();
        let (topic, first) = sub.rx.recv_timeout(Duration::from_secs(5)).unwrap();
        assert_eq!(topic, "p/hb/a");
        let hb: Heartbeat = fiberflow_messages::decode(&first).unwrap();
        assert_eq!(
            (hb.node.as_str(), hb.state, hb.step),
            ("a", Lifecycle::Running, 7)
        );
        beat.step.store(8, Ordering::Relaxed);
        watch.touch();
        let (_, next) = sub.rx.recv_timeout(Duration::from_secs(5)).unwrap();
        let hb: Heartbeat = fiberflow_messages::decode(&next).unwrap();
        assert_eq!(hb.step, 8);
        drop(pulse);
        while sub.rx.try_recv().is_ok() {}
        assert!(sub.rx.recv_timeout(Duration::from_millis(1500)).is_err());
    }

    /// A node whose loop stops stamping its watch gets no pulse once the stamp is older
    /// than [`LOOP_STALE`], and pulses again when its loop stamps again.
    #[test]
    fn a_stuck_loop_gets_no_pulse() {
        let bus: BusHandle = Arc::new(InprocBus::new());
        let sub = bus.subscribe("q/hb/**").unwrap();
        let beat = Arc::new(Beat::default());
        let watch = Arc::new(Watch::default());
        let _pulse = Pulse::start(
            bus.clone(),
            vec![("q/hb/a".into(), "a".into(), beat, watch.clone())],
        )
        .unwrap();
        assert!(sub.rx.recv_timeout(Duration::from_secs(5)).is_ok());
        // not stamped: silent from LOOP_STALE on
        std::thread::sleep(LOOP_STALE + PULSE_PERIOD);
        while sub.rx.try_recv().is_ok() {}
        assert!(
            sub.rx.recv_timeout(2 * PULSE_PERIOD).is_err(),
            "a stuck loop pulsed"
        );
        watch.touch();
        assert!(sub.rx.recv_timeout(2 * PULSE_PERIOD).is_ok());
    }
}
