//! A piece's side of contact across the shards of its group and the groups of its
//! suspension (`fiber-model`'s `contact::exchange`). The suspension's first piece (the
//! first shard of its first group) reads every other piece's free step, solves contact
//! over all of them and sends each piece what the solve did to it; every other piece sends
//! its free step to it and takes its part. So the solve runs once per step, not once per
//! piece, and a piece other than the first sends and receives only its own fibres
//! (docs/contact.md, "Across shards").

use crate::config::{build_suspension, BuiltGroup, FiberNodeConfig};
use crate::serve::FiberNodeError;
use fiberflow_bus::{BusError, BusHandle, DropCounter, Encode, Inbox};
use fiberflow_fiber_model::contact::exchange::{ContactSolved, FreeStep, OtherPiece};
use fiberflow_fiber_model::group::{FiberGroup, StepReport};
use fiberflow_fiber_model::FiberError;
use fiberflow_messages::pieces::Piece;
use fiberflow_messages::sanity::Sane;
use fiberflow_messages::topics::Topics;
use fiberflow_messages::{decode, FiberContactSolved, FiberFreeStep, SCHEMA_VERSION};
use std::time::{Duration, Instant};

/// How long a piece waits for its part of the solve before it sends its free step again
/// (one of the two messages may have been lost; the first piece answers a copy of a step
/// it solved with that step's part again), and how long the first piece waits for the
/// others' free steps before it sends its last parts again.
const RESEND_AFTER: Duration = Duration::from_secs(2);

/// Where a piece's group and the pieces it touches come from.
pub(crate) struct Touching {
    /// The piece's whole group as built (its slice is the piece).
    pub whole: BuiltGroup,
    /// Index of the piece's first fibre in the solve's order.
    pub order: usize,
    /// The other pieces it touches (none: contact, if on, stays within the piece); their
    /// fibres only on the piece that solves (the first in the solve's order).
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
) -> Result<Touching, FiberError> {
    let (groups, built) = if members.is_empty() {
        (vec![cfg.clone()], vec![cfg.build(box_plus)?])
    } else {
        (members.to_vec(), build_suspension(members, box_plus)?)
    };
    // the first piece of the solve's order solves for all and keeps the others' fibres;
    // any other piece needs only to know the pieces (no copies of their fibres)
    let solves = groups.first().is_some_and(|g| g.group == own.group) && own.first_fiber == 0;
    let mut others = Vec::new();
    let (mut order, mut offset, mut whole) = (0, 0, None);
    for (g, b) in groups.iter().zip(built) {
        for p in g.pieces(box_plus)? {
            let first = p.first_fiber as usize;
            if p.group == own.group && p.index == own.index {
                order = offset + first;
            } else if cfg.contact.is_some() {
                let fibers = if solves {
                    b.group.slice(first, p.fibers as usize).fibers()
                } else {
                    Vec::new()
                };
                others.push((p.clone(), OtherPiece::new(first, offset + first, fibers)));
            }
        }
        offset += b.group.len();
        if g.group == cfg.group {
            whole = Some(b);
        }
    }
    let whole = whole.ok_or_else(|| {
        FiberError::Config(format!("group {} is not in its own suspension", cfg.group))
    })?;
    Ok(Touching {
        whole,
        order,
        others,
    })
}

/// A piece's side of the exchange: the suspension's first piece solves, the others send
/// their free steps to it and take their parts.
pub(crate) struct Exchange {
    role: Role,
    inbox: Inbox,
    /// Whether the piece holds a free step or parts already sent (sent again while it
    /// waits for its samples: a piece still waiting for them may have lost them).
    sent: bool,
    /// Wall seconds spent sending and waiting (not solving).
    exchange_s: f64,
}

enum Role {
    /// The suspension's first piece.
    Solver {
        /// The other pieces, each with its group and first fibre (what their messages
        /// name), and the part of the last solve for each, with its topic.
        others: Vec<OtherPiece>,
        names: Vec<(String, u32)>,
        parts: Vec<Encode<FiberContactSolved>>,
        part_topics: Vec<String>,
        /// The step the parts are of.
        solved: Option<u64>,
    },
    /// Any other piece.
    Member {
        /// Boxed: the message's arrays make it far larger than the other role.
        free: Box<Encode<FiberFreeStep>>,
        free_topic: String,
        /// The first piece, for messages.
        solver: String,
    },
}

impl Exchange {
    /// The exchange of `own` with the `others` it touches ([`touching`]): `own` solves
    /// when it comes first in the solve's order (`order` below every other piece's).
    pub(crate) fn new(
        bus: &BusHandle,
        t: &Topics,
        own: &Piece,
        order: usize,
        others: Vec<(Piece, OtherPiece)>,
    ) -> Result<Self, BusError> {
        let first = others.iter().min_by_key(|(_, o)| o.order);
        match first {
            Some((p, o)) if o.order < order => {
                let inbox =
                    Inbox::new(bus.subscribe(&t.contact_solved(&own.group, own.first_fiber))?);
                Ok(Self {
                    role: Role::Member {
                        free: Box::new(Encode(FiberFreeStep {
                            schema_version: SCHEMA_VERSION,
                            group: own.group.clone(),
                            first_fiber: own.first_fiber,
                            group_fibers: own.group_fibers,
                            ..Default::default()
                        })),
                        free_topic: t.contact_free_step(&own.group, own.first_fiber),
                        solver: format!("{} fibres {}..", p.group, p.first_fiber),
                    },
                    inbox,
                    sent: false,
                    exchange_s: 0.0,
                })
            }
            _ => {
                let topics: Vec<String> = others
                    .iter()
                    .map(|(p, _)| t.contact_free_step(&p.group, p.first_fiber))
                    .collect();
                let inbox = Inbox::new(fiberflow_bus::subscribe_any(bus.as_ref(), &topics)?);
                let names = others
                    .iter()
                    .map(|(p, _)| (p.group.clone(), p.first_fiber))
                    .collect();
                let parts = others
                    .iter()
                    .map(|(p, _)| {
                        Encode(FiberContactSolved {
                            schema_version: SCHEMA_VERSION,
                            group: p.group.clone(),
                            first_fiber: p.first_fiber,
                            group_fibers: p.group_fibers,
                            ..Default::default()
                        })
                    })
                    .collect();
                let part_topics = others
                    .iter()
                    .map(|(p, _)| t.contact_solved(&p.group, p.first_fiber))
                    .collect();
                Ok(Self {
                    role: Role::Solver {
                        others: others.into_iter().map(|(_, o)| o).collect(),
                        names,
                        parts,
                        part_topics,
                        solved: None,
                    },
                    inbox,
                    sent: false,
                    exchange_s: 0.0,
                })
            }
        }
    }

    /// Wall seconds this piece spent sending its messages and waiting for the others'.
    pub(crate) fn exchange_s(&self) -> f64 {
        self.exchange_s
    }

    /// Whether this piece solves contact for the suspension.
    pub(crate) fn solves(&self) -> bool {
        matches!(self.role, Role::Solver { .. })
    }

    /// Messages dropped so far (undecodable, inconsistent, another piece's, a later step).
    pub(crate) fn drops(&self) -> &DropCounter {
        &self.inbox.drops
    }

    /// Sends what this piece last sent again (its free step, or the first piece's parts),
    /// if it sent anything yet; whether it did.
    pub(crate) fn resend(&self, bus: &BusHandle) -> Result<bool, BusError> {
        if !self.sent {
            return Ok(false);
        }
        match &self.role {
            Role::Member {
                free, free_topic, ..
            } => bus.publish_message(free_topic, free.as_ref())?,
            Role::Solver {
                parts, part_topics, ..
            } => {
                for (m, topic) in parts.iter().zip(part_topics) {
                    bus.publish_message(topic, m)?;
                }
            }
        }
        Ok(true)
    }

    /// Contact for step `k` after `group`'s free step (at `t_plus`; `order`: the piece's
    /// first fibre in the solve). The first piece waits until every other piece's free
    /// step of `k` has been read, solves and sends the parts; any other piece sends its
    /// free step and waits for its part, sending the free step again every
    /// [`RESEND_AFTER`]. `alive` is asked between waits (it fails when the run was
    /// restarted). Garbage, other pieces' and later steps' messages, and parts that do
    /// not fit the piece are dropped and counted.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn contact(
        &mut self,
        bus: &BusHandle,
        node: &str,
        group: &mut FiberGroup,
        order: usize,
        step: u64,
        t_plus: f64,
        dt: f64,
        timeout: Duration,
        alive: &mut dyn FnMut() -> Result<(), FiberNodeError>,
    ) -> Result<StepReport, FiberNodeError> {
        let t0 = Instant::now();
        if let Role::Member {
            free, free_topic, ..
        } = &mut self.role
        {
            free.0.step = step;
            free.0.t_plus = t_plus;
            let mut fs = take_free_step(&mut free.0);
            group.fill_free_step(&mut fs);
            put_free_step(&mut free.0, fs);
            self.sent = true;
            bus.publish_message(free_topic, free.as_ref())?;
        }
        let waited = self.wait(bus, node, group, order, step, timeout, alive);
        self.exchange_s += t0.elapsed().as_secs_f64();
        let mut report = waited?.unwrap_or_default();
        if let Role::Solver {
            others,
            parts,
            part_topics,
            solved,
            ..
        } = &mut self.role
        {
            for m in parts.iter_mut() {
                m.0.step = step;
                m.0.t_plus = t_plus;
            }
            let mut done: Vec<ContactSolved> =
                parts.iter_mut().map(|m| take_solved(&mut m.0)).collect();
            report = group.resolve_contact_for(order, others, dt, &mut done);
            for (m, filled) in parts.iter_mut().zip(done) {
                put_solved(&mut m.0, filled);
            }
            *solved = Some(step);
            self.sent = true;
            let t1 = Instant::now();
            for (m, topic) in parts.iter().zip(part_topics.iter()) {
                bus.publish_message(topic, m)?;
            }
            self.exchange_s += t1.elapsed().as_secs_f64();
        }
        Ok(report)
    }

    /// The wait of [`Self::contact`]: for every other piece's free step (first piece), or
    /// for this piece's part, which it takes (any other piece: what the part did).
    #[allow(clippy::too_many_arguments)]
    fn wait(
        &mut self,
        bus: &BusHandle,
        node: &str,
        group: &mut FiberGroup,
        order: usize,
        step: u64,
        timeout: Duration,
        alive: &mut dyn FnMut() -> Result<(), FiberNodeError>,
    ) -> Result<Option<StepReport>, FiberNodeError> {
        let from = Instant::now();
        let mut resend_at = from + RESEND_AFTER;
        loop {
            if let Role::Solver { others, .. } = &self.role {
                if others.iter().all(|o| o.step == Some(step)) {
                    return Ok(None);
                }
            }
            alive()?;
            let now = Instant::now();
            let left = timeout.saturating_sub(now - from);
            if left.is_zero() {
                let missing = match &self.role {
                    Role::Solver { others, .. } => {
                        let m: Vec<String> = others
                            .iter()
                            .filter(|o| o.step != Some(step))
                            .map(|o| format!("fibres {}..", o.first_fiber))
                            .collect();
                        format!(
                            "no free step of step {step} from the pieces of {}",
                            m.join(", ")
                        )
                    }
                    Role::Member { solver, .. } => {
                        format!("no contact solve of step {step} from the first piece ({solver})")
                    }
                };
                return Err(FiberNodeError::Protocol(format!(
                    "node {node}: {missing} within {:.0} s",
                    timeout.as_secs_f64()
                )));
            }
            if now >= resend_at {
                self.resend(bus)?;
                tracing::info!(node, step, "contact exchange waiting: sending ours again");
                resend_at = now + RESEND_AFTER;
            }
            let wait = left
                .min(resend_at.saturating_duration_since(now))
                .min(Duration::from_millis(500));
            let Some((topic, bytes)) = self.inbox.recv_raw(wait) else {
                continue;
            };
            let drops = &mut self.inbox.drops;
            match &mut self.role {
                Role::Solver {
                    others,
                    names,
                    parts,
                    part_topics,
                    solved,
                } => {
                    let mut m = match decode::<FiberFreeStep>(&bytes) {
                        Ok(m) => m,
                        Err(e) => {
                            drops.drop_one(&topic, &e.to_string());
                            continue;
                        }
                    };
                    let Some(i) = names
                        .iter()
                        .position(|(g, first)| *g == m.group && *first == m.first_fiber)
                    else {
                        drops.drop_one(&topic, "free step of no piece this one touches");
                        continue;
                    };
                    if m.step < step {
                        // a piece that lost its part of a step sent that free step again
                        if *solved == Some(m.step) {
                            bus.publish_message(&part_topics[i], &parts[i])?;
                        }
                        continue;
                    }
                    if m.step > step {
                        drops.drop_one(&topic, "free step of a later step");
                        continue;
                    }
                    if let Err(e) = m.check() {
                        drops.drop_one(&topic, &e);
                        continue;
                    }
                    if let Err(e) = others[i].read(&take_free_step(&mut m)) {
                        drops.drop_one(&topic, &format!("inconsistent: {e}"));
                    }
                }
                Role::Member { .. } => {
                    let mut m = match decode::<FiberContactSolved>(&bytes) {
                        Ok(m) => m,
                        Err(e) => {
                            drops.drop_one(&topic, &e.to_string());
                            continue;
                        }
                    };
                    if m.step < step {
                        // the first piece answered an earlier copy of our free step
                        continue;
                    }
                    if m.step > step {
                        drops.drop_one(&topic, "contact solve of a later step");
                        continue;
                    }
                    if let Err(e) = m.check() {
                        drops.drop_one(&topic, &e);
                        continue;
                    }
                    match group.apply_contact_solved(order, &take_solved(&mut m)) {
                        Ok(report) => return Ok(Some(report)),
                        Err(e) => drops.drop_one(&topic, &format!("inconsistent: {e}")),
                    }
                }
            }
        }
    }
}

/// The model's part of a free-step message, its arrays moved out (allocations kept).
fn take_free_step(m: &mut FiberFreeStep) -> FreeStep {
    use std::mem::take;
    FreeStep {
        step: m.step,
        first_fiber: m.first_fiber,
        segments_per_fiber: take(&mut m.segments_per_fiber),
        start_centre: take(&mut m.start_centre),
        start_axis: take(&mut m.start_axis),
        start_normal: take(&mut m.start_normal),
        centre: take(&mut m.centre),
        axis: take(&mut m.axis),
        normal: take(&mut m.normal),
        velocity: take(&mut m.velocity),
        angular_velocity: take(&mut m.angular_velocity),
    }
}

/// Puts a free step's arrays into its message (the header stays the message's).
fn put_free_step(m: &mut FiberFreeStep, fs: FreeStep) {
    m.segments_per_fiber = fs.segments_per_fiber;
    m.start_centre = fs.start_centre;
    m.start_axis = fs.start_axis;
    m.start_normal = fs.start_normal;
    m.centre = fs.centre;
    m.axis = fs.axis;
    m.normal = fs.normal;
    m.velocity = fs.velocity;
    m.angular_velocity = fs.angular_velocity;
}

/// The model's part of a contact-solved message, its arrays moved out.
fn take_solved(m: &mut FiberContactSolved) -> ContactSolved {
    use std::mem::take;
    ContactSolved {
        fibers: m.fibers,
        moved: take(&mut m.moved),
        moved_segments: take(&mut m.moved_segments),
        centre: take(&mut m.centre),
        axis: take(&mut m.axis),
        normal: take(&mut m.normal),
        velocity: take(&mut m.velocity),
        angular_velocity: take(&mut m.angular_velocity),
        contact_segment: take(&mut m.contact_segment),
        contact_force: take(&mut m.contact_force),
        contacts: take(&mut m.contacts),
        worst_gap: m.worst_gap,
        sweeps: m.sweeps,
        pairs: m.pairs,
        candidates: m.candidates,
        locked: take(&mut m.locked),
        frozen: take(&mut m.frozen),
    }
}

/// Puts what the solve did to a piece into its message (the header stays the message's).
fn put_solved(m: &mut FiberContactSolved, s: ContactSolved) {
    m.fibers = s.fibers;
    m.moved = s.moved;
    m.moved_segments = s.moved_segments;
    m.centre = s.centre;
    m.axis = s.axis;
    m.normal = s.normal;
    m.velocity = s.velocity;
    m.angular_velocity = s.angular_velocity;
    m.contact_segment = s.contact_segment;
    m.contact_force = s.contact_force;
    m.contacts = s.contacts;
    m.worst_gap = s.worst_gap;
    m.sweeps = s.sweeps;
    m.pairs = s.pairs;
    m.candidates = s.candidates;
    m.locked = s.locked;
    m.frozen = s.frozen;
}
