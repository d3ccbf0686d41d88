//! Contacts and flocs in recorded fibre states (docs/contact.md): which segments of
//! different fibres touch (centre-lines within 1% of their contact distance), contacts per
//! fibre, the contact graph's clusters of fibres (flocs: count, largest, share of fibres
//! in one), the closest approach of any two fibres, and the crowding number.
//!
//! A run without contact has fibres that pass through each other: there the same numbers
//! measure how much they interpenetrate.

use fiberflow_fiber_model::contact::{closest_points, self_touching, touching};
use fiberflow_fiber_model::fiber::{Fiber, Segment, SegmentProps};
use fiberflow_messages::FiberGroupState;
use nalgebra::Vector3;
use std::fmt::Write as _;

/// Centre-lines within this fraction of their contact distance are in contact.
pub const CONTACT_TOLERANCE: f64 = 0.01;

/// Wall-distance bands of a fibre's centre of mass (wall units from the nearer wall):
/// below the first edge the wall band (viscous and buffer layers), then the log layer,
/// from the second edge the centre.
pub const BAND_EDGES_PLUS: [f64; 2] = [30.0, 100.0];

/// Names of the bands of [`BAND_EDGES_PLUS`], as the CSV's column suffixes.
pub const BAND_NAMES: [&str; 3] = ["wall", "log", "centre"];

/// Contacts and flocs of the fibres whose centre of mass lies in one wall-distance band.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BandRow {
    pub fibers: usize,
    /// Mean number of other fibres (anywhere) each of the band's fibres touches.
    pub contacts_per_fiber: f64,
    /// Share of the band's fibres that are in a floc.
    pub in_flocs: f64,
}

/// One recorded state's contacts and flocs.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct FlocRow {
    pub step: u64,
    pub t_plus: f64,
    pub fibers: usize,
    /// Mean number of other fibres each fibre touches.
    pub contacts_per_fiber: f64,
    /// Pairs of segments of different fibres in contact.
    pub segment_contacts: usize,
    /// Clusters of two or more fibres joined by contacts.
    pub flocs: usize,
    /// Fibres in the largest cluster (1 when no fibre touches another).
    pub largest: usize,
    /// Share of the fibres that are in a floc.
    pub in_flocs: f64,
    /// Closest centre-line distance between segments of different fibres over the mean
    /// diameter (∞ when none is within 1% of touching).
    pub closest_over_d: f64,
    /// Crowding number N = (2/3) c_v (L/d)² of the group in the box.
    pub crowding: f64,
    /// Pairs of non-adjacent segments of one fibre in contact (a fibre folded onto
    /// itself), and their closest centre-lines over the mean diameter (∞ when none is
    /// within 1% of touching; below 1, a fibre folded through itself).
    pub self_contacts: usize,
    pub self_closest_over_d: f64,
    /// The same by where the fibres are ([`BAND_NAMES`]).
    pub bands: [BandRow; 3],
    /// The solve's own account of the step that ended at this state (the state's contact
    /// arrays, schema 4; 0 and NaN when it has none): the pairs of segments that touched
    /// (each pair counted once, a fibre's own included), and the mean magnitude of the
    /// contact force on the segments that touched (wall units).
    pub solve_pairs: usize,
    pub mean_contact_force_plus: f64,
}

/// The fibres of a full state (centres and axes) as the model's fibres.
fn fibers_of(s: &FiberGroupState) -> Vec<Fiber> {
    let mut out = Vec::with_capacity(s.segments_per_fiber.len());
    let mut seg = 0usize;
    for (f, &n) in s.segments_per_fiber.iter().enumerate() {
        let (l, d) = (s.segment_length[f], s.diameter[f]);
        let rho = s.density_ratio.get(f).copied().unwrap_or(1.0);
        let mut segments = Vec::with_capacity(n as usize);
        for i in seg..seg + n as usize {
            let r = Vector3::new(s.centre[3 * i], s.centre[3 * i + 1], s.centre[3 * i + 2]);
            let z = Vector3::new(s.axis[3 * i], s.axis[3 * i + 1], s.axis[3 * i + 2]);
            segments.push(Segment {
                r,
                z,
                v: Vector3::zeros(),
                w: Vector3::zeros(),
                n: z.cross(&Vector3::x())
                    .try_normalize(1e-9)
                    .unwrap_or(Vector3::y()),
                f: Vector3::zeros(),
            });
        }
        seg += n as usize;
        out.push(Fiber {
            props: vec![SegmentProps::new(l, d, rho); n as usize],
            segments,
            density: rho,
        });
    }
    out
}

/// Where segments touch in one full state: the midpoint of the closest points of each
/// pair of segments of different fibres in contact (within 1% of its contact distance), in
/// (fibre, segment) order of the pairs, then of each pair of a fibre's own non-adjacent
/// segments in contact; folded into the box along the periodic x1 and x3.
pub fn contact_points(s: &FiberGroupState, box_plus: [f64; 3]) -> Vec<[f64; 3]> {
    let fibers = fibers_of(s);
    let period = [Some(box_plus[0]), None, Some(box_plus[2])];
    let ends = |f: &Fiber, i: usize| {
        let (sg, h) = (&f.segments[i], 0.5 * f.props[i].shape.length);
        (sg.r - sg.z * h, sg.r + sg.z * h)
    };
    let own = self_touching(&fibers, CONTACT_TOLERANCE)
        .into_iter()
        .map(|(k, i, j, _)| (k, i, k, j, 0.0));
    touching(&fibers, &period, CONTACT_TOLERANCE)
        .into_iter()
        .chain(own)
        .map(|(fa, ia, fb, ib, _)| {
            let (p0, p1) = ends(&fibers[fa], ia);
            let (q0, q1) = ends(&fibers[fb], ib);
            // b's nearest image beside a
            let gap = fibers[fa].segments[ia].r - fibers[fb].segments[ib].r;
            let shift = Vector3::new(
                (gap.x / box_plus[0]).round() * box_plus[0],
                0.0,
                (gap.z / box_plus[2]).round() * box_plus[2],
            );
            let (q0, q1) = (q0 + shift, q1 + shift);
            let (t_a, t_b) = closest_points(&p0, &p1, &q0, &q1);
            let m = 0.5 * ((p0 + (p1 - p0) * t_a) + (q0 + (q1 - q0) * t_b));
            [
                m.x.rem_euclid(box_plus[0]),
                m.y,
                m.z.rem_euclid(box_plus[2]),
            ]
        })
        .collect()
}

/// Union–find root with path halving.
fn root(parent: &mut [usize], mut a: usize) -> usize {
    while parent[a] != a {
        parent[a] = parent[parent[a]];
        a = parent[a];
    }
    a
}

/// The clusters of `n` fibres joined by `fiber_pairs`: each fibre's root, the lowest
/// fibre of its cluster.
fn clusters(n: usize, fiber_pairs: &[(usize, usize)]) -> Vec<usize> {
    let mut parent: Vec<usize> = (0..n).collect();
    for &(a, b) in fiber_pairs {
        let (ra, rb) = (root(&mut parent, a), root(&mut parent, b));
        if ra != rb {
            parent[ra.max(rb)] = ra.min(rb);
        }
    }
    (0..n).map(|k| root(&mut parent, k)).collect()
}

/// The pairs of fibres in contact in one full state, each once, ascending.
fn fiber_pairs(pairs: &[(usize, usize, usize, usize, f64)]) -> Vec<(usize, usize)> {
    let mut out: Vec<(usize, usize)> = pairs.iter().map(|p| (p.0, p.2)).collect();
    out.sort_unstable();
    out.dedup();
    out
}

/// The fibres of one full state that are in a floc (a cluster of two or more joined by
/// contacts), ascending, each with its floc's name: the floc's lowest fibre.
pub fn floc_members(s: &FiberGroupState, box_plus: [f64; 3]) -> Vec<(usize, usize)> {
    let fibers = fibers_of(s);
    let period = [Some(box_plus[0]), None, Some(box_plus[2])];
    let pairs = fiber_pairs(&touching(&fibers, &period, CONTACT_TOLERANCE));
    let roots = clusters(fibers.len(), &pairs);
    let mut size = vec![0usize; fibers.len()];
    for &r in &roots {
        size[r] += 1;
    }
    roots
        .iter()
        .enumerate()
        .filter(|&(_, &r)| size[r] >= 2)
        .map(|(k, &r)| (k, r))
        .collect()
}

/// Contacts and flocs of one full state of a whole group in a box periodic along x1
/// and x3 (`box_plus` its lengths).
pub fn of_state(s: &FiberGroupState, box_plus: [f64; 3]) -> FlocRow {
    let fibers = fibers_of(s);
    let n = fibers.len();
    let period = [Some(box_plus[0]), None, Some(box_plus[2])];
    let pairs = touching(&fibers, &period, CONTACT_TOLERANCE);
    let fiber_pairs = fiber_pairs(&pairs);
    let roots = clusters(n, &fiber_pairs);
    let mut size = vec![0usize; n];
    for &r in &roots {
        size[r] += 1;
    }
    // each fibre's band, from its centre of mass's distance to the nearer wall
    let half_height = 0.5 * box_plus[1];
    let band_of = |f: &Fiber| {
        let mass: f64 = f.props.iter().map(|p| p.mass).sum();
        let y = f
            .segments
            .iter()
            .zip(&f.props)
            .map(|(s, p)| s.r.y * p.mass)
            .sum::<f64>()
            / mass;
        let wall = half_height - y.abs();
        BAND_EDGES_PLUS.iter().filter(|&&e| wall >= e).count()
    };
    let mut degree = vec![0usize; n];
    for &(a, b) in &fiber_pairs {
        degree[a] += 1;
        degree[b] += 1;
    }
    let mut bands = [BandRow::default(); 3];
    let mut in_band_flocs = [0usize; 3];
    for (k, f) in fibers.iter().enumerate() {
        let b = band_of(f);
        bands[b].fibers += 1;
        bands[b].contacts_per_fiber += degree[k] as f64;
        if size[roots[k]] >= 2 {
            in_band_flocs[b] += 1;
        }
    }
    for (b, row) in bands.iter_mut().enumerate() {
        let m = row.fibers.max(1) as f64;
        row.contacts_per_fiber /= m;
        row.in_flocs = in_band_flocs[b] as f64 / m;
    }
    let flocs = size.iter().filter(|&&c| c >= 2).count();
    let in_flocs = size.iter().filter(|&&c| c >= 2).sum::<usize>();
    let mean_d = s.diameter.iter().sum::<f64>() / s.diameter.len().max(1) as f64;
    let closest = pairs.iter().map(|p| p.4).fold(f64::INFINITY, f64::min);
    let own = self_touching(&fibers, CONTACT_TOLERANCE);
    let own_closest = own.iter().map(|p| p.3).fold(f64::INFINITY, f64::min);
    let fiber_volume: f64 = fibers
        .iter()
        .flat_map(|f| f.props.iter())
        .map(|p| std::f64::consts::FRAC_PI_4 * p.shape.diameter.powi(2) * p.shape.length)
        .sum();
    let length = fibers
        .iter()
        .map(|f| f.props.iter().map(|p| p.shape.length).sum::<f64>())
        .sum::<f64>()
        / n.max(1) as f64;
    let cv = fiber_volume / box_plus.iter().product::<f64>();
    FlocRow {
        step: s.step,
        t_plus: s.t_plus,
        fibers: n,
        contacts_per_fiber: 2.0 * fiber_pairs.len() as f64 / n.max(1) as f64,
        segment_contacts: pairs.len(),
        flocs,
        largest: size.iter().copied().max().unwrap_or(0),
        in_flocs: in_flocs as f64 / n.max(1) as f64,
        closest_over_d: closest / mean_d,
        crowding: 2.0 / 3.0 * cv * (length / mean_d).powi(2),
        self_contacts: own.len(),
        self_closest_over_d: own_closest / mean_d,
        bands,
        solve_pairs: s.contacts.iter().map(|&c| c as usize).sum::<usize>() / 2,
        mean_contact_force_plus: s
            .contact_force
            .chunks_exact(3)
            .map(|f| (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt())
            .sum::<f64>()
            / s.contact_segment.len() as f64,
    }
}

/// `{group}_flocs.csv`: one row per recorded full state.
/// The groups of each `[[suspensions]]` table of a run folder's `launch.toml` (groups
/// whose fibres touch each other); none for a single file or a launch without one.
pub fn suspensions_of_run(run: &std::path::Path) -> Vec<Vec<String>> {
    let Ok(text) = std::fs::read_to_string(run.join("launch.toml")) else {
        return Vec::new();
    };
    let Ok(doc) = text.parse::<toml::Table>() else {
        return Vec::new();
    };
    let Some(list) = doc.get("suspensions").and_then(toml::Value::as_array) else {
        return Vec::new();
    };
    list.iter()
        .filter_map(|s| s.get("groups")?.as_array())
        .map(|g| {
            g.iter()
                .filter_map(|n| n.as_str().map(String::from))
                .collect()
        })
        .filter(|g: &Vec<String>| g.len() >= 2)
        .collect()
}

/// The fibres of several groups' states of one step as one state, in the order given:
/// the suspension whose groups touch each other, for [`of_state`].
pub fn merged(states: &[&FiberGroupState]) -> Option<FiberGroupState> {
    let (first, rest) = states.split_first()?;
    let mut m = (*first).clone();
    m.first_fiber = 0;
    m.group = states
        .iter()
        .map(|s| s.group.as_str())
        .collect::<Vec<_>>()
        .join("+");
    for s in rest {
        if s.step != m.step || s.is_lean() != m.is_lean() {
            return None;
        }
        m.group_fibers += s.group_fibers;
        let before: u32 = m.segments_per_fiber.iter().sum();
        m.contact_segment
            .extend(s.contact_segment.iter().map(|&i| i + before));
        m.contact_force.extend(&s.contact_force);
        m.contacts.extend(&s.contacts);
        m.segments_per_fiber.extend(&s.segments_per_fiber);
        m.segment_length.extend(&s.segment_length);
        m.diameter.extend(&s.diameter);
        m.density_ratio.extend(&s.density_ratio);
        m.layer.extend(&s.layer);
        m.centre.extend(&s.centre);
        m.axis.extend(&s.axis);
        m.velocity.extend(&s.velocity);
        m.angular_velocity.extend(&s.angular_velocity);
        m.hydro_force.extend(&s.hydro_force);
    }
    Some(m)
}

pub fn csv(rows: &[FlocRow]) -> String {
    let mut out = String::from(
        "step,t_plus,fibers,contacts_per_fiber,segment_contacts,flocs,largest_floc,share_in_flocs,closest_over_d,crowding",
    );
    for name in BAND_NAMES {
        let _ = write!(
            out,
            ",fibers_{name},contacts_per_fiber_{name},share_in_flocs_{name}"
        );
    }
    out.push_str(",self_contacts,self_closest_over_d,solve_pairs,mean_contact_force_plus\n");
    for r in rows {
        let _ = write!(
            out,
            "{},{:.4},{},{:.5},{},{},{},{:.5},{:.5},{:.4}",
            r.step,
            r.t_plus,
            r.fibers,
            r.contacts_per_fiber,
            r.segment_contacts,
            r.flocs,
            r.largest,
            r.in_flocs,
            r.closest_over_d,
            r.crowding
        );
        for b in &r.bands {
            let _ = write!(
                out,
                ",{},{:.5},{:.5}",
                b.fibers, b.contacts_per_fiber, b.in_flocs
            );
        }
        let _ = writeln!(
            out,
            ",{},{:.5},{},{:.6e}",
            r.self_contacts, r.self_closest_over_d, r.solve_pairs, r.mean_contact_force_plus
        );
    }
    out
}

/// The Markdown table of every group's first and last recorded state.
pub fn table(groups: &[(String, Vec<FlocRow>)]) -> String {
    let mut out = String::from(
        "# Contacts and flocs\n\nSegments of different fibres are in contact when their centre-lines are within 1% of a diameter; flocs are clusters of two or more fibres joined by contacts; \"closest own\" is the closest approach of non-adjacent segments of one fibre (below 1: a fibre folded through itself). Without `[fibers.contact]` fibres pass through each other, and these numbers measure how much.\n\n| group | t+ | crowding N | contacts per fibre | flocs | largest floc | share in flocs | closest / d | closest own / d | contacts per fibre: wall / log / centre (fibres) |\n|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for (name, rows) in groups {
        let ends = match (rows.first(), rows.last()) {
            (Some(a), Some(b)) if a.step != b.step => vec![a, b],
            (Some(a), _) => vec![a],
            _ => vec![],
        };
        for r in ends {
            let _ = writeln!(
                out,
                "| {name} | {:.1} | {:.2} | {:.3} | {} | {} | {:.3} | {} | {} | {} |",
                r.t_plus,
                r.crowding,
                r.contacts_per_fiber,
                r.flocs,
                r.largest,
                r.in_flocs,
                if r.closest_over_d.is_finite() {
                    format!("{:.4}", r.closest_over_d)
                } else {
                    "> 1.01".into()
                },
                if r.self_closest_over_d.is_finite() {
                    format!("{:.4}", r.self_closest_over_d)
                } else {
                    "> 1.01".into()
                },
                r.bands
                    .iter()
                    .map(|b| format!("{:.3} ({})", b.contacts_per_fiber, b.fibers))
                    .collect::<Vec<_>>()
                    .join(" / ")
            );
        }
    }
    out
}

/// `{group}_flocs.png`: contacts per fibre, the share of fibres in flocs, the closest
/// approach of two fibres and of a fibre's own segments over d, against t+.
pub fn plot(
    path: &std::path::Path,
    group: &str,
    rows: &[FlocRow],
) -> Result<(), crate::AnalysisError> {
    let series = |label: &str, colour: usize, f: &dyn Fn(&FlocRow) -> f64| crate::plot::Series {
        label: label.into(),
        points: rows
            .iter()
            .map(|r| (r.t_plus, f(r)))
            .filter(|p| p.1.is_finite())
            .collect(),
        colour,
        markers: true,
    };
    crate::plot::line_plot(
        path,
        &format!("{group}: contacts and flocs"),
        "t+",
        "per fibre / share / closest over d",
        &[
            series("contacts per fibre", 0, &|r| r.contacts_per_fiber),
            series("share of fibres in flocs", 1, &|r| r.in_flocs),
            series("closest centre-lines / d", 2, &|r| r.closest_over_d),
            series("closest own segments / d", 3, &|r| r.self_closest_over_d),
        ],
        false,
        false,
    )?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A state of fibres along x3 at given (x1, x2), 7 segments of l 3, d 0.232.
    fn state(positions: &[(f64, f64)]) -> FiberGroupState {
        let n = positions.len();
        let mut centre = Vec::new();
        let mut axis = Vec::new();
        for &(x, y) in positions {
            for i in 0..7 {
                centre.extend([x, y, 100.0 + 3.0 * i as f64]);
                axis.extend([0.0, 0.0, 1.0]);
            }
        }
        FiberGroupState {
            group: "g".into(),
            step: 5,
            t_plus: 1.0,
            group_fibers: n as u32,
            segments_per_fiber: vec![7; n],
            segment_length: vec![3.0; n],
            diameter: vec![0.232; n],
            density_ratio: vec![1150.0; n],
            layer: vec![0; n],
            centre,
            axis,
            ..Default::default()
        }
    }

    /// A fibre whose third segment lies back alongside its first, 0.2 apart (folded through
    /// itself): one pair of its own segments in contact, 0.2 / 0.232 apart; its neighbours
    /// along the chain (adjacent segments) do not count, nor does it touch another fibre.
    #[test]
    fn a_fiber_folded_through_itself_is_counted() {
        let mut s = state(&[(10.0, 0.0), (60.0, 0.0)]);
        s.centre[6..9].copy_from_slice(&[10.2, 0.0, 100.0]);
        let r = of_state(&s, [942.0, 300.0, 471.0]);
        assert_eq!(r.self_contacts, 1);
        assert!((r.self_closest_over_d - 0.2 / 0.232).abs() < 1e-12);
        assert_eq!(r.segment_contacts, 0);
        let text = csv(&[r]);
        let header: Vec<&str> = text.lines().next().unwrap().split(',').collect();
        let row: Vec<&str> = text.lines().nth(1).unwrap().split(',').collect();
        let at = header.iter().position(|h| *h == "self_contacts").unwrap();
        assert_eq!(row[at], "1");
        assert_eq!(row[at + 1], "0.86207");
    }

    /// Four parallel fibres: a chain of three touching (0.232 and 0.233 apart, within 1%),
    /// one alone; a pair 0.24 apart (3% off) does not count. Flocs, sizes, contacts per
    /// fibre and the closest approach follow by hand; the crowding number is (2/3) c_v (L/d)².
    #[test]
    fn a_chain_of_touching_fibers_is_one_floc() {
        let s = state(&[
            (10.0, 0.0),
            (10.0, 0.232),
            (10.0, 0.465),
            (50.0, 0.0),
            (50.0, 0.24),
        ]);
        let box_plus = [942.0, 300.0, 471.0];
        let r = of_state(&s, box_plus);
        assert_eq!(r.fibers, 5);
        assert_eq!(r.flocs, 1);
        assert_eq!(r.largest, 3);
        assert!((r.in_flocs - 0.6).abs() < 1e-12);
        // two fibre pairs touch: 2 × 2 / 5
        assert!((r.contacts_per_fiber - 0.8).abs() < 1e-12);
        assert_eq!(r.segment_contacts, 2 * 7 + 2 * 2 * 6);
        assert!(
            (r.closest_over_d - 1.0).abs() < 1e-9,
            "{}",
            r.closest_over_d
        );
        assert_eq!(r.self_contacts, 0);
        assert!(r.self_closest_over_d.is_infinite());
        let cv =
            5.0 * std::f64::consts::FRAC_PI_4 * 0.232f64.powi(2) * 21.0 / (942.0 * 300.0 * 471.0);
        let want = 2.0 / 3.0 * cv * (21.0 / 0.232f64).powi(2);
        assert!((r.crowding - want).abs() < 1e-12 * want);
    }

    /// A suspension's groups are analysed as one: two groups of two fibres each, where
    /// each group's fibres are apart but touch a fibre of the other group, have no floc
    /// alone and one of four fibres merged; the merged state lists both groups' fibres in
    /// order, and their contact arrays (the solve's pairs and mean contact force) with the
    /// second group's segments renumbered. `suspensions_of_run` reads `[[suspensions]]`
    /// from a run folder's launch.toml.
    #[test]
    fn a_suspension_s_groups_make_flocs_together() {
        let box_plus = [942.0, 300.0, 471.0];
        let mut a = state(&[(10.0, 0.0), (10.0, 0.464)]);
        a.group = "a".into();
        let mut b = state(&[(10.0, 0.232), (10.0, 0.696)]);
        b.group = "b".into();
        assert_eq!(
            (of_state(&a, box_plus).flocs, of_state(&b, box_plus).flocs),
            (0, 0)
        );
        let m = merged(&[&a, &b]).unwrap();
        assert_eq!(m.group, "a+b");
        assert_eq!((m.group_fibers, m.segments_per_fiber.len()), (4, 4));
        assert_eq!(&m.centre[..a.centre.len()], &a.centre[..]);
        let r = of_state(&m, box_plus);
        assert_eq!((r.fibers, r.flocs, r.largest), (4, 1, 4));
        // the solve's account rides along: b's listed segments renumbered past a's 14
        let mut a2 = a.clone();
        (a2.contact_segment, a2.contact_force, a2.contacts) =
            (vec![3], vec![3.0, 0.0, 4.0], vec![1]);
        let mut b2 = b.clone();
        (b2.contact_segment, b2.contact_force, b2.contacts) = (
            vec![3, 10],
            vec![-3.0, 0.0, -4.0, 0.0, 1.0, 0.0],
            vec![1, 2],
        );
        let m2 = merged(&[&a2, &b2]).unwrap();
        assert_eq!(m2.contact_segment, vec![3, 17, 24]);
        let r2 = of_state(&m2, box_plus);
        // counts 1 + 1 + 2 = 4: two pairs; |F| 5, 5, 1
        assert_eq!(r2.solve_pairs, 2);
        assert!((r2.mean_contact_force_plus - 11.0 / 3.0).abs() < 1e-12);
        assert!(r.mean_contact_force_plus.is_nan() && r.solve_pairs == 0);
        let dir = std::env::temp_dir().join(format!("ff-susp-run-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        assert!(suspensions_of_run(&dir).is_empty());
        std::fs::write(
            dir.join("launch.toml"),
            "[run]\nid = \"x\"\n[[suspensions]]\ngroups = [\"a\", \"b\"]\n",
        )
        .unwrap();
        assert_eq!(
            suspensions_of_run(&dir),
            vec![vec!["a".to_string(), "b".into()]]
        );
        std::fs::remove_dir_all(&dir).ok();
    }

    /// Contact points are the midpoints between touching centre-lines: two parallel
    /// fibres 0.232 apart along x3 touch segment by segment, at x1 halfway between them;
    /// across the periodic boundary the point lies inside the box, on the boundary side.
    #[test]
    fn contact_points_lie_between_the_centre_lines_inside_the_box() {
        let box_plus = [942.0, 300.0, 471.0];
        let p = contact_points(&state(&[(10.0, 0.0), (10.232, 0.0)]), box_plus);
        // 7 facing segments, and each touches its neighbours' ends: 7 + 2 × 6 pairs
        assert_eq!(p.len(), 7 + 2 * 6);
        for q in &p {
            assert!((q[0] - 10.116).abs() < 1e-9 && q[1].abs() < 1e-12, "{q:?}");
            assert!((100.0 - 1.5..=118.0 + 1.5).contains(&q[2]), "{q:?}");
        }
        // a fibre whose third segment lies back alongside its first, 0.2 apart: one more
        // point, between those two
        let mut folded = state(&[(10.0, 0.0), (10.232, 0.0)]);
        folded.centre[6..9].copy_from_slice(&[9.8, 0.0, 100.0]);
        let p = contact_points(&folded, box_plus);
        let last = p.last().copied().unwrap_or_default();
        assert!(
            (last[0] - 9.9).abs() < 1e-9 && (100.0 - 1.5..=100.0 + 1.5).contains(&last[2]),
            "{last:?}"
        );
        let p = contact_points(&state(&[(0.05, 0.0), (941.95 - 0.132, 0.0)]), box_plus);
        assert!(!p.is_empty());
        for q in &p {
            let x = q[0];
            assert!((0.0..942.0).contains(&x), "{q:?}");
            assert!(!(0.05..=941.8).contains(&x), "{q:?}");
        }
    }

    /// Fibres are counted in the band of their centre's distance to the nearer wall: a
    /// touching pair 10 from the lower wall, a lone fibre 60 from the upper one, a chain
    /// of three at the centre plane (box height 300).
    #[test]
    fn contacts_are_counted_by_the_band_of_the_fibers_wall_distance() {
        let s = state(&[
            (10.0, -140.0),
            (10.0, -140.0 + 0.232),
            (50.0, 90.0),
            (90.0, 0.0),
            (90.0, 0.232),
            (90.0, 0.464),
        ]);
        let r = of_state(&s, [942.0, 300.0, 471.0]);
        let [wall, log, centre] = r.bands;
        assert_eq!((wall.fibers, log.fibers, centre.fibers), (2, 1, 3));
        assert!((wall.contacts_per_fiber - 1.0).abs() < 1e-12);
        assert!((wall.in_flocs - 1.0).abs() < 1e-12);
        assert_eq!((log.contacts_per_fiber, log.in_flocs), (0.0, 0.0));
        // the chain: 1, 2 and 1 other fibres
        assert!((centre.contacts_per_fiber - 4.0 / 3.0).abs() < 1e-12);
        assert!((centre.in_flocs - 1.0).abs() < 1e-12);
        let csv = csv(&[r]);
        assert!(csv.lines().next().unwrap().ends_with(
            "fibers_wall,contacts_per_fiber_wall,share_in_flocs_wall,fibers_log,contacts_per_fiber_log,share_in_flocs_log,fibers_centre,contacts_per_fiber_centre,share_in_flocs_centre,self_contacts,self_closest_over_d,solve_pairs,mean_contact_force_plus"
        ));
        assert!(csv
            .lines()
            .nth(1)
            .unwrap()
            .ends_with(",2,1.00000,1.00000,1,0.00000,0.00000,3,1.33333,1.00000,0,inf,0,NaN"));
    }

    /// Floc members are named by their floc's lowest fibre; a lone fibre is in none.
    #[test]
    fn floc_members_name_each_floc_by_its_lowest_fiber() {
        let s = state(&[
            (50.0, 0.0),
            (10.0, 0.0),
            (10.0, 0.232),
            (50.0, 0.232),
            (90.0, 0.0),
            (10.0, 0.464),
        ]);
        let m = floc_members(&s, [942.0, 300.0, 471.0]);
        assert_eq!(m, vec![(0, 0), (1, 1), (2, 1), (3, 0), (5, 1)]);
    }

    /// Across the periodic boundary in x1 two fibres still touch.
    #[test]
    fn contacts_are_found_across_the_periodic_boundary() {
        let s = state(&[(0.05, 0.0), (941.95 - 0.132, 0.0)]);
        let r = of_state(&s, [942.0, 300.0, 471.0]);
        assert_eq!((r.flocs, r.largest), (1, 2));
        assert!((r.closest_over_d - 0.232 / 0.232).abs() < 1e-9);
    }
}
