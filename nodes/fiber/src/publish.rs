//! What a fibre node publishes: its group's state every step (complete, or lean between
//! the recorder's complete states; with two-way coupling each segment's force; with
//! contact the load) and its per-fibre metrics when due. The messages are refilled in
//! place: their per-fibre arrays are set once, the segment arrays keep their allocations.

use crate::piece::ServedPiece;
use fiberflow_bus::BusError;
use std::time::Instant;

impl ServedPiece {
    /// Publishes the state of step `step`.
    pub(crate) fn publish_state(&mut self, step: u64) -> Result<(), BusError> {
        let full = self.full_states_every <= 1
            || step.is_multiple_of(self.full_states_every)
            || step == self.steps;
        let st = &mut self.state_msg.0;
        st.step = step;
        st.t_plus = step as f64 * self.dt;
        st.centre.clear();
        st.axis.clear();
        st.velocity.clear();
        st.angular_velocity.clear();
        self.group.extend_state(
            full,
            &mut st.centre,
            &mut st.axis,
            &mut st.velocity,
            &mut st.angular_velocity,
        );
        st.hydro_force.clear();
        if self.two_way {
            self.group.extend_forces(&mut st.hydro_force);
        }
        let load = self.group.contact_load();
        st.contact_segment.clone_from(&load.segment);
        st.contact_force.clone_from(&load.force);
        st.contacts.clone_from(&load.count);
        self.bus.publish_message(&self.state_topic, &self.state_msg)
    }

    /// Publishes the per-fibre metrics of step `step`.
    pub(crate) fn publish_metrics(&mut self, step: u64) -> Result<(), BusError> {
        self.group.metrics_into(&mut self.fiber_metrics);
        let ms = &self.fiber_metrics;
        let n = ms.len().max(1) as f64;
        let m = &mut self.metrics_msg.0;
        m.step = step;
        m.t_plus = step as f64 * self.dt;
        m.centre_of_mass.clear();
        m.centre_of_mass
            .extend(ms.iter().flat_map(|m| m.centre_of_mass.iter().copied()));
        m.z1.clear();
        m.z1.extend(ms.iter().map(|m| m.z1));
        m.sigma2.clear();
        m.sigma2.extend(ms.iter().map(|m| m.sigma2));
        m.end_to_end.clear();
        m.end_to_end.extend(ms.iter().map(|m| m.end_to_end));
        m.mean_abs_z1 = ms.iter().map(|m| m.z1.abs()).sum::<f64>() / n;
        m.mean_sigma2 = ms.iter().map(|m| m.sigma2).sum::<f64>() / n;
        self.bus
            .publish_message(&self.metrics_topic, &self.metrics_msg)
    }

    /// Publishes the state of step `step` just integrated to (and its metrics when due).
    pub(crate) fn publish_step(&mut self, step: u64) -> Result<(), BusError> {
        let t0 = Instant::now();
        self.publish_state(step)?;
        if step.is_multiple_of(self.metrics_every_steps) || step == self.steps {
            self.publish_metrics(step)?;
        }
        self.times.publishing_s += t0.elapsed().as_secs_f64();
        Ok(())
    }
}
