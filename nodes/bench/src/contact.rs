//! `fiberflow-bench contact`: what fibre–fibre contact costs the fibre stage. One group of
//! case-1 fibres placed at random over the fine-grid box (as a launch file's
//! `placement.kind = "random"` does), stepped in a steady shear flow with a spanwise swirl
//! so neighbours move against each other, with contact off and on in alternating rounds
//! (off, on, on, off, …) from the same start; prints the wall per step of each, their
//! ratio per pair of rounds, and the contacts per step.

use anyhow::{Context, Result};
use fiberflow_fiber::FiberNodeConfig;
use fiberflow_fiber_model::group::FibreGroup;
use fiberflow_fiber_model::FluidSample;
use nalgebra::{Matrix3, Vector3};
use std::time::Instant;

/// The fine grid's box (x, 2h, z) in wall units.
const BOX_PLUS: [f64; 3] = [942.48, 300.0, 471.24];

pub struct ContactOptions {
    pub fibres: usize,
    pub steps: usize,
    pub rounds: usize,
    pub friction: f64,
}

/// A steady flow with shear and a spanwise swirl of wavelength 50 wall units: u = y'·1 +
/// 2 sin(2π z/50), w = 0.5 sin(2π x/50), where y' = y from the centre plane.
fn flow(r: &Vector3<f64>) -> FluidSample {
    let k = std::f64::consts::TAU / 50.0;
    let y = r.y;
    FluidSample {
        vel: Vector3::new(0.05 * y + 2.0 * (k * r.z).sin(), 0.0, 0.5 * (k * r.x).sin()),
        grad: Matrix3::new(
            0.0,
            0.05,
            2.0 * k * (k * r.z).cos(),
            0.0,
            0.0,
            0.0,
            0.5 * k * (k * r.x).cos(),
            0.0,
            0.0,
        ),
    }
}

fn build(o: &ContactOptions, contact: bool) -> Result<FibreGroup> {
    let text = format!(
        "group = \"bench\"\ncase = \"case1\"\nplacement = {{ kind = \"random\", count = {}, seed = 1 }}\n{}",
        o.fibres,
        if contact {
            format!("contact = {{ friction = {} }}\n", o.friction)
        } else {
            String::new()
        }
    );
    let cfg: FiberNodeConfig = toml::from_str(&text).context("the benchmark's group")?;
    Ok(cfg.build(BOX_PLUS)?.group)
}

/// Steps `group` `steps` times; wall seconds per step, contacts and candidate pairs per
/// step.
fn run(mut group: FibreGroup, steps: usize) -> Result<(f64, f64, f64)> {
    let dt = 0.2;
    let mut contacts = 0usize;
    let mut candidates = 0usize;
    let mut wall = 0.0;
    for _ in 0..steps {
        let fluid: Vec<FluidSample> = group.segment_centres().iter().map(flow).collect();
        let t = Instant::now();
        group.step(&fluid, dt)?;
        wall += t.elapsed().as_secs_f64();
        contacts += group.last_contact().contacts.len();
        candidates += group.last_contact().candidates;
    }
    let n = steps as f64;
    Ok((wall / n, contacts as f64 / n, candidates as f64 / n))
}

pub fn run_contact(o: &ContactOptions) -> Result<()> {
    let t = Instant::now();
    let off = build(o, false)?;
    let on = build(o, true)?;
    println!(
        "{} case-1 fibres at random in the fine-grid box (crowding N = {:.2}), placed in {:.1} s; {} steps per round",
        o.fibres,
        crowding(o.fibres),
        t.elapsed().as_secs_f64(),
        o.steps
    );
    let mut ratios = Vec::new();
    println!(
        "| round | off ms/step | on ms/step | on/off | contacts/step | candidates/step |\n|---|---|---|---|---|---|"
    );
    for r in 0..o.rounds {
        let order = if r % 2 == 0 {
            [false, true]
        } else {
            [true, false]
        };
        let mut got = [(0.0, 0.0, 0.0); 2];
        for c in order {
            got[usize::from(c)] = run(if c { on.clone() } else { off.clone() }, o.steps)?;
        }
        let ratio = got[1].0 / got[0].0;
        ratios.push(ratio);
        println!(
            "| {} | {:.1} | {:.1} | {:.3} | {:.0} | {:.0} |",
            r + 1,
            1e3 * got[0].0,
            1e3 * got[1].0,
            ratio,
            got[1].1,
            got[1].2
        );
    }
    ratios.sort_by(f64::total_cmp);
    println!(
        "on/off: median {:.3}, range {:.3}–{:.3} over {} rounds",
        ratios[ratios.len() / 2],
        ratios[0],
        ratios[ratios.len() - 1],
        ratios.len()
    );
    Ok(())
}

/// Crowding number N = (2/3) c_v (L/d)² of `n` case-1 fibres (7 × l+ 3, d+ 0.232) in the box.
fn crowding(n: usize) -> f64 {
    let (l, d) = (21.0, 0.232_f64);
    let volume = BOX_PLUS.iter().product::<f64>();
    let cv = n as f64 * std::f64::consts::FRAC_PI_4 * d * d * l / volume;
    2.0 / 3.0 * cv * (l / d).powi(2)
}
