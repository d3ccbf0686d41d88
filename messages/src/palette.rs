//! Colour maps shared by the recorder's image channels and the viewer.

/// Colour range of the streamwise velocity fluctuation u' in flow slices, wall units
/// (±4 u_tau; white = 0, blue slow, red fast), shared by the recorder's images and the
/// viewer.
pub const U_FLUCT_RANGE_PLUS: f64 = 4.0;

/// The `quantity` of a slice of the fibres' streamwise force on the fluid per unit volume
/// (two-way coupling), wall units.
pub const FIBER_FORCE_QUANTITY: &str = "fiber_force_x_plus";

/// Colour range of a slice's values: ±[`U_FLUCT_RANGE_PLUS`] for u'; for any other
/// quantity (the fibres' force, which has no natural scale) the 99th percentile of |value|
/// over the slice, so the strongest 1% saturate (1 when every value is 0).
pub fn range_for(quantity: &str, values: &[f32]) -> f64 {
    if quantity == "u_fluct_plus" {
        return U_FLUCT_RANGE_PLUS;
    }
    let mut a: Vec<f32> = values
        .iter()
        .map(|v| v.abs())
        .filter(|v| v.is_finite())
        .collect();
    if a.is_empty() {
        return 1.0;
    }
    let k = ((a.len() - 1) as f64 * 0.99).round() as usize;
    let (_, x, _) = a.select_nth_unstable_by(k, f32::total_cmp);
    if *x > 0.0 {
        f64::from(*x)
    } else {
        1.0
    }
}

/// Diverging blue–white–red for a signed value in [−range, range] (clamped outside):
/// blue slow, red fast.
pub fn diverging(x: f64, range: f64) -> [u8; 3] {
    let t = if range > 0.0 && x.is_finite() {
        (x / range).clamp(-1.0, 1.0)
    } else {
        0.0
    };
    // a channel lies in [24, 247]: rounded half up by its integer part and fraction (the
    // same bits as `round`, without a call into the C library for every pixel)
    let lerp = |a: f64, b: f64, f: f64| {
        let x = a + (b - a) * f;
        let whole = x as u8;
        if x - f64::from(whole) >= 0.5 {
            whole + 1
        } else {
            whole
        }
    };
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

    /// u' keeps its fixed ±4; another quantity takes its slice's 99th percentile of |value|
    /// (values 1..=100 in any order: 99), and an all-zero slice 1.
    #[test]
    fn ranges_by_quantity() {
        assert_eq!(range_for("u_fluct_plus", &[100.0]), U_FLUCT_RANGE_PLUS);
        let v: Vec<f32> = (1..=100)
            .rev()
            .map(|x| if x % 2 == 0 { x as f32 } else { -(x as f32) })
            .collect();
        assert_eq!(range_for(FIBER_FORCE_QUANTITY, &v), 99.0);
        assert_eq!(range_for(FIBER_FORCE_QUANTITY, &[0.0; 5]), 1.0);
        assert_eq!(range_for(FIBER_FORCE_QUANTITY, &[]), 1.0);
    }

    #[test]
    fn diverging_rounds_as_round_does() {
        let reference = |x: f64, range: f64| {
            let t = if range > 0.0 && x.is_finite() {
                (x / range).clamp(-1.0, 1.0)
            } else {
                0.0
            };
            let lerp = |a: f64, b: f64, f: f64| (a + (b - a) * f).round() as u8;
            if t < 0.0 {
                [
                    lerp(247.0, 33.0, -t),
                    lerp(247.0, 102.0, -t),
                    lerp(247.0, 172.0, -t),
                ]
            } else {
                [
                    lerp(247.0, 178.0, t),
                    lerp(247.0, 24.0, t),
                    lerp(247.0, 43.0, t),
                ]
            }
        };
        // a dense sweep of [−range, range]
        for i in -200_000..=200_000 {
            let x = i as f64 * 1e-5;
            assert_eq!(diverging(x, 2.0), reference(x, 2.0), "at {x}");
        }
        // and the values where a channel is an integer and a half: a + (b − a) f with
        // f = (k + ½) / |b − a|, on both sides
        for (end, sign) in [
            (33.0, -1.0),
            (102.0, -1.0),
            (172.0, -1.0),
            (178.0, 1.0),
            (24.0, 1.0),
            (43.0, 1.0),
        ] {
            let span: f64 = (247.0_f64 - end).abs();
            for k in 0..span as i64 {
                let x = sign * 2.0 * (k as f64 + 0.5) / span;
                assert_eq!(diverging(x, 2.0), reference(x, 2.0), "at {x}");
            }
        }
    }

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
