//! `inspect`, `replay` and `inject`: working with recordings and the live bus.

use anyhow::{bail, Context, Result};
use fiberflow_bus::zenoh_bus::{ZenohBus, ZenohSettings};
use fiberflow_bus::Bus;
use std::path::Path;
use std::time::{Duration, Instant};

pub fn inspect_cmd(path: &Path, recover: bool) -> Result<()> {
    let ins = fiberflow_recorder::recover::inspect(path)
        .with_context(|| format!("reading {}", path.display()))?;
    println!("{}: {} messages", path.display(), ins.messages);
    println!("{:<60} {:<40} {:>8}", "topic", "schema", "count");
    for (t, (s, n)) in &ins.channels {
        println!("{t:<60} {s:<40} {n:>8}");
    }
    for (name, md) in &ins.metadata {
        println!("metadata {name}:");
        for (k, v) in md {
            let v = if v.len() > 70 {
                format!(
                    "{}…",
                    &v[..v.char_indices().nth(70).map(|c| c.0).unwrap_or(v.len())]
                )
            } else {
                v.clone()
            };
            println!("  {k} = {}", v.replace('\n', " "));
        }
    }
    for a in &ins.attachments {
        println!("attachment {a}");
    }
    match &ins.damage {
        None => println!("integrity: complete"),
        Some(d) => println!("integrity: DAMAGED ({d})"),
    }
    if recover {
        let dst = path.with_extension("recovered.mcap");
        let n =
            fiberflow_recorder::recover::recover(path, &dst).map_err(|e| anyhow::anyhow!("{e}"))?;
        println!("recovered {n} messages into {}", dst.display());
    }
    Ok(())
}

fn zenoh(connect: Vec<String>, listen: Vec<String>) -> Result<ZenohBus> {
    let listen = if listen.is_empty() {
        vec!["tcp/127.0.0.1:0".into()]
    } else {
        listen
    };
    let s = ZenohSettings {
        listen,
        connect,
        ..ZenohSettings::default()
    };
    ZenohBus::open(&s).context("opening zenoh session")
}

pub fn replay_cmd(
    path: &Path,
    speed: f64,
    connect: Vec<String>,
    listen: Vec<String>,
) -> Result<()> {
    if !(speed >= 0.0 && speed.is_finite()) {
        bail!("--speed must be >= 0 (got {speed})");
    }
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    let bus = zenoh(connect, listen)?;
    std::thread::sleep(Duration::from_millis(500));
    let start = Instant::now();
    let mut first: Option<u64> = None;
    let mut n = 0u64;
    for m in mcap::MessageStream::new(&bytes)? {
        let m = m?;
        if m.channel.topic.ends_with("/points") {
            continue; // derived by the recorder, not a bus topic
        }
        let t0 = *first.get_or_insert(m.log_time);
        if speed > 0.0 {
            let due = Duration::from_secs_f64((m.log_time - t0) as f64 / 1e9 / speed);
            if let Some(wait) = due.checked_sub(start.elapsed()) {
                std::thread::sleep(wait);
            }
        }
        bus.publish(&m.channel.topic, &m.data)?;
        n += 1;
    }
    println!(
        "replayed {n} messages in {:.1} s",
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

pub fn inject_cmd(
    run: &str,
    connect: Vec<String>,
    topics: &[String],
    count: u64,
    seed: u64,
) -> Result<()> {
    let bus = zenoh(connect, vec![])?;
    std::thread::sleep(Duration::from_millis(500));
    let mut x = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    let mut next = || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        x
    };
    for i in 0..count {
        for t in topics {
            let len = (next() % 512) as usize;
            let payload: Vec<u8> = (0..len).map(|_| next() as u8).collect();
            bus.publish(&format!("fiberflow/{run}/{t}"), &payload)?;
        }
        if i % 1000 == 999 {
            std::thread::sleep(Duration::from_millis(10));
        }
    }
    println!(
        "injected {count} random payloads on each of {} topics",
        topics.len()
    );
    Ok(())
}

/// Prints `<topic> <bytes>` for every message under `pattern`, then a per-topic count.
pub fn echo_cmd(
    pattern: &str,
    connect: Vec<String>,
    listen: Vec<String>,
    count: Option<u64>,
    idle_s: f64,
) -> Result<()> {
    let bus = zenoh(connect, listen)?;
    let sub = bus.subscribe(pattern)?;
    let mut n = 0u64;
    let mut by: std::collections::BTreeMap<String, u64> = Default::default();
    while let Ok((topic, bytes)) = sub
        .rx
        .recv_timeout(Duration::from_secs_f64(idle_s.max(0.1)))
    {
        println!("{topic} {}", bytes.len());
        *by.entry(topic).or_insert(0) += 1;
        n += 1;
        if count.is_some_and(|c| n >= c) {
            break;
        }
    }
    for (t, c) in by {
        println!("total {t} {c}");
    }
    Ok(())
}
