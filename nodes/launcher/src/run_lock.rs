//! One live iceoryx2 run per run id on a host. Over iceoryx2 a run's topics are services
//! of the host, found by name (`fiberflow/<run id>/…`): a second run with the same id
//! would read the first one's states and samples (two such runs at once in the scale
//! benchmark did: "state of step 2 while serving step 1", and one stalled). A launch
//! therefore holds a lock named for its run id while it runs; a second launch with that
//! id waits for it, saying so, as `cargo` waits for a build directory. The operating
//! system drops the lock when the holder exits, however it exits. A run folder has a lock
//! of its own ([`FolderLock`]), for every transport.

use anyhow::{bail, Context, Result};
use std::fs::File;
use std::os::fd::AsRawFd;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

/// Held while a run is live; dropping it (or exiting) releases the run id.
#[derive(Debug)]
pub struct RunLock {
    _file: File,
}

/// Where the locks live: beside iceoryx2's own files, in the temporary directory.
pub fn default_dir() -> PathBuf {
    std::env::temp_dir().join("fiberflow").join("runs")
}

/// Tries once to take the lock on `file`: true if taken, false if another holds it.
fn try_lock(file: &File) -> std::io::Result<bool> {
    // SAFETY: flock on a descriptor this process owns; it changes no memory
    let rc = unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) };
    if rc == 0 {
        return Ok(true);
    }
    let e = std::io::Error::last_os_error();
    if e.raw_os_error() == Some(libc::EWOULDBLOCK) {
        Ok(false)
    } else {
        Err(e)
    }
}

impl RunLock {
    /// Takes the lock of `run_id` in `dir`; if another process holds it, calls `waiting`
    /// once and polls until it is free, or until `stop` is set (then an error).
    pub fn acquire_in(
        dir: &Path,
        run_id: &str,
        stop: &AtomicBool,
        waiting: impl FnOnce(),
    ) -> Result<Self> {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        let path = dir.join(format!("{run_id}.lock"));
        let file = std::fs::OpenOptions::new()
            .create(true)
            .truncate(false)
            .write(true)
            .open(&path)
            .with_context(|| format!("opening {}", path.display()))?;
        let locked = |f: &File| try_lock(f).with_context(|| format!("locking {}", path.display()));
        if !locked(&file)? {
            waiting();
            while !locked(&file)? {
                if stop.load(Ordering::SeqCst) {
                    bail!("stopped while waiting for the run id {run_id:?} to be free");
                }
                std::thread::sleep(Duration::from_millis(100));
            }
        }
        Ok(Self { _file: file })
    }
}

/// The run folder's lock file (hidden; it holds the launcher's process id).
pub const FOLDER_LOCK: &str = ".fiberflow.lock";

/// Held by the launcher for as long as it works in a run folder: a second launcher with the
/// same `--out`, or a `--resume` of a run that is still live, is refused before it touches
/// anything there (either would overwrite or prune what the live run is writing).
#[derive(Debug)]
pub struct FolderLock {
    _file: File,
}

/// How long a launcher waits for a folder lock whose holder is exiting (killed, its files
/// not yet closed by the kernel) or gone.
pub const DYING_HOLDER_WAIT: Duration = Duration::from_secs(10);

/// Whether process `pid` (as the lock file gives it) is gone or on its way out: no such
/// process, a zombie, or one whose command line is already empty (the kernel releases a
/// killed process's memory before its files, and its locks with them).
fn dying(pid: &str) -> bool {
    let Ok(stat) = std::fs::read_to_string(format!("/proc/{pid}/stat")) else {
        return true;
    };
    let state = stat
        .rsplit(')')
        .next()
        .and_then(|s| s.split_whitespace().next());
    let cmdline_empty =
        std::fs::read(format!("/proc/{pid}/cmdline")).map_or(true, |c| c.is_empty());
    matches!(state, Some("Z" | "X" | "x")) || cmdline_empty
}

impl FolderLock {
    /// Takes the lock of `dir` (which must exist) at once, or fails naming the live
    /// process that holds it. A holder that is exiting (a launcher just killed) is waited
    /// for, up to [`DYING_HOLDER_WAIT`].
    pub fn acquire(dir: &Path) -> Result<Self> {
        Self::acquire_waiting(dir, DYING_HOLDER_WAIT)
    }

    fn acquire_waiting(dir: &Path, dying_wait: Duration) -> Result<Self> {
        use std::io::{Read, Seek, Write};
        let path = dir.join(FOLDER_LOCK);
        let mut file = std::fs::OpenOptions::new()
            .create(true)
            .truncate(false)
            .read(true)
            .write(true)
            .open(&path)
            .with_context(|| format!("opening {}", path.display()))?;
        let locked = |f: &File| try_lock(f).with_context(|| format!("locking {}", path.display()));
        let mut taken = locked(&file)?;
        let mut holder = String::new();
        if !taken {
            let _ = file.read_to_string(&mut holder);
            if dying(holder.trim()) {
                let t0 = std::time::Instant::now();
                while !taken && t0.elapsed() < dying_wait {
                    std::thread::sleep(Duration::from_millis(50));
                    taken = locked(&file)?;
                }
            }
        }
        if !taken {
            let pid = holder.trim();
            let what = std::fs::read(format!("/proc/{pid}/cmdline"))
                .map(|c| {
                    String::from_utf8_lossy(&c)
                        .replace('\0', " ")
                        .trim()
                        .to_string()
                })
                .unwrap_or_default();
            bail!(
                "{} is in use by a live run: process {pid} ({what}) holds {}; wait for it to end \
                 (or stop it: kill {pid}) before launching or resuming in this folder",
                dir.display(),
                path.display()
            );
        }
        // ours now: say who holds it
        file.set_len(0)?;
        file.rewind()?;
        write!(file, "{}", std::process::id())?;
        file.flush()?;
        Ok(Self { _file: file })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    /// A second taker of a run folder is refused at once with the holder's process id;
    /// once the holder lets go the folder is free again.
    #[test]
    fn a_live_run_folder_is_refused_naming_its_process() {
        let dir = std::env::temp_dir().join(format!("ff-folder-lock-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let held = FolderLock::acquire(&dir).unwrap();
        let pid = std::process::id().to_string();
        assert_eq!(std::fs::read_to_string(dir.join(FOLDER_LOCK)).unwrap(), pid);
        let e = format!("{:#}", FolderLock::acquire(&dir).unwrap_err());
        assert!(
            e.contains("in use by a live run") && e.contains(&format!("process {pid}")),
            "{e}"
        );
        drop(held);
        let again = FolderLock::acquire(&dir).unwrap();
        drop(again);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A holder that is on its way out (here: the lock file names a zombie, as it names a
    /// launcher just killed whose files the kernel has not closed yet) is waited for, and
    /// the folder taken once it lets go; a live holder is refused at once.
    #[test]
    fn a_dying_holder_is_waited_for_and_a_live_one_refused() {
        let dir = std::env::temp_dir().join(format!("ff-folder-dying-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut zombie = std::process::Command::new("true").spawn().unwrap();
        let zpid = zombie.id();
        // not waited for yet: a zombie
        let zombie_state = || {
            std::fs::read_to_string(format!("/proc/{zpid}/stat")).is_ok_and(|s| {
                s.rsplit(')')
                    .next()
                    .is_some_and(|r| r.trim_start().starts_with('Z'))
            })
        };
        let t0 = std::time::Instant::now();
        while !zombie_state() {
            assert!(
                t0.elapsed() < Duration::from_secs(5),
                "the child never exited"
            );
            std::thread::sleep(Duration::from_millis(10));
        }
        assert!(
            !dying(&std::process::id().to_string()),
            "this process is alive"
        );
        let held = FolderLock::acquire(&dir).unwrap();
        std::fs::write(dir.join(FOLDER_LOCK), zpid.to_string()).unwrap();
        let letting_go = std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(300));
            drop(held);
        });
        let t0 = std::time::Instant::now();
        let taken = FolderLock::acquire_waiting(&dir, Duration::from_secs(10));
        assert!(taken.is_ok(), "{taken:?}");
        assert!(
            t0.elapsed() >= Duration::from_millis(250),
            "it waited for the holder"
        );
        letting_go.join().unwrap();
        drop(taken);
        // a live holder: refused without waiting
        let held = FolderLock::acquire(&dir).unwrap();
        let t0 = std::time::Instant::now();
        assert!(FolderLock::acquire_waiting(&dir, Duration::from_secs(10)).is_err());
        assert!(t0.elapsed() < Duration::from_secs(2));
        drop(held);
        zombie.wait().unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A second taker of the same id waits (and says so) until the first lets go; another
    /// id is not held up; a stop ends the wait with an error.
    #[test]
    fn a_second_run_with_the_same_id_waits_for_the_first() {
        let dir = std::env::temp_dir().join(format!("ff-run-lock-{}", std::process::id()));
        let no_stop = AtomicBool::new(false);
        let first = RunLock::acquire_in(&dir, "quick", &no_stop, || panic!("free")).unwrap();
        // another id: at once
        let other = RunLock::acquire_in(&dir, "paper", &no_stop, || panic!("free")).unwrap();
        // the same id from another thread: it waits until `first` is dropped
        let (said_tx, said_rx) = std::sync::mpsc::channel();
        let d = dir.clone();
        let second = std::thread::spawn(move || {
            let stop = AtomicBool::new(false);
            RunLock::acquire_in(&d, "quick", &stop, move || said_tx.send(()).unwrap()).map(|_| ())
        });
        said_rx
            .recv_timeout(Duration::from_secs(10))
            .expect("the second taker says it waits");
        std::thread::sleep(Duration::from_millis(300));
        assert!(
            !second.is_finished(),
            "it waits while the first holds the id"
        );
        drop(first);
        second.join().unwrap().unwrap();
        assert!(dir.join("quick.lock").exists());
        // a stop while waiting: an error naming the run id
        let held = RunLock::acquire_in(&dir, "paper2", &no_stop, || {}).unwrap();
        let stop = Arc::new(AtomicBool::new(false));
        let s = stop.clone();
        let d = dir.clone();
        let waiter =
            std::thread::spawn(move || RunLock::acquire_in(&d, "paper2", &s, || {}).map(|_| ()));
        std::thread::sleep(Duration::from_millis(200));
        stop.store(true, Ordering::SeqCst);
        let e = waiter.join().unwrap().unwrap_err().to_string();
        assert!(e.contains("paper2"), "{e}");
        drop((held, other));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
