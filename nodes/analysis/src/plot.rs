//! Small line-plot helper over plotters (PNG).

use crate::AnalysisError;
use plotters::prelude::*;
use std::path::Path;

/// One curve: label, points, colour index, dashed (drawn as markers) or solid.
pub struct Series {
    pub label: String,
    pub points: Vec<(f64, f64)>,
    pub colour: usize,
    pub markers: bool,
}

const PALETTE: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(80, 80, 80),
];

/// Draws the series into a PNG; `log_x`/`log_y` select logarithmic axes. Whether it drew:
/// series without a finite point (on a log axis: a positive one) draw nothing and leave no
/// file, with a warning, so that one empty figure (a recording with a single state has no
/// mean-square displacement) does not end an analysis whose other results stand.
///
/// Long (≈115 lines): one plotters chart, axes to legend, in drawing order.
pub fn line_plot(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
    log_x: bool,
    log_y: bool,
) -> Result<bool, AnalysisError> {
    let perr = |e: String| AnalysisError::Plot {
        path: path.display().to_string(),
        reason: e,
    };
    let pts = series
        .iter()
        .flat_map(|s| s.points.iter())
        .filter(|(x, y)| {
            x.is_finite() && y.is_finite() && (!log_x || *x > 0.0) && (!log_y || *y > 0.0)
        });
    let (mut x0, mut x1, mut y0, mut y1) = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    for (x, y) in pts {
        x0 = x0.min(*x);
        x1 = x1.max(*x);
        y0 = y0.min(*y);
        y1 = y1.max(*y);
    }
    if !x0.is_finite() || !y0.is_finite() {
        tracing::warn!(figure = %path.display(), "no finite points to plot: figure left out");
        return Ok(false);
    }
    if x1 <= x0 {
        x1 = x0 + 1.0;
    }
    if y1 <= y0 {
        y1 = y0 + 1.0;
    }
    if !log_y {
        let pad = 0.05 * (y1 - y0);
        y0 -= pad;
        y1 += pad;
    }
    let root = BitMapBackend::new(path, (900, 620)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| perr(e.to_string()))?;
    macro_rules! draw {
        ($xr:expr, $yr:expr) => {{
            let mut chart = ChartBuilder::on(&root)
                .caption(title, ("sans-serif", 24))
                .margin(15)
                .x_label_area_size(45)
                .y_label_area_size(70)
                .build_cartesian_2d($xr, $yr)
                .map_err(|e| perr(e.to_string()))?;
            chart
                .configure_mesh()
                .x_desc(x_label)
                .y_desc(y_label)
                .label_style(("sans-serif", 16))
                .draw()
                .map_err(|e| perr(e.to_string()))?;
            for s in series {
                let c = PALETTE[s.colour % PALETTE.len()];
                let data: Vec<(f64, f64)> = s
                    .points
                    .iter()
                    .copied()
                    .filter(|(x, y)| {
                        x.is_finite()
                            && y.is_finite()
                            && (!log_x || *x > 0.0)
                            && (!log_y || *y > 0.0)
                    })
                    .collect();
                if s.markers {
                    let a = chart
                        .draw_series(data.iter().map(|p| Circle::new(*p, 3, c.filled())))
                        .map_err(|e| perr(e.to_string()))?;
                    if !s.label.is_empty() {
                        a.label(s.label.clone())
                            .legend(move |(x, y)| Circle::new((x + 10, y), 3, c.filled()));
                    }
                } else {
                    let a = chart
                        .draw_series(LineSeries::new(data, c.stroke_width(2)))
                        .map_err(|e| perr(e.to_string()))?;
                    if !s.label.is_empty() {
                        a.label(s.label.clone()).legend(move |(x, y)| {
                            PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2))
                        });
                    }
                }
            }
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK)
                .label_font(("sans-serif", 15))
                .position(SeriesLabelPosition::UpperLeft)
                .draw()
                .map_err(|e| perr(e.to_string()))?;
        }};
    }
    match (log_x, log_y) {
        (false, false) => draw!(x0..x1, y0..y1),
        (true, false) => draw!((x0..x1).log_scale(), y0..y1),
        (false, true) => draw!(x0..x1, (y0..y1).log_scale()),
        (true, true) => draw!((x0..x1).log_scale(), (y0..y1).log_scale()),
    }
    root.present().map_err(|e| perr(e.to_string()))?;
    Ok(true)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A figure with a finite point is drawn; one without (NaN, or nothing positive on a
    /// log axis) is left out with no file and no error.
    #[test]
    fn a_figure_without_finite_points_is_left_out() {
        let dir = std::env::temp_dir().join(format!("ff-plot-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let series = |points: Vec<(f64, f64)>| Series {
            label: "s".into(),
            points,
            colour: 0,
            markers: false,
        };
        let drawn = dir.join("drawn.png");
        assert!(line_plot(
            &drawn,
            "t",
            "x",
            "y",
            &[series(vec![(1.0, 2.0), (2.0, 3.0)])],
            false,
            false
        )
        .unwrap());
        assert!(drawn.is_file());
        for (name, points, log) in [
            ("nan.png", vec![(f64::NAN, 1.0)], false),
            ("empty.png", vec![], false),
            ("log.png", vec![(0.0, 1.0), (1.0, -1.0)], true),
        ] {
            let p = dir.join(name);
            assert!(
                !line_plot(&p, "t", "x", "y", &[series(points)], log, log).unwrap(),
                "{name}"
            );
            assert!(!p.exists(), "{name}");
        }
        std::fs::remove_dir_all(&dir).ok();
    }
}
