//! Which fibres a scene shows: every fibre of a small group; for a large one a sample
//! stratified by initial layer (each layer in proportion to its share, evenly spread over
//! the layer's fibres) plus the most coiled fibres at the end of the run, so a scene of a
//! 10^4-fibre case stays small and still shows what coils.

/// How many fibres per case the scene shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Sampling {
    /// Fibres per case in the stratified sample (a group this small or smaller is shown whole).
    pub per_case: usize,
    /// The most coiled fibres (largest final σ²) added on top of the sample.
    pub most_coiled: usize,
}

impl Default for Sampling {
    fn default() -> Self {
        Self {
            per_case: 300,
            most_coiled: 20,
        }
    }
}

/// Indices of the fibres to show, ordered by initial layer and then by final σ² (ties by
/// index): the gallery's order. `layer[f]` and `final_sigma2[f]` describe fibre `f`.
pub fn choose(layer: &[u8], final_sigma2: &[f64], s: Sampling) -> Vec<usize> {
    let n = layer.len().min(final_sigma2.len());
    let mut picked = vec![false; n];
    if n <= s.per_case + s.most_coiled {
        picked.iter_mut().for_each(|p| *p = true);
    } else {
        let mut layers: Vec<u8> = layer[..n].to_vec();
        layers.sort_unstable();
        layers.dedup();
        for &l in &layers {
            let members: Vec<usize> = (0..n).filter(|&f| layer[f] == l).collect();
            // this layer's share of the sample, at least one fibre
            let k = ((s.per_case * members.len()) as f64 / n as f64)
                .round()
                .max(1.0) as usize;
            let k = k.min(members.len());
            for i in 0..k {
                let at = ((i as f64 + 0.5) * members.len() as f64 / k as f64) as usize;
                picked[members[at.min(members.len() - 1)]] = true;
            }
        }
        for f in by_final_sigma2_desc(final_sigma2, n)
            .into_iter()
            .take(s.most_coiled)
        {
            picked[f] = true;
        }
    }
    let mut out: Vec<usize> = (0..n).filter(|&f| picked[f]).collect();
    out.sort_by(|&a, &b| {
        layer[a]
            .cmp(&layer[b])
            .then(final_sigma2[a].total_cmp(&final_sigma2[b]))
            .then(a.cmp(&b))
    });
    out
}

fn by_final_sigma2_desc(s2: &[f64], n: usize) -> Vec<usize> {
    let mut idx: Vec<usize> = (0..n).collect();
    idx.sort_by(|&a, &b| s2[b].total_cmp(&s2[a]).then(a.cmp(&b)));
    idx
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn small_groups_are_shown_whole_in_gallery_order() {
        let layer = [2, 0, 1, 0];
        let s2 = [0.1, 0.9, 0.5, 0.2];
        let got = choose(&layer, &s2, Sampling::default());
        // layer 0 (fibres 3 then 1 by σ²), layer 1, layer 2
        assert_eq!(got, vec![3, 1, 2, 0]);
    }

    #[test]
    fn large_groups_are_stratified_by_layer_and_keep_the_most_coiled() {
        // 10 000 fibres: 20% layer 0, 30% layer 1, 50% layer 2; fibre 7777 coils most
        let n = 10_000;
        let layer: Vec<u8> = (0..n)
            .map(|f| match f % 10 {
                0 | 1 => 0,
                2..=4 => 1,
                _ => 2,
            })
            .collect();
        let mut s2: Vec<f64> = (0..n).map(|f| (f % 97) as f64 * 1e-3).collect();
        s2[7777] = 5.0;
        let s = Sampling {
            per_case: 300,
            most_coiled: 10,
        };
        let got = choose(&layer, &s2, s);
        assert!(got.len() >= 300 && got.len() <= 310, "{}", got.len());
        let count = |l: u8| got.iter().filter(|&&f| layer[f] == l).count();
        // each layer within the most-coiled extras of its proportional share
        for (l, share) in [(0u8, 60usize), (1, 90), (2, 150)] {
            let c = count(l);
            assert!(c >= share && c <= share + 10, "layer {l}: {c} vs {share}");
        }
        assert!(got.contains(&7777));
        // the ten largest final σ² are all in
        let mut top = by_final_sigma2_desc(&s2, n);
        top.truncate(10);
        assert!(top.iter().all(|f| got.contains(f)));
        // gallery order: layer, then σ²
        for w in got.windows(2) {
            let (a, b) = (w[0], w[1]);
            assert!(layer[a] < layer[b] || (layer[a] == layer[b] && s2[a] <= s2[b]));
        }
        // deterministic
        assert_eq!(got, choose(&layer, &s2, s));
    }
}
