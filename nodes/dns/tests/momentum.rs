//! Two-way coupling's momentum budget in the DNS (docs/two-way.md): over 100 steps of a
//! turbulent channel with a body force from scattered point forces that change every step,
//! the fluid's x and z momentum changes by exactly the driving, the body force and the wall
//! stress (the solver's ledger), and the body force's impulse is exactly the spread forces'
//! sum times the time step.

use fiberflow_dns::{DnsConfig, Forcing, InitialField, Solver};

fn rnd(seed: &mut u64) -> f64 {
    *seed = seed
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    (*seed >> 11) as f64 / (1u64 << 53) as f64
}

/// 300 random points (a third within a kernel width of a wall) with random forces.
fn forces(seed: &mut u64, g: &fiberflow_dns::Grid) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
    let mut pts = Vec::new();
    let mut fs = Vec::new();
    for n in 0..300 {
        let y = if n % 3 == 0 {
            let near = 1.0 - 2.0 * (g.yf[2] - g.yf[0]) * rnd(seed);
            if n % 2 == 0 {
                near
            } else {
                -near
            }
        } else {
            2.0 * rnd(seed) - 1.0
        };
        pts.push([g.lx * rnd(seed), y, g.lz * rnd(seed)]);
        fs.push([
            5e-4 * (rnd(seed) - 0.3),
            5e-4 * (rnd(seed) - 0.5),
            5e-4 * (rnd(seed) - 0.3),
        ]);
    }
    (pts, fs)
}

fn budget_closes(forcing: Forcing) {
    let mut cfg = DnsConfig::with_cells(32, 32, 32);
    cfg.lx = 2.0;
    cfg.lz = 1.0;
    cfg.y1_plus = Some(1.0);
    cfg.forcing = forcing;
    cfg.init = InitialField::Turbulent {
        amplitude: 1.0,
        seed: 3,
    };
    let mut s = Solver::new(cfg).unwrap();
    let mut seed = 11u64;
    let p0 = s.momentum();
    s.open_ledger();
    let mut body_expected = [0.0f64; 2];
    let mut scale = 0.0f64;
    for _ in 0..100 {
        let (pts, fs) = forces(&mut seed, &s.grid);
        s.set_body_force(&pts, &fs);
        let dt = s.next_dt();
        let before = s.ledger().unwrap().body;
        s.step().unwrap();
        let after = s.ledger().unwrap().body;
        // every step: the fluid got the forces' sum times dt, exactly as given
        let sum: [f64; 2] = [fs.iter().map(|f| f[0]).sum(), fs.iter().map(|f| f[2]).sum()];
        for a in 0..2 {
            let got = after[a] - before[a];
            assert!(
                (got - dt * sum[a]).abs() <= 1e-12 * (dt * sum[a]).abs().max(1e-300),
                "step body impulse {got} vs {}",
                dt * sum[a]
            );
            body_expected[a] += dt * sum[a];
        }
        scale = scale.max(s.momentum()[0].abs());
    }
    let p1 = s.momentum();
    let l = s.ledger().unwrap();
    for a in 0..2 {
        let change = p1[a] - p0[a];
        let booked = l.driving[a] + l.body[a] + l.walls[a];
        let terms = l.driving[a].abs() + l.body[a].abs() + l.walls[a].abs();
        eprintln!(
            "axis {a}: change {change:.6e}, driving {:.6e}, body {:.6e}, walls {:.6e}, residual {:.2e}",
            l.driving[a],
            l.body[a],
            l.walls[a],
            change - booked
        );
        // round-off: 1e-12 of the momentum (sums of 32³ values over 300 substeps)
        assert!(
            (change - booked).abs() <= 1e-12 * (scale + terms),
            "axis {a}: change {change} booked {booked}"
        );
        assert!(
            (l.body[a] - body_expected[a]).abs() <= 1e-12 * body_expected[a].abs(),
            "body {} vs {}",
            l.body[a],
            body_expected[a]
        );
        assert!(l.body[a].abs() > 1e-3 * terms, "the body force must matter");
    }
}

#[test]
fn momentum_budget_closes_at_a_constant_pressure_gradient() {
    budget_closes(Forcing::PressureGradient);
}

#[test]
fn momentum_budget_closes_at_a_constant_flow_rate() {
    budget_closes(Forcing::FlowRate {
        bulk_velocity: 15.0,
    });
}
