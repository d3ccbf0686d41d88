//! What the fibres do to the flow (docs/two-way.md, "Reading a two-way run"): Re_τ from the
//! wall shear, bulk velocity, skin friction, the pressure gradient that held the flow rate
//! and the fibres' term of the mean-momentum budget, each as a batch mean over time with a
//! 95% interval; mean-velocity, rms and Reynolds-stress profiles per batch; and all of it
//! against an unladen (or one-way) run of the same flow. CSV + PNG + summary.
//!
//! Batch means: the samples after the transient are cut into `batches` contiguous runs of
//! equal length, each run's mean is one sample, and the interval is Student's t (95%,
//! batches − 1 degrees of freedom) times their standard error. Batches much longer than the
//! flow's correlation time (≈ 100 t+ here) make the batch means nearly independent.
//!
//! The mean-momentum budget per unit volume, outer units (u_τ = 1 nominal, h = 1), averaged
//! over the channel and over time at a constant flow rate:
//!   Π = τ_w + f_x,   τ_w = (Re_τ/h+)²,   f_x = −F_x+ h+/V+,
//! Π the driving pressure gradient, τ_w the mean wall shear, F_x+ the fibres' total force on
//! the fluid (wall units) and V+ the box volume. Its residual is reported too.
//!
//! Profiles: the flow node publishes statistics accumulated since the run started, so a
//! batch is the difference of two consecutive publications (sums = samples × means). The
//! second moments use ⟨v⟩ = 0 (continuity between two walls) and ⟨w⟩ = 0 (symmetry: the
//! publication does not carry the finite-time ⟨v⟩ and ⟨w⟩; what they leave is second order).
//!
//! Size (≈ 670 lines before the tests): the estimates, the report and its plots read one
//! [`FlowSeries`] and write one summary; pooling over realisations is `realisations.rs`.

use crate::plot::{line_plot, Series};
use crate::realisations::{pooled_profile_batches, pooled_scalars, Pooled};
use crate::{io_err, AnalysisError};
use fiberflow_messages::sanity::Sane;
use fiberflow_messages::{decode, FiberGroupState, FlowProfiles, FlowStatus, RunAnnouncement};
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

/// One recorded flow status with statistics (those published with Re_τ).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StatusRow {
    pub t_plus: f64,
    pub re_tau: f64,
    pub bulk_velocity: f64,
    pub pressure_gradient: f64,
    /// The fibres' total streamwise force on the fluid, wall units (0 one-way).
    pub fiber_force_x_plus: f64,
}

/// The flow side of a recording.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FlowSeries {
    pub box_plus: [f64; 3],
    pub status: Vec<StatusRow>,
    /// Cumulative statistics, by time.
    pub profiles: Vec<FlowProfiles>,
    /// Total fibre mass (wall units, ρ_f = 1) from the first state of every piece.
    pub fiber_mass_plus: f64,
    /// Whether the fibres' forces reached the fluid (a status carried them).
    pub two_way: bool,
}

impl FlowSeries {
    pub fn half_height_plus(&self) -> f64 {
        0.5 * self.box_plus[1]
    }
    pub fn volume_plus(&self) -> f64 {
        self.box_plus.iter().product()
    }
    pub fn mass_loading(&self) -> f64 {
        self.fiber_mass_plus / self.volume_plus()
    }
}

/// Reads the flow status, profiles, run box and fibre mass of a recording (run folder or
/// one `.mcap`); messages that fail their checks are skipped.
pub fn read_flow(mcap_path: &Path) -> Result<FlowSeries, AnalysisError> {
    let segs = fiberflow_messages::segments::segment_paths(mcap_path).map_err(io_err(mcap_path))?;
    let mut out = FlowSeries::default();
    let mut masses: BTreeMap<(String, u32), f64> = BTreeMap::new();
    // a flow part (scripts/flow_part.py) holds no state: its metadata carries the mass
    let mut part_mass: Option<f64> = None;
    for seg in &segs {
        // streamed a chunk at a time; a damaged tail ends the segment: analyse what is there
        fiberflow_messages::reading::for_each_message_and_metadata(
            seg,
            |m| {
                let (topic, data) = (m.topic, m.data);
                if topic.ends_with("/flow/status") {
                    let Ok(s) = decode::<FlowStatus>(data) else {
                        return;
                    };
                    if s.check().is_err() || s.re_tau <= 0.0 {
                        return;
                    }
                    out.two_way |= s.fiber_force_plus.len() == 3;
                    out.status.push(StatusRow {
                        t_plus: s.t_plus,
                        re_tau: s.re_tau,
                        bulk_velocity: s.bulk_velocity,
                        pressure_gradient: s.pressure_gradient,
                        fiber_force_x_plus: s.fiber_force_plus.first().copied().unwrap_or(0.0),
                    });
                } else if topic.ends_with("/flow/profiles") {
                    if let Ok(p) = decode::<FlowProfiles>(data) {
                        if p.check().is_ok() && p.samples > 0 {
                            out.profiles.push(p);
                        }
                    }
                } else if topic.ends_with("/control/announce") {
                    if let Ok(a) = decode::<RunAnnouncement>(data) {
                        if let [x, y, z] = a.box_plus[..] {
                            out.box_plus = [x, y, z];
                        }
                    }
                } else if topic.ends_with("/state") {
                    let Ok(s) = decode::<FiberGroupState>(data) else {
                        return;
                    };
                    if s.check().is_err() {
                        return;
                    }
                    masses
                        .entry((s.group.clone(), s.first_fiber))
                        .or_insert_with(|| state_mass(&s));
                }
            },
            |md| {
                if md.name == FLOW_PART_METADATA {
                    part_mass = md
                        .metadata
                        .get("fiber_mass_plus")
                        .and_then(|v| v.parse::<f64>().ok())
                        .filter(|m| m.is_finite() && *m >= 0.0);
                }
            },
        )
        .map_err(io_err(seg))?;
    }
    if out.box_plus[1] <= 0.0 {
        return Err(AnalysisError::Data(format!(
            "{}: no run announcement (the channel box is unknown)",
            mcap_path.display()
        )));
    }
    out.status.sort_by(|a, b| a.t_plus.total_cmp(&b.t_plus));
    out.status.dedup_by(|a, b| a.t_plus == b.t_plus);
    out.profiles.sort_by(|a, b| a.t_plus.total_cmp(&b.t_plus));
    out.profiles.dedup_by(|a, b| a.t_plus == b.t_plus);
    out.fiber_mass_plus = if masses.is_empty() {
        part_mass.unwrap_or(0.0)
    } else {
        masses.values().sum()
    };
    Ok(out)
}

/// The metadata record of a recording's flow part (`scripts/flow_part.py`: the flow status
/// and profiles without the fibres' states) that carries the fibres' total mass in wall
/// units (`fiber_mass_plus`, ρ_f = 1), as the first states would give it.
pub const FLOW_PART_METADATA: &str = "fiberflow.flow_part";

/// Mass of a state's fibres: Σ ρ_s/ρ_f · π d²/4 · l over its segments.
fn state_mass(s: &FiberGroupState) -> f64 {
    s.segments_per_fiber
        .iter()
        .enumerate()
        .map(|(i, &n)| {
            let d = s.diameter.get(i).copied().unwrap_or(0.0);
            let l = s.segment_length.get(i).copied().unwrap_or(0.0);
            let r = s.density_ratio.get(i).copied().unwrap_or(0.0);
            r * std::f64::consts::FRAC_PI_4 * d * d * l * n as f64
        })
        .sum()
}

/// Student's t, two-sided 95%, for `dof` degrees of freedom (1.96 beyond 30).
pub fn student_t95(dof: usize) -> f64 {
    const T: [f64; 30] = [
        12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160,
        2.145, 2.131, 2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056,
        2.052, 2.048, 2.045, 2.042,
    ];
    match dof {
        0 => f64::NAN,
        d if d <= 30 => T[d - 1],
        _ => 1.96,
    }
}

/// A batch-mean estimate: mean and 95% half-width over `batches`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimate {
    pub mean: f64,
    pub half_width: f64,
    pub batches: usize,
}

impl Estimate {
    /// Mean and interval of equally weighted batch values.
    pub fn of_batches(values: &[f64]) -> Self {
        let n = values.len();
        let mean = values.iter().sum::<f64>() / n as f64;
        let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n as f64 - 1.0);
        Self {
            mean,
            half_width: student_t95(n.saturating_sub(1)) * (var / n as f64).sqrt(),
            batches: n,
        }
    }

    /// The relative change `self/base − 1` and its 95% half-width (the two independent,
    /// first-order propagation).
    pub fn change_from(&self, base: &Estimate) -> (f64, f64) {
        let r = self.mean / base.mean;
        let h = ((self.half_width / base.mean).powi(2) + (r * base.half_width / base.mean).powi(2))
            .sqrt();
        (r - 1.0, h)
    }
}

/// Batch means of `x` over the samples with `t ≥ from` (contiguous batches of equal count,
/// the remainder dropped from the front); `None` with fewer than 2 samples per batch.
pub fn batch_means(t: &[f64], x: &[f64], from: f64, batches: usize) -> Option<Estimate> {
    batch_values(t, x, from, batches).map(|v| Estimate::of_batches(&v))
}

/// The batches' means behind [`batch_means`], in time order.
pub fn batch_values(t: &[f64], x: &[f64], from: f64, batches: usize) -> Option<Vec<f64>> {
    let vals: Vec<f64> = t
        .iter()
        .zip(x)
        .filter(|(t, _)| **t >= from)
        .map(|(_, x)| *x)
        .collect();
    if batches < 2 || vals.len() < 2 * batches {
        return None;
    }
    let per = vals.len() / batches;
    let start = vals.len() - per * batches;
    let means: Vec<f64> = vals[start..]
        .chunks_exact(per)
        .map(|c| c.iter().sum::<f64>() / per as f64)
        .collect();
    Some(means)
}

/// The scalar results of a run: name, estimate.
pub fn scalars(f: &FlowSeries, from: f64, batches: usize) -> Vec<(&'static str, Option<Estimate>)> {
    scalar_batches(f, from, batches)
        .into_iter()
        .map(|(n, v)| (n, v.map(|v| Estimate::of_batches(&v))))
        .collect()
}

/// The scalar results of a run as their batch means: name, batch values.
pub fn scalar_batches(
    f: &FlowSeries,
    from: f64,
    batches: usize,
) -> Vec<(&'static str, Option<Vec<f64>>)> {
    let h = f.half_height_plus();
    let v = f.volume_plus();
    let t: Vec<f64> = f.status.iter().map(|s| s.t_plus).collect();
    let col = |g: &dyn Fn(&StatusRow) -> f64| -> Vec<f64> { f.status.iter().map(g).collect() };
    let tau_w = |s: &StatusRow| (s.re_tau / h).powi(2);
    let fibers = |s: &StatusRow| -s.fiber_force_x_plus * h / v;
    let est = |x: Vec<f64>| batch_values(&t, &x, from, batches);
    vec![
        ("re_tau", est(col(&|s| s.re_tau))),
        ("bulk_velocity_plus", est(col(&|s| s.bulk_velocity))),
        (
            "skin_friction_cf",
            est(col(&|s| {
                2.0 * tau_w(s) / (s.bulk_velocity * s.bulk_velocity)
            })),
        ),
        ("pressure_gradient", est(col(&|s| s.pressure_gradient))),
        ("wall_shear", est(col(&tau_w))),
        ("fiber_force_x", est(col(&fibers))),
        (
            "budget_residual",
            est(col(&|s| s.pressure_gradient - tau_w(s) - fibers(s))),
        ),
    ]
}

/// Profile quantities per row, in [`PROFILE_NAMES`] order.
pub const PROFILE_NAMES: [&str; 6] = [
    "u_mean",
    "u_rms",
    "v_rms",
    "w_rms",
    "minus_uv",
    "fiber_stress",
];

/// The shear stress the fibres carry across the channel (wall units): what the mean
/// streamwise momentum balance of the fluid leaves once viscous and Reynolds stress are
/// counted, Π (1 − y+/h+) − dU+/dy+ − (−⟨u'v'⟩+), with Π the mean pressure gradient
/// (outer units, the total stress at the wall). Zero in an unladen channel. `y` the rows
/// (ascending, above the wall at 0 where U = 0), `u` and `minus_uv` their values; dU/dy
/// by the three-point formula on the uneven rows (exact for a quadratic), one-sided at the
/// last row.
pub fn fiber_stress(y: &[f64], u: &[f64], minus_uv: &[f64], pi: f64, h_plus: f64) -> Vec<f64> {
    let n = y.len();
    (0..n)
        .map(|j| {
            let (ym, um) = if j == 0 {
                (0.0, 0.0)
            } else {
                (y[j - 1], u[j - 1])
            };
            let (a, b, c, ua, ub, uc, at) = if j + 1 < n {
                (ym, y[j], y[j + 1], um, u[j], u[j + 1], y[j])
            } else if n >= 3 {
                (y[j - 2], y[j - 1], y[j], u[j - 2], u[j - 1], u[j], y[j])
            } else {
                return f64::NAN;
            };
            // derivative at `at` of the parabola through (a, ua), (b, ub), (c, uc)
            let dudy = ua * (2.0 * at - b - c) / ((a - b) * (a - c))
                + ub * (2.0 * at - a - c) / ((b - a) * (b - c))
                + uc * (2.0 * at - a - b) / ((c - a) * (c - b));
            pi * (1.0 - y[j] / h_plus) - dudy - minus_uv[j]
        })
        .collect()
}

/// Per-batch profiles between consecutive cumulative publications in the window
/// (`[batch][quantity][row]`), and the rows' y+. A batch's fibre stress uses the mean
/// pressure gradient of the statuses inside it (none: the window's).
pub fn profile_batches(f: &FlowSeries, from: f64) -> (Vec<f64>, Vec<[Vec<f64>; 6]>) {
    // the last publication at or before `from` opens the window (none: the run's start)
    let first = f.profiles.iter().rposition(|p| p.t_plus <= from + 1e-9);
    let snaps: Vec<Option<&FlowProfiles>> = match first {
        Some(i) => f.profiles[i..].iter().map(Some).collect(),
        None => std::iter::once(None)
            .chain(f.profiles.iter().map(Some))
            .collect(),
    };
    let y: Vec<f64> = f
        .profiles
        .last()
        .map(|p| p.y_plus.clone())
        .unwrap_or_default();
    let nrow = y.len();
    // sums of u, u², v², w², uv per row
    let sums = |p: Option<&FlowProfiles>| -> (f64, Vec<[f64; 5]>) {
        let Some(p) = p else {
            return (0.0, vec![[0.0; 5]; nrow]);
        };
        let n = p.samples as f64;
        let rows = (0..nrow)
            .map(|j| {
                let g = |v: &Vec<f64>| v.get(j).copied().unwrap_or(f64::NAN);
                let (u, ur) = (g(&p.u_mean), g(&p.u_rms));
                [
                    n * u,
                    n * (ur * ur + u * u),
                    n * g(&p.v_rms).powi(2),
                    n * g(&p.w_rms).powi(2),
                    n * g(&p.uv),
                ]
            })
            .collect();
        (n, rows)
    };
    let mut out = Vec::new();
    for w in snaps.windows(2) {
        let (n0, s0) = sums(w[0]);
        let (n1, s1) = sums(w[1]);
        let dn = n1 - n0;
        if dn <= 0.0 {
            continue;
        }
        let mut b: [Vec<f64>; 6] = Default::default();
        for j in 0..nrow {
            let d = |q: usize| (s1[j][q] - s0[j][q]) / dn;
            let u = d(0);
            b[0].push(u);
            b[1].push((d(1) - u * u).max(0.0).sqrt());
            b[2].push(d(2).max(0.0).sqrt());
            b[3].push(d(3).max(0.0).sqrt());
            b[4].push(-d(4));
        }
        let (t0, t1) = (
            w[0].map_or(f64::NEG_INFINITY, |p| p.t_plus),
            w[1].map_or(f64::NEG_INFINITY, |p| p.t_plus),
        );
        let pi = mean_pressure_gradient(f, t0, t1)
            .or_else(|| mean_pressure_gradient(f, from, f64::INFINITY))
            .unwrap_or(f64::NAN);
        b[5] = fiber_stress(&y, &b[0], &b[4], pi, f.half_height_plus());
        out.push(b);
    }
    (y, out)
}

/// Mean pressure gradient of the statuses with t+ in (t0, t1].
fn mean_pressure_gradient(f: &FlowSeries, t0: f64, t1: f64) -> Option<f64> {
    let v: Vec<f64> = f
        .status
        .iter()
        .filter(|s| s.t_plus > t0 && s.t_plus <= t1)
        .map(|s| s.pressure_gradient)
        .collect();
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

/// Mean and half-width per row of each profile quantity over the batches.
pub fn profile_estimates(batches: &[[Vec<f64>; 6]]) -> [Vec<Estimate>; 6] {
    std::array::from_fn(|q| {
        let nrow = batches.first().map_or(0, |b| b[q].len());
        (0..nrow)
            .map(|j| Estimate::of_batches(&batches.iter().map(|b| b[q][j]).collect::<Vec<_>>()))
            .collect()
    })
}

/// Writes `flow_modulation.csv`, `flow_profiles.csv`, `flow_mean_velocity.png`,
/// `flow_rms.png` and `flow_modulation.md` for `runs` (one run or realisations of it)
/// against `bases` (unladen or one-way realisations of the same flow, none for no
/// comparison) into `out`, pooled as [`crate::realisations`] says; returns the summary.
pub fn report(
    runs: &[FlowSeries],
    bases: &[FlowSeries],
    from: f64,
    batches: usize,
    out: &Path,
) -> Result<String, AnalysisError> {
    let Some(first) = runs.first() else {
        return Err(AnalysisError::Data("no run to report on".into()));
    };
    std::fs::create_dir_all(out).map_err(io_err(out))?;
    let ours = pooled_scalars(runs, from, batches);
    let theirs = (!bases.is_empty()).then(|| pooled_scalars(bases, from, batches));
    let (csv, mut md) = scalar_table(
        first,
        &ours,
        theirs.as_deref(),
        from,
        batches,
        [runs.len(), bases.len()],
    );
    std::fs::write(out.join("flow_modulation.csv"), csv)
        .map_err(io_err(&out.join("flow_modulation.csv")))?;
    if runs.len() > 1 || bases.len() > 1 {
        md.push_str(&per_realisation_table(runs, bases, from, batches));
    }

    // profiles
    let (y, ours_b) = pooled_profile_batches(runs, from)?;
    let ours_p = profile_estimates(&ours_b);
    let theirs_p = if bases.is_empty() {
        None
    } else {
        let (yb, bb) = pooled_profile_batches(bases, from)?;
        Some((yb, profile_estimates(&bb)))
    };
    let pcsv = profiles_csv(&y, &ours_p, theirs_p.as_ref());
    std::fs::write(out.join("flow_profiles.csv"), pcsv)
        .map_err(io_err(&out.join("flow_profiles.csv")))?;
    if !ours_b.is_empty() {
        profile_plots(out, &y, &ours_p, theirs_p.as_ref())?;
    }
    let _ = writeln!(
        md,
        "\nProfiles: {} batches{}{}; `flow_profiles.csv`, `flow_mean_velocity.png`, \
         `flow_rms.png`. Budget: pressure_gradient = wall_shear + fiber_force_x (outer \
         units); the residual is what the time average leaves.",
        ours_b.len(),
        if runs.len() > 1 {
            format!(
                " over {} realisations (Student's t over all their batches)",
                runs.len()
            )
        } else {
            " of this run".into()
        },
        theirs_p
            .as_ref()
            .map_or(String::new(), |_| " beside the unladen run's".into())
    );
    std::fs::write(out.join("flow_modulation.md"), &md)
        .map_err(io_err(&out.join("flow_modulation.md")))?;
    Ok(md)
}

/// Each realisation's own drag (pressure gradient) and skin friction, so the spread behind
/// the pooled figures shows.
fn per_realisation_table(
    runs: &[FlowSeries],
    bases: &[FlowSeries],
    from: f64,
    batches: usize,
) -> String {
    let mut md = String::from(
        "\nEach realisation on its own (batch means, 95%; run: the runs analysed, unladen: \
         those given with --unladen):\n\n| realisation | pressure gradient Π | C_f |\n|---|---|---|\n",
    );
    let rows = runs
        .iter()
        .map(|r| ("run", r))
        .chain(bases.iter().map(|b| ("unladen", b)));
    let mut counts = [0usize; 2];
    for (kind, f) in rows {
        let k = usize::from(kind == "unladen");
        counts[k] += 1;
        let s: BTreeMap<&str, Option<Estimate>> = scalars(f, from, batches).into_iter().collect();
        let fmt = |e: Option<&Option<Estimate>>| match e {
            Some(Some(e)) => format!("{:.5} ± {:.5}", e.mean, e.half_width),
            _ => "—".into(),
        };
        let _ = writeln!(
            md,
            "| {kind} {} | {} | {} |",
            counts[k],
            fmt(s.get("pressure_gradient")),
            fmt(s.get("skin_friction_cf"))
        );
    }
    md
}

/// The scalar rows (this run, the base run, the change) as CSV and as the summary's
/// Markdown table, which opens the summary; `counts` are the realisations of each.
fn scalar_table(
    run: &FlowSeries,
    ours: &[(&'static str, Option<Pooled>)],
    theirs: Option<&[(&'static str, Option<Pooled>)]>,
    from: f64,
    batches: usize,
    counts: [usize; 2],
) -> (String, String) {
    let fmt = |e: &Option<Estimate>| match e {
        Some(e) => format!("{:.5} ± {:.5}", e.mean, e.half_width),
        None => "—".into(),
    };
    let mut csv = String::from(
        "quantity,run,run_half_width,unladen,unladen_half_width,change,change_half_width\n",
    );
    let mut md = String::new();
    let pooled = if counts[0] > 1 || counts[1] > 1 {
        format!(
            " per run; {} realisations of this run and {} unladen, each quantity's mean over all \
             their batches with Student's t over them, or over the realisations' means where \
             those scatter beyond their batches (marked *; docs/realisations.md)",
            counts[0], counts[1]
        )
    } else {
        String::new()
    };
    let _ = writeln!(
        md,
        "# What the fibres do to the flow\n\nStatistics from t+ = {from} on, {batches} batch \
         means{pooled}, 95% intervals (Student's t). Mass loading {:.3} ({} coupling).\n",
        run.mass_loading(),
        if run.two_way { "two-way" } else { "one-way" }
    );
    let _ = writeln!(
        md,
        "| quantity | this run | unladen | change |\n|---|---|---|---|"
    );
    let mark = |e: &Option<Pooled>| {
        if matches!(e, Some((_, true))) {
            "*"
        } else {
            ""
        }
    };
    for (k, (name, eb)) in ours.iter().enumerate() {
        let e = eb.map(|e| e.0);
        let bb = theirs.and_then(|t| t[k].1);
        let b = bb.map(|b| b.0);
        let change = match (e, b) {
            (Some(e), Some(b)) if b.mean.abs() > 1e-12 => Some(e.change_from(&b)),
            _ => None,
        };
        let num = |x: Option<f64>| x.map_or(String::new(), |x| format!("{x:.6e}"));
        let _ = writeln!(
            csv,
            "{name},{},{},{},{},{},{}",
            num(e.map(|e| e.mean)),
            num(e.map(|e| e.half_width)),
            num(b.map(|b| b.mean)),
            num(b.map(|b| b.half_width)),
            num(change.map(|c| c.0)),
            num(change.map(|c| c.1)),
        );
        let _ = writeln!(
            md,
            "| {name} | {}{} | {}{} | {} |",
            fmt(&e),
            mark(eb),
            fmt(&b),
            mark(&bb),
            change.map_or("—".into(), |(c, h)| format!(
                "{:+.2}% ± {:.2}%",
                100.0 * c,
                100.0 * h
            ))
        );
    }
    if ours.iter().any(|(_, e)| e.is_none()) {
        let _ = writeln!(
            md,
            "\n—: fewer than two flow statuses with statistics per batch after t+ = {from} \
             (`flow.status_every_steps` sets how often the flow node measures them)."
        );
    }
    (csv, md)
}

/// Profile means and half-widths per y+ row, with the base run's beside them.
type BaseProfiles = (Vec<f64>, [Vec<Estimate>; 6]);

/// `flow_profiles.csv`: y+, each profile quantity and its half-width (and the base run's).
fn profiles_csv(y: &[f64], ours_p: &[Vec<Estimate>; 6], theirs_p: Option<&BaseProfiles>) -> String {
    let mut pcsv = String::from("y_plus");
    for q in PROFILE_NAMES {
        let _ = write!(pcsv, ",{q},{q}_half_width");
    }
    if theirs_p.is_some() {
        for q in PROFILE_NAMES {
            let _ = write!(pcsv, ",unladen_{q},unladen_{q}_half_width");
        }
    }
    pcsv.push('\n');
    for (j, yj) in y.iter().enumerate() {
        let _ = write!(pcsv, "{yj:.6}");
        for q in ours_p {
            let _ = write!(pcsv, ",{:.6e},{:.6e}", q[j].mean, q[j].half_width);
        }
        if let Some((_, tp)) = theirs_p {
            for q in tp {
                match q.get(j) {
                    Some(e) => {
                        let _ = write!(pcsv, ",{:.6e},{:.6e}", e.mean, e.half_width);
                    }
                    None => pcsv.push_str(",,"),
                }
            }
        }
        pcsv.push('\n');
    }
    pcsv
}

/// `flow_mean_velocity.png` and `flow_rms.png` (lines: this run; dots: the base run).
fn profile_plots(
    out: &Path,
    y: &[f64],
    ours_p: &[Vec<Estimate>; 6],
    theirs_p: Option<&BaseProfiles>,
) -> Result<(), AnalysisError> {
    let curve = |yy: &[f64], e: &[Estimate], label: &str, colour: usize, markers: bool| Series {
        label: label.into(),
        points: yy.iter().zip(e).map(|(y, e)| (*y, e.mean)).collect(),
        colour,
        markers,
    };
    let mut s = vec![curve(y, &ours_p[0], "U+ (this run)", 0, false)];
    if let Some((yb, tp)) = theirs_p {
        s.push(curve(yb, &tp[0], "U+ unladen", 7, true));
    }
    line_plot(
        &out.join("flow_mean_velocity.png"),
        "Mean velocity",
        "y+",
        "U+",
        &s,
        true,
        false,
    )?;
    let labels = ["u'", "v'", "w'", "-u'v'", "fibre stress"];
    let mut s = Vec::new();
    for q in 1..6 {
        s.push(curve(y, &ours_p[q], labels[q - 1], q - 1, false));
        if let Some((yb, tp)) = theirs_p {
            s.push(curve(yb, &tp[q], "", q - 1, true));
        }
    }
    line_plot(
        &out.join("flow_rms.png"),
        if theirs_p.is_some() {
            "RMS, Reynolds and fibre stress (lines: this run; dots: unladen)"
        } else {
            "RMS, Reynolds and fibre stress"
        },
        "y+",
        "wall units",
        &s,
        false,
        false,
    )?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Batches of a series with known batch means give that mean, and the t interval of
    /// their scatter (10 batch means 1 ± 0.1 alternating: sd 0.1054, half-width
    /// 2.262·0.1054/√10 = 0.0754); samples before the window are ignored.
    #[test]
    fn batch_means_of_a_known_series() {
        let mut t = Vec::new();
        let mut x = Vec::new();
        for k in 0..120 {
            t.push(k as f64);
            // 20 transient samples, then 10 batches of 10 with means 1.1, 0.9, ...
            x.push(if k < 20 {
                50.0
            } else if ((k - 20) / 10) % 2 == 0 {
                1.1
            } else {
                0.9
            });
        }
        let e = batch_means(&t, &x, 20.0, 10).unwrap();
        assert!((e.mean - 1.0).abs() < 1e-12, "{e:?}");
        let sd = (10.0 * 0.01 / 9.0f64).sqrt();
        assert!(
            (e.half_width - 2.262 * sd / 10f64.sqrt()).abs() < 1e-12,
            "{e:?}"
        );
        assert!(batch_means(&t, &x, 110.0, 10).is_none());
    }

    /// The change of 1.1 ± 0.011 from 1.0 ± 0.01 is +10% ± √(0.011² + 0.011²).
    #[test]
    fn relative_change_and_its_interval() {
        let a = Estimate {
            mean: 1.1,
            half_width: 0.011,
            batches: 10,
        };
        let b = Estimate {
            mean: 1.0,
            half_width: 0.01,
            batches: 10,
        };
        let (c, h) = a.change_from(&b);
        assert!((c - 0.1).abs() < 1e-12 && (h - (2.0 * 0.011f64.powi(2)).sqrt()).abs() < 1e-12);
    }

    fn profile(t_plus: f64, samples: u64, u: f64, urms: f64, v: f64, uv: f64) -> FlowProfiles {
        FlowProfiles {
            t_plus,
            samples,
            y_plus: vec![1.0],
            u_mean: vec![u],
            u_rms: vec![urms],
            v_rms: vec![v],
            w_rms: vec![v],
            uv: vec![uv],
            ..Default::default()
        }
    }

    /// Two batches put back from cumulative publications: batch 1 has u = 1 exactly (no
    /// fluctuation), batch 2 has u = 3 exactly; cumulative after both: mean 2, rms 1.
    /// The differences recover each batch: means 1 and 3, rms 0.
    #[test]
    fn batches_from_cumulative_profiles() {
        let f = FlowSeries {
            box_plus: [1.0, 2.0, 1.0],
            profiles: vec![
                profile(100.0, 10, 1.0, 0.0, 0.5, -0.2),
                profile(200.0, 20, 2.0, 1.0, 0.5, -0.3),
            ],
            ..Default::default()
        };
        let (y, b) = profile_batches(&f, 0.0);
        assert_eq!(y, vec![1.0]);
        assert_eq!(b.len(), 2);
        assert!((b[0][0][0] - 1.0).abs() < 1e-12 && b[0][1][0].abs() < 1e-6);
        assert!((b[1][0][0] - 3.0).abs() < 1e-12 && b[1][1][0].abs() < 1e-6);
        // −uv: batch 2's ⟨uv⟩ = (20·(−0.3) − 10·(−0.2))/10 = −0.4
        assert!((b[1][4][0] - 0.4).abs() < 1e-12);
        assert!((b[1][2][0] - 0.5).abs() < 1e-12);
        // from t+ = 100: only the second batch
        assert_eq!(profile_batches(&f, 100.0).1.len(), 1);
    }

    /// The stress balance on uneven rows: a laminar channel (U+ = Π(y − y²/2h), no
    /// Reynolds stress) leaves no fibre stress, and a flow whose viscous and Reynolds
    /// stress (−u'v' = a·y) fall short of Π(1 − y/h) by c(1 − y/h) gives back exactly that
    /// shortfall (both to 1e-12, the quadratic's derivative being exact).
    #[test]
    fn fiber_stress_is_what_the_momentum_balance_leaves() {
        let (h, pi) = (150.0, 1.02);
        let y: Vec<f64> = (0..40)
            .map(|j| 0.33 * (1.11f64).powi(j) + 0.2 * j as f64)
            .collect();
        let laminar: Vec<f64> = y.iter().map(|y| pi * (y - y * y / (2.0 * h))).collect();
        let s = fiber_stress(&y, &laminar, &vec![0.0; y.len()], pi, h);
        assert!(s.iter().all(|x| x.abs() < 1e-12), "{s:?}");
        let (a, c) = (0.004, 0.3);
        // dU/dy = (Π − c)(1 − y/h) − a y
        let u: Vec<f64> = y
            .iter()
            .map(|y| (pi - c) * (y - y * y / (2.0 * h)) - 0.5 * a * y * y)
            .collect();
        let uv: Vec<f64> = y.iter().map(|y| a * y).collect();
        let s = fiber_stress(&y, &u, &uv, pi, h);
        for (sj, yj) in s.iter().zip(&y) {
            assert!((sj - c * (1.0 - yj / h)).abs() < 1e-12, "{sj} at y+ {yj}");
        }
    }

    /// The budget terms of a synthetic steady laden run: Re_τ 160 on h+ = 150 (τ_w =
    /// 1.1378), fibres taking F_x+ = −0.05·V+/h+ from the fluid (f_x = 0.05), Π = τ_w + f_x:
    /// the residual is zero and the skin friction is 2τ_w/U_b².
    #[test]
    fn budget_terms_close() {
        let box_plus = [900.0, 300.0, 450.0];
        let v: f64 = box_plus.iter().product();
        let tau_w = (160.0f64 / 150.0).powi(2);
        let status = (0..100)
            .map(|k| StatusRow {
                t_plus: k as f64,
                re_tau: 160.0,
                bulk_velocity: 15.5,
                pressure_gradient: tau_w + 0.05,
                fiber_force_x_plus: -0.05 * v / 150.0,
            })
            .collect();
        let f = FlowSeries {
            box_plus,
            status,
            ..Default::default()
        };
        let s: BTreeMap<&str, Estimate> = scalars(&f, 0.0, 10)
            .into_iter()
            .map(|(n, e)| (n, e.unwrap()))
            .collect();
        assert!((s["fiber_force_x"].mean - 0.05).abs() < 1e-12);
        assert!(s["budget_residual"].mean.abs() < 1e-12);
        assert!((s["skin_friction_cf"].mean - 2.0 * tau_w / 15.5f64.powi(2)).abs() < 1e-12);
    }
}
