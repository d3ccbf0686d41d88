//! Reference DNS profiles (Moser, Kim & Mansour 1999, Re_tau = 178; Hoyas & Jiménez data,
//! Re_tau = 186), read from the whitespace-separated files in `shared/reference/`.

use crate::{io_err, AnalysisError};
use std::path::Path;

/// Inner-scaled reference profile (half channel).
#[derive(Debug, Clone, Default)]
pub struct Reference {
    pub name: String,
    pub re_tau: f64,
    pub y_plus: Vec<f64>,
    pub u_mean: Vec<f64>,
    pub u_rms: Vec<f64>,
    pub v_rms: Vec<f64>,
    pub w_rms: Vec<f64>,
    pub uv: Vec<f64>,
    pub omega_x_rms: Vec<f64>,
    pub omega_y_rms: Vec<f64>,
    pub omega_z_rms: Vec<f64>,
}

fn rows(path: &Path, comment: char) -> Result<Vec<Vec<f64>>, AnalysisError> {
    let text = std::fs::read_to_string(path).map_err(io_err(path))?;
    Ok(text
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with(comment))
        .map(|l| {
            l.split_whitespace()
                .filter_map(|t| t.parse::<f64>().ok())
                .collect::<Vec<_>>()
        })
        .filter(|r| !r.is_empty())
        .collect())
}

/// Hoyas & Jiménez `Re180.prof` (columns documented in shared/reference/README.md).
pub fn hoyas_jimenez(path: &Path) -> Result<Reference, AnalysisError> {
    let r = rows(path, '%')?;
    if r.iter().any(|x| x.len() < 11) {
        return Err(AnalysisError::Data(format!(
            "{}: expected >= 11 columns",
            path.display()
        )));
    }
    let col = |c: usize| r.iter().map(|x| x[c]).collect::<Vec<_>>();
    Ok(Reference {
        name: "Hoyas & Jiménez, Re_tau 186".into(),
        re_tau: 186.34,
        y_plus: col(1),
        u_mean: col(2),
        u_rms: col(3),
        v_rms: col(4),
        w_rms: col(5),
        omega_x_rms: col(7),
        omega_y_rms: col(8),
        omega_z_rms: col(9),
        uv: col(10),
    })
}

/// MKM `chan180.means` + `.reystress` + `.vortvar`.
pub fn mkm(dir: &Path) -> Result<Reference, AnalysisError> {
    let m = rows(&dir.join("MKM_chan180.means"), '#')?;
    let s = rows(&dir.join("MKM_chan180.reystress"), '#')?;
    let v = rows(&dir.join("MKM_chan180.vortvar"), '#')?;
    if m.len() != s.len() || m.len() != v.len() {
        return Err(AnalysisError::Data(
            "MKM files have different row counts".into(),
        ));
    }
    Ok(Reference {
        name: "Moser, Kim & Mansour, Re_tau 178".into(),
        re_tau: 178.12,
        y_plus: m.iter().map(|r| r[1]).collect(),
        u_mean: m.iter().map(|r| r[2]).collect(),
        u_rms: s.iter().map(|r| r[2].sqrt()).collect(),
        v_rms: s.iter().map(|r| r[3].sqrt()).collect(),
        w_rms: s.iter().map(|r| r[4].sqrt()).collect(),
        uv: s.iter().map(|r| r[5]).collect(),
        omega_x_rms: v.iter().map(|r| r[2].sqrt()).collect(),
        omega_y_rms: v.iter().map(|r| r[3].sqrt()).collect(),
        omega_z_rms: v.iter().map(|r| r[4].sqrt()).collect(),
    })
}

/// Linear interpolation in a monotone table (clamped).
pub fn interp(xs: &[f64], ys: &[f64], x: f64) -> f64 {
    if xs.is_empty() {
        return f64::NAN;
    }
    if x <= xs[0] {
        return ys[0];
    }
    for i in 1..xs.len() {
        if x <= xs[i] {
            let f = (x - xs[i - 1]) / (xs[i] - xs[i - 1]);
            return ys[i - 1] + f * (ys[i] - ys[i - 1]);
        }
    }
    ys[ys.len() - 1]
}
