//! CPU scheduling of a node process: the fibre nodes, off the DNS's critical path, may
//! run under Linux `SCHED_IDLE`, in the time the flow node leaves free.
//!
//! Why: a fibre node's step overlaps the field step. Under the default time sharing each
//! of its wake-ups preempts one of the two DNS threads in the middle of a parallel loop,
//! whose other thread then waits at the loop's end. Under `SCHED_IDLE` the fibre node
//! runs in the DNS's idle gaps (and, at the latest, while the flow node waits for the
//! states), so its work no longer stretches the field step. The recorder keeps the
//! default: under `SCHED_IDLE` it fell behind at 6 × 10⁴ fibres and its back-pressure
//! held the flow node (docs/architecture.md, "Fibre nodes in the DNS's idle time").

use anyhow::{bail, Result};

/// Puts the calling thread, and every thread it starts from now on, under `SCHED_IDLE`.
/// Call it before the node starts its threads (bus, thread pool).
pub fn run_in_idle_time() -> Result<()> {
    let param = libc::sched_param { sched_priority: 0 };
    // SAFETY: pid 0 is the calling thread; `param` is a valid sched_param for the call
    let rc = unsafe { libc::sched_setscheduler(0, libc::SCHED_IDLE, &param) };
    if rc != 0 {
        bail!(
            "could not put the node under SCHED_IDLE (run.fiber_scheduling = \"idle\"): {}; \
             set run.fiber_scheduling = \"normal\"",
            std::io::Error::last_os_error()
        );
    }
    Ok(())
}

/// True if the calling thread runs under `SCHED_IDLE`.
#[cfg(test)]
pub fn in_idle_time() -> bool {
    // SAFETY: pid 0 is the calling thread
    unsafe { libc::sched_getscheduler(0) == libc::SCHED_IDLE }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The thread that asks runs under SCHED_IDLE, and so do the threads it starts
    /// afterwards; other threads of the process keep the default policy.
    #[test]
    fn idle_time_is_inherited_by_later_threads_only() {
        let (me, child) = std::thread::spawn(|| {
            run_in_idle_time().unwrap();
            let child = std::thread::spawn(in_idle_time).join().unwrap();
            (in_idle_time(), child)
        })
        .join()
        .unwrap();
        assert!(me, "the thread that asked runs under SCHED_IDLE");
        assert!(child, "a thread it started afterwards inherits it");
        assert!(!in_idle_time(), "the test's own thread keeps the default");
    }
}
