//! A fixed amount of trilinear sampling (10⁵ samples at 10³ points spread over a 32³
//! turbulent channel field), for counting the sampler's instructions, which unlike its
//! time do not depend on the host's load:
//!
//! ```text
//! cargo build --release -p fiberflow-dns --example sample_instructions
//! valgrind --tool=callgrind --toggle-collect='*sample_instructions*sample_all*' \
//!     target/release/examples/sample_instructions
//! ```
//!
//! It prints a checksum of the samples, so two builds can also be checked for the same
//! bits.

use fiberflow_dns::sample::Sampler;
use fiberflow_dns::{DnsConfig, InitialField, Solver};

/// Samples every point 100 times; the sum of two sampled quantities.
#[inline(never)]
fn sample_all(smp: &Sampler, s: &Solver, points: &[[f64; 3]]) -> f64 {
    let mut sum = 0.0;
    for _ in 0..100 {
        for p in points {
            let x = smp.sample(&s.grid, &s.vel, *p);
            sum += x.grad[4] + x.vel[0];
        }
    }
    sum
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut cfg = DnsConfig::with_cells(32, 32, 32);
    cfg.init = InitialField::Turbulent {
        amplitude: 0.25,
        seed: 1,
    };
    let s = Solver::new(cfg)?;
    let smp = Sampler::new(&s.grid);
    let mut x = 1u64;
    let mut uniform = || {
        x = x
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (x >> 11) as f64 / (1u64 << 53) as f64
    };
    let points: Vec<[f64; 3]> = (0..1000)
        .map(|_| {
            [
                uniform() * s.grid.lx,
                uniform() * 1.998 - 0.999,
                uniform() * s.grid.lz,
            ]
        })
        .collect();
    println!("checksum {}", sample_all(&smp, &s, &points));
    Ok(())
}
