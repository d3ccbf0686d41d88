//! The time integrator: low-storage 3-stage Runge–Kutta (Wray) with a fractional-step
//! projection per substep, Crank–Nicolson wall-normal diffusion, and adaptive Δt.

use crate::config::{DnsConfig, Forcing};
use crate::correct;
use crate::error::DnsError;
use crate::field::{bulk_mean, copy_z_halos, fill_plane_halo, update_halo, Component, Velocity};
use crate::grid::Grid;
use crate::implicit::YTridiag;
use crate::init;
use crate::poisson::Poisson;
use crate::rhs;
use crate::timestep;
use rayon::prelude::*;

const GAMMA: [f64; 3] = [8.0 / 15.0, 5.0 / 12.0, 3.0 / 4.0];
const ZETA: [f64; 3] = [0.0, -17.0 / 60.0, -5.0 / 12.0];

/// What one step did (the numbers a flow-status message carries).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepReport {
    pub step: u64,
    pub t_plus: f64,
    pub dt_plus: f64,
    pub cfl: f64,
    pub max_divergence: f64,
    pub bulk_velocity: f64,
    /// Mean body force applied this step (1 for a constant pressure gradient).
    pub forcing: f64,
}

/// Channel-flow DNS state and work arrays.
#[derive(Debug)]
pub struct Solver {
    pub cfg: DnsConfig,
    pub grid: Grid,
    pub vel: Velocity,
    /// Pressure correction of the last substep (padded, cell-centred).
    pub phi: Vec<f64>,
    /// Time in outer units (h/u_tau).
    pub time: f64,
    pub step: u64,
    rhs_new: Velocity,
    rhs_old: Velocity,
    /// Second velocity buffer: each substep writes the updated field here, then swaps.
    vel_next: Velocity,
    poisson: Poisson,
    /// Current mean body force (flow-rate mode adjusts it).
    forcing: f64,
    /// Max |div u| at the last check.
    last_divergence: f64,
    /// Two-way coupling: the fibres' body force per unit mass (outer units, staggered like
    /// the velocity), added to every substep of the next step; `None` when one-way.
    body_force: Option<crate::spread::BodyForce>,
    /// Where the fluid's x and z momentum came from, when kept (tests and budgets).
    ledger: Option<MomentumLedger>,
}

/// The impulses the fluid received in x and z since the ledger was opened, term by term
/// (outer units, Σ over the grid of velocity × control volume): the discrete momentum
/// budget, exact to round-off because convection and the x/z diffusion telescope to zero
/// over the periodic box and the projection's pressure gradient sums to zero along x and z.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct MomentumLedger {
    /// Mean pressure gradient (and, at a constant flow rate, the shifts that hold it).
    pub driving: [f64; 2],
    /// The body force of two-way coupling.
    pub body: [f64; 2],
    /// Viscous stress at the two walls (Crank–Nicolson: the mean of the substep's old and
    /// new wall gradients).
    pub walls: [f64; 2],
}

impl Solver {
    /// A solver with the configured initial field.
    pub fn new(cfg: DnsConfig) -> Result<Self, DnsError> {
        cfg.validate()?;
        let grid = Grid::new(
            cfg.nx,
            cfg.ny,
            cfg.nz,
            cfg.lx,
            cfg.lz,
            cfg.re_tau,
            cfg.y1_plus,
        )?;
        let mut vel = Velocity::zeros(&grid);
        init::fill(&grid, cfg.re_tau, &cfg.init, &mut vel);
        vel.update_halos(&grid);
        let n = grid.padded_len();
        let poisson = Poisson::new(&grid);
        let mut s = Self {
            rhs_new: Velocity::zeros(&grid),
            rhs_old: Velocity::zeros(&grid),
            vel_next: Velocity::zeros(&grid),
            phi: vec![0.0; n],
            poisson,
            grid,
            vel,
            time: 0.0,
            step: 0,
            forcing: 1.0,
            last_divergence: 0.0,
            body_force: None,
            ledger: None,
            cfg,
        };
        s.project(1.0);
        if let Forcing::FlowRate { bulk_velocity } = s.cfg.forcing {
            s.set_bulk_velocity(bulk_velocity);
        }
        Ok(s)
    }

    /// Viscous time unit in outer units.
    pub fn t_unit(&self) -> f64 {
        1.0 / self.cfg.re_tau
    }

    pub fn t_plus(&self) -> f64 {
        self.time * self.cfg.re_tau
    }

    /// Makes the field divergence-free (`scale` only sets the size of `phi`).
    pub fn project(&mut self, scale: f64) {
        let g = &self.grid;
        self.poisson
            .solve_divergence(g, &self.vel, 1.0 / scale, &mut self.phi);
        update_halo(g, &mut self.phi, Component::Scalar);
        correct::project(g, &mut self.vel, &self.phi, scale);
        self.vel.update_halos(g);
    }

    /// Gives the field realisation `seed`'s start: adds the seeded disturbance of
    /// [`crate::perturb`], projects, and restores the held flow rate.
    pub fn perturb(&mut self, seed: u64) {
        crate::perturb::add_disturbance(&self.grid, seed, &mut self.vel);
        self.vel.update_halos(&self.grid);
        self.project(1.0);
        if let Forcing::FlowRate { bulk_velocity } = self.cfg.forcing {
            self.set_bulk_velocity(bulk_velocity);
        }
    }

    fn set_bulk_velocity(&mut self, target: f64) {
        let ub = bulk_mean(&self.grid, &self.vel.u);
        let g = &self.grid;
        let shift = target - ub;
        for k in 1..=g.nz {
            for j in 1..=g.ny {
                for i in 1..=g.nx {
                    self.vel.u[g.idx(i, j, k)] += shift;
                }
            }
        }
        self.vel.update_halos(g);
    }

    /// The time step the next call to [`Solver::step`] will take (outer units).
    pub fn next_dt(&self) -> f64 {
        self.dt_for_rate(timestep::max_courant_rate(&self.grid, &self.vel))
    }

    /// Time step for a given Courant rate (max of |u|/dx + |v|/dy + |w|/dz).
    fn dt_for_rate(&self, rate: f64) -> f64 {
        let unit = self.t_unit();
        if let Some(dt) = self.cfg.dt_fixed_plus {
            return dt * unit;
        }
        let visc = timestep::viscous_dt_limit(&self.grid, self.cfg.nu(), self.cfg.implicit_y);
        let conv = if rate > 0.0 {
            self.cfg.cfl / rate
        } else {
            f64::INFINITY
        };
        conv.min(visc).min(self.cfg.dt_max_plus * unit)
    }

    /// Advances one full RK3 step; returns an error instead of producing garbage.
    ///
    /// The step runs on a thread of the rayon pool (the caller waits once): its dozens of
    /// parallel loops then split among the pool's threads directly, where each loop
    /// started from outside the pool was handed in and waited for on its own (what it
    /// saves: docs/history/performance.md, "Paper size, 2026-12-03").
    pub fn step(&mut self) -> Result<StepReport, DnsError> {
        rayon::scope(|_| self.step_in_pool())
    }

    fn step_in_pool(&mut self) -> Result<StepReport, DnsError> {
        // one pass over the field for both the time step and the Courant check
        let rate = timestep::max_courant_rate(&self.grid, &self.vel);
        let dt = self.dt_for_rate(rate);
        let cfl = rate * dt;
        if !cfl.is_finite() || cfl > 2.0 * timestep::RK3_CFL_LIMIT {
            return Err(DnsError::BlowUp {
                step: self.step,
                t_plus: self.t_plus(),
                reason: format!(
                    "Courant number {cfl:.3} (limit {:.2})",
                    timestep::RK3_CFL_LIMIT
                ),
            });
        }
        for s in 0..3 {
            self.substep(dt, GAMMA[s], ZETA[s]);
        }
        self.time += dt;
        self.step += 1;
        let mut bulk = bulk_mean(&self.grid, &self.vel.u);
        if let Forcing::FlowRate { bulk_velocity } = self.cfg.forcing {
            // the uniform shift is the impulse of the extra mean pressure gradient the step
            // needed: it adds to the forcing applied (so the forcing converges to the
            // mean pressure gradient that holds the flow rate, and is checkpointed as such)
            self.forcing += (bulk_velocity - bulk) / dt;
            let before = self.ledger.map(|_| self.momentum()[0]);
            self.set_bulk_velocity(bulk_velocity);
            if let Some(before) = before {
                let shift = self.momentum()[0] - before;
                if let Some(l) = self.ledger.as_mut() {
                    l.driving[0] += shift;
                }
            }
            bulk = bulk_velocity;
        }
        // the divergence check is a full pass: every `check_every_steps` steps (NaN is caught
        // every step by the Courant rate and the bulk velocity)
        if self.step.is_multiple_of(self.cfg.check_every_steps) {
            self.last_divergence = correct::max_divergence(&self.grid, &self.vel);
        }
        let max_div = self.last_divergence;
        if !bulk.is_finite() || !max_div.is_finite() {
            return Err(DnsError::BlowUp {
                step: self.step,
                t_plus: self.t_plus(),
                reason: "non-finite velocity".into(),
            });
        }
        Ok(StepReport {
            step: self.step,
            t_plus: self.t_plus(),
            dt_plus: dt * self.cfg.re_tau,
            cfl,
            max_divergence: max_div,
            bulk_velocity: bulk,
            forcing: self.forcing,
        })
    }

    /// One Runge–Kutta substep: right-hand side, implicit y-diffusion, projection. Long
    /// (≈110 lines): the stages in order, each a call with its buffers.
    fn substep(&mut self, dt: f64, gamma: f64, zeta: f64) {
        let alpha = gamma + zeta;
        let walls_before = self.ledger.map(|_| self.wall_gradients());
        let g = &self.grid;
        let nu = self.cfg.nu();
        let implicit = self.cfg.implicit_y;
        let fx = match self.cfg.forcing {
            Forcing::PressureGradient => 1.0,
            Forcing::FlowRate { .. } => self.forcing,
        };
        let c = 0.5 * alpha * dt * nu;
        let tri_t = YTridiag::tangential(g, c);
        let tri_n = YTridiag::normal(g, c);
        let plane = g.plane();
        let vel = &self.vel;
        let body = self.body_force.as_ref();
        let (px, nx, ny) = (g.px, g.nx, g.ny);
        let new = &mut self.rhs_new;
        let old = &mut self.rhs_old;
        let next = &mut self.vel_next;
        // One pass per k-plane: explicit terms, RK combination, implicit y-solve, and the
        // updated velocity (with its in-plane halo) into the second buffer; `old` ends up
        // holding the increment, `new` this substep's explicit terms.
        new.u
            .par_chunks_mut(plane)
            .zip(new.v.par_chunks_mut(plane))
            .zip(new.w.par_chunks_mut(plane))
            .zip(old.u.par_chunks_mut(plane))
            .zip(old.v.par_chunks_mut(plane))
            .zip(old.w.par_chunks_mut(plane))
            .zip(next.u.par_chunks_mut(plane))
            .zip(next.v.par_chunks_mut(plane))
            .zip(next.w.par_chunks_mut(plane))
            .enumerate()
            .filter(|(k, _)| *k >= 1 && *k <= g.nz)
            .for_each(
                |(k, ((((((((nu_, nv_), nw_), ou), ov), ow), xu), xv), xw))| {
                    rhs::plane_rhs(g, vel, nu, implicit, k, nu_, nv_, nw_);
                    let a = dt * gamma;
                    let b = dt * zeta;
                    let f = alpha * dt * fx;
                    for j in 1..=ny {
                        let r = j * px + 1..j * px + 1 + nx;
                        for (o, n) in ou[r.clone()].iter_mut().zip(&nu_[r.clone()]) {
                            *o = a * n + b * *o + f;
                        }
                        for (o, n) in ow[r.clone()].iter_mut().zip(&nw_[r.clone()]) {
                            *o = a * n + b * *o;
                        }
                        if j < ny {
                            for (o, n) in ov[r.clone()].iter_mut().zip(&nv_[r.clone()]) {
                                *o = a * n + b * *o;
                            }
                        }
                    }
                    if let Some(force) = body {
                        // the fibres' reaction, constant over the step (Σ α = 1 over the
                        // three substeps, so the step's impulse is dt·a exactly), added at
                        // the nodes the fibres touch
                        let c = alpha * dt;
                        for (comp, o) in [&mut *ou, &mut *ov, &mut *ow].into_iter().enumerate() {
                            for &(at, a) in force.entries(comp, k) {
                                o[at as usize] += c * a;
                            }
                        }
                    }
                    if implicit {
                        let s = alpha * dt * nu;
                        rhs::add_lyy_tangential(g, &vel.u, k, s, ou);
                        rhs::add_lyy_tangential(g, &vel.w, k, s, ow);
                        rhs::add_lyy_normal(g, &vel.v, k, s, ov);
                        tri_t.solve_plane(g, ou);
                        tri_t.solve_plane(g, ow);
                        tri_n.solve_plane(g, ov);
                    }
                    let c = k * plane;
                    for (x, cur, d, jmax, comp) in [
                        (xu, &vel.u, &*ou, ny, Component::Tangential),
                        (xv, &vel.v, &*ov, ny - 1, Component::Normal),
                        (xw, &vel.w, &*ow, ny, Component::Tangential),
                    ] {
                        for j in 1..=jmax {
                            let r = j * px + 1..j * px + 1 + nx;
                            let cur_row = &cur[c + r.start..c + r.end];
                            for ((y, v0), dv) in x[r.clone()].iter_mut().zip(cur_row).zip(&d[r]) {
                                *y = v0 + dv;
                            }
                        }
                        fill_plane_halo(g, x, comp);
                    }
                },
            );
        copy_z_halos(g, [&mut next.u, &mut next.v, &mut next.w]);
        std::mem::swap(&mut self.vel, &mut self.vel_next);
        std::mem::swap(&mut self.rhs_new, &mut self.rhs_old);
        self.project(alpha * dt);
        if let Some(before) = walls_before {
            self.book_substep(alpha * dt, fx, before);
        }
    }

    /// Σ over the walls' faces of ν ∂u/∂y and ν ∂w/∂y pointing into the fluid, times the
    /// face areas: the x and z force the walls exert on the fluid (outer units; minus the
    /// wall shear force, the drag).
    pub fn wall_gradients(&self) -> [f64; 2] {
        let g = &self.grid;
        let (ny, nu) = (g.ny, self.cfg.nu());
        let mut out = [0.0; 2];
        for (o, f) in out.iter_mut().zip([&self.vel.u, &self.vel.w]) {
            let mut s = 0.0;
            for k in 1..=g.nz {
                for i in 1..=g.nx {
                    let top = (f[g.idx(i, ny + 1, k)] - f[g.idx(i, ny, k)]) / g.dyc[ny];
                    let bottom = (f[g.idx(i, 1, k)] - f[g.idx(i, 0, k)]) / g.dyc[0];
                    s += top - bottom;
                }
            }
            *o = nu * s * g.dx * g.dz;
        }
        out
    }

    /// Books one substep of length `c = α dt` in the ledger.
    fn book_substep(&mut self, c: f64, fx: f64, before: [f64; 2]) {
        let g = &self.grid;
        let volume = g.lx * 2.0 * g.lz;
        let after = self.wall_gradients();
        let body = self.body_force.as_ref().map_or([0.0; 2], |b| {
            [
                crate::spread::total(g, &b.field.u, 0),
                crate::spread::total(g, &b.field.w, 2),
            ]
        });
        if let Some(l) = self.ledger.as_mut() {
            l.driving[0] += c * fx * volume;
            for a in 0..2 {
                l.body[a] += c * body[a];
                l.walls[a] += 0.5 * c * (before[a] + after[a]);
            }
        }
    }
}

impl Solver {
    /// The checkpoint header describing the current state.
    pub fn checkpoint_header(&self) -> crate::checkpoint::CheckpointHeader {
        crate::checkpoint::CheckpointHeader {
            nx: self.grid.nx,
            ny: self.grid.ny,
            nz: self.grid.nz,
            lx: self.grid.lx,
            lz: self.grid.lz,
            re_tau: self.cfg.re_tau,
            time: self.time,
            step: self.step,
            forcing: self.forcing,
            dy_first: self.grid.dyf[1],
        }
    }

    /// Two-way coupling: spreads point forces on the fluid (`points` and `forces` in outer
    /// units, ρ = 1; see [`crate::spread`]) into the body force every substep of the next
    /// steps adds, until it is set again or cleared.
    pub fn set_body_force(&mut self, points: &[[f64; 3]], forces: &[[f64; 3]]) {
        let g = &self.grid;
        let out = self
            .body_force
            .get_or_insert_with(|| crate::spread::BodyForce::zeros(g));
        crate::spread::spread(g, points, forces, out);
    }

    /// Starts (or restarts) keeping the momentum ledger.
    pub fn open_ledger(&mut self) {
        self.ledger = Some(MomentumLedger::default());
    }

    /// The ledger since [`Self::open_ledger`] (None: not kept).
    pub fn ledger(&self) -> Option<MomentumLedger> {
        self.ledger
    }

    /// Total x and z momentum of the fluid (Σ u V, Σ w V over the interior, outer units).
    pub fn momentum(&self) -> [f64; 2] {
        let g = &self.grid;
        [
            crate::spread::total(g, &self.vel.u, 0),
            crate::spread::total(g, &self.vel.w, 2),
        ]
    }

    /// Back to no body force (the one-way step, bit for bit).
    pub fn clear_body_force(&mut self) {
        self.body_force = None;
    }

    /// The body force per unit mass the next step adds (None: none).
    pub fn body_force(&self) -> Option<&Velocity> {
        self.body_force.as_ref().map(|b| &b.field)
    }

    /// Max |div u| found by the last periodic check (reported in every step's report).
    pub fn last_divergence(&self) -> f64 {
        self.last_divergence
    }

    /// Restores the last check's value (coupled checkpoints carry it, so a resumed run
    /// reports what an uninterrupted one does between two checks).
    pub fn set_last_divergence(&mut self, d: f64) {
        self.last_divergence = d;
    }

    /// Writes a checkpoint (atomic).
    pub fn write_checkpoint(&self, path: &std::path::Path) -> Result<(), DnsError> {
        crate::checkpoint::write(path, &self.grid, &self.checkpoint_header(), &self.vel)
    }

    /// Restores velocity, time, step and forcing from a checkpoint.
    pub fn read_checkpoint(&mut self, path: &std::path::Path) -> Result<(), DnsError> {
        let h = crate::checkpoint::read(path, &self.grid, &mut self.vel)?;
        if (h.dy_first - self.grid.dyf[1]).abs() > 1e-12 * self.grid.dyf[1]
            || (h.lx - self.grid.lx).abs() > 1e-12
            || (h.lz - self.grid.lz).abs() > 1e-12
        {
            return Err(DnsError::Checkpoint {
                path: path.display().to_string(),
                reason: "box size or y-stretching differs from the configuration".into(),
            });
        }
        self.vel.update_halos(&self.grid);
        self.time = h.time;
        self.step = h.step;
        self.forcing = h.forcing;
        Ok(())
    }

    /// Restores from a checkpoint written on another grid over the same box: the velocity
    /// is interpolated (tricubic) and projected; time, step and forcing carry over.
    pub fn read_checkpoint_regridded(&mut self, path: &std::path::Path) -> Result<(), DnsError> {
        let (vel, h) = crate::regrid::read_onto(path, &self.grid)?;
        self.vel = vel;
        self.time = h.time;
        self.step = h.step;
        self.forcing = h.forcing;
        self.project(1.0);
        Ok(())
    }
}
