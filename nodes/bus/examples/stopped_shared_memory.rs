//! Do zenoh shared-memory messages in flight survive their processes being stopped and
//! continued (`SIGSTOP`, `SIGCONT`: what `fiberflow-bench scale --slice-ms` does to run
//! configurations in turns, and what a suspended launch gets)?
//!
//! `cargo run --release -p fiberflow-bus --example stopped_shared_memory -- MODE CYCLES`
//! starts a receiver and a sender process on this host (zenoh over loopback). The sender
//! publishes a 40 kB message (this bus's shared memory) every millisecond. Each cycle stops
//! the receiver, lets the sender publish 5 ms more (messages in flight, unread), stops the
//! sender too (`MODE` = `both`) or not (`receiver`), waits 300 ms, and continues both.
//! Prints how many messages the receiver got of those sent, and which were missing.

use fiberflow_bus::zenoh_bus::{ZenohBus, ZenohSettings};
use fiberflow_bus::Bus;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const ROLE: &str = "FIBERFLOW_STOP_ROLE";
const ENDPOINT: &str = "FIBERFLOW_STOP_ENDPOINT";
const TOPIC: &str = "stop/t";
const END: &str = "stop/end";
const SEND_MS: &str = "FIBERFLOW_STOP_SEND_MS";
const BYTES: usize = 40_000;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    match std::env::var(ROLE).as_deref() {
        Ok("receive") => receive(&std::env::var(ENDPOINT)?),
        Ok("send") => send(
            &std::env::var(ENDPOINT)?,
            Duration::from_millis(std::env::var(SEND_MS)?.parse()?),
        ),
        _ => orchestrate(),
    }
}

/// Counts the messages by sequence number until the sender's end message says how many
/// it sent; prints the tally.
fn receive(endpoint: &str) -> Result<(), Box<dyn std::error::Error>> {
    let bus = ZenohBus::open(&ZenohSettings {
        listen: vec![endpoint.to_string()],
        ..ZenohSettings::default()
    })?;
    let sub = bus.subscribe("stop/**")?;
    let mut seen = std::collections::BTreeSet::new();
    let mut shared = 0usize;
    loop {
        let (topic, payload) = sub.rx.recv_timeout(Duration::from_secs(120))?;
        let seq = u64::from_le_bytes(payload[..8].try_into()?);
        if topic == END {
            let missing: Vec<u64> = (0..seq).filter(|s| !seen.contains(s)).collect();
            println!(
                "received {} of {seq} ({shared} in shared memory); missing {}: {:?}",
                seen.len(),
                missing.len(),
                &missing[..missing.len().min(20)]
            );
            return Ok(());
        }
        shared += usize::from(payload.is_shared());
        seen.insert(seq);
    }
}

/// Publishes one numbered message a millisecond for `send_for` of its own running time,
/// then the count.
fn send(endpoint: &str, send_for: Duration) -> Result<(), Box<dyn std::error::Error>> {
    let bus = ZenohBus::open(&ZenohSettings {
        connect: vec![endpoint.to_string()],
        ..ZenohSettings::default()
    })?;
    let missing = bus.await_subscribers(&[TOPIC.to_string()], Duration::from_secs(20))?;
    if !missing.is_empty() {
        return Err("no receiver".into());
    }
    let mut seq = 0u64;
    let mut ran = Duration::ZERO;
    let mut last = Instant::now();
    while ran < send_for {
        let mut m = vec![7u8; BYTES];
        m[..8].copy_from_slice(&seq.to_le_bytes());
        bus.publish_message(TOPIC, &m)?;
        seq += 1;
        std::thread::sleep(Duration::from_millis(1));
        // time spent stopped does not count
        let step = last.elapsed();
        last = Instant::now();
        if step < Duration::from_millis(50) {
            ran += step;
        }
    }
    std::thread::sleep(Duration::from_secs(1));
    bus.publish(END, &seq.to_le_bytes())?;
    std::thread::sleep(Duration::from_secs(1));
    Ok(())
}

fn signal(pid: u32, sig: i32) {
    // SAFETY: plain syscall on a child's pid
    unsafe {
        libc::kill(pid as i32, sig);
    }
}

/// Starts both roles and stops and continues them in cycles.
fn orchestrate() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let both = match args.get(1).map(String::as_str) {
        Some("both") => true,
        Some("receiver") => false,
        _ => return Err("usage: stopped_shared_memory both|receiver [CYCLES]".into()),
    };
    let cycles: u32 = args.get(2).map(|c| c.parse()).transpose()?.unwrap_or(10);
    let port = std::net::TcpListener::bind("127.0.0.1:0")?
        .local_addr()?
        .port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let exe = std::env::current_exe()?;
    let receiver = Command::new(&exe)
        .env(ROLE, "receive")
        .env(ENDPOINT, &endpoint)
        .stdout(Stdio::piped())
        .spawn()?;
    std::thread::sleep(Duration::from_millis(500));
    // sending all through the cycles and one second after
    let send_ms = 3_000 + 510 * u64::from(cycles);
    let mut sender = Command::new(&exe)
        .env(ROLE, "send")
        .env(ENDPOINT, &endpoint)
        .env(SEND_MS, send_ms.to_string())
        .spawn()?;
    std::thread::sleep(Duration::from_secs(2));
    for _ in 0..cycles {
        signal(receiver.id(), libc::SIGSTOP);
        std::thread::sleep(Duration::from_millis(5));
        if both {
            signal(sender.id(), libc::SIGSTOP);
        }
        std::thread::sleep(Duration::from_millis(300));
        if both {
            signal(sender.id(), libc::SIGCONT);
        }
        signal(receiver.id(), libc::SIGCONT);
        std::thread::sleep(Duration::from_millis(200));
    }
    sender.wait()?;
    let out = receiver.wait_with_output()?;
    print!("{}", String::from_utf8_lossy(&out.stdout));
    Ok(())
}
