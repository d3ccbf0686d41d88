//! Sampling the flow at every segment centre of a group's state. Fibres are visited in
//! the order of the grid cell of their first segment, so fibres close in space are sampled
//! one after the other and the field's neighbouring planes stay in cache; every point is
//! sampled on its own, so the order changes no bit of the result
//! (test `cell_order_gives_the_same_samples`).

use rayon::prelude::*;

/// One point's sample: velocity and `grad[3a + b] = ∂v_a/∂x_b`.
pub type PointSample = ([f64; 3], [f64; 9]);

/// Velocity (3 per point) and gradient (9 per point) at `centres` (3 per point), in the
/// points' order. `segments_per_fiber` groups the points into fibres (if it does not add
/// up to the points, each point counts as its own fibre); `cell` gives a point's sort key.
pub fn sample_fibres(
    centres: &[f64],
    segments_per_fiber: &[u32],
    cell: impl Fn(&[f64]) -> u64 + Sync,
    sample: impl Fn(&[f64]) -> PointSample + Sync,
) -> (Vec<f64>, Vec<f64>) {
    let n = centres.len() / 3;
    let mut vel = vec![0.0; 3 * n];
    let mut grad = vec![0.0; 9 * n];
    let counted: u64 = segments_per_fiber.iter().map(|&c| c as u64).sum();
    let lengths: Box<dyn Iterator<Item = usize>> = if counted == n as u64 {
        Box::new(segments_per_fiber.iter().map(|&c| c as usize))
    } else {
        Box::new(std::iter::repeat_n(1, n))
    };
    let mut fibres = Vec::with_capacity(segments_per_fiber.len().max(1));
    let (mut c, mut v, mut g) = (&centres[..3 * n], &mut vel[..], &mut grad[..]);
    for len in lengths {
        let (c0, c1) = c.split_at(3 * len);
        let (v0, v1) = std::mem::take(&mut v).split_at_mut(3 * len);
        let (g0, g1) = std::mem::take(&mut g).split_at_mut(9 * len);
        let key = if len > 0 { cell(&c0[..3]) } else { 0 };
        fibres.push((key, c0, v0, g0));
        (c, v, g) = (c1, v1, g1);
    }
    fibres.sort_unstable_by_key(|f| f.0);
    fibres
        .par_iter_mut()
        .with_min_len(32)
        .for_each(|(_, c, v, g)| {
            for ((p, vo), go) in c
                .chunks_exact(3)
                .zip(v.chunks_exact_mut(3))
                .zip(g.chunks_exact_mut(9))
            {
                let (sv, sg) = sample(p);
                vo.copy_from_slice(&sv);
                go.copy_from_slice(&sg);
            }
        });
    (vel, grad)
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
            let (v, g) = sample_fibres(&centres, counts, cell, fake);
            assert_eq!(v, want_v);
            assert_eq!(g, want_g);
        }
    }
}
