//! `sensor_msgs/Image` (rgb8) of a flow slice, so generic MCAP viewers show the streaks
//! with no converter. The slice's samples may be unevenly spaced (the stretched wall-normal
//! grid); the image resamples them bilinearly onto square pixels half the typical (median)
//! sample spacing of the denser axis, `axis_u` to the right and `axis_v` up (row 0 is the
//! largest v).

use crate::ros::Header;
#[cfg(test)]
use fiberflow_messages::palette::U_FLUCT_RANGE_PLUS;
use fiberflow_messages::palette::{diverging, range_for};
use fiberflow_messages::FlowSlice;
use serde::{Deserialize, Serialize};

/// No image side grows beyond this many pixels (a very fine slice is drawn coarser).
const MAX_SIDE_PX: usize = 1024;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Image {
    pub header: Header,
    pub height: u32,
    pub width: u32,
    pub encoding: String,
    pub is_bigendian: u8,
    pub step: u32,
    pub data: Vec<u8>,
}

/// Lower sample index and fraction of `x` among increasing `coords` (clamped at the ends).
fn bracket(coords: &[f64], x: f64) -> (usize, f64) {
    let n = coords.len();
    if n < 2 || x <= coords[0] {
        return (0, 0.0);
    }
    if x >= coords[n - 1] {
        return (n - 2, 1.0);
    }
    let i = coords
        .partition_point(|&c| c <= x)
        .saturating_sub(1)
        .min(n - 2);
    (i, (x - coords[i]) / (coords[i + 1] - coords[i]))
}

/// Median spacing of an increasing coordinate list (None for fewer than two samples).
fn typical_spacing(coords: &[f64]) -> Option<f64> {
    let mut d: Vec<f64> = coords.windows(2).map(|w| w[1] - w[0]).collect();
    d.sort_by(f64::total_cmp);
    d.get(d.len() / 2).copied()
}

/// Extent of an increasing coordinate list.
fn extent(coords: &[f64]) -> f64 {
    coords[coords.len() - 1] - coords[0]
}

/// Pixel positions along one axis: from the first to the last coordinate, `px` apart.
fn pixels(coords: &[f64], px: f64) -> Vec<f64> {
    let (lo, hi) = (coords[0], coords[coords.len() - 1]);
    let n = (((hi - lo) / px).round() as usize + 1).clamp(1, MAX_SIDE_PX);
    let step = if n > 1 {
        (hi - lo) / (n - 1) as f64
    } else {
        0.0
    };
    (0..n).map(|i| lo + i as f64 * step).collect()
}

/// The slice value at the pixel whose column and row lie at `(i, fu)` and `(j, fv)`
/// among the samples ([`bracket`]), bilinear between them.
fn value_at(s: &FlowSlice, (i, fu): (usize, f64), (j, fv): (usize, f64)) -> f64 {
    let nu = s.u_plus.len();
    let at = |i: usize, j: usize| {
        let i = i.min(nu - 1);
        let j = j.min(s.v_plus.len() - 1);
        s.values[j * nu + i] as f64
    };
    let lower = at(i, j) * (1.0 - fu) + at(i + 1, j) * fu;
    let upper = at(i, j + 1) * (1.0 - fu) + at(i + 1, j + 1) * fu;
    lower * (1.0 - fv) + upper * fv
}

/// Renders a checked slice (non-empty, increasing coordinates, `values` of the right
/// length) as an rgb8 image.
pub fn from_slice(s: &FlowSlice) -> Image {
    let px = match (typical_spacing(&s.u_plus), typical_spacing(&s.v_plus)) {
        (Some(a), Some(b)) => 0.5 * a.min(b),
        (Some(a), None) | (None, Some(a)) => 0.5 * a,
        (None, None) => 1.0,
    };
    let px = px
        .max(extent(&s.u_plus) / (MAX_SIDE_PX - 1) as f64)
        .max(extent(&s.v_plus) / (MAX_SIDE_PX - 1) as f64);
    let us = pixels(&s.u_plus, px);
    let mut vs = pixels(&s.v_plus, px);
    vs.reverse(); // row 0 at the top
    let (width, height) = (us.len(), vs.len());
    let mut data = Vec::with_capacity(3 * width * height);
    let range = range_for(&s.quantity, &s.values);
    // each column's and row's place among the samples, found once (not per pixel)
    let columns: Vec<(usize, f64)> = us.iter().map(|&u| bracket(&s.u_plus, u)).collect();
    let rows: Vec<(usize, f64)> = vs.iter().map(|&v| bracket(&s.v_plus, v)).collect();
    for &row in &rows {
        for &column in &columns {
            data.extend_from_slice(&diverging(value_at(s, column, row), range));
        }
    }
    Image {
        // no frame: a slice image is a picture, not a sensor in the channel frame (with a
        // frame of its own, Rerun's MCAP reader cannot place the fibres' 3-D points next to
        // it — seen when opening run.mcap)
        header: Header::at_t_plus(s.t_plus, ""),
        height: height as u32,
        width: width as u32,
        encoding: "rgb8".into(),
        is_bigendian: 0,
        step: 3 * width as u32,
        data,
    }
}

/// The image as CDR bytes.
pub fn encode(img: &Image) -> Vec<u8> {
    cdr::serialize::<_, _, cdr::CdrLe>(img, cdr::Infinite).unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A cross-section-like slice: u uniform (7 apart), v stretched, value = v / 50.
    fn slice() -> FlowSlice {
        let u_plus: Vec<f64> = (0..8).map(|i| 3.5 + 7.0 * i as f64).collect();
        let v_plus = vec![
            -150.0, -149.0, -140.0, -100.0, 0.0, 100.0, 140.0, 149.0, 150.0,
        ];
        let values = v_plus
            .iter()
            .flat_map(|&v| std::iter::repeat_n((v / 50.0) as f32, u_plus.len()))
            .collect();
        FlowSlice {
            schema_version: fiberflow_messages::SCHEMA_VERSION,
            step: 4,
            t_plus: 1.25,
            name: "cross_section".into(),
            quantity: "u_fluct_plus".into(),
            origin: vec![0.0; 3],
            axis_u: vec![0.0, 0.0, 1.0],
            axis_v: vec![0.0, 1.0, 0.0],
            u_plus,
            v_plus,
            values,
        }
    }

    #[test]
    fn image_has_square_pixels_top_row_up_and_the_palette_colours() {
        let s = slice();
        let img = from_slice(&s);
        // median spacings 7 (u) and 40 (v): pixels of 3.5, 49 / 3.5 + 1 wide, 300 / 3.5
        // (rounded) + 1 high
        assert_eq!((img.width, img.height), (15, 87));
        assert_eq!(img.step, 3 * img.width);
        assert_eq!(img.data.len(), (img.step * img.height) as usize);
        let px = |col: usize, row: usize| {
            let o = row * img.step as usize + 3 * col;
            [img.data[o], img.data[o + 1], img.data[o + 2]]
        };
        // top row is v = 150 (u' = 3), bottom v = −150, middle v = 0 (white)
        assert_eq!(px(0, 0), diverging(3.0, U_FLUCT_RANGE_PLUS));
        assert_eq!(px(14, 86), diverging(-3.0, U_FLUCT_RANGE_PLUS));
        assert_eq!(px(7, 43), diverging(0.0, U_FLUCT_RANGE_PLUS));
        // linear in v in between: row 10 is v = 150 − 10·300/86 ≈ 115, between the
        // samples at 100 and 140
        let v = 150.0 - 10.0 * 300.0 / 86.0;
        assert_eq!(px(7, 10), diverging(v / 50.0, U_FLUCT_RANGE_PLUS));
        assert_eq!(
            (img.header.stamp.sec, img.header.stamp.nanosec),
            (1, 250_000_000)
        );
        assert_eq!(img.header.frame_id, "");
    }

    #[test]
    fn cdr_bytes_decode_back_and_follow_the_schema_header() {
        let img = from_slice(&slice());
        let bytes = encode(&img);
        let back: Image = cdr::deserialize(&bytes).unwrap();
        assert_eq!(back, img);
        assert!(fiberflow_messages::schema::IMAGE.starts_with("std_msgs/Header header\n"));
    }

    #[test]
    fn one_sample_each_way_gives_one_pixel() {
        let mut s = slice();
        s.u_plus = vec![0.0];
        s.v_plus = vec![0.0];
        s.values = vec![-9.0];
        let img = from_slice(&s);
        assert_eq!((img.width, img.height), (1, 1));
        assert_eq!(img.data, diverging(-4.0, U_FLUCT_RANGE_PLUS).to_vec());
    }
}
