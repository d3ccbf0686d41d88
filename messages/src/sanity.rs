//! Checks after decoding (docs/architecture.md): a message can be valid CDR and still make no sense —
//! array lengths that disagree with the segment counts, NaN or infinite values, an unknown
//! lifecycle state. Receivers drop and count such messages like undecodable ones, so no
//! node indexes an array by a count it has not checked.

use crate::kind::Kind;
use crate::types::*;

/// Semantic validity of a decoded message.
pub trait Sane {
    /// `Err(reason)` if the message is inconsistent.
    fn check(&self) -> Result<(), String>;
}

pub(crate) fn finite(name: &str, xs: &[f64]) -> Result<(), String> {
    finite_all(name, xs.iter().copied())
}

/// Whether every value is finite: one pass without an early exit, so that it runs over
/// whole SIMD registers (the early-exit search cost ≈ 4 ns per value on the flow node's
/// states at 6 × 10⁴ fibres).
#[inline]
pub fn all_finite(xs: impl Iterator<Item = f64>) -> bool {
    xs.fold(true, |ok, x| ok & (x.abs() < f64::INFINITY))
}

fn len(name: &str, got: usize, want: usize) -> Result<(), String> {
    if got != want {
        return Err(format!("{name} has {got} values, expected {want}"));
    }
    Ok(())
}

/// A message about fibres `first ..< first + n` of a group of `total`.
fn piece(first: u32, n: usize, total: u32) -> Result<(), String> {
    if first >= total || first as u64 + n as u64 > total as u64 {
        return Err(format!(
            "fibres {first}..{} of a group of {total}",
            first as u64 + n as u64
        ));
    }
    Ok(())
}

fn time(t_plus: f64) -> Result<(), String> {
    if !(t_plus.is_finite() && t_plus >= 0.0) {
        return Err(format!("t_plus {t_plus} is not a time"));
    }
    Ok(())
}

impl Sane for RunAnnouncement {
    fn check(&self) -> Result<(), String> {
        if self.run_id.is_empty() || self.groups.iter().any(|g| g.is_empty()) {
            return Err("empty run or group name".into());
        }
        if !(self.dt_plus.is_finite() && self.dt_plus > 0.0) || self.steps == 0 {
            return Err("dt_plus and steps must be positive".into());
        }
        len("box_plus", self.box_plus.len(), 3)?;
        if !self.box_plus.iter().all(|b| b.is_finite() && *b > 0.0) {
            return Err("box_plus must be positive".into());
        }
        Ok(())
    }
}

impl Sane for FlowStatus {
    fn check(&self) -> Result<(), String> {
        time(self.t_plus)?;
        // re_tau is NaN on steps without a wall-shear evaluation
        finite(
            "status",
            &[
                self.dt_plus,
                self.cfl,
                self.max_divergence,
                self.bulk_velocity,
                self.pressure_gradient,
            ],
        )?;
        if !(self.fiber_force_plus.is_empty() || self.fiber_force_plus.len() == 3) {
            return Err("fiber_force_plus must hold 0 or 3 values".into());
        }
        finite("fiber_force_plus", &self.fiber_force_plus)
    }
}

impl Sane for FlowProfiles {
    fn check(&self) -> Result<(), String> {
        time(self.t_plus)?;
        let n = self.y_plus.len();
        for (name, v) in [
            ("y_plus", &self.y_plus),
            ("u_mean", &self.u_mean),
            ("u_rms", &self.u_rms),
            ("v_rms", &self.v_rms),
            ("w_rms", &self.w_rms),
            ("uv", &self.uv),
            ("omega_z_mean", &self.omega_z_mean),
            ("omega_x_rms", &self.omega_x_rms),
            ("omega_y_rms", &self.omega_y_rms),
            ("omega_z_rms", &self.omega_z_rms),
        ] {
            len(name, v.len(), n)?;
            finite(name, v)?;
        }
        Ok(())
    }
}

impl Sane for FlowSlice {
    fn check(&self) -> Result<(), String> {
        time(self.t_plus)?;
        if self.name.is_empty() {
            return Err("empty slice name".into());
        }
        for (name, v) in [
            ("origin", &self.origin),
            ("axis_u", &self.axis_u),
            ("axis_v", &self.axis_v),
        ] {
            len(name, v.len(), 3)?;
            finite(name, v)?;
        }
        let unit = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() - 1.0).abs() < 1e-6;
        if !unit(&self.axis_u) || !unit(&self.axis_v) {
            return Err("axis_u and axis_v must be unit vectors".into());
        }
        if self.u_plus.is_empty() || self.v_plus.is_empty() {
            return Err("a slice needs at least one sample each way".into());
        }
        finite("u_plus", &self.u_plus)?;
        finite("v_plus", &self.v_plus)?;
        for (name, c) in [("u_plus", &self.u_plus), ("v_plus", &self.v_plus)] {
            if c.windows(2).any(|w| w[1] <= w[0]) {
                return Err(format!("{name} must increase strictly"));
            }
        }
        let n = self.u_plus.len().checked_mul(self.v_plus.len());
        len("values", self.values.len(), n.unwrap_or(usize::MAX))?;
        finite_all("values", self.values.iter().map(|&x| f64::from(x)))
    }
}

impl Sane for FlowSamples {
    fn check(&self) -> Result<(), String> {
        check_samples(
            (
                self.t_plus,
                &self.group,
                self.first_fiber,
                self.group_fibers,
            ),
            self.velocity.len(),
            self.velocity_gradient.len(),
            || self.velocity.iter().copied(),
            || self.velocity_gradient.iter().copied(),
        )
    }
}

/// The checks of FlowSamples, on its header, its array lengths and its values (shared by
/// the decoded message and [`crate::bulk::SamplesView`]).
/// `piece` is (t_plus, group, first_fiber, group_fibers).
pub(crate) fn check_samples<V, G>(
    piece_of: (f64, &str, u32, u32),
    velocity_len: usize,
    gradient_len: usize,
    velocity: impl FnOnce() -> V,
    gradient: impl FnOnce() -> G,
) -> Result<(), String>
where
    V: Iterator<Item = f64> + Clone,
    G: Iterator<Item = f64> + Clone,
{
    check_samples_shape(piece_of, velocity_len, gradient_len)?;
    finite_all("velocity", velocity())?;
    finite_all("velocity_gradient", gradient())
}

/// [`check_samples`] but for the values' finiteness: time, group, piece and lengths.
pub(crate) fn check_samples_shape(
    piece_of: (f64, &str, u32, u32),
    velocity_len: usize,
    gradient_len: usize,
) -> Result<(), String> {
    let (t_plus, group, first_fiber, group_fibers) = piece_of;
    time(t_plus)?;
    if group.is_empty() || !velocity_len.is_multiple_of(3) {
        return Err("empty group or velocity not in triples".into());
    }
    piece(first_fiber, 0, group_fibers)?;
    len("velocity_gradient", gradient_len, 3 * velocity_len)
}

/// `Err` naming the first value that is not finite (searched for only if there is one).
fn finite_all(name: &str, xs: impl Iterator<Item = f64> + Clone) -> Result<(), String> {
    if all_finite(xs.clone()) {
        return Ok(());
    }
    match xs.into_iter().position(|x| !x.is_finite()) {
        Some(i) => Err(format!("{name}[{i}] is not finite")),
        None => Ok(()),
    }
}

impl Sane for FiberGroupState {
    fn check(&self) -> Result<(), String> {
        time(self.t_plus)?;
        let nf = self.segments_per_fiber.len();
        if self.group.is_empty() {
            return Err("empty group name".into());
        }
        len("segment_length", self.segment_length.len(), nf)?;
        len("diameter", self.diameter.len(), nf)?;
        len("density_ratio", self.density_ratio.len(), nf)?;
        len("layer", self.layer.len(), nf)?;
        piece(self.first_fiber, nf, self.group_fibers)?;
        if self.segments_per_fiber.contains(&0) {
            return Err("a fibre with 0 segments".into());
        }
        let nseg: u64 = self.segments_per_fiber.iter().map(|&n| n as u64).sum();
        let want = usize::try_from(nseg.saturating_mul(3)).map_err(|_| "too many segments")?;
        len("centre", self.centre.len(), want)?;
        finite("centre", &self.centre)?;
        // a lean state has no axes and velocities; a complete one has all of them
        if !self.is_lean() {
            for (name, v) in [
                ("axis", &self.axis),
                ("velocity", &self.velocity),
                ("angular_velocity", &self.angular_velocity),
            ] {
                len(name, v.len(), want)?;
                finite(name, v)?;
            }
        }
        // two-way coupling's forces: none (one-way) or one per segment
        if !self.hydro_force.is_empty() {
            len("hydro_force", self.hydro_force.len(), want)?;
            finite("hydro_force", &self.hydro_force)?;
        }
        // contact: the segments that touched, ascending, each with a force and a count
        let touched = self.contact_segment.len();
        len("contact_force", self.contact_force.len(), 3 * touched)?;
        len("contacts", self.contacts.len(), touched)?;
        finite("contact_force", &self.contact_force)?;
        if let Some(i) = self.contact_segment.windows(2).position(|w| w[0] >= w[1]) {
            return Err(format!("contact_segment[{}] is not ascending", i + 1));
        }
        if let Some(&last) = self.contact_segment.last() {
            if u64::from(last) >= nseg {
                return Err(format!(
                    "contact_segment {last} is past the message's {nseg} segments"
                ));
            }
        }
        if self.contacts.contains(&0) {
            return Err("a listed contact segment with 0 contacts".into());
        }
        finite("segment_length", &self.segment_length)?;
        finite("diameter", &self.diameter)?;
        finite("density_ratio", &self.density_ratio)
    }
}

impl Sane for FiberFreeStep {
    fn check(&self) -> Result<(), String> {
        time(self.t_plus)?;
        if self.group.is_empty() {
            return Err("empty group name".into());
        }
        let nf = self.segments_per_fiber.len();
        piece(self.first_fiber, nf, self.group_fibers)?;
        per_segment(
            "fiber",
            &self.segments_per_fiber,
            &[
                ("start_centre", &self.start_centre),
                ("start_axis", &self.start_axis),
                ("start_normal", &self.start_normal),
                ("centre", &self.centre),
                ("axis", &self.axis),
                ("normal", &self.normal),
                ("velocity", &self.velocity),
                ("angular_velocity", &self.angular_velocity),
            ],
        )
    }
}

/// Arrays of 3 values per segment of fibres of `counts` segments each (`what` names such a
/// fibre): no fibre without segments, every array as long as the segments ask and finite.
fn per_segment(what: &str, counts: &[u32], arrays: &[(&str, &[f64])]) -> Result<(), String> {
    if counts.contains(&0) {
        return Err(format!("a {what} with 0 segments"));
    }
    let nseg: u64 = counts.iter().map(|&n| n as u64).sum();
    let want = usize::try_from(nseg.saturating_mul(3)).map_err(|_| "too many segments")?;
    for (name, v) in arrays {
        len(name, v.len(), want)?;
        finite(name, v)?;
    }
    Ok(())
}

impl Sane for FiberContactSolved {
    fn check(&self) -> Result<(), String> {
        time(self.t_plus)?;
        if self.group.is_empty() {
            return Err("empty group name".into());
        }
        let nf = self.fibers as usize;
        piece(self.first_fiber, nf, self.group_fibers)?;
        len(
            "moved_segments",
            self.moved_segments.len(),
            self.moved.len(),
        )?;
        ascending_below("moved", &self.moved, nf)?;
        ascending_below("locked", &self.locked, nf)?;
        ascending_below("frozen", &self.frozen, nf)?;
        per_segment(
            "moved fibre",
            &self.moved_segments,
            &[
                ("centre", &self.centre),
                ("axis", &self.axis),
                ("normal", &self.normal),
                ("velocity", &self.velocity),
                ("angular_velocity", &self.angular_velocity),
            ],
        )?;
        let nc = self.contact_segment.len();
        len("contacts", self.contacts.len(), nc)?;
        len("contact_force", self.contact_force.len(), 3 * nc)?;
        finite("contact_force", &self.contact_force)?;
        if self.contact_segment.windows(2).any(|w| w[0] >= w[1]) {
            return Err("contact_segment is not ascending".into());
        }
        // the segments of a piece are at most 2^32: a listed segment is checked against
        // the piece by the receiver, which knows its segment count
        if self.worst_gap.is_nan() {
            return Err("worst_gap is not a number".into());
        }
        Ok(())
    }
}

/// `xs` ascending, each below `n`.
fn ascending_below(name: &str, xs: &[u32], n: usize) -> Result<(), String> {
    if xs.windows(2).any(|w| w[0] >= w[1]) {
        return Err(format!("{name} is not ascending"));
    }
    match xs.last() {
        Some(&last) if last as usize >= n => Err(format!("{name} names fibre {last} of {n}")),
        _ => Ok(()),
    }
}

impl Sane for FiberGroupMetrics {
    fn check(&self) -> Result<(), String> {
        time(self.t_plus)?;
        let n = self.z1.len();
        piece(self.first_fiber, n, self.group_fibers)?;
        len("centre_of_mass", self.centre_of_mass.len(), 3 * n)?;
        len("sigma2", self.sigma2.len(), n)?;
        len("end_to_end", self.end_to_end.len(), n)?;
        for (name, v) in [
            ("centre_of_mass", &self.centre_of_mass),
            ("z1", &self.z1),
            ("sigma2", &self.sigma2),
            ("end_to_end", &self.end_to_end),
        ] {
            finite(name, v)?;
        }
        finite("means", &[self.mean_abs_z1, self.mean_sigma2])
    }
}

impl Sane for Heartbeat {
    fn check(&self) -> Result<(), String> {
        if self.node.is_empty() {
            return Err("heartbeat of no node".into());
        }
        Ok(())
    }
}

/// What a checked message is about: its step (step-stamped types) and its owner (the
/// group of group messages, the node of a heartbeat, the run of an announcement).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Stamp {
    pub step: Option<u64>,
    pub owner: Option<String>,
    /// First fibre of a group message (a sharded group's shards each send their slice;
    /// 0 for the whole group and for other messages).
    pub first_fiber: u32,
}

/// Decodes and checks a fibre-group state, keeping it (receivers that use the state
/// itself decode once).
pub fn check_state(bytes: &[u8]) -> Result<FiberGroupState, String> {
    let s = crate::decode::<FiberGroupState>(bytes).map_err(|e| e.to_string())?;
    s.check()?;
    Ok(s)
}

/// Decodes `bytes` as a message of `kind` and checks it; `Err(reason)` for garbage or nonsense.
pub fn check_payload(kind: Kind, bytes: &[u8]) -> Result<Stamp, String> {
    fn go<M: crate::Message + Sane>(b: &[u8], stamp: impl Fn(M) -> Stamp) -> Result<Stamp, String> {
        let m = crate::decode::<M>(b).map_err(|e| e.to_string())?;
        m.check()?;
        Ok(stamp(m))
    }
    let st = |step: u64, owner: Option<String>, first_fiber: u32| Stamp {
        step: Some(step),
        owner,
        first_fiber,
    };
    match kind {
        Kind::RunAnnouncement => go::<RunAnnouncement>(bytes, |m| Stamp {
            owner: Some(m.run_id),
            ..Stamp::default()
        }),
        Kind::Heartbeat => go::<Heartbeat>(bytes, |m| Stamp {
            owner: Some(m.node),
            ..Stamp::default()
        }),
        Kind::FlowStatus => go::<FlowStatus>(bytes, |m| st(m.step, None, 0)),
        Kind::FlowProfiles => go::<FlowProfiles>(bytes, |m| st(m.step, None, 0)),
        Kind::FlowSlice => go::<FlowSlice>(bytes, |m| st(m.step, None, 0)),
        Kind::FlowSamples => go::<FlowSamples>(bytes, |m| st(m.step, Some(m.group), m.first_fiber)),
        Kind::FiberGroupState => {
            check_state(bytes).map(|m| st(m.step, Some(m.group), m.first_fiber))
        }
        Kind::FiberGroupMetrics => {
            go::<FiberGroupMetrics>(bytes, |m| st(m.step, Some(m.group), m.first_fiber))
        }
        Kind::FiberFreeStep => {
            go::<FiberFreeStep>(bytes, |m| st(m.step, Some(m.group), m.first_fiber))
        }
        Kind::FiberContactSolved => {
            go::<FiberContactSolved>(bytes, |m| st(m.step, Some(m.group), m.first_fiber))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn state() -> FiberGroupState {
        FiberGroupState {
            schema_version: crate::SCHEMA_VERSION,
            group: "g".into(),
            step: 3,
            t_plus: 0.75,
            first_fiber: 0,
            group_fibers: 1,
            segments_per_fiber: vec![2],
            segment_length: vec![3.0],
            diameter: vec![0.2],
            density_ratio: vec![800.0],
            layer: vec![0],
            centre: vec![0.0, 1.0, 2.0, 3.0, 1.0, 2.0],
            axis: vec![1.0, 0.0, 0.0, 1.0, 0.0, 0.0],
            velocity: vec![0.0; 6],
            angular_velocity: vec![0.0; 6],
            hydro_force: vec![],
            contact_segment: vec![],
            contact_force: vec![],
            contacts: vec![],
        }
    }

    /// A lean state (centres only) is sane; one missing only some of the per-segment
    /// arrays, or lean without its centres, is not.
    #[test]
    fn lean_states_carry_all_centres_and_nothing_else() {
        let full = state();
        assert!(full.check().is_ok() && !full.is_lean());
        let mut lean = full.clone();
        lean.axis.clear();
        lean.velocity.clear();
        lean.angular_velocity.clear();
        assert!(lean.is_lean());
        assert_eq!(lean.check(), Ok(()));
        let mut half = full.clone();
        half.axis.clear();
        assert!(half.check().unwrap_err().contains("axis"));
        let mut no_centres = lean.clone();
        no_centres.centre.pop();
        assert!(no_centres.check().unwrap_err().contains("centre"));
    }

    /// The contact arrays list touched segments ascending, inside the message, each with
    /// three force values and at least one contact; anything else is refused by name.
    #[test]
    fn contact_arrays_list_touched_segments_with_a_force_and_a_count() {
        let mut s = state();
        s.contact_segment = vec![0, 1];
        s.contact_force = vec![0.5, -1.0, 0.0, -0.5, 1.0, 0.0];
        s.contacts = vec![1, 2];
        assert_eq!(s.check(), Ok(()));
        let refused = |f: &dyn Fn(&mut FiberGroupState), name: &str| {
            let mut t = s.clone();
            f(&mut t);
            let e = t.check().unwrap_err();
            assert!(e.contains(name), "{e}");
        };
        refused(
            &|t| t.contact_force.pop().map(|_| ()).unwrap_or(()),
            "contact_force",
        );
        refused(&|t| t.contacts.push(1), "contacts");
        refused(&|t| t.contact_force[4] = f64::NAN, "contact_force");
        refused(&|t| t.contact_segment = vec![1, 1], "ascending");
        refused(&|t| t.contact_segment = vec![1, 2], "past");
        refused(&|t| t.contacts = vec![1, 0], "0 contacts");
    }
}
