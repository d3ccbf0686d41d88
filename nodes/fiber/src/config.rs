//! Fibre-group configuration (the `[[fibers]]` tables of a launch file), in wall units.

use fiberflow_fiber_model::cases::{
    build_fiber, five_layers, paper_diameter_plus, Layer, PaperCase, Placement,
};
use fiberflow_fiber_model::contact::{self, ContactParams};
use fiberflow_fiber_model::group::FiberGroup;
use fiberflow_fiber_model::suspension::{random_suspension_avoiding, Placed, Suspension};
use fiberflow_fiber_model::{DragModel, FiberError, ModelParams};
use fiberflow_messages::pieces::{split, Piece};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// Initial segment velocities.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default, schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum InitialVelocity {
    /// The fluid's velocity and rotation at each segment centre (default).
    #[default]
    Fluid,
    /// At rest.
    Rest,
}

/// Where fibres start.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum PlacementConfig {
    /// 5 layers in x2 (near each wall, next, centre) of `per_layer` vertical fibres.
    Layers {
        /// Fibres per layer, ≥ 1 (spread along the layer's diagonal).
        #[serde(default = "default_per_layer")]
        per_layer: usize,
        /// Wall distance of the layers next to each wall, wall units, in [half a fibre
        /// length, h+).
        #[serde(default = "default_near")]
        near_wall_plus: f64,
        /// Wall distance of the next layers, wall units, in [half a fibre length, h+).
        #[serde(default = "default_next")]
        next_plus: f64,
    },
    /// A suspension: `count` straight fibres at random centres and isotropic random
    /// axes, none closer to another than `min_distance_plus` (default: the diameter),
    /// within `band_plus` (wall distances from the lower wall; default the whole channel).
    Random {
        /// Number of fibres, ≥ 1.
        count: usize,
        /// Seed of the placement (same seed, same fibres).
        #[serde(default = "default_seed")]
        seed: u64,
        /// [lowest, highest] wall distance of fibre centres from the lower wall, wall
        /// units, within [0, 2h+] (default: the whole channel).
        #[serde(default)]
        band_plus: Option<[f64; 2]>,
        /// Closest allowed centre-line distance between segments of different fibres,
        /// wall units, ≥ 0 (default: the diameter).
        #[serde(default)]
        min_distance_plus: Option<f64>,
    },
    /// Explicit centres and axes (wall units); layer tags default to "middle".
    Explicit {
        /// Fibre centres, wall units (x2 from the channel centre).
        centres: Vec<[f64; 3]>,
        /// Fibre axes (normalised), one per centre.
        axes: Vec<[f64; 3]>,
    },
}

fn default_per_layer() -> usize {
    10
}
fn default_near() -> f64 {
    // centre 20 wall units from the wall: the longest case (7 x 4.5) still fits
    20.0
}
fn default_next() -> f64 {
    50.0
}
fn default_seed() -> u64 {
    1
}

/// One fibre group.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct FiberNodeConfig {
    /// Group name (topic path component).
    pub group: String,
    /// A paper case sets segment length and density ratio (explicit values override).
    #[serde(default)]
    pub case: Option<PaperCase>,
    /// Segments per fibre N, in 1..=1000.
    #[serde(default = "default_segments")]
    pub segments: usize,
    /// Segment length l+ (wall units), > `diameter_plus` (default: the case's, else 3).
    #[serde(default)]
    pub segment_length_plus: Option<f64>,
    /// Default: the d+ ≈ 0.232 consistent with the paper's τ_s+ = 13.5.
    #[serde(default)]
    pub diameter_plus: Option<f64>,
    /// Fibre to fluid density ratio ρ_s/ρ_f, > 0 (default: the case's, else 1150).
    #[serde(default)]
    pub density_ratio: Option<f64>,
    /// Where the fibres start (default: layers of 10).
    #[serde(default = "default_placement")]
    pub placement: PlacementConfig,
    #[serde(default)]
    pub initial_velocity: InitialVelocity,
    /// Joint bending stiffness in wall units, ≥ 0 (0: joints bend freely, as in the paper).
    #[serde(default)]
    pub bending_stiffness_plus: f64,
    /// Joint twisting stiffness in wall units (0: joints twist freely, as in the paper).
    #[serde(default)]
    pub twisting_stiffness_plus: f64,
    /// Gravitational acceleration, wall units (g ν / u_tau³); buoyancy is included.
    #[serde(default)]
    pub gravity_plus: [f64; 3],
    /// Relative Tikhonov parameter of the joint-force solve, in [0, 1) (0: the exact
    /// block-Thomas solve, as in the paper).
    #[serde(default)]
    pub tikhonov: f64,
    /// Cross-flow drag coefficient C_D (1 in the paper; 0 = viscous only).
    #[serde(default = "default_cd")]
    pub drag_coefficient: f64,
    /// Keep segment ends inside the walls (|x2| <= box_plus[1]/2).
    #[serde(default = "default_true")]
    pub wall_contact: bool,
    /// Publish metrics every this many steps, ≥ 1.
    #[serde(default = "default_metrics_every")]
    pub metrics_every_steps: u64,
    /// Fibre steps per coupling step, each of `run.dt_plus / substeps` with the flow's
    /// samples held, in 1..=64 (1 with `contact`): the fibres' own dynamics resolved finer
    /// than the coupling step at the cost of the fibre step alone; the force the fluid
    /// receives is the substeps' mean (docs/two-way.md, "The fibres' own step").
    #[serde(default = "default_substeps")]
    pub substeps: u32,
    /// Fibre nodes that integrate the group, each a contiguous slice of its fibres (nodes
    /// `<group>.0`, `<group>.1`, … when > 1); results do not depend on it.
    #[serde(default = "default_shards")]
    pub shards: u32,
    /// Fibre properties in physical units instead of wall units (overrides the `_plus`
    /// values and the case preset for the quantities it gives).
    #[serde(default)]
    pub physical: Option<PhysicalProperties>,
    /// Fibre–fibre contact within the group (docs/contact.md); unset: the fibres pass
    /// through each other, as in the paper. Needs a start without overlaps
    /// (`placement.kind = "random"`); a sharded group's shards touch each other.
    #[serde(default)]
    pub contact: Option<ContactConfig>,
}

/// `[fibers.contact]`: segments of different fibres of the group keep their centre-lines
/// at least a diameter apart, with Coulomb friction where they touch.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ContactConfig {
    /// Coulomb friction coefficient μ between fibres (static = sliding), ≥ 0 and finite.
    /// 0.5 is of the order measured for wood–wood contact; inter-fibre friction is what
    /// makes flocs (Schmid, Switzer & Klingenberg 2000), so vary it.
    #[serde(default = "default_friction")]
    pub friction: f64,
    /// Most Gauss–Seidel sweeps per floc and round of the contact solve, in 1..=10000 (it
    /// stops earlier once no pair is closer than its contact distance; a floc still
    /// overlapping after them moves as one body for the step, docs/contact.md).
    #[serde(default = "default_sweeps")]
    pub sweeps: u32,
}

fn default_substeps() -> u32 {
    1
}
fn default_friction() -> f64 {
    0.5
}
fn default_sweeps() -> u32 {
    100
}

/// Fibre and fluid properties in SI units, converted to wall units with ν and u_tau:
/// length+ = L u_tau / ν, density ratio = ρ_s / ρ_f.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct PhysicalProperties {
    /// Kinematic viscosity of the fluid, m²/s (air at 20 °C: 1.5e-5).
    pub kinematic_viscosity_m2_s: f64,
    /// Friction velocity of the channel flow, m/s.
    pub friction_velocity_m_s: f64,
    /// Fluid density, kg/m³ (air: 1.2).
    pub fluid_density_kg_m3: f64,
    /// Segment length, m (overrides `segment_length_plus`).
    #[serde(default)]
    pub segment_length_m: Option<f64>,
    /// Fibre diameter, m (overrides `diameter_plus`).
    #[serde(default)]
    pub diameter_m: Option<f64>,
    /// Fibre density, kg/m³ (overrides `density_ratio`).
    #[serde(default)]
    pub density_kg_m3: Option<f64>,
}

impl PhysicalProperties {
    fn check(&self, group: &str) -> Result<(), FiberError> {
        for (k, v) in [
            ("kinematic_viscosity_m2_s", self.kinematic_viscosity_m2_s),
            ("friction_velocity_m_s", self.friction_velocity_m_s),
            ("fluid_density_kg_m3", self.fluid_density_kg_m3),
        ] {
            if !(v > 0.0 && v.is_finite()) {
                return Err(FiberError::Config(format!(
                    "fibers[{group}].physical.{k} must be positive and finite (got {v})"
                )));
            }
        }
        Ok(())
    }

    /// Wall-unit length of a physical length.
    pub fn length_plus(&self, metres: f64) -> f64 {
        metres * self.friction_velocity_m_s / self.kinematic_viscosity_m2_s
    }
}

fn default_segments() -> usize {
    7
}
fn default_placement() -> PlacementConfig {
    PlacementConfig::Layers {
        per_layer: default_per_layer(),
        near_wall_plus: default_near(),
        next_plus: default_next(),
    }
}
fn default_cd() -> f64 {
    1.0
}
fn default_true() -> bool {
    true
}
fn default_shards() -> u32 {
    1
}

fn default_metrics_every() -> u64 {
    1
}

/// A built group plus per-fibre layer tags.
pub struct BuiltGroup {
    pub group: FiberGroup,
    pub layers: Vec<u8>,
}

impl BuiltGroup {
    /// Keeps fibres `first .. first + n` (one shard's share).
    pub fn slice(self, first: usize, n: usize) -> BuiltGroup {
        BuiltGroup {
            group: self.group.slice(first, n),
            layers: self.layers.into_iter().skip(first).take(n).collect(),
        }
    }
}

/// Builds the groups of one suspension (groups whose fibres touch each other, the launch
/// file's `[[suspensions]]`), in its order: a group placed at random keeps clear of the
/// groups before it. Refuses a start where fibres of different groups overlap (explicit
/// or layered placements), naming them.
pub fn build_suspension(
    members: &[FiberNodeConfig],
    box_plus: [f64; 3],
) -> Result<Vec<BuiltGroup>, FiberError> {
    let mut placed = Vec::new();
    let mut built: Vec<BuiltGroup> = Vec::with_capacity(members.len());
    for m in members {
        let b = m.build_avoiding(box_plus, &placed)?;
        for k in 0..b.group.len() {
            for (s, p) in b.group.segments(k).zip(b.group.props(k)) {
                let half = 0.5 * p.shape.length * s.z;
                placed.push(Placed {
                    ends: [s.r - half, s.r + half],
                    diameter_plus: p.shape.diameter,
                });
            }
        }
        built.push(b);
    }
    let all: Vec<_> = built.iter().flat_map(|b| b.group.fibers()).collect();
    let period = [Some(box_plus[0]), None, Some(box_plus[2])];
    let overlaps = contact::overlaps(&all, &period);
    if let Some(&(a, i, b, j, dist)) = overlaps.first() {
        let name = |k: usize| {
            let mut k = k;
            for (m, g) in members.iter().zip(&built) {
                if k < g.group.len() {
                    return format!("fibre {k} of group {}", m.group);
                }
                k -= g.group.len();
            }
            format!("fibre {k}")
        };
        return Err(FiberError::Config(format!(
            "suspensions: the start overlaps: segment {i} of {} and segment {j} of {} are {dist:.4} apart, closer than their contact distance ({} pairs in all); place the groups at random (placement.kind = \"random\") so that each keeps clear of those before it",
            name(a),
            name(b),
            overlaps.len()
        )));
    }
    Ok(built)
}

impl FiberNodeConfig {
    /// (segment length+, diameter+, density ratio) after presets and unit conversion.
    pub fn resolved(&self) -> (f64, f64, f64) {
        let (lc, rc) = self.case.map(|c| c.parameters()).unwrap_or((3.0, 1150.0));
        let mut l = self.segment_length_plus.unwrap_or(lc);
        let mut d = self.diameter_plus.unwrap_or_else(paper_diameter_plus);
        let mut r = self.density_ratio.unwrap_or(rc);
        if let Some(p) = &self.physical {
            if let Some(x) = p.segment_length_m {
                l = p.length_plus(x);
            }
            if let Some(x) = p.diameter_m {
                d = p.length_plus(x);
            }
            if let Some(x) = p.density_kg_m3 {
                r = x / p.fluid_density_kg_m3;
            }
        }
        (l, d, r)
    }

    /// Validates and builds the group for a channel box (wall units).
    pub fn build(&self, box_plus: [f64; 3]) -> Result<BuiltGroup, FiberError> {
        self.build_avoiding(box_plus, &[])
    }

    /// [`Self::build`] with a random placement kept clear of `placed` (the segments of the
    /// groups before it in a suspension whose groups touch).
    pub fn build_avoiding(
        &self,
        box_plus: [f64; 3],
        placed: &[Placed],
    ) -> Result<BuiltGroup, FiberError> {
        let (l, d, rho) = self.checked_sizes()?;
        let placements = self.placements(box_plus, l, d, placed)?;
        if self.shards == 0 || self.shards as usize > placements.len() {
            return self.bad(
                "shards",
                &format!("in 1..={} (the group's fibres)", placements.len()),
                self.shards.to_string(),
            );
        }
        let mut fibers = Vec::with_capacity(placements.len());
        let mut layers = Vec::with_capacity(placements.len());
        for p in &placements {
            fibers.push(build_fiber(p, self.segments, l, d, rho)?);
            layers.push(p.layer.index());
        }
        let params = ModelParams {
            drag: DragModel {
                viscosity: 1.0,
                fluid_density: 1.0,
                drag_coefficient: self.drag_coefficient,
            },
            gravity: Vector3::from(self.gravity_plus),
            bending_stiffness: self.bending_stiffness_plus,
            twisting_stiffness: self.twisting_stiffness_plus,
            tikhonov: self.tikhonov,
            wall_half_height: self.wall_contact.then_some(0.5 * box_plus[1]),
        };
        let mut group = FiberGroup::new(params, fibers);
        group.set_contact(self.contact_params(box_plus, &group)?);
        Ok(BuiltGroup { group, layers })
    }

    /// The group's contact parameters (None without `contact`), checked: its keys, and a
    /// start where no two fibres overlap.
    fn contact_params(
        &self,
        box_plus: [f64; 3],
        group: &FiberGroup,
    ) -> Result<Option<ContactParams>, FiberError> {
        let Some(c) = &self.contact else {
            return Ok(None);
        };
        if !(c.friction >= 0.0 && c.friction.is_finite()) {
            return self.bad(
                "contact.friction",
                ">= 0 and finite",
                c.friction.to_string(),
            );
        }
        if !(1..=10_000).contains(&c.sweeps) {
            return self.bad("contact.sweeps", "in 1..=10000", c.sweeps.to_string());
        }
        let params = ContactParams {
            friction: c.friction,
            sweeps: c.sweeps,
            period: [Some(box_plus[0]), None, Some(box_plus[2])],
            // the group's model walls are set when it steps
            wall_half_height: None,
        };
        let overlaps = contact::overlaps(&group.fibers(), &params.period);
        if let Some(&(a, i, b, j, dist)) = overlaps.first() {
            return Err(FiberError::Config(format!(
                "fibers[{}].contact: the start overlaps: segment {i} of fibre {a} and segment {j} of fibre {b} are {dist:.4} apart, closer than a diameter ({} pairs in all); start from placement.kind = \"random\" with min_distance_plus >= diameter_plus",
                self.group,
                overlaps.len()
            )));
        }
        Ok(Some(params))
    }

    /// The error for key `key` of this group outside `range`.
    fn bad<T>(&self, key: &str, range: &str, got: String) -> Result<T, FiberError> {
        Err(FiberError::Config(format!(
            "fibers[{}].{key} must be {range} (got {got})",
            self.group
        )))
    }

    /// Checks the group's name and scalar keys (each error names its key and range) and
    /// gives the resolved segment length, diameter and density ratio.
    fn checked_sizes(&self) -> Result<(f64, f64, f64), FiberError> {
        if self.group.is_empty()
            || !self
                .group
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
        {
            return self.bad(
                "group",
                "a non-empty name of [A-Za-z0-9_-]",
                format!("{:?}", self.group),
            );
        }
        if let Some(p) = &self.physical {
            p.check(&self.group)?;
        }
        if self.segments == 0 || self.segments > 1000 {
            return self.bad("segments", "in 1..=1000", self.segments.to_string());
        }
        let (l, d, rho) = self.resolved();
        if !(d > 0.0 && d.is_finite()) {
            return self.bad("diameter_plus", "positive and finite", d.to_string());
        }
        if !(l > d && l.is_finite()) {
            return self.bad(
                "segment_length_plus",
                "greater than diameter_plus",
                l.to_string(),
            );
        }
        if !(rho > 0.0 && rho.is_finite()) {
            return self.bad("density_ratio", "positive and finite", rho.to_string());
        }
        if !(self.bending_stiffness_plus >= 0.0 && self.bending_stiffness_plus.is_finite()) {
            return self.bad(
                "bending_stiffness_plus",
                ">= 0 and finite",
                self.bending_stiffness_plus.to_string(),
            );
        }
        if !(self.twisting_stiffness_plus >= 0.0 && self.twisting_stiffness_plus.is_finite()) {
            return self.bad(
                "twisting_stiffness_plus",
                ">= 0 and finite",
                self.twisting_stiffness_plus.to_string(),
            );
        }
        if !(self.tikhonov >= 0.0 && self.tikhonov < 1.0) {
            return self.bad("tikhonov", "in [0, 1)", self.tikhonov.to_string());
        }
        if !(self.drag_coefficient >= 0.0 && self.drag_coefficient.is_finite()) {
            return self.bad(
                "drag_coefficient",
                ">= 0",
                self.drag_coefficient.to_string(),
            );
        }
        if self.metrics_every_steps == 0 {
            return self.bad("metrics_every_steps", ">= 1", "0".into());
        }
        if !(1..=64).contains(&self.substeps) {
            return self.bad("substeps", "in 1..=64", self.substeps.to_string());
        }
        if self.substeps > 1 && self.contact.is_some() {
            return self.bad(
                "substeps",
                "1 with [fibers.contact] (the contact solve runs once per coupling step)",
                self.substeps.to_string(),
            );
        }
        Ok((l, d, rho))
    }

    /// Where the group's fibres start, by `placement.kind` (checked against the box).
    fn placements(
        &self,
        box_plus: [f64; 3],
        l: f64,
        d: f64,
        placed: &[Placed],
    ) -> Result<Vec<Placement>, FiberError> {
        Ok(match &self.placement {
            PlacementConfig::Layers {
                per_layer,
                near_wall_plus,
                next_plus,
            } => {
                let half = 0.5 * l * self.segments as f64;
                if *per_layer == 0 {
                    return self.bad("placement.per_layer", ">= 1", "0".into());
                }
                if !(*near_wall_plus >= half && *near_wall_plus < 0.5 * box_plus[1]) {
                    return self.bad(
                        "placement.near_wall_plus",
                        &format!(
                            "in [{half}, {}) so the fibre starts inside the channel",
                            0.5 * box_plus[1]
                        ),
                        near_wall_plus.to_string(),
                    );
                }
                if !(*next_plus >= half && *next_plus < 0.5 * box_plus[1]) {
                    return self.bad(
                        "placement.next_plus",
                        "inside the channel",
                        next_plus.to_string(),
                    );
                }
                five_layers(box_plus, *per_layer, *near_wall_plus, *next_plus)
            }
            PlacementConfig::Random {
                count,
                seed,
                band_plus,
                min_distance_plus,
            } => {
                if *count == 0 {
                    return self.bad("placement.count", ">= 1", "0".into());
                }
                let gap = min_distance_plus.unwrap_or(d);
                if !(gap >= 0.0 && gap.is_finite()) {
                    return self.bad("placement.min_distance_plus", ">= 0", gap.to_string());
                }
                let band = band_plus.unwrap_or([0.0, box_plus[1]]);
                random_suspension_avoiding(
                    &Suspension {
                        count: *count,
                        seed: *seed,
                        box_plus,
                        band_plus: band,
                        segments: self.segments,
                        segment_length_plus: l,
                        diameter_plus: d,
                        min_distance_plus: gap,
                    },
                    placed,
                )
                .map_err(|e| FiberError::Config(format!("fibers[{}].{e}", self.group)))?
            }
            PlacementConfig::Explicit { centres, axes } => {
                if centres.len() != axes.len() || centres.is_empty() {
                    return self.bad(
                        "placement.axes",
                        "as many entries as placement.centres (>= 1)",
                        format!("{} vs {}", axes.len(), centres.len()),
                    );
                }
                centres
                    .iter()
                    .zip(axes)
                    .map(|(c, a)| Placement {
                        centre: Vector3::from(*c),
                        axis: Vector3::from(*a),
                        layer: Layer::Middle,
                        upper: false,
                    })
                    .collect()
            }
        })
    }

    /// The fibre nodes of the group: `shards` contiguous slices of its fibres.
    pub fn pieces(&self, box_plus: [f64; 3]) -> Result<Vec<Piece>, FiberError> {
        let built = self.build(box_plus)?;
        let total = built.group.len() as u32;
        Ok(split(total, self.shards)
            .into_iter()
            .enumerate()
            .map(|(i, (first, n))| Piece {
                group: self.group.clone(),
                index: i as u32,
                shards: self.shards,
                first_fiber: first,
                fibers: n,
                group_fibers: total,
                segments: (first as usize..(first + n) as usize)
                    .map(|k| built.group.fiber_len(k))
                    .sum(),
            })
            .collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn base() -> FiberNodeConfig {
        toml::from_str("group = \"g\"\ncase = \"case1\"").unwrap()
    }

    /// Physical units convert to the same wall-unit fibre as the preset: air (ν = 1.5e-5 m²/s,
    /// ρ = 1.2 kg/m³), u_tau = 0.5 m/s, l = 90 µm, d = 6.96 µm, ρ_s = 1380 kg/m³.
    #[test]
    fn physical_units_convert() {
        let mut c = base();
        c.physical = Some(PhysicalProperties {
            kinematic_viscosity_m2_s: 1.5e-5,
            friction_velocity_m_s: 0.5,
            fluid_density_kg_m3: 1.2,
            segment_length_m: Some(90e-6),
            diameter_m: Some(6.96e-6),
            density_kg_m3: Some(1380.0),
        });
        let (l, d, r) = c.resolved();
        assert!((l - 3.0).abs() < 1e-12 && (d - 0.232).abs() < 1e-12 && (r - 1150.0).abs() < 1e-9);
        c.physical.as_mut().unwrap().friction_velocity_m_s = -1.0;
        let e = c.build([942.0, 300.0, 471.0]).err().unwrap().to_string();
        assert!(e.contains("physical.friction_velocity_m_s"), "{e}");
    }

    /// `placement = { kind = "random", ... }` builds `count` fibres (the layer tags by
    /// where they start), and bad keys are refused by name.
    #[test]
    fn random_placement_builds_and_checks_its_keys() {
        let b = [942.0, 300.0, 471.0];
        let c: FiberNodeConfig = toml::from_str(
            "group = \"g\"\ncase = \"case1\"\nplacement = { kind = \"random\", count = 500 }",
        )
        .unwrap();
        let g = c.build(b).unwrap();
        assert_eq!(g.group.len(), 500);
        assert!(g.layers.iter().any(|&l| l == Layer::Middle.index()));
        assert!(g.layers.iter().any(|&l| l == Layer::NearWall.index()));
        for (text, key) in [
            ("count = 0", "placement.count"),
            (
                "count = 5, min_distance_plus = -1.0",
                "placement.min_distance_plus",
            ),
            ("count = 5, band_plus = [0.0, 5.0]", "placement.band_plus"),
        ] {
            let c: FiberNodeConfig = toml::from_str(&format!(
                "group = \"g\"\ncase = \"case1\"\nplacement = {{ kind = \"random\", {text} }}"
            ))
            .unwrap();
            let e = c.build(b).err().unwrap().to_string();
            assert!(e.contains(&format!("fibers[g].{key}")), "{e}");
        }
    }

    /// `substeps` outside 1..=64, or above 1 with contact, is refused naming the key.
    #[test]
    fn substeps_are_checked() {
        let b = [942.0, 300.0, 471.0];
        for (extra, ok) in [
            ("substeps = 4", true),
            ("substeps = 64", true),
            ("substeps = 0", false),
            ("substeps = 65", false),
            (
                "substeps = 2\ncontact = {}\nplacement = { kind = \"random\", count = 20 }",
                false,
            ),
        ] {
            let c: FiberNodeConfig =
                toml::from_str(&format!("group = \"g\"\ncase = \"case1\"\n{extra}")).unwrap();
            match c.build(b) {
                Ok(_) => assert!(ok, "{extra}"),
                Err(e) => {
                    assert!(!ok, "{extra}: {e}");
                    assert!(e.to_string().contains("fibers[g].substeps"), "{e}");
                }
            }
        }
    }

    #[test]
    fn bad_values_name_the_key() {
        let mut c = base();
        c.density_ratio = Some(-1.0);
        let e = c.build([942.0, 300.0, 471.0]).err().unwrap().to_string();
        assert!(e.contains("fibers[g].density_ratio"), "{e}");
        let mut c = base();
        c.segments = 0;
        assert!(c
            .build([942.0, 300.0, 471.0])
            .err()
            .unwrap()
            .to_string()
            .contains("segments"));
        let mut c = base();
        c.diameter_plus = Some(f64::NAN);
        assert!(c
            .build([942.0, 300.0, 471.0])
            .err()
            .unwrap()
            .to_string()
            .contains("diameter_plus"));
    }

    /// Shards split the group into contiguous slices named `<group>.<i>`; a shard count
    /// outside 1..=fibres is refused with the key and the range.
    #[test]
    fn shards_split_the_group_and_are_checked() {
        let mut c = base();
        c.shards = 3;
        let p = c.pieces([942.0, 300.0, 471.0]).unwrap();
        let got: Vec<(String, u32, u32)> = p
            .iter()
            .map(|p| (p.node(), p.first_fiber, p.fibers))
            .collect();
        assert_eq!(
            got,
            vec![
                ("g.0".to_string(), 0, 16),
                ("g.1".to_string(), 16, 17),
                ("g.2".to_string(), 33, 17)
            ]
        );
        assert!(p
            .iter()
            .all(|p| p.group_fibers == 50 && p.segments == 7 * p.fibers as usize));
        for bad in [0, 51] {
            c.shards = bad;
            let e = c.build([942.0, 300.0, 471.0]).err().unwrap().to_string();
            assert!(
                e.contains("fibers[g].shards") && e.contains("1..=50"),
                "{e}"
            );
        }
        c.shards = 1;
        assert_eq!(c.pieces([942.0, 300.0, 471.0]).unwrap()[0].node(), "g");
    }

    /// The groups of a suspension are placed in order, each clear of those before it: two
    /// random groups in one band overlap when placed alone, not when placed together; the
    /// first group is placed as it is alone.
    #[test]
    fn a_suspension_places_each_group_clear_of_those_before() {
        let b = [942.0, 300.0, 471.0];
        let group = |name: &str, seed: u32| -> FiberNodeConfig {
            toml::from_str(&format!(
                "group = \"{name}\"\ncase = \"case1\"\ncontact = {{}}\n\
                 placement = {{ kind = \"random\", count = 1500, seed = {seed}, band_plus = [135.0, 165.0] }}"
            ))
            .unwrap()
        };
        let members = [group("a", 1), group("b", 2)];
        let period = [Some(b[0]), None, Some(b[2])];
        let alone: Vec<_> = members
            .iter()
            .flat_map(|m| m.build(b).unwrap().group.fibers())
            .collect();
        assert!(!contact::overlaps(&alone, &period).is_empty());
        let together = build_suspension(&members, b).unwrap();
        let all: Vec<_> = together.iter().flat_map(|g| g.group.fibers()).collect();
        assert!(contact::overlaps(&all, &period).is_empty());
        assert_eq!(
            together[0].group.fibers(),
            members[0].build(b).unwrap().group.fibers()
        );
        assert_eq!(together[1].group.len(), 1500);
    }

    /// `[fibers.contact]` turns contact on for the group with its keys checked by name
    /// (any shard count: the shards exchange their free steps, `serve`), and a start
    /// where fibres overlap is refused naming them.
    #[test]
    fn contact_keys_are_checked_and_overlapping_starts_refused() {
        let b = [942.0, 300.0, 471.0];
        let random =
            "group = \"g\"\ncase = \"case1\"\nplacement = { kind = \"random\", count = 200 }\n";
        let c: FiberNodeConfig = toml::from_str(&format!("{random}contact = {{}}")).unwrap();
        let g = c.build(b).unwrap().group;
        let on = g.contact().unwrap();
        assert_eq!((on.friction, on.sweeps), (0.5, 100));
        assert_eq!(on.period, [Some(942.0), None, Some(471.0)]);
        assert!(base().build(b).unwrap().group.contact().is_none());
        for (extra, key) in [
            (
                "contact = { friction = -0.1 }",
                "fibers[g].contact.friction",
            ),
            ("contact = { sweeps = 0 }", "fibers[g].contact.sweeps"),
        ] {
            let c: FiberNodeConfig = toml::from_str(&format!("{random}{extra}")).unwrap();
            let e = c.build(b).err().unwrap().to_string();
            assert!(e.contains(key), "{e}");
        }
        let sharded: FiberNodeConfig =
            toml::from_str(&format!("{random}contact = {{}}\nshards = 3")).unwrap();
        assert!(sharded.build(b).unwrap().group.contact().is_some());
        let crossed: FiberNodeConfig = toml::from_str(
            "group = \"g\"\ncase = \"case1\"\ncontact = {}\n\
             placement = { kind = \"explicit\", centres = [[100.0, 0.0, 100.0], [100.0, 0.1, 100.0]], axes = [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]] }",
        )
        .unwrap();
        let e = crossed.build(b).err().unwrap().to_string();
        assert!(
            e.contains("fibers[g].contact: the start overlaps")
                && e.contains("of fibre 0 and segment 3 of fibre 1 are 0.1000 apart"),
            "{e}"
        );
    }
}
