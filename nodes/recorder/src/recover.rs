//! Reading and salvaging recordings: summary of channels, counts and metadata, and
//! recovery of a file whose writer was killed (every complete chunk is kept).

use std::collections::BTreeMap;
use std::io::BufWriter;
use std::path::Path;

/// What `inspect` reports.
#[derive(Debug, Clone, Default)]
pub struct Inspection {
    /// topic -> (schema name, message count)
    pub channels: BTreeMap<String, (String, u64)>,
    pub metadata: BTreeMap<String, BTreeMap<String, String>>,
    pub attachments: Vec<String>,
    pub messages: u64,
    /// None if the file is complete; otherwise why reading stopped.
    pub damage: Option<String>,
}

pub use fiberflow_messages::reading::{for_each_record, RECORD_LIMIT_BYTES};

/// Reads every record in order ([`for_each_record`]: streamed, bounded), tolerating a
/// truncated or damaged tail.
pub fn inspect(path: &Path) -> Result<Inspection, std::io::Error> {
    let mut out = Inspection::default();
    let mut chans: BTreeMap<u16, (String, u16)> = BTreeMap::new();
    let mut schemas: BTreeMap<u16, String> = BTreeMap::new();
    let damage = for_each_record(path, |r| visit(r, &mut out, &mut chans, &mut schemas))?;
    out.damage = damage;
    Ok(out)
}

/// Calls `f(topic, payload)` for every message of the file in order (streamed,
/// `fiberflow_messages::reading`); returns why reading stopped early, if it did.
pub fn for_each_message(
    path: &Path,
    mut f: impl FnMut(&str, &[u8]),
) -> Result<Option<String>, std::io::Error> {
    fiberflow_messages::reading::for_each_message(path, |m| f(m.topic, m.data))
}

/// True if the file ends with an MCAP footer record and the closing magic: its writer
/// finished it. Reads the last 37 bytes only.
pub fn is_finished(path: &Path) -> Result<bool, std::io::Error> {
    use std::io::{Read, Seek, SeekFrom};
    // footer: opcode, u64 length (20), summary start, summary offset start, summary crc
    const FOOTER_BYTES: u64 = 1 + 8 + 20;
    let mut file = std::fs::File::open(path)?;
    let len = file.metadata()?.len();
    if len < FOOTER_BYTES + 8 + 8 {
        return Ok(false);
    }
    file.seek(SeekFrom::Start(len - FOOTER_BYTES - 8))?;
    let mut tail = [0u8; 37];
    file.read_exact(&mut tail)?;
    Ok(tail[0] == 0x02
        && u64::from_le_bytes(tail[1..9].try_into().unwrap_or_default()) == 20
        && tail[29..] == *mcap::MAGIC)
}

fn visit(
    r: mcap::records::Record<'_>,
    out: &mut Inspection,
    chans: &mut BTreeMap<u16, (String, u16)>,
    schemas: &mut BTreeMap<u16, String>,
) {
    use mcap::records::Record;
    match r {
        Record::Schema { header, .. } => {
            schemas.insert(header.id, header.name.clone());
        }
        Record::Channel(c) => {
            chans.insert(c.id, (c.topic.clone(), c.schema_id));
        }
        Record::Message { header, .. } => {
            if let Some((topic, sid)) = chans.get(&header.channel_id) {
                let sname = schemas.get(sid).cloned().unwrap_or_default();
                let e = out.channels.entry(topic.clone()).or_insert((sname, 0));
                e.1 += 1;
                out.messages += 1;
            }
        }
        Record::Metadata(m) => {
            out.metadata.insert(m.name.clone(), m.metadata.clone());
        }
        Record::Attachment { header, .. } => out.attachments.push(header.name.clone()),
        _ => {}
    }
}

/// Copies every readable message (with its schema and channel), and the metadata, of a
/// damaged file into a new, properly finished MCAP, streaming ([`for_each_record`]: a
/// chunk at a time, never the whole file in memory; test
/// `tests/recover_memory.rs`). Returns the number of messages saved.
pub fn recover(src: &Path, dst: &Path) -> Result<u64, Box<dyn std::error::Error>> {
    use mcap::records::Record;
    let mut w = mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Zstd))
        .profile("ros2")
        .create(BufWriter::new(std::fs::File::create(dst)?))?;
    let mut saved = 0u64;
    // the source's schemas (name, encoding, data) and channels, and the ids they got in
    // the new file once a message used them
    let mut schemas: BTreeMap<u16, (String, String, Vec<u8>)> = BTreeMap::new();
    let mut channels: BTreeMap<u16, mcap::records::Channel> = BTreeMap::new();
    let mut new_schema: BTreeMap<u16, u16> = BTreeMap::new();
    let mut new_channel: BTreeMap<u16, u16> = BTreeMap::new();
    let mut failed: Option<mcap::McapError> = None;
    for_each_record(src, |r| {
        if failed.is_some() {
            return;
        }
        let step = || -> Result<(), mcap::McapError> {
            match r {
                Record::Schema { header, data } => {
                    schemas.insert(header.id, (header.name, header.encoding, data.into_owned()));
                }
                Record::Channel(c) => {
                    channels.insert(c.id, c);
                }
                Record::Message { header, data } => {
                    let id = match new_channel.get(&header.channel_id) {
                        Some(&id) => id,
                        None => {
                            // a message whose channel was never declared is not readable
                            let Some(c) = channels.get(&header.channel_id) else {
                                return Ok(());
                            };
                            let sid =
                                match (new_schema.get(&c.schema_id), schemas.get(&c.schema_id)) {
                                    (Some(&sid), _) => sid,
                                    (None, Some((name, enc, data))) => {
                                        let sid = w.add_schema(name, enc, data)?;
                                        new_schema.insert(c.schema_id, sid);
                                        sid
                                    }
                                    (None, None) => 0,
                                };
                            let id =
                                w.add_channel(sid, &c.topic, &c.message_encoding, &c.metadata)?;
                            new_channel.insert(header.channel_id, id);
                            id
                        }
                    };
                    w.write_to_known_channel(
                        &mcap::records::MessageHeader {
                            channel_id: id,
                            sequence: header.sequence,
                            log_time: header.log_time,
                            publish_time: header.publish_time,
                        },
                        &data,
                    )?;
                    saved += 1;
                }
                Record::Metadata(m) => w.write_metadata(&m)?,
                _ => {}
            }
            Ok(())
        };
        if let Err(e) = step() {
            failed = Some(e);
        }
    })?;
    if let Some(e) = failed {
        return Err(e.into());
    }
    w.finish()?;
    Ok(saved)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small complete file: one channel, three messages, chunked and compressed.
    fn small_file(path: &Path) {
        let mut w = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Zstd))
            .create(BufWriter::new(std::fs::File::create(path).unwrap()))
            .unwrap();
        let ch = w.add_channel(0, "t/x", "raw", &BTreeMap::new()).unwrap();
        for i in 0..3u32 {
            let header = mcap::records::MessageHeader {
                channel_id: ch,
                sequence: i,
                log_time: u64::from(i),
                publish_time: u64::from(i),
            };
            w.write_to_known_channel(&header, &[7u8; 100]).unwrap();
        }
        w.finish().unwrap();
    }

    /// A record length beyond [`RECORD_LIMIT_BYTES`] is reported as damage, not
    /// allocated; a truncated tail is damage too, and what came before it still counts.
    #[test]
    fn absurd_lengths_and_truncation_are_damage_not_allocations() {
        let dir = std::env::temp_dir().join(format!("ff-inspect-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let good = dir.join("good.mcap");
        small_file(&good);
        let ins = inspect(&good).unwrap();
        assert!(ins.damage.is_none(), "{:?}", ins.damage);
        assert_eq!(ins.messages, 3);
        let bytes = std::fs::read(&good).unwrap();
        // the start magic (8 bytes) and the header record, then a chunk that claims 1 TiB
        let header_len = u64::from_le_bytes(bytes[9..17].try_into().unwrap()) as usize;
        let mut absurd = bytes[..8 + 9 + header_len].to_vec();
        absurd.push(0x06);
        absurd.extend_from_slice(&(1u64 << 40).to_le_bytes());
        absurd.extend_from_slice(&[0u8; 64]);
        let p = dir.join("absurd.mcap");
        std::fs::write(&p, &absurd).unwrap();
        let ins = inspect(&p).unwrap();
        assert!(ins.damage.is_some(), "a 1 TiB chunk was not reported");
        // truncated in the middle of the file
        let p = dir.join("cut.mcap");
        std::fs::write(&p, &bytes[..bytes.len() / 2]).unwrap();
        let ins = inspect(&p).unwrap();
        assert!(ins.damage.is_some(), "a truncated file was not reported");
        assert!(ins.messages <= 3);
        assert!(is_finished(&good).unwrap());
        assert!(!is_finished(&p).unwrap());
        let mut seen = Vec::new();
        assert_eq!(
            for_each_message(&good, |t, d| seen.push((t.to_string(), d.len()))).unwrap(),
            None
        );
        assert_eq!(seen, vec![("t/x".to_string(), 100); 3]);
        assert!(for_each_message(&p, |_, _| {}).unwrap().is_some());
        std::fs::remove_dir_all(&dir).ok();
    }
}
