//! How much fibre a run carries: mass loading (fibre mass over fluid mass) and volume
//! fraction over the channel box, printed when a launch starts, with the coupling it asks
//! for (docs/two-way.md).

use crate::launchfile::{Coupling, LaunchFile};
use anyhow::Result;

/// Above this mass loading one-way coupling is usually no longer physics (the fibres'
/// drag changes the flow noticeably; e.g. Elghobashi's map, and Gualtieri et al. 2023 find
/// a drag change at 0.4).
pub const ONE_WAY_MASS_LOADING_LIMIT: f64 = 0.1;

/// Fibre mass and volume of every group and the fluid's mass (box volume, ρ_f = 1), wall
/// units.
#[derive(Debug, Clone, PartialEq)]
pub struct Loading {
    pub fiber_mass: f64,
    pub fiber_volume: f64,
    pub fluid_mass: f64,
    pub fibers: usize,
}

impl Loading {
    pub fn mass_loading(&self) -> f64 {
        self.fiber_mass / self.fluid_mass
    }
    pub fn volume_fraction(&self) -> f64 {
        self.fiber_volume / self.fluid_mass
    }
}

/// Sums the groups of a launch file (each built as its nodes build it).
pub fn loading(lf: &LaunchFile) -> Result<Loading> {
    let b = lf.box_plus();
    let mut l = Loading {
        fiber_mass: 0.0,
        fiber_volume: 0.0,
        fluid_mass: b[0] * b[1] * b[2],
        fibers: 0,
    };
    for f in &lf.fibers {
        let g = f.build(b)?.group;
        l.fibers += g.len();
        for k in 0..g.len() {
            let m: f64 = g.props(k).iter().map(|p| p.mass).sum();
            l.fiber_mass += m;
            l.fiber_volume += m / g.density(k);
        }
    }
    Ok(l)
}

/// The lines a launch prints about its loading and coupling: the figures, what two-way
/// makes of several groups, and a warning when a one-way run is loaded past the usual
/// limit.
pub fn describe(lf: &LaunchFile, l: &Loading) -> Vec<String> {
    let mut out = vec![format!(
        "fibres: {} in {} group(s), mass loading {:.3}, volume fraction {:.2e}, coupling {}",
        l.fibers,
        lf.fibers.len(),
        l.mass_loading(),
        l.volume_fraction(),
        match lf.run.coupling {
            Coupling::OneWay => "one-way",
            Coupling::TwoWay => "two-way",
        }
    )];
    match lf.run.coupling {
        Coupling::TwoWay if lf.fibers.len() > 1 => out.push(format!(
            "two-way: the {} groups are one suspension that the flow feels together (a \
             mixture, not separate experiments)",
            lf.fibers.len()
        )),
        Coupling::OneWay if l.mass_loading() > ONE_WAY_MASS_LOADING_LIMIT => out.push(format!(
            "warning: mass loading {:.3} is above {ONE_WAY_MASS_LOADING_LIMIT}, where one-way \
             coupling usually stops being physics; set run.coupling = \"two-way\" to let the \
             fibres act on the flow",
            l.mass_loading()
        )),
        _ => {}
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn launch(extra: &str, per_layer: usize) -> LaunchFile {
        let text = format!(
            r#"
[run]
id = "t"
steps = 4
dt_plus = 0.25
{extra}
[flow.source]
kind = "dns"
[flow.source.dns]
nx = 16
ny = 16
nz = 16
re_tau = 150.0
[[fibers]]
group = "case1"
case = "case1"
placement = {{ kind = "layers", per_layer = {per_layer} }}
"#
        );
        toml::from_str(&text).unwrap()
    }

    /// 10^4 case-1 fibres in the paper's box carry ≈ 0.077 of the fluid's mass (the figure
    /// quoted in docs/two-way.md, from d+ ≈ 0.232, 7 segments of l+ = 3, ρ_s/ρ_f = 1150, box
    /// 2πh × 2h × πh at Re_τ 150): the sum over the built fibres matches the closed form to
    /// 1e-12.
    #[test]
    fn paper_loading_figure() {
        let lf = launch("", 2000);
        let l = loading(&lf).unwrap();
        assert_eq!(l.fibers, 10_000);
        let (l_plus, d_plus, ratio) = lf.fibers[0].resolved();
        let want = 10_000.0 * 7.0 * ratio * std::f64::consts::PI * 0.25 * d_plus.powi(2) * l_plus
            / (std::f64::consts::TAU * 150.0 * 300.0 * std::f64::consts::PI * 150.0);
        assert!(
            (l.mass_loading() / want - 1.0).abs() < 1e-12,
            "{} vs {want}",
            l.mass_loading()
        );
        assert!(
            (l.mass_loading() - 0.077).abs() < 0.002,
            "{}",
            l.mass_loading()
        );
        // one-way below the limit says nothing more; above it, it warns naming the key
        assert_eq!(describe(&lf, &l).len(), 1);
        let heavy = launch("", 20_000);
        let lh = loading(&heavy).unwrap();
        let d = describe(&heavy, &lh);
        assert!(
            d[1].contains("run.coupling") && d[1].contains("warning"),
            "{d:?}"
        );
        let two = launch("coupling = \"two-way\"", 20_000);
        assert_eq!(describe(&two, &lh).len(), 1);
    }
}
