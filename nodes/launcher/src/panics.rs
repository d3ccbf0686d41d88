//! A panic ends the node at once: the process exits with status 101 (Rust's panic status)
//! the moment any of its threads panics, so the launcher sees a dead node and applies
//! `[run.restart]` at once, rather than the process living on (its other threads waiting
//! for the dead one) until its peers' step timeout notices.
//! Nodes run as threads of one process report a panic as that node's failure, at once.

use anyhow::{anyhow, Result};
use std::panic::{catch_unwind, AssertUnwindSafe};

/// The exit status of a node process that panicked.
pub const PANIC_STATUS: i32 = 101;

/// Makes any panic, on any thread of this process, end the process with
/// [`PANIC_STATUS`] after the usual message (thread name, payload, location) is printed.
/// For node processes only: a process that hosts other work (tests, the launcher) keeps
/// Rust's default of unwinding the one thread.
pub fn end_process_on_panic() {
    let previous = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        previous(info);
        let thread = std::thread::current();
        tracing::error!(
            thread = thread.name().unwrap_or("unnamed"),
            "a thread panicked: the node ends now (status {PANIC_STATUS})"
        );
        // `_exit`, not `exit`: no atexit handlers or destructors of other threads' data,
        // which a panic may have left locked; the recorder's file survives a kill -9 too
        // SAFETY: ends the process; nothing after it runs
        unsafe { libc::_exit(PANIC_STATUS) }
    }));
}

/// The message a panic carried.
pub fn payload_text(payload: &(dyn std::any::Any + Send)) -> String {
    if let Some(s) = payload.downcast_ref::<&str>() {
        (*s).to_string()
    } else if let Some(s) = payload.downcast_ref::<String>() {
        s.clone()
    } else {
        "(no message)".to_string()
    }
}

/// Runs `task`, turning a panic into an error that names `what`.
pub fn catching<T>(what: &str, task: impl FnOnce() -> Result<T>) -> Result<T> {
    match catch_unwind(AssertUnwindSafe(task)) {
        Ok(r) => r,
        Err(p) => Err(anyhow!("{what} panicked: {}", payload_text(&*p))),
    }
}

/// A named piece of work for [`first_failure`].
pub type Task = (String, Box<dyn FnOnce() -> Result<()> + Send>);

/// Runs every task on a thread of its own (named `node-<name>`) and returns as soon as
/// one fails or panics, with that error (the others keep running: the caller ends the
/// process, as the launcher stops the processes of a failed run); `Ok` once all succeed.
pub fn first_failure(tasks: Vec<Task>) -> Result<()> {
    let (done_tx, done_rx) = std::sync::mpsc::channel();
    let n = tasks.len();
    for (name, task) in tasks {
        let done = done_tx.clone();
        let what = format!("node {name}");
        std::thread::Builder::new()
            .name(format!("node-{name}"))
            .spawn(move || {
                let _ = done.send(catching(&what, task));
            })
            .map_err(|e| anyhow!("starting node {name}: {e}"))?;
    }
    drop(done_tx);
    for _ in 0..n {
        match done_rx.recv() {
            Ok(Ok(())) => {}
            Ok(Err(e)) => return Err(e),
            Err(_) => return Err(anyhow!("a node thread ended without a result")),
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::Arc;
    use std::time::Duration;

    /// A panicking node thread is reported at once, while its sibling still runs
    /// (before, the sibling had to end first: a run waited out its step timeout).
    #[test]
    fn a_panic_is_the_first_failure_while_the_others_still_run() {
        let (release_tx, release_rx) = std::sync::mpsc::channel::<()>();
        let sibling_ended = Arc::new(AtomicBool::new(false));
        let ended = sibling_ended.clone();
        let tasks: Vec<Task> = vec![
            (
                "waits".into(),
                Box::new(move || {
                    // a peer waiting for the dead node's message (bounded for the test)
                    let _ = release_rx.recv_timeout(Duration::from_secs(60));
                    ended.store(true, Ordering::SeqCst);
                    Ok(())
                }),
            ),
            ("breaks".into(), Box::new(|| panic!("index out of bounds"))),
        ];
        let err = first_failure(tasks).unwrap_err();
        assert!(
            !sibling_ended.load(Ordering::SeqCst),
            "the failure was reported only after the sibling ended"
        );
        let msg = format!("{err:#}");
        assert!(
            msg.contains("node breaks panicked: index out of bounds"),
            "{msg}"
        );
        release_tx.send(()).unwrap();
    }

    #[test]
    fn errors_and_successes_pass_through() {
        assert!(first_failure(vec![("a".into(), Box::new(|| Ok(())))]).is_ok());
        let err = first_failure(vec![("a".into(), Box::new(|| Err(anyhow!("no field"))))]);
        assert_eq!(format!("{:#}", err.unwrap_err()), "no field");
        assert_eq!(catching("x", || Ok(3)).unwrap(), 3);
    }

    const CHILD: &str = "FIBERFLOW_TEST_PANIC_CHILD";

    /// In a node process a panic on any thread ends the process with status 101, though
    /// its main thread would go on (this test binary run again as a child: its main
    /// thread sleeps and would exit 0).
    #[test]
    fn a_panic_on_any_thread_ends_a_node_process() {
        if std::env::var_os(CHILD).is_some() {
            end_process_on_panic();
            std::thread::spawn(|| panic!("a worker thread fails"));
            std::thread::sleep(Duration::from_secs(20));
            return;
        }
        let exe = std::env::current_exe().unwrap();
        let out = std::process::Command::new(exe)
            .args([
                "--exact",
                "panics::tests::a_panic_on_any_thread_ends_a_node_process",
                "--nocapture",
                "--test-threads=1",
            ])
            .env(CHILD, "1")
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(PANIC_STATUS), "{stderr}");
        assert!(stderr.contains("a worker thread fails"), "{stderr}");
    }
}
