//! The rows each recorded message becomes (columns in the order of `columns.rs`).

use crate::table::{TableWriter, Value};
use crate::ExportError;
use fiberflow_messages::{FiberGroupMetrics, FiberGroupState, FlowProfiles, FlowStatus};

/// The three components of point `i` of a flat array of 3-vectors.
fn xyz(v: &[f64], i: usize) -> &[f64] {
    &v[3 * i..3 * i + 3]
}

/// The rows of one group's state at one step, from its slices in fibre order: one per
/// segment to `states`, one per segment that touched to `contacts`.
pub fn state(
    slices: &[FiberGroupState],
    mut states: Option<&mut TableWriter>,
    mut contacts: Option<&mut TableWriter>,
) -> Result<(), ExportError> {
    for s in slices {
        let mut seg = 0usize;
        // the slice's touched segments are ascending: walked beside its segments
        let mut touched = s.contact_segment.iter().enumerate().peekable();
        for (f, &n) in s.segments_per_fiber.iter().enumerate() {
            let fiber = s.first_fiber + f as u32;
            for k in 0..n {
                let contact = match touched.peek() {
                    Some(&(j, &at)) if at as usize == seg => {
                        touched.next();
                        Some((xyz(&s.contact_force, j), s.contacts[j]))
                    }
                    _ => None,
                };
                if let Some(w) = states.as_deref_mut() {
                    w.push(Value::U64(s.step));
                    w.push(Value::F64(s.t_plus));
                    w.push(Value::Text(&s.group));
                    w.push(Value::U32(fiber));
                    w.push(Value::U32(k));
                    w.push(Value::U32(n));
                    w.push(Value::F64(s.segment_length[f]));
                    w.push(Value::F64(s.diameter[f]));
                    w.push(Value::F64(s.density_ratio[f]));
                    w.push(Value::U8(s.layer[f]));
                    w.push_f64s(xyz(&s.centre, seg));
                    w.push_f64s(xyz(&s.axis, seg));
                    w.push_f64s(xyz(&s.velocity, seg));
                    w.push_f64s(xyz(&s.angular_velocity, seg));
                    for c in 0..3 {
                        w.push(Value::Opt(s.hydro_force.get(3 * seg + c).copied()));
                    }
                    match contact {
                        Some((force, count)) => {
                            w.push_f64s(force);
                            w.push(Value::U32(count));
                        }
                        None => {
                            w.push_f64s(&[0.0; 3]);
                            w.push(Value::U32(0));
                        }
                    }
                    w.end_row()?;
                }
                if let (Some(w), Some((force, count))) = (contacts.as_deref_mut(), contact) {
                    w.push(Value::U64(s.step));
                    w.push(Value::F64(s.t_plus));
                    w.push(Value::Text(&s.group));
                    w.push(Value::U32(fiber));
                    w.push(Value::U32(k));
                    w.push_f64s(force);
                    w.push(Value::U32(count));
                    w.end_row()?;
                }
                seg += 1;
            }
        }
    }
    Ok(())
}

/// The rows of one group's metrics at one step, from its slices in fibre order.
pub fn metrics(slices: &[FiberGroupMetrics], w: &mut TableWriter) -> Result<(), ExportError> {
    for m in slices {
        for f in 0..m.z1.len() {
            w.push(Value::U64(m.step));
            w.push(Value::F64(m.t_plus));
            w.push(Value::Text(&m.group));
            w.push(Value::U32(m.first_fiber + f as u32));
            w.push_f64s(xyz(&m.centre_of_mass, f));
            w.push(Value::F64(m.z1[f]));
            w.push(Value::F64(m.sigma2[f]));
            w.push(Value::F64(m.end_to_end[f]));
            w.end_row()?;
        }
    }
    Ok(())
}

/// The row of one flow status.
pub fn flow(s: &FlowStatus, w: &mut TableWriter) -> Result<(), ExportError> {
    w.push(Value::U64(s.step));
    w.push(Value::F64(s.t_plus));
    w.push_f64s(&[s.dt_plus, s.cfl, s.max_divergence, s.bulk_velocity]);
    // NaN on steps without a wall-shear evaluation
    w.push(Value::Opt(Some(s.re_tau).filter(|x| !x.is_nan())));
    w.push(Value::F64(s.pressure_gradient));
    for c in 0..3 {
        w.push(Value::Opt(s.fiber_force_plus.get(c).copied()));
    }
    w.end_row()
}

/// The rows of one profiles message: one per wall distance.
pub fn profiles(p: &FlowProfiles, w: &mut TableWriter) -> Result<(), ExportError> {
    for j in 0..p.y_plus.len() {
        w.push(Value::U64(p.step));
        w.push(Value::F64(p.t_plus));
        w.push(Value::U64(p.samples));
        w.push_f64s(&[p.t_plus_span, p.re_tau, p.bulk_velocity]);
        w.push_f64s(&[
            p.y_plus[j],
            p.u_mean[j],
            p.u_rms[j],
            p.v_rms[j],
            p.w_rms[j],
            p.uv[j],
            p.omega_z_mean[j],
            p.omega_x_rms[j],
            p.omega_y_rms[j],
            p.omega_z_rms[j],
        ]);
        w.end_row()?;
    }
    Ok(())
}
