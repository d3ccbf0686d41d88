//! A coupling step of several field steps (`flow.field_steps`, docs/two-way.md, "Field
//! steps per coupling step"): the DNS takes `m` steps of Δt/m while the fibres, and every
//! per-fibre stage of the flow node (sampling, spreading, the self-induced correction),
//! take one step of Δt. The fibres' body force is held over the `m` field steps, so the
//! fluid still receives exactly Δt·ΣF per coupling step.
//!
//! The field's bits are those of `m` plain steps: a run with `m` field steps per coupling
//! step of Δt walks the same field as one with a coupling step of Δt/m as long as the
//! fibres do not push on it (test `m_field_steps_are_m_plain_steps`).

use fiberflow_dns::{DnsError, Solver, StepReport};

/// Advances the field by `m` ≥ 1 steps (the solver's own fixed step each) and reports them
/// as one coupling step: the last step's number, time and bulk velocity, the summed time
/// step, the largest Courant sum and divergence, and the mean forcing (the mean pressure
/// gradient over the coupling step: the drag the flow status reports).
pub fn advance(solver: &mut Solver, m: u32) -> Result<StepReport, DnsError> {
    let mut r = solver.step()?;
    let mut forcing = r.forcing;
    for _ in 1..m {
        let next = solver.step()?;
        forcing += next.forcing;
        r = StepReport {
            dt_plus: r.dt_plus + next.dt_plus,
            cfl: r.cfl.max(next.cfl),
            max_divergence: r.max_divergence.max(next.max_divergence),
            ..next
        };
    }
    r.forcing = forcing / m.max(1) as f64;
    Ok(r)
}

#[cfg(test)]
mod tests {
    use super::*;
    use fiberflow_dns::{DnsConfig, Forcing};

    fn solver() -> Solver {
        let mut cfg = DnsConfig::with_cells(16, 16, 16);
        cfg.dt_fixed_plus = Some(0.3);
        cfg.forcing = Forcing::FlowRate {
            bulk_velocity: 15.0,
        };
        Solver::new(cfg).unwrap()
    }

    /// Three field steps in one call leave the field bit for bit where three plain steps
    /// leave it, and report the three as one: the summed Δt, the last step's number and
    /// time, the largest Courant sum and the forcing's mean.
    #[test]
    fn m_field_steps_are_m_plain_steps() {
        let (mut a, mut b) = (solver(), solver());
        let plain: Vec<StepReport> = (0..3).map(|_| a.step().unwrap()).collect();
        let r = advance(&mut b, 3).unwrap();
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert!(bits(&a.vel.u) == bits(&b.vel.u));
        assert!(bits(&a.vel.v) == bits(&b.vel.v));
        assert!(bits(&a.vel.w) == bits(&b.vel.w));
        assert_eq!(r.step, 3);
        assert_eq!(r.t_plus.to_bits(), plain[2].t_plus.to_bits());
        assert!((r.dt_plus - 0.9).abs() < 1e-12, "{}", r.dt_plus);
        let cfl = plain.iter().map(|p| p.cfl).fold(0.0, f64::max);
        assert_eq!(r.cfl, cfl);
        let forcing = plain.iter().map(|p| p.forcing).sum::<f64>() / 3.0;
        assert!(
            (r.forcing - forcing).abs() <= 1e-12 * forcing.abs(),
            "{}",
            r.forcing
        );
        assert_eq!(r.bulk_velocity, plain[2].bulk_velocity);
        // one field step is a plain step
        let (mut c, mut d) = (solver(), solver());
        let one = advance(&mut c, 1).unwrap();
        let p = d.step().unwrap();
        assert_eq!(one.forcing.to_bits(), p.forcing.to_bits());
        assert!(bits(&c.vel.u) == bits(&d.vel.u));
    }
}
