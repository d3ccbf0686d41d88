//! Flow slices in the channel view: each plane as a mesh with one vertex per sample,
//! coloured by u' (diverging map, ±4 u_tau). A wall-parallel plane (the streaks) is drawn
//! on the nearer wall, under every fibre, so it hides none of them.

use crate::{err, ViewerError};
use fiberflow_messages::FlowSlice;

/// Where each sample of a slice is drawn (row by row, `u` fastest): at its own position,
/// except that a wall-parallel plane is moved onto the nearer wall (y = ±`h_plus`), and
/// the fibres' force (`fiber_force`, the streaks' plane) is drawn beside the channel, one
/// box width and a gap back along z (beyond the channel as the opening camera, at high z
/// looking along −z, sees it), so it sits next to the streaks it pushes.
pub fn positions(s: &FlowSlice, h_plus: f64) -> Vec<[f32; 3]> {
    let (a, b) = (&s.axis_u, &s.axis_v);
    let normal_y = a[2] * b[0] - a[0] * b[2];
    let wall_y = (normal_y.abs() > 0.99).then(|| h_plus.copysign(s.origin[1]));
    // beside the channel: the plane's z extent (samples at cell centres) and a twentieth
    // (recordings of schema 4 and before name it "fibre_force")
    let beside = matches!(s.name.as_str(), "fiber_force" | "fibre_force");
    let dz = match (beside, s.v_plus.first(), s.v_plus.last()) {
        (true, Some(a), Some(b)) => -1.05 * (a + b),
        _ => 0.0,
    };
    let mut out = Vec::with_capacity(s.u_plus.len() * s.v_plus.len());
    for &v in &s.v_plus {
        for &u in &s.u_plus {
            let mut p = [0, 1, 2].map(|i| s.origin[i] + u * a[i] + v * b[i]);
            if let Some(y) = wall_y {
                p[1] = y;
            }
            p[2] += dz;
            out.push(p.map(|x| x as f32));
        }
    }
    out
}

/// Two triangles per quad of neighbouring samples (row by row, `nu` per row).
fn triangles(nu: usize, nv: usize) -> Vec<[u32; 3]> {
    let mut t = Vec::with_capacity(2 * nu.saturating_sub(1) * nv.saturating_sub(1));
    for j in 0..nv.saturating_sub(1) {
        for i in 0..nu.saturating_sub(1) {
            let a = (j * nu + i) as u32;
            let b = a + 1;
            let c = a + nu as u32;
            let d = c + 1;
            t.push([a, b, d]);
            t.push([a, d, c]);
        }
    }
    t
}

/// The slices' geometry already in the scene, by name: a plane keeps its samples for a
/// whole run, so after the first time only its colours are logged (they are what changes).
#[derive(Default)]
pub struct Logged {
    geometry: std::collections::HashMap<String, Vec<[f32; 3]>>,
}

/// Logs one slice at `world/slices/<name>` (the time must be set): the mesh the first time
/// (or when its samples moved), the vertex colours alone afterwards.
pub fn log(
    rec: &rerun::RecordingStream,
    logged: &mut Logged,
    s: &FlowSlice,
    h_plus: f64,
) -> Result<(), ViewerError> {
    let path = format!("world/slices/{}", s.name);
    let range = fiberflow_messages::palette::range_for(&s.quantity, &s.values);
    let colours = s.values.iter().map(|&x| {
        let c = fiberflow_messages::palette::diverging(x as f64, range);
        rerun::Color::from_rgb(c[0], c[1], c[2])
    });
    let positions = positions(s, h_plus);
    if logged.geometry.get(&s.name) == Some(&positions) {
        return rec
            .log(
                path.as_str(),
                &rerun::Mesh3D::update_fields().with_vertex_colors(colours),
            )
            .map_err(err);
    }
    let tris = triangles(s.u_plus.len(), s.v_plus.len());
    rec.log(
        path,
        &rerun::Mesh3D::new(positions.clone())
            .with_triangle_indices(tris)
            .with_vertex_colors(colours),
    )
    .map_err(err)?;
    logged.geometry.insert(s.name.clone(), positions);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn slice(name: &str, origin_y: f64, axis_u: [f64; 3], axis_v: [f64; 3]) -> FlowSlice {
        FlowSlice {
            schema_version: fiberflow_messages::SCHEMA_VERSION,
            step: 0,
            t_plus: 0.0,
            name: name.into(),
            quantity: "u_fluct_plus".into(),
            origin: vec![0.0, origin_y, 0.0],
            axis_u: axis_u.to_vec(),
            axis_v: axis_v.to_vec(),
            u_plus: vec![0.0, 10.0, 20.0],
            v_plus: vec![-100.0, 5.0],
            values: vec![0.0; 6],
        }
    }

    #[test]
    fn streaks_lie_on_the_nearer_wall_and_a_cross_section_where_it_is() {
        let s = slice("streaks", -135.0, [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]);
        let p = positions(&s, 150.0);
        assert_eq!(p.len(), 6);
        assert!(p.iter().all(|q| q[1] == -150.0));
        // x from u, z from v, row by row
        assert_eq!(p[1], [10.0, -150.0, -100.0]);
        assert_eq!(p[5], [20.0, -150.0, 5.0]);
        let upper = slice("streaks", 135.0, [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]);
        assert!(positions(&upper, 150.0).iter().all(|q| q[1] == 150.0));
        let c = slice("cross_section", 0.0, [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]);
        let p = positions(&c, 150.0);
        assert_eq!(p[0], [0.0, -100.0, 0.0]);
        assert_eq!(p[5], [0.0, 5.0, 20.0]);
    }

    /// The fibres' force plane lies on the streaks' wall, shifted back along z by its own
    /// extent (first + last sample: cell centres) and a twentieth.
    #[test]
    fn fiber_force_lies_beside_the_streaks() {
        let mut s = slice("fiber_force", -135.0, [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]);
        s.v_plus = vec![5.0, 15.0, 25.0];
        s.values = vec![0.0; 9];
        let p = positions(&s, 150.0);
        let shift = (1.05 * 30.0) as f32;
        assert_eq!(p[0], [0.0, -150.0, 5.0 - shift]);
        assert_eq!(p[8], [20.0, -150.0, 25.0 - shift]);
    }

    #[test]
    fn triangles_cover_each_quad_once_and_index_inside() {
        let t = triangles(3, 2);
        assert_eq!(t, vec![[0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4]]);
        assert!(triangles(5, 7).iter().flatten().all(|&i| i < 35));
        assert!(triangles(1, 4).is_empty());
    }
}
