//! Realisations end to end (docs/realisations.md): `run.realisation = i` gives a two-way
//! run its own start — the flow field disturbed, random placements reseeded — the same bits
//! for the same i over transports, shard counts and a kill with resume; realisation 0 is
//! the run without the key.

use fiberflow_e2e::*;
use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

/// The quick launch, two-way and short (80 steps, 20 t+, a checkpoint every 5 t+), with
/// case1 placed at random.
fn sets(realisation: Option<u32>, shards: u32) -> Vec<String> {
    let mut v = vec![
        "run.steps=80".to_string(),
        "run.checkpoint_every_plus=5".into(),
        "run.analyze=false".into(),
        "run.step_timeout_s=60".into(),
        "run.coupling=\"two-way\"".into(),
        "fibers.case1.placement={ kind = \"random\", count = 40, seed = 3 }".into(),
        format!("fibers.case1.shards={shards}"),
    ];
    if let Some(r) = realisation {
        v.push(format!("run.realisation={r}"));
    }
    v
}

fn cmd(out: &Path, transport: &str, sets: &[String]) -> Command {
    let mut c = Command::new(fiberflow());
    c.arg("launch")
        .arg(root().join("launch/quick.toml"))
        .args(["--transport", transport, "--out"])
        .arg(out);
    for s in sets {
        c.arg("--set").arg(s);
    }
    c
}

fn run(out: &Path, transport: &str, sets: &[String]) -> BTreeMap<(String, u64), Vec<u8>> {
    let o = cmd(out, transport, sets).output().unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{transport}: {stderr}");
    let w = warnings_in_logs(out);
    assert!(w.is_empty(), "{transport}: warnings in node logs: {w:#?}");
    whole_states(out)
}

fn assert_same(
    a: &BTreeMap<(String, u64), Vec<u8>>,
    b: &BTreeMap<(String, u64), Vec<u8>>,
    what: &str,
) {
    assert_eq!(
        a.keys().collect::<Vec<_>>(),
        b.keys().collect::<Vec<_>>(),
        "{what}: other states"
    );
    for (k, x) in a {
        assert!(x == &b[k], "{what}: {k:?} differs");
    }
}

fn centres(states: &BTreeMap<(String, u64), Vec<u8>>, group: &str, step: u64) -> Vec<f64> {
    let s: fiberflow_messages::FiberGroupState =
        fiberflow_messages::decode(&states[&(group.to_string(), step)]).unwrap();
    s.centre
}

#[test]
fn a_realisation_is_the_same_bits_everywhere_and_its_own_start() {
    let _one = one_run_at_a_time();
    let dir = scratch("realisations");
    let a = run(&dir.join("r2-inproc"), "inproc", &sets(Some(2), 1));
    assert_eq!(a.len(), 6 * 81, "six groups, steps 0..=80");
    // the same realisation over zenoh with case1 in three shards
    let b = run(&dir.join("r2-zenoh"), "zenoh", &sets(Some(2), 3));
    assert_same(&a, &b, "realisation 2 over zenoh, three shards");
    // ... and over iceoryx2 with the flow node killed after the first checkpoint: rolled
    // back, resumed from the checkpoint (not disturbed again), the same bits
    let out = dir.join("r2-kill");
    launch_and_kill_the_flow_node(cmd(&out, "iceoryx2", &sets(Some(2), 1)), &out);
    assert_same(&a, &whole_states(&out), "realisation 2, flow node killed");

    // another realisation: case1 placed elsewhere; a group in fixed layers starts where it
    // did, and its samples differ from the first step on (the field is another)
    let c = run(&dir.join("r3"), "inproc", &sets(Some(3), 1));
    assert_ne!(centres(&a, "case1", 0), centres(&c, "case1", 0));
    assert_eq!(centres(&a, "case2", 0), centres(&c, "case2", 0));
    assert_ne!(centres(&a, "case2", 2), centres(&c, "case2", 2));

    // realisation 0 is the run without the key
    let plain = run(&dir.join("plain"), "inproc", &sets(None, 1));
    let zero = run(&dir.join("r0"), "inproc", &sets(Some(0), 1));
    assert_same(&plain, &zero, "realisation 0 against no key");
    assert_ne!(centres(&plain, "case1", 0), centres(&a, "case1", 0));

    // the analysis pools realisations: two laden against two unladen
    let o = Command::new(fiberflow())
        .arg("analyze")
        .args([dir.join("r2-inproc"), dir.join("r3")])
        .arg("--unladen")
        .args([dir.join("plain"), dir.join("r0")])
        .args(["--batches", "2"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let md =
        std::fs::read_to_string(dir.join("r2-inproc-realisations/flow_modulation.md")).unwrap();
    assert!(
        md.contains("2 realisations of this run and 2 unladen"),
        "{md}"
    );
    assert!(
        md.contains("| run 2 |") && md.contains("| unladen 2 |"),
        "{md}"
    );
    assert!(
        dir.join("r3/analysis/summary.md").exists(),
        "each run's fibres analysed"
    );

    // the runs' flow parts (scripts/flow_part.py: no fibre states, the fibres' mass as
    // metadata) pool to the very same table and loading
    assert!(
        python_ok(),
        "python3 with `mcap` and `mcap-ros2-support` is required"
    );
    let parts = dir.join("parts");
    for r in ["r2-inproc", "r3", "plain", "r0"] {
        std::fs::create_dir_all(parts.join(r)).unwrap();
        let o = Command::new("python3")
            .arg(root().join("scripts/flow_part.py"))
            .arg(dir.join(r).join("run.mcap"))
            .arg(parts.join(r).join("run.mcap"))
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        assert!(
            states(&parts.join(r).join("run.mcap")).is_empty(),
            "a flow part holds no fibre state"
        );
    }
    let o = Command::new(fiberflow())
        .arg("analyze")
        .args([parts.join("r2-inproc"), parts.join("r3")])
        .arg("--unladen")
        .args([parts.join("plain"), parts.join("r0")])
        .args(["--batches", "2"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(
        String::from_utf8_lossy(&o.stdout).contains("no fibre states (a flow part)"),
        "{}",
        String::from_utf8_lossy(&o.stdout)
    );
    let table = |d: &Path| std::fs::read_to_string(d.join("flow_modulation.csv")).unwrap();
    assert_eq!(
        table(&dir.join("r2-inproc-realisations")),
        table(&parts.join("r2-inproc-realisations")),
        "the flow parts pool as the whole recordings"
    );
    let loading = |d: &Path| -> String {
        let md = std::fs::read_to_string(d.join("flow_modulation.md")).unwrap();
        let at = md.find("Mass loading").expect("the loading");
        md[at..at + 20].to_string()
    };
    assert_eq!(
        loading(&dir.join("r2-inproc-realisations")),
        loading(&parts.join("r2-inproc-realisations"))
    );
    std::fs::remove_dir_all(&dir).ok();
}
