//! Fibre–fibre contact end to end (docs/contact.md): a suspension with contact and friction
//! on the coarse grid, run with real processes over the three transports, in three shards,
//! and with a fibre node killed (SIGKILL) mid-run; every recorded state must be bitwise
//! that of the in-process run, fibres must touch, and in no recorded state may two
//! fibres' centre-lines be closer than 0.99 d.

use fiberflow_e2e::*;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

/// 10⁴ case-1 fibres placed at random in a band 24 wall units thick around the centre
/// plane (crowding N ≈ 4.6 in the band), contact with μ = 0.5, 80 steps of 0.25 t+ (20 t+),
/// a checkpoint every 5 t+, every state recorded.
fn launch_file(dir: &Path) -> PathBuf {
    let restart = root().join("recordings/samples/coarse-re150.ckpt");
    let text = format!(
        r#"[run]
id = "contact-e2e"
steps = 80
dt_plus = 0.25
analyze = false
step_timeout_s = 120
checkpoint_every_plus = 5

[flow.source]
kind = "dns"
restart = "{}"

[flow.source.dns]
nx = 64
ny = 64
nz = 64
re_tau = 150.0
y1_plus = 0.33

[[fibers]]
group = "suspension"
case = "case1"
initial_velocity = "fluid"
placement = {{ kind = "random", count = 10000, seed = 3, band_plus = [138.0, 162.0] }}
contact = {{ friction = 0.5 }}
"#,
        restart.display()
    );
    let path = dir.join("contact-e2e.toml");
    std::fs::write(&path, text).unwrap();
    path
}

fn cmd(file: &Path, out: &Path, transport: &str, sets: &[&str]) -> Command {
    let mut c = Command::new(fiberflow());
    c.arg("launch")
        .arg(file)
        .args(["--transport", transport, "--out"])
        .arg(out);
    for s in sets {
        c.arg("--set").arg(s);
    }
    c
}

fn run(file: &Path, out: &Path, transport: &str) {
    let o = cmd(file, out, transport, &[]).output().unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{transport}: {stderr}");
    let w = warnings_in_logs(out);
    assert!(w.is_empty(), "{transport}: warnings in node logs: {w:#?}");
}

/// Runs the launch over iceoryx2, kills fibre node `node` (SIGKILL) after the first
/// checkpoint, and checks that the launcher rolled the run back and completed it.
fn run_killing(file: &Path, out: &Path, sets: &[&str], node: &str) {
    std::fs::create_dir_all(out).unwrap();
    let se = std::fs::File::create(out.with_extension("stderr")).unwrap();
    let mut child = cmd(file, out, "iceoryx2", sets)
        .stdout(std::process::Stdio::null())
        .stderr(se)
        .spawn()
        .unwrap();
    wait_for_checkpoint(out, 120);
    let spec = out
        .join(format!("config/{node}.toml"))
        .display()
        .to_string();
    let pids = pids_with(&spec);
    assert_eq!(
        pids.len(),
        1,
        "fibre node {node} not found (run over already?)"
    );
    // SAFETY: plain syscall on a process this test's launcher started
    unsafe { libc::kill(pids[0], libc::SIGKILL) };
    assert!(child.wait().unwrap().success());
    let err = std::fs::read_to_string(out.with_extension("stderr")).unwrap();
    assert!(err.contains("restarting every node from step"), "{err}");
}

/// Every recorded fibre state by step, decoded.
fn states(out: &Path) -> BTreeMap<u64, fiberflow_messages::FiberGroupState> {
    let mut by = BTreeMap::new();
    for seg in fiberflow_messages::segments::segment_paths(out).unwrap() {
        let bytes = std::fs::read(&seg).unwrap();
        for m in mcap::MessageStream::new(&bytes).unwrap() {
            let m = m.unwrap();
            if m.channel.topic.ends_with("/state") {
                let s: fiberflow_messages::FiberGroupState =
                    fiberflow_messages::decode(&m.data).unwrap();
                by.insert(s.step, s);
            }
        }
    }
    by
}

fn assert_same(
    a: &BTreeMap<u64, fiberflow_messages::FiberGroupState>,
    b: &BTreeMap<u64, fiberflow_messages::FiberGroupState>,
    what: &str,
) {
    assert_eq!(
        a.keys().collect::<Vec<_>>(),
        b.keys().collect::<Vec<_>>(),
        "{what}: other steps"
    );
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    for (k, x) in a {
        let y = &b[k];
        for (name, p, q) in [
            ("centre", &x.centre, &y.centre),
            ("axis", &x.axis, &y.axis),
            ("velocity", &x.velocity, &y.velocity),
            ("angular_velocity", &x.angular_velocity, &y.angular_velocity),
            ("contact_force", &x.contact_force, &y.contact_force),
        ] {
            assert!(bits(p) == bits(q), "{what}: step {k} {name} differs");
        }
        assert!(
            x.contact_segment == y.contact_segment && x.contacts == y.contacts,
            "{what}: step {k} contact segments differ"
        );
    }
}

#[test]
fn contact_is_bitwise_over_transports_and_a_kill_and_keeps_fibers_apart() {
    let _one = one_run_at_a_time();
    let dir = scratch("contact");
    let file = launch_file(&dir);
    let a_out = dir.join("inproc");
    run(&file, &a_out, "inproc");
    let a = states(&a_out);
    assert_eq!(a.len(), 81, "steps 0..=80");
    // fibres touch, and never come closer than 0.99 d, to each other or to themselves (the
    // box of the coarse grid)
    let box_plus = [
        2.0 * std::f64::consts::PI * 150.0,
        300.0,
        std::f64::consts::PI * 150.0,
    ];
    let mut touched = 0.0_f64;
    for (step, s) in &a {
        let r = fiberflow_analysis::flocs::of_state(s, box_plus);
        assert!(
            r.closest_over_d >= 0.99,
            "step {step}: centre-lines {} d apart",
            r.closest_over_d
        );
        assert!(
            r.self_closest_over_d >= 0.99,
            "step {step}: a fibre's own segments {} d apart",
            r.self_closest_over_d
        );
        touched = touched.max(r.contacts_per_fiber);
    }
    assert!(
        touched > 0.01,
        "fibres hardly touched: {touched} contacts per fibre"
    );
    // the states carry each step's contact load: segments that touched, and forces that
    // sum to zero over the group (every pair is inside it), to round-off
    let mut listed = 0;
    for (step, s) in &a {
        listed += s.contact_segment.len();
        let (mut sum, mut largest) = ([0.0_f64; 3], 0.0_f64);
        for f in s.contact_force.chunks_exact(3) {
            for c in 0..3 {
                sum[c] += f[c];
                largest = largest.max(f[c].abs());
            }
        }
        let n = s.contact_segment.len() as f64;
        assert!(
            sum.iter().all(|x| x.abs() <= 1e-12 * largest * n.max(1.0)),
            "step {step}: contact forces sum to {sum:?}"
        );
    }
    assert!(listed > 0, "no state lists a segment in contact");
    for transport in ["zenoh", "iceoryx2"] {
        let out = dir.join(transport);
        run(&file, &out, transport);
        assert_same(&a, &states(&out), transport);
    }
    // kill -9 of the fibre node after the first checkpoint: rolled back, resumed, and
    // every state bitwise that of the uninterrupted run
    let out = dir.join("kill-fibers");
    run_killing(&file, &out, &[], "suspension");
    assert_same(&a, &states(&out), "kill -9 fibres, restarted");
    std::fs::remove_dir_all(&dir).ok();
}

/// Every recorded state by step with a sharded group's slices put together (re-encoded,
/// so the unsharded run's compares byte for byte); a step recorded again after a restart
/// must have the same bytes.
fn whole_by_step(out: &Path) -> BTreeMap<u64, Vec<u8>> {
    let mut tiles = fiberflow_messages::pieces::Tiles::default();
    let mut by = BTreeMap::new();
    for_each_state(out, |s| {
        if let Some(w) = tiles.add_slice(s) {
            let bytes = fiberflow_messages::encode(&w);
            if let Some(old) = by.insert(w.step, bytes.clone()) {
                assert!(old == bytes, "step {} recorded twice, differently", w.step);
            }
        }
    });
    by
}

/// The suspension of the test above in three shards (3334 + 3333 + 3333 fibres, each a
/// process over zenoh and iceoryx2; the first solves contact for all, the others send it
/// their free steps and take their parts): every recorded state is bitwise that of the
/// unsharded run, over the three transports and after a kill -9 of the middle shard's
/// process and of the first shard's.
#[test]
fn contact_across_three_shards_is_bitwise_the_unsharded_run() {
    let _one = one_run_at_a_time();
    let dir = scratch("contact-shards");
    let file = launch_file(&dir);
    let one = dir.join("one");
    run(&file, &one, "inproc");
    let a = whole_by_step(&one);
    assert_eq!(a.len(), 81, "steps 0..=80");
    let three = ["fibers.suspension.shards=3"];
    for transport in ["inproc", "zenoh", "iceoryx2"] {
        let out = dir.join(format!("three-{transport}"));
        let o = cmd(&file, &out, transport, &three).output().unwrap();
        assert!(
            o.status.success(),
            "{transport}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        let w = warnings_in_logs(&out);
        assert!(w.is_empty(), "{transport}: warnings in node logs: {w:#?}");
        let b = whole_by_step(&out);
        assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
        for (k, v) in &a {
            assert!(v == &b[k], "{transport}, three shards: step {k} differs");
        }
    }
    for shard in ["1", "0"] {
        let out = dir.join(format!("three-kill-{shard}"));
        run_killing(&file, &out, &three, &format!("suspension.{shard}"));
        let b = whole_by_step(&out);
        assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
        for (k, v) in &a {
            assert!(
                v == &b[k],
                "three shards, shard {shard} killed: step {k} differs"
            );
        }
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// Two groups of one suspension (`[[suspensions]]`): 5000 case-1 and 5000 case-2 fibres
/// (twice as dense) placed at random in the same band, contact with μ = 0.5, 40 steps.
fn two_groups_launch_file(dir: &Path, touching: bool) -> PathBuf {
    let restart = root().join("recordings/samples/coarse-re150.ckpt");
    let group = |name: &str, case: &str, seed: u32| {
        format!(
            r#"
[[fibers]]
group = "{name}"
case = "{case}"
initial_velocity = "fluid"
placement = {{ kind = "random", count = 5000, seed = {seed}, band_plus = [138.0, 162.0] }}
contact = {{ friction = 0.5 }}
"#
        )
    };
    let text = format!(
        r#"[run]
id = "contact-groups"
steps = 40
dt_plus = 0.25
analyze = false
step_timeout_s = 120

[flow.source]
kind = "dns"
restart = "{}"

[flow.source.dns]
nx = 64
ny = 64
nz = 64
re_tau = 150.0
y1_plus = 0.33
{}{}{}"#,
        restart.display(),
        group("light", "case1", 3),
        group("heavy", "case2", 4),
        if touching {
            "\n[[suspensions]]\ngroups = [\"light\", \"heavy\"]\n"
        } else {
            ""
        }
    );
    let path = dir.join(format!("groups-{touching}.toml"));
    std::fs::write(&path, text).unwrap();
    path
}

/// Both groups' fibres of each recorded step as one state (light's fibres, then heavy's),
/// with each group's own: (both, light, heavy).
type Three = (
    fiberflow_messages::FiberGroupState,
    fiberflow_messages::FiberGroupState,
    fiberflow_messages::FiberGroupState,
);

fn both_groups(out: &Path) -> BTreeMap<u64, Three> {
    let mut by: BTreeMap<u64, BTreeMap<String, fiberflow_messages::FiberGroupState>> =
        BTreeMap::new();
    let mut tiles = fiberflow_messages::pieces::Tiles::default();
    for_each_state(out, |s| {
        if let Some(w) = tiles.add_slice(s) {
            by.entry(w.step).or_default().insert(w.group.clone(), w);
        }
    });
    by.into_iter()
        .map(|(k, g)| {
            let (a, b) = (g["light"].clone(), g["heavy"].clone());
            let both = fiberflow_analysis::flocs::merged(&[&a, &b]).expect("one step");
            (k, (both, a, b))
        })
        .collect()
}

/// Two groups in one suspension touch each other: in no recorded state are fibres of the
/// two groups (or of one) closer than 0.99 d, and fibres of different groups touch; the
/// same run with the heavy group in two shards (three processes, iceoryx2) records the
/// same bits. Without `[[suspensions]]` the two groups pass through each other.
#[test]
fn two_groups_of_one_suspension_touch_and_shards_keep_the_bits() {
    let _one = one_run_at_a_time();
    let dir = scratch("contact-groups");
    let box_plus = [
        2.0 * std::f64::consts::PI * 150.0,
        300.0,
        std::f64::consts::PI * 150.0,
    ];
    let file = two_groups_launch_file(&dir, true);
    let one = dir.join("one");
    run(&file, &one, "inproc");
    let states = both_groups(&one);
    assert_eq!(states.len(), 41, "steps 0..=40");
    let mut across = 0;
    for (step, (both, a, b)) in &states {
        let r = fiberflow_analysis::flocs::of_state(both, box_plus);
        assert!(
            r.closest_over_d >= 0.99,
            "step {step}: centre-lines {} d apart",
            r.closest_over_d
        );
        let own = fiberflow_analysis::flocs::of_state(a, box_plus).segment_contacts
            + fiberflow_analysis::flocs::of_state(b, box_plus).segment_contacts;
        across = across.max(r.segment_contacts - own);
    }
    assert!(across > 0, "fibres of the two groups never touched");
    let out = dir.join("sharded");
    let o = cmd(&file, &out, "iceoryx2", &["fibers.heavy.shards=2"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let w = warnings_in_logs(&out);
    assert!(w.is_empty(), "warnings in node logs: {w:#?}");
    let a = whole_states(&one);
    let b = whole_states(&out);
    assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
    for (k, v) in &a {
        assert!(v == &b[k], "heavy in two shards: {k:?} differs");
    }
    // the same groups without [[suspensions]]: they pass through each other
    let apart = dir.join("apart");
    run(&two_groups_launch_file(&dir, false), &apart, "inproc");
    let closest = both_groups(&apart)
        .values()
        .map(|(both, _, _)| fiberflow_analysis::flocs::of_state(both, box_plus).closest_over_d)
        .fold(f64::INFINITY, f64::min);
    assert!(
        closest < 0.5,
        "without a suspension the groups came only to {closest} d"
    );
    std::fs::remove_dir_all(&dir).ok();
}
