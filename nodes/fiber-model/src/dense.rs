//! Dense regularised solve of the joint-force system (paper §2.5: Tikhonov regularisation),
//! with faer: minimise |A x − b|² + λ_eff |x|², λ_eff = λ · tr(AᵀA)/dim.

use faer::linalg::solvers::Solve;
use faer::Mat;
use nalgebra::{DMatrix, DVector};

/// Solves (AᵀA + λ_eff I) x = Aᵀ b; None if the result is not finite.
pub fn tikhonov_solve(a: &DMatrix<f64>, b: &DVector<f64>, lambda: f64) -> Option<DVector<f64>> {
    let n = a.ncols();
    let fa = Mat::<f64>::from_fn(a.nrows(), n, |i, j| a[(i, j)]);
    let fb = Mat::<f64>::from_fn(b.len(), 1, |i, _| b[i]);
    let ata = fa.transpose() * &fa;
    let trace: f64 = (0..n).map(|i| ata[(i, i)]).sum();
    let lam = lambda * trace / n as f64;
    let reg = Mat::<f64>::from_fn(n, n, |i, j| ata[(i, j)] + if i == j { lam } else { 0.0 });
    let atb = fa.transpose() * &fb;
    let x = reg.partial_piv_lu().solve(&atb);
    let out = DVector::from_fn(n, |i, _| x[(i, 0)]);
    out.iter().all(|v| v.is_finite()).then_some(out)
}
