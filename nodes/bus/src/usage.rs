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
