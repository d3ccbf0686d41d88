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

    /// Refreshes all halos (periodic x, z; walls in y).
    pub fn update_halos(&mut self, grid: &Grid) {
        update_halo(grid, &mut self.u, Component::Tangential);
        update_halo(grid, &mut self.v, Component::Normal);
        update_halo(grid, &mut self.w, Component::Tangential);
    }
}

/// Fills the halo layer of one padded field.
pub fn update_halo(grid: &Grid, f: &mut [f64], comp: Component) {
    let plane = grid.plane();
    // y walls and x periodicity, per k-plane (interior k only; z halo copies whole planes).
    f.par_chunks_mut(plane)
        .enumerate()
        .filter(|(k, _)| *k >= 1 && *k <= grid.nz)
        .for_each(|(_, p)| fill_plane_halo(grid, p, comp));
    copy_z_halo(grid, f);
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

/// z periodicity: copies the first and last interior planes into the opposite halo.
pub fn copy_z_halo(grid: &Grid, f: &mut [f64]) {
    let (plane, nz) = (grid.plane(), grid.nz);
    let (first, rest) = f.split_at_mut(plane);
    let (mid, last) = rest.split_at_mut(nz * plane);
    first.copy_from_slice(&mid[(nz - 1) * plane..nz * plane]);
    last.copy_from_slice(&mid[0..plane]);
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
