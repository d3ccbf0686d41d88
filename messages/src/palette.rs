//! Colour maps shared by the recorder's image channels and the viewer.

/// Colour range of the streamwise velocity fluctuation u' in flow slices, wall units
/// (±4 u_tau; white = 0, blue slow, red fast), shared by the recorder's images and the
/// viewer.
pub const U_FLUCT_RANGE_PLUS: f64 = 4.0;

/// Diverging blue–white–red for a signed value in [−range, range] (clamped outside):
/// blue slow, red fast.
pub fn diverging(x: f64, range: f64) -> [u8; 3] {
    let t = if range > 0.0 && x.is_finite() {
        (x / range).clamp(-1.0, 1.0)
    } else {
        0.0
    };
    let lerp = |a: f64, b: f64, f: f64| (a + (b - a) * f).round() as u8;
    if t < 0.0 {
        let f = -t;
        [
            lerp(247.0, 33.0, f),
            lerp(247.0, 102.0, f),
            lerp(247.0, 172.0, f),
        ]
    } else {
        [
            lerp(247.0, 178.0, t),
            lerp(247.0, 24.0, t),
            lerp(247.0, 43.0, t),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn diverging_is_white_at_zero_and_saturates() {
        assert_eq!(diverging(0.0, 4.0), [247, 247, 247]);
        assert_eq!(diverging(-4.0, 4.0), [33, 102, 172]);
        assert_eq!(diverging(9.0, 4.0), diverging(4.0, 4.0));
        assert_eq!(diverging(f64::NAN, 4.0), [247, 247, 247]);
        // blue side is bluer than red, red side redder than blue
        let (b, r) = (diverging(-2.0, 4.0), diverging(2.0, 4.0));
        assert!(b[2] > b[0] && r[0] > r[2]);
    }
}
