//! A group of fibres stepped together (one fibre node owns one or more groups): each
//! fibre's free step is independent of the others', so they step in parallel, and contact
//! (when on) corrects the pairs that touch after it. A group cut into pieces that solve
//! contact together is [`pieces`].
//!
//! Layout: the group keeps its state as lanes ([`crate::batch`]). Fibres 4b … 4b+3 form
//! block b; segment i of the block is one [`LaneSeg`] holding that segment of each of the
//! four fibres (structure of arrays across fibres, contiguous block after block), so the
//! SIMD step reads and writes it in place with no gather. The per-segment constants of
//! the step ([`LaneConsts`]) are computed once, at construction; a group whose segments
//! are all alike (every paper case) keeps one set for all. Checkpoints and messages see
//! the fibre-major order of [`Segment`]s, never this layout.
//!
//! Size (≈ 740 lines): the lane layout and the step that reads it in place (blocks, the
//! split over the pool, the per-block context) are one piece of work and stay together.

use crate::batch::{self, LaneConsts, LaneSeg};
use crate::contact::{self, ContactParams, Outcome as ContactOutcome};
use crate::error::FiberError;
use crate::fiber::{Fiber, Segment, SegmentProps};
use crate::lanes::LANES;
use crate::metrics::{metrics_from, FiberMetrics};
use crate::step::{step, Fluid, FluidSample, ModelParams};
use nalgebra::Vector3;
use rayon::prelude::*;

mod pieces;

/// Below this many segments a group steps (and measures its metrics) on the calling
/// thread: ≈ 0.5 ms of work, where waking the pool's threads and their idle spinning
/// would cost the shared cores more than splitting saves (a paper case is 350 segments).
/// Either way every fibre gets the same bits.
pub const PARALLEL_MIN_SEGMENTS: usize = 4096;

/// Where a block of up to [`LANES`] fibres sits in the lane storage.
#[derive(Debug, Clone, Copy)]
struct Block {
    /// Index of its first [`LaneSeg`].
    start: usize,
    /// Segments of its longest fibre (its share of the storage).
    len: usize,
    /// Its index (its first fibre is `LANES * index`).
    index: usize,
    /// Fibres in it (4 except possibly the last block).
    used: usize,
    /// All its fibres have `len` segments and the model allows the lane step.
    lanes: bool,
}

/// The step's constants: one set for a group of identical segments, else one per
/// [`LaneSeg`] (stride 1).
#[derive(Debug, Clone)]
#[allow(clippy::large_enum_variant)] // one per group
enum Consts {
    Uniform(LaneConsts),
    PerSegment(Vec<LaneConsts>),
}

/// Fibres sharing model parameters.
#[derive(Debug, Clone)]
pub struct FiberGroup {
    params: ModelParams,
    /// Properties of every segment, fibre-major.
    props: Vec<SegmentProps>,
    /// Material density of each fibre.
    density: Vec<f64>,
    /// Offsets of each fibre's first segment in the flat segment order (plus the total).
    offsets: Vec<usize>,
    blocks: Vec<Block>,
    state: Vec<LaneSeg>,
    consts: Consts,
    /// The calling thread's working memory of [`Self::step`], kept between steps: a group
    /// below [`PARALLEL_MIN_SEGMENTS`] allocates nothing in a step after its first (test
    /// `tests/no_allocation.rs`).
    work: Work,
    /// Fibre–fibre contact within the group ([`crate::contact`]); None: fibres pass
    /// through each other (the paper's independent fibres).
    contact: Option<ContactParams>,
    /// The contact load on this group's segments of the step its state is at (or the one a
    /// checkpoint restored): part of the state its message carries.
    load: contact::SegmentLoad,
    /// With contact on: every segment's centre, axis and normal at the start of the step,
    /// fibre-major (kept between steps for its allocation).
    start: Vec<[Vector3<f64>; 3]>,
    /// With contact on: the contact search's cell list, kept for its memory.
    search: contact::Search,
}

/// What a step's contact did ([`FiberGroup::step`], and on the pieces of a sharded
/// suspension [`FiberGroup::resolve_contact_for`] and [`FiberGroup::apply_contact_solved`]);
/// empty when contact is off.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StepReport {
    /// What the solve did to this group's (or piece's) fibres: its pairs (on the piece that
    /// solved), moved, locked and kept fibres, sweeps and worst gap.
    pub contact: ContactOutcome,
    /// Pairs that touched in the whole solve (also on a piece that took its part from
    /// another piece's solve, whose [`ContactOutcome::contacts`] are then not here).
    pub pairs: usize,
}

impl FiberGroup {
    pub fn new(params: ModelParams, fibers: Vec<Fiber>) -> Self {
        let mut offsets = Vec::with_capacity(fibers.len() + 1);
        let mut o = 0;
        for f in &fibers {
            offsets.push(o);
            o += f.len();
        }
        offsets.push(o);
        let model_lanes = batch::model_allows_lanes(&params);
        let mut blocks = Vec::with_capacity(fibers.len().div_ceil(LANES));
        let mut state = Vec::new();
        for chunk in fibers.chunks(LANES) {
            let len = chunk.iter().map(Fiber::len).max().unwrap_or(0);
            let lanes = model_lanes && len > 0 && chunk.iter().all(|f| f.len() == len);
            blocks.push(Block {
                index: blocks.len(),
                start: state.len(),
                len,
                used: chunk.len(),
                lanes,
            });
            // unused lanes (and the missing tail of shorter fibres) repeat lane 0's segment
            for i in 0..len {
                let seg = |l: usize| {
                    let f = chunk.get(l).filter(|f| i < f.len()).unwrap_or(&chunk[0]);
                    f.segments[i.min(f.len() - 1)]
                };
                state.push(LaneSeg::of([seg(0), seg(1), seg(2), seg(3)]));
            }
        }
        let uniform = fibers.first().and_then(|f0| {
            let (p0, d0) = (f0.props.first()?, f0.density);
            let alike = fibers.iter().all(|f| {
                f.density.to_bits() == d0.to_bits() && f.props.iter().all(|p| same_props(p, p0))
            });
            alike.then(|| LaneConsts::new(&params, [p0; LANES], [d0; LANES]))
        });
        let consts = match uniform {
            Some(c) => Consts::Uniform(c),
            None => {
                let mut v = Vec::with_capacity(state.len());
                for chunk in fibers.chunks(LANES) {
                    let len = chunk.iter().map(Fiber::len).max().unwrap_or(0);
                    for i in 0..len {
                        let pick = |l: usize| {
                            let f = chunk.get(l).filter(|f| i < f.len()).unwrap_or(&chunk[0]);
                            (&f.props[i.min(f.len() - 1)], f.density)
                        };
                        let pd = [pick(0), pick(1), pick(2), pick(3)];
                        v.push(LaneConsts::new(&params, pd.map(|x| x.0), pd.map(|x| x.1)));
                    }
                }
                Consts::PerSegment(v)
            }
        };
        let props = fibers
            .iter()
            .flat_map(|f| f.props.iter().copied())
            .collect();
        let density = fibers.iter().map(|f| f.density).collect();
        Self {
            params,
            props,
            density,
            offsets,
            blocks,
            state,
            consts,
            work: Work::default(),
            contact: None,
            load: contact::SegmentLoad::default(),
            start: Vec::new(),
            search: contact::Search::default(),
        }
    }

    /// Turns fibre–fibre contact within the group on (Some) or off.
    pub fn set_contact(&mut self, contact: Option<ContactParams>) {
        self.contact = contact;
    }

    /// The group's contact parameters, if contact is on.
    pub fn contact(&self) -> Option<&ContactParams> {
        self.contact.as_ref()
    }

    /// Where the contact solves of this group (or, on the shard that solves a sharded
    /// suspension's contact, of the whole suspension) spent their time so far.
    pub fn contact_time(&self) -> contact::ContactTime {
        self.search.spent
    }

    /// The contact load on this group's segments of the step its state is at (empty when
    /// contact is off or nothing touched): what its state message carries.
    pub fn contact_load(&self) -> &contact::SegmentLoad {
        &self.load
    }

    /// Each fibre's first segment in the group's segment order, plus the total.
    #[cfg(test)]
    pub(crate) fn offsets_for_tests(&self) -> Vec<usize> {
        self.offsets.clone()
    }

    /// Sets the contact load of the step a checkpoint holds (it reports that step's
    /// state again, bit for bit).
    pub fn restore_contact_load(&mut self, load: contact::SegmentLoad) {
        self.load = load;
    }

    /// Keeps every segment's centre, axis and normal before a step with contact, read in
    /// the lane storage (in parallel from [`PARALLEL_MIN_SEGMENTS`] on).
    fn keep_start(&mut self) {
        let mut start = std::mem::take(&mut self.start);
        start.resize(self.segment_count(), [Vector3::zeros(); 3]);
        // each block's fibres are contiguous in the fibre-major order
        let mut parts = Vec::with_capacity(self.blocks.len());
        let mut rest = start.as_mut_slice();
        for b in &self.blocks {
            let first = b.index * LANES;
            let n = self.offsets[first + b.used] - self.offsets[first];
            let (head, tail) = std::mem::take(&mut rest).split_at_mut(n);
            parts.push((*b, head));
            rest = tail;
        }
        let (state, offsets) = (&self.state, &self.offsets);
        let copy = |(b, out): (Block, &mut [[Vector3<f64>; 3]])| {
            let first = b.index * LANES;
            for l in 0..b.used {
                let (o, len) = (
                    offsets[first + l] - offsets[first],
                    offsets[first + l + 1] - offsets[first + l],
                );
                for (i, slot) in out[o..o + len].iter_mut().enumerate() {
                    let s = &state[b.start + i];
                    *slot = [s.r.lane(l), s.z.lane(l), s.n.lane(l)].map(Vector3::from);
                }
            }
        };
        if self.segment_count() < PARALLEL_MIN_SEGMENTS {
            parts.into_iter().for_each(copy);
        } else {
            parts.into_par_iter().for_each(copy);
        }
        self.start = start;
    }

    /// Resolves contact after a free step from the kept start ([`Self::keep_start`]): the
    /// fibres that touched get their corrected segments back, then the walls again (a
    /// contact must not push a fibre through a wall). Only the fibres of candidate pairs
    /// are copied out of the lane storage.
    fn apply_contact(&mut self, dt: f64) -> StepReport {
        let Some(mut c) = self.contact else {
            return StepReport::default();
        };
        c.wall_half_height = self.params.wall_half_height;
        let mut search = std::mem::take(&mut self.search);
        let (outcome, mut solved) =
            contact::resolve_segments(&Kept { group: self }, &mut search, &[], &c, dt);
        self.search = search;
        for &k in &outcome.moved {
            if let Some(hh) = self.params.wall_half_height {
                crate::step::wall_contact(&mut solved[k], hh);
            }
            for (i, s) in solved[k].segments.iter().enumerate() {
                self.set_segment(k, i, *s);
            }
        }
        self.load = contact::SegmentLoad::of(&outcome.contacts, 0..self.len(), &self.offsets, dt);
        StepReport {
            pairs: outcome.contacts.len(),
            contact: outcome,
        }
    }

    /// The model parameters shared by the group.
    pub fn params(&self) -> &ModelParams {
        &self.params
    }

    /// Number of fibres.
    pub fn len(&self) -> usize {
        self.density.len()
    }

    pub fn is_empty(&self) -> bool {
        self.density.is_empty()
    }

    /// Total number of segments.
    pub fn segment_count(&self) -> usize {
        self.offsets.last().copied().unwrap_or(0)
    }

    /// Segments of fibre `k`.
    pub fn fiber_len(&self, k: usize) -> usize {
        self.offsets[k + 1] - self.offsets[k]
    }

    /// Properties of fibre `k`'s segments.
    pub fn props(&self, k: usize) -> &[SegmentProps] {
        &self.props[self.offsets[k]..self.offsets[k + 1]]
    }

    /// Material density of fibre `k`.
    pub fn density(&self, k: usize) -> f64 {
        self.density[k]
    }

    /// Segment `i` of fibre `k`.
    pub fn segment(&self, k: usize, i: usize) -> Segment {
        let b = &self.blocks[k / LANES];
        self.state[b.start + i].get(k % LANES)
    }

    /// Fibre `k`'s segments, first to last.
    pub fn segments(&self, k: usize) -> impl Iterator<Item = Segment> + '_ {
        let (segs, l) = self.lanes_of(k);
        segs.iter().map(move |s| s.get(l))
    }

    /// The lane records holding fibre `k`'s segments, first to last, and its lane.
    fn lanes_of(&self, k: usize) -> (&[LaneSeg], usize) {
        let b = &self.blocks[k / LANES];
        (&self.state[b.start..b.start + self.fiber_len(k)], k % LANES)
    }

    /// Replaces segment `i` of fibre `k` (velocities and all: the caller owns consistency).
    pub fn set_segment(&mut self, k: usize, i: usize, s: Segment) {
        let b = self.blocks[k / LANES];
        let lane = k % LANES;
        // the unused lanes of the last block follow fibre 0 of the block
        let lanes = if lane == 0 { b.used..LANES } else { 0..0 };
        for l in std::iter::once(lane).chain(lanes) {
            self.state[b.start + i].set(l, s);
        }
    }

    /// Fibre `k` as a [`Fiber`] (a copy).
    pub fn fiber(&self, k: usize) -> Fiber {
        Fiber {
            segments: self.segments(k).collect(),
            props: self.props(k).to_vec(),
            density: self.density[k],
        }
    }

    /// Every fibre as a [`Fiber`] (a copy).
    pub fn fibers(&self) -> Vec<Fiber> {
        (0..self.len()).map(|k| self.fiber(k)).collect()
    }

    /// The group of fibres `first .. first + n` (one shard's share), same parameters.
    pub fn slice(&self, first: usize, n: usize) -> FiberGroup {
        let end = (first + n).min(self.len());
        let mut g = FiberGroup::new(
            self.params,
            (first.min(end)..end).map(|k| self.fiber(k)).collect(),
        );
        g.contact = self.contact;
        g
    }

    /// Shape and orientation metrics of every fibre, in order (in parallel from
    /// [`PARALLEL_MIN_SEGMENTS`] on).
    pub fn metrics(&self) -> Vec<FiberMetrics> {
        let mut out = Vec::new();
        self.metrics_into(&mut out);
        out
    }

    /// [`Self::metrics`] into `out` (its allocation reused from step to step).
    pub fn metrics_into(&self, out: &mut Vec<FiberMetrics>) {
        // read in the lane storage: centres and axes only, no segment copied out
        let one = |k: usize| metrics_from(self.centres_and_axes(k), self.props(k));
        if self.segment_count() < PARALLEL_MIN_SEGMENTS {
            out.clear();
            out.extend((0..self.len()).map(one));
        } else {
            (0..self.len())
                .into_par_iter()
                .map(one)
                .collect_into_vec(out);
        }
    }

    /// Fibre `k`'s segment centres and axes, first to last, read in the lane storage.
    fn centres_and_axes(
        &self,
        k: usize,
    ) -> impl Iterator<Item = (Vector3<f64>, Vector3<f64>)> + Clone + '_ {
        let (segs, l) = self.lanes_of(k);
        segs.iter()
            .map(move |s| (Vector3::from(s.r.lane(l)), Vector3::from(s.z.lane(l))))
    }

    /// Appends every segment's centre (x, y, z; fibre by fibre, first segment to last) to
    /// `centre`, and with `full` its axis, velocity and angular velocity to the others:
    /// a state message's arrays, read in the lane storage.
    pub fn extend_state(
        &self,
        full: bool,
        centre: &mut Vec<f64>,
        axis: &mut Vec<f64>,
        velocity: &mut Vec<f64>,
        angular_velocity: &mut Vec<f64>,
    ) {
        for k in 0..self.len() {
            let (segs, l) = self.lanes_of(k);
            for s in segs {
                centre.extend_from_slice(&s.r.lane(l));
                if full {
                    axis.extend_from_slice(&s.z.lane(l));
                    velocity.extend_from_slice(&s.v.lane(l));
                    angular_velocity.extend_from_slice(&s.w.lane(l));
                }
            }
        }
    }

    /// Appends every segment's hydrodynamic force of the last step ([`Segment::f`], 3
    /// values each, in the order of [`Self::extend_state`]): two-way coupling's feedback.
    pub fn extend_forces(&self, force: &mut Vec<f64>) {
        for k in 0..self.len() {
            let (segs, l) = self.lanes_of(k);
            for s in segs {
                force.extend_from_slice(&s.f.lane(l));
            }
        }
    }

    /// Segment centres in flat order (where the flow must be sampled).
    pub fn segment_centres(&self) -> Vec<nalgebra::Vector3<f64>> {
        (0..self.len())
            .flat_map(|k| self.segments(k).map(|s| s.r))
            .collect()
    }

    /// Sets every segment's velocity to the fluid's (linear and angular).
    pub fn set_velocity_to_fluid<'f>(
        &mut self,
        fluid: impl Into<Fluid<'f>>,
    ) -> Result<(), FiberError> {
        let fluid = fluid.into();
        self.check(fluid)?;
        for k in 0..self.len() {
            let o = self.offsets[k];
            for i in 0..self.fiber_len(k) {
                let mut s = self.segment(k, i);
                let f = fluid.at(o + i);
                s.v = f.vel;
                s.w = f.rotation();
                self.set_segment(k, i, s);
            }
        }
        Ok(())
    }

    fn check(&self, fluid: Fluid<'_>) -> Result<(), FiberError> {
        if fluid.len() != self.segment_count() {
            return Err(FiberError::SampleCount {
                expected: self.segment_count(),
                got: fluid.len(),
            });
        }
        Ok(())
    }

    /// Advances every fibre by `dt`, in parallel, four fibres at a time in SIMD lanes
    /// where the block allows it ([`batch`]); deterministic: fibres are independent and
    /// every fibre gets the same bits as from [`step`] one fibre at a time.
    /// Groups below [`PARALLEL_MIN_SEGMENTS`] are stepped on the calling thread.
    /// With contact on, the fibres that touch are then corrected ([`crate::contact`]);
    /// the report says what contact did.
    pub fn step<'f>(
        &mut self,
        fluid: impl Into<Fluid<'f>>,
        dt: f64,
    ) -> Result<StepReport, FiberError> {
        self.step_free(fluid, dt)?;
        Ok(self.apply_contact(dt))
    }

    /// [`Self::step`] as `substeps` steps of `dt / substeps` with the fluid held
    /// (`fibers[].substeps`): the fibres' own dynamics resolved finer than the coupling
    /// step, at the cost of the fibre step alone (docs/two-way.md, "The fibres' own
    /// step"). Each segment's force ([`Segment::f`], two-way coupling's feedback) is the
    /// mean over the substeps, so the fluid receives exactly the impulse the fibres took
    /// from it over `dt`. One substep is [`Self::step`], bit for bit.
    pub fn step_in_substeps<'f>(
        &mut self,
        fluid: impl Into<Fluid<'f>>,
        dt: f64,
        substeps: u32,
    ) -> Result<StepReport, FiberError> {
        let fluid = fluid.into();
        if substeps <= 1 {
            return self.step(fluid, dt);
        }
        let h = dt / f64::from(substeps);
        // the sum of the substeps' forces, in the group's working memory between steps
        let mut sum = std::mem::take(&mut self.work.force_sum);
        sum.clear();
        sum.resize(self.state.len(), crate::lanes::V3::default());
        let mut report = StepReport::default();
        for _ in 0..substeps {
            report = self.step(fluid, h)?;
            for (acc, s) in sum.iter_mut().zip(&self.state) {
                *acc = *acc + s.f;
            }
        }
        let n = crate::lanes::F4::splat(f64::from(substeps));
        for (s, acc) in self.state.iter_mut().zip(&sum) {
            s.f = acc.unscale(n);
        }
        self.work.force_sum = sum;
        Ok(report)
    }

    /// [`Self::step`] without the contact solve (the start kept for it when contact is
    /// on): a piece of a suspension sends this free step to its first piece, which solves
    /// contact for all ([`Self::resolve_contact_for`]) and sends each piece its part
    /// ([`Self::apply_contact_solved`]).
    pub fn step_free<'f>(
        &mut self,
        fluid: impl Into<Fluid<'f>>,
        dt: f64,
    ) -> Result<(), FiberError> {
        let fluid = fluid.into();
        if self.contact.is_some() {
            self.keep_start();
        }
        if self.segment_count() < PARALLEL_MIN_SEGMENTS {
            self.step_here(fluid, dt, true)
        } else {
            self.step_parallel(fluid, dt)
        }
    }

    /// [`Self::step`] split over the thread pool whatever the group's size.
    pub fn step_parallel<'f>(
        &mut self,
        fluid: impl Into<Fluid<'f>>,
        dt: f64,
    ) -> Result<(), FiberError> {
        let fluid = fluid.into();
        self.check(fluid)?;
        let (ctx, parts) = self.split(fluid, dt, true);
        // each pool thread keeps its working memory from step to step
        parts.into_par_iter().try_for_each(|(b, seg)| {
            POOL_WORK.with(|work| ctx.step_block(b, seg, &mut work.borrow_mut()))
        })
    }

    /// [`Self::step`] on the current thread only (for single-thread benchmarks).
    pub fn step_serial<'f>(
        &mut self,
        fluid: impl Into<Fluid<'f>>,
        dt: f64,
    ) -> Result<(), FiberError> {
        self.step_here(fluid.into(), dt, true)
    }

    /// One fibre at a time with [`step`] on the current thread, never in lanes (the
    /// reference the lane step is compared with, in tests and benchmarks).
    pub fn step_serial_unbatched<'f>(
        &mut self,
        fluid: impl Into<Fluid<'f>>,
        dt: f64,
    ) -> Result<(), FiberError> {
        self.step_here(fluid.into(), dt, false)
    }

    /// Every block on the current thread, in lanes where allowed if `use_lanes`.
    fn step_here(&mut self, fluid: Fluid<'_>, dt: f64, use_lanes: bool) -> Result<(), FiberError> {
        self.check(fluid)?;
        let mut work = std::mem::take(&mut self.work);
        let (ctx, mut rest) = self.context(fluid, dt, use_lanes);
        let mut stepped = Ok(());
        for &b in ctx.blocks {
            let (seg, tail) = std::mem::take(&mut rest).split_at_mut(b.len);
            rest = tail;
            stepped = ctx.step_block(b, seg, &mut work);
            if stepped.is_err() {
                break;
            }
        }
        self.work = work;
        stepped
    }

    /// What every block's step reads, and each block's storage, split so that blocks
    /// can be stepped independently.
    fn split<'a>(
        &'a mut self,
        fluid: Fluid<'a>,
        dt: f64,
        use_lanes: bool,
    ) -> (Ctx<'a>, Vec<(Block, &'a mut [LaneSeg])>) {
        let (ctx, mut rest) = self.context(fluid, dt, use_lanes);
        let mut parts = Vec::with_capacity(ctx.blocks.len());
        for blk in ctx.blocks {
            let (head, tail) = std::mem::take(&mut rest).split_at_mut(blk.len);
            parts.push((*blk, head));
            rest = tail;
        }
        (ctx, parts)
    }

    /// What every block's step reads, and the storage of all blocks (block after block).
    fn context<'a>(
        &'a mut self,
        fluid: Fluid<'a>,
        dt: f64,
        use_lanes: bool,
    ) -> (Ctx<'a>, &'a mut [LaneSeg]) {
        let (consts, stride): (&[LaneConsts], usize) = match &self.consts {
            Consts::Uniform(c) => (std::slice::from_ref(c), 0),
            Consts::PerSegment(v) => (v, 1),
        };
        let ctx = Ctx {
            params: &self.params,
            props: &self.props,
            density: &self.density,
            offsets: &self.offsets,
            blocks: &self.blocks,
            consts,
            stride,
            fluid,
            dt,
            use_lanes,
        };
        (ctx, &mut self.state)
    }
}

/// A group after its free step, with the start kept by [`FiberGroup::keep_start`]: the
/// contact search reads both where they are.
struct Kept<'a> {
    group: &'a FiberGroup,
}

impl contact::Segments for Kept<'_> {
    fn offsets(&self) -> &[usize] {
        &self.group.offsets
    }
    fn props(&self, k: usize, i: usize) -> &SegmentProps {
        &self.group.props[self.group.offsets[k] + i]
    }
    fn start(&self, k: usize, i: usize) -> (Vector3<f64>, Vector3<f64>) {
        let s = &self.group.start[self.group.offsets[k] + i];
        (s[0], s[1])
    }
    fn end(&self, k: usize, i: usize) -> (Vector3<f64>, Vector3<f64>) {
        let b = &self.group.blocks[k / LANES];
        let s = &self.group.state[b.start + i];
        let l = k % LANES;
        (Vector3::from(s.r.lane(l)), Vector3::from(s.z.lane(l)))
    }
    fn start_fiber(&self, k: usize) -> Fiber {
        let mut f = self.group.fiber(k);
        let o = self.group.offsets[k];
        for (i, s) in f.segments.iter_mut().enumerate() {
            // velocities and force stay those after the step: a locked island, the one
            // reader of the start, takes only positions and axes from it
            [s.r, s.z, s.n] = self.group.start[o + i];
        }
        f
    }
    fn end_fiber(&self, k: usize) -> Fiber {
        self.group.fiber(k)
    }
}

/// Whether two segments have the same properties, bit for bit.
fn same_props(a: &SegmentProps, b: &SegmentProps) -> bool {
    let bits = |p: &SegmentProps| {
        let s = &p.shape;
        let c = &s.coeffs;
        [
            s.length,
            s.diameter,
            c.xa,
            c.ya,
            c.xc,
            c.yc,
            c.yh,
            p.mass,
            p.inertia_axial,
            p.inertia_perp,
        ]
        .map(f64::to_bits)
    };
    bits(a) == bits(b)
}

thread_local! {
    /// A pool thread's working memory of the parallel step.
    static POOL_WORK: std::cell::RefCell<Work> = std::cell::RefCell::new(Work::default());
}

/// Reused working memory of one thread's block steps.
#[derive(Debug, Default, Clone)]
struct Work {
    lanes: batch::Scratch,
    one: Option<Fiber>,
    /// One fibre's samples, decoded for the fibre-by-fibre step.
    fluid: Vec<FluidSample>,
    /// The substeps' summed forces ([`FiberGroup::step_in_substeps`]).
    force_sum: Vec<crate::lanes::V3>,
}

/// What a block's step reads besides its own storage.
struct Ctx<'a> {
    params: &'a ModelParams,
    props: &'a [SegmentProps],
    density: &'a [f64],
    offsets: &'a [usize],
    blocks: &'a [Block],
    consts: &'a [LaneConsts],
    stride: usize,
    fluid: Fluid<'a>,
    dt: f64,
    use_lanes: bool,
}

impl Ctx<'_> {
    /// The samples of fibre `k`.
    fn fluid_of(&self, k: usize) -> Fluid<'_> {
        self.fluid.range(self.offsets[k], self.offsets[k + 1])
    }

    /// Steps block `b` (storage `seg`): in lanes if it can, else fibre by fibre.
    fn step_block(&self, b: Block, seg: &mut [LaneSeg], work: &mut Work) -> Result<(), FiberError> {
        let first = b.index * LANES;
        if self.use_lanes && b.lanes {
            // unused lanes repeat fibre `first`
            let samples: [Fluid<'_>; LANES] =
                std::array::from_fn(|l| self.fluid_of(first + if l < b.used { l } else { 0 }));
            let consts = if self.stride == 0 {
                self.consts
            } else {
                &self.consts[b.start..b.start + b.len]
            };
            return batch::step(
                self.params,
                seg,
                consts,
                self.stride,
                b.used,
                &samples,
                self.dt,
                &mut work.lanes,
            )
            .map_err(|lane| FiberError::Singular {
                fiber: first + lane,
            });
        }
        let one = work.one.get_or_insert_with(|| Fiber {
            segments: Vec::new(),
            props: Vec::new(),
            density: 1.0,
        });
        for l in 0..b.used {
            let k = first + l;
            let n = self.offsets[k + 1] - self.offsets[k];
            one.segments.clear();
            one.segments.extend(seg[..n].iter().map(|s| s.get(l)));
            one.props.clear();
            one.props
                .extend_from_slice(&self.props[self.offsets[k]..self.offsets[k + 1]]);
            one.density = self.density[k];
            let fluid = self.fluid_of(k).decoded(&mut work.fluid);
            step(self.params, one, fluid, self.dt).map_err(|e| match e {
                FiberError::Singular { .. } => FiberError::Singular { fiber: k },
                other => other,
            })?;
            for (s, &new) in seg.iter_mut().zip(&one.segments) {
                s.set(l, new);
            }
        }
        Ok(())
    }
}
