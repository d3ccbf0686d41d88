//! Running statistics over x–z planes and time (paper figs. 3 and 4): mean and RMS
//! velocity, Reynolds shear stress, mean and RMS vorticity, wall shear (Re_tau) and bulk
//! velocity. Folded onto the half channel (lower wall to centreline).

use crate::field::Velocity;
use crate::grid::Grid;
use rayon::prelude::*;

/// Quantities accumulated per y cell (sums over samples and x–z points).
const NQ: usize = 16;
// u v w uu vv ww uv ox oy oz oxox oyoy ozoz  (3 spare)
const U: usize = 0;
const V: usize = 1;
const W: usize = 2;
const UU: usize = 3;
const VV: usize = 4;
const WW: usize = 5;
const UV: usize = 6;
const OX: usize = 7;
const OY: usize = 8;
const OZ: usize = 9;
const OXX: usize = 10;
const OYY: usize = 11;
const OZZ: usize = 12;

/// Accumulator of plane- and time-averaged statistics.
#[derive(Debug, Clone, PartialEq)]
pub struct RunningStats {
    pub samples: u64,
    /// Per cell j in 0..ny (unpadded): sums of the NQ quantities.
    sums: Vec<[f64; NQ]>,
    /// Time span covered, in viscous units (first and last sample).
    pub t_plus_first: f64,
    pub t_plus_last: f64,
}

/// A half-channel profile row in wall units (outer units have u_tau = 1, so velocities
/// are already "+" quantities; vorticities are multiplied by ν).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ProfileRow {
    pub y: f64,
    pub y_plus: f64,
    pub u_mean: f64,
    pub u_rms: f64,
    pub v_rms: f64,
    pub w_rms: f64,
    pub uv: f64,
    pub omega_z_mean: f64,
    pub omega_x_rms: f64,
    pub omega_y_rms: f64,
    pub omega_z_rms: f64,
}

/// Summary numbers of a statistics window.
#[derive(Debug, Clone, PartialEq)]
pub struct Profiles {
    pub rows: Vec<ProfileRow>,
    /// Re_tau measured from the mean wall shear, `sqrt(τ_w) h / ν`.
    pub re_tau: f64,
    /// Bulk velocity in units of the nominal u_tau.
    pub bulk_velocity: f64,
    pub samples: u64,
    pub t_plus_span: f64,
}

/// Derivative at `y1` of the parabola through three points (second order, non-uniform).
fn d3(y0: f64, f0: f64, y1: f64, f1: f64, y2: f64, f2: f64) -> f64 {
    f0 * (y1 - y2) / ((y0 - y1) * (y0 - y2))
        + f1 * (2.0 * y1 - y0 - y2) / ((y1 - y0) * (y1 - y2))
        + f2 * (y1 - y0) / ((y2 - y0) * (y2 - y1))
}

impl RunningStats {
    pub fn new(g: &Grid) -> Self {
        Self {
            samples: 0,
            sums: vec![[0.0; NQ]; g.ny],
            t_plus_first: f64::NAN,
            t_plus_last: f64::NAN,
        }
    }

    /// Serialises the running sums bit for bit (part of a coupled checkpoint: a resumed
    /// run publishes the same statistics as an uninterrupted one).
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(32 + 8 * NQ * self.sums.len());
        out.extend_from_slice(b"FFSTATS1");
        out.extend_from_slice(&self.samples.to_le_bytes());
        out.extend_from_slice(&(self.sums.len() as u64).to_le_bytes());
        out.extend_from_slice(&self.t_plus_first.to_le_bytes());
        out.extend_from_slice(&self.t_plus_last.to_le_bytes());
        for row in &self.sums {
            for x in row {
                out.extend_from_slice(&x.to_le_bytes());
            }
        }
        out
    }

    /// Parses [`Self::to_bytes`] for grid `g`; `None` if the bytes do not fit it.
    pub fn from_bytes(g: &Grid, b: &[u8]) -> Option<Self> {
        let word = |o: usize| -> Option<[u8; 8]> { b.get(o..o + 8)?.try_into().ok() };
        if b.get(..8)? != b"FFSTATS1" {
            return None;
        }
        let samples = u64::from_le_bytes(word(8)?);
        let ny = usize::try_from(u64::from_le_bytes(word(16)?)).ok()?;
        if ny != g.ny || b.len() != 40 + 8 * NQ * ny {
            return None;
        }
        let mut sums = vec![[0.0; NQ]; ny];
        let mut o = 40;
        for row in sums.iter_mut() {
            for x in row.iter_mut() {
                *x = f64::from_le_bytes(word(o)?);
                o += 8;
            }
        }
        Some(Self {
            samples,
            sums,
            t_plus_first: f64::from_le_bytes(word(24)?),
            t_plus_last: f64::from_le_bytes(word(32)?),
        })
    }

    /// Adds one snapshot (halos of `vel` must be current).
    pub fn add(&mut self, g: &Grid, vel: &Velocity, t_plus: f64) {
        let (px, nx, ny, nz) = (g.px, g.nx, g.ny, g.nz);
        let plane = g.plane();
        let (u, v, w) = (&vel.u, &vel.v, &vel.w);
        // centre values with wall nodes: y index 0 = lower wall, 1..=ny centres, ny+1 upper wall
        let uc = |i: usize, j: usize, k: usize| -> f64 {
            if j == 0 || j == ny + 1 {
                0.0
            } else {
                let n = i + px * j + plane * k;
                0.5 * (u[n] + u[n - 1])
            }
        };
        let wc = |i: usize, j: usize, k: usize| -> f64 {
            if j == 0 || j == ny + 1 {
                0.0
            } else {
                let n = i + px * j + plane * k;
                0.5 * (w[n] + w[n - plane])
            }
        };
        let vc = |i: usize, j: usize, k: usize| -> f64 {
            let n = i + px * j + plane * k;
            0.5 * (v[n] + v[n - px])
        };
        let ynode = |j: usize| -> f64 {
            if j == 0 {
                g.yf[0]
            } else if j == ny + 1 {
                g.yf[ny]
            } else {
                g.yc[j]
            }
        };
        let rows: Vec<[f64; NQ]> = (1..=ny)
            .into_par_iter()
            .map(|j| {
                let mut acc = [0.0; NQ];
                let (y0, y1, y2) = (ynode(j - 1), ynode(j), ynode(j + 1));
                for k in 1..=nz {
                    for i in 1..=nx {
                        let (uu, vv, ww) = (uc(i, j, k), vc(i, j, k), wc(i, j, k));
                        let dudy = d3(y0, uc(i, j - 1, k), y1, uu, y2, uc(i, j + 1, k));
                        let dwdy = d3(y0, wc(i, j - 1, k), y1, ww, y2, wc(i, j + 1, k));
                        let ip = if i == nx { 1 } else { i + 1 };
                        let im = if i == 1 { nx } else { i - 1 };
                        let kp = if k == nz { 1 } else { k + 1 };
                        let km = if k == 1 { nz } else { k - 1 };
                        let dvdx = (vc(ip, j, k) - vc(im, j, k)) / (2.0 * g.dx);
                        let dvdz = (vc(i, j, kp) - vc(i, j, km)) / (2.0 * g.dz);
                        let dudz = (uc(i, j, kp) - uc(i, j, km)) / (2.0 * g.dz);
                        let dwdx = (wc(ip, j, k) - wc(im, j, k)) / (2.0 * g.dx);
                        let ox = dwdy - dvdz;
                        let oy = dudz - dwdx;
                        let oz = dvdx - dudy;
                        acc[U] += uu;
                        acc[V] += vv;
                        acc[W] += ww;
                        acc[UU] += uu * uu;
                        acc[VV] += vv * vv;
                        acc[WW] += ww * ww;
                        acc[UV] += uu * vv;
                        acc[OX] += ox;
                        acc[OY] += oy;
                        acc[OZ] += oz;
                        acc[OXX] += ox * ox;
                        acc[OYY] += oy * oy;
                        acc[OZZ] += oz * oz;
                    }
                }
                let norm = 1.0 / (nx * nz) as f64;
                acc.iter_mut().for_each(|a| *a *= norm);
                acc
            })
            .collect();
        for (s, r) in self.sums.iter_mut().zip(rows) {
            for q in 0..NQ {
                s[q] += r[q];
            }
        }
        if self.samples == 0 {
            self.t_plus_first = t_plus;
        }
        self.t_plus_last = t_plus;
        self.samples += 1;
    }

    /// Folded half-channel profiles (lower half plus mirrored upper half).
    pub fn profiles(&self, g: &Grid, re_tau_nominal: f64) -> Profiles {
        let ny = g.ny;
        let n = self.samples.max(1) as f64;
        let mean = |j: usize, q: usize| self.sums[j][q] / n;
        let mut rows = Vec::with_capacity(ny / 2);
        for j in 0..ny / 2 {
            let jm = ny - 1 - j; // mirror cell
                                 // fold: u, w, uu, vv, ww, oxx.. symmetric; v, uv, oz antisymmetric
            let um = 0.5 * (mean(j, U) + mean(jm, U));
            let vm_lo = mean(j, V);
            let vm_hi = mean(jm, V);
            let var = |jj: usize, q2: usize, q1: usize| mean(jj, q2) - mean(jj, q1).powi(2);
            let uvar = 0.5 * (var(j, UU, U) + var(jm, UU, U));
            let vvar = 0.5 * (var(j, VV, V) + var(jm, VV, V));
            let wvar = 0.5 * (var(j, WW, W) + var(jm, WW, W));
            let cov_lo = mean(j, UV) - mean(j, U) * vm_lo;
            let cov_hi = mean(jm, UV) - mean(jm, U) * vm_hi;
            let uv = 0.5 * (cov_lo - cov_hi);
            let ozm = 0.5 * (mean(j, OZ) - mean(jm, OZ));
            let oxv = 0.5 * (var(j, OXX, OX) + var(jm, OXX, OX));
            let oyv = 0.5 * (var(j, OYY, OY) + var(jm, OYY, OY));
            let ozv = 0.5 * (var(j, OZZ, OZ) + var(jm, OZZ, OZ));
            let nu = 1.0 / re_tau_nominal;
            let y = g.yc[j + 1] - g.yf[0];
            rows.push(ProfileRow {
                y,
                y_plus: y * re_tau_nominal,
                u_mean: um,
                u_rms: uvar.max(0.0).sqrt(),
                v_rms: vvar.max(0.0).sqrt(),
                w_rms: wvar.max(0.0).sqrt(),
                uv,
                omega_z_mean: ozm * nu,
                omega_x_rms: oxv.max(0.0).sqrt() * nu,
                omega_y_rms: oyv.max(0.0).sqrt() * nu,
                omega_z_rms: ozv.max(0.0).sqrt() * nu,
            });
        }
        // wall shear from the parabola through the wall and the first two centres
        let (y1, y2) = (rows[0].y, rows[1].y);
        let (u1, u2) = (rows[0].u_mean, rows[1].u_mean);
        let dudy_wall = (u1 * y2 * y2 - u2 * y1 * y1) / (y1 * y2 * (y2 - y1));
        let tau_w = dudy_wall / re_tau_nominal;
        let mut bulk = 0.0;
        for j in 0..ny {
            bulk += mean(j, U) * g.dyf[j + 1];
        }
        Profiles {
            rows,
            re_tau: tau_w.max(0.0).sqrt() * re_tau_nominal,
            bulk_velocity: bulk / 2.0,
            samples: self.samples,
            t_plus_span: self.t_plus_last - self.t_plus_first,
        }
    }
}

impl Profiles {
    /// CSV with a header line; wall units.
    pub fn to_csv(&self) -> String {
        let mut s = String::from(
            "y_over_h,y_plus,u_mean_plus,u_rms_plus,v_rms_plus,w_rms_plus,uv_plus,omega_z_mean_plus,omega_x_rms_plus,omega_y_rms_plus,omega_z_rms_plus\n",
        );
        for r in &self.rows {
            s.push_str(&format!(
                "{:.6},{:.4},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6}\n",
                r.y,
                r.y_plus,
                r.u_mean,
                r.u_rms,
                r.v_rms,
                r.w_rms,
                r.uv,
                r.omega_z_mean,
                r.omega_x_rms,
                r.omega_y_rms,
                r.omega_z_rms
            ));
        }
        s
    }
}

/// Instantaneous Re_tau from the plane-averaged wall shear of both walls (second-order
/// one-sided derivative through the wall and the first two cell centres).
pub fn wall_re_tau(g: &Grid, vel: &Velocity, re_tau_nominal: f64) -> f64 {
    let (nx, ny, nz) = (g.nx, g.ny, g.nz);
    let mean_row = |j: usize| -> f64 {
        let mut s = 0.0;
        for k in 1..=nz {
            for i in 1..=nx {
                s += vel.u[g.idx(i, j, k)];
            }
        }
        s / (nx * nz) as f64
    };
    let slope =
        |y1: f64, u1: f64, y2: f64, u2: f64| (u1 * y2 * y2 - u2 * y1 * y1) / (y1 * y2 * (y2 - y1));
    let lo = slope(
        g.yc[1] - g.yf[0],
        mean_row(1),
        g.yc[2] - g.yf[0],
        mean_row(2),
    );
    let hi = slope(
        g.yf[ny] - g.yc[ny],
        mean_row(ny),
        g.yf[ny] - g.yc[ny - 1],
        mean_row(ny - 1),
    );
    let tau = 0.5 * (lo + hi) / re_tau_nominal;
    tau.max(0.0).sqrt() * re_tau_nominal
}
