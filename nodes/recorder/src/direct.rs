//! The recording file, written past the page cache (`O_DIRECT`) where the file system
//! takes it. A recorder at scale writes several MB per coupling step; through the page
//! cache the kernel copies every byte into fresh pages on the recorder's CPU (about half
//! of its CPU at 6 × 10⁴ fibres, `perf record`), while a direct write hands the buffer to
//! the device. Bytes are gathered in a block-aligned buffer and written out in whole
//! blocks; on `flush` the partial last block also goes to the file, through the page
//! cache, and is written again whole with the next direct write. So after every flush the
//! file holds every byte written so far, in order, as a plain buffered file would.

use std::fs::File;
use std::io::{self, Seek, SeekFrom, Write};
use std::os::unix::fs::{FileExt, OpenOptionsExt};
use std::path::Path;

/// Alignment of direct writes (file offset, length and memory): a multiple of every
/// logical block size in use.
const BLOCK: usize = 4096;

/// Bytes gathered before they are written out.
const BUFFER_BLOCKS: usize = 1024;

#[repr(C, align(4096))]
#[derive(Clone, Copy)]
struct Block([u8; BLOCK]);

/// A new file, written sequentially (see the module's doc).
pub struct RecordingFile {
    /// The file opened with `O_DIRECT`; `None` where the file system refuses it (tmpfs)
    /// or a direct write failed: then everything goes through `plain`.
    direct: Option<File>,
    plain: File,
    buf: Vec<Block>,
    /// Bytes held in `buf`.
    len: usize,
    /// The file offset of `buf`'s first byte (a multiple of [`BLOCK`] while direct).
    at: u64,
}

impl RecordingFile {
    /// Creates (or truncates) the file at `path`.
    pub fn create(path: &Path) -> io::Result<Self> {
        // a segment is never rewritten: a restarted recorder writes the next one
        let plain = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(path)?;
        let direct = std::fs::OpenOptions::new()
            .write(true)
            .custom_flags(libc::O_DIRECT)
            .open(path)
            .ok();
        if direct.is_none() {
            tracing::info!(path = %path.display(), "no direct writes on this file system: recording through the page cache");
        }
        Ok(Self {
            direct,
            plain,
            buf: vec![Block([0; BLOCK]); BUFFER_BLOCKS],
            len: 0,
            at: 0,
        })
    }

    /// Whether writes go past the page cache.
    pub fn is_direct(&self) -> bool {
        self.direct.is_some()
    }

    fn bytes(&self) -> &[u8] {
        // SAFETY: `Block` is `repr(C)` around a byte array whose size is a multiple of its
        // alignment, so the vector's blocks are contiguous initialised bytes.
        unsafe {
            std::slice::from_raw_parts(self.buf.as_ptr().cast::<u8>(), self.buf.len() * BLOCK)
        }
    }

    fn bytes_mut(&mut self) -> &mut [u8] {
        // SAFETY: as in `bytes`, and borrowed mutably through `self`.
        unsafe {
            std::slice::from_raw_parts_mut(
                self.buf.as_mut_ptr().cast::<u8>(),
                self.buf.len() * BLOCK,
            )
        }
    }

    /// Writes out the whole blocks held (directly), keeps the partial last one, and with
    /// `tail` also puts that one in the file through the page cache.
    fn write_out(&mut self, tail: bool) -> io::Result<()> {
        if let Some(direct) = &self.direct {
            let whole = self.len / BLOCK * BLOCK;
            if whole > 0 {
                match direct.write_all_at(&self.bytes()[..whole], self.at) {
                    Ok(()) => {
                        let len = self.len;
                        self.bytes_mut().copy_within(whole..len, 0);
                        self.len -= whole;
                        self.at += whole as u64;
                    }
                    // a file system that opened the file but takes no direct writes
                    Err(e) if e.raw_os_error() == Some(libc::EINVAL) => {
                        tracing::info!("direct writes refused: recording through the page cache");
                        self.direct = None;
                        return self.write_out(tail);
                    }
                    Err(e) => return Err(e),
                }
            }
            if tail && self.len > 0 {
                self.plain
                    .write_all_at(&self.bytes()[..self.len], self.at)?;
            }
            return Ok(());
        }
        self.plain
            .write_all_at(&self.bytes()[..self.len], self.at)?;
        self.at += self.len as u64;
        self.len = 0;
        Ok(())
    }
}

impl Write for RecordingFile {
    fn write(&mut self, data: &[u8]) -> io::Result<usize> {
        let room = self.buf.len() * BLOCK - self.len;
        let n = room.min(data.len());
        let len = self.len;
        self.bytes_mut()[len..len + n].copy_from_slice(&data[..n]);
        self.len += n;
        if self.len == self.buf.len() * BLOCK {
            self.write_out(false)?;
        }
        Ok(n)
    }

    fn flush(&mut self) -> io::Result<()> {
        self.write_out(true)
    }
}

/// Only the current position can be asked for or sought to: the file is written in order.
impl Seek for RecordingFile {
    fn seek(&mut self, to: SeekFrom) -> io::Result<u64> {
        let here = self.at + self.len as u64;
        let target = match to {
            SeekFrom::Start(p) => Some(p),
            SeekFrom::Current(d) => here.checked_add_signed(d),
            SeekFrom::End(_) => None,
        };
        match target {
            Some(p) if p == here => Ok(here),
            _ => Err(io::Error::new(
                io::ErrorKind::Unsupported,
                "a recording file is written in order",
            )),
        }
    }
}

impl Drop for RecordingFile {
    fn drop(&mut self) {
        if let Err(e) = self.flush() {
            tracing::warn!(error = %e, "the recording's last bytes could not be written");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A scratch file in the workspace's (git-ignored) `target/`: on the checkout's disk,
    /// which takes direct writes where a tmpfs `/tmp` would not.
    fn scratch(name: &str) -> std::path::PathBuf {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../target")
            .join(format!("ff-direct-{}-{name}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir.join("f.bin")
    }

    /// A segment that exists is never opened for writing again: creating it fails and
    /// leaves its bytes as they were.
    #[test]
    fn an_existing_segment_is_not_rewritten() {
        let path = scratch("existing");
        std::fs::write(&path, b"recorded").unwrap();
        let e = RecordingFile::create(&path).err().expect("refused");
        assert_eq!(e.kind(), io::ErrorKind::AlreadyExists);
        assert_eq!(std::fs::read(&path).unwrap(), b"recorded");
        std::fs::remove_dir_all(path.parent().unwrap()).ok();
    }

    /// Pieces of every size (across block and buffer edges) with flushes in between: after
    /// each flush the file is exactly the bytes written so far, and at the end all of them
    /// — written directly (where the scratch file system takes direct writes) and through
    /// the page cache.
    #[test]
    fn file_holds_every_flushed_byte_in_order() {
        for direct in [true, false] {
            let path = scratch(if direct { "direct" } else { "plain" });
            let mut f = RecordingFile::create(&path).unwrap();
            if direct && !f.is_direct() {
                // nothing to test the direct path on: the buffered case below still runs
                eprintln!("{}: no direct writes on this file system", path.display());
                std::fs::remove_dir_all(path.parent().unwrap()).ok();
                continue;
            }
            if !direct {
                f.direct = None;
            }
            let mut want = Vec::new();
            let mut x = 0x2545_f491_4f6c_dd1du64;
            let mut rnd = move |n: u64| {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                x % n
            };
            for i in 0..300 {
                let n = match i % 4 {
                    0 => rnd(10) as usize,
                    1 => rnd(3 * BLOCK as u64) as usize,
                    2 => BLOCK,
                    _ => rnd(2 * (BUFFER_BLOCKS * BLOCK) as u64) as usize,
                };
                let piece: Vec<u8> = (0..n).map(|k| (k as u64 * 31 + i) as u8).collect();
                f.write_all(&piece).unwrap();
                want.extend_from_slice(&piece);
                assert_eq!(f.stream_position().unwrap(), want.len() as u64);
                if rnd(3) == 0 {
                    f.flush().unwrap();
                    assert!(std::fs::read(&path).unwrap() == want, "after piece {i}");
                }
            }
            assert!(f.seek(SeekFrom::Start(0)).is_err(), "seeking back");
            drop(f);
            assert!(std::fs::read(&path).unwrap() == want);
            std::fs::remove_dir_all(path.parent().unwrap()).ok();
        }
    }
}
