//! Crank–Nicolson wall-normal diffusion: one tridiagonal solve per velocity component and
//! wall-normal line, `(I - c Lyy) du = rhs`, vectorised across x within each k-plane.

use crate::grid::Grid;

/// A factorised constant-coefficient (in x) tridiagonal system along y.
#[derive(Debug, Clone)]
pub struct YTridiag {
    /// First unknown row (padded j) and last.
    j0: usize,
    j1: usize,
    a: Vec<f64>,
    cp: Vec<f64>,
    inv_den: Vec<f64>,
}

impl YTridiag {
    /// Factorises `(I - c Lyy)` for a tangential (cell-centred, no-slip ghost) component.
    pub fn tangential(g: &Grid, c: f64) -> Self {
        let ny = g.ny;
        let mut a = vec![0.0; ny + 2];
        let mut b = vec![0.0; ny + 2];
        let mut cc = vec![0.0; ny + 2];
        for j in 1..=ny {
            a[j] = -c / (g.dyc[j - 1] * g.dyf[j]);
            cc[j] = -c / (g.dyc[j] * g.dyf[j]);
            b[j] = 1.0 - a[j] - cc[j];
        }
        // mirrored ghosts: f0 = -f1, f(ny+1) = -f(ny)
        b[1] -= a[1];
        a[1] = 0.0;
        b[ny] -= cc[ny];
        cc[ny] = 0.0;
        Self::factor(1, ny, a, b, cc)
    }

    /// Factorises `(I - c Lyy)` for v on interior faces 1..ny-1 (zero on the walls).
    pub fn normal(g: &Grid, c: f64) -> Self {
        let ny = g.ny;
        let mut a = vec![0.0; ny + 2];
        let mut b = vec![0.0; ny + 2];
        let mut cc = vec![0.0; ny + 2];
        for j in 1..ny {
            a[j] = -c / (g.dyf[j] * g.dyc[j]);
            cc[j] = -c / (g.dyf[j + 1] * g.dyc[j]);
            b[j] = 1.0 - a[j] - cc[j];
        }
        a[1] = 0.0;
        cc[ny - 1] = 0.0;
        Self::factor(1, ny - 1, a, b, cc)
    }

    fn factor(j0: usize, j1: usize, a: Vec<f64>, b: Vec<f64>, c: Vec<f64>) -> Self {
        let n = a.len();
        let mut cp = vec![0.0; n];
        let mut inv_den = vec![0.0; n];
        let mut prev_cp = 0.0;
        for j in j0..=j1 {
            let den = b[j] - a[j] * prev_cp;
            inv_den[j] = 1.0 / den;
            cp[j] = c[j] * inv_den[j];
            prev_cp = cp[j];
        }
        Self {
            j0,
            j1,
            a,
            cp,
            inv_den,
        }
    }

    /// Solves in place on one padded k-plane (`px*py` values), every x line at once.
    pub fn solve_plane(&self, g: &Grid, p: &mut [f64]) {
        let (px, nx) = (g.px, g.nx);
        let j0 = self.j0;
        {
            let row = &mut p[j0 * px + 1..j0 * px + 1 + nx];
            let s = self.inv_den[j0];
            row.iter_mut().for_each(|x| *x *= s);
        }
        for j in j0 + 1..=self.j1 {
            let (before, after) = p.split_at_mut(j * px);
            let prev = &before[(j - 1) * px + 1..(j - 1) * px + 1 + nx];
            let row = &mut after[1..1 + nx];
            let (a, s) = (self.a[j], self.inv_den[j]);
            for (x, pv) in row.iter_mut().zip(prev) {
                *x = (*x - a * pv) * s;
            }
        }
        for j in (j0..self.j1).rev() {
            let (before, after) = p.split_at_mut((j + 1) * px);
            let next = &after[1..1 + nx];
            let row = &mut before[j * px + 1..j * px + 1 + nx];
            let cpj = self.cp[j];
            for (x, nv) in row.iter_mut().zip(next) {
                *x -= cpj * nv;
            }
        }
    }
}
