//! Flow validation (paper §3.2, figs. 3–4): our statistics CSV against reference DNS in
//! inner units near the wall, with a table of the acceptance numbers and PNG plots.

use crate::plot::{line_plot, Series};
use crate::reference::{interp, Reference};
use crate::{io_err, AnalysisError};
use std::path::Path;

/// Our folded profile as read from `stats.csv`.
#[derive(Debug, Clone, Default)]
pub struct Ours {
    pub cols: Vec<Vec<f64>>,
}

impl Ours {
    pub fn read(path: &Path) -> Result<Self, AnalysisError> {
        let text = std::fs::read_to_string(path).map_err(io_err(path))?;
        let mut cols = vec![Vec::new(); 11];
        for l in text.lines().skip(1) {
            let v: Vec<f64> = l.split(',').filter_map(|t| t.trim().parse().ok()).collect();
            if v.len() == 11 {
                for (c, x) in cols.iter_mut().zip(v) {
                    c.push(x);
                }
            }
        }
        if cols[0].is_empty() {
            return Err(AnalysisError::Data(format!("{}: no rows", path.display())));
        }
        Ok(Self { cols })
    }
    fn col(&self, i: usize) -> &[f64] {
        &self.cols[i]
    }

    /// The Re_tau the statistics are scaled with: y+ / (y/h), from the row nearest the
    /// centre (the largest y/h, least affected by rounding in the CSV).
    pub fn re_tau(&self) -> f64 {
        let (y, yp) = (self.col(0), self.col(1));
        let mut best = (0.0, f64::NAN);
        for (a, b) in y.iter().zip(yp) {
            if *a > best.0 {
                best = (*a, b / a);
            }
        }
        best.1
    }
}

/// The acceptance numbers.
#[derive(Debug, Clone)]
pub struct Comparison {
    pub max_u_error_below_50: f64,
    pub y_plus_of_max_u_error: f64,
    pub peak_u_rms: f64,
    pub peak_u_rms_y_plus: f64,
    pub ref_peak_u_rms: f64,
    pub ref_peak_u_rms_y_plus: f64,
}

pub fn compare(ours: &Ours, r: &Reference) -> Comparison {
    let (yp, u, urms) = (ours.col(1), ours.col(2), ours.col(3));
    let (mut emax, mut ye) = (0.0f64, 0.0);
    for (y, uu) in yp.iter().zip(u) {
        if *y < 50.0 {
            let ur = interp(&r.y_plus, &r.u_mean, *y);
            let e = (uu - ur).abs() / ur;
            if e > emax {
                emax = e;
                ye = *y;
            }
        }
    }
    let (i, _) = urms.iter().enumerate().fold(
        (0, f64::MIN),
        |a, (i, v)| if *v > a.1 { (i, *v) } else { a },
    );
    let (ri, _) =
        r.u_rms.iter().enumerate().fold(
            (0, f64::MIN),
            |a, (i, v)| if *v > a.1 { (i, *v) } else { a },
        );
    Comparison {
        max_u_error_below_50: emax,
        y_plus_of_max_u_error: ye,
        peak_u_rms: urms[i],
        peak_u_rms_y_plus: yp[i],
        ref_peak_u_rms: r.u_rms[ri],
        ref_peak_u_rms_y_plus: r.y_plus[ri],
    }
}

/// Writes `flow_u_mean.png`, `flow_rms.png`, `flow_vorticity_rms.png` and returns a
/// markdown table against each reference.
///
/// Long (≈130 lines): three figures and one table, in the order the summary shows them.
pub fn report(stats_csv: &Path, refs: &[Reference], out: &Path) -> Result<String, AnalysisError> {
    std::fs::create_dir_all(out).map_err(io_err(out))?;
    let ours = Ours::read(stats_csv)?;
    let re_tau = ours.re_tau();
    let yp = ours.col(1).to_vec();
    let pts = |c: usize| {
        yp.iter()
            .copied()
            .zip(ours.col(c).iter().copied())
            .collect::<Vec<_>>()
    };
    let rpts = |r: &Reference, v: &[f64]| {
        r.y_plus
            .iter()
            .copied()
            .zip(v.iter().copied())
            .collect::<Vec<_>>()
    };
    let mut s = vec![Series {
        label: "fiberflow U+".into(),
        points: pts(2),
        colour: 0,
        markers: false,
    }];
    for (i, r) in refs.iter().enumerate() {
        s.push(Series {
            label: r.name.clone(),
            points: rpts(r, &r.u_mean),
            colour: 3 + i,
            markers: true,
        });
    }
    line_plot(
        &out.join("flow_u_mean.png"),
        "Mean velocity (inner units)",
        "y+",
        "U+",
        &s,
        true,
        false,
    )?;
    let mut s = Vec::new();
    for (c, n) in [(3, "u'"), (4, "v'"), (5, "w'")] {
        s.push(Series {
            label: format!("fiberflow {n}rms+"),
            points: pts(c),
            colour: c - 3,
            markers: false,
        });
    }
    s.push(Series {
        label: "fiberflow -u'v'+".into(),
        points: yp.iter().zip(ours.col(6)).map(|(a, b)| (*a, -b)).collect(),
        colour: 6,
        markers: false,
    });
    if let Some(r) = refs.first() {
        for (v, c) in [(&r.u_rms, 0), (&r.v_rms, 1), (&r.w_rms, 2)] {
            s.push(Series {
                label: String::new(),
                points: rpts(r, v),
                colour: c,
                markers: true,
            });
        }
        s.push(Series {
            label: format!("{} (markers)", r.name),
            points: rpts(r, &r.uv.iter().map(|x| -x).collect::<Vec<_>>()),
            colour: 6,
            markers: true,
        });
    }
    line_plot(
        &out.join("flow_rms.png"),
        "RMS velocity and Reynolds stress",
        "y+",
        "rms+",
        &s,
        false,
        false,
    )?;
    let mut s = Vec::new();
    for (c, n) in [(8, "x"), (9, "y"), (10, "z")] {
        s.push(Series {
            label: format!("fiberflow omega_{n} rms+"),
            points: pts(c),
            colour: c - 8,
            markers: false,
        });
    }
    if let Some(r) = refs.first() {
        for (v, c) in [
            (&r.omega_x_rms, 0),
            (&r.omega_y_rms, 1),
            (&r.omega_z_rms, 2),
        ] {
            s.push(Series {
                label: String::new(),
                points: rpts(r, v),
                colour: c,
                markers: true,
            });
        }
    }
    line_plot(
        &out.join("flow_vorticity_rms.png"),
        "RMS vorticity (markers: reference)",
        "y+",
        "omega rms+",
        &s,
        false,
        false,
    )?;
    let mut md =
        format!("Flow statistics at Re_tau = {re_tau:.2} vs reference DNS (inner units):\n\n");
    md.push_str("| reference | max U+ error, y+ < 50 | peak u'rms+ (y+) | reference peak (y+) |\n|---|---|---|---|\n");
    for r in refs {
        let c = compare(&ours, r);
        md.push_str(&format!(
            "| {} | {:.2}% (at y+ = {:.1}) | {:.3} ({:.1}) | {:.3} ({:.1}) |\n",
            r.name,
            100.0 * c.max_u_error_below_50,
            c.y_plus_of_max_u_error,
            c.peak_u_rms,
            c.peak_u_rms_y_plus,
            c.ref_peak_u_rms,
            c.ref_peak_u_rms_y_plus
        ));
    }
    Ok(md)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The report's Re_tau is read from the statistics (y+ over y/h), not assumed.
    #[test]
    fn re_tau_comes_from_the_statistics() {
        let dir = std::env::temp_dir().join(format!("ff-flowval-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("stats.csv");
        let row = |y: f64| format!("{y},{},1,1,1,1,-0.5,-1,0.1,0.1,0.1\n", y * 178.12);
        let text = format!("header\n{}{}", row(0.002), row(0.95));
        std::fs::write(&p, text).unwrap();
        let ours = Ours::read(&p).unwrap();
        assert!((ours.re_tau() - 178.12).abs() < 1e-9, "{}", ours.re_tau());
        std::fs::remove_dir_all(&dir).ok();
    }
}
