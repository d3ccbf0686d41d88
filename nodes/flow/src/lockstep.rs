//! The lockstep's bookkeeping on the flow node's side: the fibre nodes' states gathered
//! for each step (those that make no sense dropped and counted), and the samples served
//! to each piece, sent again to a node that says it still waits for them.

use crate::error::FlowError;
use crate::outgoing::heartbeat;
use crate::run::RunInfo;
use fiberflow_bus::{BusHandle, DropCounter, Encode, Inbox};
use fiberflow_messages::topics::Topics;
use fiberflow_messages::Lifecycle;
use fiberflow_messages::NodeRole;
use fiberflow_messages::{lifecycle, FiberGroupState, FlowSamples, Heartbeat};
use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// How often the flow node looks at heartbeats while it waits for states.
const HEARTBEAT_POLL: Duration = Duration::from_millis(200);

/// The samples last published to each piece: (step, topic, message). The message is
/// encoded on the outbox's thread, straight into the transport's buffer; its arrays are
/// sampled into again next step.
pub(crate) type SentSamples = BTreeMap<(String, u32), (u64, String, Arc<Encode<FlowSamples>>)>;

/// How often the run's announcement may go out again to nodes that still say READY.
const REANNOUNCE_EVERY: Duration = Duration::from_secs(1);

/// What the flow node hears from the other nodes besides their states: when each was last
/// heard from, how far the recorder has recorded, and who still waits for the run's
/// announcement.
#[derive(Default)]
struct Peers {
    /// When each node was last heard from (any heartbeat: its pulse, WAITING, …).
    heard: BTreeMap<String, Instant>,
    /// The step the recorder holds every piece's state through (its RUNNING heartbeats).
    recorded: u64,
    /// The newest checkpoint the recorder has on disk (its COMMITTED heartbeats).
    committed: Option<u64>,
    /// The run's announcement (topic, bytes) and when it last went out.
    announcement: Option<(String, Vec<u8>, Instant)>,
}

impl Peers {
    /// Reads the heartbeats that came in (waiting up to `first_wait` for the first): marks
    /// each node as heard from, takes the recorder's progress from its RUNNING heartbeats,
    /// announces the run again (at most once per [`REANNOUNCE_EVERY`]) while a node still
    /// says READY — it missed the announcement, e.g. behind a partition as it went out,
    /// and would otherwise wait for it until its timeout — and answers fibre nodes that wait
    /// (WAITING) for samples already published: the message was lost in transit, so it goes
    /// out again. A node waiting for a step not served yet has re-sent its state instead.
    fn listen(
        &mut self,
        bus: &BusHandle,
        hb_in: &mut Inbox,
        served: &SentSamples,
        run: &RunInfo,
        first_wait: Duration,
    ) -> Result<(), FlowError> {
        // an in-process run whose other node failed: the launcher says so (a heartbeat
        // saying FAILED could be anyone's on the bus)
        if run.stop.as_ref().is_some_and(|s| s.is_set()) {
            heartbeat(bus, &Topics::new(&run.run_id), Lifecycle::Failed, 0, 0)?;
            return Err(FlowError::Protocol(
                "stopped: the run is stopping (another node failed, or Ctrl-C)".into(),
            ));
        }
        let mut wait = first_wait;
        while let Some((_, hb)) = hb_in.recv::<Heartbeat>(wait) {
            wait = Duration::ZERO;
            self.heard.insert(hb.node.clone(), Instant::now());
            if NodeRole::Recorder.is(&hb.node) && hb.state == Lifecycle::Running {
                self.recorded = self.recorded.max(hb.step);
            }
            if NodeRole::Recorder.is(&hb.node) && hb.state == Lifecycle::Committed {
                self.committed = self.committed.max(Some(hb.step));
            }
            if hb.state == Lifecycle::Ready {
                if let Some((topic, bytes, at)) = self.announcement.as_mut() {
                    if at.elapsed() >= REANNOUNCE_EVERY {
                        tracing::info!(node = %hb.node, "node still waits for the run's announcement: announcing again");
                        bus.publish(topic, bytes)?;
                        *at = Instant::now();
                    }
                }
            }
            if hb.state != Lifecycle::Waiting {
                continue;
            }
            let Some(p) = run.pieces.iter().find(|p| p.node() == hb.node) else {
                continue;
            };
            if let Some((step, topic, msg)) = served.get(&(p.group.clone(), p.first_fiber)) {
                if *step == hb.step {
                    tracing::info!(node = %hb.node, step, "node waits for samples already sent: sending them again");
                    bus.publish_message(topic, msg.as_ref())?;
                }
            }
        }
        Ok(())
    }
}

/// The states of the step being served, by (group, first fibre), and the states already
/// served, whose arrays (MBs per group at scale) are decoded into again.
pub(crate) struct States {
    inbox: Inbox,
    pending: BTreeMap<(String, u32), FiberGroupState>,
    spare: Vec<FiberGroupState>,
    peers: Peers,
}

impl States {
    pub(crate) fn new(inbox: Inbox) -> Self {
        Self {
            inbox,
            pending: BTreeMap::new(),
            spare: Vec::new(),
            peers: Peers::default(),
        }
    }

    /// The run's announcement as published (`topic`, `bytes`): it goes out again to
    /// nodes that still say READY.
    pub(crate) fn announced(&mut self, topic: String, bytes: Vec<u8>) {
        self.peers.announcement = Some((topic, bytes, Instant::now()));
    }

    /// The newest checkpoint the recorder has said is on its disk.
    pub(crate) fn recorder_committed(&self) -> Option<u64> {
        self.peers.committed
    }

    /// Drops (and counts) what arrived before the run started: none of it is part of it.
    pub(crate) fn drop_early(&mut self) {
        while let Some((topic, _)) = self.inbox.recv_raw(Duration::ZERO) {
            self.inbox
                .drops
                .drop_one(&topic, "message before the run started");
        }
    }

    /// Waits until every piece's state of step `k` is in (answering nodes that wait for
    /// samples already served meanwhile), then for the recorder to be at most
    /// [`lifecycle::RECORDER_LAG_STEPS`] behind; fails, saying FAILED and naming the silent
    /// nodes, after the run's step timeout.
    pub(crate) fn gather(
        &mut self,
        k: u64,
        run: &RunInfo,
        bus: &BusHandle,
        t: &Topics,
        hb_in: &mut Inbox,
        served: &SentSamples,
    ) -> Result<(), FlowError> {
        let step_timeout = Duration::from_secs_f64(run.step_timeout_s);
        let wait_from = Instant::now();
        // a node not heard from yet counts as heard now: its silence is timed from here
        for p in &run.pieces {
            self.peers.heard.entry(p.node()).or_insert(wait_from);
        }
        while self.pending.len() < run.pieces.len() {
            let left = step_timeout.saturating_sub(wait_from.elapsed());
            if left.is_zero() {
                let missing: Vec<_> = run
                    .pieces
                    .iter()
                    .filter(|p| !self.pending.contains_key(&(p.group.clone(), p.first_fiber)))
                    .map(|p| p.node())
                    .collect();
                heartbeat(bus, t, Lifecycle::Failed, k, self.inbox.drops.total())?;
                return Err(FlowError::PeerLost(format!(
                    "step {k}: no state from fibre node(s) {} within {:.0} s",
                    missing.join(", "),
                    run.step_timeout_s
                )));
            }
            self.peers.listen(bus, hb_in, served, run, Duration::ZERO)?;
            if let Some(silent) = self.silent(run) {
                heartbeat(bus, t, Lifecycle::Failed, k, self.inbox.drops.total())?;
                return Err(FlowError::PeerLost(format!(
                    "step {k}: fibre node(s) {silent} silent for more than run.liveness_s = {:.0} s \
                     (no state, no heartbeat: the process hung, or its host or the link to it is gone)",
                    run.liveness_s
                )));
            }
            let Some((topic, bytes)) = self.inbox.recv_raw(left.min(HEARTBEAT_POLL)) else {
                continue;
            };
            if !topic.ends_with("/state") {
                continue; // metrics and other fibre topics are not for us
            }
            // decoded into a state served before, when there is one: its arrays keep
            // their allocations
            let mut s = self.spare.pop().unwrap_or_default();
            let decoded = fiberflow_messages::decode_state_into(&mut s, &bytes).map(|()| s);
            match decoded {
                Ok(s) => match admit(&s, k, run) {
                    Admit::Take => match self.pending.entry((s.group.clone(), s.first_fiber)) {
                        std::collections::btree_map::Entry::Vacant(e) => {
                            e.insert(s);
                        }
                        std::collections::btree_map::Entry::Occupied(_) => self.spare.push(s),
                    },
                    Admit::Ignore => {
                        tracing::debug!(group = %s.group, step = s.step, expected = k, "ignoring the state of the step just served");
                        self.spare.push(s);
                    }
                    Admit::Drop(why) => {
                        self.inbox.drops.drop_one(&topic, &why);
                        self.spare.push(s);
                    }
                },
                Err(e) => self.inbox.drops.drop_one(&topic, &e.to_string()),
            }
        }
        self.await_recorder(k, run, bus, t, hb_in, served)
    }

    /// Waits until the recorder (when the run has one, and fibres) holds every piece's
    /// state through step k − [`lifecycle::RECORDER_LAG_STEPS`], so a slow recorder slows
    /// the run rather than letting messages pile up in its queue; fails, naming the
    /// recorder, when it is silent for `run.liveness_s` (or, with liveness off, after the
    /// step timeout).
    fn await_recorder(
        &mut self,
        k: u64,
        run: &RunInfo,
        bus: &BusHandle,
        t: &Topics,
        hb_in: &mut Inbox,
        served: &SentSamples,
    ) -> Result<(), FlowError> {
        // the recorder tells how far it has recorded by the fibre states it holds: with no
        // fibre group there are none to wait for (and it would never say it got further)
        if !run.expected_nodes.iter().any(|n| NodeRole::Recorder.is(n)) || run.pieces.is_empty() {
            return Ok(());
        }
        let wait_from = Instant::now();
        // not heard from yet: its silence is timed from here
        self.peers
            .heard
            .entry("recorder".into())
            .or_insert(wait_from);
        let mut first_wait = Duration::ZERO;
        loop {
            self.peers.listen(bus, hb_in, served, run, first_wait)?;
            let through = self.peers.recorded.max(run.start_step);
            if through + lifecycle::RECORDER_LAG_STEPS >= k {
                return Ok(());
            }
            let silent_s = self
                .peers
                .heard
                .get("recorder")
                .map_or(0.0, |t| t.elapsed().as_secs_f64());
            let limit_s = if run.liveness_s > 0.0 {
                run.liveness_s
            } else {
                run.step_timeout_s
            };
            if silent_s > limit_s || wait_from.elapsed().as_secs_f64() > run.step_timeout_s {
                heartbeat(bus, t, Lifecycle::Failed, k, self.inbox.drops.total())?;
                return Err(FlowError::PeerLost(format!(
                    "step {k}: the recorder has recorded only through step {through} and was \
                     silent for {silent_s:.0} s (run.liveness_s = {:.0} s, run.step_timeout_s = \
                     {:.0} s): the process hung, or its host or the link to it is gone",
                    run.liveness_s, run.step_timeout_s
                )));
            }
            first_wait = HEARTBEAT_POLL;
        }
    }

    /// The fibre nodes whose state is awaited and that have not been heard from for longer
    /// than `run.liveness_s` (None: all alive, or liveness off).
    fn silent(&self, run: &RunInfo) -> Option<String> {
        if run.liveness_s <= 0.0 {
            return None;
        }
        let limit = Duration::from_secs_f64(run.liveness_s);
        let silent: Vec<String> = run
            .pieces
            .iter()
            .filter(|p| !self.pending.contains_key(&(p.group.clone(), p.first_fiber)))
            .map(|p| p.node())
            .filter(|n| self.peers.heard.get(n).is_some_and(|t| t.elapsed() > limit))
            .map(|n| {
                let s = self
                    .peers
                    .heard
                    .get(&n)
                    .map_or(0.0, |t| t.elapsed().as_secs_f64());
                format!("{n} ({s:.0} s)")
            })
            .collect();
        (!silent.is_empty()).then(|| silent.join(", "))
    }

    /// The step's states, by (group, first fibre); [`States::recycle`] takes each back
    /// once served.
    pub(crate) fn take(&mut self) -> BTreeMap<(String, u32), FiberGroupState> {
        std::mem::take(&mut self.pending)
    }

    /// A served state, whose arrays a later state is decoded into.
    pub(crate) fn recycle(&mut self, s: FiberGroupState) {
        self.spare.push(s);
    }

    /// What was dropped so far, by topic.
    pub(crate) fn drops(&self) -> &DropCounter {
        &self.inbox.drops
    }
}

/// What becomes of a state that decoded while a step is served.
pub(crate) enum Admit {
    Take,
    /// The state of step k−1 again (a fluid-velocity start republishes step 0 with its
    /// velocities set): expected, not counted.
    Ignore,
    Drop(String),
}

/// Decides what to do with a state that decoded while serving step `k`: states that make
/// no sense (inconsistent arrays, an unknown group, another segment count than the
/// group's, a point outside the channel, a step from the past or the future) are dropped.
pub(crate) fn admit(s: &FiberGroupState, k: u64, run: &RunInfo) -> Admit {
    use fiberflow_messages::sanity::Sane;
    if let Err(why) = s.check() {
        return Admit::Drop(format!("inconsistent: {why}"));
    }
    if !run.groups.contains(&s.group) {
        return Admit::Drop(format!("state of unknown group {:?}", s.group));
    }
    let Some(p) = run
        .pieces
        .iter()
        .find(|p| p.group == s.group && p.first_fiber == s.first_fiber)
    else {
        return Admit::Drop(format!(
            "group {} has no shard starting at fibre {}",
            s.group, s.first_fiber
        ));
    };
    if s.group_fibers != p.group_fibers || s.centre.len() != 3 * p.segments {
        return Admit::Drop(format!(
            "shard {} has {} of {} fibres in {} segments, the state {} of {} in {}",
            p.node(),
            p.fibers,
            p.group_fibers,
            p.segments,
            s.segments_per_fiber.len(),
            s.group_fibers,
            s.centre.len() / 3
        ));
    }
    if s.step + 1 == k {
        return Admit::Ignore;
    }
    if s.step != k {
        return Admit::Drop(format!("state of step {} while serving step {k}", s.step));
    }
    let half = 0.5 * run.box_plus[1] * (1.0 + 1e-9);
    // one pass without an early exit (vectorised; the values are finite by now)
    let inside = s.centre.chunks_exact(3).fold(true, |ok, p| {
        ok & (p[1].abs() <= half) & (p[0].abs() <= 1e12) & (p[2].abs() <= 1e12)
    });
    if !inside {
        return Admit::Drop("a segment centre outside the channel".into());
    }
    Admit::Take
}

/// A run of one group, `case1`, in one piece of one 7-segment fibre.
#[cfg(test)]
pub(crate) fn one_piece_run() -> RunInfo {
    let groups = vec!["case1".to_string()];
    RunInfo {
        run_id: "fz".into(),
        config_digest: String::new(),
        groups: groups.clone(),
        expected_nodes: groups,
        steps: 400,
        box_plus: [942.0, 300.0, 471.0],
        step_timeout_s: 1.0,
        liveness_s: 0.0,
        start_step: 0,
        resume_dir: None,
        checkpoint_every: 0,
        checkpoint_root: None,
        pieces: vec![fiberflow_messages::pieces::Piece {
            group: "case1".into(),
            index: 0,
            shards: 1,
            first_fiber: 0,
            fibers: 1,
            group_fibers: 1,
            segments: 7,
        }],
        step_times: None,
        two_way: false,
        remote_pieces: vec![],
        stop: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fiberflow_bus::inproc::InprocBus;
    use fiberflow_messages::{encode, SCHEMA_VERSION};

    fn ready(node: &str) -> Vec<u8> {
        encode(&Heartbeat {
            schema_version: SCHEMA_VERSION,
            node: node.into(),
            state: Lifecycle::Ready,
            step: 0,
            dropped: 0,
        })
    }

    /// A node that still says READY a second after the run was announced missed the
    /// announcement (a partition as it went out): it goes out again, the same bytes, at
    /// most once a second; READYs from before that second (sent as the first went out) do
    /// not repeat it.
    #[test]
    fn a_node_still_ready_after_the_announcement_is_announced_to_again() {
        let bus: BusHandle = Arc::new(InprocBus::new());
        let ann_sub = bus.subscribe("r/announce").unwrap();
        let mut hb_in = Inbox::new(bus.subscribe("r/hb/**").unwrap());
        let run = one_piece_run();
        let mut peers = Peers {
            announcement: Some(("r/announce".into(), vec![1, 2, 3], Instant::now())),
            ..Peers::default()
        };
        let served = SentSamples::new();
        bus.publish("r/hb/case1", &ready("case1")).unwrap();
        peers
            .listen(&bus, &mut hb_in, &served, &run, Duration::from_millis(500))
            .unwrap();
        assert!(
            ann_sub.rx.try_recv().is_err(),
            "announced again within the second"
        );
        std::thread::sleep(REANNOUNCE_EVERY);
        for _ in 0..3 {
            bus.publish("r/hb/case1", &ready("case1")).unwrap();
        }
        peers
            .listen(&bus, &mut hb_in, &served, &run, Duration::from_millis(500))
            .unwrap();
        let (topic, bytes) = ann_sub.rx.recv_timeout(Duration::from_secs(1)).unwrap();
        assert_eq!(topic, "r/announce");
        assert_eq!(&bytes[..], &[1u8, 2, 3][..]);
        assert!(
            ann_sub.rx.try_recv().is_err(),
            "three READYs, one announcement"
        );
        assert!(peers.heard.contains_key("case1"));
    }
}

#[cfg(test)]
mod fuzz {
    use super::*;
    use fiberflow_messages::fuzz::{random_payload, Rng};

    /// 10^5 random states (valid CDR, random lengths, values and steps) through the flow
    /// node's admission: no panic, and every admitted state has the group's segment count,
    /// finite values and centres inside the channel (what the sampler then reads).
    #[test]
    fn admission_survives_random_states() {
        let groups = vec!["case1".to_string()];
        let run = one_piece_run();
        let mut r = Rng::new(5);
        let mut taken = 0;
        for i in 0..100_000u64 {
            let b = random_payload(fiberflow_messages::Kind::FiberGroupState, &mut r, &groups);
            let Ok(mut s) = fiberflow_messages::decode::<FiberGroupState>(&b) else {
                continue;
            };
            // steer a share of the cases to the step being served and the right size
            if i % 3 == 0 {
                s.step = i % 50;
                for p in s.centre.chunks_mut(3) {
                    if p.len() == 3 {
                        p[1] = p[1].clamp(-150.0, 150.0);
                    }
                }
            }
            if let Admit::Take = admit(&s, i % 50, &run) {
                assert_eq!(s.centre.len(), 21);
                assert!(s.centre.iter().all(|x| x.is_finite()));
                assert!(s.centre.chunks(3).all(|p| p[1].abs() <= 150.0 + 1e-6));
                taken += 1;
            }
        }
        assert!(
            taken > 0,
            "no random state was ever admitted: the test does not reach it"
        );
    }
}
