//! Staggered channel grid: uniform in x and z, tanh-stretched in y.
//!
//! Outer units throughout the solver: half-height h = 1, friction velocity u_tau = 1,
//! so ν = 1/Re_tau and one viscous time unit is t+ = 1/Re_tau.
//!
//! Index conventions (padded arrays, one halo layer in every direction):
//! cell `j` (1..=ny) spans `[yf[j-1], yf[j]]` with centre `yc[j]`; `v(j)` lives on the top
//! face `yf[j]` (walls at `j = 0` and `j = ny`). In x, cell `i` (1..=nx) spans
//! `[(i-1)dx, i dx]` and `u(i)` sits on its right face `x = i dx`; z likewise for `w`.

use crate::error::DnsError;

/// Geometry and metric terms of the staggered grid.
#[derive(Debug, Clone, PartialEq)]
pub struct Grid {
    pub nx: usize,
    pub ny: usize,
    pub nz: usize,
    /// Box length in x, in units of h.
    pub lx: f64,
    /// Box length in z, in units of h.
    pub lz: f64,
    pub dx: f64,
    pub dz: f64,
    /// Face positions, `yf[0] = -1` .. `yf[ny] = 1` (length ny+1).
    pub yf: Vec<f64>,
    /// Cell-centre positions with mirrored ghosts, padded index 0..=ny+1.
    pub yc: Vec<f64>,
    /// Cell widths `yf[j]-yf[j-1]`, padded index (ghosts copy the neighbours).
    pub dyf: Vec<f64>,
    /// Centre-to-centre distances `yc[j+1]-yc[j]`, index 0..=ny (lives on face j).
    pub dyc: Vec<f64>,
    /// Padded sizes.
    pub px: usize,
    pub py: usize,
    pub pz: usize,
}

impl Grid {
    /// Builds a grid whose first cell centre sits at `y1_plus` wall units for `re_tau`.
    /// `y1_plus = None` (or a value at or above the uniform spacing) gives a uniform grid.
    pub fn new(
        nx: usize,
        ny: usize,
        nz: usize,
        lx: f64,
        lz: f64,
        re_tau: f64,
        y1_plus: Option<f64>,
    ) -> Result<Self, DnsError> {
        let gamma = match y1_plus {
            Some(y1) => stretch_for_first_centre(ny, 2.0 * y1 / re_tau)?,
            None => 0.0,
        };
        Self::with_stretch(nx, ny, nz, lx, lz, gamma)
    }

    /// Builds a grid with an explicit tanh stretching factor (0 = uniform).
    pub fn with_stretch(
        nx: usize,
        ny: usize,
        nz: usize,
        lx: f64,
        lz: f64,
        gamma: f64,
    ) -> Result<Self, DnsError> {
        if nx < 4 || nz < 4 || !nx.is_multiple_of(2) || !nz.is_multiple_of(2) {
            return Err(DnsError::Config(format!(
                "grid.nx and grid.nz must be even and >= 4 (got nx = {nx}, nz = {nz})"
            )));
        }
        if ny < 4 {
            return Err(DnsError::Config(format!("grid.ny must be >= 4 (got {ny})")));
        }
        if !(lx > 0.0 && lz > 0.0 && lx.is_finite() && lz.is_finite()) {
            return Err(DnsError::Config(format!(
                "grid.lx and grid.lz must be positive and finite (got {lx}, {lz})"
            )));
        }
        let yf: Vec<f64> = (0..=ny).map(|j| face_position(j, ny, gamma)).collect();
        let mut yc = vec![0.0; ny + 2];
        for j in 1..=ny {
            yc[j] = 0.5 * (yf[j - 1] + yf[j]);
        }
        yc[0] = 2.0 * yf[0] - yc[1];
        yc[ny + 1] = 2.0 * yf[ny] - yc[ny];
        let mut dyf = vec![0.0; ny + 2];
        for j in 1..=ny {
            dyf[j] = yf[j] - yf[j - 1];
        }
        dyf[0] = dyf[1];
        dyf[ny + 1] = dyf[ny];
        let dyc: Vec<f64> = (0..=ny).map(|j| yc[j + 1] - yc[j]).collect();
        Ok(Self {
            nx,
            ny,
            nz,
            lx,
            lz,
            dx: lx / nx as f64,
            dz: lz / nz as f64,
            yf,
            yc,
            dyf,
            dyc,
            px: nx + 2,
            py: ny + 2,
            pz: nz + 2,
        })
    }

    /// Linear index into a padded array.
    #[inline(always)]
    pub fn idx(&self, i: usize, j: usize, k: usize) -> usize {
        i + self.px * (j + self.py * k)
    }

    /// Number of values in a padded array.
    pub fn padded_len(&self) -> usize {
        self.px * self.py * self.pz
    }

    /// Number of interior cells.
    pub fn cells(&self) -> usize {
        self.nx * self.ny * self.nz
    }

    /// Stride of one k-plane in a padded array.
    pub fn plane(&self) -> usize {
        self.px * self.py
    }

    /// Distance of the first cell centre from the wall, in units of h.
    pub fn first_centre_distance(&self) -> f64 {
        self.yc[1] - self.yf[0]
    }
}

/// tanh clustering towards both walls: `y = tanh(γ(2j/ny-1))/tanh(γ)`.
fn face_position(j: usize, ny: usize, gamma: f64) -> f64 {
    let s = 2.0 * j as f64 / ny as f64 - 1.0;
    if gamma.abs() < 1e-12 {
        s
    } else {
        (gamma * s).tanh() / gamma.tanh()
    }
}

/// Finds γ so that the first cell has width `first_width` (bisection, monotone in γ).
fn stretch_for_first_centre(ny: usize, first_width: f64) -> Result<f64, DnsError> {
    let uniform = 2.0 / ny as f64;
    if !(first_width > 0.0) || !first_width.is_finite() {
        return Err(DnsError::Config(format!(
            "grid.y1_plus must be positive (got first width {first_width})"
        )));
    }
    if first_width >= uniform {
        return Ok(0.0);
    }
    let width = |g: f64| face_position(1, ny, g) - face_position(0, ny, g);
    let (mut lo, mut hi) = (1e-9, 20.0);
    if width(hi) > first_width {
        return Err(DnsError::Config(format!(
            "grid.y1_plus too small for ny = {ny}: cannot cluster that strongly"
        )));
    }
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if width(mid) > first_width {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Ok(0.5 * (lo + hi))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn first_centre_matches_target() {
        let g = Grid::new(
            64,
            64,
            64,
            std::f64::consts::TAU,
            std::f64::consts::PI,
            150.0,
            Some(0.33),
        )
        .unwrap();
        let y1_plus = g.first_centre_distance() * 150.0;
        assert!((y1_plus - 0.33).abs() < 1e-9, "y1+ = {y1_plus}");
        assert!((g.yf[0] + 1.0).abs() < 1e-15 && (g.yf[64] - 1.0).abs() < 1e-15);
        // symmetric about the centreline
        for j in 0..=64 {
            assert!((g.yf[j] + g.yf[64 - j]).abs() < 1e-14);
        }
    }

    #[test]
    fn rejects_odd_sizes() {
        assert!(Grid::with_stretch(63, 8, 8, 1.0, 1.0, 0.0).is_err());
        assert!(Grid::with_stretch(8, 2, 8, 1.0, 1.0, 0.0).is_err());
    }
}
