//! Launch files (TOML): one run — its flow node, fibre groups and recorder — checked up
//! front with errors that name the key.
//!
//! Size (≈ 630 lines before the tests): every table's schema and its checks, in the file's
//! order; the `--set` overrides and renamed keys are `overrides.rs`, the keys' reference
//! `keys.rs`.

use anyhow::{bail, Context, Result};
use fiberflow_bus::Transport;
use fiberflow_fiber::FiberNodeConfig;
use fiberflow_flow::{FlowNodeConfig, FlowSource};
use fiberflow_messages::NodeRole;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

pub use crate::overrides::apply_overrides;
use crate::overrides::refuse_misplaced_keys;

/// `[run]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct RunSection {
    /// Run id: a non-empty name of [A-Za-z0-9_-]; the topics' prefix and the default
    /// output folder `recordings/<id>` (`recordings/<id>-r<i>` for realisation i ≥ 1).
    pub id: String,
    /// Number of coupling steps, in 1..=1e8.
    pub steps: u64,
    /// Coupling (fibre and flow) time step, viscous units.
    pub dt_plus: f64,
    /// Channel box in wall units; default 2πh × 2h × πh at the DNS Re_tau (or 150).
    #[serde(default)]
    pub box_plus: Option<[f64; 3]>,
    /// Seconds any node waits for a peer's message of one step, in (0, 3600].
    #[serde(default = "default_step_timeout")]
    pub step_timeout_s: f64,
    /// Seconds without a word from a fibre node (every node says it is alive once a
    /// second) after which the flow node takes it as gone — hung, or its host or link lost —
    /// and fails the step at once, naming it, for the restart policy to handle: 0 (off:
    /// only `step_timeout_s`) or in [3, 3600].
    #[serde(default = "default_liveness")]
    pub liveness_s: f64,
    /// Default transport when `--transport` is not given: `"inproc"`, `"zenoh"` or
    /// `"iceoryx2"`.
    #[serde(default = "default_transport")]
    #[schemars(with = "String")]
    pub transport: Transport,
    /// Run the analysis after the run (and write the .rrd scene).
    #[serde(default)]
    pub analyze: bool,
    /// Coupled checkpoint (flow field, every group, recorder position) every this many
    /// t+ (0 = never). Runs shorter than the interval never write one.
    #[serde(default = "default_checkpoint_every_plus")]
    pub checkpoint_every_plus: f64,
    /// What the launcher does when a node dies mid-run.
    #[serde(default)]
    pub restart: RestartSection,
    /// How the fibre nodes share the cores with the flow node.
    #[serde(default)]
    pub fiber_scheduling: FiberScheduling,
    /// Processes that carry the fibre nodes of one launcher: 0 (the default) runs each
    /// fibre node in a process of its own; N ≥ 1 spreads them over N processes, each
    /// running its share as threads on one bus connection (fewer processes, transport
    /// sessions and task switches; a node that dies takes its process's others with it).
    #[serde(default)]
    pub fiber_processes: u32,
    /// `"one-way"` (the default, the paper's): the fibres feel the flow, the flow does not
    /// feel them. `"two-way"`: every segment's hydrodynamic force goes back to the fluid as
    /// a body force (docs/two-way.md); all groups of the run are then one suspension.
    #[serde(default)]
    pub coupling: Coupling,
    /// Which realisation of the run this is (docs/realisations.md), in 0..=1000000: 0 (the
    /// default) starts from the flow source's field and the groups' placement seeds as
    /// given; i ≥ 1 gives the run its own start — the DNS field with realisation i's seeded
    /// divergence-free disturbance and every random placement's seed mixed with i — the
    /// same bits for the same i.
    #[serde(default)]
    pub realisation: u32,
}

/// `run.coupling`: whether the fluid feels the fibres.
#[derive(
    Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "kebab-case")]
pub enum Coupling {
    #[default]
    OneWay,
    TwoWay,
}

/// `run.fiber_scheduling`: the CPU scheduling of the fibre nodes when they run as
/// processes of their own (the in-process bus leaves every thread as it is).
#[derive(
    Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "kebab-case")]
pub enum FiberScheduling {
    /// The default time sharing, equal with the flow node: safe on a machine shared
    /// with other work.
    #[default]
    Normal,
    /// Linux `SCHED_IDLE`: they run when a core would otherwise idle, so they no longer
    /// preempt the field step's parallel loops, which their step overlaps. For a run that
    /// has the machine to itself: beside another busy run they get only its idle time.
    Idle,
}

fn default_checkpoint_every_plus() -> f64 {
    100.0
}

/// `[run.restart]`: supervision of the nodes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct RestartSection {
    /// `"on-failure"`: roll every node back to the newest complete checkpoint (or the
    /// start) and go on; `"never"`: stop the run.
    #[serde(default = "default_policy")]
    pub policy: RestartPolicy,
    /// Restarts allowed before the run stops.
    #[serde(default = "default_max_restarts")]
    pub max_restarts: u32,
}

/// `run.restart.policy`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "kebab-case")]
pub enum RestartPolicy {
    Never,
    OnFailure,
}

fn default_policy() -> RestartPolicy {
    RestartPolicy::OnFailure
}
fn default_max_restarts() -> u32 {
    3
}

impl Default for RestartSection {
    fn default() -> Self {
        Self {
            policy: default_policy(),
            max_restarts: default_max_restarts(),
        }
    }
}

impl RunSection {
    /// The run's folder under `recordings/`: its id, or `<id>-r<i>` for realisation i ≥ 1
    /// (so realisations sit side by side).
    pub fn default_folder(&self) -> String {
        match self.realisation {
            0 => self.id.clone(),
            i => format!("{}-r{i}", self.id),
        }
    }

    /// Coupling steps between checkpoints (0 = never).
    pub fn checkpoint_every_steps(&self) -> u64 {
        if self.checkpoint_every_plus <= 0.0 {
            return 0;
        }
        (self.checkpoint_every_plus / self.dt_plus).round().max(1.0) as u64
    }
}

fn default_step_timeout() -> f64 {
    120.0
}
fn default_liveness() -> f64 {
    30.0
}
fn default_transport() -> Transport {
    Transport::Zenoh
}

/// `[recorder]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct RecorderSection {
    /// Run the recorder node (writes `run.mcap`).
    #[serde(default = "default_true")]
    pub enabled: bool,
    /// Record every group's full state (and its PointCloud2) every this many steps, in
    /// 1..=`run.steps`; the
    /// first and last step always. Metrics, flow status and profiles are recorded every
    /// time they are published.
    #[serde(default = "default_one")]
    pub states_every_steps: u64,
    /// Record the flow samples (needed only to re-drive fibre nodes with `replay`).
    #[serde(default = "default_true")]
    pub samples: bool,
    /// Chunk compression: "zstd" (default, smallest files), "lz4" (least CPU) or "none".
    #[serde(default)]
    pub compression: fiberflow_recorder::ChunkCompression,
}

fn default_one() -> u64 {
    1
}

fn default_true() -> bool {
    true
}

impl Default for RecorderSection {
    fn default() -> Self {
        Self {
            enabled: true,
            states_every_steps: 1,
            samples: true,
            compression: fiberflow_recorder::ChunkCompression::Zstd,
        }
    }
}

/// `[network]`: one run spread over several hosts. zenoh only, always over TLS with
/// mutual authentication and access control. The host that runs the flow node is the
/// zenoh router every other node connects to; `fiberflow launch FILE --host NAME` starts
/// one host's share of the nodes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct NetworkSection {
    /// The endpoint every node connects to, e.g. `tls/head.example.org:7447`.
    pub rendezvous: String,
    /// Where the flow node's host binds (default: the rendezvous endpoint), e.g.
    /// `tls/0.0.0.0:7447`.
    #[serde(default)]
    pub listen: Option<String>,
    /// PEM of the CA that signed every host's certificate.
    pub root_ca_certificate: PathBuf,
    /// Certificate common names allowed to publish and subscribe under the run's topics
    /// (zenoh access control, deny by default).
    pub allowed_common_names: Vec<String>,
    /// One table per host.
    pub hosts: Vec<HostSection>,
}

impl NetworkSection {
    /// The host names, comma-separated (for messages).
    pub fn host_names(&self) -> String {
        let names: Vec<_> = self.hosts.iter().map(|h| h.name.as_str()).collect();
        names.join(", ")
    }
}

/// `[[network.hosts]]`: the nodes one host runs and its TLS identity.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct HostSection {
    /// The name `fiberflow launch FILE --host NAME` takes.
    pub name: String,
    /// Node names: `flow`, `recorder`, fibre group names.
    pub nodes: Vec<String>,
    /// PEM certificate of this host (its common name must be allowed).
    pub certificate: PathBuf,
    /// PEM private key of that certificate.
    pub private_key: PathBuf,
}

/// `[[suspensions]]`: groups whose fibres touch each other (fibre–fibre contact between
/// groups, docs/contact.md); groups in no suspension touch only their own fibres.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct SuspensionSection {
    /// Two or more group names, each with `contact` set alike (the same `friction` and
    /// `sweeps`), in no other suspension. Placed in this order: a group placed at random
    /// keeps clear of the groups before it.
    pub groups: Vec<String>,
}

/// The whole launch file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct LaunchFile {
    pub run: RunSection,
    pub flow: FlowNodeConfig,
    #[serde(default)]
    pub fibers: Vec<FiberNodeConfig>,
    #[serde(default)]
    pub suspensions: Vec<SuspensionSection>,
    #[serde(default)]
    pub recorder: RecorderSection,
    #[serde(default)]
    pub network: Option<NetworkSection>,
}

impl LaunchFile {
    /// Reads a launch file with `--set` overrides, resolves relative paths against the
    /// file's folder, and validates. The returned text is the effective launch
    /// file: the file itself, or with overrides the merged TOML under a header naming them
    /// (its digest identifies the run's configuration for checkpoints).
    pub fn load_with(path: &Path, sets: &[String]) -> Result<(Self, String)> {
        let mut text = std::fs::read_to_string(path)
            .with_context(|| format!("reading launch file {}", path.display()))?;
        if !sets.is_empty() {
            let mut doc: toml::Table = toml::from_str(&text)
                .with_context(|| format!("parsing launch file {}", path.display()))?;
            apply_overrides(&mut doc, sets)?;
            let merged = toml::to_string(&doc).context("writing the merged launch file")?;
            text = format!(
                "# {} with overrides: {}\n{merged}",
                path.display(),
                sets.join(" ")
            );
        }
        refuse_misplaced_keys(&text)?;
        let mut lf: LaunchFile = toml::from_str(&text).with_context(|| {
            if sets.is_empty() {
                format!("parsing launch file {}", path.display())
            } else {
                format!(
                    "parsing launch file {} after --set {}",
                    path.display(),
                    sets.join(" ")
                )
            }
        })?;
        let base = path
            .parent()
            .map(Path::to_path_buf)
            .unwrap_or_else(|| PathBuf::from("."));
        let fix = |p: &mut PathBuf| {
            if p.is_relative() {
                *p = base.join(&*p);
            }
        };
        if let FlowSource::Dns {
            restart: Some(r), ..
        } = &mut lf.flow.source
        {
            fix(r);
        }
        if let Some(sp) = lf.flow.spinup.as_mut() {
            if let Some(r) = sp.restart.as_mut() {
                fix(r);
            }
        }
        if let Some(n) = lf.network.as_mut() {
            fix(&mut n.root_ca_certificate);
            for h in &mut n.hosts {
                fix(&mut h.certificate);
                fix(&mut h.private_key);
            }
        }
        lf.flow.dt_plus = lf.run.dt_plus;
        lf.flow.steps = lf.run.steps;
        lf.flow.realisation = lf.run.realisation;
        for f in &mut lf.fibers {
            if let fiberflow_fiber::config::PlacementConfig::Random { seed, .. } = &mut f.placement
            {
                *seed = fiberflow_dns::perturb::realisation_seed(*seed, lf.run.realisation);
            }
        }
        lf.validate()?;
        Ok((lf, text))
    }

    pub fn validate(&self) -> Result<()> {
        let r = &self.run;
        if r.id.is_empty()
            || !r
                .id
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
        {
            bail!(
                "run.id must be a non-empty name of [A-Za-z0-9_-] (got {:?})",
                r.id
            );
        }
        if r.realisation > 1_000_000 {
            bail!(
                "run.realisation must be in 0..=1000000 (got {})",
                r.realisation
            );
        }
        if r.steps == 0 || r.steps > 100_000_000 {
            bail!("run.steps must be in 1..=1e8 (got {})", r.steps);
        }
        if !(r.checkpoint_every_plus == 0.0
            || (r.checkpoint_every_plus >= r.dt_plus && r.checkpoint_every_plus.is_finite()))
        {
            bail!(
                "run.checkpoint_every_plus must be 0 (never) or in [run.dt_plus = {}, inf) (got {})",
                r.dt_plus,
                r.checkpoint_every_plus
            );
        }
        if let (Some(b), FlowSource::Dns { dns, .. }) = (r.box_plus, &self.flow.source) {
            let dns_box = [dns.lx * dns.re_tau, 2.0 * dns.re_tau, dns.lz * dns.re_tau];
            if b.iter()
                .zip(dns_box)
                .any(|(a, d)| !((a - d).abs() <= 1e-6 * d))
            {
                bail!(
                    "run.box_plus = {b:?} differs from the DNS box {dns_box:?} (lx, 2, lz times re_tau): \
                     fibres would meet walls where the flow has none; remove run.box_plus or make them agree"
                );
            }
        }
        if !(r.step_timeout_s > 0.0 && r.step_timeout_s <= 3600.0) {
            bail!(
                "run.step_timeout_s must be in (0, 3600] (got {})",
                r.step_timeout_s
            );
        }
        if !(r.liveness_s == 0.0 || (3.0..=3600.0).contains(&r.liveness_s)) {
            bail!(
                "run.liveness_s must be 0 (off) or in [3, 3600] (got {})",
                r.liveness_s
            );
        }
        if !(1..=r.steps).contains(&self.recorder.states_every_steps) {
            bail!(
                "recorder.states_every_steps must be in 1..=run.steps = {} (got {})",
                r.steps,
                self.recorder.states_every_steps
            );
        }
        let fiber_nodes = self.pieces().map(|p| p.len()).unwrap_or(0);
        if r.fiber_processes as usize > fiber_nodes.max(1) {
            bail!(
                "run.fiber_processes must be in 0..={} (the fibre nodes; 0 = a process each) (got {})",
                fiber_nodes.max(1),
                r.fiber_processes
            );
        }
        if r.coupling == Coupling::TwoWay && !matches!(self.flow.source, FlowSource::Dns { .. }) {
            bail!(
                "run.coupling = \"two-way\" needs flow.source.kind = \"dns\" (an analytic flow \
                 cannot feel the fibres); use run.coupling = \"one-way\""
            );
        }
        self.flow.validate()?;
        let mut names = std::collections::BTreeSet::new();
        for f in &self.fibers {
            f.build(self.box_plus())
                .map_err(|e| anyhow::anyhow!("{e}"))?;
            if !names.insert(f.group.clone()) {
                bail!("fibers: group name {:?} is used twice", f.group);
            }
            if NodeRole::of(&f.group) != NodeRole::Fiber || f.group == "launcher" {
                bail!(
                    "fibers[{}].group: the names flow, recorder and launcher are reserved",
                    f.group
                );
            }
        }
        self.validate_suspensions()?;
        if let Some(n) = &self.network {
            self.validate_network(n)?;
        }
        Ok(())
    }

    /// `[[suspensions]]`: known groups with contact set alike, each in one suspension, and
    /// a start without overlaps between them.
    fn validate_suspensions(&self) -> Result<()> {
        let mut seen = std::collections::BTreeSet::new();
        for (i, s) in self.suspensions.iter().enumerate() {
            if s.groups.len() < 2 {
                bail!(
                    "suspensions[{i}].groups must name 2 or more groups (got {:?})",
                    s.groups
                );
            }
            let members = self.suspension_members(i)?;
            for m in &members {
                if !seen.insert(m.group.clone()) {
                    bail!(
                        "suspensions[{i}].groups: group {:?} is named twice or is in another suspension",
                        m.group
                    );
                }
                let (Some(c), Some(c0)) = (&m.contact, &members[0].contact) else {
                    bail!(
                        "suspensions[{i}].groups: group {:?} has no contact; allowed: groups with fibers.contact set",
                        m.group
                    );
                };
                if c != c0 {
                    bail!(
                        "suspensions[{i}].groups: groups {:?} and {:?} set fibers.contact differently ({c0:?} and {c:?}); allowed: the same friction and sweeps",
                        members[0].group,
                        m.group
                    );
                }
            }
            fiberflow_fiber::config::build_suspension(&members, self.box_plus())
                .map_err(|e| anyhow::anyhow!("{e}"))?;
        }
        Ok(())
    }

    /// The groups of suspension `i`, in its order.
    pub fn suspension_members(&self, i: usize) -> Result<Vec<FiberNodeConfig>> {
        let s = self
            .suspensions
            .get(i)
            .with_context(|| format!("no suspension {i}"))?;
        s.groups
            .iter()
            .map(|g| {
                self.fibers
                    .iter()
                    .find(|f| &f.group == g)
                    .cloned()
                    .with_context(|| {
                        format!(
                            "suspensions[{i}].groups: no fibre group {g:?} (groups: {})",
                            self.groups().join(", ")
                        )
                    })
            })
            .collect()
    }

    /// The groups of the suspension `group` belongs to, in its order (empty: none).
    pub fn suspension_of(&self, group: &str) -> Result<Vec<FiberNodeConfig>> {
        match self
            .suspensions
            .iter()
            .position(|s| s.groups.iter().any(|g| g == group))
        {
            Some(i) => self.suspension_members(i),
            None => Ok(Vec::new()),
        }
    }

    fn validate_network(&self, n: &NetworkSection) -> Result<()> {
        for (key, ep) in [
            ("network.rendezvous", Some(&n.rendezvous)),
            ("network.listen", n.listen.as_ref()),
        ] {
            if let Some(ep) = ep {
                if !ep.starts_with("tls/") {
                    bail!("{key} must be a tls/<host>:<port> endpoint: multi-host runs are always encrypted (got {ep:?})");
                }
            }
        }
        if n.allowed_common_names.is_empty() {
            bail!("network.allowed_common_names must list the certificate names of the hosts");
        }
        let mut all = vec!["flow".to_string()];
        all.extend(self.fiber_nodes()?);
        if self.recorder.enabled {
            all.push("recorder".into());
        }
        let mut seen = std::collections::BTreeMap::new();
        for h in &n.hosts {
            for node in &h.nodes {
                if !all.contains(node) {
                    bail!(
                        "network.hosts[{}].nodes: {node:?} is not a node of this run (nodes: {})",
                        h.name,
                        all.join(", ")
                    );
                }
                if let Some(other) = seen.insert(node.clone(), h.name.clone()) {
                    bail!(
                        "network.hosts: node {node:?} is on both {other} and {}",
                        h.name
                    );
                }
            }
        }
        let missing: Vec<_> = all
            .iter()
            .filter(|x| !seen.contains_key(*x))
            .cloned()
            .collect();
        if !missing.is_empty() {
            bail!("network.hosts: no host runs {}", missing.join(", "));
        }
        Ok(())
    }

    /// The host section called `name` (multi-host runs).
    pub fn host(&self, name: &str) -> Result<&HostSection> {
        let n = self
            .network
            .as_ref()
            .context("--host is only for launch files with a [network] section")?;
        n.hosts.iter().find(|h| h.name == name).with_context(|| {
            format!(
                "--host {name:?}: the launch file's hosts are {}",
                n.host_names()
            )
        })
    }

    /// The channel box in wall units.
    pub fn box_plus(&self) -> [f64; 3] {
        if let Some(b) = self.run.box_plus {
            return b;
        }
        let (re, lx, lz) = match &self.flow.source {
            FlowSource::Dns { dns, .. } => (dns.re_tau, dns.lx, dns.lz),
            FlowSource::Analytic { .. } => {
                (150.0, 2.0 * std::f64::consts::PI, std::f64::consts::PI)
            }
        };
        [lx * re, 2.0 * re, lz * re]
    }

    pub fn groups(&self) -> Vec<String> {
        self.fibers.iter().map(|f| f.group.clone()).collect()
    }

    /// Every fibre node's share of its group, in launch-file order.
    pub fn pieces(&self) -> Result<Vec<fiberflow_messages::pieces::Piece>> {
        let mut v = Vec::new();
        for f in &self.fibers {
            v.extend(
                f.pieces(self.box_plus())
                    .map_err(|e| anyhow::anyhow!("{e}"))?,
            );
        }
        Ok(v)
    }

    /// The fibre nodes: one per group, or `<group>.<i>` per shard of a sharded group.
    pub fn fiber_nodes(&self) -> Result<Vec<String>> {
        Ok(self.pieces()?.iter().map(|p| p.node()).collect())
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// Every `.toml` under `launch/` and its sub-folders, sorted.
    pub(crate) fn shipped_launch_files() -> Vec<PathBuf> {
        fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
            for e in std::fs::read_dir(dir).unwrap().flatten() {
                let p = e.path();
                if p.is_dir() {
                    walk(&p, out);
                } else if p.extension().is_some_and(|x| x == "toml") {
                    out.push(p);
                }
            }
        }
        let mut out = Vec::new();
        walk(
            &Path::new(env!("CARGO_MANIFEST_DIR")).join("../../launch"),
            &mut out,
        );
        out.sort();
        out
    }

    fn write_launch(dir: &Path, flow_extra: &str) -> PathBuf {
        let text = format!(
            "[run]\nid = \"t\"\nsteps = 10\ndt_plus = 0.25\n\n[flow]\n{flow_extra}\n\n\
             [flow.source]\nkind = \"analytic\"\nflow = {{ kind = \"simple_shear\", shear_rate = 0.1 }}\n"
        );
        let p = dir.join("t.toml");
        std::fs::write(&p, text).unwrap();
        p
    }

    #[test]
    fn interpolation_key_parses_and_bad_values_are_named() {
        let dir = std::env::temp_dir().join(format!("ff-lf-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let (lf, _) =
            LaunchFile::load_with(&write_launch(&dir, "interpolation = \"tricubic\""), &[])
                .unwrap();
        assert_eq!(
            lf.flow.interpolation,
            fiberflow_dns::sample::Interpolation::Tricubic
        );
        let (lf, _) = LaunchFile::load_with(&write_launch(&dir, ""), &[]).unwrap();
        assert_eq!(
            lf.flow.interpolation,
            fiberflow_dns::sample::Interpolation::Trilinear
        );
        let err = LaunchFile::load_with(&write_launch(&dir, "interpolation = \"quintic\""), &[])
            .unwrap_err();
        let msg = format!("{err:#}");
        assert!(
            msg.contains("interpolation") && msg.contains("tricubic"),
            "{msg}"
        );
        std::fs::remove_dir_all(&dir).ok();
    }

    /// `flow.steps` / `flow.dt_plus` in a launch file would be replaced by the run's: an
    /// error that names the key to use instead.
    #[test]
    fn run_keys_under_flow_are_refused_naming_the_run_key() {
        let dir = std::env::temp_dir().join(format!("ff-fk-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        for (extra, want) in [
            ("steps = 5", "run.steps"),
            ("dt_plus = 0.1", "run.dt_plus"),
            ("realisation = 2", "run.realisation"),
        ] {
            let err = LaunchFile::load_with(&write_launch(&dir, extra), &[]).unwrap_err();
            let msg = format!("{err:#}");
            assert!(msg.contains(want) && msg.contains("flow."), "{msg}");
        }
        let err =
            LaunchFile::load_with(&write_launch(&dir, ""), &["flow.steps=3".into()]).unwrap_err();
        assert!(format!("{err:#}").contains("run.steps"), "{err:#}");
        std::fs::remove_dir_all(&dir).ok();
    }

    /// `run.realisation` reaches the flow node and mixes every random placement's seed
    /// (realisation 0 leaves the configured seeds); out of range, the error names the key.
    #[test]
    fn a_realisation_reaches_the_flow_and_every_random_placement() {
        let dir = std::env::temp_dir().join(format!("ff-real-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("r.toml");
        std::fs::write(
            &file,
            "[run]\nid = \"r\"\nsteps = 10\ndt_plus = 0.25\n\n[flow.source]\nkind = \"analytic\"\n\
             flow = { kind = \"simple_shear\", shear_rate = 0.1 }\n\n\
             [[fibers]]\ngroup = \"a\"\nplacement = { kind = \"random\", count = 5, seed = 7 }\n\n\
             [[fibers]]\ngroup = \"b\"\n",
        )
        .unwrap();
        let seed = |lf: &LaunchFile| match &lf.fibers[0].placement {
            fiberflow_fiber::config::PlacementConfig::Random { seed, .. } => *seed,
            other => panic!("{other:?}"),
        };
        let (lf0, _) = LaunchFile::load_with(&file, &[]).unwrap();
        assert_eq!(
            (lf0.run.realisation, lf0.flow.realisation, seed(&lf0)),
            (0, 0, 7)
        );
        let (lf3, _) = LaunchFile::load_with(&file, &["run.realisation=3".into()]).unwrap();
        let (lf3b, _) = LaunchFile::load_with(&file, &["run.realisation=3".into()]).unwrap();
        let (lf4, _) = LaunchFile::load_with(&file, &["run.realisation=4".into()]).unwrap();
        assert_eq!(lf3.flow.realisation, 3);
        assert_eq!(seed(&lf3), fiberflow_dns::perturb::realisation_seed(7, 3));
        assert_eq!(seed(&lf3), seed(&lf3b));
        assert!(seed(&lf3) != 7 && seed(&lf3) != seed(&lf4));
        // the layers of group b have no seed: the same fibres in every realisation
        assert_eq!(lf3.fibers[1].placement, lf0.fibers[1].placement);
        assert_eq!(lf3.run.default_folder(), "r-r3");
        assert_eq!(lf0.run.default_folder(), "r");
        let err = LaunchFile::load_with(&file, &["run.realisation=2000000".into()]).unwrap_err();
        let msg = format!("{err:#}");
        assert!(
            msg.contains("run.realisation") && msg.contains("0..=1000000"),
            "{msg}"
        );
        std::fs::remove_dir_all(&dir).ok();
    }

    /// The old spellings of renamed keys name the new key.
    #[test]
    fn renamed_keys_name_their_new_spelling() {
        let dir = std::env::temp_dir().join(format!("ff-rn-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        for (old, new, value) in [
            ("run.fibre_processes", "run.fiber_processes", "1"),
            ("run.fibre_scheduling", "run.fiber_scheduling", "\"idle\""),
            ("flow.status_every", "flow.status_every_steps", "5"),
            ("flow.profiles_every", "flow.profiles_every_steps", "5"),
            ("flow.slices_every", "flow.slices_every_steps", "5"),
            ("recorder.states_every", "recorder.states_every_steps", "5"),
        ] {
            let set = format!("{old}={value}");
            let err = LaunchFile::load_with(&write_launch(&dir, ""), &[set]).unwrap_err();
            let msg = format!("{err:#}");
            assert!(
                msg.contains(&format!("{old} was renamed: use {new}")),
                "{msg}"
            );
            let set = format!("{new}={value}");
            LaunchFile::load_with(&write_launch(&dir, ""), &[set]).unwrap();
        }
        // in any [[fibers]] table, and in the nested DNS table
        for (text, new) in [
            (
                "[[fibers]]\ncase = \"case1\"\n[[fibers]]\ncase = \"case2\"\nmetrics_every = 3\n",
                "fibers[].metrics_every_steps",
            ),
            (
                "[flow.source.dns]\ncheck_every = 3\n",
                "flow.source.dns.check_every_steps",
            ),
        ] {
            let err = refuse_misplaced_keys(text).unwrap_err();
            assert!(
                format!("{err:#}").contains(&format!("was renamed: use {new}")),
                "{err:#}"
            );
            let fixed = text.replace("_every = 3", "_every_steps = 3");
            refuse_misplaced_keys(&fixed).unwrap();
        }
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn network_section_is_checked() {
        let dir = std::env::temp_dir().join(format!("ff-net-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let net = |rendezvous: &str, head: &str, worker: &str| {
            format!(
                "\n[[fibers]]\ngroup = \"g1\"\ncase = \"case1\"\n\n[network]\n\
                 rendezvous = \"{rendezvous}\"\nroot_ca_certificate = \"ca.pem\"\n\
                 allowed_common_names = [\"a\"]\n\
                 [[network.hosts]]\nname = \"head\"\nnodes = [{head}]\n\
                 certificate = \"h.pem\"\nprivate_key = \"h-key.pem\"\n\
                 [[network.hosts]]\nname = \"worker\"\nnodes = [{worker}]\n\
                 certificate = \"w.pem\"\nprivate_key = \"w-key.pem\"\n"
            )
        };
        let load = |extra: String| {
            let p = write_launch(&dir, "");
            let mut text = std::fs::read_to_string(&p).unwrap();
            text.push_str(&extra);
            std::fs::write(&p, text).unwrap();
            LaunchFile::load_with(&p, &[]).map_err(|e| format!("{e:#}"))
        };
        let ok = load(net("tls/h:7447", "\"flow\", \"recorder\"", "\"g1\"")).unwrap();
        assert_eq!(ok.0.host("worker").unwrap().nodes, vec!["g1".to_string()]);
        assert!(ok.0.host("w2").is_err());
        let e = load(net("tcp/h:7447", "\"flow\", \"recorder\"", "\"g1\"")).unwrap_err();
        assert!(
            e.contains("network.rendezvous") && e.contains("tls/"),
            "{e}"
        );
        let e = load(net(
            "tls/h:7447",
            "\"flow\", \"g1\"",
            "\"g1\", \"recorder\"",
        ))
        .unwrap_err();
        assert!(e.contains("both"), "{e}");
        let e = load(net("tls/h:7447", "\"flow\"", "\"g1\"")).unwrap_err();
        assert!(e.contains("no host runs recorder"), "{e}");
        let e = load(net("tls/h:7447", "\"flow\", \"recorder\"", "\"g2\"")).unwrap_err();
        assert!(e.contains("not a node of this run"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn set_overrides_keys_and_reports_bad_ones() {
        let dir = std::env::temp_dir().join(format!("ff-set-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = write_launch(&dir, "");
        let mut text = std::fs::read_to_string(&p).unwrap();
        text.push_str("\n[[fibers]]\ngroup = \"g1\"\ncase = \"case1\"\n");
        std::fs::write(&p, text).unwrap();
        let sets = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        let (lf, eff) = LaunchFile::load_with(
            &p,
            &sets(&[
                "run.steps=400",
                "run.checkpoint_every_plus=5",
                "run.transport=iceoryx2",
                "fibers.g1.density_ratio=2300.0",
                "fibers.g1.placement.per_layer=3",
                "run.restart.max_restarts=1",
                "run.liveness_s=0",
            ]),
        )
        .unwrap();
        assert_eq!(lf.run.steps, 400);
        assert_eq!(lf.run.liveness_s, 0.0);
        assert_eq!(lf.run.checkpoint_every_steps(), 20);
        assert_eq!(lf.run.transport, Transport::Iceoryx2);
        // a transport that is none of them: the line, and the allowed values
        let e = format!(
            "{:#}",
            LaunchFile::load_with(&p, &sets(&["run.transport=\"shm\""])).unwrap_err()
        );
        assert!(
            e.contains("transport = \"shm\"") && e.contains("`inproc`, `zenoh`, `iceoryx2`"),
            "{e}"
        );
        assert_eq!(lf.run.restart.max_restarts, 1);
        assert_eq!(lf.fibers[0].density_ratio, Some(2300.0));
        // a group without a placement table keeps the default (layers) kind
        assert!(matches!(
            lf.fibers[0].placement,
            fiberflow_fiber::config::PlacementConfig::Layers { per_layer: 3, .. }
        ));
        assert!(eff.starts_with('#') && eff.contains("run.steps=400"));
        // the effective text is itself a launch file with the same content
        let again = dir.join("eff.toml");
        std::fs::write(&again, &eff).unwrap();
        assert_eq!(LaunchFile::load_with(&again, &[]).unwrap().0.run, lf.run);
        for (set, want) in [
            ("run.stepz=3", "stepz"),
            ("run.steps=-1", "run.steps"),
            ("run.checkpoint_every_plus=0.1", "run.checkpoint_every_plus"),
            ("fibers.nope.density_ratio=3", "no entry \"nope\""),
            ("run.steps", "KEY=VALUE"),
            ("run.restart.policy=sometimes", "policy"),
            ("run.fiber_scheduling=low", "fiber_scheduling"),
            ("run.fiber_processes=-1", "fiber_processes"),
            (
                "run.fiber_processes=99",
                "run.fiber_processes must be in 0..=",
            ),
            (
                "run.liveness_s=1",
                "run.liveness_s must be 0 (off) or in [3, 3600]",
            ),
        ] {
            let e = format!(
                "{:#}",
                LaunchFile::load_with(&p, &sets(&[set])).unwrap_err()
            );
            assert!(e.contains(want), "--set {set}: {e}");
        }
        std::fs::remove_dir_all(&dir).ok();
    }

    /// Every shipped launch file loads and passes the checks; the runs that have the
    /// machine to themselves (the paper's set-ups, the scale benchmark) put their fibre
    /// nodes in the DNS's idle time and in one process, the others share the cores as
    /// usual, a process per node.
    #[test]
    fn every_shipped_launch_file_loads() {
        let mut idle = Vec::new();
        let mut n = 0;
        for p in shipped_launch_files() {
            // the spin-up files configure `fiberflow spinup`, not a launch
            let text = std::fs::read_to_string(&p).unwrap_or_default();
            if p.extension().is_none_or(|x| x != "toml")
                || !text.lines().any(|l| l.trim() == "[run]")
            {
                continue;
            }
            let (lf, _) =
                LaunchFile::load_with(&p, &[]).unwrap_or_else(|e| panic!("{}: {e:#}", p.display()));
            n += 1;
            if lf.run.fiber_scheduling == FiberScheduling::Idle {
                idle.push(p.file_name().unwrap().to_string_lossy().to_string());
            }
            // the same runs carry their fibre nodes in one process
            assert_eq!(
                lf.run.fiber_processes,
                u32::from(lf.run.fiber_scheduling == FiberScheduling::Idle),
                "{}",
                p.display()
            );
        }
        idle.sort();
        assert_eq!(n, 17, "launch files with a [run] table");
        assert_eq!(
            idle,
            [
                "paper-1e4.toml",
                "paper.toml",
                "scale-1e4.toml",
                "two-way.toml"
            ]
        );
    }

    /// `[[suspensions]]` names known groups, each with contact set alike and in one
    /// suspension only; bad ones are refused naming the key; a good one loads and its
    /// groups are placed clear of each other.
    #[test]
    fn suspensions_are_checked() {
        let dir = std::env::temp_dir().join(format!("ff-susp-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("s.toml");
        let group = |name: &str, contact: &str| {
            format!(
                "[[fibers]]\ngroup = \"{name}\"\ncase = \"case1\"\n\
                 placement = {{ kind = \"random\", count = 300, band_plus = [130.0, 170.0] }}\n{contact}\n"
            )
        };
        let text = |extra: &str, b_contact: &str| {
            format!(
                "[run]\nid = \"s\"\nsteps = 2\ndt_plus = 0.25\n\
                 [flow.source]\nkind = \"analytic\"\nflow = {{ kind = \"simple_shear\", shear_rate = 0.1 }}\n\
                 {}{}{}{extra}",
                group("a", "contact = { friction = 0.5 }"),
                group("b", b_contact),
                group("c", "contact = { friction = 0.5 }"),
            )
        };
        let ok = "[[suspensions]]\ngroups = [\"a\", \"b\"]\n";
        std::fs::write(&p, text(ok, "contact = { friction = 0.5 }")).unwrap();
        let (lf, _) = LaunchFile::load_with(&p, &[]).unwrap();
        assert_eq!(lf.suspension_of("b").unwrap().len(), 2);
        assert!(lf.suspension_of("c").unwrap().is_empty());
        for (extra, b_contact, key) in [
            (
                "[[suspensions]]\ngroups = [\"a\"]\n",
                "contact = {}",
                "suspensions[0].groups must name 2 or more",
            ),
            (
                "[[suspensions]]\ngroups = [\"a\", \"x\"]\n",
                "contact = {}",
                "suspensions[0].groups: no fibre group \"x\"",
            ),
            (ok, "", "group \"b\" has no contact"),
            (ok, "contact = { friction = 0.3 }", "set fibers.contact differently"),
            (
                "[[suspensions]]\ngroups = [\"a\", \"c\"]\n[[suspensions]]\ngroups = [\"c\", \"b\"]\n",
                "contact = { friction = 0.5 }",
                "group \"c\" is named twice or is in another suspension",
            ),
        ] {
            std::fs::write(&p, text(extra, b_contact)).unwrap();
            let e = format!("{:#}", LaunchFile::load_with(&p, &[]).unwrap_err());
            assert!(e.contains(key), "{e}");
        }
        std::fs::remove_dir_all(&dir).ok();
    }

    /// Two-way coupling needs a DNS to act on: an analytic flow is refused by key.
    #[test]
    fn two_way_needs_the_dns() {
        let dir = std::env::temp_dir().join(format!("ff-twoway-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("a.toml");
        std::fs::write(
            &p,
            "[run]\nid = \"a\"\nsteps = 2\ndt_plus = 0.25\ncoupling = \"two-way\"\n\
             [flow.source]\nkind = \"analytic\"\nflow = { kind = \"uniform\", velocity = [1.0, 0.0, 0.0] }\n",
        )
        .unwrap();
        let e = format!("{:#}", LaunchFile::load_with(&p, &[]).unwrap_err());
        assert!(e.contains("run.coupling") && e.contains("dns"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn box_plus_must_match_the_dns_box() {
        let dir = std::env::temp_dir().join(format!("ff-box-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("b.toml");
        let text = |b: &str| {
            format!(
                "[run]\nid = \"b\"\nsteps = 2\ndt_plus = 0.25\n{b}\n[flow.source]\nkind = \"dns\"\n\
                 [flow.source.dns]\nnx = 16\nny = 16\nnz = 16\nre_tau = 150.0\n"
            )
        };
        std::fs::write(&p, text("")).unwrap();
        let (lf, _) = LaunchFile::load_with(&p, &[]).unwrap();
        let b = lf.box_plus();
        std::fs::write(
            &p,
            text(&format!("box_plus = [{}, {}, {}]", b[0], b[1], b[2])),
        )
        .unwrap();
        assert!(LaunchFile::load_with(&p, &[]).is_ok());
        std::fs::write(&p, text(&format!("box_plus = [{}, 320.0, {}]", b[0], b[2]))).unwrap();
        let e = format!("{:#}", LaunchFile::load_with(&p, &[]).unwrap_err());
        assert!(e.contains("run.box_plus") && e.contains("DNS box"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
    }
}
