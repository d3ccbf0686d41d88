//! Checkpoints: the complete solver state (velocity, time, step, forcing) in a small
//! self-describing binary file, written atomically (temp file + rename) so a killed
//! process never leaves a half-written checkpoint behind.

use crate::error::DnsError;
use crate::field::Velocity;
use crate::grid::Grid;
use std::io::{Read, Write};
use std::path::Path;

const MAGIC: &[u8; 8] = b"FFDNSCK1";
/// Magic, three sizes, four floats, step, forcing, first width: 11 words of 8 bytes.
const HEADER_LEN: usize = 88;

/// Header of a checkpoint file.
#[derive(Debug, Clone, PartialEq)]
pub struct CheckpointHeader {
    pub nx: usize,
    pub ny: usize,
    pub nz: usize,
    pub lx: f64,
    pub lz: f64,
    pub re_tau: f64,
    pub time: f64,
    pub step: u64,
    pub forcing: f64,
    /// First cell width (identifies the stretching).
    pub dy_first: f64,
}

fn interior(g: &Grid, f: &[f64], out: &mut Vec<u8>) {
    for k in 1..=g.nz {
        for j in 1..=g.ny {
            for i in 1..=g.nx {
                out.extend_from_slice(&f[g.idx(i, j, k)].to_le_bytes());
            }
        }
    }
}

/// Serialises the state to bytes.
pub fn encode(g: &Grid, h: &CheckpointHeader, vel: &Velocity) -> Vec<u8> {
    let mut out = Vec::with_capacity(HEADER_LEN + 3 * 8 * g.cells());
    out.extend_from_slice(MAGIC);
    for n in [h.nx, h.ny, h.nz] {
        out.extend_from_slice(&(n as u64).to_le_bytes());
    }
    for x in [h.lx, h.lz, h.re_tau, h.time] {
        out.extend_from_slice(&x.to_le_bytes());
    }
    out.extend_from_slice(&h.step.to_le_bytes());
    out.extend_from_slice(&h.forcing.to_le_bytes());
    out.extend_from_slice(&h.dy_first.to_le_bytes());
    interior(g, &vel.u, &mut out);
    interior(g, &vel.v, &mut out);
    interior(g, &vel.w, &mut out);
    out
}

/// Writes atomically.
pub fn write(path: &Path, g: &Grid, h: &CheckpointHeader, vel: &Velocity) -> Result<(), DnsError> {
    let io = |source| DnsError::Io {
        path: path.display().to_string(),
        source,
    };
    let bytes = encode(g, h, vel);
    let tmp = path.with_extension("tmp");
    {
        let mut f = std::fs::File::create(&tmp).map_err(io)?;
        f.write_all(&bytes).map_err(io)?;
        f.sync_all().map_err(io)?;
    }
    std::fs::rename(&tmp, path).map_err(io)
}

struct Cursor<'a>(&'a [u8], usize);
impl Cursor<'_> {
    fn take8(&mut self) -> Option<[u8; 8]> {
        let s = self.0.get(self.1..self.1 + 8)?;
        self.1 += 8;
        s.try_into().ok()
    }
    fn u64(&mut self) -> Option<u64> {
        self.take8().map(u64::from_le_bytes)
    }
    fn f64(&mut self) -> Option<f64> {
        self.take8().map(f64::from_le_bytes)
    }
}

/// Reads the header only.
pub fn read_header(bytes: &[u8]) -> Option<CheckpointHeader> {
    if bytes.get(0..8)? != MAGIC {
        return None;
    }
    let mut c = Cursor(bytes, 8);
    Some(CheckpointHeader {
        nx: c.u64()? as usize,
        ny: c.u64()? as usize,
        nz: c.u64()? as usize,
        lx: c.f64()?,
        lz: c.f64()?,
        re_tau: c.f64()?,
        time: c.f64()?,
        step: c.u64()?,
        forcing: c.f64()?,
        dy_first: c.f64()?,
    })
}

/// Loads a checkpoint into `vel` (halos are left for the caller to refresh).
pub fn read(path: &Path, g: &Grid, vel: &mut Velocity) -> Result<CheckpointHeader, DnsError> {
    let err = |reason: String| DnsError::Checkpoint {
        path: path.display().to_string(),
        reason,
    };
    let mut bytes = Vec::new();
    std::fs::File::open(path)
        .and_then(|mut f| f.read_to_end(&mut bytes))
        .map_err(|source| DnsError::Io {
            path: path.display().to_string(),
            source,
        })?;
    let h = read_header(&bytes).ok_or_else(|| err("not a fiberflow DNS checkpoint".into()))?;
    if (h.nx, h.ny, h.nz) != (g.nx, g.ny, g.nz) {
        return Err(err(format!(
            "grid {}x{}x{} does not match the configured {}x{}x{}",
            h.nx, h.ny, h.nz, g.nx, g.ny, g.nz
        )));
    }
    let n = g.cells();
    let body = &bytes[HEADER_LEN..];
    if body.len() != 3 * 8 * n {
        return Err(err(format!(
            "truncated: {} bytes of field data, expected {}",
            body.len(),
            3 * 8 * n
        )));
    }
    for (c, f) in [&mut vel.u, &mut vel.v, &mut vel.w].into_iter().enumerate() {
        let mut off = c * 8 * n;
        for k in 1..=g.nz {
            for j in 1..=g.ny {
                for i in 1..=g.nx {
                    let mut b = [0u8; 8];
                    b.copy_from_slice(&body[off..off + 8]);
                    f[g.idx(i, j, k)] = f64::from_le_bytes(b);
                    off += 8;
                }
            }
        }
    }
    Ok(h)
}
