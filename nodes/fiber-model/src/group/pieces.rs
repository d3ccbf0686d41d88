//! A group cut into pieces (shards, or the groups of a suspension) that solve contact
//! together ([`crate::contact::exchange`]): what a piece's free step gives the solve, the
//! solve over every piece on the first, and what another piece takes back.

use super::{FiberGroup, Kept, StepReport};
use crate::contact::exchange::{ContactSolved, FreeStep, OtherPiece};
use crate::contact::{self, Outcome as ContactOutcome};
use crate::fiber::{Fiber, SegmentProps};
use nalgebra::Vector3;

impl FiberGroup {
    /// After [`Self::step_free`]: what the contact solve reads of it
    /// ([`FreeStep`]; `msg`'s step and first fibre are the caller's, its
    /// arrays are refilled, allocations kept).
    pub fn fill_free_step(&self, msg: &mut FreeStep) {
        msg.segments_per_fiber.clear();
        msg.segments_per_fiber
            .extend((0..self.len()).map(|k| self.fiber_len(k) as u32));
        for a in [
            &mut msg.start_centre,
            &mut msg.start_axis,
            &mut msg.start_normal,
            &mut msg.centre,
            &mut msg.axis,
            &mut msg.normal,
            &mut msg.velocity,
            &mut msg.angular_velocity,
        ] {
            a.clear();
        }
        for s in &self.start {
            msg.start_centre.extend_from_slice(s[0].as_slice());
            msg.start_axis.extend_from_slice(s[1].as_slice());
            msg.start_normal.extend_from_slice(s[2].as_slice());
        }
        for k in 0..self.len() {
            let (segs, l) = self.lanes_of(k);
            for s in segs {
                msg.centre.extend_from_slice(&s.r.lane(l));
                msg.axis.extend_from_slice(&s.z.lane(l));
                msg.normal.extend_from_slice(&s.n.lane(l));
                msg.velocity.extend_from_slice(&s.v.lane(l));
                msg.angular_velocity.extend_from_slice(&s.w.lane(l));
            }
        }
    }

    /// After [`Self::step_free`], on a suspension's first piece: contact over all the
    /// fibres that touch, this piece's (its first fibre at `order` in the solve: its index
    /// in the group, or in the suspension's groups one after the other) with the other
    /// pieces' free steps (`others`, each read for this step). Keeps the corrections of
    /// this piece's fibres and writes what the solve did to each other piece into
    /// `solved[p]` (arrays refilled), for
    /// [`Self::apply_contact_solved`] there. The pairs are solved in that order, so every
    /// piece's fibres get the bits [`Self::step`] of one unsharded group of all of them
    /// gives them.
    pub fn resolve_contact_for(
        &mut self,
        order: usize,
        others: &[OtherPiece],
        dt: f64,
        solved: &mut [ContactSolved],
    ) -> StepReport {
        let Some(mut c) = self.contact else {
            return StepReport::default();
        };
        c.wall_half_height = self.params.wall_half_height;
        let mut search = std::mem::take(&mut self.search);
        let view = Joined::new(self, order, others);
        let (own, starts) = (view.own_start, view.starts.clone());
        let (mut outcome, mut fibers) = contact::resolve_segments(&view, &mut search, &[], &c, dt);
        self.search = search;
        let hh = self.params.wall_half_height;
        for ((o, &start), m) in others.iter().zip(&starts).zip(solved.iter_mut()) {
            fill_solved(m, &outcome, &mut fibers, start, o, hh, dt);
        }
        let mine = own..own + self.len();
        for &k in outcome.moved.iter().filter(|k| mine.contains(k)) {
            if let Some(hh) = hh {
                crate::step::wall_contact(&mut fibers[k], hh);
            }
            for (i, s) in fibers[k].segments.iter().enumerate() {
                self.set_segment(k - own, i, *s);
            }
        }
        // what the log reports is this piece's: its fibres moved and locked
        outcome.moved.retain(|k| mine.contains(k));
        outcome.locked.retain(|k| mine.contains(k));
        outcome.frozen.retain(|k| mine.contains(k));
        self.load = contact::SegmentLoad::of(&outcome.contacts, mine, &self.offsets, dt);
        StepReport {
            pairs: outcome.contacts.len(),
            contact: outcome,
        }
    }

    /// After [`Self::step_free`], on a piece other than its suspension's first: takes what
    /// that piece's solve ([`Self::resolve_contact_for`]) did to this one (`order`: this
    /// piece's first fibre in the solve). Checked against the piece first (its fibre
    /// count, the moved fibres' segment counts, the loaded segments, every value finite);
    /// on an error the piece is left as it was. Each moved segment keeps its own
    /// hydrodynamic force (the solve neither reads nor changes it).
    pub fn apply_contact_solved(
        &mut self,
        order: usize,
        m: &ContactSolved,
    ) -> Result<StepReport, contact::exchange::ExchangeError> {
        use contact::exchange::ExchangeError;
        m.check()?;
        if m.fibers as usize != self.len() {
            return Err(ExchangeError::Insane(format!(
                "the solve's part names {} fibres, this piece holds {}",
                m.fibers,
                self.len()
            )));
        }
        for (&k, &n) in m.moved.iter().zip(&m.moved_segments) {
            if n as usize != self.fiber_len(k as usize) {
                return Err(ExchangeError::Segments {
                    fiber: k as usize,
                    got: n,
                    want: self.fiber_len(k as usize),
                });
            }
        }
        if let Some(&last) = m.contact_segment.last() {
            if last as usize >= self.segment_count() {
                return Err(ExchangeError::Insane(format!(
                    "contact load on segment {last} of {}",
                    self.segment_count()
                )));
            }
        }
        let flat = crate::fiber::FlatSegments {
            centre: &m.centre,
            axis: &m.axis,
            velocity: &m.velocity,
            angular_velocity: &m.angular_velocity,
            normal: &m.normal,
        };
        let mut j = 0;
        for &k in &m.moved {
            let k = k as usize;
            for i in 0..self.fiber_len(k) {
                let f = self.segments(k).nth(i).map_or(Vector3::zeros(), |s| s.f);
                self.set_segment(k, i, flat.get(j, f));
                j += 1;
            }
        }
        self.load = contact::SegmentLoad {
            segment: m.contact_segment.clone(),
            force: m.contact_force.clone(),
            count: m.contacts.clone(),
        };
        let at = |ks: &[u32]| -> Vec<usize> { ks.iter().map(|&k| order + k as usize).collect() };
        Ok(StepReport {
            pairs: m.pairs as usize,
            contact: ContactOutcome {
                contacts: Vec::new(),
                candidates: m.candidates as usize,
                sweeps: m.sweeps,
                worst_gap: m.worst_gap,
                moved: at(&m.moved),
                locked: at(&m.locked),
                frozen: at(&m.frozen),
            },
        })
    }
}

/// A shard's own fibres (kept as [`Kept`]) between the other shards' ([`OtherPiece`]s), in
/// the whole group's order of first fibres: the group the contact solve of
/// [`FiberGroup::resolve_contact_for`] reads.
struct Joined<'a> {
    own: Kept<'a>,
    others: &'a [OtherPiece],
    /// Index of this shard's first fibre among the joined fibres.
    own_start: usize,
    /// Index of each other piece's first fibre among the joined fibres.
    starts: Vec<usize>,
    offsets: Vec<usize>,
    /// Per joined fibre: its piece (`OWN`, or an index into `others`) and its index there.
    at: Vec<(usize, usize)>,
}

const OWN: usize = usize::MAX;

impl<'a> Joined<'a> {
    fn new(group: &'a FiberGroup, order: usize, others: &'a [OtherPiece]) -> Self {
        let mut pieces: Vec<(usize, usize, usize)> = others
            .iter()
            .enumerate()
            .map(|(p, o)| (o.order, p, o.after.len()))
            .collect();
        pieces.push((order, OWN, group.len()));
        pieces.sort_unstable();
        let mut at = Vec::new();
        let mut offsets = vec![0];
        let mut own_start = 0;
        let mut starts = vec![0; others.len()];
        for (_, p, n) in pieces {
            if p == OWN {
                own_start = at.len();
            } else {
                starts[p] = at.len();
            }
            for l in 0..n {
                at.push((p, l));
                let len = if p == OWN {
                    group.fiber_len(l)
                } else {
                    others[p].after[l].len()
                };
                offsets.push(offsets.last().copied().unwrap_or(0) + len);
            }
        }
        Self {
            own: Kept { group },
            others,
            own_start,
            starts,
            offsets,
            at,
        }
    }
}

impl contact::Segments for Joined<'_> {
    fn offsets(&self) -> &[usize] {
        &self.offsets
    }
    fn props(&self, k: usize, i: usize) -> &SegmentProps {
        match self.at[k] {
            (OWN, l) => self.own.props(l, i),
            (p, l) => &self.others[p].after[l].props[i],
        }
    }
    fn start(&self, k: usize, i: usize) -> (Vector3<f64>, Vector3<f64>) {
        match self.at[k] {
            (OWN, l) => self.own.start(l, i),
            (p, l) => {
                let s = &self.others[p].before[l].segments[i];
                (s.r, s.z)
            }
        }
    }
    fn end(&self, k: usize, i: usize) -> (Vector3<f64>, Vector3<f64>) {
        match self.at[k] {
            (OWN, l) => self.own.end(l, i),
            (p, l) => {
                let s = &self.others[p].after[l].segments[i];
                (s.r, s.z)
            }
        }
    }
    fn start_fiber(&self, k: usize) -> Fiber {
        match self.at[k] {
            (OWN, l) => self.own.start_fiber(l),
            (p, l) => self.others[p].before[l].clone(),
        }
    }
    fn end_fiber(&self, k: usize) -> Fiber {
        match self.at[k] {
            (OWN, l) => self.own.end_fiber(l),
            (p, l) => self.others[p].after[l].clone(),
        }
    }
}

/// What the solve did to the piece `o` whose first fibre is `start` among the solve's
/// fibres, into `m` ([`FiberGroup::resolve_contact_for`]): its moved fibres (brought
/// within the walls, as the piece itself would), its contact load, its locked and frozen
/// fibres, and the solve's summary.
fn fill_solved(
    m: &mut ContactSolved,
    outcome: &ContactOutcome,
    fibers: &mut [Fiber],
    start: usize,
    o: &OtherPiece,
    wall_half_height: Option<f64>,
    dt: f64,
) {
    let piece = start..start + o.after.len();
    let local = |ks: &[usize]| -> Vec<u32> {
        ks.iter()
            .filter(|k| piece.contains(k))
            .map(|&k| (k - start) as u32)
            .collect()
    };
    m.fibers = o.after.len() as u32;
    m.moved = local(&outcome.moved);
    m.moved_segments.clear();
    for a in [
        &mut m.centre,
        &mut m.axis,
        &mut m.normal,
        &mut m.velocity,
        &mut m.angular_velocity,
    ] {
        a.clear();
    }
    for &k in &m.moved {
        let f = &mut fibers[start + k as usize];
        if let Some(hh) = wall_half_height {
            crate::step::wall_contact(f, hh);
        }
        m.moved_segments.push(f.len() as u32);
        for s in &f.segments {
            m.centre.extend_from_slice(s.r.as_slice());
            m.axis.extend_from_slice(s.z.as_slice());
            m.normal.extend_from_slice(s.n.as_slice());
            m.velocity.extend_from_slice(s.v.as_slice());
            m.angular_velocity.extend_from_slice(s.w.as_slice());
        }
    }
    let load = contact::SegmentLoad::of(&outcome.contacts, piece.clone(), &o.offsets, dt);
    m.contact_segment = load.segment;
    m.contact_force = load.force;
    m.contacts = load.count;
    m.worst_gap = outcome.worst_gap;
    m.sweeps = outcome.sweeps;
    m.pairs = outcome.contacts.len() as u32;
    m.candidates = outcome.candidates as u32;
    m.locked = local(&outcome.locked);
    m.frozen = local(&outcome.frozen);
}
