//! Padded velocity fields and their halo (boundary) updates.

use crate::grid::Grid;
use rayon::prelude::*;

/// Which staggered component a field holds; decides its wall condition.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Component {
    /// u or w: cell-centred in y, no-slip through a mirrored ghost (`f0 = -f1`).
    Tangential,
    /// v: on y faces, zero on the walls.
    Normal,
    /// Pressure-like scalar: cell-centred, zero normal gradient at the walls.
    Scalar,
}

/// The velocity state of the channel (padded arrays, outer units).
#[derive(Debug, Clone, PartialEq)]
pub struct Velocity {
    pub u: Vec<f64>,
    pub v: Vec<f64>,
    pub w: Vec<f64>,
}

impl Velocity {
    pub fn zeros(grid: &Grid) -> Self {
        let n = grid.padded_len();
        Self {
            u: vec![0.0; n],
            v: vec![0.0; n],
            w: vec![0.0; n],
        }
    }

    /// Refreshes all halos (periodic x, z; walls in y): the three fields' planes in one
    /// parallel pass, then their z copies in another.
    pub fn update_halos(&mut self, grid: &Grid) {
        interior_planes(grid, &mut self.u, Component::Tangential)
            .chain(interior_planes(grid, &mut self.v, Component::Normal))
            .chain(interior_planes(grid, &mut self.w, Component::Tangential))
            .for_each(|(p, comp)| fill_plane_halo(grid, p, comp));
        copy_z_halos(grid, [&mut self.u, &mut self.v, &mut self.w]);
    }
}

/// The interior k-planes of a padded field (1..=nz), each with the field's component.
fn interior_planes<'a>(
    grid: &Grid,
    f: &'a mut [f64],
    comp: Component,
) -> impl IndexedParallelIterator<Item = (&'a mut [f64], Component)> + 'a {
    let plane = grid.plane();
    f[plane..(grid.nz + 1) * plane]
        .par_chunks_mut(plane)
        .map(move |p| (p, comp))
}

/// Fills the halo layer of one padded field.
pub fn update_halo(grid: &Grid, f: &mut [f64], comp: Component) {
    interior_planes(grid, f, comp).for_each(|(p, comp)| fill_plane_halo(grid, p, comp));
    copy_z_halos(grid, [f]);
}

/// The x-periodic copies and the wall ghosts of one k-plane (`px*py` values).
pub fn fill_plane_halo(grid: &Grid, p: &mut [f64], comp: Component) {
    let (nx, ny, px, py) = (grid.nx, grid.ny, grid.px, grid.py);
    for j in 0..py {
        let row = &mut p[j * px..(j + 1) * px];
        row[0] = row[nx];
        row[nx + 1] = row[1];
    }
    match comp {
        Component::Tangential => {
            for i in 0..px {
                p[i] = -p[px + i];
                p[(ny + 1) * px + i] = -p[ny * px + i];
            }
        }
        Component::Normal => {
            for i in 0..px {
                p[i] = 0.0;
                p[ny * px + i] = 0.0;
                p[(ny + 1) * px + i] = 0.0;
            }
        }
        Component::Scalar => {
            for i in 0..px {
                p[i] = p[px + i];
                p[(ny + 1) * px + i] = p[ny * px + i];
            }
        }
    }
}

/// z periodicity of several fields: each field's first and last interior planes copied
/// into the opposite halo, the copies spread over the thread pool (they ran on one thread
/// while the other waited).
pub fn copy_z_halos<const N: usize>(grid: &Grid, fields: [&mut [f64]; N]) {
    let (plane, nz) = (grid.plane(), grid.nz);
    fields.into_par_iter().for_each(|f| {
        let (first, rest) = f.split_at_mut(plane);
        let (mid, last) = rest.split_at_mut(nz * plane);
        rayon::join(
            || first.copy_from_slice(&mid[(nz - 1) * plane..]),
            || last[..plane].copy_from_slice(&mid[..plane]),
        );
    });
}

/// Sum over interior cells of `f(i,j,k) * dyf[j]` divided by the channel volume: the bulk
/// mean of a cell-centred-in-y quantity (u or w). Deterministic (fixed summation order).
pub fn bulk_mean(grid: &Grid, f: &[f64]) -> f64 {
    let plane = grid.plane();
    let partial: Vec<f64> = f
        .par_chunks(plane)
        .enumerate()
        .filter(|(k, _)| *k >= 1 && *k <= grid.nz)
        .map(|(_, p)| {
            let mut s = 0.0;
            for j in 1..=grid.ny {
                let row = &p[j * grid.px + 1..j * grid.px + 1 + grid.nx];
                s += row.iter().sum::<f64>() * grid.dyf[j];
            }
            s
        })
        .collect();
    partial.iter().sum::<f64>() / (2.0 * (grid.nx * grid.nz) as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// After `update_halos` every halo value is what its definition says: x and z
    /// periodic copies of the interior (taken after the walls' ghosts are set), mirrored
    /// ghosts for u and w at the walls, zeros for v on and beyond the walls; interior
    /// values untouched. A grid whose plane does not split evenly into the copy pieces.
    #[test]
    fn halos_hold_their_definitions() {
        let g = Grid::with_stretch(8, 5, 6, 2.0, 1.0, 1.5).unwrap();
        let mut vel = Velocity::zeros(&g);
        let mut x = 1u64;
        for f in [&mut vel.u, &mut vel.v, &mut vel.w] {
            for value in f.iter_mut() {
                x = x
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                *value = (x >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
            }
        }
        let before = vel.clone();
        vel.update_halos(&g);
        let (nx, ny, nz) = (g.nx, g.ny, g.nz);
        for (f, f0, comp) in [
            (&vel.u, &before.u, Component::Tangential),
            (&vel.v, &before.v, Component::Normal),
            (&vel.w, &before.w, Component::Tangential),
        ] {
            // the value at (i, j, k) after the x-, y- and z-halo rules, from the interior
            let want = |i: usize, j: usize, k: usize| -> f64 {
                let k = if k == 0 {
                    nz
                } else if k == nz + 1 {
                    1
                } else {
                    k
                };
                let i = if i == 0 {
                    nx
                } else if i == nx + 1 {
                    1
                } else {
                    i
                };
                match comp {
                    Component::Normal if j == 0 || j >= ny => 0.0,
                    Component::Tangential if j == 0 => -f0[g.idx(i, 1, k)],
                    Component::Tangential if j == ny + 1 => -f0[g.idx(i, ny, k)],
                    _ => f0[g.idx(i, j, k)],
                }
            };
            for k in 0..=nz + 1 {
                for j in 0..=ny + 1 {
                    for i in 0..=nx + 1 {
                        let got = f[g.idx(i, j, k)];
                        assert_eq!(got.to_bits(), want(i, j, k).to_bits(), "({i}, {j}, {k})");
                    }
                }
            }
        }
    }
}
