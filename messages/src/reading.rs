//! Reading recordings a chunk at a time: every reader of a segment (analysis, viewer,
//! replay, recovery) streams it through mcap's own reader, so a 1–3 GB segment never sits
//! in memory whole and no record longer than [`RECORD_LIMIT_BYTES`] is buffered.

use std::collections::BTreeMap;
use std::path::Path;

/// The largest record (or chunk, compressed or not) a reader accepts; a larger length in a
/// file is damage, not an allocation (a full state of 3 × 10⁵ fibres is ≈ 0.3 GB).
pub const RECORD_LIMIT_BYTES: usize = 1 << 30;

/// Calls `f` with every record of the file in order (the records inside chunks, not the
/// chunks), streaming it: chunks are decompressed by the mcap crate a piece at a time. A
/// damaged or truncated tail ends the walk; its reason is returned (None: read to the end).
pub fn for_each_record(
    path: &Path,
    mut f: impl FnMut(mcap::records::Record<'_>),
) -> Result<Option<String>, std::io::Error> {
    use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
    use std::io::Read;
    let mut file = std::fs::File::open(path)?;
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default().with_record_length_limit(RECORD_LIMIT_BYTES),
    );
    while let Some(event) = reader.next_event() {
        match event {
            Ok(LinearReadEvent::ReadRequest(need)) => {
                let read = file.read(reader.insert(need))?;
                reader.notify_read(read);
            }
            Ok(LinearReadEvent::Record { data, opcode }) => {
                match mcap::parse_record(opcode, data) {
                    Ok(r) => f(r),
                    Err(e) => return Ok(Some(e.to_string())),
                }
            }
            Err(e) => return Ok(Some(e.to_string())),
        }
    }
    Ok(None)
}

/// One message of a recording as [`for_each_message`] hands it over.
#[derive(Debug, Clone, Copy)]
pub struct Message<'a> {
    pub topic: &'a str,
    pub log_time_nanos: u64,
    pub data: &'a [u8],
}

/// Calls `f` for every message of the file in order ([`for_each_record`]: streamed);
/// returns why reading stopped early, if it did (what came before was handed over).
pub fn for_each_message(
    path: &Path,
    f: impl FnMut(Message<'_>),
) -> Result<Option<String>, std::io::Error> {
    for_each_message_and_metadata(path, f, |_| {})
}

/// [`for_each_message`], and `meta` for every metadata record (name and key–value map) in
/// the order the file holds them.
pub fn for_each_message_and_metadata(
    path: &Path,
    mut f: impl FnMut(Message<'_>),
    mut meta: impl FnMut(&mcap::records::Metadata),
) -> Result<Option<String>, std::io::Error> {
    use mcap::records::Record;
    let mut topics: BTreeMap<u16, String> = BTreeMap::new();
    for_each_record(path, |r| match r {
        Record::Channel(c) => {
            topics.insert(c.id, c.topic.clone());
        }
        Record::Message { header, data } => {
            if let Some(topic) = topics.get(&header.channel_id) {
                f(Message {
                    topic,
                    log_time_nanos: header.log_time,
                    data: &data,
                });
            }
        }
        Record::Metadata(m) => meta(&m),
        _ => {}
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::BufWriter;

    /// Every message of a chunked, compressed file comes out in order with its topic,
    /// time and bytes; a file cut inside its last chunk hands over the messages of the
    /// complete chunks and says why it stopped.
    #[test]
    fn messages_stream_in_order_and_a_cut_tail_is_reported() {
        let dir = std::env::temp_dir().join(format!("ff-reading-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("r.mcap");
        {
            let mut w = mcap::WriteOptions::new()
                .compression(Some(mcap::Compression::Zstd))
                .chunk_size(Some(4096))
                .create(BufWriter::new(std::fs::File::create(&path).unwrap()))
                .unwrap();
            let a = w.add_channel(0, "t/a", "raw", &BTreeMap::new()).unwrap();
            let b = w.add_channel(0, "t/b", "raw", &BTreeMap::new()).unwrap();
            for i in 0..100u32 {
                let h = mcap::records::MessageHeader {
                    channel_id: if i % 2 == 0 { a } else { b },
                    sequence: i,
                    log_time: 10 * u64::from(i),
                    publish_time: 0,
                };
                // incompressible enough that the file has many chunks
                let data: Vec<u8> = (0..1000u32).map(|k| (k * 7919 + i * 31) as u8).collect();
                w.write_to_known_channel(&h, &data).unwrap();
            }
            w.finish().unwrap();
        }
        let mut got = Vec::new();
        let stop = for_each_message(&path, |m| {
            got.push((m.topic.to_string(), m.log_time_nanos, m.data[1]))
        })
        .unwrap();
        assert!(stop.is_none());
        assert_eq!(got.len(), 100);
        for (i, (topic, t, b1)) in got.iter().enumerate() {
            assert_eq!(topic, if i % 2 == 0 { "t/a" } else { "t/b" });
            assert_eq!(*t, 10 * i as u64);
            assert_eq!(*b1, (7919 + i as u32 * 31) as u8);
        }
        let len = std::fs::metadata(&path).unwrap().len();
        let f = std::fs::OpenOptions::new().write(true).open(&path).unwrap();
        f.set_len(len / 2).unwrap();
        let mut n = 0;
        let stop = for_each_message(&path, |_| n += 1).unwrap();
        assert!(stop.is_some());
        assert!(n > 10 && n < 100, "{n}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
