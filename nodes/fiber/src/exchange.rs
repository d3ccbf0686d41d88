//! A piece's side of contact across the shards of its group and the groups of its
//! suspension (`fiber-model`'s `contact::exchange`): after its free step it sends it to
//! the other pieces and waits for theirs, then solves contact over all of them.

use crate::config::{build_suspension, BuiltGroup, FiberNodeConfig};
use crate::serve::FiberNodeError;
use fiberflow_bus::{BusError, BusHandle, DropCounter, Encode, Inbox};
use fiberflow_fiber_model::contact::exchange::OtherPiece;
use fiberflow_fiber_model::group::FibreGroup;
use fiberflow_fiber_model::FibreError;
use fiberflow_messages::pieces::Piece;
use fiberflow_messages::topics::Topics;
use fiberflow_messages::{decode, FiberFreeStep, SCHEMA_VERSION};
use std::time::{Duration, Instant};

/// How long a shard waits for the others' free steps before it sends its own again (one
/// of them may have lost it; they drop copies of a step they hold).
const RESEND_AFTER: Duration = Duration::from_secs(2);

/// Where a piece's group and the pieces it touches come from.
pub(crate) struct Touching {
    /// The piece's whole group as built (its slice is the piece).
    pub whole: BuiltGroup,
    /// Index of the piece's first fibre in the solve's order.
    pub order: usize,
    /// The other pieces it touches (none: contact, if on, stays within the piece).
    pub others: Vec<(Piece, OtherPiece)>,
}

/// Builds `cfg`'s group and, with contact on, finds the pieces its piece `own` touches: the
/// group's other shards, and the pieces of the other groups of its suspension (`members`,
/// in the suspension's order, `cfg`'s group among them; empty: in no suspension), each
/// group built as the suspension places it, so that every piece knows the others' fibres'
/// properties.
pub(crate) fn touching(
    cfg: &FiberNodeConfig,
    own: &Piece,
    members: &[FiberNodeConfig],
    box_plus: [f64; 3],
) -> Result<Touching, FibreError> {
    let (groups, built) = if members.is_empty() {
        (vec![cfg.clone()], vec![cfg.build(box_plus)?])
    } else {
        (members.to_vec(), build_suspension(members, box_plus)?)
    };
    let mut others = Vec::new();
    let (mut order, mut offset, mut whole) = (0, 0, None);
    for (g, b) in groups.iter().zip(built) {
        for p in g.pieces(box_plus)? {
            let first = p.first_fiber as usize;
            if p.group == own.group && p.index == own.index {
                order = offset + first;
            } else if cfg.contact.is_some() {
                let fibres = b.group.slice(first, p.fibers as usize).fibres();
                others.push((p.clone(), OtherPiece::new(first, offset + first, fibres)));
            }
        }
        offset += b.group.len();
        if g.group == cfg.group {
            whole = Some(b);
        }
    }
    let whole = whole.ok_or_else(|| {
        FibreError::Config(format!("group {} is not in its own suspension", cfg.group))
    })?;
    Ok(Touching {
        whole,
        order,
        others,
    })
}

/// The free steps a piece sends and receives.
pub(crate) struct Exchange {
    /// The other pieces, each with its group and first fibre (what their messages name).
    others: Vec<OtherPiece>,
    names: Vec<(String, u32)>,
    inbox: Inbox,
    msg: Encode<FiberFreeStep>,
    topic: String,
    /// Whether `msg` holds a free step already sent (sent again while this shard waits for
    /// its samples: a shard still waiting for it may have lost it).
    sent: bool,
}

impl Exchange {
    /// The exchange of `own` with the `others` it touches ([`touching`]).
    pub(crate) fn new(
        bus: &BusHandle,
        t: &Topics,
        own: &Piece,
        others: Vec<(Piece, OtherPiece)>,
    ) -> Result<Self, BusError> {
        let topics: Vec<String> = others
            .iter()
            .map(|(p, _)| t.contact_free_step(&p.group, p.first_fiber))
            .collect();
        let inbox = Inbox::new(fiberflow_bus::subscribe_any(bus.as_ref(), &topics)?);
        let names = others
            .iter()
            .map(|(p, _)| (p.group.clone(), p.first_fiber))
            .collect();
        Ok(Self {
            others: others.into_iter().map(|(_, o)| o).collect(),
            names,
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

    /// The other pieces as last read.
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

    /// Waits until every other piece's free step of `step` has been read, sending this
    /// piece's again every [`RESEND_AFTER`]; `alive` is asked between waits (it fails
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
                tracing::info!(
                    node,
                    step,
                    "no free step from every shard yet: sending ours again"
                );
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
            if m.step < step {
                // a shard that waited for its samples sent its free step again
                continue;
            }
            if m.step > step {
                self.inbox
                    .drops
                    .drop_one(&topic, "free step of a later step");
                continue;
            }
            let Some(i) = self
                .names
                .iter()
                .position(|(g, first)| *g == m.group && *first == m.first_fiber)
            else {
                self.inbox
                    .drops
                    .drop_one(&topic, "free step of no piece this one touches");
                continue;
            };
            if let Err(e) = self.others[i].read(&m) {
                self.inbox
                    .drops
                    .drop_one(&topic, &format!("inconsistent: {e}"));
            }
        }
    }
}
