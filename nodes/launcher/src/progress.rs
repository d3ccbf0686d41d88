//! Progress bars (indicatif) for long work.

use indicatif::{ProgressBar, ProgressStyle};

/// A bar over viscous time t+ with ETA.
pub fn t_plus_bar(total_plus: f64) -> ProgressBar {
    let pb = ProgressBar::new((total_plus * 100.0).round() as u64);
    let style = ProgressStyle::with_template(
        "{spinner} [{elapsed_precise}] {bar:40.cyan/blue} t+ {msg} ETA {eta}",
    )
    .unwrap_or_else(|_| ProgressStyle::default_bar())
    .progress_chars("=> ");
    pb.set_style(style);
    pb
}

/// A bar over a count of `what` (runs, files) with ETA.
pub fn bar(total: u64, what: &str) -> ProgressBar {
    let pb = ProgressBar::new(total);
    let style = ProgressStyle::with_template(&format!(
        "{{spinner}} [{{elapsed_precise}}] {{bar:40.cyan/blue}} {{pos}}/{{len}} {what} {{msg}} ETA {{eta}}"
    ))
    .unwrap_or_else(|_| ProgressStyle::default_bar())
    .progress_chars("=> ");
    pb.set_style(style);
    pb
}
