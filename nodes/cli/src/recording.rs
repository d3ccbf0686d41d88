//! `inspect`, `replay` and `inject`: working with recordings and the live bus.

use anyhow::{bail, Context, Result};
use fiberflow_bus::zenoh_bus::{ZenohBus, ZenohSettings};
use fiberflow_bus::Bus;
use std::path::Path;
use std::time::{Duration, Instant};

/// `inspect`: every segment of a run folder (or the one file), then the totals.
pub fn inspect_cmd(path: &Path, recover: bool) -> Result<()> {
    let segs = fiberflow_messages::segments::segment_paths(path)
        .with_context(|| format!("reading {}", path.display()))?;
    if path.is_dir() {
        println!("{}: {} segment(s)", path.display(), segs.len());
    }
    let mut total = 0u64;
    let mut by: std::collections::BTreeMap<String, u64> = Default::default();
    for seg in &segs {
        let (n, counts) = inspect_one(seg, recover)?;
        total += n;
        for (t, c) in counts {
            *by.entry(t).or_insert(0) += c;
        }
    }
    if segs.len() > 1 {
        println!("all segments: {total} messages");
        for (t, n) in &by {
            println!("{t:<60} {n:>8}");
        }
    }
    let mut steps = StateSteps::default();
    for seg in &segs {
        fiberflow_messages::reading::for_each_message(seg, |m| steps.add(m.topic, m.data))
            .with_context(|| format!("reading {}", seg.display()))?;
    }
    for line in steps.report() {
        println!("{line}");
    }
    Ok(())
}

/// The steps of the fibre states a recording holds, per group piece (a group, or one
/// shard's slice of it), over all segments.
#[derive(Default)]
struct StateSteps {
    by_piece: std::collections::BTreeMap<(String, u32), Vec<u64>>,
}

impl StateSteps {
    fn add(&mut self, topic: &str, data: &[u8]) {
        if !topic.ends_with("/state") || !topic.contains("/fibers/") {
            return;
        }
        if let Ok(h) = fiberflow_messages::peek_group_header(data) {
            self.by_piece
                .entry((h.group, h.first_fiber))
                .or_default()
                .push(h.step);
        }
    }

    /// One line per piece: its first and last step, how many states, and whether every
    /// step is there once — steps recorded twice, and steps missing from the piece's
    /// usual stride (the most common step between recorded states, so a decimated
    /// recording is judged by its own spacing).
    fn report(&self) -> Vec<String> {
        let mut out = Vec::new();
        for ((group, first), steps) in &self.by_piece {
            let mut s = steps.clone();
            s.sort_unstable();
            let n = s.len();
            let twice: Vec<u64> = s
                .windows(2)
                .filter(|w| w[0] == w[1])
                .map(|w| w[0])
                .collect();
            s.dedup();
            let mut gaps: std::collections::BTreeMap<u64, usize> = Default::default();
            for w in s.windows(2) {
                *gaps.entry(w[1] - w[0]).or_insert(0) += 1;
            }
            let stride = gaps
                .iter()
                .max_by_key(|(gap, count)| (**count, std::cmp::Reverse(**gap)))
                .map_or(1, |(gap, _)| *gap);
            let mut missing = 0u64;
            let mut first_missing = None;
            for w in s.windows(2) {
                if w[1] - w[0] > stride {
                    missing += (w[1] - w[0]).div_ceil(stride) - 1;
                    first_missing.get_or_insert(w[0] + stride);
                }
            }
            let (lo, hi) = (
                s.first().copied().unwrap_or(0),
                s.last().copied().unwrap_or(0),
            );
            let every = if stride == 1 {
                "step".to_string()
            } else {
                format!("{stride}th step")
            };
            let verdict = if twice.is_empty() && missing == 0 {
                format!("every {every} once")
            } else {
                let mut v = Vec::new();
                if let Some(k) = twice.first() {
                    v.push(format!("{} recorded twice (first: step {k})", twice.len()));
                }
                if let Some(k) = first_missing {
                    v.push(format!("{missing} missing (first: step {k})"));
                }
                v.join(", ")
            };
            out.push(format!(
                "states of {group} from fibre {first}: steps {lo}..={hi}, {n} recorded, {verdict}"
            ));
        }
        out
    }
}

fn inspect_one(path: &Path, recover: bool) -> Result<(u64, Vec<(String, u64)>)> {
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
    let counts = ins
        .channels
        .iter()
        .map(|(t, (_, n))| (t.clone(), *n))
        .collect();
    Ok((ins.messages, counts))
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

/// Whom a publishing command waits for before it starts.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Await {
    /// A subscriber on every topic (the topics were asked for).
    Every,
    /// A subscriber on any topic, then a moment for the rest of its declarations (a
    /// viewer or `echo` of one topic is all there may be).
    Any,
}

/// How long the number of connected peers must stay the same before a publishing command
/// starts (the mesh is complete: [`ZenohBus::await_peers_settled`]).
const PEERS_QUIET: Duration = Duration::from_secs(1);

/// A zenoh session on which every topic of `topics` has a subscriber, or as many as have
/// one after `wait_s` seconds (the others go on without: a topic may have none in this
/// run), and whose links to the run's peers have stopped coming up ([`PEERS_QUIET`]). A
/// session that reached no peer at all by then is opened once more (on a loaded host a
/// first connection attempt has stalled for good), and if that one reaches none either it
/// is an error naming the endpoints: sending into nothing would only look like success.
fn session_with_subscribers(
    connect: &[String],
    listen: &[String],
    topics: &[String],
    wait_s: f64,
    doing: &str,
    need: Await,
) -> Result<ZenohBus> {
    if !(wait_s > 0.0 && wait_s.is_finite()) {
        bail!("--wait-s must be > 0 (got {wait_s})");
    }
    let wait = Duration::from_secs_f64(wait_s);
    eprintln!(
        "waiting up to {wait_s:.0} s for a subscriber to {} of {} topic(s) before {doing}",
        if need == Await::Every { "each" } else { "any" },
        topics.len()
    );
    for attempt in 1..=2 {
        let bus = zenoh(connect.to_vec(), listen.to_vec())?;
        let unheard = match need {
            Await::Every => bus.await_subscribers(topics, wait)?,
            Await::Any => bus.await_any_subscriber(topics, wait, Duration::from_millis(500))?,
        };
        if unheard.len() < topics.len() {
            let peers = bus.await_peers_settled(PEERS_QUIET, wait);
            tracing::info!(peers, "connected to the run's peers");
        }
        if need == Await::Any && unheard.len() < topics.len() {
            if !unheard.is_empty() {
                tracing::info!(
                    without_subscriber = unheard.len(),
                    "{doing} to the subscribers there are (topics nobody subscribes to go nowhere)"
                );
            }
            return Ok(bus);
        }
        if unheard.is_empty() {
            return Ok(bus);
        }
        let peers = bus.connections();
        if peers > 0 {
            tracing::warn!(
                topics = %unheard.join(", "),
                peers,
                "no subscriber after {:.0} s; {doing} anyway",
                wait.as_secs_f64()
            );
            return Ok(bus);
        }
        if attempt == 1 {
            tracing::warn!(
                connect = ?connect,
                listen = ?listen,
                "no peer reached within {:.0} s; trying a new session",
                wait.as_secs_f64()
            );
        }
    }
    bail!(
        "no peer of the run reached (connect {connect:?}, listen {listen:?}) by two sessions, each given {:.0} s once open: is the run still going, and is the endpoint the one in its endpoint.txt?",
        wait.as_secs_f64()
    )
}

/// `replay`: republishes a recording's messages (all, or those on topics matching one of
/// `only`, zenoh key expressions) in their recorded order and timing.
pub fn replay_cmd(
    path: &Path,
    speed: f64,
    connect: Vec<String>,
    listen: Vec<String>,
    wait_s: f64,
    only: &[String],
) -> Result<()> {
    let wanted = |topic: &str| {
        !topic.ends_with("/points") // derived by the recorder, not a bus topic
            && (only.is_empty() || only.iter().any(|p| fiberflow_bus::matches(p, topic)))
    };
    if !(speed >= 0.0 && speed.is_finite()) {
        bail!("--speed must be >= 0 (got {speed})");
    }
    let segs = fiberflow_messages::segments::segment_paths(path)
        .with_context(|| format!("reading {}", path.display()))?;
    // zenoh drops a put whose subscribers it does not know yet: wait until every recorded
    // topic has one (as `inject` does), then a little for the others' declarations
    let mut topics: Vec<String> = Vec::new();
    for seg in &segs {
        fiberflow_messages::reading::for_each_message(seg, |m| {
            if wanted(m.topic) && !topics.iter().any(|t| t == m.topic) {
                topics.push(m.topic.to_string());
            }
        })
        .with_context(|| format!("reading {}", seg.display()))?;
    }
    if topics.is_empty() {
        bail!("no recorded topic matches --topics {}", only.join(" "));
    }
    // topics asked for by name must each be heard; otherwise whoever listens
    let need = if only.is_empty() {
        Await::Any
    } else {
        Await::Every
    };
    let bus = session_with_subscribers(&connect, &listen, &topics, wait_s, "replaying", need)?;
    std::thread::sleep(Duration::from_millis(500));
    let start = Instant::now();
    let mut first: Option<u64> = None;
    let mut n = 0u64;
    // the segments of a resumed run follow each other in time; each holds its steps once
    for seg in &segs {
        // streamed a chunk at a time; the first failure to publish ends the replay
        let mut failed: Option<fiberflow_bus::BusError> = None;
        let stopped = fiberflow_messages::reading::for_each_message(seg, |m| {
            if failed.is_some() || !wanted(m.topic) {
                return;
            }
            let t0 = *first.get_or_insert(m.log_time_nanos);
            if speed > 0.0 {
                let due = Duration::from_secs_f64(
                    m.log_time_nanos.saturating_sub(t0) as f64 / 1e9 / speed,
                );
                if let Some(wait) = due.checked_sub(start.elapsed()) {
                    std::thread::sleep(wait);
                }
            }
            match bus.publish(m.topic, m.data) {
                Ok(()) => n += 1,
                Err(e) => failed = Some(e),
            }
        })
        .with_context(|| format!("reading {}", seg.display()))?;
        if let Some(e) = failed {
            return Err(e).context("publishing a recorded message");
        }
        if let Some(why) = stopped {
            tracing::warn!(segment = %seg.display(), reason = %why, "the segment ends early; replayed what came before");
        }
    }
    println!(
        "replayed {n} messages in {:.1} s",
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

/// `inject`: random byte strings, or (`structured`) valid CDR of each topic's type whose
/// content breaks a rule receivers check (see `fiberflow_messages::fuzz`).
pub fn inject_cmd(
    run: &str,
    connect: Vec<String>,
    topics: &[String],
    count: u64,
    seed: u64,
    structured: bool,
    wait_s: f64,
) -> Result<()> {
    let mut rng = fiberflow_messages::fuzz::Rng::new(seed);
    let full: Vec<String> = topics
        .iter()
        .map(|t| format!("fiberflow/{run}/{t}"))
        .collect();
    // what is sent before the run's subscriptions are known here would go nowhere
    let bus = session_with_subscribers(&connect, &[], &full, wait_s, "injecting", Await::Every)?;
    // the run's group names, so that structured messages also name real groups
    let groups: Vec<String> = full
        .iter()
        .filter_map(|t| {
            let p: Vec<&str> = t.split('/').collect();
            match (p.get(2), p.get(4)) {
                (Some(&"fibers"), _) => p.get(3).map(|g| g.to_string()),
                (Some(&"flow"), Some(g)) => Some(g.to_string()),
                _ => None,
            }
        })
        .collect();
    for t in &full {
        if structured && fiberflow_messages::topics::kind_of(t).is_none() {
            bail!("--structured: {t} carries no message type");
        }
    }
    for i in 0..count {
        for t in &full {
            let payload = match fiberflow_messages::topics::kind_of(t) {
                Some(ty) if structured => {
                    fiberflow_messages::fuzz::nonsense_payload(ty, &mut rng, &groups)
                }
                _ => {
                    let len = rng.below(512) as usize;
                    (0..len).map(|_| rng.next_u64() as u8).collect()
                }
            };
            bus.publish(t, &payload)?;
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

/// Prints every message under `pattern` — its decoded fields (`decoded`: the values shown
/// of a long array), or with `None` only `<topic> <bytes>` — then a per-topic count;
/// waits up to `wait_s` for the first message (a publisher may take a while to start),
/// then stops after `idle_s` without one.
pub fn echo_cmd(
    pattern: &str,
    connect: Vec<String>,
    listen: Vec<String>,
    count: Option<u64>,
    idle_s: f64,
    wait_s: f64,
    decoded: Option<usize>,
) -> Result<()> {
    let bus = zenoh(connect, listen)?;
    let sub = bus.subscribe(pattern)?;
    let mut n = 0u64;
    let mut by: std::collections::BTreeMap<String, u64> = Default::default();
    while let Ok((topic, bytes)) = sub.rx.recv_timeout(Duration::from_secs_f64(
        if n == 0 { wait_s } else { idle_s }.max(0.1),
    )) {
        match decoded {
            // as `ros2 topic echo`: the fields, long arrays shortened
            Some(items) => match fiberflow_messages::echo::echo_text(&topic, &bytes, items) {
                Ok(text) => print!("topic: {topic}\n{text}"),
                Err(e) => println!("topic: {topic}\n({} bytes: {e})\n---", bytes.len()),
            },
            None => println!("{topic} {}", bytes.len()),
        }
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

#[cfg(test)]
mod tests {
    use super::*;

    fn steps_of(pieces: &[(&str, u32, &[u64])]) -> Vec<String> {
        let mut s = StateSteps::default();
        for (g, first, steps) in pieces {
            s.by_piece.insert((g.to_string(), *first), steps.to_vec());
        }
        s.report()
    }

    /// Every step once, a decimated recording judged by its own stride, a step twice and
    /// steps missing, each piece of a sharded group on its own line.
    #[test]
    fn the_steps_report_says_what_is_twice_or_missing() {
        let r = steps_of(&[
            ("case1", 0, &[0, 1, 2, 3, 4]),
            ("case1", 25, &[0, 10, 20, 30]),
            ("stiff", 0, &[0, 1, 1, 2, 6, 7]),
        ]);
        assert_eq!(
            r,
            vec![
                "states of case1 from fibre 0: steps 0..=4, 5 recorded, every step once",
                "states of case1 from fibre 25: steps 0..=30, 4 recorded, every 10th step once",
                "states of stiff from fibre 0: steps 0..=7, 6 recorded, 1 recorded twice (first: step 1), 3 missing (first: step 3)",
            ]
        );
    }
}
