//! `fiberflow-bench stages`: the flow node's per-fibre stages at scale, each beside a
//! floor kernel that does the stage's irreducible work with trivial arithmetic, in
//! alternating rounds on one and on two threads (docs/performance.md, "Stages and their
//! floors").
//!
//! The case: `fibers` straight seven-segment case-1 fibres (segments 3 wall units apart) at
//! random places and directions in the fine grid's channel (192 × 64 × 64), random forces,
//! listed fibre by fibre as the flow node receives them. The floors:
//! - sampling: per point, in the flow node's order (fibres by the cell of their first
//!   segment), the 8 corners of each of the 12 trilinear quantities read from one
//!   interleaved table (96 values, the tables' layout and size) and summed with equal
//!   weights, 12 values written;
//! - spreading: per point and component the 27 nodes of its cell's neighbourhood each
//!   given a constant share, the points sorted by z plane and the planes split between
//!   threads as the stage splits them (no stencil weights, no node lists);
//! - correction: per fibre its memories of the held modes read and written once (what
//!   carries from step to step), and per pair of segments the pair shares' arithmetic of
//!   the long-wave path (u = Σ_b c_b r_b², a degree-5 polynomial in u) over the held lanes
//!   in single precision (no square root, range reduction or division);
//! - fibre step (a fibre node's `FiberGroup::step`, viscous + inertial drag, no contact):
//!   per segment its state as the group stores it (six 3-vectors: centre, axis, velocity,
//!   angular velocity, normal, force; 144 bytes) read and written once and its fluid
//!   sample (12 values) read once, with one add per value;
//! - state out (the group's full state arrays gathered and its message encoded as CDR into
//!   a buffer of the message's size, as a fibre node sends it): per segment the message's
//!   12 values copied once from a flat array into the buffer;
//! - recording (the encoded state written as one message into a new MCAP file with the
//!   recorder's options: zstd level 1 in 4 MB chunks, as `fiberflow_recorder::write_options`
//!   gives them, in the system's temporary folder): the same bytes written once into a new
//!   plain file there.
//!
//! Size (≈ 680 lines before the tests): each stage sits beside its floor kernel, so that a
//! reader sees what the floor leaves out, and all of them share one case (fibres, grid,
//! samples).

use anyhow::{Context, Result};
use fiberflow_dns::sample::Interpolation;
use fiberflow_dns::spread::{spread, BodyForce};
use fiberflow_dns::{DnsConfig, Grid, InitialField, Solver};
use fiberflow_fiber_model::fiber::Fiber;
use fiberflow_fiber_model::group::FiberGroup;
use fiberflow_fiber_model::{DragModel, FluidSample, ModelParams};
use fiberflow_flow::sampling::{Field, PieceSamples};
use fiberflow_flow::self_induced::{History, Widths, PER_FIBER};
use fiberflow_messages::FiberGroupState;
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use std::time::Instant;

const SEGMENTS: usize = 7;
const RE_TAU: f64 = 150.0;
/// The memory modes the fine grid's rows hold (test
/// `self_induced::tests::modes_no_row_holds_weigh_nothing_in_any_row` prints them).
const HELD_MODES: usize = 41;

/// What `fiberflow-bench stages` runs.
pub struct StagesOptions {
    pub fibers: usize,
    pub rounds: usize,
    pub threads: Vec<usize>,
}

/// The case's fibres: segment centres (wall units, 3 per point) and forces (3 per point).
fn fibers(n: usize) -> (Vec<f64>, Vec<f64>) {
    let pi = std::f64::consts::PI;
    let mut rng = fiberflow_dns::init::SplitMix64::new(0x0dd_5eed);
    let mut rnd = move || 0.5 * (rng.symmetric() + 1.0);
    let (mut centre, mut force) = (Vec::with_capacity(21 * n), Vec::with_capacity(21 * n));
    for _ in 0..n {
        let c = [rnd() * 2.0 * pi, rnd() * 1.8 - 0.9, rnd() * pi].map(|v| v * RE_TAU);
        let p = [rnd() - 0.5, rnd() - 0.5, rnd() - 0.5];
        let norm = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt().max(1e-9);
        for s in 0..SEGMENTS {
            let along = 3.0 * (s as f64 - 3.0);
            centre.extend((0..3).map(|a| c[a] + along * p[a] / norm));
            force.extend((0..3).map(|_| rnd() - 0.5));
        }
    }
    (centre, force)
}

/// CPU seconds of this process so far (user + system, every thread).
fn cpu_s() -> f64 {
    let mut u = std::mem::MaybeUninit::<libc::rusage>::zeroed();
    // SAFETY: getrusage writes the struct it is given; zeroed is a valid rusage
    let rc = unsafe { libc::getrusage(libc::RUSAGE_SELF, u.as_mut_ptr()) };
    if rc != 0 {
        return f64::NAN;
    }
    // SAFETY: initialised (zeroed, then written by the call)
    let u = unsafe { u.assume_init() };
    let t = |v: libc::timeval| v.tv_sec as f64 + v.tv_usec as f64 * 1e-6;
    t(u.ru_utime) + t(u.ru_stime)
}

/// Wall and CPU seconds of one call of `f`.
fn timed(f: &mut dyn FnMut()) -> (f64, f64) {
    let (t, c) = (Instant::now(), cpu_s());
    f();
    (t.elapsed().as_secs_f64(), cpu_s() - c)
}

/// The sampling floor's table: 12 values per padded node, interleaved.
struct FloorTable {
    values: Vec<f64>,
    px: usize,
    plane: usize,
    inv: [f64; 3],
    n: [usize; 3],
}

impl FloorTable {
    fn new(g: &Grid) -> Self {
        Self {
            values: (0..12 * g.padded_len())
                .map(|i| (i % 97) as f64 * 1e-3)
                .collect(),
            px: g.px,
            plane: g.plane(),
            inv: [g.nx as f64 / g.lx, g.ny as f64 / 2.0, g.nz as f64 / g.lz],
            n: [g.nx, g.ny, g.nz],
        }
    }

    /// The 96 corner values of a point (outer units) summed per quantity into `out`.
    #[inline(always)]
    fn sample(&self, p: &[f64], out: &mut [f64]) {
        let cell = |x: f64, a: usize| -> usize {
            let s = (x * self.inv[a]).max(0.0) as usize;
            s % self.n[a] + 1
        };
        let (i, j, k) = (cell(p[0], 0), cell(p[1] + 1.0, 1), cell(p[2], 2));
        let j = j.min(self.n[1]);
        let mut acc = [0.0f64; 12];
        for dk in 0..2 {
            for dj in 0..2 {
                let row = 12 * (i + self.px * (j + dj) + self.plane * (k + dk));
                let corners = &self.values[row..row + 24];
                for (q, a) in acc.iter_mut().enumerate() {
                    *a += corners[q] + corners[12 + q];
                }
            }
        }
        for (o, a) in out.iter_mut().zip(acc) {
            *o = 0.125 * a;
        }
    }
}

/// The stages and their floors, each a closure doing one step's work on the case.
struct Case {
    g: Grid,
    centre: Vec<f64>,
    force: Vec<f64>,
    spf: Vec<u32>,
    points: Vec<[f64; 3]>,
    point_forces: Vec<[f64; 3]>,
    field: Field,
    samples: Vec<PieceSamples>,
    body: BodyForce,
    widths: Widths,
    history: History,
    velocity: Vec<f64>,
    table: FloorTable,
    /// The sampling floor's order: point indices, fibres by their first segment's cell.
    cell_order: Vec<u32>,
    floor_out: Vec<f64>,
    /// The spreading floor: the points' cells sorted by z plane, and where each plane's
    /// run starts.
    by_plane: Vec<[u32; 3]>,
    plane_start: Vec<usize>,
    floor_field: Vec<f64>,
    floor_memory: Vec<f64>,
    /// The fibre step: the case's fibres as a group, a fluid sample per segment, and the
    /// floor's state (18 values per segment) and samples (12).
    group: FiberGroup,
    fluid: Vec<FluidSample>,
    floor_state: Vec<f64>,
    floor_samples: Vec<f64>,
    /// State out: the message (its arrays reused), its bytes, and the floor's flat copy.
    state_msg: FiberGroupState,
    state_bytes: Vec<u8>,
    floor_src: Vec<f64>,
    floor_dst: Vec<f64>,
    /// Recording: where the stage's MCAP file and the floor's plain file go.
    record_path: std::path::PathBuf,
    floor_path: std::path::PathBuf,
}

/// The case's fibres as a group of case-1 fibres (N = 7, l+ 3, d+ 0.232, ρ 1150) with the
/// fibre nodes' drag, and a fluid sample per segment (a shear and a gradient).
fn fiber_group(centre: &[f64]) -> Result<(FiberGroup, Vec<FluidSample>)> {
    let params = ModelParams {
        drag: DragModel {
            viscosity: 1.0,
            fluid_density: 1.0,
            drag_coefficient: 1.0,
        },
        gravity: Vector3::zeros(),
        bending_stiffness: 0.0,
        twisting_stiffness: 0.0,
        tikhonov: 0.0,
        wall_half_height: Some(RE_TAU),
    };
    let fibers = centre
        .chunks_exact(3 * SEGMENTS)
        .map(|c| {
            let first = Vector3::new(c[0], c[1], c[2]);
            let last = Vector3::new(
                c[3 * SEGMENTS - 3],
                c[3 * SEGMENTS - 2],
                c[3 * SEGMENTS - 1],
            );
            let mid = 0.5 * (first + last);
            Fiber::straight(
                mid,
                last - first,
                &[3.0; SEGMENTS],
                &[0.232; SEGMENTS],
                1150.0,
            )
            .context("a case fibre")
        })
        .collect::<Result<Vec<_>>>()?;
    let group = FiberGroup::new(params, fibers);
    let fluid = group
        .segment_centres()
        .iter()
        .map(|r| FluidSample {
            vel: Vector3::new(0.1 * r.y + 10.0, 0.3, -0.2),
            grad: Matrix3::new(0.01, 0.1, 0.0, 0.0, -0.02, 0.03, 0.01, 0.0, 0.01),
        })
        .collect();
    Ok((group, fluid))
}

impl Case {
    fn new(n: usize) -> Result<Self> {
        let mut cfg = DnsConfig::with_cells(192, 64, 64);
        cfg.init = InitialField::Turbulent {
            amplitude: 0.25,
            seed: 1,
        };
        let solver = Solver::new(cfg).context("the fine grid's solver")?;
        let g = solver.grid.clone();
        let (centre, force) = fibers(n);
        let points: Vec<[f64; 3]> = centre
            .chunks_exact(3)
            .map(|c| {
                [
                    c[0] / RE_TAU,
                    (c[1] / RE_TAU).clamp(-1.0, 1.0),
                    c[2] / RE_TAU,
                ]
            })
            .collect();
        let point_forces: Vec<[f64; 3]> = force
            .chunks_exact(3)
            .map(|f| [f[0] * 1e-6, f[1] * 1e-6, f[2] * 1e-6])
            .collect();
        let table = FloorTable::new(&g);
        let cell_of = |p: &[f64; 3]| -> u64 {
            let c = |x: f64, a: usize| (x * table.inv[a]).max(0.0) as u64 % table.n[a] as u64;
            (c(p[2], 2) * (g.ny as u64 + 1) + c(p[1] + 1.0, 1)) * g.nx as u64 + c(p[0], 0)
        };
        let mut fibers_by_cell: Vec<(u64, u32)> = (0..n)
            .map(|f| (cell_of(&points[SEGMENTS * f]), f as u32))
            .collect();
        fibers_by_cell.sort_unstable();
        let cell_order = fibers_by_cell
            .iter()
            .flat_map(|&(_, f)| (0..SEGMENTS as u32).map(move |s| SEGMENTS as u32 * f + s))
            .collect();
        let mut by_plane: Vec<[u32; 3]> = points
            .iter()
            .map(|p| {
                let c = |x: f64, a: usize| {
                    ((x * table.inv[a]).max(0.0) as usize % table.n[a]) as u32 + 1
                };
                [
                    c(p[0], 0),
                    c(p[1] + 1.0, 1).min(g.ny as u32 - 1),
                    c(p[2], 2),
                ]
            })
            .collect();
        by_plane.sort_by_key(|c| c[2]);
        let mut plane_start = vec![0usize; g.nz + 3];
        for c in &by_plane {
            plane_start[c[2] as usize + 1] += 1;
        }
        for k in 0..g.nz + 2 {
            plane_start[k + 1] += plane_start[k];
        }
        let widths = Widths::new(&g, RE_TAU);
        let (group, fluid) = fiber_group(&centre)?;
        let segments = SEGMENTS * n;
        let state_msg = FiberGroupState {
            schema_version: fiberflow_messages::SCHEMA_VERSION,
            group: "case1".into(),
            group_fibers: n as u32,
            segments_per_fiber: vec![SEGMENTS as u32; n],
            segment_length: vec![3.0; n],
            diameter: vec![0.232; n],
            density_ratio: vec![1150.0; n],
            layer: vec![0; n],
            ..Default::default()
        };
        Ok(Self {
            group,
            fluid,
            floor_state: (0..18 * segments).map(|i| (i % 89) as f64).collect(),
            floor_samples: (0..12 * segments).map(|i| (i % 83) as f64 * 1e-3).collect(),
            state_msg,
            state_bytes: Vec::new(),
            floor_src: (0..12 * segments).map(|i| (i % 79) as f64).collect(),
            floor_dst: vec![0.0; 12 * segments],
            record_path: std::env::temp_dir()
                .join(format!("ff-stages-record-{}.mcap", std::process::id())),
            floor_path: std::env::temp_dir()
                .join(format!("ff-stages-record-{}.bin", std::process::id())),
            body: BodyForce::zeros(&g),
            floor_field: vec![0.0; 3 * g.padded_len()],
            floor_out: vec![0.0; 12 * points.len()],
            floor_memory: vec![0.0; PER_FIBER * n],
            velocity: vec![0.0; centre.len()],
            spf: vec![SEGMENTS as u32; n],
            field: Field::dns(solver, Interpolation::Trilinear),
            samples: Vec::new(),
            history: History::default(),
            g,
            centre,
            force,
            points,
            point_forces,
            widths,
            table,
            cell_order,
            by_plane,
            plane_start,
        })
    }

    fn sampling(&mut self) {
        let reuse = std::mem::take(&mut self.samples);
        self.samples = self
            .field
            .sample_pieces(&[(&self.centre[..], &self.spf[..])], reuse);
    }

    fn sampling_floor(&mut self) {
        let (table, points) = (&self.table, &self.points);
        let order = &self.cell_order;
        let out = &mut self.floor_out;
        // in the stage's order, each thread a run of points, the answers in list order
        out.par_chunks_mut(12 * 7 * 64)
            .zip(order.par_chunks(7 * 64))
            .for_each(|(out, order)| {
                for (o, &n) in out.chunks_exact_mut(12).zip(order) {
                    table.sample(&points[n as usize], o);
                }
            });
    }

    fn spreading(&mut self) {
        spread(&self.g, &self.points, &self.point_forces, &mut self.body);
    }

    fn spreading_floor(&mut self) {
        let (px, plane, nz) = (self.g.px, self.g.plane(), self.g.nz);
        let (by_plane, start) = (&self.by_plane, &self.plane_start);
        let share = 1.0 / 27.0;
        // per component, each plane written by one thread: the runs of the three planes
        // that reach it
        for c in 0..3 {
            let f = &mut self.floor_field[c * self.g.padded_len()..(c + 1) * self.g.padded_len()];
            f.par_chunks_mut(plane)
                .enumerate()
                .filter(|(k, _)| (1..=nz).contains(k))
                .for_each(|(k, pl)| {
                    pl.iter_mut().for_each(|x| *x = 0.0);
                    for oz in 0..3usize {
                        let first = (k + nz - oz - 1) % nz + 1;
                        for cell in &by_plane[start[first]..start[first + 1]] {
                            let (i, j) = (cell[0] as usize, cell[1] as usize);
                            for dj in 0..3 {
                                let row = px * (j + dj - 1);
                                for di in 0..3 {
                                    pl[row + i + di - 1] += share;
                                }
                            }
                        }
                    }
                });
        }
    }

    fn correction(&mut self) {
        self.velocity.iter_mut().for_each(|v| *v = 0.0);
        self.history.correct_and_advance(
            &self.widths,
            RE_TAU,
            0.2,
            &self.spf,
            &self.centre,
            &self.force,
            &mut self.velocity,
        );
    }

    fn fiber_step(&mut self) {
        // a failed step (it cannot fail for these straight fibres) would show as no time
        let _ = self.group.step(&self.fluid[..], 0.2);
    }

    fn fiber_step_floor(&mut self) {
        let chunk = 7 * 64;
        self.floor_state
            .par_chunks_mut(18 * chunk)
            .zip(self.floor_samples.par_chunks(12 * chunk))
            .for_each(|(state, samples)| {
                for (s, q) in state.chunks_exact_mut(18).zip(samples.chunks_exact(12)) {
                    let a: f64 = q.iter().sum();
                    for x in s.iter_mut() {
                        *x = 0.999 * *x + 1e-9 * a;
                    }
                }
            });
    }

    fn state_out(&mut self) {
        let m = &mut self.state_msg;
        for v in [
            &mut m.centre,
            &mut m.axis,
            &mut m.velocity,
            &mut m.angular_velocity,
        ] {
            v.clear();
        }
        self.group.extend_state(
            true,
            &mut m.centre,
            &mut m.axis,
            &mut m.velocity,
            &mut m.angular_velocity,
        );
        self.state_bytes
            .resize(fiberflow_messages::encoded_len(&self.state_msg), 0);
        let _ = fiberflow_messages::encode_into(&self.state_msg, &mut self.state_bytes);
    }

    /// The last encoded state as a recorder writes it (the stage state out runs first in
    /// every round, so the bytes are this round's).
    fn recording(&mut self) {
        let write = || -> Result<()> {
            let file = std::fs::File::create(&self.record_path)?;
            let mut w = fiberflow_recorder::write_options(
                fiberflow_recorder::ChunkCompression::Zstd,
                env!("CARGO_PKG_VERSION"),
            )
            .create(std::io::BufWriter::new(file))?;
            let kind = fiberflow_messages::Kind::FiberGroupState;
            let schema = w.add_schema(
                kind.type_name(),
                "ros2msg",
                fiberflow_messages::schema::kind_text(kind).as_bytes(),
            )?;
            let channel = w.add_channel(
                schema,
                "fiberflow/bench/fibers/case1/state",
                "cdr",
                &Default::default(),
            )?;
            w.write_to_known_channel(
                &mcap::records::MessageHeader {
                    channel_id: channel,
                    sequence: 0,
                    log_time: 0,
                    publish_time: 0,
                },
                &self.state_bytes,
            )?;
            w.finish()?;
            Ok(())
        };
        if let Err(e) = write() {
            tracing::warn!(error = %e, "recording stage");
        }
    }

    fn recording_floor(&mut self) {
        let write = || -> std::io::Result<()> {
            use std::io::Write;
            let mut f = std::fs::File::create(&self.floor_path)?;
            f.write_all(&self.state_bytes)
        };
        if let Err(e) = write() {
            tracing::warn!(error = %e, "recording floor");
        }
    }

    fn state_out_floor(&mut self) {
        let chunk = 12 * 7 * 64;
        self.floor_dst
            .par_chunks_mut(chunk)
            .zip(self.floor_src.par_chunks(chunk))
            .for_each(|(d, s)| d.copy_from_slice(s));
    }

    fn correction_floor(&mut self) {
        let centre = &self.centre;
        // the held lanes' coefficients, plane by plane as the stage keeps them (their
        // magnitudes are immaterial to the flops)
        let lanes = 16 * (3 * HELD_MODES).div_ceil(16);
        let coeff: [Vec<f32>; 3] =
            std::array::from_fn(|b| (0..lanes).map(|q| 1e-6 * (q + b + 1) as f32).collect());
        self.floor_memory
            .par_chunks_mut(PER_FIBER)
            .zip(centre.par_chunks(3 * SEGMENTS))
            .with_min_len(16)
            .for_each_init(
                || vec![0.0f32; SEGMENTS * lanes],
                |share, (m, c)| {
                    for x in m[..10 * HELD_MODES].iter_mut() {
                        *x = 0.99 * *x + 1.0;
                    }
                    share.iter_mut().for_each(|s| *s = 1.0);
                    for i in 0..SEGMENTS {
                        for j in i + 1..SEGMENTS {
                            let r2 = [0, 1, 2].map(|a| {
                                let d = c[3 * i + a] - c[3 * j + a];
                                (d * d) as f32
                            });
                            let (lo, hi) = share.split_at_mut(j * lanes);
                            series_lanes(
                                &coeff,
                                r2,
                                &mut lo[i * lanes..(i + 1) * lanes],
                                &mut hi[..lanes],
                            );
                        }
                    }
                    m[PER_FIBER - 1] += share.iter().map(|&s| s as f64).sum::<f64>();
                },
            );
    }
}

/// The correction floor's arithmetic for one pair: per lane u = Σ_b c_b r_b² and a degree-5
/// polynomial in u, added to both segments' shares; sixteen lanes a vector where the
/// processor has AVX-512, with fused multiply-adds (a floor, not a result).
fn series_lanes(coeff: &[Vec<f32>; 3], r2: [f32; 3], near: &mut [f32], far: &mut [f32]) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") && is_x86_feature_detected!("fma") {
            // SAFETY: the CPU has AVX-512F and FMA (checked just above)
            return unsafe { series_lanes_avx512(coeff, r2, near, far) };
        }
    }
    series_lanes_plain(coeff, r2, near, far)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,fma")]
unsafe fn series_lanes_avx512(
    coeff: &[Vec<f32>; 3],
    r2: [f32; 3],
    near: &mut [f32],
    far: &mut [f32],
) {
    series_lanes_plain(coeff, r2, near, far)
}

#[inline(always)]
fn series_lanes_plain(coeff: &[Vec<f32>; 3], r2: [f32; 3], near: &mut [f32], far: &mut [f32]) {
    let n = near.len().min(far.len()).min(coeff[0].len());
    let (cx, cy, cz) = (&coeff[0][..n], &coeff[1][..n], &coeff[2][..n]);
    for q in 0..n {
        let u = cx[q] * r2[0] + cy[q] * r2[1] + cz[q] * r2[2];
        let s = 1.0
            + u * (-1.0 / 6.0
                + u * (1.0 / 120.0
                    + u * (-1.0 / 5040.0 + u * (1.0 / 362_880.0 + u * (-1.0 / 39_916_800.0)))));
        near[q] += s;
        far[q] += s;
    }
}

type Stage = fn(&mut Case);

/// Runs the stages beside their floors: per round, per thread count, each stage and its
/// floor once each (the order alternating between rounds), after one warm-up call each.
pub fn run_stages(opts: &StagesOptions) -> Result<()> {
    anyhow::ensure!(
        opts.fibers > 0 && opts.rounds > 0,
        "--fibers and --rounds must be at least 1"
    );
    anyhow::ensure!(
        !opts.threads.is_empty() && opts.threads.iter().all(|&t| (1..=256).contains(&t)),
        "--threads: thread counts in 1..=256, e.g. 1,2 (got {:?})",
        opts.threads
    );
    let mut case = Case::new(opts.fibers)?;
    let segments = (opts.fibers * SEGMENTS) as f64;
    let stages: [(&str, Stage, Stage); 6] = [
        ("sampling", Case::sampling, Case::sampling_floor),
        ("spreading", Case::spreading, Case::spreading_floor),
        ("correction", Case::correction, Case::correction_floor),
        ("fibre step", Case::fiber_step, Case::fiber_step_floor),
        ("state out", Case::state_out, Case::state_out_floor),
        ("recording", Case::recording, Case::recording_floor),
    ];
    let pools: Vec<(usize, rayon::ThreadPool)> = opts
        .threads
        .iter()
        .map(|&t| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(t)
                .build()
                .map(|p| (t, p))
                .context("thread pool")
        })
        .collect::<Result<_>>()?;
    // [stage][pool][stage or floor] → per round (wall s, CPU s)
    let mut times = vec![vec![[Vec::new(), Vec::new()]; pools.len()]; stages.len()];
    for round in 0..=opts.rounds {
        for (p, (_, pool)) in pools.iter().enumerate() {
            for (s, (_, stage, floor)) in stages.iter().enumerate() {
                let order = if round % 2 == 0 { [0, 1] } else { [1, 0] };
                for which in order {
                    let f = [stage, floor][which];
                    let t = pool.install(|| timed(&mut || f(&mut case)));
                    if round > 0 {
                        times[s][p][which].push(t);
                    }
                }
            }
        }
        tracing::info!(round, "stages: round done");
    }
    std::fs::remove_file(&case.record_path).ok();
    std::fs::remove_file(&case.floor_path).ok();
    let median = |v: &[(f64, f64)], cpu: bool| -> (f64, f64, f64) {
        let mut x: Vec<f64> = v.iter().map(|t| if cpu { t.1 } else { t.0 }).collect();
        x.sort_by(f64::total_cmp);
        (x[x.len() / 2], x[0], x[x.len() - 1])
    };
    println!(
        "{} fibres of {SEGMENTS} segments, fine grid 192 x 64 x 64, {} rounds (median, min-max)\n",
        opts.fibers, opts.rounds
    );
    println!("| stage | threads | wall ms | CPU ns per segment | floor wall ms | floor CPU ns per segment | stage / floor (CPU) |");
    println!("|---|---|---|---|---|---|---|");
    for (s, (name, _, _)) in stages.iter().enumerate() {
        for (p, (threads, _)) in pools.iter().enumerate() {
            let [st, fl] = &times[s][p];
            let (w, w0, w1) = median(st, false);
            let (c, c0, c1) = median(st, true);
            let (fw, _, _) = median(fl, false);
            let (fc, fc0, fc1) = median(fl, true);
            let ns = |x: f64| x * 1e9 / segments;
            println!(
                "| {name} | {threads} | {:.1} ({:.1}–{:.1}) | {:.0} ({:.0}–{:.0}) | {:.1} | {:.0} ({:.0}–{:.0}) | {:.1} |",
                w * 1e3,
                w0 * 1e3,
                w1 * 1e3,
                ns(c),
                ns(c0),
                ns(c1),
                fw * 1e3,
                ns(fc),
                ns(fc0),
                ns(fc1),
                c / fc
            );
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The stages and their floors run on a few fibres on one and two threads, and a
    /// thread count of 0 is refused by name.
    #[test]
    fn stages_run_on_a_few_fibers_and_refuse_no_threads() {
        let ok = run_stages(&StagesOptions {
            fibers: 40,
            rounds: 1,
            threads: vec![1, 2],
        });
        assert!(ok.is_ok(), "{ok:?}");
        let err = run_stages(&StagesOptions {
            fibers: 40,
            rounds: 1,
            threads: vec![0],
        });
        let msg = format!("{:#}", err.expect_err("0 threads refused"));
        assert!(
            msg.contains("--threads") && msg.contains("1..=256"),
            "{msg}"
        );
    }
}
