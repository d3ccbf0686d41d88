//! The message types. Field order is the wire order and matches the `.msg` files in
//! `messages/msg/` (a test checks them against an independent CDR decoder).
//! Units: wall units throughout (lengths ν/u_tau, velocities u_tau, time ν/u_tau²).

use serde::{Deserialize, Serialize};

/// Published once by the flow node when every expected node has joined.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunAnnouncement {
    pub schema_version: u32,
    pub run_id: String,
    /// SHA-256 of the launch file text.
    pub config_digest: String,
    /// Fibre groups taking part.
    pub groups: Vec<String>,
    pub steps: u64,
    pub dt_plus: f64,
    /// Channel box in wall units (x, y, z); y spans [-box/2, box/2].
    pub box_plus: Vec<f64>,
}

/// Flow-solver health, every few coupling steps.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FlowStatus {
    pub schema_version: u32,
    pub step: u64,
    pub t_plus: f64,
    pub dt_plus: f64,
    pub cfl: f64,
    pub max_divergence: f64,
    pub bulk_velocity: f64,
    pub re_tau: f64,
    /// Mean streamwise pressure gradient that drove the step (outer units, u_τ²/h): 1 at a
    /// constant pressure gradient; at a constant flow rate, the gradient that held it (its
    /// change is the change of drag).
    pub pressure_gradient: f64,
    /// Two-way coupling: the fibres' total force on the fluid applied in the step (x, y,
    /// z, wall units ρ u_τ² ℓ_ν²); empty when one-way.
    pub fiber_force_plus: Vec<f64>,
}

/// Running flow statistics (paper figs. 3–4), half channel in wall units, averaged over
/// x–z planes and time since the run started.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct FlowProfiles {
    pub schema_version: u32,
    pub step: u64,
    pub t_plus: f64,
    pub samples: u64,
    pub t_plus_span: f64,
    /// From the mean wall shear.
    pub re_tau: f64,
    pub bulk_velocity: f64,
    pub y_plus: Vec<f64>,
    pub u_mean: Vec<f64>,
    pub u_rms: Vec<f64>,
    pub v_rms: Vec<f64>,
    pub w_rms: Vec<f64>,
    pub uv: Vec<f64>,
    pub omega_z_mean: Vec<f64>,
    pub omega_x_rms: Vec<f64>,
    pub omega_y_rms: Vec<f64>,
    pub omega_z_rms: Vec<f64>,
}

/// A plane of the flow for viewers (the near-wall streaks, a cross-section), every few
/// coupling steps. Sample (i, j) sits at `origin + u_plus[i]·axis_u + v_plus[j]·axis_v`
/// (wall units; `axis_u`, `axis_v` unit vectors) and has value `values[j·len(u_plus) + i]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FlowSlice {
    pub schema_version: u32,
    pub step: u64,
    pub t_plus: f64,
    /// `"streaks"` (wall-parallel plane at y+ ≈ 15) or `"cross_section"` (a y–z plane).
    pub name: String,
    /// `"u_fluct_plus"`: streamwise velocity minus its x–z plane mean, wall units.
    pub quantity: String,
    pub origin: Vec<f64>,
    pub axis_u: Vec<f64>,
    pub axis_v: Vec<f64>,
    pub u_plus: Vec<f64>,
    pub v_plus: Vec<f64>,
    pub values: Vec<f32>,
}

/// Fluid velocity and velocity gradient at a group's segment centres (state of `step`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FlowSamples {
    pub schema_version: u32,
    pub group: String,
    pub step: u64,
    pub t_plus: f64,
    /// This message covers fibres `first_fiber ..` of a group of `group_fibers` fibres:
    /// the whole group, or the slice one shard of a sharded group integrates.
    pub first_fiber: u32,
    pub group_fibers: u32,
    /// 3 per point.
    pub velocity: Vec<f64>,
    /// 9 per point, row-major ∂v_a/∂x_b.
    pub velocity_gradient: Vec<f64>,
}

/// State of a fibre group at `step` (positions unwrapped). At the steps the recording keeps
/// (`recorder.states_every_steps`, and the last) it is complete; at the others it is *lean*:
/// `axis`, `velocity` and `angular_velocity` are empty and it carries only what the flow
/// node samples at (the centres), a quarter of the bytes. A recorder never writes a lean
/// state.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct FiberGroupState {
    pub schema_version: u32,
    pub group: String,
    pub step: u64,
    pub t_plus: f64,
    /// This message covers fibres `first_fiber ..` of a group of `group_fibers` fibres:
    /// the whole group, or the slice one shard of a sharded group integrates.
    pub first_fiber: u32,
    pub group_fibers: u32,
    /// Per fibre: number of segments N.
    pub segments_per_fiber: Vec<u32>,
    /// Per fibre: segment length, diameter, density ratio, initial layer (0 near wall,
    /// 1 next, 2 middle).
    pub segment_length: Vec<f64>,
    pub diameter: Vec<f64>,
    pub density_ratio: Vec<f64>,
    pub layer: Vec<u8>,
    /// Per segment, 3 values each.
    pub centre: Vec<f64>,
    pub axis: Vec<f64>,
    pub velocity: Vec<f64>,
    pub angular_velocity: Vec<f64>,
    /// Two-way coupling only (empty when one-way): per segment, 3 values, the
    /// hydrodynamic force F^h the fluid exerted on it over the step that ended at `step`
    /// (wall units, ρ_f u_τ² (ν/u_τ)²). The flow node adds −F^h to the fluid's next step.
    /// Carried by lean states too.
    pub hydro_force: Vec<f64>,
    /// Fibre–fibre contact (schema 4; empty without contact or when nothing touched):
    /// the segments that touched in the step that ended at `step`, as indices into this
    /// message's segments (fibre-major, from 0), ascending. Few of a suspension's segments
    /// touch in a step, so the contact arrays list only those. Carried by lean states too.
    pub contact_segment: Vec<u32>,
    /// 3 per listed segment: the contact force the segments of other fibres (and the
    /// fibre's own non-adjacent ones) exerted on it over the step, the sum of its pairs'
    /// impulses over Δt (wall units, as `hydro_force`). Internal to the suspension: the
    /// fluid does not receive it.
    pub contact_force: Vec<f64>,
    /// Per listed segment: how many pairs it was in that touched in the step (≥ 1).
    pub contacts: Vec<u32>,
}

impl FiberGroupState {
    /// Centres only (see the type's documentation).
    pub fn is_lean(&self) -> bool {
        self.axis.is_empty() && self.velocity.is_empty() && self.angular_velocity.is_empty()
    }
}

/// One piece of a fibre group after its free step of `step` → `step` + 1, before contact:
/// what the group's other pieces (shards in other processes) read of its fibres for the
/// contact solve (docs/contact.md). Per segment, 3 values each: the centre, axis and
/// material normal at the start of the step, and after the free step the centre, axis,
/// material normal, velocity and angular velocity. Not recorded.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct FiberFreeStep {
    pub schema_version: u32,
    pub group: String,
    pub step: u64,
    pub t_plus: f64,
    pub first_fiber: u32,
    pub group_fibers: u32,
    /// Per fibre: number of segments N.
    pub segments_per_fiber: Vec<u32>,
    pub start_centre: Vec<f64>,
    pub start_axis: Vec<f64>,
    pub start_normal: Vec<f64>,
    pub centre: Vec<f64>,
    pub axis: Vec<f64>,
    pub normal: Vec<f64>,
    pub velocity: Vec<f64>,
    pub angular_velocity: Vec<f64>,
}

/// What the contact solve of step `step` did to one piece of a group (the suspension's
/// first piece solves over every piece's free step and sends each other piece its part;
/// docs/contact.md). Per moved fibre its segments after the solve, 3 values each; the
/// piece's contact load; the solve's summary. Not recorded.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct FiberContactSolved {
    pub schema_version: u32,
    pub group: String,
    pub step: u64,
    pub t_plus: f64,
    pub first_fiber: u32,
    pub group_fibers: u32,
    /// Fibres in the piece.
    pub fibers: u32,
    /// The piece's fibres the solve moved (indices within the piece, ascending).
    pub moved: Vec<u32>,
    /// Per moved fibre: its number of segments.
    pub moved_segments: Vec<u32>,
    pub centre: Vec<f64>,
    pub axis: Vec<f64>,
    pub normal: Vec<f64>,
    pub velocity: Vec<f64>,
    pub angular_velocity: Vec<f64>,
    /// Contact load: segments (within the piece, ascending), 3 force values each, pairs.
    pub contact_segment: Vec<u32>,
    pub contact_force: Vec<f64>,
    pub contacts: Vec<u32>,
    /// Smallest centre-line gap minus contact distance after the whole solve.
    pub worst_gap: f64,
    pub sweeps: u32,
    /// Pairs that touched in the whole solve.
    pub pairs: u32,
    pub candidates: u32,
    /// The piece's fibres locked into one body, and kept where they started.
    pub locked: Vec<u32>,
    pub frozen: Vec<u32>,
}

/// Per-fibre metrics of a group at `step` (paper §4.3).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FiberGroupMetrics {
    pub schema_version: u32,
    pub group: String,
    pub step: u64,
    pub t_plus: f64,
    /// This message covers fibres `first_fiber ..` of a group of `group_fibers` fibres:
    /// the whole group, or the slice one shard of a sharded group integrates.
    pub first_fiber: u32,
    pub group_fibers: u32,
    /// 3 per fibre.
    pub centre_of_mass: Vec<f64>,
    pub z1: Vec<f64>,
    pub sigma2: Vec<f64>,
    pub end_to_end: Vec<f64>,
    pub mean_abs_z1: f64,
    pub mean_sigma2: f64,
}

/// Node lifecycle and health.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Heartbeat {
    pub schema_version: u32,
    pub node: String,
    pub state: Lifecycle,
    pub step: u64,
    /// Messages dropped so far (undecodable or wrong version).
    pub dropped: u64,
}

/// A node's lifecycle state, as [`Heartbeat::state`] carries it (one byte on the wire:
/// 0 starting, 1 ready, 2 running, 3 done, 4 failed, then the states below in order). A
/// byte that names no state does not decode: the message is dropped and counted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Lifecycle {
    Starting = 0,
    Ready = 1,
    Running = 2,
    Done = 3,
    Failed = 4,
    /// A fibre node has waited long for the samples of `step` (and has sent its state of
    /// `step` again): the flow node sends those samples again if it already served them.
    /// Lockstep survives a message the transport lost.
    Waiting = 5,
    /// The recorder has the flow node's DONE of the last step and is finishing the file. The
    /// flow node sends its DONE again until it sees this, so a DONE the transport lost as
    /// the flow process exits cannot keep the recorder open.
    Finishing = 6,
    /// The recorder has flushed and synced to disk every message through its checkpoint
    /// of `step` (its `recorder.ckpt` there is written). Said again with each progress
    /// report, so a lost one is made good: a head whose recorder runs on another host
    /// completes a checkpoint only once it has heard this for it.
    Committed = 7,
    /// The run is complete: every node of every host said DONE. A multi-host run's flow
    /// node (its router) says it until each worker host's launcher answers with its own
    /// COMPLETE, so a worker waits for it (and follows a restart instead) rather than
    /// leaving while the head may still roll back to a step that needs it.
    Complete = 8,
}

impl Lifecycle {
    /// Every state, in the order of their bytes.
    pub const ALL: [Lifecycle; 9] = [
        Lifecycle::Starting,
        Lifecycle::Ready,
        Lifecycle::Running,
        Lifecycle::Done,
        Lifecycle::Failed,
        Lifecycle::Waiting,
        Lifecycle::Finishing,
        Lifecycle::Committed,
        Lifecycle::Complete,
    ];
}

impl Serialize for Lifecycle {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_u8(*self as u8)
    }
}

impl<'de> Deserialize<'de> for Lifecycle {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let b = u8::deserialize(d)?;
        Lifecycle::ALL
            .get(usize::from(b))
            .copied()
            .ok_or_else(|| serde::de::Error::custom(format!("unknown lifecycle state {b}")))
    }
}

/// What the lifecycle states leave to numbers.
pub mod lifecycle {
    /// How far the run may get ahead of its recorder: the flow node serves step k only
    /// once the recorder's RUNNING heartbeats say it holds every piece's state through
    /// step k − `RECORDER_LAG_STEPS`. A slow recorder (a slow disk, a busy host) slows the
    /// run instead of letting messages pile up in its receive queue; at most this many
    /// steps of messages wait there.
    pub const RECORDER_LAG_STEPS: u64 = 4;
}
