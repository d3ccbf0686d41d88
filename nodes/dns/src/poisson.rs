//! Direct pressure Poisson solver: real FFT in x, complex FFT in z, then one tridiagonal
//! solve in y per wavenumber pair (modified wavenumbers of the second-order stencil, so the
//! discrete projection is exact to round-off). Homogeneous Neumann conditions at the walls.

use crate::grid::Grid;
use rayon::prelude::*;
use realfft::{ComplexToReal, RealFftPlanner, RealToComplex};
use rustfft::{num_complex::Complex64, Fft, FftPlanner};
use std::sync::Arc;

/// Plans, eigenvalues and factorised tridiagonals for one grid.
pub struct Poisson {
    nx: usize,
    ny: usize,
    nz: usize,
    nxh: usize,
    r2c: Arc<dyn RealToComplex<f64>>,
    c2r: Arc<dyn ComplexToReal<f64>>,
    fwd_z: Arc<dyn Fft<f64>>,
    inv_z: Arc<dyn Fft<f64>>,
    /// Lower/upper couplings per j (independent of the wavenumbers).
    a: Vec<f64>,
    /// Per (kx, kz, j): layout `kz + nz*(j + ny*kx)`.
    inv_den: Vec<f64>,
    cp: Vec<f64>,
    /// Spectral work array, layout `kz + nz*(j + ny*kx)`.
    spec: Vec<Complex64>,
    /// x-transformed rows, layout `kx + nxh*(j + ny*k)`.
    rows: Vec<Complex64>,
}

impl std::fmt::Debug for Poisson {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Poisson({}x{}x{})", self.nx, self.ny, self.nz)
    }
}

impl Poisson {
    pub fn new(g: &Grid) -> Self {
        let (nx, ny, nz) = (g.nx, g.ny, g.nz);
        let nxh = nx / 2 + 1;
        let mut rp = RealFftPlanner::<f64>::new();
        let mut cpz = FftPlanner::<f64>::new();
        // couplings: cell-centred phi, face gradients, Neumann walls
        let mut a = vec![0.0; ny];
        let mut c = vec![0.0; ny];
        for j in 0..ny {
            let jp = j + 1; // padded
            a[j] = if j == 0 {
                0.0
            } else {
                1.0 / (g.dyf[jp] * g.dyc[jp - 1])
            };
            c[j] = if j == ny - 1 {
                0.0
            } else {
                1.0 / (g.dyf[jp] * g.dyc[jp])
            };
        }
        let lam_x: Vec<f64> = (0..nxh)
            .map(|i| {
                let s = (std::f64::consts::PI * i as f64 / nx as f64).sin();
                -4.0 * s * s / (g.dx * g.dx)
            })
            .collect();
        let lam_z: Vec<f64> = (0..nz)
            .map(|k| {
                let s = (std::f64::consts::PI * k as f64 / nz as f64).sin();
                -4.0 * s * s / (g.dz * g.dz)
            })
            .collect();
        let n = nxh * ny * nz;
        let mut inv_den = vec![0.0; n];
        let mut cp = vec![0.0; n];
        for kx in 0..nxh {
            for kz in 0..nz {
                let lam = lam_x[kx] + lam_z[kz];
                let mut prev_cp = 0.0;
                for j in 0..ny {
                    let mut b = -a[j] - c[j] + lam;
                    let mut cj = c[j];
                    let aj = a[j];
                    if kx == 0 && kz == 0 && j == 0 {
                        // pin the mean: phi_0 = 0 for the singular (0,0) mode
                        b = 1.0;
                        cj = 0.0;
                    }
                    let den = b - aj * prev_cp;
                    let id = kz + nz * (j + ny * kx);
                    inv_den[id] = 1.0 / den;
                    cp[id] = cj / den;
                    prev_cp = cp[id];
                }
            }
        }
        Self {
            nx,
            ny,
            nz,
            nxh,
            r2c: rp.plan_fft_forward(nx),
            c2r: rp.plan_fft_inverse(nx),
            fwd_z: cpz.plan_fft_forward(nz),
            inv_z: cpz.plan_fft_inverse(nz),
            a,
            inv_den,
            cp,
            spec: vec![Complex64::new(0.0, 0.0); n],
            rows: vec![Complex64::new(0.0, 0.0); n],
        }
    }

    /// Solves `L phi = rhs` where both are padded cell-centred arrays; the halo of `phi`
    /// is not touched. The (0,0) mode is pinned so that phi at the first cell is zero.
    pub fn solve(&mut self, g: &Grid, rhs: &[f64], phi: &mut [f64]) {
        let (nx, ny, nz, nxh) = (self.nx, self.ny, self.nz, self.nxh);
        let plane = g.plane();
        let px = g.px;
        // 1. real FFT in x of every (j, k) row into `rows`
        {
            let r2c = &self.r2c;
            self.rows
                .par_chunks_mut(nxh * ny)
                .enumerate()
                .for_each_init(
                    || (vec![0.0; nx], r2c.make_scratch_vec()),
                    |(inp, scratch), (k, out)| {
                        for j in 0..ny {
                            let src = (k + 1) * plane + (j + 1) * px + 1;
                            inp.copy_from_slice(&rhs[src..src + nx]);
                            // length mismatch cannot happen: buffers sized from the plan
                            let _ = r2c.process_with_scratch(
                                inp,
                                &mut out[j * nxh..(j + 1) * nxh],
                                scratch,
                            );
                        }
                    },
                );
        }
        // 2. transpose rows -> spec (kz fastest), then FFT along z, tridiagonal along y
        {
            let rows = &self.rows;
            let fwd_z = &self.fwd_z;
            let inv_z = &self.inv_z;
            let a = &self.a;
            let inv_den = &self.inv_den;
            let cp = &self.cp;
            self.spec.par_chunks_mut(ny * nz).enumerate().for_each_init(
                || vec![Complex64::new(0.0, 0.0); fwd_z.get_inplace_scratch_len().max(1)],
                |scratch, (kx, blk)| {
                    for j in 0..ny {
                        for k in 0..nz {
                            blk[j * nz + k] = rows[kx + nxh * (j + ny * k)];
                        }
                    }
                    fwd_z.process_with_scratch(blk, scratch);
                    let base = ny * nz * kx;
                    // forward sweep, vectorised over kz
                    for kz in 0..nz {
                        blk[kz] *= inv_den[base + kz];
                    }
                    for j in 1..ny {
                        let (prev, cur) = blk.split_at_mut(j * nz);
                        let prev = &prev[(j - 1) * nz..];
                        let aj = a[j];
                        for kz in 0..nz {
                            cur[kz] = (cur[kz] - prev[kz] * aj) * inv_den[base + j * nz + kz];
                        }
                    }
                    for j in (0..ny - 1).rev() {
                        let (cur, next) = blk.split_at_mut((j + 1) * nz);
                        let cur = &mut cur[j * nz..];
                        for kz in 0..nz {
                            cur[kz] -= next[kz] * cp[base + j * nz + kz];
                        }
                    }
                    inv_z.process_with_scratch(blk, scratch);
                },
            );
        }
        // 3. transpose back and inverse real FFT in x
        {
            let spec = &self.spec;
            let c2r = &self.c2r;
            let norm = 1.0 / (nx * nz) as f64;
            self.rows
                .par_chunks_mut(nxh * ny)
                .zip(phi[plane..(nz + 1) * plane].par_chunks_mut(plane))
                .enumerate()
                .for_each_init(
                    || (vec![0.0; nx], c2r.make_scratch_vec()),
                    |(outr, scratch), (k, (blk, pl))| {
                        for j in 0..ny {
                            let row = &mut blk[j * nxh..(j + 1) * nxh];
                            for (kx, r) in row.iter_mut().enumerate() {
                                *r = spec[k + nz * (j + ny * kx)];
                            }
                            row[0].im = 0.0;
                            row[nxh - 1].im = 0.0;
                            let _ = c2r.process_with_scratch(row, outr, scratch);
                            let dst = (j + 1) * px + 1;
                            for (d, s) in pl[dst..dst + nx].iter_mut().zip(outr.iter()) {
                                *d = s * norm;
                            }
                        }
                    },
                );
        }
    }
}
