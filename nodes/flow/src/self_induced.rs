//! Two-way coupling's self-induced disturbance (docs/two-way.md, "Self-induced velocity").
//!
//! A fibre's force, spread onto the grid, disturbs the very velocity its segments then
//! sample; the drag laws (paper eq. 21–31) already hold the fibre's own disturbance, so
//! left in it counts twice (a settling case-1 fibre falls ≈ 15% too fast after 150 t+ on the
//! coarse grid, and the share grows over thousands of t+: `examples/settling.rs`). The flow
//! node removes an estimate of it from the samples, in the spirit of the exact regularised
//! point particles of Gualtieri et al. (JFM 2015): the fluid's response to a force impulse,
//! in unsteady Stokes flow, is a sum over wavenumbers k of modes that decay as e^{−ν|k̃|²s},
//! so the disturbance the fibre's own force history leaves at its centre is
//!   u_a(t) = Σ_k w_ka ∫ e^{−ν|k̃_k|²(t−τ)} F_a(τ) dτ / ρ,
//! a sum of [`MODES`] exponentially fading memories per fibre, each advanced exactly for a
//! force constant over a step; no force history is stored. The weights are those of the
//! grid the run uses: for a point spread with the three-point Roma–Peskin function and
//! sampled trilinearly (spectra φ̂(kΔ) and sinc²(kΔ/2) per direction), on the staggered
//! second-order grid (modified wavenumbers k̃ = 2 sin(kΔ/2)/Δ, which the discrete Laplacian
//! and projection share), over the wavenumbers the grid holds (|k_a Δ_a| ≤ π),
//!   w_ka = ∫ S(k) (1 − k̃_a²/|k̃|²) d³k/(2π)³   gathered by decay rate ν|k̃|² into the modes
//! (each share split between the two nearest modes so that its weight and its time integral,
//! the steady disturbance, are kept),
//! with the local spacings of the fibre's grid row. Far from the source's scale (small k)
//! this is the continuum's (2/3)(4πνs)^{−3/2} (test `long_time_tail_is_the_continuum`).
//!
//! Per fibre, not per segment: the memories hold the fibre's total force, shared equally
//! by its segments; segment i sees segment j's share through the mode's average of
//! e^{ik·r_ij}, sinc(√(3 Σ_b ⟨k_b²⟩ r_b²)) ([`crate::pair_shares`]), so a long fibre's force
//! is spread over its length and its ends see less of it than its middle. A fibre that
//! slips through the fluid leaves its disturbance behind (it drifts with the fluid): each
//! mode keeps the force-weighted mean and mean square of its impulses' offsets o behind the
//! fibre, advanced by the fibre's displacement less the fluid's, and counts
//! e^{−½ Σ_b ⟨k_b²⟩⟨o_b²⟩}. ⟨k_b²⟩ is the mean over the mode's actual wavenumbers (not the
//! modified ones that set its rate) as component a's weight weighs them: both factors are
//! exact to second order in r and o.
//!
//! Left out, said plainly: the correction's variation along the fibre (its effect on the
//! fibre's rotation and shape), the disturbance's gradient (∇v is left as sampled), the
//! walls' and periodic images' share of the fibre's own disturbance, and the phases of the
//! staggered components and of the point within its cell (spectra averaged over both).
//! The settling fibre measures what is left (docs/two-way.md).

use crate::pair_shares::add_pair;
use fiberflow_dns::Grid;
use rayon::prelude::*;

/// Memories per fibre: λ = |k̃|²/2 from 1e-8 to 1e2 per squared wall unit (decay rate 2νλ),
/// h = 0.5 in ln λ.
pub const MODES: usize = 47;
/// (mode, component) lanes of the pair shares.
const LANES: usize = 3 * MODES;
const LN_LAMBDA_MIN: f64 = -18.420_680_743_952_367; // ln 1e-8
const H: f64 = 0.5;

fn lambda(k: usize) -> f64 {
    (LN_LAMBDA_MIN + H * k as f64).exp()
}

/// Fourier transform of the three-point Roma–Peskin function at θ (radians per grid
/// spacing), by the midpoint rule over its support (it is even: a cosine transform).
fn roma_peskin_spectrum(theta: f64) -> f64 {
    let n = 600;
    let h = 3.0 / n as f64;
    (0..n)
        .map(|i| {
            let r = -1.5 + (i as f64 + 0.5) * h;
            fiberflow_dns::spread::roma_peskin(r) * (theta * r).cos() * h
        })
        .sum()
}

/// The spreading kernel's spectrum times the trilinear sampler's, at θ = k Δ.
fn spectrum(theta: f64) -> f64 {
    let x = 0.5 * theta;
    let sinc = if x.abs() < 1e-8 { 1.0 } else { x.sin() / x };
    roma_peskin_spectrum(theta) * sinc * sinc
}

/// Intervals of the tabulated [`spectrum`] over θ in [0, π].
const SPECTRUM_TABLE_N: usize = 512;

/// [`spectrum`] at θ = π i / [`SPECTRUM_TABLE_N`]: it depends on θ alone, not on the grid,
/// so every row's weights read one table, made once per process.
fn spectrum_table() -> &'static [f64] {
    static TABLE: std::sync::OnceLock<Vec<f64>> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        (0..=SPECTRUM_TABLE_N)
            .map(|i| spectrum(std::f64::consts::PI * i as f64 / SPECTRUM_TABLE_N as f64))
            .collect()
    })
}

/// The memories' weights w_ka for grid spacings `d` (wall units): the integral of the
/// module's documentation over the wavenumbers the grid holds, in spherical coordinates
/// (log-spaced radii, a Fibonacci sphere of 800 directions, 100 at the long waves where every
/// |k_b Δ_b| ≤ π/2), each contribution given to the two modes around its rate.
pub fn mode_weights(d: [f64; 3]) -> Modes {
    weights_by_quadrature(d, std::f64::consts::FRAC_PI_2)
}

/// [`mode_weights`] with the coarse set of directions where every |k_b Δ_b| ≤
/// `coarse_below` (0: the fine set everywhere).
fn weights_by_quadrature(d: [f64; 3], coarse_below: f64) -> Modes {
    // one spectrum table per direction: θ in [0, π], the same for every grid row
    let table = spectrum_table();
    let spec = |theta: f64| -> f64 {
        let x = theta.abs() / std::f64::consts::PI * SPECTRUM_TABLE_N as f64;
        let i = (x as usize).min(SPECTRUM_TABLE_N - 1);
        let t = x - i as f64;
        table[i] * (1.0 - t) + table[i + 1] * t
    };
    let k_max = std::f64::consts::PI * d.iter().map(|x| 1.0 / (x * x)).sum::<f64>().sqrt();
    let k_min = 1e-5 / d.iter().cloned().fold(0.0, f64::max);
    let nr = 400;
    let hr = (k_max / k_min).ln() / nr as f64;
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let sphere = |nd: usize| -> (Vec<[f64; 3]>, f64) {
        let dirs = (0..nd)
            .map(|i| {
                let z = 1.0 - 2.0 * (i as f64 + 0.5) / nd as f64;
                let r = (1.0 - z * z).sqrt();
                let phi = golden * i as f64;
                [r * phi.cos(), r * phi.sin(), z]
            })
            .collect();
        (dirs, 4.0 * std::f64::consts::PI / nd as f64)
    };
    // 800 directions where the grid's cut-off makes the integrand sharply anisotropic;
    // 100 where every |k_b Δ_b| ≤ π/2, where it is smooth on the sphere (most of the
    // log-spaced radii: the weights cost ≈ a third, test
    // `fewer_directions_at_long_waves_keep_the_weights`)
    let (fine, coarse) = (sphere(800), sphere(100));
    let d_max = d.iter().cloned().fold(0.0, f64::max);
    let norm = 1.0 / (2.0 * std::f64::consts::PI).powi(3);
    let mut w = [[0.0; 3]; MODES];
    // per mode: Σ c and Σ c n nᵀ (xx, yy, zz, xy, xz, yz) over its wavenumbers
    let mut dir_sum = [[[0.0; 4]; 3]; MODES];
    let lambdas: [f64; MODES] = std::array::from_fn(lambda);
    for ir in 0..nr {
        let k = (k_min.ln() + (ir as f64 + 0.5) * hr).exp();
        let (dirs, d_omega) = if k * d_max <= coarse_below {
            &coarse
        } else {
            &fine
        };
        let dv = k * k * (k * hr) * d_omega * norm;
        for dir in dirs {
            let theta = [0, 1, 2].map(|b| k * dir[b] * d[b]);
            if theta.iter().any(|t| t.abs() > std::f64::consts::PI) {
                continue;
            }
            let s = spec(theta[0]) * spec(theta[1]) * spec(theta[2]);
            let kt = [0, 1, 2].map(|b| 2.0 * (0.5 * theta[b]).sin() / d[b]);
            let q2 = kt[0] * kt[0] + kt[1] * kt[1] + kt[2] * kt[2];
            // split between the two modes around the rate so that the weight and the time
            // integral (weight / rate: the steady disturbance) are both kept
            let lam = 0.5 * q2;
            let x = (lam.ln() - LN_LAMBDA_MIN) / H;
            let (m, f) = if x <= 0.0 {
                (0, 0.0)
            } else if x >= (MODES - 1) as f64 {
                (MODES - 2, 1.0)
            } else {
                let m = x as usize;
                let (lo, hi) = (lambdas[m], lambdas[m + 1]);
                (m, (1.0 / lo - 1.0 / lam) / (1.0 / lo - 1.0 / hi))
            };
            let mut c = [0.0; 3];
            for a in 0..3 {
                c[a] = s * (1.0 - kt[a] * kt[a] / q2) * dv;
                w[m][a] += c[a] * (1.0 - f);
                w[m + 1][a] += c[a] * f;
            }
            // the wavenumber itself (not the modified one that sets the rate): e^{ik·r}
            // (⟨k kᵀ⟩ is diagonal: the spectrum is even in each component of k)
            let kk = dir.map(|x| k * k * x * x);
            for (mm, share) in [(m, 1.0 - f), (m + 1, f)] {
                for a in 0..3 {
                    dir_sum[mm][a][3] += c[a] * share;
                    for b in 0..3 {
                        dir_sum[mm][a][b] += c[a] * share * kk[b];
                    }
                }
            }
        }
    }
    let moments = std::array::from_fn(|m| {
        std::array::from_fn(|a| {
            let d = dir_sum[m][a];
            if d[3] > 0.0 {
                std::array::from_fn(|b| d[b] / d[3])
            } else {
                // a mode the grid does not hold: the isotropic shell of its rate
                [2.0 * lambda(m) / 3.0; 3]
            }
        })
    });
    let pair_coeff = std::array::from_fn(|b| {
        (0..LANES)
            .map(|q| (3.0 * moments[q / 3][q % 3][b]) as f32)
            .collect()
    });
    let held = |m: &usize| w[*m].iter().any(|x| *x != 0.0);
    let first = (0..MODES).find(held).unwrap_or(0);
    let end = (0..MODES).rev().find(held).map_or(first, |m| m + 1);
    Modes {
        weights: w,
        moments,
        pair_coeff,
        active: first..end,
    }
}

/// The memories' weights w_ka of a grid row, and per mode and component a the mean ⟨k_b²⟩
/// of its wavenumbers weighted as w_ka weighs them (b = x, y, z; per squared wall unit; the
/// other entries of ⟨k kᵀ⟩ vanish: the spectrum is even in each component of k).
#[derive(Debug, Clone)]
pub struct Modes {
    pub weights: [[f64; 3]; MODES],
    pub moments: [[[f64; 3]; 3]; MODES],
    /// The pair shares' coefficients (`pair_shares::add_pair`): plane b, lane 3k + a holds
    /// 3⟨k_b²⟩ of mode k, component a, so that sinc(√(Σ_b c_b r_b²)) is the mode's average
    /// of e^{ik·r} to second order in r (a shell's sinc(|k|r) is 1 − |k|²r²/6 + …).
    pub pair_coeff: [Vec<f32>; 3],
    /// The modes the grid holds (from the first to the last with a weight): the others
    /// carry nothing.
    pub active: std::ops::Range<usize>,
}

/// The memories' weights per grid row (nearest row of a point).
#[derive(Debug, Clone)]
pub struct Widths {
    rows_y: Vec<f64>,
    rows: Vec<Modes>,
    /// The modes some row holds (from the first of any row to the last): the memories of
    /// the others are never read, so they are not kept up.
    held: std::ops::Range<usize>,
}

impl Widths {
    pub fn new(g: &Grid, re_tau: f64) -> Self {
        let rows_y: Vec<f64> = (1..=g.ny).map(|j| g.yc[j]).collect();
        // the grid is symmetric about the centreline: the lower half's rows serve both
        let half: Vec<Modes> = (1..=g.ny.div_ceil(2))
            .into_par_iter()
            .map(|j| mode_weights([g.dx, g.dyf[j], g.dz].map(|x| x * re_tau)))
            .collect();
        let rows: Vec<Modes> = (1..=g.ny)
            .map(|j| half[j.min(g.ny + 1 - j) - 1].clone())
            .collect();
        let held = rows.iter().map(|m| m.active.start).min().unwrap_or(0)
            ..rows.iter().map(|m| m.active.end).max().unwrap_or(0);
        Self { rows_y, rows, held }
    }

    fn at(&self, y_outer: f64) -> &Modes {
        let j = self.rows_y.partition_point(|&y| y < y_outer);
        let j = match j {
            0 => 0,
            j if j >= self.rows_y.len() => self.rows_y.len() - 1,
            j if y_outer - self.rows_y[j - 1] < self.rows_y[j] - y_outer => j - 1,
            j => j,
        };
        &self.rows[j]
    }
}

/// From this many fibres in a piece on (≈ 16 MB of memories), the correction works in
/// tasks of 16 fibres and fetches each next fibre's memories ahead.
const PREFETCH_FROM_FIBERS: usize = 4096;

/// Values per fibre in [`History::memory`]: per mode its force memory (3), its weight, the
/// mean offset of its impulses behind the fibre (3) and their mean square offset (3); then
/// the fibre's last mean centre, the last mean fluid velocity it sampled (3 each) and
/// whether they are set.
pub const PER_FIBER: usize = 10 * MODES + 7;

/// The memories of every fibre of one piece ([`PER_FIBER`] each, fibre-major): the state
/// the correction carries from step to step (and in coupled checkpoints).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct History {
    pub memory: Vec<f64>,
}

impl History {
    /// Adds the fibre's own disturbance back to its sampled velocities, from the memories
    /// (the fluid's state at the samples' time), then books the forces the fluid receives
    /// over the next `dt_plus`. `centre` and `force` (F^h) in wall units, 3 per segment;
    /// `velocity` the samples, 3 per segment.
    pub fn correct_and_advance(
        &mut self,
        widths: &Widths,
        re_tau: f64,
        dt_plus: f64,
        segments_per_fiber: &[u32],
        centre: &[f64],
        force: &[f64],
        velocity: &mut [f64],
    ) {
        self.memory
            .resize(PER_FIBER * segments_per_fiber.len(), 0.0);
        // e^{−2νλ dt} and (1 − e^{−2νλ dt})/(2νλ)
        let fade: [(f64, f64); MODES] = std::array::from_fn(|k| {
            let a = 2.0 * lambda(k);
            let e = (-a * dt_plus).exp();
            (e, -(-a * dt_plus).exp_m1() / a)
        });
        // the fibres' segment ranges, then each fibre on its own (in parallel: every
        // fibre's arithmetic is its own, so the bits do not depend on the threads)
        let mut pieces = Vec::with_capacity(segments_per_fiber.len());
        let mut rest_v = velocity;
        let mut first = 0usize;
        for (&n, m) in segments_per_fiber
            .iter()
            .zip(self.memory.chunks_exact_mut(PER_FIBER))
        {
            let n = n as usize;
            let (v, tail) = std::mem::take(&mut rest_v).split_at_mut(3 * n);
            rest_v = tail;
            pieces.push((
                n,
                &centre[3 * first..3 * (first + n)],
                &force[3 * first..3 * (first + n)],
                v,
                m,
            ));
            first += n;
        }
        // many fibres (their memories, ≈ 4 kB a fibre, beyond the caches): the memories of
        // the fibre after this one are fetched into cache while this one is worked on (its
        // pair shares are the bulk of the work); few: a fibre a task, which balances the
        // threads best
        let per_task = if pieces.len() >= PREFETCH_FROM_FIBERS {
            16
        } else {
            1
        };
        pieces
            .par_chunks_mut(per_task)
            .for_each_init(Vec::new, |share, chunk| {
                for i in 0..chunk.len() {
                    if let Some((_, c, f, v, m)) = chunk.get(i + 1) {
                        crate::sampling::prefetch(m);
                        crate::sampling::prefetch(c);
                        crate::sampling::prefetch(f);
                        crate::sampling::prefetch(v);
                    }
                    let (n, c, f, v, m) = &mut chunk[i];
                    fiber(widths, re_tau, dt_plus, &fade, *n, c, f, v, m, share);
                }
            });
    }
}

/// One fibre's correction and advance ([`History::correct_and_advance`]): `centre`,
/// `force` and `velocity` its segments' (3 each), `m` its [`PER_FIBER`] memories.
/// Long (≈105 lines): the correction's steps for one fibre's segments, in order.
fn fiber(
    widths: &Widths,
    re_tau: f64,
    dt_plus: f64,
    fade: &[(f64, f64); MODES],
    n: usize,
    centre: &[f64],
    force: &[f64],
    velocity: &mut [f64],
    m: &mut [f64],
    share: &mut Vec<f32>,
) {
    let segs = 0..n;
    let mut mean = [0.0; 3];
    let mut total = [0.0; 3];
    for i in segs.clone() {
        for a in 0..3 {
            mean[a] += centre[3 * i + a] / n as f64;
            total[a] += force[3 * i + a];
        }
    }
    // offsets between the fibre's segment centres
    let gap = |i: usize, j: usize| -> [f64; 3] {
        [0, 1, 2].map(|a| centre[3 * i + a] - centre[3 * j + a])
    };
    let w = widths.at(mean[1] / re_tau);
    let (forces, rest) = m.split_at_mut(3 * MODES);
    let (weight, rest) = rest.split_at_mut(MODES);
    let (offset, rest) = rest.split_at_mut(3 * MODES);
    let (square, last) = rest.split_at_mut(3 * MODES);
    // the fibre's slip since the last step: its own displacement less the fluid's
    // (the disturbance drifts with the fluid); the past impulses now lie that much
    // further behind
    let mut slip = [0.0; 3];
    if last[6] != 0.0 {
        for a in 0..3 {
            slip[a] = mean[a] - last[a] - dt_plus * last[3 + a];
        }
    }
    // per mode: its wavenumbers seen from the impulses' offsets o behind the fibre
    // average e^{ik·o} to e^{−½ Σ_b ⟨k_b²⟩⟨o_b²⟩} (second order in o)
    // (modes no row holds are skipped: a fibre's row changes, the modes any row holds
    // are kept up in every row)
    let held = widths.held.clone();
    // per (mode, component) lane: −½ Σ_b ⟨k_b²⟩⟨o_b²⟩, then its exponential, all lanes at
    // once (`fast_exp`)
    let mut drift = [0.0; LANES];
    for k in held.clone() {
        for b in 0..3 {
            let (o, s) = (&mut offset[3 * k + b], slip[b]);
            square[3 * k + b] += (2.0 * *o + s) * s;
            *o += s;
        }
        if !w.active.contains(&k) {
            continue;
        }
        for a in 0..3 {
            let m = &w.moments[k][a];
            let spread: f64 = (0..3).map(|b| m[b] * square[3 * k + b]).sum();
            drift[3 * k + a] = -0.5 * spread;
        }
    }
    crate::fast_exp::exp_in_place(&mut drift[3 * w.active.start..3 * w.active.end]);
    let mut mode = [[0.0; 3]; MODES];
    for k in w.active.clone() {
        for a in 0..3 {
            mode[k][a] = drift[3 * k + a] * w.weights[k][a] * forces[3 * k + a];
        }
    }
    // segment i gets segment j's share of the force (1/n of it) through the mode's
    // average of e^{ik·r_ij} (each pair once; only the modes the grid holds)
    let lanes = 3 * w.active.start..3 * w.active.end;
    share.clear();
    share.resize(n * LANES, 1.0);
    for i in 0..n {
        for j in i + 1..n {
            let r2 = gap(i, j).map(|x| (x * x) as f32);
            let (lo, hi) = share.split_at_mut(j * LANES);
            add_pair(
                &w.pair_coeff,
                lanes.clone(),
                r2,
                &mut lo[i * LANES..(i + 1) * LANES],
                &mut hi[..LANES],
            );
        }
    }
    let mut fluid = [0.0; 3];
    for (i, seg) in segs.clone().enumerate() {
        let mut du = [0.0; 3];
        for (k, mk) in mode
            .iter()
            .enumerate()
            .take(w.active.end)
            .skip(w.active.start)
        {
            for a in 0..3 {
                du[a] += share[i * LANES + 3 * k + a] as f64 * mk[a];
            }
        }
        // each segment gets 1/n of the fibre's force: one division per component
        for a in 0..3 {
            velocity[3 * seg + a] += du[a] / n as f64;
            fluid[a] += velocity[3 * seg + a] / n as f64;
        }
    }
    // the step's impulse enters every memory at offset 0; the offsets are the
    // memories' force-weighted mean positions behind the fibre
    let size = (total[0] * total[0] + total[1] * total[1] + total[2] * total[2]).sqrt();
    for (k, &(e, g)) in fade.iter().enumerate().take(held.end).skip(held.start) {
        for a in 0..3 {
            forces[3 * k + a] = e * forces[3 * k + a] + g * total[a];
        }
        let old = e * weight[k];
        let new = old + g * size;
        if new > 0.0 {
            for b in 0..3 {
                offset[3 * k + b] *= old / new;
                square[3 * k + b] *= old / new;
            }
        }
        weight[k] = new;
    }
    last[..3].copy_from_slice(&mean);
    last[3..6].copy_from_slice(&fluid);
    last[6] = 1.0;
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The kernel Σ_k w_ka e^{−2λ_k s} of a grid tends, at long times, to the continuum's
    /// (2/3)(4πs)^{−3/2} (wall units, ν = 1; at s = 10^4 t+ on the coarse grid's spacings,
    /// 3% pointwise, the binning into modes, and 1% for its integral from s on);
    /// at s = 0 it is near the Gaussian of the same variance (measured 1.07 times it, x
    /// component: the spreading and sampling spectra are broader than a Gaussian's, and
    /// the grid holds no wavenumber beyond π/Δ; the test asks 0.9–1.15).
    #[test]
    fn long_time_tail_is_the_continuum() {
        let d = [14.7, 7.0, 7.4];
        let w = mode_weights(d).weights;
        let kernel = |s: f64, a: usize| -> f64 {
            (0..MODES)
                .map(|k| w[k][a] * (-2.0 * lambda(k) * s).exp())
                .sum()
        };
        let c = (2.0 / 3.0) * (4.0 * std::f64::consts::PI).powf(-1.5);
        for a in 0..3 {
            let s: f64 = 1e4;
            let want = c * s.powf(-1.5);
            assert!(
                (kernel(s, a) / want - 1.0).abs() < 0.03,
                "{a}: {} vs {want}",
                kernel(s, a)
            );
            // the disturbance a force leaves after T: ∫_T^∞ K = 2c/√T
            let tail: f64 = (0..MODES)
                .map(|k| w[k][a] * (-2.0 * lambda(k) * s).exp() / (2.0 * lambda(k)))
                .sum();
            let want = 2.0 * c / s.sqrt();
            assert!(
                (tail / want - 1.0).abs() < 0.01,
                "{a}: tail {tail} vs {want}"
            );
        }
        let var = 0.298 + 1.0 / 6.0;
        let sigma2 = d.iter().map(|x| var * x * x).product::<f64>().cbrt();
        let gaussian = (2.0 / 3.0) * (2.0 * std::f64::consts::PI * sigma2).powf(-1.5);
        let ratio = kernel(0.0, 0) / gaussian;
        assert!(
            ratio > 0.9 && ratio < 1.15,
            "K(0) / the Gaussian's = {ratio}"
        );
    }

    /// The weights with 100 directions where every |k_b Δ_b| ≤ π/2 are those with 800
    /// everywhere: each mode's weight within 1e-5 of the component's total weight
    /// (measured 5e-6), its wavenumber moments within 1e-3 (measured 4.5e-4) where its
    /// weight is at least 1e-3 of the total, for rows by the wall and at the centre of both
    /// grids.
    #[test]
    fn fewer_directions_at_long_waves_keep_the_weights() {
        let mut worst = [0.0f64; 2];
        for d in [
            [14.7, 0.33, 7.4],
            [14.7, 12.0, 7.4],
            [4.9, 0.33, 7.4],
            [4.9, 12.0, 7.4],
        ] {
            let (a, b) = (mode_weights(d), weights_by_quadrature(d, 0.0));
            assert_eq!(a.active, b.active, "{d:?}");
            for c in 0..3 {
                let total: f64 = (0..MODES).map(|k| b.weights[k][c]).sum();
                for k in 0..MODES {
                    let dw = (a.weights[k][c] - b.weights[k][c]).abs() / total;
                    worst[0] = worst[0].max(dw);
                    if b.weights[k][c] >= 1e-3 * total {
                        for e in 0..3 {
                            let (x, y) = (a.moments[k][c][e], b.moments[k][c][e]);
                            worst[1] = worst[1].max((x / y - 1.0).abs());
                        }
                    }
                }
            }
        }
        eprintln!("worst: weight {:e}, moment {:e}", worst[0], worst[1]);
        assert!(worst[0] < 1e-5 && worst[1] < 1e-3, "{worst:?}");
    }

    /// The modes whose memories are not kept up weigh nothing in any row of the coarse and
    /// the fine grid, so leaving them out changes no correction (exactly: each mode's
    /// memories are their own); measured, the fine grid's rows hold 0 of them.
    #[test]
    fn modes_no_row_holds_weigh_nothing_in_any_row() {
        for nx in [64, 192] {
            let pi = std::f64::consts::PI;
            let g = Grid::new(nx, 64, 64, 2.0 * pi, pi, 150.0, Some(0.33)).unwrap();
            let widths = Widths::new(&g, 150.0);
            let held = widths.held.clone();
            for row in &widths.rows {
                for k in (0..MODES).filter(|k| !held.contains(k)) {
                    assert_eq!(row.weights[k], [0.0; 3], "{nx}: mode {k}");
                }
                assert!(held.start <= row.active.start && row.active.end <= held.end);
            }
            eprintln!("{nx}: modes held {held:?} of {MODES}");
        }
    }

    /// A fibre slipping steadily by s a step: each mode's memories hold the force-weighted
    /// mean and mean square of its impulses' offsets behind the fibre, Σ w_j j s / Σ w_j and
    /// Σ w_j (j s)² / Σ w_j with w_j = e^{−2λ_k Δt j} (1e-12 relative). The drift factor is
    /// then exact to second order in the offsets: a mean offset alone under-counts a trail's
    /// spread (for an exponential trail by half).
    #[test]
    fn memories_keep_the_mean_square_offset_of_a_slipping_fiber() {
        let g = Grid::with_stretch(8, 8, 8, 1.0, 1.0, 0.0).unwrap();
        let widths = Widths::new(&g, 150.0);
        let (dt, s, steps) = (0.2, 0.3, 60);
        let spf = [1u32];
        let force = [1.0, 0.5, 0.0];
        let mut centre = [10.0, 0.0, 5.0];
        let mut h = History::default();
        for _ in 0..steps {
            let mut v = [0.01, 0.0, 0.02];
            h.correct_and_advance(&widths, 150.0, dt, &spf, &centre, &force, &mut v);
            // next: carried by the (corrected) fluid, and slipped by s along x
            centre = [0, 1, 2].map(|a| centre[a] + dt * v[a] + if a == 0 { s } else { 0.0 });
        }
        // the modes some row holds (the others' memories are not kept up)
        let held = widths.held.clone();
        assert!(held.len() >= 3, "{held:?}");
        for k in [held.start, (held.start + held.end) / 2, held.end - 1] {
            let e = (-2.0 * lambda(k) * dt).exp();
            let w: Vec<f64> = (0..steps).map(|j| e.powi(j)).collect();
            let sum: f64 = w.iter().sum();
            let mean: f64 = w
                .iter()
                .enumerate()
                .map(|(j, w)| w * j as f64 * s)
                .sum::<f64>()
                / sum;
            let square: f64 = w
                .iter()
                .enumerate()
                .map(|(j, w)| w * (j as f64 * s).powi(2))
                .sum::<f64>()
                / sum;
            let offset = h.memory[4 * MODES + 3 * k];
            let sq = h.memory[7 * MODES + 3 * k];
            assert!(
                (offset / mean - 1.0).abs() < 1e-12,
                "{k}: {offset} vs {mean}"
            );
            assert!((sq / square - 1.0).abs() < 1e-12, "{k}: {sq} vs {square}");
            // nothing moved along y and z
            assert!(h.memory[7 * MODES + 3 * k + 1].abs() < 1e-20);
        }
    }

    /// A piece of many fibres (worked in tasks of 16 with the next fibre's memories fetched
    /// ahead) gives each fibre the bits it gets in a piece of few (a fibre a task), over
    /// three steps: the fetching changes no value.
    #[test]
    fn many_fibers_in_a_piece_give_the_bits_of_few() {
        let g = Grid::with_stretch(16, 16, 16, 6.0, 3.0, 0.0).unwrap();
        let widths = Widths::new(&g, 150.0);
        let fibers = PREFETCH_FROM_FIBERS + 7;
        let mut rng = fiberflow_dns::init::SplitMix64::new(0x2545_f491);
        let mut rnd = move || 0.5 * (rng.symmetric() + 1.0);
        let spf = vec![7u32; fibers];
        let (mut centre, mut force) = (Vec::new(), Vec::new());
        for _ in 0..fibers {
            let c = [rnd() * 900.0, rnd() * 270.0 - 135.0, rnd() * 450.0];
            for s in 0..7 {
                centre
                    .extend((0..3).map(|a| c[a] + 3.0 * s as f64 * if a == 0 { 1.0 } else { 0.3 }));
                force.extend((0..3).map(|_| rnd() - 0.5));
            }
        }
        let (mut whole, mut parts) = (History::default(), vec![History::default(); 5]);
        let per_part = fibers.div_ceil(5);
        for step in 0..3 {
            let mut v_whole = vec![0.01 * step as f64; centre.len()];
            whole.correct_and_advance(&widths, 150.0, 0.2, &spf, &centre, &force, &mut v_whole);
            let mut v_parts = vec![0.01 * step as f64; centre.len()];
            for (p, h) in parts.iter_mut().enumerate() {
                let fs = p * per_part..((p + 1) * per_part).min(fibers);
                let seg = 21 * fs.start..21 * fs.end;
                h.correct_and_advance(
                    &widths,
                    150.0,
                    0.2,
                    &spf[fs.clone()],
                    &centre[seg.clone()],
                    &force[seg.clone()],
                    &mut v_parts[seg],
                );
            }
            assert!(v_whole
                .iter()
                .zip(&v_parts)
                .all(|(a, b)| a.to_bits() == b.to_bits()));
        }
        let joined: Vec<f64> = parts
            .iter()
            .flat_map(|h| h.memory.iter().copied())
            .collect();
        assert!(whole
            .memory
            .iter()
            .zip(&joined)
            .all(|(a, b)| a.to_bits() == b.to_bits()));
    }

    /// A constant force's correction after a time T is the kernel's integral
    /// Σ_k w_ka (1 − e^{−2λ_k T})/(2λ_k) (1e-9: the slip the test's samples leave, a
    /// step's change of the correction, moves the impulses a little), and the memories
    /// advance exactly: two steps of dt equal one of 2 dt (1e-12).
    #[test]
    fn constant_force_builds_up_the_kernel_integral() {
        let g = Grid::with_stretch(8, 8, 8, 1.0, 1.0, 0.0).unwrap();
        let widths = Widths::new(&g, 150.0);
        let w = widths.at(0.0).weights;
        let spf = [1u32];
        let centre = [0.0, 0.0, 0.0];
        let force = [1.0, 0.0, 0.0];
        // the samples hold the disturbance the correction removes (that of the step before,
        // which it changes little), so the corrected fluid is at rest and the fibre does
        // not slip: its impulses stay where it is
        let mut h = History::default();
        let mut last = 0.0;
        for _ in 0..1000 {
            let mut v = [-last, 0.0, 0.0];
            h.correct_and_advance(&widths, 150.0, 10.0, &spf, &centre, &force, &mut v);
            last += v[0];
        }
        let mut v = [0.0; 3];
        h.correct_and_advance(&widths, 150.0, 10.0, &spf, &centre, &force, &mut v);
        let want: f64 = (0..MODES)
            .map(|k| {
                let r = 2.0 * lambda(k);
                w[k][0] * -(-r * 1e4).exp_m1() / r
            })
            .sum();
        assert!((v[0] / want - 1.0).abs() < 1e-9, "{} vs {want}", v[0]);
        let (mut a, mut b) = (History::default(), History::default());
        let mut sink = [0.0; 3];
        a.correct_and_advance(&widths, 150.0, 0.4, &spf, &centre, &force, &mut sink);
        b.correct_and_advance(&widths, 150.0, 0.2, &spf, &centre, &force, &mut sink);
        b.correct_and_advance(&widths, 150.0, 0.2, &spf, &centre, &force, &mut sink);
        // the force memories (the offsets depend on the samples, which differ here)
        for (x, y) in a.memory[..3 * MODES].iter().zip(&b.memory[..3 * MODES]) {
            assert!((x - y).abs() <= 1e-12 * x.abs().max(1e-300), "{x} vs {y}");
        }
    }
}
