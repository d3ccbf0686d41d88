//! A shard's side of contact across the shards of its group (`fiber-model`'s
//! `contact::exchange`): after its free step it sends it to the group's other shards and
//! waits for theirs, then solves contact over the whole group.

use crate::serve::FiberNodeError;
use fiberflow_bus::{BusError, BusHandle, DropCounter, Encode, Inbox};
use fiberflow_fiber_model::contact::exchange::OtherPiece;
use fiberflow_fiber_model::group::FibreGroup;
use fiberflow_messages::pieces::Piece;
use fiberflow_messages::topics::Topics;
use fiberflow_messages::{decode, FiberFreeStep, SCHEMA_VERSION};
use std::time::{Duration, Instant};

/// How long a shard waits for the others' free steps before it sends its own again (one
/// of them may have lost it; they drop copies of a step they hold).
const RESEND_AFTER: Duration = Duration::from_secs(2);

/// The free steps a shard sends and receives.
pub(crate) struct Exchange {
    /// The other shards' pieces, in the order of their first fibres.
    others: Vec<OtherPiece>,
    inbox: Inbox,
    msg: Encode<FiberFreeStep>,
    topic: String,
    /// Whether `msg` holds a free step already sent (sent again while this shard waits for
    /// its samples: a shard still waiting for it may have lost it).
    sent: bool,
}

impl Exchange {
    /// The exchange of `own` with the group's other `pieces`; `whole` is the group as
    /// built (every shard builds it whole), which gives the others' fibres' properties.
    pub(crate) fn new(
        bus: &BusHandle,
        t: &Topics,
        own: &Piece,
        pieces: &[Piece],
        whole: &FibreGroup,
    ) -> Result<Self, BusError> {
        let others: Vec<&Piece> = pieces.iter().filter(|p| p.index != own.index).collect();
        let topics: Vec<String> = others
            .iter()
            .map(|p| t.contact_free_step(&p.group, p.first_fiber))
            .collect();
        let inbox = Inbox::new(fiberflow_bus::subscribe_any(bus.as_ref(), &topics)?);
        let others = others
            .iter()
            .map(|p| {
                let first = p.first_fiber as usize;
                OtherPiece::new(first, whole.slice(first, p.fibers as usize).fibres())
            })
            .collect();
        Ok(Self {
            others,
            inbox,
            msg: Encode(FiberFreeStep {
                schema_version: SCHEMA_VERSION,
                group: own.group.clone(),
                first_fiber: own.first_fiber,
                group_fibers: own.group_fibers,
                ..Default::default()
            }),
            topic: t.contact_free_step(&own.group, own.first_fiber),
            sent: false,
        })
    }

    /// The other shards' pieces as last read.
    pub(crate) fn others(&self) -> &[OtherPiece] {
        &self.others
    }

    /// Messages dropped so far (undecodable, inconsistent, another group's, a later step).
    pub(crate) fn drops(&self) -> &DropCounter {
        &self.inbox.drops
    }

    /// Sends the free step `group` just made of step `step` (at `t_plus`).
    pub(crate) fn send(
        &mut self,
        bus: &BusHandle,
        group: &FibreGroup,
        step: u64,
        t_plus: f64,
    ) -> Result<(), BusError> {
        self.msg.0.step = step;
        self.msg.0.t_plus = t_plus;
        group.fill_free_step(&mut self.msg.0);
        self.sent = true;
        bus.publish_message(&self.topic, &self.msg)
    }

    /// Sends the last free step again, if there is one; whether there was.
    pub(crate) fn resend(&self, bus: &BusHandle) -> Result<bool, BusError> {
        if self.sent {
            bus.publish_message(&self.topic, &self.msg)?;
        }
        Ok(self.sent)
    }

    /// Waits until every other shard's free step of `step` has been read, sending this
    /// shard's again every [`RESEND_AFTER`]; `alive` is asked between waits (it fails
    /// when the run was restarted). Copies of earlier steps (resends) are let go;
    /// garbage, other groups' and later steps' messages are dropped and counted.
    pub(crate) fn gather(
        &mut self,
        bus: &BusHandle,
        node: &str,
        step: u64,
        timeout: Duration,
        alive: &mut dyn FnMut() -> Result<(), FiberNodeError>,
    ) -> Result<(), FiberNodeError> {
        let from = Instant::now();
        let mut resend_at = from + RESEND_AFTER;
        loop {
            if self.others.iter().all(|o| o.step == Some(step)) {
                return Ok(());
            }
            alive()?;
            let now = Instant::now();
            let left = timeout.saturating_sub(now - from);
            if left.is_zero() {
                let missing: Vec<String> = self
                    .others
                    .iter()
                    .filter(|o| o.step != Some(step))
                    .map(|o| format!("fibres {}..", o.first_fiber))
                    .collect();
                return Err(FiberNodeError::Protocol(format!(
                    "node {node}: no free step of step {step} from the shards of {} within {:.0} s",
                    missing.join(", "),
                    timeout.as_secs_f64()
                )));
            }
            if now >= resend_at {
                self.resend(bus)?;
                tracing::info!(node, step, "no free step from every shard yet: sending ours again");
                resend_at = now + RESEND_AFTER;
            }
            let wait = left
                .min(resend_at.saturating_duration_since(now))
                .min(Duration::from_millis(500));
            let Some((topic, bytes)) = self.inbox.recv_raw(wait) else {
                continue;
            };
            let m = match decode::<FiberFreeStep>(&bytes) {
                Ok(m) => m,
                Err(e) => {
                    self.inbox.drops.drop_one(&topic, &e.to_string());
                    continue;
                }
            };
            if m.group != self.msg.0.group {
                self.inbox.drops.drop_one(&topic, "free step of another group");
                continue;
            }
            if m.step < step {
                // a shard that waited for its samples sent its free step again
                continue;
            }
            if m.step > step {
                self.inbox.drops.drop_one(&topic, "free step of a later step");
                continue;
            }
            let Some(o) = self
                .others
                .iter_mut()
                .find(|o| o.first_fiber == m.first_fiber as usize)
            else {
                self.inbox.drops.drop_one(&topic, "free step of no other shard");
                continue;
            };
            if let Err(e) = o.read(&m) {
                self.inbox.drops.drop_one(&topic, &format!("inconsistent: {e}"));
            }
        }
    }
}
