//! Sampling of velocity and velocity gradient at arbitrary points (what the fibre nodes
//! need: v, G and Ω of paper eq. 4). Trilinear interpolation of each quantity from its
//! natural staggered location; periodic in x and z (positions are wrapped), wall values
//! enforced in y. Exact for fields that are multilinear between the nodes (uniform flow,
//! simple shear); second-order accurate otherwise.

use crate::field::Velocity;
use crate::grid::Grid;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Hx {
    Centre,
    Face,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Vy {
    /// Wall, cell centres 1..=ny, wall (ny+2 nodes).
    Centre,
    /// Faces 0..=ny.
    Face,
    /// Wall, midpoints of neighbouring centres 1..ny-1, wall (ny+1 nodes).
    Mid,
}

/// A velocity sample: `vel[a]` and `grad[3a+b] = ∂v_a/∂x_b`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Sample {
    pub vel: [f64; 3],
    pub grad: [f64; 9],
}

/// Node positions in y for each location kind.
#[derive(Debug, Clone)]
pub struct Sampler {
    centre: Vec<f64>,
    face: Vec<f64>,
    mid: Vec<f64>,
}

impl Sampler {
    pub fn new(g: &Grid) -> Self {
        let ny = g.ny;
        let mut centre = Vec::with_capacity(ny + 2);
        centre.push(g.yf[0]);
        centre.extend_from_slice(&g.yc[1..=ny]);
        centre.push(g.yf[ny]);
        let face = g.yf.clone();
        let mut mid = Vec::with_capacity(ny + 1);
        mid.push(g.yf[0]);
        for j in 1..ny {
            mid.push(0.5 * (g.yc[j] + g.yc[j + 1]));
        }
        mid.push(g.yf[ny]);
        Self { centre, face, mid }
    }

    fn nodes(&self, y: Vy) -> &[f64] {
        match y {
            Vy::Centre => &self.centre,
            Vy::Face => &self.face,
            Vy::Mid => &self.mid,
        }
    }

    /// Samples velocity and gradient at `p` (x and z wrapped; y clamped to the channel).
    pub fn sample(&self, g: &Grid, vel: &Velocity, p: [f64; 3]) -> Sample {
        let (u, v, w) = (&vel.u, &vel.v, &vel.w);
        let px = g.px;
        let plane = g.plane();
        let ny = g.ny;
        let dx = g.dx;
        let dz = g.dz;
        // value accessors take (i, jnode, k) with i, k in 1..=nx / 1..=nz (wrapped)
        let at = |i: usize, j: usize, k: usize| i + px * j + plane * k;
        let centre_val = |f: &[f64], i: usize, jn: usize, k: usize| -> f64 {
            if jn == 0 || jn == ny + 1 {
                0.0
            } else {
                f[at(i, jn, k)]
            }
        };
        let y_mid_deriv = |f: &[f64], i: usize, jn: usize, k: usize| -> f64 {
            if jn == 0 {
                f[at(i, 1, k)] / (g.yc[1] - g.yf[0])
            } else if jn == ny {
                -f[at(i, ny, k)] / (g.yf[ny] - g.yc[ny])
            } else {
                (f[at(i, jn + 1, k)] - f[at(i, jn, k)]) / g.dyc[jn]
            }
        };
        let mut s = Sample::default();
        use Hx::{Centre as C, Face as F};
        s.vel[0] = self.interp(g, p, F, Vy::Centre, C, |i, j, k| centre_val(u, i, j, k));
        s.vel[1] = self.interp(g, p, C, Vy::Face, C, |i, j, k| v[at(i, j, k)]);
        s.vel[2] = self.interp(g, p, C, Vy::Centre, F, |i, j, k| centre_val(w, i, j, k));
        // ∂u/∂x, ∂u/∂y, ∂u/∂z
        s.grad[0] = self.interp(g, p, C, Vy::Centre, C, |i, j, k| {
            (centre_val(u, i, j, k) - centre_val(u, i - 1, j, k)) / dx
        });
        s.grad[1] = self.interp(g, p, F, Vy::Mid, C, |i, j, k| y_mid_deriv(u, i, j, k));
        s.grad[2] = self.interp(g, p, F, Vy::Centre, F, |i, j, k| {
            (centre_val(u, i, j, k + 1) - centre_val(u, i, j, k)) / dz
        });
        // ∂v/∂x, ∂v/∂y, ∂v/∂z
        s.grad[3] = self.interp(g, p, F, Vy::Face, C, |i, j, k| {
            (v[at(i + 1, j, k)] - v[at(i, j, k)]) / dx
        });
        s.grad[4] = self.interp(g, p, C, Vy::Centre, C, |i, j, k| {
            if j == 0 || j == ny + 1 {
                0.0
            } else {
                (v[at(i, j, k)] - v[at(i, j - 1, k)]) / g.dyf[j]
            }
        });
        s.grad[5] = self.interp(g, p, C, Vy::Face, F, |i, j, k| {
            (v[at(i, j, k + 1)] - v[at(i, j, k)]) / dz
        });
        // ∂w/∂x, ∂w/∂y, ∂w/∂z
        s.grad[6] = self.interp(g, p, F, Vy::Centre, F, |i, j, k| {
            (centre_val(w, i + 1, j, k) - centre_val(w, i, j, k)) / dx
        });
        s.grad[7] = self.interp(g, p, C, Vy::Mid, F, |i, j, k| y_mid_deriv(w, i, j, k));
        s.grad[8] = self.interp(g, p, C, Vy::Centre, C, |i, j, k| {
            (centre_val(w, i, j, k) - centre_val(w, i, j, k - 1)) / dz
        });
        s
    }

    /// Trilinear interpolation of a located quantity given by `val(i, jnode, k)`; the
    /// accessor may read one index either side of 1..=n (the halos hold periodic copies).
    fn interp(
        &self,
        g: &Grid,
        p: [f64; 3],
        hx: Hx,
        vy: Vy,
        hz: Hx,
        val: impl Fn(usize, usize, usize) -> f64,
    ) -> f64 {
        let (i0, fx) = periodic_bracket(p[0], g.dx, g.nx, hx);
        let (k0, fz) = periodic_bracket(p[2], g.dz, g.nz, hz);
        let nodes = self.nodes(vy);
        let (j0, fy) = bracket(nodes, p[1]);
        let i1 = if i0 == g.nx { 1 } else { i0 + 1 };
        let k1 = if k0 == g.nz { 1 } else { k0 + 1 };
        let mut acc = 0.0;
        for (jj, wy) in [(j0, 1.0 - fy), (j0 + 1, fy)] {
            for (kk, wz) in [(k0, 1.0 - fz), (k1, fz)] {
                for (ii, wx) in [(i0, 1.0 - fx), (i1, fx)] {
                    let wgt = wx * wy * wz;
                    if wgt != 0.0 {
                        acc += wgt * val(ii, jj, kk);
                    }
                }
            }
        }
        acc
    }
}

/// Lower node index in 1..=n and fraction for a periodic direction.
fn periodic_bracket(x: f64, d: f64, n: usize, h: Hx) -> (usize, f64) {
    let l = d * n as f64;
    let shift = match h {
        Hx::Centre => 0.5,
        Hx::Face => 0.0,
    };
    // node m (1..=n) sits at (m - shift) d
    let s = (x.rem_euclid(l)) / d + shift; // in [shift, n + shift)
    let mut m = s.floor();
    let mut f = s - m;
    if m < 1.0 {
        m += n as f64;
    }
    if m > n as f64 {
        m -= n as f64;
    }
    if !(0.0..=1.0).contains(&f) {
        f = f.clamp(0.0, 1.0);
    }
    (m as usize, f)
}

/// Lower node index and fraction in a sorted node list (clamped to the ends).
fn bracket(nodes: &[f64], y: f64) -> (usize, f64) {
    let n = nodes.len();
    if y <= nodes[0] {
        return (0, 0.0);
    }
    if y >= nodes[n - 1] {
        return (n - 2, 1.0);
    }
    let j = nodes.partition_point(|&v| v <= y) - 1;
    let j = j.min(n - 2);
    (j, (y - nodes[j]) / (nodes[j + 1] - nodes[j]))
}
