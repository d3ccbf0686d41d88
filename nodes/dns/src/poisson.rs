//! Direct pressure Poisson solver: real FFT in x, complex FFT in z, then one tridiagonal
//! solve in y per wavenumber pair (modified wavenumbers of the second-order stencil, so the
//! discrete projection is exact to round-off). Homogeneous Neumann conditions at the walls.

use crate::field::Velocity;
use crate::grid::Grid;
use rayon::prelude::*;
use realfft::{ComplexToReal, RealFftPlanner, RealToComplex};
use rustfft::{num_complex::Complex64, Fft, FftPlanner};
use std::sync::Arc;

/// Wavenumbers (or planes) per parallel task in the transposes: 4 complex values fill a
/// 64-byte cache line.
const BLOCK: usize = 4;

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
        let (plane, px, nx) = (g.plane(), g.px, g.nx);
        self.solve_rows(g, phi, |k, j, row| {
            let src = (k + 1) * plane + (j + 1) * px + 1;
            row.copy_from_slice(&rhs[src..src + nx]);
        });
    }

    /// Solves `L phi = scale · div(u)` with the divergence formed on the fly in the first
    /// pass (the same arithmetic as [`crate::correct::divergence`], without the array).
    pub fn solve_divergence(&mut self, g: &Grid, vel: &Velocity, scale: f64, phi: &mut [f64]) {
        self.solve_rows(g, phi, |k, j, row| {
            crate::correct::divergence_row(g, vel, scale, k + 1, j + 1, row)
        });
    }

    /// The solver proper; `fill(k, j, row)` writes the right-hand side of interior row
    /// (j, k) (0-based) into `row` (nx values).
    ///
    /// Long (≈125 lines): its numbered stages (FFT in x, FFT in z, tridiagonal solves in
    /// y, inverse transforms) share the row buffers and read as the method.
    fn solve_rows(
        &mut self,
        g: &Grid,
        phi: &mut [f64],
        fill: impl Fn(usize, usize, &mut [f64]) + Sync,
    ) {
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
                            fill(k, j, inp);
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
        // 2. transpose rows -> spec (kz fastest), then FFT along z, tridiagonal along y.
        // Each task takes BLOCK consecutive kx so every cache line of `rows` it touches is
        // used whole (the transpose reads are strided by nxh*ny).
        {
            let rows = &self.rows;
            let fwd_z = &self.fwd_z;
            let inv_z = &self.inv_z;
            let a = &self.a;
            let inv_den = &self.inv_den;
            let cp = &self.cp;
            self.spec
                .par_chunks_mut(BLOCK * ny * nz)
                .enumerate()
                .for_each_init(
                    || vec![Complex64::new(0.0, 0.0); fwd_z.get_inplace_scratch_len().max(1)],
                    |scratch, (kb, blks)| {
                        let kx0 = kb * BLOCK;
                        let nb = blks.len() / (ny * nz);
                        for k in 0..nz {
                            for j in 0..ny {
                                let src = kx0 + nxh * (j + ny * k);
                                for (b, r) in rows[src..src + nb].iter().enumerate() {
                                    blks[b * ny * nz + j * nz + k] = *r;
                                }
                            }
                        }
                        for (b, blk) in blks.chunks_mut(ny * nz).enumerate() {
                            fwd_z.process_with_scratch(blk, scratch);
                            let base = ny * nz * (kx0 + b);
                            // forward sweep, vectorised over kz
                            for kz in 0..nz {
                                blk[kz] *= inv_den[base + kz];
                            }
                            for j in 1..ny {
                                let (prev, cur) = blk.split_at_mut(j * nz);
                                let prev = &prev[(j - 1) * nz..];
                                let aj = a[j];
                                let id = &inv_den[base + j * nz..base + (j + 1) * nz];
                                for ((c, p), d) in cur[..nz].iter_mut().zip(prev).zip(id) {
                                    *c = (*c - p * aj) * d;
                                }
                            }
                            for j in (0..ny - 1).rev() {
                                let (cur, next) = blk.split_at_mut((j + 1) * nz);
                                let cur = &mut cur[j * nz..];
                                let cj = &cp[base + j * nz..base + (j + 1) * nz];
                                for ((c, n), q) in cur.iter_mut().zip(&next[..nz]).zip(cj) {
                                    *c -= n * q;
                                }
                            }
                            inv_z.process_with_scratch(blk, scratch);
                        }
                    },
                );
        }
        // 3. transpose back (BLOCK planes per task, for the same cache reason) and inverse
        // real FFT in x
        {
            let spec = &self.spec;
            let c2r = &self.c2r;
            let norm = 1.0 / (nx * nz) as f64;
            self.rows
                .par_chunks_mut(BLOCK * nxh * ny)
                .zip(phi[plane..(nz + 1) * plane].par_chunks_mut(BLOCK * plane))
                .enumerate()
                .for_each_init(
                    || (vec![0.0; nx], c2r.make_scratch_vec()),
                    |(outr, scratch), (kb, (blks, pls))| {
                        let k0 = kb * BLOCK;
                        let nb = blks.len() / (nxh * ny);
                        for j in 0..ny {
                            for kx in 0..nxh {
                                let src = k0 + nz * (j + ny * kx);
                                for (b, v) in spec[src..src + nb].iter().enumerate() {
                                    blks[b * nxh * ny + j * nxh + kx] = *v;
                                }
                            }
                        }
                        for (blk, pl) in blks.chunks_mut(nxh * ny).zip(pls.chunks_mut(plane)) {
                            for j in 0..ny {
                                let row = &mut blk[j * nxh..(j + 1) * nxh];
                                row[0].im = 0.0;
                                row[nxh - 1].im = 0.0;
                                let _ = c2r.process_with_scratch(row, outr, scratch);
                                let dst = (j + 1) * px + 1;
                                for (d, s) in pl[dst..dst + nx].iter_mut().zip(outr.iter()) {
                                    *d = s * norm;
                                }
                            }
                        }
                    },
                );
        }
    }
}
