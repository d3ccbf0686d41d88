//! Checkpoints of a fibre group: everything the next step reads (docs/architecture.md), bit for bit.
//!
//! The implicit step (eq. 5, 7, 8, 11, 12) reads, per segment, the centre r, the axis ẑ,
//! the velocity ṙ and angular velocity ω at n−1 (the inertial drag is linearised with the
//! previous velocity, and the gyroscopic term uses ω_{n−1}), plus the material normal n
//! that measures twist. Nothing else carries over between steps (no RNG, no history), so
//! these five arrays and the step number are the whole integrator state. Two-way coupling
//! adds a sixth: each segment's hydrodynamic force of the last step, which the state of the
//! checkpoint's step returns to the fluid (a resumed run sends the same bits). They are
//! stored structure-of-arrays, 3 f64 per segment each, little-endian, after a header.
//! Contact adds the last step's contact load (the segments that touched, their forces and
//! pair counts: the state of the checkpoint's step carries them again) as a count and three
//! arrays after the six. An FNV-1a checksum closes the file; files are written atomically
//! (temp file, fsync, rename). Files of the earlier formats are read: `FFGRPCK1` (five
//! arrays) with zero forces, `FFGRPCK2` (six) with no contact load.

use crate::group::FiberGroup;
use nalgebra::Vector3;
use std::path::Path;

const MAGIC: &[u8; 8] = b"FFGRPCK3";
/// The format before contact's load: six arrays.
const MAGIC_V2: &[u8; 8] = b"FFGRPCK2";
/// The format before two-way coupling: no force array.
const MAGIC_V1: &[u8; 8] = b"FFGRPCK1";

/// Checkpoint errors (I/O, damage, or a checkpoint that does not fit the group).
#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    #[error("i/o error on {path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{path} is not a usable fibre-group checkpoint: {reason}")]
    Invalid { path: String, reason: String },
}

/// Per-segment arrays in a file of the current format.
const ARRAYS: usize = 6;

/// The integrator state of a group at one step (flat, segment-major arrays).
#[derive(Debug, Clone, PartialEq)]
pub struct GroupSnapshot {
    pub step: u64,
    pub segments_per_fiber: Vec<u32>,
    pub centre: Vec<f64>,
    pub axis: Vec<f64>,
    pub velocity: Vec<f64>,
    pub angular_velocity: Vec<f64>,
    pub normal: Vec<f64>,
    /// Hydrodynamic force of the last step ([`crate::fiber::Segment::f`]).
    pub force: Vec<f64>,
    /// Contact load of the last step ([`FiberGroup::contact_load`]).
    pub contact: crate::contact::SegmentLoad,
}

impl GroupSnapshot {
    /// Captures the group's state at `step`.
    pub fn capture(group: &FiberGroup, step: u64) -> Self {
        let n = group.segment_count();
        let mut s = Self {
            step,
            segments_per_fiber: (0..group.len())
                .map(|k| group.fiber_len(k) as u32)
                .collect(),
            centre: Vec::with_capacity(3 * n),
            axis: Vec::with_capacity(3 * n),
            velocity: Vec::with_capacity(3 * n),
            angular_velocity: Vec::with_capacity(3 * n),
            normal: Vec::with_capacity(3 * n),
            force: Vec::with_capacity(3 * n),
            contact: group.contact_load().clone(),
        };
        for seg in (0..group.len()).flat_map(|k| group.segments(k)) {
            s.centre.extend_from_slice(seg.r.as_slice());
            s.axis.extend_from_slice(seg.z.as_slice());
            s.velocity.extend_from_slice(seg.v.as_slice());
            s.angular_velocity.extend_from_slice(seg.w.as_slice());
            s.normal.extend_from_slice(seg.n.as_slice());
            s.force.extend_from_slice(seg.f.as_slice());
        }
        s
    }

    /// Puts this state into `group` (built from the same configuration).
    pub fn restore(&self, group: &mut FiberGroup) -> Result<(), String> {
        let shape: Vec<u32> = (0..group.len())
            .map(|k| group.fiber_len(k) as u32)
            .collect();
        if shape != self.segments_per_fiber {
            return Err(format!(
                "it holds {} fibres / {} segments, the configured group {} / {}",
                self.segments_per_fiber.len(),
                self.segments_per_fiber
                    .iter()
                    .map(|&n| n as u64)
                    .sum::<u64>(),
                shape.len(),
                group.segment_count()
            ));
        }
        let flat = crate::fiber::FlatSegments {
            centre: &self.centre,
            axis: &self.axis,
            velocity: &self.velocity,
            angular_velocity: &self.angular_velocity,
            normal: &self.normal,
        };
        let f = |i: usize| {
            Vector3::new(
                self.force[3 * i],
                self.force[3 * i + 1],
                self.force[3 * i + 2],
            )
        };
        let mut i = 0;
        for k in 0..group.len() {
            for j in 0..group.fiber_len(k) {
                group.set_segment(k, j, flat.get(i, f(i)));
                i += 1;
            }
        }
        group.restore_contact_load(self.contact.clone());
        Ok(())
    }

    fn arrays(&self) -> [&Vec<f64>; ARRAYS] {
        [
            &self.centre,
            &self.axis,
            &self.velocity,
            &self.angular_velocity,
            &self.normal,
            &self.force,
        ]
    }

    /// Serialises to bytes (header, per-fibre counts, six arrays, checksum).
    pub fn to_bytes(&self) -> Vec<u8> {
        let nseg = self.centre.len() / 3;
        let mut out =
            Vec::with_capacity(40 + 4 * self.segments_per_fiber.len() + 24 * ARRAYS * nseg);
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&self.step.to_le_bytes());
        out.extend_from_slice(&(self.segments_per_fiber.len() as u64).to_le_bytes());
        out.extend_from_slice(&(nseg as u64).to_le_bytes());
        for &n in &self.segments_per_fiber {
            out.extend_from_slice(&n.to_le_bytes());
        }
        for a in self.arrays() {
            for x in a {
                out.extend_from_slice(&x.to_le_bytes());
            }
        }
        let c = &self.contact;
        out.extend_from_slice(&(c.segment.len() as u64).to_le_bytes());
        for i in c.segment.iter().chain(&c.count) {
            out.extend_from_slice(&i.to_le_bytes());
        }
        for x in &c.force {
            out.extend_from_slice(&x.to_le_bytes());
        }
        let sum = fnv1a(&out);
        out.extend_from_slice(&sum.to_le_bytes());
        out
    }

    /// Parses bytes written by [`Self::to_bytes`]; every length and the checksum are checked.
    pub fn from_bytes(b: &[u8]) -> Result<Self, String> {
        if b.len() < 40 {
            return Err("too short".into());
        }
        let (arrays_in_file, with_load) = match &b[..8] {
            m if m == MAGIC => (ARRAYS, true),
            m if m == MAGIC_V2 => (ARRAYS, false),
            m if m == MAGIC_V1 => (ARRAYS - 1, false),
            _ => return Err("wrong magic".into()),
        };
        let (body, tail) = b.split_at(b.len() - 8);
        let sum = u64::from_le_bytes(tail.try_into().map_err(|_| "short checksum")?);
        if fnv1a(body) != sum {
            return Err("checksum mismatch (damaged file)".into());
        }
        let word = |o: usize| -> u64 {
            let mut w = [0u8; 8];
            w.copy_from_slice(&body[o..o + 8]);
            u64::from_le_bytes(w)
        };
        let step = word(8);
        let nfib = usize::try_from(word(16)).map_err(|_| "fibre count overflows")?;
        let nseg = usize::try_from(word(24)).map_err(|_| "segment count overflows")?;
        let expect = nfib
            .checked_mul(4)
            .and_then(|c| {
                nseg.checked_mul(24 * arrays_in_file)
                    .and_then(|s| s.checked_add(c))
            })
            .and_then(|x| x.checked_add(32))
            .ok_or("sizes overflow")?;
        // the contact load: a count, then per listed segment its index, pair count and force
        let touched = if with_load {
            if body.len() < expect + 8 {
                return Err("no contact load".into());
            }
            usize::try_from(word(expect)).map_err(|_| "contact count overflows")?
        } else {
            0
        };
        let expect = if with_load {
            touched
                .checked_mul(32)
                .and_then(|x| x.checked_add(expect + 8))
                .ok_or("sizes overflow")?
        } else {
            expect
        };
        if body.len() != expect {
            return Err(format!(
                "{} bytes for {nfib} fibres and {nseg} segments, expected {expect}",
                body.len()
            ));
        }
        let mut o = 32;
        let mut segments_per_fiber = Vec::with_capacity(nfib);
        for _ in 0..nfib {
            let mut w = [0u8; 4];
            w.copy_from_slice(&body[o..o + 4]);
            segments_per_fiber.push(u32::from_le_bytes(w));
            o += 4;
        }
        if segments_per_fiber.iter().map(|&n| n as u64).sum::<u64>() != nseg as u64 {
            return Err("per-fibre segment counts do not add up".into());
        }
        let mut arrays: Vec<Vec<f64>> = Vec::with_capacity(ARRAYS);
        for _ in 0..arrays_in_file {
            let a: Vec<f64> = body[o..o + 24 * nseg]
                .chunks_exact(8)
                .map(|c| {
                    let mut w = [0u8; 8];
                    w.copy_from_slice(c);
                    f64::from_le_bytes(w)
                })
                .collect();
            o += 24 * nseg;
            arrays.push(a);
        }
        let mut contact = crate::contact::SegmentLoad::default();
        if with_load {
            o += 8;
            let u32_at = |o: usize| {
                let mut w = [0u8; 4];
                w.copy_from_slice(&body[o..o + 4]);
                u32::from_le_bytes(w)
            };
            contact.segment = (0..touched).map(|i| u32_at(o + 4 * i)).collect();
            o += 4 * touched;
            contact.count = (0..touched).map(|i| u32_at(o + 4 * i)).collect();
            o += 4 * touched;
            contact.force = (0..3 * touched)
                .map(|i| f64::from_bits(word(o + 8 * i)))
                .collect();
            if contact.segment.iter().any(|&s| s as usize >= nseg) {
                return Err("a contact segment past the group's segments".into());
            }
        }
        let mut it = arrays.into_iter();
        let mut next = || it.next().unwrap_or_default();
        Ok(Self {
            step,
            segments_per_fiber,
            centre: next(),
            axis: next(),
            velocity: next(),
            angular_velocity: next(),
            normal: next(),
            force: if arrays_in_file == ARRAYS {
                next()
            } else {
                vec![0.0; 3 * nseg]
            },
            contact,
        })
    }

    pub fn read(path: &Path) -> Result<Self, CheckpointError> {
        let b = std::fs::read(path).map_err(|source| CheckpointError::Io {
            path: path.display().to_string(),
            source,
        })?;
        Self::from_bytes(&b).map_err(|reason| CheckpointError::Invalid {
            path: path.display().to_string(),
            reason,
        })
    }
}

fn fnv1a(b: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &x in b {
        h ^= x as u64;
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    h
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fiber::Fiber;
    use crate::step::{step, FluidSample, ModelParams};
    use crate::DragModel;
    use nalgebra::Matrix3;

    fn group() -> FiberGroup {
        let fibers = (0..3)
            .map(|k| {
                Fiber::straight(
                    Vector3::new(k as f64, 0.1 * k as f64, 0.0),
                    Vector3::new(0.0, 1.0, 0.2).normalize(),
                    &[3.0; 7],
                    &[0.232; 7],
                    1150.0,
                )
                .unwrap()
            })
            .collect();
        let params = ModelParams {
            drag: DragModel {
                viscosity: 1.0,
                fluid_density: 1.0,
                drag_coefficient: 1.0,
            },
            gravity: Vector3::zeros(),
            bending_stiffness: 0.0,
            twisting_stiffness: 1e-3,
            tikhonov: 0.0,
            wall_half_height: None,
        };
        FiberGroup::new(params, fibers)
    }

    fn shear(g: &FiberGroup) -> Vec<FluidSample> {
        let mut grad = Matrix3::zeros();
        grad[(0, 1)] = 0.3;
        g.segment_centres()
            .iter()
            .map(|r| FluidSample {
                vel: Vector3::new(0.3 * r.y, 0.0, 0.0),
                grad,
            })
            .collect()
    }

    /// Stop after k steps, save, restore into a fresh group, continue: the states after
    /// k + m steps are bitwise equal to an uninterrupted k + m steps (N + N == 2N).
    #[test]
    fn restore_continues_bit_for_bit() {
        let dt = 0.25;
        let mut a = group();
        for _ in 0..20 {
            let f = shear(&a);
            a.step(&f, dt).unwrap();
        }
        let snap = GroupSnapshot::capture(&a, 20);
        let path = std::env::temp_dir().join(format!("ff-grp-{}.ckpt", std::process::id()));
        std::fs::write(&path, snap.to_bytes()).unwrap();
        let back = GroupSnapshot::read(&path).unwrap();
        assert_eq!(back, snap);
        let mut b = group();
        back.restore(&mut b).unwrap();
        for _ in 0..20 {
            let f = shear(&a);
            a.step(&f, dt).unwrap();
            let f = shear(&b);
            b.step(&f, dt).unwrap();
        }
        let (sa, sb) = (
            GroupSnapshot::capture(&a, 40),
            GroupSnapshot::capture(&b, 40),
        );
        assert_eq!(sa.to_bytes(), sb.to_bytes());
        // the normals carry state: a restore that dropped them would differ
        assert!(sa.normal.iter().any(|x| x.abs() > 1e-6));
        std::fs::remove_file(&path).ok();
        // sanity of the single-fibre API on the restored group
        let f0 = shear(&b)[..7].to_vec();
        let mut one = b.fiber(0);
        step(b.params(), &mut one, &f0, dt).unwrap();
    }

    /// The last step's contact load goes through a checkpoint and back into the group
    /// unchanged (a resumed node sends the checkpoint's state again, bit for bit); a file
    /// of the format before it (`FFGRPCK2`) reads with no load, and one whose load names a
    /// segment past the group is refused.
    #[test]
    fn the_contact_load_survives_a_checkpoint_and_older_files_read_without_it() {
        let mut g = group();
        let load = crate::contact::SegmentLoad {
            segment: vec![3, 9, 20],
            force: vec![
                0.5,
                -1.25,
                3.0,
                1e-300,
                0.0,
                -0.0,
                f64::MAX,
                -7.0,
                1.0 / 3.0,
            ],
            count: vec![1, 2, 1],
        };
        g.restore_contact_load(load.clone());
        let snap = GroupSnapshot::capture(&g, 5);
        let bytes = snap.to_bytes();
        let back = GroupSnapshot::from_bytes(&bytes).unwrap();
        assert_eq!(back, snap);
        let mut h = group();
        back.restore(&mut h).unwrap();
        let bits = |l: &crate::contact::SegmentLoad| {
            (
                l.segment.clone(),
                l.count.clone(),
                l.force.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
            )
        };
        assert_eq!(bits(h.contact_load()), bits(&load));
        // the same file without its load, as the format before wrote it
        let empty = GroupSnapshot {
            contact: Default::default(),
            ..snap.clone()
        };
        let b = empty.to_bytes();
        let mut v2 = b[..b.len() - 16].to_vec();
        v2[..8].copy_from_slice(MAGIC_V2);
        let sum = fnv1a(&v2);
        v2.extend_from_slice(&sum.to_le_bytes());
        assert_eq!(GroupSnapshot::from_bytes(&v2).unwrap(), empty);
        // a load past the group's 21 segments
        let past = GroupSnapshot {
            contact: crate::contact::SegmentLoad {
                segment: vec![21],
                force: vec![0.0; 3],
                count: vec![1],
            },
            ..snap
        };
        let e = GroupSnapshot::from_bytes(&past.to_bytes()).unwrap_err();
        assert!(e.contains("past"), "{e}");
    }

    #[test]
    fn damage_and_mismatch_are_named_errors() {
        let g = group();
        let mut b = GroupSnapshot::capture(&g, 3).to_bytes();
        let n = b.len();
        b[n / 2] ^= 1;
        assert!(GroupSnapshot::from_bytes(&b)
            .unwrap_err()
            .contains("checksum"));
        assert!(GroupSnapshot::from_bytes(&b[..n - 9]).is_err());
        assert!(GroupSnapshot::from_bytes(b"FFGRPCK1").is_err());
        let other = group();
        let other = other.slice(0, other.len() - 1);
        let mut g2 = group();
        let e = GroupSnapshot::capture(&other, 0)
            .restore(&mut g2)
            .unwrap_err();
        assert!(e.contains("2 fibres"), "{e}");
    }
}
