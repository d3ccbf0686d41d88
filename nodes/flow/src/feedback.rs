//! Two-way coupling in the flow node: the fibres' hydrodynamic forces of a step, gathered
//! from the states in a fixed global order and turned into the fluid's body force for the
//! next field step (`docs/two-way.md`).

use crate::error::FlowError;
use fiberflow_messages::FiberGroupState;
use std::collections::BTreeMap;

/// The fluid's share of a step: where each segment is and the force on the fluid there,
/// in the DNS's outer units (h, u_τ, ρ_f = 1), plus their sum in wall units.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Feedback {
    pub points: Vec<[f64; 3]>,
    pub forces: Vec<[f64; 3]>,
    /// Σ of the forces on the fluid, wall units (−Σ F^h over every segment).
    pub total_plus: [f64; 3],
}

/// Collects every segment's −F^h from `states` in the map's order (group name, then first
/// fibre: the same sequence of segments whatever the shard count), converting wall units
/// to outer ones: positions /Re_τ, forces /Re_τ² (ρ u_τ² ℓ_ν² = ρ u_τ² h² / Re_τ²).
/// A state without forces in a two-way run is a protocol error that names the group.
pub fn gather(
    states: &BTreeMap<(String, u32), FiberGroupState>,
    re_tau: f64,
    out: &mut Feedback,
) -> Result<(), FlowError> {
    out.points.clear();
    out.forces.clear();
    out.total_plus = [0.0; 3];
    let f_scale = 1.0 / (re_tau * re_tau);
    for ((group, first), s) in states {
        if s.hydro_force.len() != s.centre.len() {
            return Err(FlowError::Protocol(format!(
                "two-way run: the state of group {group} (fibres from {first}) at step {} \
                 carries {} force values for {} segment values (is run.coupling the same for \
                 every node?)",
                s.step,
                s.hydro_force.len(),
                s.centre.len()
            )));
        }
        for (c, f) in s.centre.chunks_exact(3).zip(s.hydro_force.chunks_exact(3)) {
            out.points
                .push([c[0] / re_tau, c[1] / re_tau, c[2] / re_tau]);
            out.forces
                .push([-f[0] * f_scale, -f[1] * f_scale, -f[2] * f_scale]);
            for a in 0..3 {
                out.total_plus[a] -= f[a];
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn state(group: &str, first: u32, centre: Vec<f64>, force: Vec<f64>) -> FiberGroupState {
        FiberGroupState {
            group: group.into(),
            first_fiber: first,
            segments_per_fiber: vec![(centre.len() / 3) as u32],
            centre,
            hydro_force: force,
            ..Default::default()
        }
    }

    /// The forces are reversed and scaled by 1/Re_τ², the points by 1/Re_τ; the order is
    /// group then first fibre; a state without forces is refused by name.
    #[test]
    fn gathers_reversed_forces_in_global_order() {
        let mut m = BTreeMap::new();
        m.insert(
            ("b".to_string(), 0),
            state("b", 0, vec![150.0, 0.0, 0.0], vec![1.0, 2.0, 3.0]),
        );
        m.insert(
            ("a".to_string(), 5),
            state("a", 5, vec![300.0, 15.0, 0.0], vec![4.0, 0.0, 0.0]),
        );
        m.insert(
            ("a".to_string(), 0),
            state("a", 0, vec![0.0, -150.0, 75.0], vec![-1.0, 0.0, 0.0]),
        );
        let mut fb = Feedback::default();
        gather(&m, 150.0, &mut fb).unwrap();
        assert_eq!(
            fb.points,
            vec![[0.0, -1.0, 0.5], [2.0, 0.1, 0.0], [1.0, 0.0, 0.0]]
        );
        let s = 1.0 / 22500.0;
        assert_eq!(fb.forces[0], [s, -0.0, -0.0]);
        assert_eq!(fb.forces[1], [-4.0 * s, -0.0, -0.0]);
        assert_eq!(fb.total_plus, [-4.0, -2.0, -3.0]);
        m.insert(("c".to_string(), 0), state("c", 0, vec![0.0; 3], vec![]));
        let e = gather(&m, 150.0, &mut fb).unwrap_err().to_string();
        assert!(e.contains("group c") && e.contains("run.coupling"), "{e}");
    }
}
