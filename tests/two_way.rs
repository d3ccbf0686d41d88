//! Two-way coupling end to end (docs/two-way.md): real processes over the three transports,
//! sharded and unsharded, and a node killed with SIGKILL mid-run; every recorded fibre state
//! must be bitwise that of the in-process run, and the fibres' forces must really reach the
//! fluid (the states differ from a one-way run's).

use fiberflow_e2e::*;
use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

/// The quick launch, shortened and two-way: 120 steps (30 t+), a checkpoint every 5 t+.
fn sets(coupling: &str, shards: u32) -> Vec<String> {
    vec![
        "run.steps=120".into(),
        "run.checkpoint_every_plus=5".into(),
        "run.analyze=false".into(),
        "run.step_timeout_s=60".into(),
        format!("run.coupling=\"{coupling}\""),
        format!("fibers.case1.shards={shards}"),
        format!("fibers.case4.shards={shards}"),
    ]
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

fn run(out: &Path, transport: &str, sets: &[String]) -> String {
    let o = cmd(out, transport, sets).output().unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{transport}: {stderr}");
    assert!(!stderr.contains("WARN"), "{transport}: {stderr}");
    let w = warnings_in_logs(out);
    assert!(w.is_empty(), "{transport}: warnings in node logs: {w:#?}");
    String::from_utf8_lossy(&o.stdout).to_string()
}

/// Whole-group states by (group, step), slices of sharded groups merged.
fn whole(out: &Path) -> BTreeMap<(String, u64), fiberflow_messages::FiberGroupState> {
    let (raw, _) = states_by_step_merged(out);
    raw
}

fn states_by_step_merged(
    out: &Path,
) -> (
    BTreeMap<(String, u64), fiberflow_messages::FiberGroupState>,
    usize,
) {
    let mut slices: BTreeMap<(String, u64), Vec<fiberflow_messages::FiberGroupState>> =
        BTreeMap::new();
    for_each_state(out, |s| {
        slices.entry((s.group.clone(), s.step)).or_default().push(s)
    });
    let merged = slices
        .into_iter()
        .map(|(k, mut v)| {
            v.sort_by_key(|s| s.first_fiber);
            v.dedup_by_key(|s| s.first_fiber);
            (k, fiberflow_messages::pieces::merge_states(v).unwrap())
        })
        .collect();
    let segments = fiberflow_messages::segments::segment_paths(out)
        .unwrap()
        .len();
    (merged, segments)
}

fn assert_same(
    a: &BTreeMap<(String, u64), fiberflow_messages::FiberGroupState>,
    b: &BTreeMap<(String, u64), fiberflow_messages::FiberGroupState>,
    what: &str,
) {
    assert_eq!(
        a.keys().collect::<Vec<_>>(),
        b.keys().collect::<Vec<_>>(),
        "{what}: other states"
    );
    for (k, x) in a {
        let y = &b[k];
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        for (name, p, q) in [
            ("centre", &x.centre, &y.centre),
            ("axis", &x.axis, &y.axis),
            ("velocity", &x.velocity, &y.velocity),
            ("angular_velocity", &x.angular_velocity, &y.angular_velocity),
            ("hydro_force", &x.hydro_force, &y.hydro_force),
        ] {
            assert!(bits(p) == bits(q), "{what}: {k:?} {name} differs");
        }
    }
}

#[test]
fn two_way_is_bitwise_over_transports_shards_and_a_kill() {
    let _one = one_run_at_a_time();
    let dir = scratch("two-way");
    let a_out = dir.join("inproc");
    let said = run(&a_out, "inproc", &sets("two-way", 1));
    assert!(
        said.contains("coupling two-way") && said.contains("one suspension"),
        "the launcher must say the groups are one suspension: {said}"
    );
    let a = whole(&a_out);
    assert_eq!(a.len(), 6 * 121, "six groups, steps 0..=120");
    // every recorded state carries one force per segment: zero before the first step
    // (fibres start at rest), then the drag of each step
    for ((g, step), s) in &a {
        assert_eq!(s.hydro_force.len(), s.centre.len(), "{g} {step}");
        let any = s.hydro_force.iter().any(|f| *f != 0.0);
        assert_eq!(any, *step > 0, "{g} step {step}: forces {any}");
    }
    // the fluid feels them: the flow status carries their sum, and the fibres' states
    // differ from the one-way run's from step 2 on (step 1 was sampled from the same field)
    let one_way_out = dir.join("one-way");
    let said = run(&one_way_out, "inproc", &sets("one-way", 1));
    assert!(said.contains("coupling one-way"), "{said}");
    let b = whole(&one_way_out);
    for g in 1..=6 {
        let g = format!("case{g}");
        assert!(a[&(g.clone(), 1)].centre == b[&(g.clone(), 1)].centre);
        assert!(
            a[&(g.clone(), 120)].centre != b[&(g.clone(), 120)].centre,
            "{g}"
        );
        assert!(
            b[&(g.clone(), 120)].hydro_force.is_empty(),
            "one-way states carry no forces"
        );
    }
    for (name, transport, shards) in [
        ("zenoh", "zenoh", 1),
        ("iceoryx2-sharded", "iceoryx2", 3),
        ("inproc-sharded", "inproc", 3),
    ] {
        let out = dir.join(name);
        run(&out, transport, &sets("two-way", shards));
        assert_same(&a, &whole(&out), name);
    }
    // kill -9 of the flow node after the first checkpoint: rolled back, resumed, and every
    // state bitwise that of the uninterrupted run
    let out = dir.join("kill-flow");
    launch_and_kill_the_flow_node(cmd(&out, "iceoryx2", &sets("two-way", 1)), &out);
    let (resumed, segments) = states_by_step_merged(&out);
    assert!(segments >= 2, "a restart records into a new segment");
    assert_same(&a, &resumed, "kill -9 flow, restarted");
    // the flow status of a two-way run carries the fibres' total force
    let bytes = std::fs::read(a_out.join("run.mcap")).unwrap();
    let mut statuses = 0;
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        if m.channel.topic.ends_with("/flow/status") {
            let st: fiberflow_messages::FlowStatus = fiberflow_messages::decode(&m.data).unwrap();
            assert_eq!(st.fiber_force_plus.len(), 3);
            statuses += 1;
        }
    }
    assert!(statuses > 0);
    std::fs::remove_dir_all(&dir).ok();
}

/// `flow.field_steps = 2` (docs/two-way.md, "Field steps per coupling step"), one-way: a
/// coupling step of 0.5 t+ in two field steps walks the very field of coupling steps of
/// 0.25 t+ (the flow checkpoint at t+ 5 byte for byte: the fibres do not push on it), while
/// the fibres step once per 0.5 t+; two-way, the same coupling steps run to the end.
#[test]
fn two_field_steps_walk_the_field_of_half_the_coupling_step() {
    let _one = one_run_at_a_time();
    let dir = scratch("field-steps");
    let sets = |coupling: &str, steps: u32, dt_plus: f64, field_steps: u32| -> Vec<String> {
        vec![
            format!("run.steps={steps}"),
            format!("run.dt_plus={dt_plus}"),
            format!("flow.field_steps={field_steps}"),
            "run.checkpoint_every_plus=2.5".into(),
            "run.analyze=false".into(),
            "run.step_timeout_s=60".into(),
            format!("run.coupling=\"{coupling}\""),
        ]
    };
    let one = dir.join("one");
    run(&one, "inproc", &sets("one-way", 24, 0.25, 1));
    let two = dir.join("two");
    run(&two, "inproc", &sets("one-way", 12, 0.5, 2));
    let field = |out: &Path, step: u64| -> Vec<u8> {
        let root = fiberflow_messages::checkpoints::root(out);
        let dir = fiberflow_messages::checkpoints::step_dir(&root, step);
        std::fs::read(fiberflow_messages::checkpoints::piece(&dir, "flow"))
            .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
    };
    assert!(field(&one, 20) == field(&two, 10), "the field at t+ 5");
    let (a, b) = (whole(&one), whole(&two));
    assert_eq!(b.len(), 6 * 13, "six groups, coupling steps 0..=12");
    for g in 1..=6 {
        let g = format!("case{g}");
        assert!(
            a[&(g.clone(), 0)].centre == b[&(g.clone(), 0)].centre,
            "{g}"
        );
        // one fibre step of 0.5 t+ is not two of 0.25
        assert!(
            a[&(g.clone(), 20)].centre != b[&(g.clone(), 10)].centre,
            "{g}"
        );
    }
    let two_way = dir.join("two-way");
    run(&two_way, "inproc", &sets("two-way", 12, 0.5, 2));
    let c = whole(&two_way);
    assert_eq!(c.len(), 6 * 13);
    assert!(c[&("case1".to_string(), 10)].centre != b[&("case1".to_string(), 10)].centre);
}

/// `fibers[].substeps` (docs/two-way.md, "The fibres' own step"), two-way: two fibre steps
/// per coupling step give the same bits in one process and over zenoh with case 1 and
/// case 4 in three shards each, and other states than one step.
#[test]
fn fiber_substeps_are_bitwise_over_transports_and_shards() {
    let _one = one_run_at_a_time();
    let dir = scratch("substeps");
    let with = |shards: u32, substeps: u32| -> Vec<String> {
        let mut s = sets("two-way", shards);
        s[0] = "run.steps=40".into();
        for g in 1..=6 {
            s.push(format!("fibers.case{g}.substeps={substeps}"));
        }
        s
    };
    let a_out = dir.join("inproc");
    run(&a_out, "inproc", &with(1, 2));
    let a = whole(&a_out);
    assert_eq!(a.len(), 6 * 41);
    let b_out = dir.join("zenoh");
    run(&b_out, "zenoh", &with(3, 2));
    assert_same(&a, &whole(&b_out), "two substeps over zenoh, three shards");
    let c_out = dir.join("one-substep");
    run(&c_out, "inproc", &with(1, 1));
    let c = whole(&c_out);
    assert!(a[&("case1".to_string(), 40)].centre != c[&("case1".to_string(), 40)].centre);
    std::fs::remove_dir_all(&dir).ok();
}
