//! A flow node on another host, as a fibre node sees it: its heartbeats say whether it
//! started the run again (this node then fails, and its launcher follows the restart) or
//! went silent (its host or its router gone).

use crate::serve::FiberNodeError;
use fiberflow_bus::Inbox;
use fiberflow_messages::{Heartbeat, Lifecycle};
use std::time::{Duration, Instant};

/// The heartbeats of a flow node on another host: whether it started the run again, or
/// went silent ([`flow_restarted`]).
pub(crate) struct FlowWatch {
    pub(crate) inbox: Inbox,
    /// When a heartbeat of the flow node last arrived (None: not yet).
    pub(crate) heard: Option<Instant>,
    pub(crate) silent_after: Duration,
    /// When this node took the run's announcement (None: not yet).
    pub(crate) announced: Option<Instant>,
}

/// The flow node says READY while the nodes join, before it announces the run: a READY of
/// this node's own first step that arrives this long after the announcement comes from a
/// flow node started again (one whose host was lost while this node waited at its first
/// step), not from the join.
const JOIN_READY_GRACE: Duration = Duration::from_secs(2);

/// Fails when the flow node (on another host) has started the run again: it says READY
/// (with the step it starts from) only while it waits for the nodes to join, so a READY
/// read once node `node` (which started at step `start`) is past its first step comes
/// from a restarted flow node, and so does one at the first step that names another step
/// or arrives [`JOIN_READY_GRACE`] after the announcement (the join's own, of step `start`,
/// are read and let go there). Fails too when the flow
/// node, once heard, has been silent for the run's liveness: its host or its router is
/// gone, and a restarted one would not reach this node's session. `flow_hb`: the flow
/// node's heartbeats (None: the flow node runs beside this node and cannot restart alone).
pub(crate) fn flow_restarted(
    flow_hb: Option<&mut FlowWatch>,
    node: &str,
    start: u64,
    k: u64,
) -> Result<(), FiberNodeError> {
    let Some(w) = flow_hb else {
        return Ok(());
    };
    while let Some((_, hb)) = w.inbox.recv::<Heartbeat>(Duration::ZERO) {
        w.heard = Some(Instant::now());
        let late = w.announced.is_some_and(|t| t.elapsed() > JOIN_READY_GRACE);
        if hb.state == Lifecycle::Ready && (k > start || hb.step != start || late) {
            return Err(FiberNodeError::Protocol(format!(
                "node {node}: the flow node started the run again from step {} while this \
                 node was at step {k} (it was restarted): this node is restarted from \
                 that step too",
                hb.step
            )));
        }
    }
    if let Some(t) = w.heard {
        if t.elapsed() > w.silent_after {
            return Err(FiberNodeError::Protocol(format!(
                "node {node}: the flow node has been silent for {:.0} s (run.liveness_s) at \
                 step {k}: its host or its router is gone; this node follows the run's restart",
                w.silent_after.as_secs_f64()
            )));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use fiberflow_bus::{inproc::InprocBus, Bus};

    /// A READY of the flow node: let go at the node's first step when it names that step
    /// and comes with the announcement (the join's), taken as a restart past the first
    /// step, when it names another step, or when it comes well after the announcement
    /// (a head restarted again while this node, restarted itself, was at its first step:
    /// before, it waited for samples the new flow node never sent, and the run burnt a
    /// restart on its liveness).
    #[test]
    fn a_ready_of_another_step_at_the_first_step_is_a_restart() {
        let bus = InprocBus::new();
        let mut watch = FlowWatch {
            inbox: Inbox::new(bus.subscribe("hb").unwrap()),
            heard: None,
            silent_after: Duration::from_secs(30),
            announced: Some(Instant::now()),
        };
        let ready = |step: u64| {
            let hb = Heartbeat {
                schema_version: fiberflow_messages::SCHEMA_VERSION,
                node: "flow".into(),
                state: Lifecycle::Ready,
                step,
                dropped: 0,
            };
            bus.publish("hb", &fiberflow_messages::encode(&hb)).unwrap();
        };
        for (said, k, restart) in [(200, 200, false), (100, 200, true), (200, 201, true)] {
            ready(said);
            let r = flow_restarted(Some(&mut watch), "stiff", 200, k);
            assert_eq!(r.is_err(), restart, "READY {said} at step {k}: {r:?}");
        }
        // the node's own step, long after the announcement: a flow node started again
        watch.announced = Some(Instant::now() - 2 * JOIN_READY_GRACE);
        ready(200);
        assert!(flow_restarted(Some(&mut watch), "stiff", 200, 200).is_err());
    }

    /// A flow node heard once and then silent for the liveness is gone (its router with
    /// it: the node's session would not reach a restarted one), and the node fails to
    /// follow the restart; one never heard is left to the join's timeouts.
    #[test]
    fn a_flow_node_silent_for_the_liveness_is_gone() {
        let bus = InprocBus::new();
        let mut watch = FlowWatch {
            inbox: Inbox::new(bus.subscribe("hb").unwrap()),
            heard: None,
            silent_after: Duration::from_millis(200),
            announced: None,
        };
        std::thread::sleep(Duration::from_millis(300));
        assert!(flow_restarted(Some(&mut watch), "stiff", 0, 0).is_ok());
        let hb = Heartbeat {
            schema_version: fiberflow_messages::SCHEMA_VERSION,
            node: "flow".into(),
            state: Lifecycle::Running,
            step: 0,
            dropped: 0,
        };
        bus.publish("hb", &fiberflow_messages::encode(&hb)).unwrap();
        assert!(flow_restarted(Some(&mut watch), "stiff", 0, 0).is_ok());
        std::thread::sleep(Duration::from_millis(300));
        let e = flow_restarted(Some(&mut watch), "stiff", 0, 0).unwrap_err();
        assert!(e.to_string().contains("silent"), "{e}");
    }
}
