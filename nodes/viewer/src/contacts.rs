//! Contacts and flocs in the scene: each floc coloured as one, its fibres' centre lines
//! folded into the box, and the contact forces as arrows.

use super::*;

/// The colour of the floc named by its lowest fibre `root` (neighbouring names spread
/// over the palette).
pub fn floc_colour(root: usize) -> [u8; 3] {
    FLOC_COLOURS[(root.wrapping_mul(2_654_435_761) >> 7) % FLOC_COLOURS.len()]
}

/// The centre-line of fibre `k` of a full state (its joints, first end to last), moved by
/// whole periods so that its centre of mass lies in the box.
pub fn folded_centre_line(
    s: &fiberflow_messages::FiberGroupState,
    first_segment: usize,
    k: usize,
    box_plus: [f64; 3],
) -> Vec<[f32; 3]> {
    let n = s.segments_per_fiber[k] as usize;
    let h = 0.5 * s.segment_length[k];
    let at = |i: usize, v: &[f64]| [v[3 * i], v[3 * i + 1], v[3 * i + 2]];
    let mut line = Vec::with_capacity(n + 1);
    for i in first_segment..first_segment + n {
        let (r, z) = (at(i, &s.centre), at(i, &s.axis));
        line.push([r[0] - h * z[0], r[1] - h * z[1], r[2] - h * z[2]]);
    }
    let last = first_segment + n - 1;
    let (r, z) = (at(last, &s.centre), at(last, &s.axis));
    line.push([r[0] + h * z[0], r[1] + h * z[1], r[2] + h * z[2]]);
    let com: Vec<f64> = (0..3)
        .map(|c| {
            (first_segment..=last)
                .map(|i| s.centre[3 * i + c])
                .sum::<f64>()
                / n as f64
        })
        .collect();
    let shift = [
        com[0].rem_euclid(box_plus[0]) - com[0],
        0.0,
        com[2].rem_euclid(box_plus[2]) - com[2],
    ];
    line.iter()
        .map(|p| [0, 1, 2].map(|c| (p[c] + shift[c]) as f32))
        .collect()
}

/// Logs the fibres of every floc of one state at `world/flocs/<group>`, each floc in its
/// own colour ([`floc_colour`]); returns how many fibres it drew.
pub(crate) fn log_flocs(
    rec: &rerun::RecordingStream,
    s: &fiberflow_messages::FiberGroupState,
    box_plus: [f64; 3],
) -> Result<usize, ViewerError> {
    let members = fiberflow_analysis::flocs::floc_members(s, box_plus);
    let mut first = Vec::with_capacity(s.segments_per_fiber.len());
    let mut o = 0usize;
    for &n in &s.segments_per_fiber {
        first.push(o);
        o += n as usize;
    }
    let strips: Vec<Vec<[f32; 3]>> = members
        .iter()
        .map(|&(k, _)| folded_centre_line(s, first[k], k, box_plus))
        .collect();
    let colours = members.iter().map(|&(_, r)| {
        let [red, green, blue] = floc_colour(r);
        rerun::Color::from_rgb(red, green, blue)
    });
    rec.log(
        format!("world/flocs/{}", s.group),
        &rerun::LineStrips3D::new(strips)
            .with_radii([0.3])
            .with_colors(colours),
    )
    .map_err(err)?;
    Ok(members.len())
}

/// Longest contact-force arrow, wall units.
const FORCE_ARROW_PLUS: f64 = 6.0;

/// The contact forces a state carries (schema 4), as arrows: from each touched segment's
/// centre (moved into the box along the periodic directions) along its force, the largest
/// of the state [`FORCE_ARROW_PLUS`] long. Origins and vectors.
pub(crate) fn contact_arrows(
    s: &fiberflow_messages::FiberGroupState,
    box_plus: [f64; 3],
) -> (Vec<[f32; 3]>, Vec<[f32; 3]>) {
    let largest = s
        .contact_force
        .chunks_exact(3)
        .map(|f| (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt())
        .fold(0.0_f64, f64::max);
    if largest <= 0.0 || !largest.is_finite() {
        return (Vec::new(), Vec::new());
    }
    let scale = FORCE_ARROW_PLUS / largest;
    s.contact_segment
        .iter()
        .zip(s.contact_force.chunks_exact(3))
        .filter_map(|(&i, f)| {
            let c = s.centre.get(3 * i as usize..3 * i as usize + 3)?;
            let origin = [
                c[0].rem_euclid(box_plus[0]) as f32,
                c[1] as f32,
                c[2].rem_euclid(box_plus[2]) as f32,
            ];
            Some((origin, [0, 1, 2].map(|a| (f[a] * scale) as f32)))
        })
        .unzip()
}

/// Logs where the fibres of one state touch, at `world/contacts/<group>` (red points of
/// about four diameters, so they show at the channel's scale), and the contact forces the
/// state carries at `world/contact_forces/<group>` (orange arrows, [`contact_arrows`]).
pub(crate) fn log_contacts(
    rec: &rerun::RecordingStream,
    s: &fiberflow_messages::FiberGroupState,
    box_plus: [f64; 3],
    dt_plus: f64,
) -> Result<(), ViewerError> {
    let points: Vec<[f32; 3]> = fiberflow_analysis::flocs::contact_points(s, box_plus)
        .into_iter()
        .map(|p| p.map(|x| x as f32))
        .collect();
    set_time(rec, s.step, s.t_plus, dt_plus);
    rec.log(
        format!("world/contacts/{}", s.group),
        &rerun::Points3D::new(points)
            .with_radii([0.5])
            .with_colors([rerun::Color::from_rgb(230, 40, 40)]),
    )
    .map_err(err)?;
    let (origins, vectors) = contact_arrows(s, box_plus);
    rec.log(
        format!("world/contact_forces/{}", s.group),
        &rerun::Arrows3D::from_vectors(vectors)
            .with_origins(origins)
            .with_radii([0.25])
            .with_colors([rerun::Color::from_rgb(255, 150, 20)]),
    )
    .map_err(err)
}

#[cfg(test)]
mod floc_tests {
    use super::*;

    /// A fibre of two segments along x1 whose centre of mass lies one period beyond the
    /// box is drawn at its joints, moved back by that period; flocs next to each other by
    /// name get different colours.
    #[test]
    fn a_floc_fiber_is_drawn_at_its_joints_inside_the_box() {
        let s = fiberflow_messages::FiberGroupState {
            segments_per_fiber: vec![2],
            segment_length: vec![3.0],
            centre: vec![1001.5, 10.0, 5.0, 1004.5, 10.0, 5.0],
            axis: vec![1.0, 0.0, 0.0, 1.0, 0.0, 0.0],
            ..Default::default()
        };
        let line = folded_centre_line(&s, 0, 0, [1000.0, 300.0, 400.0]);
        assert_eq!(
            line,
            vec![[0.0, 10.0, 5.0], [3.0, 10.0, 5.0], [6.0, 10.0, 5.0]]
        );
        assert_ne!(floc_colour(3), floc_colour(4));
    }

    /// The recorded contact forces become arrows from the touched segments' centres,
    /// moved into the box, the largest `FORCE_ARROW_PLUS` long and each along its force;
    /// a state without contact arrays has none.
    #[test]
    fn contact_forces_are_arrows_from_the_touched_segments() {
        let mut s = fiberflow_messages::FiberGroupState {
            segments_per_fiber: vec![2, 2],
            segment_length: vec![3.0, 3.0],
            centre: vec![
                -1.0, 10.0, 5.0, 2.0, 10.0, 5.0, 2.0, 10.2, 405.0, 5.0, 10.2, 5.0,
            ],
            ..Default::default()
        };
        assert_eq!(contact_arrows(&s, [1000.0, 300.0, 400.0]), (vec![], vec![]));
        s.contact_segment = vec![0, 2];
        s.contact_force = vec![0.0, -2.0, 0.0, 0.0, 1.0, 0.0];
        s.contacts = vec![1, 1];
        let (origins, vectors) = contact_arrows(&s, [1000.0, 300.0, 400.0]);
        assert_eq!(origins, vec![[999.0, 10.0, 5.0], [2.0, 10.2, 5.0]]);
        let l = FORCE_ARROW_PLUS as f32;
        assert_eq!(vectors, vec![[0.0, -l, 0.0], [0.0, 0.5 * l, 0.0]]);
    }
}
