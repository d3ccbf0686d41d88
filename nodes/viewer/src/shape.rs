//! What the scene draws of one fibre at one step: its joints, centre of mass and coiling
//! σ² (paper §4.3: σ² = Σ|ẑ_i − ẑ|²/(N−1), ẑ the normalised mean axis), and the times at
//! which the scene shows it.

use fiberflow_messages::FiberGroupState;

/// One fibre at one step.
#[derive(Debug, Clone, PartialEq)]
pub struct Shape {
    /// N + 1 joints (segment ends), unwrapped, wall units.
    pub joints: Vec<[f64; 3]>,
    pub com: [f64; 3],
    pub sigma2: f64,
}

/// Index of each fibre's first segment in a state's per-segment arrays.
pub fn first_segments(s: &FiberGroupState) -> Vec<usize> {
    let mut out = Vec::with_capacity(s.segments_per_fiber.len());
    let mut k = 0usize;
    for &n in &s.segments_per_fiber {
        out.push(k);
        k += n as usize;
    }
    out
}

/// Fibre `f` of a state whose first segment is `seg0` (centre of mass and σ² as the
/// analysis computes them, [`fiberflow_analysis::fibers::fiber_of_state`]).
pub fn shape(s: &FiberGroupState, f: usize, seg0: usize) -> Shape {
    let n = s.segments_per_fiber.get(f).copied().unwrap_or(0) as usize;
    let l = s.segment_length.get(f).copied().unwrap_or(0.0);
    let at = |v: &[f64], i: usize| [v[3 * i], v[3 * i + 1], v[3 * i + 2]];
    let mut joints = Vec::with_capacity(n + 1);
    for i in seg0..seg0 + n {
        let (c, z) = (at(&s.centre, i), at(&s.axis, i));
        joints.push([0, 1, 2].map(|a| c[a] - 0.5 * l * z[a]));
        if i + 1 == seg0 + n {
            joints.push([0, 1, 2].map(|a| c[a] + 0.5 * l * z[a]));
        }
    }
    let (com, _, sigma2) = fiberflow_analysis::fibers::fiber_of_state(s, seg0, n);
    Shape {
        joints,
        com,
        sigma2,
    }
}

/// The joints shifted so the centre of mass lies in the periodic box (x and z wrapped).
pub fn in_box(sh: &Shape, box_plus: [f64; 3]) -> Vec<[f32; 3]> {
    let shift = [
        sh.com[0].rem_euclid(box_plus[0]) - sh.com[0],
        0.0,
        sh.com[2].rem_euclid(box_plus[2]) - sh.com[2],
    ];
    sh.joints
        .iter()
        .map(|p| [0, 1, 2].map(|a| (p[a] + shift[a]) as f32))
        .collect()
}

/// The joints re-centred from the centre of mass onto `centre` (a gallery cell).
pub fn at_cell(sh: &Shape, centre: [f64; 3]) -> Vec<[f32; 3]> {
    sh.joints
        .iter()
        .map(|p| [0, 1, 2].map(|a| (p[a] - sh.com[a] + centre[a]) as f32))
        .collect()
}

/// The fibre's side view (x1 to the right, x2 up) around `centre`, a gallery cell in image
/// coordinates (y down).
pub fn side_view(sh: &Shape, centre: [f64; 3]) -> Vec<[f32; 2]> {
    sh.joints
        .iter()
        .map(|p| {
            [
                (p[0] - sh.com[0] + centre[0]) as f32,
                (centre[1] - (p[1] - sh.com[1])) as f32,
            ]
        })
        .collect()
}

/// Distance of a point at height `y_plus` (channel centre 0) from the nearer wall of a
/// channel of half-height `h_plus`.
pub fn wall_distance(y_plus: f64, h_plus: f64) -> f64 {
    h_plus - y_plus.abs()
}

/// The whole t+ a step stands for on the `t+` timeline: `n` when the step is the first one
/// with t+ in [n − dt+/2, n + dt+/2), so each whole t+ gets at most one step. Steps in
/// between are on the `step` timeline only.
pub fn whole_t_plus(t_plus: f64, dt_plus: f64) -> Option<i64> {
    if !(t_plus.is_finite() && dt_plus > 0.0) {
        return None;
    }
    let n = (t_plus + 0.5 * dt_plus).floor();
    (t_plus - n < 0.5 * dt_plus).then_some(n as i64)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn state(axes: &[[f64; 3]], l: f64) -> FiberGroupState {
        let n = axes.len();
        let mut centre = Vec::new();
        let mut p = [1000.0, -140.0, -5.0];
        for z in axes {
            let c = [0, 1, 2].map(|a| p[a] + 0.5 * l * z[a]);
            centre.extend_from_slice(&c);
            p = [0, 1, 2].map(|a| p[a] + l * z[a]);
        }
        FiberGroupState {
            schema_version: fiberflow_messages::SCHEMA_VERSION,
            group: "g".into(),
            step: 0,
            t_plus: 0.0,
            first_fiber: 0,
            group_fibers: 1,
            segments_per_fiber: vec![n as u32],
            segment_length: vec![l],
            diameter: vec![0.1],
            density_ratio: vec![1000.0],
            layer: vec![0],
            centre,
            axis: axes.iter().flatten().copied().collect(),
            velocity: vec![0.0; 3 * n],
            angular_velocity: vec![0.0; 3 * n],
            hydro_force: vec![],
            contact_segment: vec![],
            contact_force: vec![],
            contacts: vec![],
        }
    }

    #[test]
    fn straight_fiber_has_zero_sigma2_and_joints_at_segment_ends() {
        let s = state(&[[1.0, 0.0, 0.0]; 4], 3.0);
        let sh = shape(&s, 0, 0);
        assert_eq!(sh.joints.len(), 5);
        assert!(sh.sigma2.abs() < 1e-15);
        assert!((sh.joints[4][0] - sh.joints[0][0] - 12.0).abs() < 1e-12);
        assert!((sh.com[0] - 1006.0).abs() < 1e-12);
    }

    #[test]
    fn hairpin_sigma2_matches_the_closed_form() {
        // two segments along +x, two along +y: mean axis (1,1,0)/√2, each |ẑ_i − ẑ|² = 2 − √2
        let s = state(
            &[
                [1.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                [0.0, 1.0, 0.0],
            ],
            2.0,
        );
        let sh = shape(&s, 0, 0);
        let expect = 4.0 * (2.0 - 2f64.sqrt()) / 3.0;
        assert!((sh.sigma2 - expect).abs() < 1e-12, "{}", sh.sigma2);
    }

    #[test]
    fn box_wrap_and_gallery_recentring_keep_the_shape() {
        let s = state(&[[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], 4.0);
        let sh = shape(&s, 0, 0);
        let b = [942.48, 300.0, 471.24];
        let w = in_box(&sh, b);
        let g = at_cell(&sh, [10.0, -20.0, 0.0]);
        let side = side_view(&sh, [10.0, 20.0, 0.0]);
        for (p, q) in side.iter().zip(&g) {
            // same x; y mirrored about the cell centre (image y points down)
            assert!((p[0] - q[0]).abs() < 1e-4);
            assert!((p[1] - 20.0 + (q[1] + 20.0)).abs() < 1e-4);
        }
        // wrapping shifts x1 by whole box lengths only, and leaves x2 alone
        let shift = w[0][0] as f64 - sh.joints[0][0];
        assert!(
            ((shift / b[0]).round() * b[0] - shift).abs() < 1e-3,
            "{shift}"
        );
        assert!(shift != 0.0);
        for (p, q) in w.iter().zip(&sh.joints) {
            assert!((p[1] as f64 - q[1]).abs() < 1e-4);
        }
        // the gallery copy has its centre of mass on the cell
        let seg_centre_mean = |j: &[[f32; 3]], a: usize| {
            (0..j.len() - 1)
                .map(|k| 0.5 * (j[k][a] + j[k + 1][a]) as f64)
                .sum::<f64>()
                / (j.len() - 1) as f64
        };
        assert!((seg_centre_mean(&g, 0) - 10.0).abs() < 1e-3);
        assert!((seg_centre_mean(&g, 1) + 20.0).abs() < 1e-3);
        for k in 1..w.len() {
            for a in 0..3 {
                let dw = w[k][a] - w[k - 1][a];
                let dg = g[k][a] - g[k - 1][a];
                assert!((dw - dg).abs() < 1e-3, "segment {k} axis {a}");
            }
        }
        // the centre of mass lands in the box and on the cell
        let wrapped = sh.com[0].rem_euclid(b[0]);
        assert!((0.0..b[0]).contains(&wrapped));
        assert!(wall_distance(-140.0, 150.0) == 10.0 && wall_distance(145.0, 150.0) == 5.0);
    }

    #[test]
    fn each_whole_t_plus_gets_exactly_one_step() {
        for dt in [0.1, 0.25, 0.2, 0.5, 1.0, 0.3] {
            let mut seen = std::collections::BTreeMap::new();
            for k in 0..=400u32 {
                let t = k as f64 * dt;
                if let Some(n) = whole_t_plus(t, dt) {
                    assert!((t - n as f64).abs() <= 0.5 * dt + 1e-12);
                    assert!(seen.insert(n, k).is_none(), "dt {dt}: t+ {n} twice");
                }
            }
            let last = (400.0 * dt - 0.5 * dt).floor() as i64;
            for n in 0..=last {
                assert!(seen.contains_key(&n), "dt {dt}: t+ {n} missing");
            }
        }
        assert_eq!(whole_t_plus(20.0, 0.25), Some(20));
        assert_eq!(whole_t_plus(20.25, 0.25), None);
        assert_eq!(whole_t_plus(f64::NAN, 0.25), None);
    }
}
