//! The launcher's side of coupled checkpoints: completing them (a manifest once every
//! node's file is in), keeping the newest two, finding the one to resume from, and
//! finishing recording segments whose writer was killed.

use anyhow::{Context, Result};
use fiberflow_messages::checkpoints::{piece, step_of};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// The nodes whose files make a checkpoint complete.
pub fn pieces(nodes: &[String]) -> Vec<String> {
    nodes.iter().filter(|n| *n != "launcher").cloned().collect()
}

/// Checkpoint folders under `root`, oldest first.
fn step_dirs(root: &Path) -> Vec<(u64, PathBuf)> {
    let mut v: Vec<(u64, PathBuf)> = std::fs::read_dir(root)
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|e| {
            let name = e.file_name().to_string_lossy().to_string();
            step_of(&name).map(|k| (k, e.path()))
        })
        .collect();
    v.sort();
    v
}

fn is_complete(dir: &Path, pieces: &[String]) -> bool {
    pieces.iter().all(|n| piece(dir, n).is_file())
}

/// One completion at a time in this process: the launcher's background watcher and a
/// roll-back after a node died both complete checkpoints, and one pruning a folder while
/// the other writes its manifest failed the roll-back ("No such file or directory").
static COMPLETING: Mutex<()> = Mutex::new(());

/// Writes the manifest of every checkpoint whose files are all in and removes all but the
/// newest two complete ones (and unfinished ones older than those). Returns the newest
/// complete step.
pub fn complete(root: &Path, pieces: &[String], digest: &str) -> Result<Option<u64>> {
    // a panic elsewhere while holding the lock leaves nothing half-done that matters here
    let _one = COMPLETING.lock().unwrap_or_else(|e| e.into_inner());
    let dirs = step_dirs(root);
    let mut complete_steps = Vec::new();
    for (k, dir) in &dirs {
        if !is_complete(dir, pieces) {
            continue;
        }
        let manifest = dir.join("manifest.toml");
        if !manifest.exists() {
            let mut text = format!(
                "# a complete coupled checkpoint: every node's state at this step\nstep = {k}\nconfig_digest = {digest:?}\n[files]\n"
            );
            for n in pieces {
                let len = std::fs::metadata(piece(dir, n))
                    .map(|m| m.len())
                    .unwrap_or(0);
                text.push_str(&format!("{n:?} = {len}\n"));
            }
            fiberflow_messages::checkpoints::write_atomic(&manifest, text.as_bytes())
                .with_context(|| format!("writing {}", manifest.display()))?;
        }
        complete_steps.push(*k);
    }
    if complete_steps.len() > 2 {
        let keep_from = complete_steps[complete_steps.len() - 2];
        for (k, dir) in &dirs {
            if *k < keep_from {
                std::fs::remove_dir_all(dir)
                    .with_context(|| format!("removing old checkpoint {}", dir.display()))?;
            }
        }
    }
    Ok(complete_steps.last().copied())
}

/// The newest complete checkpoint (step and folder), if any; it must have been written
/// under the configuration with `digest`.
pub fn newest(root: &Path, pieces: &[String], digest: &str) -> Result<Option<(u64, PathBuf)>> {
    complete(root, pieces, digest)?;
    for (k, dir) in step_dirs(root).into_iter().rev() {
        if !is_complete(&dir, pieces) {
            continue;
        }
        let m = std::fs::read_to_string(dir.join("manifest.toml")).unwrap_or_default();
        if !m.contains(&format!("config_digest = {digest:?}")) {
            anyhow::bail!(
                "checkpoint {} was written under another configuration: resume with the same launch file and --set options",
                dir.display()
            );
        }
        return Ok(Some((k, dir)));
    }
    Ok(None)
}

/// Finishes every segment of `out_dir` whose writer was killed (no summary section): its
/// readable messages, schemas and metadata are copied into a finished file that atomically
/// replaces it. Returns the segments it finished.
pub fn finish_segments(out_dir: &Path) -> Result<Vec<PathBuf>> {
    let mut fixed = Vec::new();
    let Ok(segs) = fiberflow_messages::segments::segment_paths(out_dir) else {
        return Ok(fixed);
    };
    for seg in segs {
        // its footer is all a finished segment needs read (they reach gigabytes)
        if fiberflow_recorder::recover::is_finished(&seg)
            .with_context(|| format!("reading {}", seg.display()))?
        {
            continue;
        }
        let tmp = seg.with_extension("mcap.finishing");
        fiberflow_recorder::recover::recover(&seg, &tmp)
            .map_err(|e| anyhow::anyhow!("finishing {}: {e}", seg.display()))?;
        std::fs::File::open(&tmp)
            .and_then(|f| f.sync_all())
            .with_context(|| format!("syncing {}", tmp.display()))?;
        std::fs::rename(&tmp, &seg).with_context(|| format!("replacing {}", seg.display()))?;
        fixed.push(seg);
    }
    Ok(fixed)
}

#[cfg(test)]
mod tests {
    use super::*;
    use fiberflow_messages::checkpoints::step_dir;

    #[test]
    fn manifest_only_when_complete_and_newest_two_kept() {
        let root = std::env::temp_dir().join(format!("ff-ck-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        let pieces = vec!["flow".to_string(), "g".to_string()];
        for k in [10u64, 20, 30, 40] {
            let d = step_dir(&root, k);
            std::fs::create_dir_all(&d).unwrap();
            std::fs::write(piece(&d, "flow"), b"x").unwrap();
            if k != 40 {
                std::fs::write(piece(&d, "g"), b"y").unwrap();
            }
        }
        assert_eq!(complete(&root, &pieces, "abc").unwrap(), Some(30));
        let left: Vec<u64> = step_dirs(&root).iter().map(|(k, _)| *k).collect();
        assert_eq!(
            left,
            [20, 30, 40],
            "two complete kept, the unfinished newer one too"
        );
        assert!(!step_dir(&root, 40).join("manifest.toml").exists());
        let (k, _) = newest(&root, &pieces, "abc").unwrap().unwrap();
        assert_eq!(k, 30);
        let e = newest(&root, &pieces, "other").unwrap_err();
        assert!(format!("{e}").contains("another configuration"));
        std::fs::remove_dir_all(&root).ok();
    }

    /// Completions running at once (the launcher's watcher and a roll-back) never trip
    /// over each other: four threads complete the same 30 checkpoints together, twenty
    /// times, and each call succeeds and leaves the newest two.
    #[test]
    fn concurrent_completions_do_not_collide() {
        let root = std::env::temp_dir().join(format!("ff-ck-race-{}", std::process::id()));
        let pieces = vec!["flow".to_string(), "g".to_string()];
        for _ in 0..20 {
            let _ = std::fs::remove_dir_all(&root);
            for k in 1..=30u64 {
                let d = step_dir(&root, 10 * k);
                std::fs::create_dir_all(&d).unwrap();
                for n in &pieces {
                    std::fs::write(piece(&d, n), b"x").unwrap();
                }
            }
            let start = std::sync::Barrier::new(4);
            std::thread::scope(|s| {
                let calls: Vec<_> = (0..4)
                    .map(|_| {
                        s.spawn(|| {
                            start.wait();
                            complete(&root, &pieces, "abc")
                        })
                    })
                    .collect();
                for c in calls {
                    assert_eq!(c.join().unwrap().unwrap(), Some(300));
                }
            });
            let left: Vec<u64> = step_dirs(&root).iter().map(|(k, _)| *k).collect();
            assert_eq!(left, [290, 300]);
        }
        std::fs::remove_dir_all(&root).ok();
    }
}
