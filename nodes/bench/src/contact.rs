//! `fiberflow-bench contact`: what fibre–fibre contact costs the fibre stage. One group of
//! case-1 fibres placed at random over the fine-grid box (as a launch file's
//! `placement.kind = "random"` does), stepped in a steady shear flow with a spanwise swirl
//! so neighbours move against each other, with contact off and on in alternating rounds
//! (off, on, on, off, …) from the same start; prints the wall per step of each, their
//! ratio per pair of rounds, the contacts per step and, of the steps with contact, the
//! closest approach of any two fibres (searched apart from the timing). `--near-wall`
//! puts the fibres in a band next to the lower wall, in a near-wall shear with
//! wall-normal sweeps, where fibres are pressed onto the wall and onto each other.

use anyhow::{Context, Result};
use fiberflow_fiber::FiberNodeConfig;
use fiberflow_fiber_model::contact;
use fiberflow_fiber_model::group::FiberGroup;
use fiberflow_fiber_model::FluidSample;
use nalgebra::{Matrix3, Vector3};
use std::time::Instant;

/// The fine grid's box (x, 2h, z) in wall units.
const BOX_PLUS: [f64; 3] = [942.48, 300.0, 471.24];

pub struct ContactOptions {
    pub fibers: usize,
    pub near_wall: bool,
    pub steps: usize,
    pub rounds: usize,
    /// Steps at the start of each round not counted.
    pub warmup: usize,
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

/// Near the lower wall (y from the centre, wall at −150): u+ = y+ up to 15 and
/// v = 1.5 sin(2π x/40) sin(2π z/40), faded in over the first 10 wall units.
fn near_wall_flow(r: &Vector3<f64>) -> FluidSample {
    let k = std::f64::consts::TAU / 40.0;
    let wall = r.y + 0.5 * BOX_PLUS[1];
    let (u, dudy) = if wall < 15.0 {
        (wall, 1.0)
    } else {
        (15.0, 0.0)
    };
    let (fade, dfade) = if wall < 10.0 {
        (wall / 10.0, 0.1)
    } else {
        (1.0, 0.0)
    };
    let (sx, cx, sz, cz) = (
        (k * r.x).sin(),
        (k * r.x).cos(),
        (k * r.z).sin(),
        (k * r.z).cos(),
    );
    FluidSample {
        vel: Vector3::new(u, 1.5 * sx * sz * fade, 0.0),
        grad: Matrix3::new(
            0.0,
            dudy,
            0.0,
            1.5 * k * cx * sz * fade,
            1.5 * sx * sz * dfade,
            1.5 * k * sx * cz * fade,
            0.0,
            0.0,
            0.0,
        ),
    }
}

fn build(o: &ContactOptions, contact: bool) -> Result<FiberGroup> {
    let text = format!(
        "group = \"bench\"\ncase = \"case1\"\nplacement = {{ kind = \"random\", count = {}, seed = 1{} }}\n{}",
        o.fibers,
        if o.near_wall {
            ", band_plus = [1.0, 31.0]"
        } else {
            ""
        },
        if contact {
            format!("contact = {{ friction = {} }}\n", o.friction)
        } else {
            String::new()
        }
    );
    let cfg: FiberNodeConfig = toml::from_str(&text).context("the benchmark's group")?;
    Ok(cfg.build(BOX_PLUS)?.group)
}

/// What a round of steps measured.
#[derive(Clone, Copy, Default)]
struct Round {
    /// Wall seconds per step.
    wall: f64,
    contacts: f64,
    candidates: f64,
    /// Closest centre-lines of segments of different fibres over d, over the steps
    /// (with contact only; ∞ when none within d).
    closest_over_d: f64,
    /// Minor page faults of the process per step (fresh memory touched inside the step).
    faults: f64,
    /// Wall seconds per step of the contact search (placing the segments, the scan, the
    /// rounds' searches around moved fibres) and of the solve (sweeps, copies, backstop).
    search: f64,
    solve: f64,
    /// Wall seconds per step of the search's floor ([`search_floor`]).
    floor: f64,
}

/// The contact search's floor: what any search must do with the step's segments — read
/// each centre once (24 bytes) and find its cell (side: a segment's length and a
/// diameter), counted per plane of cells across x — on one thread. A particular search
/// adds its sort and its pair tests; the candidates near the real contacts (hundreds a
/// step) are left out. Returns a checksum of the cells so the work is not optimised away.
fn search_floor(centres: &[[f64; 3]], planes: &mut Vec<u32>) -> u64 {
    let side = 3.0 + 0.232;
    let dims = BOX_PLUS.map(|l| ((l / side) as usize).max(1));
    let inv = BOX_PLUS.map(|l| 1.0 / l);
    planes.clear();
    planes.resize(dims[0], 0);
    let mut sum = 0u64;
    for c in centres {
        // the fraction of the box (periodic: wrapped), by truncation rather than a
        // library call
        let i = |k: usize| {
            let x = c[k] * inv[k] + 0.5;
            let mut f = x - (x as i64) as f64;
            if f < 0.0 {
                f += 1.0;
            }
            ((f * dims[k] as f64) as usize).min(dims[k] - 1)
        };
        let (x, y, z) = (i(0), i(1), i(2));
        planes[x] += 1;
        sum = sum.wrapping_add(((x * dims[1] + y) * dims[2] + z) as u64);
    }
    sum
}

/// The process's minor page faults so far (0 where the count cannot be read).
fn minor_faults() -> f64 {
    let mut u = std::mem::MaybeUninit::<libc::rusage>::zeroed();
    // SAFETY: getrusage writes the struct it is given; zeroed is a valid rusage
    let rc = unsafe { libc::getrusage(libc::RUSAGE_SELF, u.as_mut_ptr()) };
    if rc != 0 {
        return 0.0;
    }
    // SAFETY: initialised (zeroed, then written by the call)
    unsafe { u.assume_init() }.ru_minflt as f64
}

/// Steps `group` `warmup` times, then `steps` times counted.
fn run(mut group: FiberGroup, warmup: usize, steps: usize, near_wall: bool) -> Result<Round> {
    let dt = 0.2;
    let mut r = Round {
        closest_over_d: f64::INFINITY,
        ..Default::default()
    };
    let period = [Some(BOX_PLUS[0]), None, Some(BOX_PLUS[2])];
    let (mut planes, mut sum) = (Vec::new(), 0u64);
    let mut before = group.contact_time();
    for step in 0..warmup + steps {
        if step == warmup {
            before = group.contact_time();
        }
        let fluid: Vec<FluidSample> = group
            .segment_centres()
            .iter()
            .map(if near_wall { near_wall_flow } else { flow })
            .collect();
        let (t, f0) = (Instant::now(), minor_faults());
        let did = group.step(&fluid, dt)?.contact;
        if step >= warmup {
            r.wall += t.elapsed().as_secs_f64();
            r.faults += minor_faults() - f0;
            r.contacts += did.contacts.len() as f64;
            r.candidates += did.candidates as f64;
            if group.contact().is_some() {
                let centres: Vec<[f64; 3]> = group
                    .segment_centres()
                    .iter()
                    .map(|c| [c.x, c.y, c.z])
                    .collect();
                let t = Instant::now();
                sum = sum.wrapping_add(search_floor(&centres, &mut planes));
                r.floor += t.elapsed().as_secs_f64();
            }
        }
        if group.contact().is_some() {
            let fibers = group.fibers();
            for (a, i, _, _, distance) in contact::overlaps(&fibers, &period) {
                let d = fibers[a].props[i].shape.diameter;
                r.closest_over_d = r.closest_over_d.min(distance / d);
            }
        }
    }
    let after = group.contact_time();
    r.search = (after.rebuild_s - before.rebuild_s)
        + (after.scan_s - before.scan_s)
        + (after.around_s - before.around_s);
    r.solve = (after.sweeps_s - before.sweeps_s) + (after.rest_s - before.rest_s);
    std::hint::black_box(sum);
    let n = steps as f64;
    r.search /= n;
    r.solve /= n;
    r.floor /= n;
    r.wall /= n;
    r.contacts /= n;
    r.candidates /= n;
    r.faults /= n;
    Ok(r)
}

pub fn run_contact(o: &ContactOptions) -> Result<()> {
    let t = Instant::now();
    let off = build(o, false)?;
    let on = build(o, true)?;
    let (where_, n) = if o.near_wall {
        // the band is a tenth of the channel's height
        (
            "in a band 1-31 wall units from the lower wall",
            10.0 * crowding(o.fibers),
        )
    } else {
        ("at random in the fine-grid box", crowding(o.fibers))
    };
    println!(
        "{} case-1 fibres {where_} (crowding N = {n:.2} there), placed in {:.1} s; {} steps per round after {} not counted",
        o.fibers,
        t.elapsed().as_secs_f64(),
        o.steps,
        o.warmup
    );
    let mut ratios = Vec::new();
    println!(
        "| round | off ms/step | on ms/step | on/off | contacts/step | candidates/step | closest / d | page faults/step off, on | search ms/step | its floor ms/step (1 thread) | solve ms/step |\n|---|---|---|---|---|---|---|---|---|---|---|"
    );
    for r in 0..o.rounds {
        let order = if r % 2 == 0 {
            [false, true]
        } else {
            [true, false]
        };
        let mut got = [Round::default(); 2];
        for c in order {
            got[usize::from(c)] = run(
                if c { on.clone() } else { off.clone() },
                o.warmup,
                o.steps,
                o.near_wall,
            )?;
        }
        let ratio = got[1].wall / got[0].wall;
        ratios.push(ratio);
        println!(
            "| {} | {:.1} | {:.1} | {:.3} | {:.0} | {:.0} | {} | {:.0}, {:.0} | {:.1} | {:.1} | {:.1} |",
            r + 1,
            1e3 * got[0].wall,
            1e3 * got[1].wall,
            ratio,
            got[1].contacts,
            got[1].candidates,
            if got[1].closest_over_d.is_finite() {
                format!("{:.4}", got[1].closest_over_d)
            } else {
                "≥ 1".into()
            },
            got[0].faults,
            got[1].faults,
            1e3 * got[1].search,
            1e3 * got[1].floor,
            1e3 * got[1].solve
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
