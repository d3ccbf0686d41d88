//! What a node's process has used, for the nodes' end-of-run timing lines: on a machine
//! whose cores are shared by every node of a run, the wall of a stage says little about
//! its cost without the CPU time the processes spent.

/// User + system CPU seconds this process (all its threads) has used so far; NaN if the
/// system does not say.
pub fn process_cpu_s() -> f64 {
    cpu_s(libc::RUSAGE_SELF)
}

/// User + system CPU seconds of this process's children (and theirs) that have been
/// waited for; NaN if the system does not say.
pub fn children_cpu_s() -> f64 {
    cpu_s(libc::RUSAGE_CHILDREN)
}

/// CPU seconds of each of this process's live threads, summed by thread name (the main
/// thread as `main`), from the scheduler's nanosecond account
/// (`/proc/self/task/*/schedstat`); empty where the system does not say. What a stage's
/// wall cannot show on shared cores: which thread the time went to.
pub fn threads_cpu_s() -> std::collections::BTreeMap<String, f64> {
    let mut by_name = std::collections::BTreeMap::new();
    let me = std::process::id().to_string();
    let Ok(tasks) = std::fs::read_dir("/proc/self/task") else {
        return by_name;
    };
    for t in tasks.flatten() {
        let dir = t.path();
        let Ok(sched) = std::fs::read_to_string(dir.join("schedstat")) else {
            continue;
        };
        let Some(ns) = sched
            .split_whitespace()
            .next()
            .and_then(|x| x.parse::<u64>().ok())
        else {
            continue;
        };
        let name = if t.file_name().to_string_lossy() == me {
            "main".to_string()
        } else {
            std::fs::read_to_string(dir.join("comm"))
                .map(|c| c.trim().to_string())
                .unwrap_or_else(|_| "?".into())
        };
        *by_name.entry(name).or_insert(0.0) += ns as f64 * 1e-9;
    }
    by_name
}

/// [`threads_cpu_s`] less an earlier reading, as `name=seconds` pairs (3 decimals) for a
/// log line; threads that used under a millisecond are left out.
pub fn threads_cpu_since(before: &std::collections::BTreeMap<String, f64>) -> String {
    threads_cpu_s()
        .into_iter()
        .map(|(n, s)| (s - before.get(&n).copied().unwrap_or(0.0), n))
        .filter(|(s, _)| *s >= 1e-3)
        .map(|(s, n)| format!("{n}={s:.3}"))
        .collect::<Vec<_>>()
        .join(" ")
}

fn cpu_s(who: libc::c_int) -> f64 {
    // SAFETY: getrusage only writes the struct it is given
    let mut u: libc::rusage = unsafe { std::mem::zeroed() };
    if unsafe { libc::getrusage(who, &mut u) } != 0 {
        return f64::NAN;
    }
    let s = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    s(u.ru_utime) + s(u.ru_stime)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Busy work (here on two threads) shows in the process's CPU time.
    #[test]
    fn busy_threads_count() {
        let before = process_cpu_s();
        let spin = || {
            let t0 = std::time::Instant::now();
            let mut x = 0u64;
            while t0.elapsed() < std::time::Duration::from_millis(60) {
                x = std::hint::black_box(x.wrapping_mul(31).wrapping_add(7));
            }
            x
        };
        let h = std::thread::spawn(spin);
        spin();
        h.join().unwrap();
        let used = process_cpu_s() - before;
        assert!(used > 0.0, "no CPU time counted: {used}");
    }

    /// A named thread's busy work shows under its name: a thread that has used 20 ms of
    /// CPU by its own clock reads at least that.
    #[test]
    fn busy_threads_count_by_name() {
        let before = threads_cpu_s();
        let h = std::thread::Builder::new()
            .name("usage-spin".into())
            .spawn(move || {
                let own_cpu_s = || {
                    // SAFETY: clock_gettime writes only the timespec it is given
                    let mut t: libc::timespec = unsafe { std::mem::zeroed() };
                    unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut t) };
                    t.tv_sec as f64 + t.tv_nsec as f64 * 1e-9
                };
                let mut x = 0u64;
                while own_cpu_s() < 0.02 {
                    x = std::hint::black_box(x.wrapping_mul(31).wrapping_add(7));
                }
                // still alive: its time is read before it exits
                let line = threads_cpu_since(&before);
                (x, line)
            })
            .unwrap();
        let (_, line) = h.join().unwrap();
        let spun: f64 = line
            .split_whitespace()
            .find_map(|kv| kv.strip_prefix("usage-spin="))
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| panic!("no usage-spin thread in {line:?}"));
        // the scheduler's account and the thread's clock are the same time, printed to
        // a millisecond
        assert!(spun >= 0.019, "{line}");
    }

    /// A child's CPU time shows in the children's usage once it has been waited for.
    #[test]
    fn waited_children_count() {
        let before = children_cpu_s();
        let st = std::process::Command::new("sh")
            .arg("-c")
            .arg("i=0; while [ $i -lt 300000 ]; do i=$((i+1)); done")
            .status()
            .expect("sh runs");
        assert!(st.success());
        let used = children_cpu_s() - before;
        assert!(used > 0.0, "no CPU time counted: {used}");
    }
}
