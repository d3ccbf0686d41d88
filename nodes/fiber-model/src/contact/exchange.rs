//! Contact across the shards of a group, and between the groups of a suspension: each
//! piece (a shard's slice of a group's fibres, in a process of its own) makes its free
//! step and sends it to the suspension's first piece ([`FreeStep`]), which solves contact
//! over all of them ([`crate::group::FiberGroup::resolve_contact_for`]) and sends each
//! other piece what the solve did to its fibres ([`ContactSolved`], taken by
//! [`crate::group::FiberGroup::apply_contact_solved`]). The solve runs over all pieces in
//! the (fibre, segment) order of one unsharded group, so every piece's fibres end the step
//! with the bits that group gives them, whatever the shard count (docs/contact.md,
//! "Across shards"). How the two travel is the fibre node's (its messages
//! `FiberFreeStep` and `FiberContactSolved` carry these fields).

use crate::fiber::{Fiber, FlatSegments};
use nalgebra::Vector3;

/// A piece's free step: per fibre its segment count, per segment 3 values of each array —
/// the step's start (centre, axis, normal) and after the free step.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FreeStep {
    pub step: u64,
    /// The piece's first fibre in its group.
    pub first_fiber: u32,
    pub segments_per_fiber: Vec<u32>,
    pub start_centre: Vec<f64>,
    pub start_axis: Vec<f64>,
    pub start_normal: Vec<f64>,
    pub centre: Vec<f64>,
    pub axis: Vec<f64>,
    pub normal: Vec<f64>,
    pub velocity: Vec<f64>,
    pub angular_velocity: Vec<f64>,
}

/// What the contact solve of a step did to one piece: its moved fibres' segments after
/// the solve (3 values each), its contact load, and the solve's summary.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ContactSolved {
    /// Fibres in the piece.
    pub fibers: u32,
    /// The piece's fibres the solve moved (indices within the piece, ascending).
    pub moved: Vec<u32>,
    /// Per moved fibre: its number of segments.
    pub moved_segments: Vec<u32>,
    pub centre: Vec<f64>,
    pub axis: Vec<f64>,
    pub normal: Vec<f64>,
    pub velocity: Vec<f64>,
    pub angular_velocity: Vec<f64>,
    /// Contact load: segments (within the piece, ascending), 3 force values each, pairs.
    pub contact_segment: Vec<u32>,
    pub contact_force: Vec<f64>,
    pub contacts: Vec<u32>,
    /// Smallest centre-line gap minus contact distance after the whole solve.
    pub worst_gap: f64,
    pub sweeps: u32,
    /// Pairs that touched in the whole solve.
    pub pairs: u32,
    pub candidates: u32,
    /// The piece's fibres locked into one body, and kept where they started.
    pub locked: Vec<u32>,
    pub frozen: Vec<u32>,
}

/// Arrays of 3 finite values per segment of fibres of `counts` segments each.
fn per_segment(counts: &[u32], arrays: &[(&str, &[f64])]) -> Result<(), ExchangeError> {
    let want = 3 * counts.iter().map(|&n| n as usize).sum::<usize>();
    for (name, v) in arrays {
        if v.len() != want {
            return Err(ExchangeError::Insane(format!(
                "{name} holds {} values, the segments ask for {want}",
                v.len()
            )));
        }
        if v.iter().any(|x| !x.is_finite()) {
            return Err(ExchangeError::Insane(format!("{name} is not finite")));
        }
    }
    Ok(())
}

/// `xs` ascending, each below `n`.
fn ascending_below(name: &str, xs: &[u32], n: usize) -> Result<(), ExchangeError> {
    let ordered = xs.windows(2).all(|w| w[0] < w[1]);
    if !ordered || xs.last().is_some_and(|&l| l as usize >= n) {
        return Err(ExchangeError::Insane(format!(
            "{name} is not ascending below {n}"
        )));
    }
    Ok(())
}

impl FreeStep {
    /// Every array as long as the segments ask, every value finite.
    pub fn check(&self) -> Result<(), ExchangeError> {
        per_segment(
            &self.segments_per_fiber,
            &[
                ("start_centre", &self.start_centre),
                ("start_axis", &self.start_axis),
                ("start_normal", &self.start_normal),
                ("centre", &self.centre),
                ("axis", &self.axis),
                ("normal", &self.normal),
                ("velocity", &self.velocity),
                ("angular_velocity", &self.angular_velocity),
            ],
        )
    }
}

impl ContactSolved {
    /// The lists ascending within the piece, every array as long as the moved fibres and
    /// the loaded segments ask, every value finite (what the piece itself checks:
    /// the fibres' and segments' counts).
    pub fn check(&self) -> Result<(), ExchangeError> {
        let n = self.fibers as usize;
        if self.moved_segments.len() != self.moved.len() {
            return Err(ExchangeError::Insane(format!(
                "{} moved fibres, {} segment counts",
                self.moved.len(),
                self.moved_segments.len()
            )));
        }
        ascending_below("moved", &self.moved, n)?;
        ascending_below("locked", &self.locked, n)?;
        ascending_below("frozen", &self.frozen, n)?;
        per_segment(
            &self.moved_segments,
            &[
                ("centre", &self.centre),
                ("axis", &self.axis),
                ("normal", &self.normal),
                ("velocity", &self.velocity),
                ("angular_velocity", &self.angular_velocity),
            ],
        )?;
        let nc = self.contact_segment.len();
        if self.contacts.len() != nc || self.contact_force.len() != 3 * nc {
            return Err(ExchangeError::Insane(format!(
                "{nc} loaded segments, {} counts and {} force values",
                self.contacts.len(),
                self.contact_force.len()
            )));
        }
        if self.contact_force.iter().any(|x| !x.is_finite()) {
            return Err(ExchangeError::Insane("contact_force is not finite".into()));
        }
        if self.contact_segment.windows(2).any(|w| w[0] >= w[1]) {
            return Err(ExchangeError::Insane(
                "contact_segment is not ascending".into(),
            ));
        }
        Ok(())
    }
}

/// Another shard's slice of the group after its free step, as this shard's contact solve
/// reads it. Its fibres' properties are fixed (every shard builds the whole group at
/// start); their segments are overwritten from each step's message.
#[derive(Debug, Clone)]
pub struct OtherPiece {
    /// Index of its first fibre in its group (what its messages name).
    pub first_fiber: usize,
    /// Index of its first fibre in the order of the solve: the group's, or for a
    /// suspension of several groups, the groups' in the suspension's order, one after
    /// the other.
    pub order: usize,
    /// Its fibres at the start of the step: centres, axes and normals of the start,
    /// everything else as after the free step (what the solve reads of a start; as for a
    /// shard's own).
    pub before: Vec<Fiber>,
    /// Its fibres after the free step.
    pub after: Vec<Fiber>,
    /// Each fibre's first segment in the piece's segment order (plus the total).
    pub offsets: Vec<usize>,
    /// The step its segments are of (None: not yet received).
    pub step: Option<u64>,
}

/// Why a free step does not fit the piece it names.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ExchangeError {
    #[error("free step of fibres {got}.., this piece holds {want}..")]
    Piece { got: u32, want: usize },
    #[error("fibre {fiber} has {got} segments in the free step, {want} here")]
    Segments { fiber: usize, got: u32, want: usize },
    #[error("{0}")]
    Insane(String),
}

impl OtherPiece {
    /// The piece of fibres `first_fiber ..` of its group, at `order` in the solve, with
    /// these fibres' properties (their segments are replaced by [`Self::read`]).
    pub fn new(first_fiber: usize, order: usize, fibers: Vec<Fiber>) -> Self {
        let offsets = std::iter::once(0)
            .chain(fibers.iter().scan(0, |o, f| {
                *o += f.len();
                Some(*o)
            }))
            .collect();
        Self {
            first_fiber,
            order,
            offsets,
            before: fibers.clone(),
            after: fibers,
            step: None,
        }
    }

    /// Takes the segments of a free step of this piece (checked: its fibres, their
    /// segment counts, every array's length and finiteness). The hydrodynamic force is
    /// left zero: the solve does not read it, and only the owning shard keeps the fibre.
    pub fn read(&mut self, m: &FreeStep) -> Result<(), ExchangeError> {
        m.check()?;
        if m.first_fiber as usize != self.first_fiber
            || m.segments_per_fiber.len() != self.after.len()
        {
            return Err(ExchangeError::Piece {
                got: m.first_fiber,
                want: self.first_fiber,
            });
        }
        for (k, (&n, f)) in m.segments_per_fiber.iter().zip(&self.after).enumerate() {
            if n as usize != f.len() {
                return Err(ExchangeError::Segments {
                    fiber: self.first_fiber + k,
                    got: n,
                    want: f.len(),
                });
            }
        }
        let after_step = FlatSegments {
            centre: &m.centre,
            axis: &m.axis,
            velocity: &m.velocity,
            angular_velocity: &m.angular_velocity,
            normal: &m.normal,
        };
        // the start's positions, axes and normals, everything else as after the step
        let start = FlatSegments {
            centre: &m.start_centre,
            axis: &m.start_axis,
            normal: &m.start_normal,
            ..after_step
        };
        let mut j = 0;
        for (before, after) in self.before.iter_mut().zip(self.after.iter_mut()) {
            for (b, a) in before.segments.iter_mut().zip(after.segments.iter_mut()) {
                *a = after_step.get(j, Vector3::zeros());
                *b = start.get(j, Vector3::zeros());
                j += 1;
            }
        }
        self.step = Some(m.step);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::contact::tests::{
        com, crowded_box, fiber, hairpin, min_distance, params, uniform, D, DT,
    };
    use crate::contact::{ContactParams, SegmentLoad};
    use crate::group::FiberGroup;
    use crate::step::{FluidSample, ModelParams};
    use nalgebra::Matrix3;

    /// A group cut into shards at `cuts` (first fibres, then the total), stepping as shard
    /// processes do: every shard steps free; the first reads the others' free steps (sent
    /// through the codec), solves for all and sends each other shard its part, which that
    /// shard takes (again through the codec).
    struct Shards {
        groups: Vec<(usize, FiberGroup)>,
        /// The first shard's view of the others.
        others: Vec<OtherPiece>,
    }

    impl Shards {
        fn cut(whole: &FiberGroup, cuts: &[usize]) -> Self {
            let groups: Vec<(usize, FiberGroup)> = cuts
                .windows(2)
                .map(|w| (w[0], whole.slice(w[0], w[1] - w[0])))
                .collect();
            let others = groups[1..]
                .iter()
                .map(|(first, g)| OtherPiece::new(*first, *first, g.fibers()))
                .collect();
            Self { groups, others }
        }

        fn step(&mut self, fluid: &dyn Fn(usize, &Vector3<f64>) -> FluidSample, step: u64) {
            let mut sent = Vec::new();
            for (first, g) in self.groups.iter_mut() {
                let samples: Vec<FluidSample> = (0..g.len())
                    .flat_map(|k| {
                        g.segments(k)
                            .map(|s| fluid(*first + k, &s.r))
                            .collect::<Vec<_>>()
                    })
                    .collect();
                g.step_free(&samples, DT).unwrap();
                let mut m = FreeStep {
                    step,
                    first_fiber: *first as u32,
                    ..Default::default()
                };
                g.fill_free_step(&mut m);
                sent.push(m);
            }
            for (o, m) in self.others.iter_mut().zip(&sent[1..]) {
                o.read(m).unwrap();
            }
            let mut solved: Vec<ContactSolved> = self.groups[1..]
                .iter()
                .map(|_| ContactSolved::default())
                .collect();
            let (first, solver) = &mut self.groups[0];
            let pairs = solver
                .resolve_contact_for(*first, &self.others, DT, &mut solved)
                .pairs;
            for ((first, g), m) in self.groups[1..].iter_mut().zip(&solved) {
                let report = g.apply_contact_solved(*first, m).unwrap();
                assert_eq!(report.pairs, pairs, "every piece reports the solve's pairs");
            }
        }

        fn fibers(&self) -> Vec<Fiber> {
            self.groups.iter().flat_map(|(_, g)| g.fibers()).collect()
        }
    }

    /// Steps the whole group and the same fibres in shards side by side; every step the
    /// shards' fibres must be the whole group's, bit for bit. Returns the contacts of
    /// the whole group's steps whose fibres lie in different shards (and the steps that
    /// locked an island of fibres of different shards), the closest two fibres came,
    /// and the contacts of fibres with themselves.
    fn whole_against_shards(
        fibers: Vec<Fiber>,
        p: ModelParams,
        c: ContactParams,
        cuts: &[usize],
        fluid: &dyn Fn(usize, &Vector3<f64>) -> FluidSample,
        steps: u64,
    ) -> (usize, f64, usize) {
        let mut whole = FiberGroup::new(p, fibers);
        whole.set_contact(Some(c));
        let mut shards = Shards::cut(&whole, cuts);
        let shard_of = |k: usize| cuts.iter().rposition(|&f| f <= k);
        let (mut across, mut closest, mut own) = (0, f64::INFINITY, 0);
        for step in 0..steps {
            let samples: Vec<FluidSample> = (0..whole.len())
                .flat_map(|k| {
                    whole
                        .segments(k)
                        .map(|s| fluid(k, &s.r))
                        .collect::<Vec<_>>()
                })
                .collect();
            let whole_did = whole.step(&samples, DT).unwrap().contact;
            shards.step(fluid, step);
            assert!(shards.fibers() == whole.fibers(), "step {step}: other bits");
            for (first, g) in &shards.groups {
                let load = SegmentLoad::of(
                    &whole_did.contacts,
                    *first..*first + g.len(),
                    &g.offsets_for_tests(),
                    DT,
                );
                assert_eq!(g.contact_load(), &load, "step {step}: another contact load");
            }
            across += whole_did
                .contacts
                .iter()
                .filter(|x| shard_of(x.a.0) != shard_of(x.b.0))
                .count();
            // a pair the sweeps could not part is moved with its island as one body and
            // is not among the contacts; an island of two shards' fibres met too
            let locked = &whole_did.locked;
            if locked
                .iter()
                .any(|&k| shard_of(k) != locked.first().and_then(|&f| shard_of(f)))
            {
                across += 1;
            }
            own += whole_did.contacts.iter().filter(|x| x.a.0 == x.b.0).count();
            closest = closest.min(min_distance(&whole.fibers(), &c.period));
        }
        (across, closest, own)
    }

    /// 60 crowded fibres in a periodic box in shear, μ = 0.3, cut into three shards of
    /// unequal size: over 10 steps every shard's fibres have the unsharded group's bits,
    /// and fibres of different shards touch.
    #[test]
    fn shards_exchanging_free_steps_step_as_the_whole_group() {
        let side = 30.0;
        let fibers: Vec<Fiber> = crowded_box(side, 3)
            .iter()
            .map(|pl| fiber(pl.centre, pl.axis))
            .collect();
        let n = fibers.len();
        let c = ContactParams {
            friction: 0.3,
            period: [Some(side), None, Some(side)],
            ..Default::default()
        };
        let gamma = 2.0;
        let shear = |_: usize, r: &Vector3<f64>| FluidSample {
            vel: Vector3::new(gamma * (r.y - 0.5 * side), 0.0, 0.0),
            grad: Matrix3::new(0.0, gamma, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
        };
        let p = params(Vector3::zeros());
        let (across, _, _) = whole_against_shards(fibers, p, c, &[0, 17, 40, n], &shear, 10);
        assert!(
            across > 0,
            "no contact across shards: the test checks nothing"
        );
    }

    /// Three hairpins side by side (their arms driven into each other, as in
    /// `contact::tests::a_fiber_folded_onto_itself_does_not_pass_through_itself`, and the
    /// hairpins into each other), each in a shard of its own: every shard's fibres have the
    /// unsharded group's bits while the fibres touch themselves and each other.
    #[test]
    fn fibers_touching_themselves_in_shards_keep_the_bits() {
        let fibers: Vec<Fiber> = (0..3)
            .map(|k| {
                let mut f = hairpin();
                let shift = Vector3::new(0.0, 0.0, 0.3 * k as f64);
                f.segments.iter_mut().for_each(|s| s.r += shift);
                f
            })
            .collect();
        let c = ContactParams {
            friction: 0.5,
            ..Default::default()
        };
        let u = 2.0;
        let fluid = |k: usize, r: &Vector3<f64>| {
            let v = if r.x < -1.0 { -u * r.y.signum() } else { 0.0 };
            uniform(Vector3::new(0.0, v, if k == 1 { 0.5 } else { 0.0 }))
        };
        let p = params(Vector3::zeros());
        let (across, _, own) = whole_against_shards(fibers, p, c, &[0, 1, 2, 3], &fluid, 40);
        assert!(own > 10, "the fibres touched themselves {own} times");
        assert!(across > 0, "no contact across shards: the test checks less");
    }

    /// Two groups of unlike fibres in one suspension (30 case-1 fibres, 30 of shorter,
    /// thinner and denser segments), each in two pieces: every piece's fibres have the bits
    /// one group of all 60 gives them, and fibres of the two groups touch.
    #[test]
    fn two_groups_of_unlike_fibers_touch_as_one_group() {
        let side = 30.0;
        let placed = crowded_box(side, 5);
        let n = placed.len();
        let fibers: Vec<Fiber> = placed
            .iter()
            .enumerate()
            .map(|(k, pl)| {
                if k < n / 2 {
                    fiber(pl.centre, pl.axis)
                } else {
                    Fiber::straight(pl.centre, pl.axis.normalize(), &[2.5; 7], &[0.2; 7], 2300.0)
                        .unwrap()
                }
            })
            .collect();
        let c = ContactParams {
            friction: 0.5,
            period: [Some(side), None, Some(side)],
            ..Default::default()
        };
        let gamma = 3.0;
        let shear = |_: usize, r: &Vector3<f64>| FluidSample {
            vel: Vector3::new(gamma * (r.y - 0.5 * side), 0.0, 0.0),
            grad: Matrix3::new(0.0, gamma, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
        };
        let p = params(Vector3::zeros());
        let cuts = [0, 11, n / 2, n / 2 + 16, n];
        let (across, _, _) = whole_against_shards(fibers, p, c, &cuts, &shear, 12);
        assert!(
            across > 0,
            "no contact across pieces: the test checks nothing"
        );
    }

    /// The two encounters of the unsharded tests with each fibre in a shard of its own:
    /// driven head-on at 3.4 d per step, and carried across each other in shear (μ = 0
    /// and 0.5). Centre-lines never closer than 0.99 d, and the same bits as one group.
    /// (With μ = 0.5 the sweeps cannot part this pair where they meet, and the lock
    /// moves the two as one body for that step.)
    #[test]
    fn fibers_on_two_shards_never_pass_through() {
        let p = params(Vector3::zeros());
        let u = 2.0;
        let mut a = fiber(Vector3::new(0.0, 3.0, 0.0), Vector3::z());
        let mut b = fiber(Vector3::new(0.0, -3.0, 0.0), Vector3::x());
        a.segments
            .iter_mut()
            .for_each(|s| s.v = Vector3::new(0.0, -u, 0.0));
        b.segments
            .iter_mut()
            .for_each(|s| s.v = Vector3::new(0.0, u, 0.0));
        let head_on = |k: usize, _: &Vector3<f64>| {
            uniform(Vector3::new(0.0, if k == 0 { -u } else { u }, 0.0))
        };
        let mut whole = FiberGroup::new(p, vec![a.clone(), b.clone()]);
        let (across, closest, _) = whole_against_shards(
            vec![a, b],
            p,
            ContactParams::default(),
            &[0, 1, 2],
            &head_on,
            40,
        );
        assert!(across > 10, "head-on: touched in only {across} steps");
        assert!(closest >= 0.99 * D, "head-on: centre-lines {closest} apart");
        // the same fibres stepped without contact pass each other
        for _ in 0..40 {
            let samples: Vec<FluidSample> = (0..2)
                .flat_map(|k| {
                    whole
                        .segments(k)
                        .map(|s| head_on(k, &s.r))
                        .collect::<Vec<_>>()
                })
                .collect();
            whole.step(&samples, DT).unwrap();
        }
        assert!(
            com(&whole.fiber(0)).y < com(&whole.fiber(1)).y,
            "without contact they pass"
        );

        let gamma = 10.0;
        let shear = |_: usize, r: &Vector3<f64>| FluidSample {
            vel: Vector3::new(gamma * r.y, 0.0, 0.0),
            grad: Matrix3::new(0.0, gamma, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
        };
        for mu in [0.0, 0.5] {
            let mut fs = vec![
                fiber(Vector3::new(-12.0, 0.05, 0.0), Vector3::z()),
                fiber(Vector3::new(12.0, -0.05, 0.0), Vector3::new(0.0, 0.1, 1.0)),
            ];
            for f in fs.iter_mut() {
                for s in f.segments.iter_mut() {
                    s.v = shear(0, &s.r).vel;
                }
            }
            let c = ContactParams {
                friction: mu,
                ..Default::default()
            };
            let (across, closest, _) = whole_against_shards(fs, p, c, &[0, 1, 2], &shear, 160);
            assert!(across >= 1, "μ = {mu}: they never touched");
            assert!(
                closest >= 0.99 * D,
                "μ = {mu}: centre-lines {closest} apart"
            );
        }
    }

    /// A free step that does not fit the piece (other fibres, other segment counts, a
    /// non-finite value) is refused, and the piece keeps what it held.
    #[test]
    fn a_free_step_that_does_not_fit_is_refused() {
        let g = FiberGroup::new(
            params(Vector3::zeros()),
            vec![
                fiber(Vector3::zeros(), Vector3::x()),
                fiber(Vector3::y(), Vector3::z()),
            ],
        );
        let mut piece = OtherPiece::new(2, 2, g.fibers());
        let mut m = FreeStep {
            step: 0,
            first_fiber: 2,
            ..Default::default()
        };
        let mut g2 = g.clone();
        g2.set_contact(Some(ContactParams::default()));
        let still: Vec<FluidSample> = (0..14).map(|_| uniform(Vector3::zeros())).collect();
        g2.step_free(&still, DT).unwrap();
        g2.fill_free_step(&mut m);
        assert_eq!(piece.read(&m), Ok(()));
        assert_eq!(piece.step, Some(0));
        let held = piece.after.clone();
        let mut other = m.clone();
        other.first_fiber = 0;
        assert!(matches!(
            piece.read(&other),
            Err(ExchangeError::Piece { .. })
        ));
        let mut short = m.clone();
        short.segments_per_fiber[1] = 6;
        assert!(piece.read(&short).is_err());
        let mut nan = m.clone();
        nan.velocity[5] = f64::NAN;
        assert!(matches!(piece.read(&nan), Err(ExchangeError::Insane(_))));
        assert_eq!(piece.after, held);
    }

    /// The first piece's part for another piece that does not fit it (another fibre
    /// count, a moved fibre's segment count, a load on a segment it does not hold, a
    /// non-finite value) is refused, and the piece keeps what it held; the part that fits
    /// is taken.
    #[test]
    fn a_solved_part_that_does_not_fit_is_refused() {
        let fibers = vec![
            fiber(Vector3::zeros(), Vector3::x()),
            fiber(Vector3::new(0.0, 0.5 * D, 0.0), Vector3::z()),
        ];
        let whole = {
            let mut g = FiberGroup::new(params(Vector3::zeros()), fibers);
            g.set_contact(Some(ContactParams::default()));
            g
        };
        let mut shards = Shards::cut(&whole, &[0, 1, 2]);
        let still = |_: usize, _: &Vector3<f64>| uniform(Vector3::zeros());
        // step as the processes do, keeping the part the first piece sent the second
        let mut first = shards.groups[0].1.clone();
        let mut second = shards.groups[1].1.clone();
        let samples: Vec<FluidSample> = (0..7).map(|_| still(0, &Vector3::zeros())).collect();
        first.step_free(&samples, DT).unwrap();
        second.step_free(&samples, DT).unwrap();
        let mut free = FreeStep::default();
        second.fill_free_step(&mut free);
        free.first_fiber = 1;
        shards.others[0].read(&free).unwrap();
        let mut part = vec![ContactSolved::default()];
        first.resolve_contact_for(0, &shards.others, DT, &mut part);
        let m = &part[0];
        assert_eq!(
            m.moved,
            vec![0],
            "the overlapping pair moved the second fibre"
        );
        let held = second.fibers();
        let refused = |bad: &ContactSolved, second: &mut FiberGroup| {
            assert!(second.apply_contact_solved(1, bad).is_err());
            assert_eq!(second.fibers(), held, "a refused part changed the piece");
        };
        let mut more = m.clone();
        more.fibers = 2;
        refused(&more, &mut second);
        let mut short = m.clone();
        short.moved_segments[0] = 6;
        refused(&short, &mut second);
        let mut far = m.clone();
        far.contact_segment = vec![7];
        far.contacts = vec![1];
        far.contact_force = vec![0.0; 3];
        refused(&far, &mut second);
        let mut nan = m.clone();
        nan.centre[4] = f64::NAN;
        refused(&nan, &mut second);
        second.apply_contact_solved(1, m).unwrap();
        assert_ne!(second.fibers(), held, "the part that fits moved the fibre");
    }
}
