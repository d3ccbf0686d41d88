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

/// Reads every record in order (tolerating a truncated tail).
pub fn inspect(path: &Path) -> Result<Inspection, std::io::Error> {
    let bytes = std::fs::read(path)?;
    let mut out = Inspection::default();
    let mut chans: BTreeMap<u16, (String, u16)> = BTreeMap::new();
    let mut schemas: BTreeMap<u16, String> = BTreeMap::new();
    let reader = match mcap::read::LinearReader::new(&bytes) {
        Ok(r) => r,
        Err(e) => {
            out.damage = Some(e.to_string());
            return Ok(out);
        }
    };
    for rec in reader {
        match rec {
            Ok(r) => visit(r, &mut out, &mut chans, &mut schemas),
            Err(e) => {
                out.damage = Some(e.to_string());
                break;
            }
        }
    }
    Ok(out)
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
        Record::Chunk { header, data } => {
            // decompress and walk the chunk's records
            if let Ok(inner) = decompress(&header.compression, &data, header.uncompressed_size) {
                let rd = mcap::read::LinearReader::sans_magic(&inner);
                for rec in rd.flatten() {
                    visit(rec.into_owned(), out, chans, schemas);
                }
            }
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

fn decompress(kind: &str, data: &[u8], size: u64) -> Result<Vec<u8>, std::io::Error> {
    match kind {
        "" => Ok(data.to_vec()),
        "zstd" => zstd_decode(data, size),
        "lz4" => {
            let mut out = Vec::with_capacity(size.min(1 << 30) as usize);
            std::io::copy(&mut lz4::Decoder::new(data)?, &mut out)?;
            Ok(out)
        }
        other => Err(std::io::Error::other(format!(
            "compression {other} not supported"
        ))),
    }
}

fn zstd_decode(data: &[u8], size: u64) -> Result<Vec<u8>, std::io::Error> {
    let mut out = Vec::with_capacity(size.min(1 << 30) as usize);
    let mut dec = zstd::stream::read::Decoder::new(data)?;
    std::io::copy(&mut dec, &mut out)?;
    Ok(out)
}

/// Copies every readable message (with its schema and channel) of a damaged file into a
/// new, properly finished MCAP. Returns the number of messages saved.
pub fn recover(src: &Path, dst: &Path) -> Result<u64, Box<dyn std::error::Error>> {
    let bytes = std::fs::read(src)?;
    let mut w = mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Zstd))
        .profile("ros2")
        .create(BufWriter::new(std::fs::File::create(dst)?))?;
    let mut saved = 0u64;
    let mut stream = mcap::MessageStream::new(&bytes)?;
    let mut chan_map: BTreeMap<u16, u16> = BTreeMap::new();
    for m in stream.by_ref() {
        let Ok(m) = m else { break };
        let id = match chan_map.get(&m.channel.id) {
            Some(&id) => id,
            None => {
                let sid = match &m.channel.schema {
                    Some(s) => w.add_schema(&s.name, &s.encoding, &s.data)?,
                    None => 0,
                };
                let id = w.add_channel(
                    sid,
                    &m.channel.topic,
                    &m.channel.message_encoding,
                    &m.channel.metadata,
                )?;
                chan_map.insert(m.channel.id, id);
                id
            }
        };
        w.write_to_known_channel(
            &mcap::records::MessageHeader {
                channel_id: id,
                sequence: m.sequence,
                log_time: m.log_time,
                publish_time: m.publish_time,
            },
            &m.data,
        )?;
        saved += 1;
    }
    // metadata and attachments of the damaged file, if readable
    if let Ok(ins) = inspect(src) {
        for (name, md) in ins.metadata {
            w.write_metadata(&mcap::records::Metadata { name, metadata: md })?;
        }
    }
    w.finish()?;
    Ok(saved)
}
