//! The flow node's share of a coupled checkpoint (docs/architecture.md): the DNS field at the
//! checkpoint step in the solver's own format (`flow.ckpt`), plus `flow-extra.bin` with
//! what the solver's checkpoint does not hold but the run reads on (the running statistics
//! published as FlowProfiles, the last divergence check), and in two-way runs
//! `self-induced.bin` with the self-induced correction's memories per piece. An analytic
//! flow has no state: its `flow.ckpt` only names the step.

use crate::error::{io_err, FlowError};
use crate::self_induced::History;
use fiberflow_dns::stats::RunningStats;
use fiberflow_dns::Solver;
use fiberflow_messages::checkpoints::piece;
use std::collections::BTreeMap;
use std::path::Path;

const ANALYTIC_MAGIC: &[u8; 8] = b"FFANALYT";
/// Version 2: per mode also the mean square offsets (`self_induced::PER_FIBER`).
const HISTORY_MAGIC: &[u8; 8] = b"FFSELF02";
const HISTORY_MAGIC_V1: &[u8; 8] = b"FFSELF01";
const HISTORY_FILE: &str = "self-induced.bin";

/// The self-induced correction's memories of every piece, by (group, first fibre).
pub type Histories = BTreeMap<(String, u32), History>;

fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), FlowError> {
    fiberflow_messages::checkpoints::write_atomic(path, bytes).map_err(io_err(path))
}

/// Writes the DNS share into `dir` (the extra file first: `flow.ckpt` marks completion).
pub fn write_dns(
    dir: &Path,
    solver: &Solver,
    stats: Option<&RunningStats>,
    histories: &Histories,
) -> Result<(), FlowError> {
    std::fs::create_dir_all(dir).map_err(io_err(dir))?;
    if !histories.is_empty() {
        write_atomic(&dir.join(HISTORY_FILE), &histories_to_bytes(histories))?;
    }
    let mut extra = Vec::new();
    extra.extend_from_slice(&solver.last_divergence().to_le_bytes());
    if let Some(s) = stats {
        extra.extend_from_slice(&s.to_bytes());
    }
    write_atomic(&dir.join("flow-extra.bin"), &extra)?;
    solver.write_checkpoint(&piece(dir, "flow"))?;
    sync_dir(dir);
    Ok(())
}

/// Restores the DNS share from `dir`; returns the running statistics if there were any.
pub fn read_dns(dir: &Path, solver: &mut Solver) -> Result<Option<RunningStats>, FlowError> {
    solver.read_checkpoint(&piece(dir, "flow"))?;
    let p = dir.join("flow-extra.bin");
    let b = std::fs::read(&p).map_err(io_err(&p))?;
    let bad = |reason: &str| FlowError::Protocol(format!("{}: {reason}", p.display()));
    let d: [u8; 8] = b
        .get(..8)
        .and_then(|x| x.try_into().ok())
        .ok_or_else(|| bad("too short"))?;
    solver.set_last_divergence(f64::from_le_bytes(d));
    if b.len() == 8 {
        return Ok(None);
    }
    RunningStats::from_bytes(&solver.grid, &b[8..])
        .map(Some)
        .ok_or_else(|| bad("running statistics do not fit the grid"))
}

/// Magic, entry count, then per entry: group name (u32 length, bytes), first fibre (u32),
/// value count (u64), values (f64); all little-endian.
fn histories_to_bytes(h: &Histories) -> Vec<u8> {
    let mut b = HISTORY_MAGIC.to_vec();
    b.extend_from_slice(&(h.len() as u64).to_le_bytes());
    for ((group, first), hist) in h {
        b.extend_from_slice(&(group.len() as u32).to_le_bytes());
        b.extend_from_slice(group.as_bytes());
        b.extend_from_slice(&first.to_le_bytes());
        b.extend_from_slice(&(hist.memory.len() as u64).to_le_bytes());
        for x in &hist.memory {
            b.extend_from_slice(&x.to_le_bytes());
        }
    }
    b
}

/// The memories a two-way run's checkpoint holds (none if it has no file: a run that
/// starts two-way from a one-way checkpoint starts with empty memories).
pub fn read_histories(dir: &Path) -> Result<Histories, FlowError> {
    let p = dir.join(HISTORY_FILE);
    if !p.exists() {
        return Ok(Histories::new());
    }
    let b = std::fs::read(&p).map_err(io_err(&p))?;
    let bad = || FlowError::Protocol(format!("{}: damaged self-induced memories", p.display()));
    let mut at = 0usize;
    // a count read from the file may be anything: the end is checked, not assumed
    let mut take = |n: usize| -> Result<&[u8], FlowError> {
        let end = at.checked_add(n).ok_or_else(bad)?;
        let s = b.get(at..end).ok_or_else(bad)?;
        at = end;
        Ok(s)
    };
    match take(8)? {
        m if m == HISTORY_MAGIC => {}
        m if m == HISTORY_MAGIC_V1 => {
            return Err(FlowError::Protocol(format!(
                "{}: self-induced memories of an earlier layout (FFSELF01); resume with the \
                 build that wrote them, or start the run again",
                p.display()
            )))
        }
        _ => return Err(bad()),
    }
    let word = |s: &[u8]| u64::from_le_bytes(s.try_into().unwrap_or([0; 8]));
    let entries = word(take(8)?);
    let mut out = Histories::new();
    for _ in 0..entries {
        let len = u32::from_le_bytes(take(4)?.try_into().map_err(|_| bad())?) as usize;
        let group = String::from_utf8(take(len)?.to_vec()).map_err(|_| bad())?;
        let first = u32::from_le_bytes(take(4)?.try_into().map_err(|_| bad())?);
        let n = usize::try_from(word(take(8)?)).map_err(|_| bad())?;
        let raw = take(n.checked_mul(8).ok_or_else(bad)?)?;
        if n % crate::self_induced::PER_FIBER != 0 {
            return Err(bad());
        }
        let memory = raw.chunks_exact(8).map(word).map(f64::from_bits).collect();
        out.insert((group, first), History { memory });
    }
    Ok(out)
}

/// Writes the analytic flow's (stateless) share.
pub fn write_analytic(dir: &Path, step: u64) -> Result<(), FlowError> {
    std::fs::create_dir_all(dir).map_err(io_err(dir))?;
    let mut b = ANALYTIC_MAGIC.to_vec();
    b.extend_from_slice(&step.to_le_bytes());
    write_atomic(&piece(dir, "flow"), &b)
}

/// Checks the analytic share belongs to `step`.
pub fn read_analytic(dir: &Path, step: u64) -> Result<(), FlowError> {
    let p = piece(dir, "flow");
    let b = std::fs::read(&p).map_err(io_err(&p))?;
    let ok = b.len() == 16 && &b[..8] == ANALYTIC_MAGIC && b[8..] == step.to_le_bytes();
    if !ok {
        return Err(FlowError::Protocol(format!(
            "{} is not the analytic flow's checkpoint of step {step}",
            p.display()
        )));
    }
    Ok(())
}

fn sync_dir(dir: &Path) {
    if let Ok(d) = std::fs::File::open(dir) {
        let _ = d.sync_all();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The memories come back bit for bit; a file of the earlier layout is refused with a
    /// message that names it, and a count that is not whole fibres is damage.
    #[test]
    fn memories_round_trip_and_an_earlier_layout_is_refused() {
        let dir = std::env::temp_dir().join(format!("ff-self-ckpt-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut h = Histories::new();
        let memory: Vec<f64> = (0..2 * crate::self_induced::PER_FIBER)
            .map(|i| (i as f64).sqrt() - 3.0)
            .collect();
        h.insert(("case1".into(), 7), History { memory });
        let p = dir.join(HISTORY_FILE);
        std::fs::write(&p, histories_to_bytes(&h)).unwrap();
        assert_eq!(read_histories(&dir).unwrap(), h);
        let mut old = histories_to_bytes(&h);
        old[..8].copy_from_slice(HISTORY_MAGIC_V1);
        std::fs::write(&p, &old).unwrap();
        let e = read_histories(&dir).unwrap_err().to_string();
        assert!(e.contains("earlier layout"), "{e}");
        let mut short = Histories::new();
        short.insert(
            ("case1".into(), 0),
            History {
                memory: vec![1.0; 5],
            },
        );
        std::fs::write(&p, histories_to_bytes(&short)).unwrap();
        assert!(read_histories(&dir)
            .unwrap_err()
            .to_string()
            .contains("damaged"));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A damaged file whose value count is near the largest a u64 holds (its bytes past
    /// the end of any address) is refused as damaged, in every build (the end of what it
    /// asks for is computed with a checked add).
    #[test]
    fn a_huge_count_is_damage_not_an_overflow() {
        let dir = std::env::temp_dir().join(format!("ff-self-huge-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        for count in [u64::MAX / 8, u64::MAX / 8 - 1, u64::MAX] {
            let mut b = HISTORY_MAGIC.to_vec();
            b.extend_from_slice(&1u64.to_le_bytes());
            b.extend_from_slice(&5u32.to_le_bytes());
            b.extend_from_slice(b"case1");
            b.extend_from_slice(&0u32.to_le_bytes());
            b.extend_from_slice(&count.to_le_bytes());
            b.extend_from_slice(&[0u8; 64]);
            std::fs::write(dir.join(HISTORY_FILE), &b).unwrap();
            let e = read_histories(&dir).unwrap_err().to_string();
            assert!(e.contains("damaged"), "{count}: {e}");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
