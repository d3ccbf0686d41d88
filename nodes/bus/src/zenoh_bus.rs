//! zenoh transport (peer mode). Secure defaults: listens on loopback only, multicast
//! scouting off; peers find each other by connecting to the run's rendezvous endpoint.
//! Multi-host runs add TLS (mutual: every peer presents a certificate signed by the run's
//! CA) and zenoh access control (only peers whose certificate common name is listed may
//! publish or subscribe under the run's key prefix; everything else is denied).
//!
//! Large messages go through zenoh shared memory: [`Bus::publish_message`] encodes a
//! message of [`SHM_MIN_BYTES`] or more straight into a buffer of this process's pools,
//! and a subscriber on the same host receives it in place ([`Payload::shared`]). Between
//! hosts zenoh sends the same buffer over the network. The pools grow with what is in
//! flight: when none has room (after reclaiming the buffers every receiver has let go
//! of), another of [`shm_pool_bytes`] is added, up to [`SHM_MAX_BYTES`] per process
//! (a pool's pages all take memory). Without usable shared memory (no /dev/shm, the
//! limit reached) a message is encoded into an ordinary buffer instead, so nothing
//! depends on it. The bus holds every message it sent from shared memory until its
//! receivers have taken it, and a closing bus waits for that ([`CLOSE_WAIT_FOR_RECEIVERS`]),
//! so a publisher that exits at once loses none. Smaller
//! messages travel in the session's own buffers: zenoh's implicit shared memory (on by
//! default for 3 kB and more) is off, since it has no such hold.
//!
//! Size (≈ 610 lines before the tests): the session's set-up (TLS, access control) and the
//! shared-memory pools it publishes through are one transport.

use crate::{Bus, BusError, Outgoing, Payload, Subscription};
use std::sync::mpsc::channel;
use std::sync::Mutex;
use zenoh::bytes::ZBytes;
use zenoh::shm::{
    zshmmut, GarbageCollect, PosixShmProviderBackend, ShmBuf, ShmProvider, ShmProviderBuilder, ZShm,
};
use zenoh::Wait;

/// Messages from this size on are written into shared memory (smaller ones are cheaper
/// to copy than to hand over as a shared buffer). 16 KiB puts a 50-fibre group's ≈ 34 kB
/// samples and states there (the choice against 64 KiB: docs/history/performance.md,
/// "Coupling overhead at paper size").
pub const SHM_MIN_BYTES: usize = 16 * 1024;

/// How long a peer's open waits for the rendezvous it connects to and for the peers that
/// rendezvous tells it of (zenoh's `scouting/delay` and `connect/timeout_ms`).
pub const PEER_OPEN_WAIT_MS: u64 = 15_000;

/// Shared memory one process may take for its messages in flight.
pub const SHM_MAX_BYTES: usize = 2 << 30;

/// The smallest shared-memory pool.
pub const SHM_MIN_POOL_BYTES: usize = 32 << 20;

/// zenoh's runtime (`ZENOH_RUNTIME`, zenoh's RON syntax) with its five thread pools — `rx`
/// (two workers), `tx`, `acc`, `net`, `app` — handed over to the one worker of `acc`.
/// A link's socket waits in the poller of the pool that opened it while the receive and
/// transmit tasks ran on pools of their own, so every batch woke two or three threads,
/// each wake-up preempting a DNS pool thread on a busy core; on one worker the poller
/// runs the tasks itself. The launcher starts the nodes of a one-host zenoh run with it
/// (measured: docs/history/performance.md, "Coupling overhead at paper size"). Test
/// `one_thread_runtime_carries_messages_on_one_thread`.
pub const ONE_THREAD_RUNTIME: &str =
    "(rx: (handover: acc), tx: (handover: acc), net: (handover: acc), app: (handover: acc))";

/// The size of a pool added for a message of `bytes` that found no room: four such
/// messages, at least `min_bytes`.
pub fn shm_pool_bytes(bytes: usize, min_bytes: usize) -> usize {
    (4 * bytes).max(min_bytes)
}

/// This process's shared-memory pools (none until the first large message), or shared
/// memory not available here.
struct Shm {
    pools: Vec<ShmProvider<PosixShmProviderBackend>>,
    /// This process's hold on every message it sent from shared memory that a receiver
    /// has not yet taken and let go of (see [`Shm::release_taken`]).
    in_flight: Vec<ZShm>,
    bytes: usize,
    min_pool_bytes: usize,
    max_bytes: usize,
    unavailable: bool,
}

impl Shm {
    fn new(min_pool_bytes: usize, max_bytes: usize) -> Self {
        let lockable = may_lock_memory();
        if !lockable {
            tracing::info!(
                "no zenoh shared memory: large messages are copied (pools are locked in memory: \
                 needs CAP_IPC_LOCK or an unlimited `ulimit -l`)"
            );
        }
        Self {
            pools: Vec::new(),
            in_flight: Vec::new(),
            bytes: 0,
            min_pool_bytes,
            max_bytes,
            unavailable: !lockable,
        }
    }

    /// Lets go of the sent messages every receiver has taken and let go of (this
    /// process's hold is the only one left), and of any zenoh no longer counts as valid.
    /// One sent to a receiver that died stays held (its count is never given back, so the
    /// pool could not reuse it before either), and a closing bus gives up on it after
    /// [`CLOSE_WAIT_FOR_RECEIVERS`]. A closing bus waits until none is held: a message's buffer,
    /// and the metadata that makes it readable, live in this process, so one that exited
    /// before its receivers had read what it sent lost it (test
    /// `a_publisher_process_that_exits_at_once_loses_nothing`; waiting for the pools'
    /// free bytes instead did not help). Returns how many are held.
    fn release_taken(&mut self) -> usize {
        self.in_flight.retain_mut(|m| {
            let alone = <&mut zshmmut>::try_from(&mut *m).is_ok();
            !alone && ShmBuf::is_valid(&*m)
        });
        self.in_flight.len()
    }

    /// A buffer of `len` bytes from a pool with room, or from a new pool while the limit
    /// allows; None otherwise.
    fn buffer(&mut self, len: usize) -> Option<zenoh::shm::ZShmMut> {
        if self.unavailable {
            return None;
        }
        self.release_taken();
        for pool in &self.pools {
            if let Ok(buf) = pool.alloc(len).with_policy::<GarbageCollect>().wait() {
                return Some(buf);
            }
        }
        let size = shm_pool_bytes(len, self.min_pool_bytes);
        if self.bytes + size > self.max_bytes {
            tracing::debug!(len, "zenoh shared memory at its limit: copying");
            return None;
        }
        match ShmProviderBuilder::default_backend(size).wait() {
            Ok(pool) => {
                tracing::info!(
                    mib = size >> 20,
                    in_use_mib = (self.bytes + size) >> 20,
                    "zenoh shared-memory pool added"
                );
                let buf = pool.alloc(len).wait().ok();
                self.pools.push(pool);
                self.bytes += size;
                buf
            }
            Err(e) => {
                tracing::info!(error = %e, "no zenoh shared memory: large messages are copied");
                self.unavailable = true;
                None
            }
        }
    }
}

/// True if this process may lock as much memory as its pools and the pools it maps from
/// other processes take. zenoh locks every segment it makes or maps (`mlock`); a receiver
/// that cannot lock a sender's segment loses that message, so with a limited `ulimit -l`
/// no process of the run writes into shared memory at all (they share their limits).
fn may_lock_memory() -> bool {
    let mut limit = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit only writes the struct it is given
    let unlimited = unsafe { libc::getrlimit(libc::RLIMIT_MEMLOCK, &mut limit) } == 0
        && limit.rlim_cur == libc::RLIM_INFINITY;
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    unlimited || has_ipc_lock(&status)
}

/// True if the `CapEff:` line of a `/proc/<pid>/status` text has CAP_IPC_LOCK (bit 14).
fn has_ipc_lock(status: &str) -> bool {
    status
        .lines()
        .find_map(|l| l.strip_prefix("CapEff:"))
        .and_then(|hex| u64::from_str_radix(hex.trim(), 16).ok())
        .is_some_and(|caps| caps & (1 << 14) != 0)
}

/// A received message still in the publisher's shared memory (one contiguous buffer).
struct InPlace(ZBytes);

impl AsRef<[u8]> for InPlace {
    fn as_ref(&self) -> &[u8] {
        self.0.slices().next().unwrap_or(&[])
    }
}

/// Connection settings of one node.
#[derive(Debug, Clone, PartialEq)]
pub struct ZenohSettings {
    /// Endpoints to listen on, e.g. `tcp/127.0.0.1:0`.
    pub listen: Vec<String>,
    /// Endpoints to connect to (the rendezvous peer).
    pub connect: Vec<String>,
    /// Multicast scouting (off by default: nothing is announced on the LAN).
    pub multicast_scouting: bool,
    /// TLS certificates for `tls/...` endpoints.
    pub tls: Option<TlsFiles>,
    /// Access control: who may use which key expressions.
    pub access: Option<AccessControl>,
    /// Session role: peers mesh on one host; across hosts one router and clients.
    pub mode: ZenohMode,
}

/// The zenoh session role.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ZenohMode {
    #[default]
    Peer,
    Router,
    Client,
}

/// PEM files of one peer's TLS identity.
#[derive(Debug, Clone, PartialEq)]
pub struct TlsFiles {
    /// The CA that signed every peer's certificate.
    pub root_ca_certificate: String,
    /// This peer's certificate (used both when listening and when connecting).
    pub certificate: String,
    pub private_key: String,
    /// Require a client certificate from connecting peers (mutual TLS).
    pub mutual: bool,
}

/// zenoh access control for one run: deny by default, allow put/delete/subscribe under
/// `key_prefix/**` to peers whose TLS certificate common name is in `common_names`.
#[derive(Debug, Clone, PartialEq)]
pub struct AccessControl {
    pub key_prefix: String,
    pub common_names: Vec<String>,
}

impl Default for ZenohSettings {
    fn default() -> Self {
        Self {
            listen: vec!["tcp/127.0.0.1:0".into()],
            connect: vec![],
            multicast_scouting: false,
            tls: None,
            access: None,
            mode: ZenohMode::Peer,
        }
    }
}

impl AccessControl {
    /// The `access_control` block of the zenoh configuration (JSON).
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "enabled": true,
            "default_permission": "deny",
            "rules": [{
                "id": "run",
                "permission": "allow",
                "flows": ["ingress", "egress"],
                "messages": ["put", "delete", "declare_subscriber"],
                "key_exprs": [format!("{}/**", self.key_prefix)],
            }],
            "subjects": [{ "id": "members", "cert_common_names": self.common_names }],
            "policies": [{ "id": "members-run", "rules": ["run"], "subjects": ["members"] }],
        })
    }
}

/// A zenoh session used as a bus.
pub struct ZenohBus {
    session: zenoh::Session,
    shm: Mutex<Shm>,
}

fn terr<E: std::fmt::Display>(e: E) -> BusError {
    BusError::Transport(e.to_string())
}

impl ZenohBus {
    pub fn open(s: &ZenohSettings) -> Result<Self, BusError> {
        let mut c = zenoh::Config::default();
        let list = |v: &[String]| serde_json::to_string(v).unwrap_or_else(|_| "[]".into());
        let mode = match s.mode {
            ZenohMode::Peer => "\"peer\"",
            ZenohMode::Router => "\"router\"",
            ZenohMode::Client => "\"client\"",
        };
        c.insert_json5("mode", mode).map_err(terr)?;
        c.insert_json5("listen/endpoints", &list(&s.listen))
            .map_err(terr)?;
        c.insert_json5("connect/endpoints", &list(&s.connect))
            .map_err(terr)?;
        c.insert_json5(
            "scouting/multicast/enabled",
            if s.multicast_scouting {
                "true"
            } else {
                "false"
            },
        )
        .map_err(terr)?;
        if s.mode == ZenohMode::Peer && !s.connect.is_empty() {
            // a peer's open waits for its connections (and the peers they tell it of) at
            // most this long (15 s): on a busy machine zenoh's default (500 ms) runs out
            // before a healthy rendezvous answers (docs/history/performance.md, "From the
            // code's comments"). Open returns as soon as it is connected.
            c.insert_json5("scouting/delay", &PEER_OPEN_WAIT_MS.to_string())
                .map_err(terr)?;
            // connect to the rendezvous inside open, not in a background task: zenoh
            // 1.10's background connector records the peer it reached only after the
            // connection is up, and when the peer's first declarations come before that
            // (several sessions opening at once, or a loaded host) open misses them and
            // waits out the whole delay above ("Scouting delay elapsed before start
            // conditions are met"; `tests::sessions_opened_together_connect_at_once`).
            // Open fails if the rendezvous does not answer within the same time.
            c.insert_json5("connect/exit_on_failure", "true")
                .map_err(terr)?;
            c.insert_json5("connect/timeout_ms", &PEER_OPEN_WAIT_MS.to_string())
                .map_err(terr)?;
        }
        // lockstep messages are sent with CongestionControl::Block: a link whose queue stays
        // full for this long is closed and its message lost. zenoh's 5 s is too short for
        // tens-of-MB messages on a loaded host; a stuck run is caught by the step timeout
        c.insert_json5(
            "transport/link/tx/queue/congestion_control/block/wait_before_close",
            "60000000",
        )
        .map_err(terr)?;
        // a link silent for the lease is closed (zenoh's default 10 s). Once, a 10 s
        // partition left the two ends out of step: the client had closed and reconnected
        // while the router, its queue to the old link blocked, still held the old face,
        // refused the client's declarations again ("Resource remapped") and the
        // reconnected node was never heard (three hosts, 6 x 10^4 fibres;
        // docs/architecture.md; not seen again in later runs, with either lease). With
        // 30 s, TCP carries a partition shorter than that through on the same link, and
        // the ends cannot close it one at a time; a link gone for longer is found by the
        // flow node's liveness check (run.liveness_s, 30 s by default) as its silent nodes
        c.insert_json5("transport/link/tx/lease", "30000")
            .map_err(terr)?;
        if s.mode == ZenohMode::Client {
            // a client (a node on another host) may start before the router it connects
            // to listens: keep trying for a minute instead of failing at once (zenoh's
            // client default); open returns as soon as the router answers
            c.insert_json5("connect/timeout_ms", "60000")
                .map_err(terr)?;
        }
        if let Some(t) = &s.tls {
            let q = |v: &str| serde_json::to_string(v).unwrap_or_else(|_| "\"\"".into());
            for (key, val) in [
                ("root_ca_certificate", &t.root_ca_certificate),
                ("listen_certificate", &t.certificate),
                ("listen_private_key", &t.private_key),
                ("connect_certificate", &t.certificate),
                ("connect_private_key", &t.private_key),
            ] {
                c.insert_json5(&format!("transport/link/tls/{key}"), &q(val))
                    .map_err(terr)?;
            }
            c.insert_json5(
                "transport/link/tls/enable_mtls",
                if t.mutual { "true" } else { "false" },
            )
            .map_err(terr)?;
        }
        if let Some(a) = &s.access {
            c.insert_json5("access_control", &a.to_json().to_string())
                .map_err(terr)?;
        }
        c.insert_json5("transport/shared_memory/enabled", "true")
            .map_err(terr)?;
        // zenoh's own shared memory for messages of 3 kB and more: off. Its buffers go
        // with the publishing process, so what a process sent just before exiting was
        // lost when the receiver came to it late (test
        // `a_publisher_process_that_exits_at_once_loses_nothing`); messages below
        // SHM_MIN_BYTES now travel in the session's buffers, which its close sends on
        c.insert_json5(
            "transport/shared_memory/transport_optimization/enabled",
            "false",
        )
        .map_err(terr)?;
        let session = zenoh::open(c).wait().map_err(terr)?;
        Ok(Self {
            session,
            shm: Mutex::new(Shm::new(SHM_MIN_POOL_BYTES, SHM_MAX_BYTES)),
        })
    }

    /// The endpoints this session listens on, as the OS bound them (a `:0` port in the
    /// settings becomes the port it got): what a peer connects to. A node that listens on
    /// an ephemeral port and reports it holds the port from the moment it is chosen, so
    /// no other process can take it between choosing and binding.
    pub fn listening_endpoints(&self) -> Vec<String> {
        self.session
            .info()
            .locators()
            .wait()
            .iter()
            .map(|l| l.to_string())
            .collect()
    }

    /// How many zenoh peers and routers this session is connected to now.
    pub fn connections(&self) -> usize {
        let info = self.session.info();
        info.peers_zid().wait().count() + info.routers_zid().wait().count()
    }

    /// Waits until the number of peers this session is connected to has not changed for
    /// `quiet` (at most `timeout`); returns it. A session that joined a mesh through its
    /// rendezvous connects to the other peers as it hears of them: a topic can match the
    /// rendezvous's subscriber while another subscriber's link is still coming up, and
    /// what is sent before that link is up never reaches it. (Once, under CI load, a run's
    /// recorder counted 9974 of 10⁴ messages injected on each of nine topics, the same
    /// on every topic: a window of ≈ 3 ms of the 1.3 s injection, most likely its start.)
    pub fn await_peers_settled(
        &self,
        quiet: std::time::Duration,
        timeout: std::time::Duration,
    ) -> usize {
        let deadline = std::time::Instant::now() + timeout;
        let mut peers = self.connections();
        let mut since = std::time::Instant::now();
        while since.elapsed() < quiet && std::time::Instant::now() < deadline {
            std::thread::sleep(std::time::Duration::from_millis(50));
            let now = self.connections();
            if now != peers {
                peers = now;
                since = std::time::Instant::now();
            }
        }
        peers
    }

    /// Waits until every topic has at least one subscriber this session knows of (zenoh
    /// drops a put for which it knows none, so a tool that publishes right after opening
    /// loses what it sends before the peers' declarations arrive); returns the topics
    /// still without one when `timeout` runs out.
    pub fn await_subscribers(
        &self,
        topics: &[String],
        timeout: std::time::Duration,
    ) -> Result<Vec<String>, BusError> {
        self.await_matching(topics, timeout, false)
    }

    /// Waits until at least one of `topics` has a subscriber, then `settle` longer for the
    /// declarations that come with it (a subscriber process declares its topics together),
    /// at most `timeout` in all. Returns the topics that still have none (all of them if
    /// none was heard in time).
    pub fn await_any_subscriber(
        &self,
        topics: &[String],
        timeout: std::time::Duration,
        settle: std::time::Duration,
    ) -> Result<Vec<String>, BusError> {
        let missing = self.await_matching(topics, timeout, true)?;
        if missing.len() == topics.len() {
            return Ok(missing);
        }
        std::thread::sleep(settle);
        self.await_matching(topics, std::time::Duration::ZERO, false)
    }

    /// The topics without a subscriber once every one has one (`any`: once one has one),
    /// or at `timeout`.
    fn await_matching(
        &self,
        topics: &[String],
        timeout: std::time::Duration,
        any: bool,
    ) -> Result<Vec<String>, BusError> {
        let publishers = topics
            .iter()
            .map(|t| {
                self.session
                    .declare_publisher(t.clone())
                    .wait()
                    .map_err(terr)
            })
            .collect::<Result<Vec<_>, _>>()?;
        let deadline = std::time::Instant::now() + timeout;
        loop {
            let mut missing = Vec::new();
            for (t, p) in topics.iter().zip(&publishers) {
                if !p.matching_status().wait().map_err(terr)?.matching() {
                    missing.push(t.clone());
                }
            }
            let heard_enough = if any {
                missing.len() < topics.len()
            } else {
                missing.is_empty()
            };
            if heard_enough || std::time::Instant::now() >= deadline {
                return Ok(missing);
            }
            std::thread::sleep(std::time::Duration::from_millis(50));
        }
    }
}

impl ZenohBus {
    /// A shared-memory buffer of exactly `len` bytes, or None when shared memory is not
    /// available or at its limit.
    fn shm_buffer(&self, len: usize) -> Result<Option<zenoh::shm::ZShmMut>, BusError> {
        let mut shm = self
            .shm
            .lock()
            .map_err(|_| BusError::Transport("zenoh shared-memory lock poisoned".into()))?;
        Ok(shm.buffer(len))
    }

    /// Holds a message about to be sent from shared memory until its receivers have
    /// taken it ([`Shm::release_taken`]).
    fn hold(&self, sent: ZShm) -> Result<(), BusError> {
        self.shm
            .lock()
            .map_err(|_| BusError::Transport("zenoh shared-memory lock poisoned".into()))?
            .in_flight
            .push(sent);
        Ok(())
    }

    /// Puts `payload` on `topic`; lockstep coupling must never lose a message, so a full
    /// queue blocks instead of dropping.
    fn put(&self, topic: &str, payload: Vec<u8>) -> Result<(), BusError> {
        self.session
            .put(topic, payload)
            .congestion_control(zenoh::qos::CongestionControl::Block)
            .wait()
            .map_err(terr)
    }
}

/// How long a closing bus waits for its receivers to take what it sent from shared memory.
pub const CLOSE_WAIT_FOR_RECEIVERS: std::time::Duration = std::time::Duration::from_secs(10);

impl Drop for ZenohBus {
    /// Waits (at most [`CLOSE_WAIT_FOR_RECEIVERS`]) until every message this process sent
    /// from shared memory has been taken: its buffers and their metadata live in this
    /// process, so a process that exited at once lost what its receivers had not read yet.
    fn drop(&mut self) {
        let Ok(shm) = self.shm.get_mut() else {
            return;
        };
        let deadline = std::time::Instant::now() + CLOSE_WAIT_FOR_RECEIVERS;
        let mut held = shm.release_taken();
        while held > 0 && std::time::Instant::now() < deadline {
            std::thread::sleep(std::time::Duration::from_millis(2));
            held = shm.release_taken();
        }
        if held > 0 {
            tracing::warn!(
                messages = held,
                "closing zenoh bus: receivers never took these shared-memory messages"
            );
        }
    }
}

impl Bus for ZenohBus {
    fn publish(&self, topic: &str, payload: &[u8]) -> Result<(), BusError> {
        self.put(topic, payload.to_vec())
    }

    /// Encoded into a shared-memory buffer when large (see the module's doc), else into
    /// one buffer that zenoh then owns; no second copy either way.
    fn publish_message(&self, topic: &str, msg: &dyn Outgoing) -> Result<(), BusError> {
        let len = msg.len();
        if len >= SHM_MIN_BYTES {
            if let Some(mut buf) = self.shm_buffer(len)? {
                if !msg.write(&mut buf[..len]) {
                    return Err(crate::unwritable(topic));
                }
                let sent = ZShm::from(buf);
                self.hold(sent.clone())?;
                return self
                    .session
                    .put(topic, sent)
                    .congestion_control(zenoh::qos::CongestionControl::Block)
                    .wait()
                    .map_err(terr);
            }
        }
        let mut buf = vec![0u8; len];
        if !msg.write(&mut buf) {
            return Err(crate::unwritable(topic));
        }
        self.put(topic, buf)
    }

    fn subscribe(&self, pattern: &str) -> Result<Subscription, BusError> {
        let (tx, rx) = channel();
        let sub = self
            .session
            .declare_subscriber(pattern)
            .callback(move |sample| {
                let topic = sample.key_expr().as_str().to_string();
                let payload = sample.payload();
                // a shared-memory buffer is handed over in place, anything else copied
                let bytes = if payload.as_shm().is_some() && payload.slices().count() == 1 {
                    Payload::shared(Box::new(InPlace(payload.clone())))
                } else {
                    payload.to_bytes().into_owned().into()
                };
                let _ = tx.send((topic, bytes));
            })
            .wait()
            .map_err(terr)?;
        Ok(Subscription::new(rx, Some(Box::new(sub))))
    }

    fn name(&self) -> &'static str {
        "zenoh"
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::Counting;
    use std::time::Duration;

    /// CAP_IPC_LOCK is read from the effective capability set.
    #[test]
    fn ipc_lock_is_read_from_the_status() {
        let status = |caps: &str| format!("Name:\tx\nCapInh:\t0000000000000000\nCapEff:\t{caps}\n");
        assert!(has_ipc_lock(&status("000001ffffffffff")));
        assert!(has_ipc_lock(&status("0000000000004000")));
        assert!(!has_ipc_lock(&status("0000000000003fff")));
        assert!(!has_ipc_lock("CapInh:\t0000000000004000\n"));
        assert!(!has_ipc_lock(&status("garbage")));
    }

    /// A session listening on an ephemeral loopback port, with the endpoint it got.
    fn listening_session() -> (ZenohBus, String) {
        let bus = ZenohBus::open(&ZenohSettings::default()).unwrap();
        let endpoints = bus.listening_endpoints();
        assert_eq!(endpoints.len(), 1, "{endpoints:?}");
        let endpoint = endpoints[0].clone();
        (bus, endpoint)
    }

    /// Sessions opened together connect without waiting out the open delay: sixteen pairs
    /// opened on sixteen threads at the same moment, in a child process (this test binary run
    /// again) that logs zenoh's warnings, each carry a message, and zenoh never warns
    /// "Scouting delay elapsed before start conditions are met" — its sign of an open that
    /// missed the rendezvous's first declarations and waited out [`PEER_OPEN_WAIT_MS`].
    /// With zenoh's background connector (before `connect/exit_on_failure`) it warned in
    /// four runs of five of this test, and in none of five with it.
    #[test]
    fn sessions_opened_together_connect_at_once() {
        const CHILD: &str = "FIBERFLOW_TEST_TOGETHER_CHILD";
        if std::env::var(CHILD).is_ok() {
            let _ = tracing_subscriber::fmt()
                .with_env_filter(tracing_subscriber::EnvFilter::new("zenoh=warn"))
                .with_writer(std::io::stderr)
                .try_init();
            let pairs: Vec<_> = (0..16).map(|_| listening_session()).collect();
            let barrier = std::sync::Arc::new(std::sync::Barrier::new(pairs.len()));
            let opened: Vec<_> = pairs
                .iter()
                .map(|(_, endpoint)| {
                    let (endpoint, barrier) = (endpoint.clone(), barrier.clone());
                    std::thread::spawn(move || {
                        barrier.wait();
                        connected_session(endpoint)
                    })
                })
                .collect();
            for (i, (handle, (a, _))) in opened.into_iter().zip(&pairs).enumerate() {
                let b = handle.join().unwrap();
                let topic = format!("z/together/{i}");
                let sub = a.subscribe(&topic).unwrap();
                let missing = b
                    .await_subscribers(std::slice::from_ref(&topic), Duration::from_secs(20))
                    .unwrap();
                assert!(missing.is_empty());
                b.publish(&topic, b"hello").unwrap();
                let (_, got) = sub.rx.recv_timeout(Duration::from_secs(10)).unwrap();
                assert_eq!(&got[..], b"hello");
            }
            return;
        }
        let out = std::process::Command::new(std::env::current_exe().unwrap())
            .args([
                "--exact",
                "zenoh_bus::tests::sessions_opened_together_connect_at_once",
                "--nocapture",
                "--test-threads=1",
            ])
            .env(CHILD, "1")
            .output()
            .unwrap();
        let log = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "the child failed:\n{log}");
        assert!(
            !log.contains("Scouting delay elapsed"),
            "an open waited out the delay:\n{log}"
        );
    }

    /// A peer whose rendezvous does not answer fails to open (after [`PEER_OPEN_WAIT_MS`]),
    /// and the error names the endpoint (rather than opening without a connection and
    /// leaving the node to wait for messages that cannot come).
    #[test]
    fn open_fails_naming_a_rendezvous_that_does_not_answer() {
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let endpoint = format!("tcp/127.0.0.1:{port}");
        let opened = ZenohBus::open(&ZenohSettings {
            connect: vec![endpoint.clone()],
            ..ZenohSettings::default()
        });
        let Err(e) = opened else {
            panic!("opened without its rendezvous");
        };
        assert!(e.to_string().contains(&endpoint), "{e}");
    }

    /// A session asked to listen on port 0 reports the loopback endpoint it was given, with
    /// a real port, and a second session connected to it carries messages.
    #[test]
    fn an_ephemeral_listener_reports_the_port_it_holds() {
        let (a, endpoint) = listening_session();
        let port: u16 = endpoint
            .strip_prefix("tcp/127.0.0.1:")
            .and_then(|p| p.parse().ok())
            .unwrap_or_else(|| panic!("not a loopback tcp endpoint: {endpoint}"));
        assert_ne!(port, 0);
        // the port is taken: nobody else can bind it
        assert!(std::net::TcpListener::bind(("127.0.0.1", port)).is_err());
        let b = connected_session(endpoint);
        let sub = a.subscribe("z/e").unwrap();
        let missing = b
            .await_subscribers(&["z/e".to_string()], Duration::from_secs(20))
            .unwrap();
        assert!(missing.is_empty());
        b.publish("z/e", b"hello").unwrap();
        let (topic, got) = sub.rx.recv_timeout(Duration::from_secs(10)).unwrap();
        assert_eq!(topic, "z/e");
        assert_eq!(&got[..], b"hello");
    }

    /// A session connected to `endpoint`.
    fn connected_session(endpoint: String) -> ZenohBus {
        ZenohBus::open(&ZenohSettings {
            connect: vec![endpoint],
            ..ZenohSettings::default()
        })
        .unwrap()
    }

    /// Two sessions on this host, as two processes of a run would be: a large message
    /// crosses in the publisher's shared memory with every byte intact, a small one is
    /// copied, one that fits no pool gets a new pool, and one beyond the limit is copied;
    /// a process that may not lock memory copies them all.
    #[test]
    fn large_messages_cross_in_shared_memory() {
        let (a, endpoint) = listening_session();
        let b = connected_session(endpoint);
        // pools of at least 1 MiB, and room for 1 MiB and a 4 MiB + 4 one
        let mib = 1 << 20;
        *b.shm.lock().unwrap() = Shm::new(mib, mib + shm_pool_bytes(mib + 1, mib));
        let sub = a.subscribe("z/m").unwrap();
        let missing = b
            .await_subscribers(&["z/m".to_string()], Duration::from_secs(20))
            .unwrap();
        assert!(missing.is_empty());
        let big = Counting {
            first: 5,
            n: 3 * SHM_MIN_BYTES + 7,
        };
        let small = Counting { first: 9, n: 1000 };
        // larger than the first pool: a second one, for four such
        let large = Counting {
            first: 1,
            n: mib + 1,
        };
        // fits neither pool while `large` is held, and a third would pass the limit
        let huge = Counting {
            first: 2,
            n: 7 * mib / 2,
        };
        let sent = [
            (&big, true),
            (&small, false),
            (&large, true),
            (&huge, false),
            (&big, true),
        ];
        for (m, _) in sent {
            b.publish_message("z/m", m).unwrap();
        }
        let got: Vec<Payload> = (0..sent.len())
            .map(|_| sub.rx.recv_timeout(Duration::from_secs(20)).unwrap().1)
            .collect();
        // without the right to lock memory nothing goes through shared memory: then only
        // the copy path is checked, and the test says so
        let lockable = may_lock_memory();
        if !lockable {
            eprintln!(
                "SKIPPED the shared-memory half of large_messages_cross_in_shared_memory: this \
                 process may not lock memory (needs CAP_IPC_LOCK or an unlimited `ulimit -l`); \
                 only the copy path was checked"
            );
        }
        for (p, (m, shared)) in got.iter().zip(sent) {
            let shared = shared && lockable;
            assert_eq!(p.len(), m.n);
            assert!(p[..] == m.bytes()[..], "bytes of a {}-byte message", m.n);
            assert_eq!(p.is_shared(), shared, "{}-byte message", m.n);
        }
    }

    /// A process that publishes and then exits at once loses nothing in flight, whether
    /// a message travels in the session's own buffers (a few kB: zenoh's implicit shared
    /// memory, whose buffers went with the publisher, is off — `e2e
    /// replay_republishes_the_recording` lost the last of them on a loaded host) or in
    /// this bus's shared memory (the bus holds each until a receiver has taken it, and
    /// its close waits for that; without the hold, or without the wait, a 40 kB message
    /// near the end went missing in most runs). The publisher is this test binary run
    /// again as a child; the receiver takes 3 ms per message, so most are still on their
    /// way when it exits.
    #[test]
    fn a_publisher_process_that_exits_at_once_loses_nothing() {
        const TO: &str = "FIBERFLOW_TEST_PUBLISH_TO";
        const N: usize = 400;
        // above zenoh's 3 kB threshold, below ours; and in this bus's shared memory
        let few_kb = Counting { first: 3, n: 4_000 };
        let large = Counting {
            first: 7,
            n: 40_000,
        };
        assert!(few_kb.n < SHM_MIN_BYTES && large.n >= SHM_MIN_BYTES);
        let sent = |i: usize| if i.is_multiple_of(2) { &large } else { &few_kb };
        if let Ok(endpoint) = std::env::var(TO) {
            let b = connected_session(endpoint);
            let missing = b
                .await_subscribers(&["z/exit".to_string()], Duration::from_secs(20))
                .unwrap();
            assert!(missing.is_empty());
            for i in 0..N {
                b.publish_message("z/exit", sent(i)).unwrap();
            }
            return;
        }
        let (a, endpoint) = listening_session();
        let (tx, rx) = channel();
        let _sub = a
            .session
            .declare_subscriber("z/exit")
            .callback(move |sample| {
                std::thread::sleep(Duration::from_millis(3));
                let p = sample.payload();
                let _ = tx.send((p.to_bytes().into_owned(), p.as_shm().is_some()));
            })
            .wait()
            .unwrap();
        let mut child = std::process::Command::new(std::env::current_exe().unwrap())
            .args([
                "--exact",
                "zenoh_bus::tests::a_publisher_process_that_exits_at_once_loses_nothing",
                "--test-threads=1",
            ])
            .env(TO, &endpoint)
            .stdout(std::process::Stdio::null())
            .spawn()
            .unwrap();
        let lockable = may_lock_memory();
        if !lockable {
            eprintln!(
                "SKIPPED the shared-memory half of this test: this process may not lock memory \
                 (needs CAP_IPC_LOCK or an unlimited `ulimit -l`); only the copy path was checked"
            );
        }
        let mut got = 0;
        while got < N {
            // the first comes once the child has started and connected
            let wait_s = if got == 0 { 60 } else { 10 };
            let Ok((p, shared)) = rx.recv_timeout(Duration::from_secs(wait_s)) else {
                break;
            };
            let m = sent(got);
            assert!(
                p[..] == m.bytes()[..],
                "message {got}: {} bytes, {} expected",
                p.len(),
                m.n
            );
            let in_shm = m.n >= SHM_MIN_BYTES && lockable;
            assert_eq!(shared, in_shm, "message {got} of {} bytes", m.n);
            got += 1;
        }
        assert!(
            child.wait().unwrap().success(),
            "the publishing process failed"
        );
        assert_eq!(got, N, "messages received of those sent");
    }

    /// [`ONE_THREAD_RUNTIME`] is a runtime zenoh accepts and runs on: in a process started
    /// with it (this test binary run again as a child), two sessions on loopback exchange
    /// messages both ways, and the process has zenoh's `acc` worker but none of its `rx`,
    /// `tx`, `net` or `app` threads (with zenoh's default runtime it has all five kinds).
    #[test]
    fn one_thread_runtime_carries_messages_on_one_thread() {
        const CHILD: &str = "FIBERFLOW_TEST_ONE_THREAD_CHILD";
        let threads = || -> Vec<String> {
            std::fs::read_dir("/proc/self/task")
                .unwrap()
                .filter_map(|t| std::fs::read_to_string(t.ok()?.path().join("comm")).ok())
                .map(|c| c.trim().to_string())
                .collect()
        };
        let kind = |names: &[String], k: &str| names.iter().any(|n| n.starts_with(k));
        let (a, endpoint) = listening_session();
        let b = connected_session(endpoint);
        let (sa, sb) = (a.subscribe("z/ab").unwrap(), b.subscribe("z/ba").unwrap());
        for (from, topic) in [(&b, "z/ab"), (&a, "z/ba")] {
            let missing = from
                .await_subscribers(&[topic.to_string()], Duration::from_secs(20))
                .unwrap();
            assert!(missing.is_empty(), "{topic}: no subscriber");
        }
        b.publish("z/ab", b"to a").unwrap();
        a.publish("z/ba", b"to b").unwrap();
        let got = |s: &Subscription| s.rx.recv_timeout(Duration::from_secs(20)).unwrap().1;
        assert_eq!(&got(&sa)[..], b"to a");
        assert_eq!(&got(&sb)[..], b"to b");
        let names = threads();
        if std::env::var_os(CHILD).is_some() {
            assert!(kind(&names, "acc-"), "no acc worker: {names:?}");
            for k in ["rx-", "tx-", "net-", "app-"] {
                assert!(!kind(&names, k), "a {k} thread: {names:?}");
            }
            return;
        }
        if std::env::var_os("ZENOH_RUNTIME").is_none() {
            // zenoh's default runtime: the pools this runtime folds into one
            for k in ["acc-", "rx-", "tx-"] {
                assert!(kind(&names, k), "no {k} thread by default: {names:?}");
            }
        }
        let st = std::process::Command::new(std::env::current_exe().unwrap())
            .args([
                "--exact",
                "zenoh_bus::tests::one_thread_runtime_carries_messages_on_one_thread",
                "--test-threads=1",
            ])
            .env(CHILD, "1")
            .env("ZENOH_RUNTIME", ONE_THREAD_RUNTIME)
            .stdout(std::process::Stdio::null())
            .status()
            .unwrap();
        assert!(st.success(), "the process on the one-thread runtime failed");
    }
}
