//! `fiberflow export` end to end (docs/export.md): a two-way run with contact, one group
//! sharded, killed mid-run and restarted (so its recording has two segments), exported to
//! Parquet and read back by pyarrow beside the recording decoded by the Python `mcap`
//! readers (`tests/export_check.py`), bit for bit; and the same run unsharded exports the
//! same tables.

use fiberflow_e2e::*;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

/// 3000 case-1 fibres at random in a band around the centre plane with contact (μ = 0.5)
/// and 60 case-2 fibres in layers, two-way coupled, on the coarse grid: 40 steps of 0.25 t+,
/// a checkpoint every 2.5 t+, full states every 5 steps, the flow's status every 2 and its
/// profiles every 10.
fn launch_file(dir: &Path) -> PathBuf {
    let restart = root().join("recordings/samples/coarse-re150.ckpt");
    let text = format!(
        r#"[run]
id = "export-e2e"
steps = 40
dt_plus = 0.25
coupling = "two-way"
analyze = false
step_timeout_s = 120
checkpoint_every_plus = 2.5

[flow]
status_every_steps = 2
profiles_every_steps = 10

[flow.source]
kind = "dns"
restart = "{}"

[flow.source.dns]
nx = 64
ny = 64
nz = 64
re_tau = 150.0
y1_plus = 0.33

[recorder]
states_every_steps = 5

[[fibers]]
group = "suspension"
case = "case1"
initial_velocity = "fluid"
placement = {{ kind = "random", count = 3000, seed = 5, band_plus = [138.0, 162.0] }}
contact = {{ friction = 0.5 }}

[[fibers]]
group = "layered"
case = "case2"
initial_velocity = "fluid"
placement = {{ kind = "layers", per_layer = 20 }}
"#,
        restart.display()
    );
    let path = dir.join("export-e2e.toml");
    std::fs::write(&path, text).unwrap();
    path
}

fn launch_cmd(file: &Path, out: &Path, transport: &str, sets: &[&str]) -> Command {
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

fn export(run: &Path) -> PathBuf {
    let out = run.join("export");
    let o = Command::new(fiberflow())
        .arg("export")
        .arg(run)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    out
}

/// Row counts per table of the independent check (which fails on any difference).
fn check(run: &Path, exported: &Path) -> serde_json::Value {
    let o = Command::new("python3")
        .arg(root().join("tests/export_check.py"))
        .arg(run)
        .arg(exported)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "export differs from the recording: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    serde_json::from_slice(&o.stdout).unwrap()
}

/// pyarrow installed beside the Python `mcap` readers? (`.ci/run` installs them.)
fn pyarrow_ok() -> bool {
    python_ok()
        && Command::new("python3")
            .args(["-c", "import pyarrow, numpy"])
            .status()
            .map(|s| s.success())
            .unwrap_or(false)
}

/// The run in two shards, over iceoryx2, with shard 1 killed (SIGKILL) after the first
/// checkpoint so that every node restarts and the recording continues in a second segment:
/// the export holds every value of the recording bit for bit (states with the two-way
/// forces and contact loads, the contact lists, metrics, flow status with nulls where
/// Re_τ was not evaluated, profiles), each (group, step) once across the segments, with a
/// unit and a description on every column. Then the same run unsharded, in one process:
/// every table holds the same values in the same order.
#[test]
fn a_run_exports_to_parquet_bitwise_and_shards_give_the_same_tables() {
    if !pyarrow_ok() {
        panic!("this test needs python3 with mcap, mcap-ros2-support, pyarrow and numpy (pip install ...; .ci/run installs them)");
    }
    let _one = one_run_at_a_time();
    let dir = scratch("export");
    let file = launch_file(&dir);

    let sharded = dir.join("sharded");
    std::fs::create_dir_all(&sharded).unwrap();
    let se = std::fs::File::create(sharded.with_extension("stderr")).unwrap();
    let mut child = launch_cmd(&file, &sharded, "iceoryx2", &["fibers.suspension.shards=2"])
        .stdout(Stdio::null())
        .stderr(se)
        .spawn()
        .unwrap();
    wait_for_checkpoint(&sharded, 120);
    let spec = sharded
        .join("config/suspension.1.toml")
        .display()
        .to_string();
    let pids = pids_with(&spec);
    assert_eq!(pids.len(), 1, "shard 1 not found (run over already?)");
    // SAFETY: plain syscall on a process this test's launcher started
    unsafe { libc::kill(pids[0], libc::SIGKILL) };
    assert!(child.wait().unwrap().success());
    let segments = fiberflow_messages::segments::segment_paths(&sharded).unwrap();
    assert!(
        segments.len() >= 2,
        "a restart opens a segment: {segments:?}"
    );

    let a = check(&sharded, &export(&sharded));
    // every table has rows: fibres touched, the fluid pushed them, the flow reported
    for table in ["states", "metrics", "flow", "profiles", "contacts"] {
        assert!(a[table].as_u64().unwrap() > 0, "{table} is empty: {a}");
    }

    // scripts/wall_share.py reads the export: every 2.5 t+ (a state every 5 steps of 0.25),
    // all segments of both groups, shares that add up to one
    let o = Command::new("python3")
        .arg(root().join("scripts/wall_share.py"))
        .arg(sharded.join("export"))
        .arg("2.5")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8_lossy(&o.stdout).to_string();
    let rows: Vec<&str> = text.lines().skip(1).collect();
    assert_eq!(rows.len(), 5, "t+ 0, 2.5, 5, 7.5, 10: {text}");
    let segments = a["states"].as_u64().unwrap() / 9;
    for r in rows {
        let v: Vec<f64> = r.split(',').map(|x| x.parse().unwrap()).collect();
        assert_eq!(v[1] as u64, segments, "{r}");
        assert!((v[2..].iter().sum::<f64>() - 1.0).abs() < 5e-4, "{r}");
    }

    let one = dir.join("one");
    let o = launch_cmd(&file, &one, "inproc", &[]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let b = check(&one, &export(&one));
    assert_eq!(a["states"], b["states"]);
    let same = Command::new("python3")
        .arg("-c")
        .arg(
            "import sys, pyarrow.parquet as pq\n\
             for t in ['states', 'metrics', 'flow', 'profiles', 'contacts']:\n\
             \x20   x, y = (pq.read_table(f'{d}/{t}.parquet') for d in sys.argv[1:])\n\
             \x20   assert x.equals(y), t\n",
        )
        .arg(sharded.join("export"))
        .arg(one.join("export"))
        .output()
        .unwrap();
    assert!(
        same.status.success(),
        "the sharded run's tables differ from the unsharded run's: {}",
        String::from_utf8_lossy(&same.stderr)
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// The Python block of docs/export.md, as it stands there.
fn docs_example() -> String {
    let docs = std::fs::read_to_string(root().join("docs/export.md")).unwrap();
    let after = docs
        .split("<!-- example: abs_z1.py -->")
        .nth(1)
        .expect("docs/export.md: the example's marker");
    let code = after
        .split("```python\n")
        .nth(1)
        .and_then(|c| c.split("```").next())
        .expect("docs/export.md: the example's code block");
    code.to_string()
}

/// A CSV's rows as (first column, the other columns by header name).
fn read_csv(path: &Path) -> (Vec<String>, Vec<Vec<String>>) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header = lines
        .next()
        .unwrap()
        .split(',')
        .map(str::to_string)
        .collect();
    let rows = lines
        .map(|l| l.split(',').map(str::to_string).collect())
        .collect();
    (header, rows)
}

/// The quick run exported (every value checked as above), then the example of
/// docs/export.md, run as it stands on the export: its ⟨|z1|⟩
/// per case and t+ equal the analysis's `case*_abs_z1.csv` (layer "all") to the six
/// decimals that file prints, at every one of its times.
#[test]
fn a_figure_from_the_export_is_the_analysis_figure() {
    if !pyarrow_ok()
        || !Command::new("python3")
            .args(["-c", "import pandas, matplotlib"])
            .status()
            .is_ok_and(|s| s.success())
    {
        panic!(
            "this test needs python3 with pandas, pyarrow and matplotlib (.ci/run installs them)"
        );
    }
    let _one = one_run_at_a_time();
    let dir = scratch("export-example");
    let run = dir.join("quick");
    let o = Command::new(fiberflow())
        .arg("launch")
        .arg(root().join("launch/quick.toml"))
        .arg("--out")
        .arg(&run)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let exported = export(&run);
    // the quick run's tables hold its recording bit for bit too
    let counts = check(&run, &exported);
    assert_eq!(
        counts["states"],
        6 * 50 * 7 * 325,
        "six cases of 50 fibres of 7 segments"
    );
    let script = dir.join("abs_z1.py");
    std::fs::write(&script, docs_example()).unwrap();
    let o = Command::new("python3")
        .arg(&script)
        .arg(&exported)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(exported.join("abs_z1.png").exists());
    let (header, rows) = read_csv(&exported.join("abs_z1.csv"));
    assert_eq!(header[0], "t_plus");
    let mut compared = 0;
    for (col, case) in header.iter().enumerate().skip(1) {
        let (h, want) = read_csv(&run.join(format!("analysis/{case}_abs_z1.csv")));
        assert_eq!(h[..3], ["t_plus", "layer", "mean_abs_z1"]);
        let want: Vec<(f64, f64)> = want
            .iter()
            .filter(|r| r[1] == "all")
            .map(|r| (r[0].parse().unwrap(), r[2].parse().unwrap()))
            .collect();
        assert_eq!(want.len(), rows.len(), "{case}: times");
        for (row, (t, m)) in rows.iter().zip(&want) {
            let t_got: f64 = row[0].parse().unwrap();
            let m_got: f64 = row[col].parse().unwrap();
            assert!((t_got - t).abs() < 1e-4, "{case}: t+ {t_got} against {t}");
            // the analysis prints six decimals
            assert!(
                (m_got - m).abs() <= 5e-7 + 1e-12,
                "{case} at t+ {t}: {m_got} against the analysis's {m}"
            );
            compared += 1;
        }
    }
    assert_eq!(compared, 6 * 325, "six cases, steps 0..=324");
    std::fs::remove_dir_all(&dir).ok();
}
