//! A multi-host run's access control tried from outside (docs/architecture.md, "Runs
//! across hosts"): sessions opened with the settings the launcher gives its nodes
//! ([`crate::nodes::open_bus`]), certificates from `launch/multi-host/make-certs.sh`.

use crate::launchfile::LaunchFile;
use crate::nodes::{open_bus, NodeSpec};
use fiberflow_bus::{BusHandle, Subscription};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// A two-host launch on loopback (head: flow, recorder, case1; worker: stiff) whose
/// worker holds the identity `worker_cert`, with certificates in `dir/certs`.
fn two_host_file(dir: &Path, port: u16, worker_cert: &str) -> (LaunchFile, String) {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let base = std::fs::read_to_string(repo.join("launch/validation/analytic-shear.toml"))
        .expect("reading analytic-shear.toml");
    let c = |f: &str| dir.join("certs").join(f).display().to_string();
    let text = format!(
        r#"{base}
[network]
rendezvous = "tls/localhost:{port}"
listen = "tls/127.0.0.1:{port}"
root_ca_certificate = "{ca}"
allowed_common_names = ["fiberflow-head", "fiberflow-worker"]

[[network.hosts]]
name = "head"
nodes = ["flow", "recorder", "case1"]
certificate = "{head}"
private_key = "{head_key}"

[[network.hosts]]
name = "worker"
nodes = ["stiff"]
certificate = "{worker}"
private_key = "{worker_key}"
"#,
        ca = c("ca.pem"),
        head = c("head.pem"),
        head_key = c("head-key.pem"),
        worker = c(&format!("{worker_cert}.pem")),
        worker_key = c(&format!("{worker_cert}-key.pem")),
    );
    let file = dir.join(format!("{worker_cert}.toml"));
    std::fs::write(&file, &text).unwrap();
    (LaunchFile::load_with(&file, &[]).unwrap().0, text)
}

/// The spec of `node` on `host` of `lf`.
fn spec(lf: &LaunchFile, text: &str, host: &str, node: &str, out: &Path) -> NodeSpec {
    let mut s = NodeSpec::inproc(lf.clone(), text.to_string(), out.to_path_buf());
    s.transport = fiberflow_bus::Transport::Zenoh;
    s.host = Some(host.into());
    s.node = node.into();
    s
}

/// The payloads that reach `sub` within `wait`, or until a second after `until` arrived.
fn arrived(sub: &Subscription, wait: Duration, until: &[u8]) -> Vec<Vec<u8>> {
    let mut got = Vec::new();
    let t0 = Instant::now();
    let mut end = t0 + wait;
    while Instant::now() < end {
        if let Ok(e) = sub.rx.recv_timeout(Duration::from_millis(50)) {
            if &e.1[..] == until {
                end = end.min(Instant::now() + Duration::from_secs(1));
            }
            got.push(e.1.to_vec());
        }
    }
    got
}

/// Publishes `payload` on `topic` ten times over half a second.
fn send(bus: &BusHandle, topic: &str, payload: &[u8]) {
    for _ in 0..10 {
        let _ = bus.publish(topic, payload);
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// The head's router (the flow node's session) listens on everything. A member (the
/// worker's certificate) publishing under the run's prefix arrives; the same member
/// publishing outside the prefix does not; a stranger whose certificate the run's CA signed
/// but whose common name is not allowed either cannot join or, joined, delivers nothing
/// under the run's prefix. The member's last message, sent after the others, arrives, so
/// nothing was merely late.
#[test]
fn a_stranger_and_a_member_outside_the_run_deliver_nothing() {
    let dir = std::env::temp_dir().join(format!("ff-access-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let st = std::process::Command::new(repo.join("launch/multi-host/make-certs.sh"))
        .arg(dir.join("certs"))
        .args(["head", "worker", "intruder"])
        .stdout(std::process::Stdio::null())
        .status()
        .expect("running make-certs.sh (needs openssl)");
    assert!(st.success());
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let (lf, text) = two_host_file(&dir, port, "worker");
    let (lf_in, text_in) = two_host_file(&dir, port, "intruder");
    let out = PathBuf::from(&dir);
    let router = open_bus(&spec(&lf, &text, "head", "flow", &out)).expect("the head's router");
    let everything = router.subscribe("**").unwrap();
    let member = open_bus(&spec(&lf, &text, "worker", "stiff", &out)).expect("a member joins");
    let prefix = fiberflow_messages::topics::Topics::new(&lf.run.id).prefix();
    let inside = format!("{prefix}/fibers/stiff/state");

    // the stranger: joining may be refused outright; if not, what it sends goes nowhere
    let stranger = open_bus(&spec(&lf_in, &text_in, "worker", "stiff", &out));
    if let Ok(s) = &stranger {
        send(s, &inside, b"stranger inside");
        send(s, "elsewhere/topic", b"stranger outside");
    }
    send(&member, "elsewhere/topic", b"member outside");
    send(&member, &inside, b"member inside");
    let got = arrived(&everything, Duration::from_secs(20), b"member inside");
    let said: Vec<String> = got
        .iter()
        .map(|p| String::from_utf8_lossy(p).to_string())
        .collect();
    assert!(
        said.iter().any(|s| s == "member inside"),
        "the member's message never arrived: {said:?}"
    );
    for bad in ["stranger inside", "stranger outside", "member outside"] {
        assert!(
            !said.iter().any(|s| s == bad),
            "{bad:?} arrived (stranger joined: {})",
            stranger.is_ok()
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}
