//! A recording is one run folder holding one or more MCAP segment files: `run.mcap`, then
//! `run-1.mcap`, `run-2.mcap`, … written after each resume or restart. Together they hold
//! every step exactly once; readers treat them as one recording, in this order.

use std::path::{Path, PathBuf};

/// File name of segment `index` (0 → `run.mcap`, n → `run-n.mcap`).
pub fn segment_name(index: u32) -> String {
    if index == 0 {
        "run.mcap".to_string()
    } else {
        format!("run-{index}.mcap")
    }
}

/// Segment index of a file name (`run.mcap` → 0, `run-3.mcap` → 3), if it is one.
pub fn segment_index(name: &str) -> Option<u32> {
    if name == "run.mcap" {
        return Some(0);
    }
    let n = name.strip_prefix("run-")?.strip_suffix(".mcap")?;
    if n.is_empty() || !n.bytes().all(|b| b.is_ascii_digit()) || n.starts_with('0') {
        return None;
    }
    n.parse().ok()
}

/// The segment files of a recording in order. `path` is a run folder (every segment in
/// it) or a single `.mcap` file (just that file).
pub fn segment_paths(path: &Path) -> std::io::Result<Vec<PathBuf>> {
    if !path.is_dir() {
        return Ok(vec![path.to_path_buf()]);
    }
    let mut found: Vec<(u32, PathBuf)> = Vec::new();
    for e in std::fs::read_dir(path)? {
        let e = e?;
        let name = e.file_name().to_string_lossy().to_string();
        if let Some(i) = segment_index(&name) {
            found.push((i, e.path()));
        }
    }
    found.sort();
    if found.is_empty() {
        return Err(std::io::Error::new(
            std::io::ErrorKind::NotFound,
            format!("{} holds no recording (run.mcap)", path.display()),
        ));
    }
    Ok(found.into_iter().map(|(_, p)| p).collect())
}

/// The index the next segment of a run folder gets (0 if it has none).
pub fn next_segment_index(dir: &Path) -> u32 {
    segment_paths(dir)
        .ok()
        .filter(|v| dir.is_dir() && !v.is_empty())
        .and_then(|v| {
            v.last()
                .and_then(|p| p.file_name())
                .and_then(|n| segment_index(&n.to_string_lossy()))
        })
        .map(|i| i + 1)
        .unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_order_numerically() {
        assert_eq!(segment_index(&segment_name(0)), Some(0));
        assert_eq!(segment_index(&segment_name(12)), Some(12));
        for bad in [
            "run-.mcap",
            "run-01.mcap",
            "run-x.mcap",
            "other.mcap",
            "run.mcap.tmp",
        ] {
            assert_eq!(segment_index(bad), None, "{bad}");
        }
        let d = std::env::temp_dir().join(format!("ff-seg-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        assert_eq!(next_segment_index(&d), 0);
        for n in [
            "run.mcap",
            "run-10.mcap",
            "run-2.mcap",
            "run.recovered.mcap",
        ] {
            std::fs::write(d.join(n), b"x").unwrap();
        }
        let names: Vec<String> = segment_paths(&d)
            .unwrap()
            .iter()
            .map(|p| p.file_name().unwrap().to_string_lossy().to_string())
            .collect();
        assert_eq!(names, ["run.mcap", "run-2.mcap", "run-10.mcap"]);
        assert_eq!(next_segment_index(&d), 11);
        std::fs::remove_dir_all(&d).ok();
    }
}
