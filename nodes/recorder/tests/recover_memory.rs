//! Recovering a damaged recording streams it: the process's peak memory grows by far less
//! than the file's size (a restart recovers segments of 1–3 GB). Alone in its test binary,
//! so no other test moves the peak.

use std::collections::BTreeMap;
use std::io::BufWriter;

/// The process's peak resident memory so far, bytes (`VmHWM`).
fn peak_bytes() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap();
    let line = status.lines().find(|l| l.starts_with("VmHWM:")).unwrap();
    let kb: u64 = line.split_whitespace().nth(1).unwrap().parse().unwrap();
    kb * 1024
}

/// A 256 MiB uncompressed recording of 1 MiB messages, its tail cut off mid-chunk, is
/// recovered (every complete chunk's messages) with the peak memory growing by less than
/// 64 MiB.
#[test]
fn recovering_a_large_file_does_not_read_it_whole() {
    let dir = std::env::temp_dir().join(format!("ff-recover-mem-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (src, dst) = (dir.join("cut.mcap"), dir.join("saved.mcap"));
    let mib = 1usize << 20;
    let messages = 256u32;
    {
        let mut w = mcap::WriteOptions::new()
            .compression(None)
            .chunk_size(Some(4 * mib as u64))
            .create(BufWriter::new(std::fs::File::create(&src).unwrap()))
            .unwrap();
        let sid = w.add_schema("blob", "raw", b"bytes").unwrap();
        let ch = w
            .add_channel(sid, "t/blob", "raw", &BTreeMap::new())
            .unwrap();
        let mut payload = vec![0u8; mib];
        for i in 0..messages {
            payload[..4].copy_from_slice(&i.to_le_bytes());
            let header = mcap::records::MessageHeader {
                channel_id: ch,
                sequence: i,
                log_time: u64::from(i),
                publish_time: u64::from(i),
            };
            w.write_to_known_channel(&header, &payload).unwrap();
        }
        w.finish().unwrap();
    }
    let len = std::fs::metadata(&src).unwrap().len();
    assert!(len > 256 * mib as u64);
    // cut inside the last chunks, as a killed writer leaves a file
    let f = std::fs::OpenOptions::new().write(true).open(&src).unwrap();
    f.set_len(len - 6 * mib as u64).unwrap();
    drop(f);
    let before = peak_bytes();
    let saved = fiberflow_recorder::recover::recover(&src, &dst).unwrap();
    let grew = peak_bytes().saturating_sub(before);
    assert!(
        saved >= u64::from(messages) - 12 && saved < u64::from(messages),
        "saved {saved} of {messages}"
    );
    assert!(
        grew < 64 * mib as u64,
        "peak memory grew by {} MiB recovering a {} MiB file",
        grew / mib as u64,
        len / mib as u64
    );
    let ins = fiberflow_recorder::recover::inspect(&dst).unwrap();
    assert!(ins.damage.is_none(), "{:?}", ins.damage);
    assert_eq!(ins.messages, saved);
    std::fs::remove_dir_all(&dir).unwrap();
}
