//! Sampling the flow at every segment centre of a group's state. Fibres are visited in
//! the order of the grid cell of their first segment, so fibres close in space are sampled
//! one after the other and the field's neighbouring planes stay in cache; every point is
//! sampled on its own, so the order changes no bit of the result
//! (test `cell_order_gives_the_same_samples`).

use crate::analytic::AnalyticFlow;
use fiberflow_dns::sample::{Interpolation, Sample, Sampler, Tables, LANES};
use fiberflow_dns::Solver;
use rayon::prelude::*;

/// One point's sample: velocity and `grad[3a + b] = ∂v_a/∂x_b`.
pub type PointSample = ([f64; 3], [f64; 9]);

/// One piece's samples: velocity (3 per point) and gradient (9 per point).
pub type PieceSamples = (Vec<f64>, Vec<f64>);

/// From this many points per step on, the trilinear sampler reads per-step tables, four
/// points at a time: filling the tables is a pass over the whole field, which pays only
/// when many points read them (the measurements that set the threshold:
/// docs/performance.md, "Sampling", and docs/history/code-comments.md). Both give the
/// same bits, so the choice never shows in a result.
pub const TABLES_MIN_POINTS: usize = 400_000;

/// The field the flow node serves.
pub enum Field {
    Analytic(AnalyticFlow),
    Dns(Box<Dns>),
}

/// The DNS with its sampler and the sampler's per-step tables.
pub struct Dns {
    pub solver: Solver,
    sampler: Sampler,
    tables: Tables,
}

impl Field {
    /// A DNS field sampled with `scheme`.
    pub fn dns(solver: Solver, scheme: Interpolation) -> Self {
        let sampler = Sampler::with_scheme(&solver.grid, scheme);
        Field::Dns(Box::new(Dns {
            solver,
            sampler,
            tables: Tables::new(),
        }))
    }

    /// Velocity and gradient (plus units) at the segment centres of every piece (its
    /// centres, 3 per point, and its segments per fibre), in one pass over all pieces'
    /// fibres in cell order; per piece, in its points' order. `reuse`: the last step's
    /// buffers, filled again instead of allocated and zeroed (tens of MB at scale).
    pub fn sample_pieces(
        &mut self,
        pieces: &[(&[f64], &[u32])],
        reuse: Vec<PieceSamples>,
    ) -> Vec<PieceSamples> {
        let points: usize = pieces.iter().map(|p| p.0.len() / 3).sum();
        match self {
            Field::Analytic(a) => {
                let a = *a;
                sample_fibers(
                    pieces,
                    reuse,
                    |_| 0,
                    one_by_one(|p| a.sample([p[0], p[1], p[2]])),
                )
            }
            Field::Dns(d) => {
                let tables =
                    d.sampler.scheme() == Interpolation::Trilinear && points >= TABLES_MIN_POINTS;
                if tables {
                    d.tables.fill(&d.sampler, &d.solver.grid, &d.solver.vel);
                }
                let d = &**d;
                let (g, re) = (&d.solver.grid, d.solver.cfg.re_tau);
                let outer = |p: &[f64]| [p[0] / re, p[1] / re, p[2] / re];
                let plus = |sm: Sample| -> PointSample {
                    let mut grad = sm.grad;
                    grad.iter_mut().for_each(|x| *x /= re);
                    (sm.vel, grad)
                };
                let direct = |p: &[f64]| plus(d.sampler.sample(g, &d.solver.vel, outer(p)));
                // from the tables, four points at a time (the same bits as one by one)
                let from_tables = |c: &[f64], v: &mut [f64], gr: &mut [f64]| {
                    for ((c, v), gr) in c
                        .chunks(3 * LANES)
                        .zip(v.chunks_mut(3 * LANES))
                        .zip(gr.chunks_mut(9 * LANES))
                    {
                        // a short last group repeats its last point
                        let n = c.len() / 3;
                        if n == 0 {
                            continue;
                        }
                        let p: [[f64; 3]; LANES] =
                            std::array::from_fn(|l| outer(&c[3 * l.min(n - 1)..]));
                        let four = d.tables.sample4(&d.sampler, g, p);
                        for (l, sm) in four.into_iter().take(n).enumerate() {
                            let (sv, sg) = plus(sm);
                            v[3 * l..3 * l + 3].copy_from_slice(&sv);
                            gr[9 * l..9 * l + 9].copy_from_slice(&sg);
                        }
                    }
                };
                // a fibre's sort key: the grid cell (z plane, then y row, then x) of its
                // first segment
                let cell = |p: &[f64]| -> u64 {
                    let wrap = |x: f64, d: f64, n: usize| {
                        ((x / re / d).floor().rem_euclid(n as f64)) as u64
                    };
                    let j = ((p[1] / re + 1.0) * 0.5 * g.ny as f64).clamp(0.0, g.ny as f64);
                    (wrap(p[2], g.dz, g.nz) * (g.ny as u64 + 1) + j as u64) * g.nx as u64
                        + wrap(p[0], g.dx, g.nx)
                };
                if tables {
                    sample_fibers(pieces, reuse, cell, from_tables)
                } else {
                    sample_fibers(pieces, reuse, cell, one_by_one(direct))
                }
            }
        }
    }
}

/// A fibre's sampler (its centres, 3 per point, into its velocities and gradients) from
/// a point's sampler.
pub fn one_by_one(
    sample: impl Fn(&[f64]) -> PointSample + Sync,
) -> impl Fn(&[f64], &mut [f64], &mut [f64]) + Sync {
    move |c, v, g| {
        for ((p, vo), go) in c
            .chunks_exact(3)
            .zip(v.chunks_exact_mut(3))
            .zip(g.chunks_exact_mut(9))
        {
            let (sv, sg) = sample(p);
            vo.copy_from_slice(&sv);
            go.copy_from_slice(&sg);
        }
    }
}

/// Velocity and gradient at the points of every piece (`centres`: 3 per point), per piece
/// in its points' order, `sample` filling one fibre's at a time. A piece's
/// `segments_per_fiber` groups its points into fibres (if it does not add up to the
/// points, each point counts as its own fibre); the fibres of all pieces are sampled in
/// the order of `cell` of their first point. The output reuses
/// the buffers of `reuse` in order (every value is written, so what they held never shows).
pub fn sample_fibers(
    pieces: &[(&[f64], &[u32])],
    reuse: Vec<PieceSamples>,
    cell: impl Fn(&[f64]) -> u64 + Sync,
    sample: impl Fn(&[f64], &mut [f64], &mut [f64]) + Sync,
) -> Vec<PieceSamples> {
    let mut reuse = reuse.into_iter();
    let mut out: Vec<PieceSamples> = pieces
        .iter()
        .map(|(c, _)| {
            let n = c.len() / 3;
            let (mut v, mut g) = reuse.next().unwrap_or_default();
            v.resize(3 * n, 0.0);
            g.resize(9 * n, 0.0);
            (v, g)
        })
        .collect();
    let mut fibers = Vec::new();
    for ((centres, segments_per_fiber), (vel, grad)) in pieces.iter().zip(out.iter_mut()) {
        let n = centres.len() / 3;
        let counted: u64 = segments_per_fiber.iter().map(|&c| c as u64).sum();
        let lengths: Box<dyn Iterator<Item = usize>> = if counted == n as u64 {
            Box::new(segments_per_fiber.iter().map(|&c| c as usize))
        } else {
            Box::new(std::iter::repeat_n(1, n))
        };
        let (mut c, mut v, mut g) = (&centres[..3 * n], &mut vel[..], &mut grad[..]);
        for len in lengths {
            let (c0, c1) = c.split_at(3 * len);
            let (v0, v1) = std::mem::take(&mut v).split_at_mut(3 * len);
            let (g0, g1) = std::mem::take(&mut g).split_at_mut(9 * len);
            fibers.push((0, c0, v0, g0));
            (c, v, g) = (c1, v1, g1);
        }
    }
    // the keys and the sort in parallel too (serial, they would hold the other core idle);
    // the order of equal keys does not matter: every point
    // is sampled on its own into its own slot
    fibers
        .par_iter_mut()
        .with_min_len(4096)
        .for_each(|f| f.0 = if f.1.len() >= 3 { cell(&f.1[..3]) } else { 0 });
    fibers.par_sort_unstable_by_key(|f| f.0);
    // in cell order a fibre's arrays lie anywhere in the states and samples (tens of MB at
    // scale): the arrays of the fibre two ahead are fetched into cache while this one is
    // sampled (a third of the sampling time went to waiting for the centres)
    let per_task = fibers_per_task(fibers.len());
    fibers.par_chunks_mut(per_task).for_each(|chunk| {
        for i in 0..chunk.len() {
            if let Some((_, c, v, g)) = chunk.get(i + 2) {
                prefetch(c);
                prefetch(v);
                prefetch(g);
            }
            let (_, c, v, g) = &mut chunk[i];
            sample(c, v, g);
        }
    });
    out
}

/// Fibres per parallel task of the sampling loop: 64 at scale; fewer when the fibres are
/// few, so that the pool's second thread, woken after the first has started, still finds
/// tasks (at paper size 5 tasks of 64 kept it mostly idle: `sampling_s` over 300 steps
/// 0.111 / 0.119 / 0.116 s against 0.109 / 0.100 / 0.105 s with tasks of 16, alternated;
/// this rule gives 18).
fn fibers_per_task(fibers: usize) -> usize {
    (fibers / 16).clamp(8, 64)
}

/// Asks the CPU to bring `data` into cache (a hint: no effect on any value).
#[inline(always)]
pub(crate) fn prefetch(data: &[f64]) {
    #[cfg(target_arch = "x86_64")]
    for line in data.chunks(8) {
        // SAFETY: a prefetch never faults and changes no memory; the address is in `data`.
        unsafe {
            std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(
                line.as_ptr().cast(),
            )
        };
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = data;
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A sample that depends on every coordinate bit, so a point sampled into another
    /// point's slot shows.
    fn fake(p: &[f64]) -> PointSample {
        let h = p
            .iter()
            .fold(0u64, |h, x| (h ^ x.to_bits()).wrapping_mul(0x100_0000_01b3));
        let f = |s: u64| (h.rotate_left(s as u32) % 1000) as f64 + p[0];
        (
            [f(1), f(2), f(3)],
            [f(4), f(5), f(6), f(7), f(8), f(9), f(10), f(11), f(12)],
        )
    }

    /// Enough points for the per-step tables, in fibres of 1 to 9 segments (so every
    /// length of a last group of four): every point gets the direct sampler's bits, in its
    /// own slot, whether or not the buffers held other samples before.
    #[test]
    fn tables_four_at_a_time_give_the_direct_samples() {
        real_sampler_in_cell_order(TABLES_MIN_POINTS / 4);
    }

    /// The same below the tables' threshold: the real trilinear sampler in cell order over
    /// scrambled fibres of 1 to 9 segments gives every point its own direct sample, bit for
    /// bit (what `cell_order_gives_the_same_samples` checks with a synthetic sampler).
    #[test]
    fn cell_order_with_the_real_sampler_gives_the_direct_samples() {
        real_sampler_in_cell_order(700);
    }

    fn real_sampler_in_cell_order(fibers: usize) {
        let mut cfg = fiberflow_dns::DnsConfig::with_cells(16, 12, 8);
        cfg.init = fiberflow_dns::InitialField::Turbulent {
            amplitude: 0.3,
            seed: 5,
        };
        let solver = Solver::new(cfg.clone()).unwrap();
        let (g, re) = (solver.grid.clone(), solver.cfg.re_tau);
        let direct = Sampler::with_scheme(&g, Interpolation::Trilinear);
        let mut x = 0x9e37_79b9_7f4a_7c15u64;
        let mut rnd = move || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 11) as f64 / (1u64 << 53) as f64
        };
        let lens: Vec<u32> = (0..fibers).map(|k| 1 + (k % 9) as u32).collect();
        let n: usize = lens.iter().map(|&l| l as usize).sum();
        let centres: Vec<f64> = (0..n)
            .flat_map(|_| {
                [
                    (rnd() * 3.0 - 1.0) * g.lx * re,
                    (rnd() * 2.0 - 1.0) * re,
                    (rnd() * 3.0 - 1.0) * g.lz * re,
                ]
            })
            .collect();
        // the same field again (the initial field is seeded)
        let mut field = Field::dns(Solver::new(cfg).unwrap(), Interpolation::Trilinear);
        let stale = vec![(vec![f64::NAN; 3 * n], vec![f64::NAN; 9 * n])];
        for reuse in [Vec::new(), stale] {
            let out = field.sample_pieces(&[(&centres, &lens)], reuse);
            for (k, p) in centres.chunks_exact(3).enumerate() {
                let sm = direct.sample(&g, &solver.vel, [p[0] / re, p[1] / re, p[2] / re]);
                let grad = sm.grad.map(|x| x / re);
                let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(
                    bits(&out[0].0[3 * k..3 * k + 3]),
                    bits(&sm.vel),
                    "point {k}"
                );
                assert_eq!(bits(&out[0].1[9 * k..9 * k + 9]), bits(&grad), "point {k}");
            }
        }
    }

    /// Fibres of varied lengths in scrambled positions, sampled in cell order, give every
    /// point exactly its in-order sample; so do counts that do not add up (per point).
    #[test]
    fn cell_order_gives_the_same_samples() {
        let lens: Vec<u32> = (0..200).map(|k| 1 + (k * 7 % 9) as u32).collect();
        let n: usize = lens.iter().map(|&l| l as usize).sum();
        let centres: Vec<f64> = (0..3 * n)
            .map(|i| ((i * 7919) % 1013) as f64 * 0.37 - 100.0)
            .collect();
        let cell = |p: &[f64]| (p[2] + 200.0) as u64 * 1000 + (p[0] + 200.0) as u64;
        let want_v: Vec<f64> = centres.chunks(3).flat_map(|p| fake(p).0).collect();
        let want_g: Vec<f64> = centres.chunks(3).flat_map(|p| fake(p).1).collect();
        for counts in [&lens[..], &lens[1..], &[]] {
            let out = sample_fibers(&[(&centres, counts)], Vec::new(), cell, one_by_one(fake));
            assert_eq!(out, vec![(want_v.clone(), want_g.clone())]);
            // reused buffers, too short, too long or the right size with stale values,
            // give the same answer
            for len in [5, 3 * n, 20 * n] {
                let stale = vec![(vec![f64::NAN; len], vec![-1.0; 3 * len])];
                let out = sample_fibers(&[(&centres, counts)], stale, cell, one_by_one(fake));
                assert_eq!(out, vec![(want_v.clone(), want_g.clone())]);
            }
        }
        // several pieces sampled in one pass: each gets its own points' samples
        let (a, b) = centres.split_at(3 * 400);
        let out = sample_fibers(
            &[(a, &[]), (b, &lens[..3])],
            Vec::new(),
            cell,
            one_by_one(fake),
        );
        assert_eq!(out.len(), 2);
        assert_eq!(
            (&out[0].0[..], &out[0].1[..]),
            (&want_v[..1200], &want_g[..3600])
        );
        assert_eq!(
            (&out[1].0[..], &out[1].1[..]),
            (&want_v[1200..], &want_g[3600..])
        );
    }
}
