//! Entity paths of the scene. Each shown fibre is one entity,
//! `fibers/<case>/<layer>/f<index>`, carrying its gallery strip, its channel strip and its
//! four time series, so selecting it anywhere highlights it everywhere.

/// Name of an initial layer (paper §4.3: near wall, next, middle).
pub fn layer_name(layer: u8) -> &'static str {
    match layer {
        0 => "near_wall",
        1 => "next",
        2 => "middle",
        _ => "other",
    }
}

/// The entity of fibre `index` of `group`; indices are zero-padded to `digits` so entities
/// sort in fibre order.
pub fn fiber(group: &str, layer: u8, index: usize, digits: usize) -> String {
    format!("fibers/{group}/{}/f{index:0digits$}", layer_name(layer))
}

/// Digits needed to write every index of a group of `n` fibres.
pub fn digits(n: usize) -> usize {
    n.saturating_sub(1).max(1).to_string().len()
}

/// The coiling-onset marker over a fibre's gallery cell (`fibre` as from [`fibre`]).
pub fn onset(fiber: &str) -> String {
    format!("gallery/onsets/{}", fiber.trim_start_matches("fibers/"))
}

/// Text log of a case's coiling events.
pub fn events(group: &str) -> String {
    format!("events/{group}")
}

/// Label of a case's gallery band.
pub fn band_label(group: &str) -> String {
    format!("gallery/labels/{group}")
}

/// The custom components every fibre entity carries (archetype `fibre`): its channel-view
/// strip and its four time series. Plots and the channel view map them onto the standard
/// visualizers; the gallery uses the entity's standard `LineStrips2D`.
pub const ARCHETYPE: &str = "fiber";
pub const CHANNEL_STRIP: &str = "channel_strip";

/// One of the four per-fibre time series.
pub struct Series {
    /// The custom component it is logged as.
    pub component: &'static str,
    /// Name of its tab of plots.
    pub title: &'static str,
    /// Name in a plot's title, before the case.
    pub short: &'static str,
}

/// The four per-fibre time series.
pub const SERIES: [Series; 4] = [
    Series {
        component: "sigma2",
        title: "σ² (coiling; 0 straight)",
        short: "σ²",
    },
    Series {
        component: "abs_z1",
        title: "|z1| (alignment; 1 along the flow)",
        short: "|z1|",
    },
    Series {
        component: "end_to_end",
        title: "end-to-end distance (wall units)",
        short: "end-to-end",
    },
    Series {
        component: "x2_plus",
        title: "wall distance x2+ (wall units)",
        short: "x2+",
    },
];

/// The full name of a custom component as mappings refer to it.
pub fn component(name: &str) -> String {
    format!("{ARCHETYPE}:{name}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fiber_paths_name_case_layer_and_index_in_sort_order() {
        assert_eq!(digits(50), 2);
        assert_eq!(digits(10_000), 4);
        assert_eq!(digits(1), 1);
        assert_eq!(fiber("case1", 0, 7, 2), "fibers/case1/near_wall/f07");
        assert_eq!(fiber("case6", 2, 9999, 4), "fibers/case6/middle/f9999");
        assert_eq!(
            onset(&fiber("case2", 1, 3, 2)),
            "gallery/onsets/case2/next/f03"
        );
        let mut v: Vec<String> = (0..12).map(|i| fiber("g", 1, i, digits(12))).collect();
        let sorted = {
            let mut s = v.clone();
            s.sort();
            s
        };
        assert_eq!(v, sorted);
        v.dedup();
        assert_eq!(v.len(), 12);
        assert_eq!(component("sigma2"), "fiber:sigma2");
    }
}
