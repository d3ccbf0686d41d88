//! The scale benchmark's tables: each configuration against the flow alone, paired by
//! round, with where the step's time went.

use crate::scale::{median, Compare, Config, Figures};
use fiberflow_analysis::bootstrap::{self, Interval};
use std::collections::BTreeMap;

/// The step wall of each run over that of the flow-only run of the same round (the runs
/// of one round ran back to back, so the pair shares the host's load): median, min, max,
/// and the 95% bootstrap interval of the median (the rounds resampled).
pub(crate) fn paired_ratios(runs: &[Figures], flow_only: &[Figures]) -> (f64, f64, f64, Interval) {
    let r: Vec<f64> = runs
        .iter()
        .zip(flow_only)
        .map(|(a, b)| a.loop_s / b.loop_s)
        .collect();
    let ci = bootstrap::interval(r.len(), bootstrap::REPLICATES, 0x5ca1e, |w| {
        median(
            r.iter()
                .zip(w)
                .flat_map(|(&x, &k)| std::iter::repeat_n(x, k as usize))
                .collect(),
        )
    });
    let (m, lo, hi) = median_min_max(r);
    (m, lo, hi, ci)
}

/// The flow node's serial coupling work in each run — sampling, handing the samples over
/// and waiting for the states, less what the flow-only run of the same round spent in
/// those stages (its status and slices go out in the same stage) — over that run's step
/// wall: median, min, max.
pub(crate) fn paired_serial_share(runs: &[Figures], flow_only: &[Figures]) -> (f64, f64, f64) {
    let serial = |f: &Figures| f.sampling_s + f.flow_publish_s + f.waiting_s;
    let r: Vec<f64> = runs
        .iter()
        .zip(flow_only)
        .map(|(a, b)| (serial(a) - serial(b)) / b.loop_s)
        .collect();
    median_min_max(r)
}

/// The compared values side by side: for every fibre configuration and value after the
/// first, its step wall over that of the first value's run of the same round (the two ran
/// next to each other, or at once in turns): median, min, max, the 95% bootstrap interval
/// of the median, and in how many rounds it was the faster. Finer than the two rows'
/// ratios to the flow alone, whose own scatter both carry.
pub(crate) fn compared_table(
    results: &BTreeMap<(u64, String), Vec<Figures>>,
    configs: &[Config],
    compare: &Compare,
) -> String {
    use std::fmt::Write as _;
    let first = format!("{}={}", compare.key, compare.values[0]);
    let mut md = format!(
        "| fibres | transport | over {first}, round by round: median (min–max) | 95% interval of that median (bootstrap over rounds) | rounds in which it was the faster |\n|---|---|---|---|---|\n"
    );
    for c in configs.iter().filter(|c| c.fibers > 0) {
        let Some(setting) = c.setting.as_deref().filter(|s| *s != first) else {
            continue;
        };
        let Some(reference) = configs.iter().find(|r| {
            r.fibers == c.fibers
                && r.transport == c.transport
                && r.setting.as_deref() == Some(first.as_str())
        }) else {
            continue;
        };
        let (Some(runs), Some(refs)) = (
            results.get(&(c.fibers, c.label.clone())),
            results.get(&(reference.fibers, reference.label.clone())),
        ) else {
            continue;
        };
        let (m, lo, hi, ci) = paired_ratios(runs, refs);
        let faster = runs
            .iter()
            .zip(refs)
            .filter(|(a, b)| a.loop_s < b.loop_s)
            .count();
        let _ = writeln!(
            md,
            "| {} | {}, {setting} | {m:.3} ({lo:.3}–{hi:.3}) | {:.3}–{:.3} | {faster} of {} |",
            c.fibers,
            c.transport,
            ci.lo,
            ci.hi,
            runs.len().min(refs.len()),
        );
    }
    md
}

/// Median, smallest and largest of `r`.
pub(crate) fn median_min_max(r: Vec<f64>) -> (f64, f64, f64) {
    let lo = r.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = r.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    (median(r), lo, hi)
}

/// Milliseconds as the table prints a stage: two decimals below 1 ms, one below 100 ms,
/// whole above (so that the paper-size stages do not all read 0); "—" for a stage not
/// measured.
pub(crate) fn stage_ms(x: f64) -> String {
    if x.is_nan() {
        "—".into()
    } else if x < 1.0 {
        format!("{x:.2}")
    } else if x < 100.0 {
        format!("{x:.1}")
    } else {
        format!("{x:.0}")
    }
}

/// The markdown table: ms per coupling step, medians over the repeats.
/// `baselines`: each row label's flow-only label.
pub(crate) fn table(
    results: &BTreeMap<(u64, String), Vec<Figures>>,
    baselines: &BTreeMap<String, String>,
    steps: u64,
) -> String {
    use std::fmt::Write as _;
    let mut md = String::from(
        "| fibres | transport | step wall ms (min–max) | vs flow-only, run by run: median (min–max) | 95% interval of that median (bootstrap over rounds) | flow node's serial coupling (sampling + samples out + waiting, less the flow-only run's), % of the flow-only step: median (min–max) | field step | sampling | samples out | waiting for states | fibre step (per group) | states out (per group) | recording | whole process s | CPU s, whole process | nodes' CPU per step ms (cores busy) |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    let per = |v: &[Figures], f: fn(&Figures) -> f64| {
        median(v.iter().map(f).collect()) * 1e3 / steps as f64
    };
    for ((n, t), v) in results {
        let step = per(v, |f| f.loop_s);
        let lo = v.iter().map(|f| f.loop_s).fold(f64::INFINITY, f64::min) * 1e3 / steps as f64;
        let hi = v.iter().map(|f| f.loop_s).fold(0.0, f64::max) * 1e3 / steps as f64;
        let base = results.get(&(0, baselines.get(t).cloned().unwrap_or_else(|| t.clone())));
        let (r_med, r_lo, r_hi, ci) = base.map(|b| paired_ratios(v, b)).unwrap_or((
            f64::NAN,
            f64::NAN,
            f64::NAN,
            Interval::NAN,
        ));
        let (s_med, s_lo, s_hi) =
            base.map(|b| paired_serial_share(v, b))
                .unwrap_or((f64::NAN, f64::NAN, f64::NAN));
        let _ = writeln!(
            md,
            "| {n} | {t} | {step:.0} ({lo:.0}–{hi:.0}) | {r_med:.3} ({r_lo:.3}–{r_hi:.3}) | {:.3}–{:.3} | {:.1} ({:.1}–{:.1}) | {} | {} | {} | {} | {} | {} | {} | {} | {:.1} | {:.0} ({:.2}) |",
            ci.lo,
            ci.hi,
            100.0 * s_med,
            100.0 * s_lo,
            100.0 * s_hi,
            stage_ms(per(v, |f| f.field_step_s)),
            stage_ms(per(v, |f| f.sampling_s)),
            stage_ms(per(v, |f| f.flow_publish_s)),
            stage_ms(per(v, |f| f.waiting_s)),
            stage_ms(per(v, |f| f.fiber_step_s)),
            stage_ms(per(v, |f| f.group_publish_s)),
            stage_ms(per(v, |f| f.recording_s)),
            match median(v.iter().map(|f| f.process_s).collect()) {
                x if x.is_nan() => "—".to_string(),
                x => format!("{x:.1}"),
            },
            median(v.iter().map(|f| f.cpu_s).collect()),
            per(v, |f| f.nodes_cpu_s),
            median(v.iter().map(|f| f.nodes_cpu_s / f.loop_s).collect()),
        );
    }
    md
}
