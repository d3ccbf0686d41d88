//! The fibre node's side of the lockstep, against a scripted flow node on an in-process
//! bus: the node announces itself, takes the run's announcement, sends its state every
//! step and steps on the samples of that step. Samples that are lost make it send its
//! state again; garbage, samples of another step (late duplicates, early ones) and samples
//! of the wrong size are dropped and counted, and none of it changes a bit of what the
//! node computes. (The whole run's resends — the flow node's side and the recorder's — are
//! tested with the launcher: `launch::tests::lost_samples_and_states_are_sent_again`.)

use fiberflow_bus::inproc::InprocBus;
use fiberflow_bus::{BusHandle, Inbox};
use fiberflow_fiber::serve::{serve, RunSettings};
use fiberflow_fiber::FiberNodeConfig;
use fiberflow_messages::topics::Topics;
use fiberflow_messages::{
    decode, encode, FiberGroupState, FlowSamples, Heartbeat, Lifecycle, RunAnnouncement,
    SCHEMA_VERSION,
};
use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::{Duration, Instant};

const RUN: &str = "protocol";
const GROUP: &str = "g";
const STEPS: u64 = 6;
const BOX_PLUS: [f64; 3] = [942.5, 300.0, 471.2];
/// Wall-unit shear rate of the scripted flow, u = γ y.
const SHEAR: f64 = 0.05;

/// What the scripted flow node does wrong, and when.
#[derive(Clone, Copy, PartialEq)]
enum Script {
    /// Answers every state at once with the right samples.
    Clean,
    /// Sends garbage and samples of a later step before the samples of step 2, samples of
    /// the wrong size before those of step 3, the samples of step 3 again before those of
    /// step 4 (a late duplicate), and ignores the first state of step 5 (its samples
    /// lost) until the node sends it again.
    Faulty,
}

/// The samples of `state`'s segments in the scripted shear flow, for step `step`
/// (`segments` points: the state's own, or fewer).
fn samples(state: &FiberGroupState, step: u64, segments: usize) -> Vec<u8> {
    let mut velocity = Vec::with_capacity(3 * segments);
    let mut gradient = Vec::with_capacity(9 * segments);
    for i in 0..segments {
        let y = state.centre[3 * i + 1];
        velocity.extend_from_slice(&[SHEAR * y, 0.0, 0.0]);
        let mut g = [0.0; 9];
        g[1] = SHEAR; // ∂u/∂y
        gradient.extend_from_slice(&g);
    }
    encode(&FlowSamples {
        schema_version: SCHEMA_VERSION,
        group: GROUP.into(),
        step,
        t_plus: step as f64 * 0.1,
        first_fiber: 0,
        group_fibers: state.segments_per_fiber.len() as u32,
        velocity,
        velocity_gradient: gradient,
    })
}

/// Runs one fibre node to the end against the scripted flow node; returns every state it
/// sent (step → the last bytes sent for it), how many states it sent in all, and the
/// drops it counted.
fn run(script: Script) -> (BTreeMap<u64, Vec<u8>>, usize, u64) {
    let bus: BusHandle = Arc::new(InprocBus::new());
    let t = Topics::new(RUN);
    let mut states = Inbox::new(bus.subscribe(&t.fiber_state(GROUP)).unwrap());
    let mut beats = Inbox::new(bus.subscribe(&t.heartbeat(GROUP)).unwrap());
    let cfg: FiberNodeConfig = toml::from_str(&format!(
        "group = \"{GROUP}\"\ncase = \"case1\"\n\
         placement = {{ kind = \"random\", count = 3, seed = 7 }}"
    ))
    .unwrap();
    let node = {
        let bus = bus.clone();
        std::thread::spawn(move || {
            serve(&cfg, 0, bus, RUN, BOX_PLUS, 30.0, &RunSettings::default())
        })
    };
    // the node says it is ready until it hears the announcement
    let t0 = Instant::now();
    loop {
        assert!(t0.elapsed() < Duration::from_secs(10), "no READY");
        if let Some((_, hb)) = beats.recv::<Heartbeat>(Duration::from_millis(100)) {
            if hb.state == Lifecycle::Ready {
                break;
            }
        }
    }
    let ann = RunAnnouncement {
        schema_version: SCHEMA_VERSION,
        run_id: RUN.into(),
        config_digest: String::new(),
        groups: vec![GROUP.into()],
        steps: STEPS,
        dt_plus: 0.1,
        box_plus: BOX_PLUS.to_vec(),
    };
    bus.publish(&t.announce(), &encode(&ann)).unwrap();
    let samples_topic = t.flow_samples(GROUP);
    let mut sent: BTreeMap<u64, Vec<u8>> = BTreeMap::new();
    let mut count = 0;
    let mut answered = std::collections::BTreeSet::new();
    let mut lost_once = false;
    let t0 = Instant::now();
    while sent.len() <= STEPS as usize || sent.keys().last() != Some(&STEPS) {
        assert!(t0.elapsed() < Duration::from_secs(60), "the run stalled");
        let Some((_, bytes)) = states.recv_raw(Duration::from_millis(100)) else {
            continue;
        };
        let s: FiberGroupState = decode(&bytes).unwrap();
        count += 1;
        let k = s.step;
        sent.insert(k, bytes.to_vec());
        if k == STEPS {
            break;
        }
        // a state sent again once its samples went out (step 0 with the fluid's velocity)
        // needs no answer
        if answered.contains(&k) {
            continue;
        }
        let n = s.centre.len() / 3;
        if script == Script::Faulty {
            match k {
                2 => {
                    bus.publish(&samples_topic, b"not a message").unwrap();
                    bus.publish(&samples_topic, &samples(&s, k + 1, n)).unwrap();
                }
                3 => bus.publish(&samples_topic, &samples(&s, k, n - 1)).unwrap(),
                4 => bus.publish(&samples_topic, &samples(&s, k - 1, n)).unwrap(),
                // lost: only the state sent again is answered
                5 if !lost_once => {
                    lost_once = true;
                    continue;
                }
                _ => {}
            }
        }
        bus.publish(&samples_topic, &samples(&s, k, n)).unwrap();
        answered.insert(k);
    }
    let drops = node.join().unwrap().expect("the node finishes");
    (sent, count, drops.total())
}

/// Garbage, samples of a later and of an earlier step, samples of the wrong size and a
/// lost answer: the node drops and counts the first four, sends its state of step 5 again
/// (after its five seconds of waiting), and every state it sends is bitwise that of the
/// run without faults.
#[test]
fn faults_on_the_samples_are_dropped_counted_and_repaired_without_a_changed_bit() {
    let (clean, clean_count, clean_drops) = run(Script::Clean);
    assert_eq!(clean.len(), STEPS as usize + 1, "states 0..={STEPS}");
    // without faults one state a step, and the state of step 0 again with the fluid's
    // velocity (the default start) once it is known
    assert_eq!(
        clean_count,
        STEPS as usize + 2,
        "states sent without faults"
    );
    assert_eq!(clean_drops, 0);
    let (faulty, faulty_count, faulty_drops) = run(Script::Faulty);
    assert_eq!(
        faulty_drops, 4,
        "garbage, a later step, the wrong size, an earlier step"
    );
    assert_eq!(
        faulty_count,
        clean_count + 1,
        "the state of step 5 sent again once"
    );
    assert!(faulty == clean, "the states differ");
}
