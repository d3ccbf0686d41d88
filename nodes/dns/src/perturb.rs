//! Realisations: a seeded, divergence-free disturbance that gives a run its own start
//! from a shared field (docs/realisations.md).
//!
//! Each velocity component gets a sum of the box's longest waves, (k_x, k_z) with
//! 0 ≤ k_x, k_z ≤ [`LONGEST_WAVES`] and not both zero, each with a seeded amplitude and
//! phase, times a wall envelope 1 − y² (zero on the walls); the sum is scaled to
//! [`DISTURBANCE_RMS`] per component and added, and the solver then projects the field
//! and restores the held flow rate. The mean profile (k = 0) is left alone. Wall
//! turbulence amplifies a disturbance this small within tens of t+, so two realisations
//! decorrelate over a run's transient while their statistics are those of the same flow
//! (test `two_realisations_decorrelate_and_agree`).

use crate::field::Velocity;
use crate::grid::Grid;
use crate::init::SplitMix64;

/// Root-mean-square of each component of the disturbance before the projection, in u_tau.
pub const DISTURBANCE_RMS: f64 = 0.1;
/// Largest wave number (waves per box) in x and in z.
pub const LONGEST_WAVES: usize = 3;

/// The seed of realisation `realisation` drawn from `base`: realisation 0 keeps `base`,
/// others mix both (SplitMix64), so a run's seeds stay as configured unless a realisation
/// is asked for.
pub fn realisation_seed(base: u64, realisation: u32) -> u64 {
    if realisation == 0 {
        return base;
    }
    let mut rng = SplitMix64::new(base ^ (u64::from(realisation) << 32 | u64::from(realisation)));
    rng.next_u64()
}

/// One wave: amplitude, phase and wave numbers (waves per box).
struct Wave {
    amplitude: f64,
    phase: f64,
    kx: usize,
    kz: usize,
}

fn waves(rng: &mut SplitMix64) -> Vec<Wave> {
    let mut out = Vec::new();
    for kx in 0..=LONGEST_WAVES {
        for kz in 0..=LONGEST_WAVES {
            if kx == 0 && kz == 0 {
                continue;
            }
            out.push(Wave {
                amplitude: rng.symmetric(),
                phase: std::f64::consts::PI * rng.symmetric(),
                kx,
                kz,
            });
        }
    }
    out
}

/// Which staggered position a component sits at.
#[derive(Clone, Copy)]
enum At {
    U,
    V,
    W,
}

/// Adds the disturbance of `seed` to the interior of `vel` (halos are the caller's; the
/// field is not divergence-free until projected).
pub fn add_disturbance(g: &Grid, seed: u64, vel: &mut Velocity) {
    let mut rng = SplitMix64::new(seed);
    for (at, comp) in [
        (At::U, &mut vel.u),
        (At::V, &mut vel.v),
        (At::W, &mut vel.w),
    ] {
        let ws = waves(&mut rng);
        let mut d = vec![0.0; g.px * g.py * g.pz];
        let mut sum_sq = 0.0;
        let mut count = 0usize;
        for k in 1..=g.nz {
            let z = match at {
                At::W => k as f64 * g.dz,
                _ => (k as f64 - 0.5) * g.dz,
            };
            for j in 1..=g.ny {
                let y = match at {
                    At::V => g.yf[j],
                    _ => g.yc[j],
                };
                let envelope = 1.0 - y * y;
                for i in 1..=g.nx {
                    let x = match at {
                        At::U => i as f64 * g.dx,
                        _ => (i as f64 - 0.5) * g.dx,
                    };
                    let s: f64 = ws
                        .iter()
                        .map(|w| {
                            let arg = std::f64::consts::TAU
                                * (w.kx as f64 * x / g.lx + w.kz as f64 * z / g.lz)
                                + w.phase;
                            w.amplitude * arg.cos()
                        })
                        .sum();
                    let value = if matches!(at, At::V) && j == g.ny {
                        0.0
                    } else {
                        envelope * s
                    };
                    d[g.idx(i, j, k)] = value;
                    sum_sq += value * value;
                    count += 1;
                }
            }
        }
        let rms = (sum_sq / count.max(1) as f64).sqrt();
        let scale = if rms > 0.0 {
            DISTURBANCE_RMS / rms
        } else {
            0.0
        };
        for k in 1..=g.nz {
            for j in 1..=g.ny {
                for i in 1..=g.nx {
                    let n = g.idx(i, j, k);
                    comp[n] += scale * d[n];
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{DnsConfig, Forcing, InitialField};
    use crate::field::{bulk_mean, Velocity};
    use crate::Solver;

    fn solver() -> Solver {
        let cfg = DnsConfig {
            init: InitialField::Turbulent {
                amplitude: 0.3,
                seed: 7,
            },
            forcing: Forcing::FlowRate {
                bulk_velocity: 15.0,
            },
            ..DnsConfig::with_cells(24, 24, 16)
        };
        Solver::new(cfg).expect("solver")
    }

    fn rms_difference(g: &Grid, a: &[f64], b: &[f64]) -> f64 {
        let mut s = 0.0;
        let mut n = 0usize;
        for k in 1..=g.nz {
            for j in 1..=g.ny {
                for i in 1..=g.nx {
                    let d = a[g.idx(i, j, k)] - b[g.idx(i, j, k)];
                    s += d * d;
                    n += 1;
                }
            }
        }
        (s / n as f64).sqrt()
    }

    /// The disturbed field is divergence-free to round-off, holds the flow rate, is the
    /// same bits for the same seed and differs by ≈ [`DISTURBANCE_RMS`] per component from
    /// the field it started from (within ±50%: the projection removes part of it).
    #[test]
    fn a_disturbance_is_divergence_free_keeps_the_flow_rate_and_repeats() {
        let base = solver();
        let ub = bulk_mean(&base.grid, &base.vel.u);
        let disturbed = |seed: u64| {
            let mut s = solver();
            s.perturb(seed);
            s
        };
        let a = disturbed(realisation_seed(11, 1));
        let a2 = disturbed(realisation_seed(11, 1));
        let b = disturbed(realisation_seed(11, 2));
        let g = &a.grid;
        assert!(
            crate::correct::max_divergence(g, &a.vel) < 1e-9,
            "divergence {}",
            crate::correct::max_divergence(g, &a.vel)
        );
        assert!((bulk_mean(g, &a.vel.u) - ub).abs() < 1e-12);
        assert_eq!(a.vel.u, a2.vel.u);
        assert_eq!(a.vel.v, a2.vel.v);
        assert_eq!(a.vel.w, a2.vel.w);
        for (x, y) in [
            (&a.vel.u, &base.vel.u),
            (&a.vel.v, &base.vel.v),
            (&a.vel.w, &base.vel.w),
        ] {
            let d = rms_difference(g, x, y);
            assert!(
                (0.5 * DISTURBANCE_RMS..=1.5 * DISTURBANCE_RMS).contains(&d),
                "rms difference {d}"
            );
        }
        // two independent disturbances: ≈ √2 times one apart
        let d = rms_difference(g, &a.vel.u, &b.vel.u);
        assert!(
            (0.7 * DISTURBANCE_RMS..=2.0 * DISTURBANCE_RMS).contains(&d),
            "rms difference of two realisations {d}"
        );
        // the no-penetration face stays shut
        for k in 1..=g.nz {
            for i in 1..=g.nx {
                assert_eq!(a.vel.v[g.idx(i, g.ny, k)], 0.0);
            }
        }
    }

    /// The streamwise fluctuation's correlation between two fields over the interior.
    fn correlation(g: &Grid, a: &Velocity, b: &Velocity) -> f64 {
        let fluct = |v: &Velocity| -> Vec<f64> {
            let mut out = Vec::new();
            for j in 1..=g.ny {
                let mut row = Vec::new();
                for k in 1..=g.nz {
                    for i in 1..=g.nx {
                        row.push(v.u[g.idx(i, j, k)]);
                    }
                }
                let m = row.iter().sum::<f64>() / row.len() as f64;
                out.extend(row.iter().map(|x| x - m));
            }
            out
        };
        let (x, y) = (fluct(a), fluct(b));
        let dot = |p: &[f64], q: &[f64]| p.iter().zip(q).map(|(a, b)| a * b).sum::<f64>();
        dot(&x, &y) / (dot(&x, &x) * dot(&y, &y)).sqrt()
    }

    /// Two realisations of the shipped coarse field, stepped side by side: they start as
    /// nearly the same flow (u' correlated above 0.99), decorrelate as the turbulence
    /// amplifies the disturbance (below 0.4 after 200 t+), and their statistics agree: Re_tau
    /// from the wall shear, averaged over t+ 50–200, within 2% of each other and of 150.
    #[test]
    fn two_realisations_decorrelate_and_agree() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../recordings/samples/coarse-re150.ckpt");
        let dt_plus = 0.25;
        let open = |realisation: u32| {
            let mut cfg = DnsConfig::coarse();
            cfg.dt_fixed_plus = Some(dt_plus);
            let mut s = Solver::new(cfg).expect("solver");
            s.read_checkpoint(&path).expect("the shipped coarse field");
            s.perturb(realisation_seed(5, realisation));
            s
        };
        let (mut a, mut b) = (open(1), open(2));
        let start = correlation(&a.grid, &a.vel, &b.vel);
        assert!(start > 0.99, "start correlation {start}");
        let mut re = [0.0, 0.0];
        let mut samples = 0;
        let steps = (200.0 / dt_plus) as usize;
        for n in 1..=steps {
            a.step().expect("step");
            b.step().expect("step");
            if n as f64 * dt_plus >= 50.0 && n % 4 == 0 {
                re[0] += crate::stats::wall_re_tau(&a.grid, &a.vel, 150.0);
                re[1] += crate::stats::wall_re_tau(&b.grid, &b.vel, 150.0);
                samples += 1;
            }
        }
        let end = correlation(&a.grid, &a.vel, &b.vel);
        let re = re.map(|r| r / samples as f64);
        eprintln!("start {start:.4}, end {end:.3}, Re_tau {re:?}");
        assert!(end < 0.4, "end correlation {end}");
        assert!((re[0] - re[1]).abs() < 0.02 * re[0], "Re_tau {re:?}");
        for r in re {
            assert!((r - 150.0).abs() < 0.02 * 150.0, "Re_tau {re:?}");
        }
    }

    #[test]
    fn realisation_zero_keeps_the_configured_seed() {
        assert_eq!(realisation_seed(42, 0), 42);
        assert_ne!(realisation_seed(42, 1), 42);
        assert_ne!(realisation_seed(42, 1), realisation_seed(42, 2));
        assert_ne!(realisation_seed(42, 1), realisation_seed(43, 1));
    }
}
