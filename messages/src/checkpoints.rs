//! Where a run's coupled checkpoints live: `<out>/checkpoints/step-<k>/`, one file per node
//! (`flow.ckpt`, `<group>.ckpt`, `recorder.ckpt`) and a `manifest.toml` once all are in.
//! Shared by the nodes that write them and the launcher that completes and resumes them.

use std::path::{Path, PathBuf};

/// The checkpoints folder of a run's output folder.
pub fn root(out_dir: &Path) -> PathBuf {
    out_dir.join("checkpoints")
}

/// The folder of the checkpoint at coupling step `step`.
pub fn step_dir(root: &Path, step: u64) -> PathBuf {
    root.join(format!("step-{step:09}"))
}

/// The step of a checkpoint folder name (`step-000000120` → 120).
pub fn step_of(name: &str) -> Option<u64> {
    let d = name.strip_prefix("step-")?;
    if d.len() != 9 || !d.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    d.parse().ok()
}

/// The file a node writes into a checkpoint folder.
pub fn piece(step_dir: &Path, node: &str) -> PathBuf {
    step_dir.join(format!("{node}.ckpt"))
}

/// The piece of a checkpoint that stands for the nodes on other hosts (multi-host runs):
/// the flow node writes it into its own folder once every fibre node there has sent its
/// state of the step after, which each sends only after its own file of this step is on
/// its disk, and a recorder there has said its segment is on disk through the step
/// ([`crate::Lifecycle::Committed`]). With it, the head's checkpoint is complete for the
/// whole run.
pub const REMOTE_PIECE: &str = "remote";

/// Is `k` a checkpoint step of a run of `steps` steps checkpointing every `every` steps
/// (0 = never)? The first and last steps are not: the start is the launch file's own
/// state and the end is the finished run.
pub fn is_checkpoint_step(k: u64, every: u64, steps: u64) -> bool {
    every > 0 && k > 0 && k < steps && k.is_multiple_of(every)
}

/// Writes `bytes` to `path` so that a crash leaves the old file or the new one, never a
/// part: a temp file beside it, fsync, rename, fsync of the folder.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    use std::io::Write;
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = PathBuf::from(tmp);
    {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
    }
    std::fs::rename(&tmp, path)?;
    if let Some(dir) = path.parent() {
        if let Ok(d) = std::fs::File::open(dir) {
            let _ = d.sync_all();
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_and_schedule() {
        let r = root(Path::new("/tmp/x"));
        let d = step_dir(&r, 120);
        assert_eq!(d, Path::new("/tmp/x/checkpoints/step-000000120"));
        assert_eq!(step_of("step-000000120"), Some(120));
        assert_eq!(step_of("step-12"), None);
        assert_eq!(piece(&d, "case1"), d.join("case1.ckpt"));
        let ks: Vec<u64> = (0..=100)
            .filter(|&k| is_checkpoint_step(k, 40, 100))
            .collect();
        assert_eq!(ks, [40, 80]);
        assert!(!is_checkpoint_step(100, 50, 100));
        assert!(!is_checkpoint_step(10, 0, 100));
    }

    #[test]
    fn atomic_write_replaces_whole_and_leaves_no_temp() {
        let d = std::env::temp_dir().join(format!("ff-atomic-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        let p = d.join("x.ckpt");
        write_atomic(&p, b"old").unwrap();
        write_atomic(&p, b"new contents").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"new contents");
        assert!(!d.join("x.ckpt.tmp").exists());
        std::fs::remove_dir_all(&d).ok();
    }
}
