//! Flow slices in the channel view: each plane as a mesh with one vertex per sample,
//! coloured by u' (diverging map, ±4 u_tau).

use crate::{err, ViewerError};
use fiberflow_messages::FlowSlice;

/// Logs one slice at `world/slices/<name>` (the time must be set).
pub fn log(rec: &rerun::RecordingStream, s: &FlowSlice) -> Result<(), ViewerError> {
    let (nu, nv) = (s.u_plus.len(), s.v_plus.len());
    let mut positions = Vec::with_capacity(nu * nv);
    for &v in &s.v_plus {
        for &u in &s.u_plus {
            positions
                .push([0, 1, 2].map(|a| (s.origin[a] + u * s.axis_u[a] + v * s.axis_v[a]) as f32));
        }
    }
    let mut triangles = Vec::with_capacity(2 * nu.saturating_sub(1) * nv.saturating_sub(1));
    for j in 0..nv.saturating_sub(1) {
        for i in 0..nu.saturating_sub(1) {
            let a = (j * nu + i) as u32;
            let b = a + 1;
            let c = a + nu as u32;
            let d = c + 1;
            triangles.push([a, b, d]);
            triangles.push([a, d, c]);
        }
    }
    let colours = s.values.iter().map(|&x| {
        let c = fiberflow_messages::palette::diverging(x as f64, 4.0);
        rerun::Color::from_rgb(c[0], c[1], c[2])
    });
    rec.log(
        format!("world/slices/{}", s.name),
        &rerun::Mesh3D::new(positions)
            .with_triangle_indices(triangles)
            .with_vertex_colors(colours),
    )
    .map_err(err)
}
