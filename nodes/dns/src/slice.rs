//! Planes of the streamwise velocity fluctuation u' = u − ⟨u⟩_xz(y) for viewers: the
//! near-wall streaks (a wall-parallel plane) and a cross-section (a y–z plane).
//!
//! u lives on the x faces (`x = i·dx`) at cell centres in y and z (`y = yc[j]`,
//! `z = (k − ½)·dz`), so the planes take u where it is stored: no interpolation, and the
//! values are exactly the solver's. Positions are returned in wall units in the fibre
//! frame (x from 0 to Lx+, y from −h+ to h+, z from 0 to Lz+).

use crate::field::Velocity;
use crate::grid::Grid;

/// One plane of samples: sample (i, j) sits at `origin + u[i]·axis_u + v[j]·axis_v`
/// (wall units) and holds `values[j·len(u) + i]` (u', wall units).
#[derive(Debug, Clone, PartialEq)]
pub struct Plane {
    pub origin_plus: [f64; 3],
    pub axis_u: [f64; 3],
    pub axis_v: [f64; 3],
    pub u_plus: Vec<f64>,
    pub v_plus: Vec<f64>,
    pub values: Vec<f32>,
}

/// ⟨u⟩ over each x–z plane, by padded row j (1..=ny; the wall ghosts are left 0).
pub fn plane_means(g: &Grid, u: &[f64]) -> Vec<f64> {
    let mut mean = vec![0.0; g.py];
    for (j, m) in mean.iter_mut().enumerate().take(g.ny + 1).skip(1) {
        let mut s = 0.0;
        for k in 1..=g.nz {
            let row = g.idx(1, j, k);
            s += u[row..row + g.nx].iter().sum::<f64>();
        }
        *m = s / (g.nx * g.nz) as f64;
    }
    mean
}

/// The row of cell centres closest to `y_plus` wall units above the lower wall, and its
/// true height in wall units.
pub fn row_near(g: &Grid, re_tau: f64, y_plus: f64) -> (usize, f64) {
    let height = |j: usize| (g.yc[j] - g.yf[0]) * re_tau;
    let j = (1..=g.ny)
        .min_by(|&a, &b| {
            (height(a) - y_plus)
                .abs()
                .total_cmp(&(height(b) - y_plus).abs())
        })
        .unwrap_or(1);
    (j, height(j))
}

/// x positions of the u faces as drawn, `0, dx, …, (nx−1)·dx` in wall units; the face at
/// x = 0 is the periodic copy of the one at x = Lx (padded index nx).
fn x_faces(g: &Grid, re_tau: f64) -> Vec<f64> {
    (0..g.nx).map(|i| i as f64 * g.dx * re_tau).collect()
}

/// Padded x index of the face drawn at `x_faces()[i]`.
fn face_index(g: &Grid, i: usize) -> usize {
    if i == 0 {
        g.nx
    } else {
        i
    }
}

/// The wall-parallel plane of u' at the cell-centre row nearest `y_plus` above the lower
/// wall (the streaks at y+ ≈ 15): axis_u along x, axis_v along z.
pub fn streaks(g: &Grid, vel: &Velocity, re_tau: f64, y_plus: f64) -> Plane {
    let (j, _) = row_near(g, re_tau, y_plus);
    let mean = plane_means(g, &vel.u)[j];
    let mut values = Vec::with_capacity(g.nx * g.nz);
    for k in 1..=g.nz {
        for i in 0..g.nx {
            values.push((vel.u[g.idx(face_index(g, i), j, k)] - mean) as f32);
        }
    }
    Plane {
        origin_plus: [0.0, g.yc[j] * re_tau, 0.0],
        axis_u: [1.0, 0.0, 0.0],
        axis_v: [0.0, 0.0, 1.0],
        u_plus: x_faces(g, re_tau),
        v_plus: (1..=g.nz)
            .map(|k| (k as f64 - 0.5) * g.dz * re_tau)
            .collect(),
        values,
    }
}

/// The fibres' streamwise force on the fluid per unit volume (two-way coupling's body
/// force `f`, outer units) in the streaks' plane ([`streaks`]: same row, same samples), in
/// wall units (a+ = a/Re_τ): where the fibres push the near-wall fluid forward (> 0) or
/// hold it back.
pub fn fiber_force_plane(g: &Grid, f: &Velocity, re_tau: f64, y_plus: f64) -> Plane {
    let (j, _) = row_near(g, re_tau, y_plus);
    let mut values = Vec::with_capacity(g.nx * g.nz);
    for k in 1..=g.nz {
        for i in 0..g.nx {
            values.push((f.u[g.idx(face_index(g, i), j, k)] / re_tau) as f32);
        }
    }
    Plane {
        values,
        ..streaks(g, &Velocity::zeros(g), re_tau, y_plus)
    }
}

/// The y–z plane of u' at x = 0 (the face shared with x = Lx): axis_u along z, axis_v
/// along y, rows from wall to wall including both walls (where u' = 0, no slip).
pub fn cross_section(g: &Grid, vel: &Velocity, re_tau: f64) -> Plane {
    let means = plane_means(g, &vel.u);
    let i = face_index(g, 0);
    let mut v_plus = Vec::with_capacity(g.ny + 2);
    let mut values = Vec::with_capacity(g.nz * (g.ny + 2));
    v_plus.push(g.yf[0] * re_tau);
    values.extend(std::iter::repeat_n(0.0f32, g.nz));
    for j in 1..=g.ny {
        v_plus.push(g.yc[j] * re_tau);
        for k in 1..=g.nz {
            values.push((vel.u[g.idx(i, j, k)] - means[j]) as f32);
        }
    }
    v_plus.push(g.yf[g.ny] * re_tau);
    values.extend(std::iter::repeat_n(0.0f32, g.nz));
    Plane {
        origin_plus: [0.0, 0.0, 0.0],
        axis_u: [0.0, 0.0, 1.0],
        axis_v: [0.0, 1.0, 0.0],
        u_plus: (1..=g.nz)
            .map(|k| (k as f64 - 0.5) * g.dz * re_tau)
            .collect(),
        v_plus,
        values,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::{PI, TAU};

    /// u = U(y) + A(y)·sin(2πz/Lz)·cos(2πx/Lx): a mean profile plus streaks.
    fn streaky(g: &Grid) -> (Velocity, impl Fn(f64, f64, f64) -> f64) {
        let mean = |y: f64| 20.0 * (1.0 - y * y);
        let amp = |y: f64| 3.0 * (1.0 - y * y) * (1.0 + y);
        let (lx, lz) = (g.lx, g.lz);
        let fluct =
            move |x: f64, y: f64, z: f64| amp(y) * (TAU * z / lz).sin() * (TAU * x / lx).cos();
        let mut vel = Velocity::zeros(g);
        for k in 1..=g.nz {
            for j in 1..=g.ny {
                for i in 1..=g.nx {
                    let (x, y, z) = (i as f64 * g.dx, g.yc[j], (k as f64 - 0.5) * g.dz);
                    vel.u[g.idx(i, j, k)] = mean(y) + fluct(x, y, z);
                }
            }
        }
        vel.update_halos(g);
        (vel, fluct)
    }

    fn grid() -> Grid {
        Grid::new(16, 32, 12, TAU, PI, 150.0, Some(0.5)).unwrap()
    }

    /// The mean is removed and every value is the field at the stated position (the
    /// fluctuation integrates to zero over each plane, so the tolerance is rounding).
    #[test]
    fn streak_plane_is_the_fluctuation_at_its_positions() {
        let g = grid();
        let (vel, fluct) = streaky(&g);
        let p = streaks(&g, &vel, 150.0, 15.0);
        let (j, y_plus) = row_near(&g, 150.0, 15.0);
        assert!((p.origin_plus[1] - g.yc[j] * 150.0).abs() < 1e-12);
        assert!((y_plus - (p.origin_plus[1] + 150.0)).abs() < 1e-9);
        // the nearest row: no other centre is closer to 15
        for jj in 1..=g.ny {
            assert!(((g.yc[jj] + 1.0) * 150.0 - 15.0).abs() >= (y_plus - 15.0).abs() - 1e-12);
        }
        assert_eq!(p.values.len(), p.u_plus.len() * p.v_plus.len());
        for (jv, &z) in p.v_plus.iter().enumerate() {
            for (iu, &x) in p.u_plus.iter().enumerate() {
                let want = fluct(x / 150.0, g.yc[j], z / 150.0);
                let got = p.values[jv * p.u_plus.len() + iu] as f64;
                assert!((got - want).abs() < 1e-5, "({iu},{jv}): {got} vs {want}");
            }
        }
    }

    /// The force plane lies where the streaks do and carries the body force there, in wall
    /// units (the field's u component divided by Re_τ, no mean removed).
    #[test]
    fn fiber_force_plane_is_the_body_force_in_the_streaks_plane() {
        let g = grid();
        let (vel, fluct) = streaky(&g);
        let p = fiber_force_plane(&g, &vel, 150.0, 15.0);
        let s = streaks(&g, &vel, 150.0, 15.0);
        assert_eq!(
            (&p.u_plus, &p.v_plus, p.origin_plus),
            (&s.u_plus, &s.v_plus, s.origin_plus)
        );
        let (j, _) = row_near(&g, 150.0, 15.0);
        let mean = 20.0 * (1.0 - g.yc[j] * g.yc[j]);
        for (jv, &z) in p.v_plus.iter().enumerate() {
            for (iu, &x) in p.u_plus.iter().enumerate() {
                let want = (mean + fluct(x / 150.0, g.yc[j], z / 150.0)) / 150.0;
                let got = p.values[jv * p.u_plus.len() + iu] as f64;
                assert!((got - want).abs() < 1e-6, "({iu},{jv}): {got} vs {want}");
            }
        }
    }

    #[test]
    fn cross_section_spans_wall_to_wall_with_zero_at_the_walls() {
        let g = grid();
        let (vel, fluct) = streaky(&g);
        let p = cross_section(&g, &vel, 150.0);
        assert_eq!(p.v_plus.len(), g.ny + 2);
        assert!((p.v_plus[0] + 150.0).abs() < 1e-9 && (p.v_plus[g.ny + 1] - 150.0).abs() < 1e-9);
        assert!(p.v_plus.windows(2).all(|w| w[1] > w[0]));
        let nu = p.u_plus.len();
        assert!(p.values[..nu]
            .iter()
            .chain(&p.values[(g.ny + 1) * nu..])
            .all(|&v| v == 0.0));
        for (jv, &y) in p.v_plus.iter().enumerate().skip(1).take(g.ny) {
            for (iu, &z) in p.u_plus.iter().enumerate() {
                let want = fluct(0.0, y / 150.0, z / 150.0);
                let got = p.values[jv * nu + iu] as f64;
                assert!((got - want).abs() < 1e-5, "({iu},{jv}): {got} vs {want}");
            }
        }
    }
}
