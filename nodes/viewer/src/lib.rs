//! The viewer: logs a recording as a rich Rerun scene (SDK 0.36.3) on a `t+` timeline —
//! the channel box, every fibre as a line strip coloured by its coiling σ², joints as
//! points, centre-of-mass trails, and time series of ⟨|z1|⟩, ⟨σ²⟩ and MSD_23 per case.
//! Each case is its own entity subtree (`world/<case>`, `plots/*/<case>`).

use fiberflow_messages::{decode, FiberGroupState, RunAnnouncement};
use std::collections::BTreeMap;
use std::path::Path;

#[derive(Debug, thiserror::Error)]
pub enum ViewerError {
    #[error("reading {path}: {reason}")]
    Read { path: String, reason: String },
    #[error("rerun: {0}")]
    Rerun(String),
}

/// Where the scene goes.
#[derive(Debug, Clone)]
pub enum Sink {
    /// Write an .rrd file.
    Save(std::path::PathBuf),
    /// Spawn a viewer (the `rerun` binary on PATH, e.g. from `pip install rerun-sdk==0.36.3`).
    Spawn,
    /// Stream to a running viewer (`rerun+http://127.0.0.1:9876/proxy`).
    Connect(String),
}

/// Colour map for σ² in [0, 1.5]: dark blue (straight) -> teal -> yellow (coiled).
pub fn sigma2_colour(s2: f64) -> [u8; 3] {
    let t = (s2 / 1.5).clamp(0.0, 1.0);
    let stops = [
        (0.0, [68.0, 1.0, 84.0]),
        (0.5, [33.0, 145.0, 140.0]),
        (1.0, [253.0, 231.0, 37.0]),
    ];
    let (a, b) = if t < 0.5 {
        (stops[0], stops[1])
    } else {
        (stops[1], stops[2])
    };
    let f = (t - a.0) / (b.0 - a.0);
    let c = |i: usize| (a.1[i] + f * (b.1[i] - a.1[i])).round() as u8;
    [c(0), c(1), c(2)]
}

fn err<E: std::fmt::Display>(e: E) -> ViewerError {
    ViewerError::Rerun(e.to_string())
}

/// Logs the recording at `mcap` to `sink`. `every` thins the steps shown (1 = all).
pub fn view(mcap: &Path, sink: &Sink, every: u64) -> Result<(), ViewerError> {
    use fiberflow_messages::sanity::Sane;
    let read_err = |p: &Path, e: String| ViewerError::Read {
        path: p.display().to_string(),
        reason: e,
    };
    // a run folder: every segment in order; states that fail their checks are skipped
    let segs = fiberflow_messages::segments::segment_paths(mcap)
        .map_err(|e| read_err(mcap, e.to_string()))?;
    let mut states: BTreeMap<String, BTreeMap<u64, FiberGroupState>> = BTreeMap::new();
    let mut box_plus = [942.48, 300.0, 471.24];
    // a sharded group's slices, put back together per step
    let mut tiles = fiberflow_messages::pieces::Tiles::default();
    for seg in &segs {
        let bytes = std::fs::read(seg).map_err(|e| read_err(seg, e.to_string()))?;
        let stream = mcap::MessageStream::new(&bytes).map_err(|e| read_err(seg, e.to_string()))?;
        for m in stream {
            let Ok(m) = m else { break };
            if m.channel.topic.ends_with("/state") {
                if let Ok(s) = decode::<FiberGroupState>(&m.data) {
                    if s.check().is_ok() {
                        if let Some(whole) = tiles.add_slice(s) {
                            states
                                .entry(whole.group.clone())
                                .or_default()
                                .insert(whole.step, whole);
                        }
                    }
                }
            } else if m.channel.topic.ends_with("/control/announce") {
                if let Ok(a) = decode::<RunAnnouncement>(&m.data) {
                    if a.check().is_ok() {
                        box_plus = [a.box_plus[0], a.box_plus[1], a.box_plus[2]];
                    }
                }
            }
        }
    }
    let builder = rerun::RecordingStreamBuilder::new("fiberflow");
    let rec = match sink {
        Sink::Save(p) => builder.save(p).map_err(err)?,
        Sink::Spawn => builder.spawn().map_err(err)?,
        Sink::Connect(url) => builder.connect_grpc_opts(url.clone()).map_err(err)?,
    };
    send_blueprint(&rec, &states.keys().cloned().collect::<Vec<_>>())?;
    let h = 0.5 * box_plus[1];
    rec.log_static(
        "world/channel",
        &rerun::Boxes3D::from_centers_and_half_sizes(
            [(0.5 * box_plus[0] as f32, 0.0, 0.5 * box_plus[2] as f32)],
            [(0.5 * box_plus[0] as f32, h as f32, 0.5 * box_plus[2] as f32)],
        )
        .with_colors([rerun::Color::from_rgb(150, 150, 150)]),
    )
    .map_err(err)?;
    rec.log_static(
        "legend",
        &rerun::TextDocument::from_markdown(
            "# fiberflow\n\nFibres are line strips coloured by their coiling σ² = Σ|ẑᵢ − ẑ|²/(N−1): \
             **dark blue = straight (0)**, teal ≈ 0.75, **yellow = coiled (≥ 1.5)**. \
             Joints are points; thin lines are centre-of-mass trails. Streamwise x1 is drawn \
             wrapped into the periodic box. Plots: ⟨|z1|⟩, ⟨σ²⟩ and MSD_23 per case on the `t+` timeline.",
        ),
    )
    .map_err(err)?;
    for (group, steps) in &states {
        let Some(first) = steps.values().next() else {
            continue;
        };
        let com0 = coms(first);
        let mut trails: Vec<Vec<[f32; 3]>> = vec![Vec::new(); com0.len()];
        for (k, s) in steps {
            if k % every != 0 && *k != *steps.keys().last().unwrap_or(&0) {
                continue;
            }
            rec.set_duration_secs("t+", s.t_plus);
            let (strips, colours, joints, s2, z1) = fibres(s, box_plus);
            rec.log(
                format!("world/{group}/fibres"),
                &rerun::LineStrips3D::new(strips)
                    .with_colors(
                        colours
                            .iter()
                            .map(|c| rerun::Color::from_rgb(c[0], c[1], c[2])),
                    )
                    .with_radii([rerun::Radius::new_scene_units(1.2)]),
            )
            .map_err(err)?;
            rec.log(
                format!("world/{group}/joints"),
                &rerun::Points3D::new(joints).with_radii([rerun::Radius::new_scene_units(1.6)]),
            )
            .map_err(err)?;
            let com = coms(s);
            for (t, c) in trails.iter_mut().zip(&com) {
                t.push(wrap(*c, box_plus));
            }
            // trails are re-logged every 10th shown step to keep the file small
            if trails[0].len() % 10 == 1 {
                rec.log(
                    format!("world/{group}/trails"),
                    &rerun::LineStrips3D::new(split_wrapped(&trails, box_plus))
                        .with_colors([rerun::Color::from_unmultiplied_rgba(200, 200, 200, 50)])
                        .with_radii([rerun::Radius::new_ui_points(0.5)]),
                )
                .map_err(err)?;
            }
            let n = s2.len().max(1) as f64;
            let msd = com
                .iter()
                .zip(&com0)
                .map(|(a, b)| (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2))
                .sum::<f64>()
                / n;
            rec.log(
                format!("plots/abs_z1/{group}"),
                &rerun::Scalars::single(z1.iter().map(|z| z.abs()).sum::<f64>() / n),
            )
            .map_err(err)?;
            rec.log(
                format!("plots/sigma2/{group}"),
                &rerun::Scalars::single(s2.iter().sum::<f64>() / n),
            )
            .map_err(err)?;
            rec.log(
                format!("plots/msd23_from_start/{group}"),
                &rerun::Scalars::single(msd),
            )
            .map_err(err)?;
        }
    }
    rec.flush_blocking().map_err(err)?;
    Ok(())
}

/// Layout for a first open: the 3-D scene with the legend beside the three time series.
fn send_blueprint(rec: &rerun::RecordingStream, groups: &[String]) -> Result<(), ViewerError> {
    use rerun::blueprint::{
        Blueprint, BlueprintActivation, ContainerLike, Horizontal, Spatial3DView, TextDocumentView,
        TimePanel, TimeSeriesView, Vertical,
    };
    let left: Vec<ContainerLike> = vec![
        Spatial3DView::new("Fibres (colour: coiling σ²)")
            .with_origin("world")
            // trails exist under world/<case>/trails; hidden at first open so fibres stand out
            .with_contents(
                std::iter::once("+ /world/**".to_string())
                    .chain(groups.iter().map(|g| format!("- /world/{g}/trails"))),
            )
            .into(),
        TextDocumentView::new("Legend").with_origin("legend").into(),
    ];
    let right: Vec<ContainerLike> = vec![
        TimeSeriesView::new("mean |z1| (alignment)")
            .with_origin("plots/abs_z1")
            .into(),
        TimeSeriesView::new("mean σ² (coiling)")
            .with_origin("plots/sigma2")
            .into(),
        TimeSeriesView::new("MSD_23 from t = 0")
            .with_origin("plots/msd23_from_start")
            .into(),
    ];
    let root = Horizontal::new([
        Vertical::new(left).with_row_shares([0.8, 0.2]).into(),
        Vertical::new(right).into(),
    ])
    .with_column_shares([0.62, 0.38]);
    Blueprint::new(root)
        .with_time_panel(
            TimePanel::new()
                .with_timeline("t+")
                .with_play_state(rerun::blueprint::components::PlayState::Following),
        )
        .send(rec, BlueprintActivation::default())
        .map_err(err)
}

fn coms(s: &FiberGroupState) -> Vec<[f64; 3]> {
    let mut out = Vec::with_capacity(s.segments_per_fiber.len());
    let mut seg = 0usize;
    for &n in &s.segments_per_fiber {
        let n = n as usize;
        let mut c = [0.0; 3];
        for i in seg..seg + n {
            for a in 0..3 {
                c[a] += s.centre[3 * i + a] / n as f64;
            }
        }
        out.push(c);
        seg += n;
    }
    out
}

fn wrap(c: [f64; 3], b: [f64; 3]) -> [f32; 3] {
    [
        c[0].rem_euclid(b[0]) as f32,
        c[1] as f32,
        c[2].rem_euclid(b[2]) as f32,
    ]
}

/// Breaks trails where they wrap around the periodic box.
fn split_wrapped(trails: &[Vec<[f32; 3]>], b: [f64; 3]) -> Vec<Vec<[f32; 3]>> {
    let mut out = Vec::new();
    for t in trails {
        let mut cur: Vec<[f32; 3]> = Vec::new();
        for p in t {
            if let Some(q) = cur.last() {
                if ((p[0] - q[0]).abs() as f64) > 0.5 * b[0]
                    || ((p[2] - q[2]).abs() as f64) > 0.5 * b[2]
                {
                    out.push(std::mem::take(&mut cur));
                }
            }
            cur.push(*p);
        }
        if cur.len() > 1 {
            out.push(cur);
        }
    }
    out
}

type FibreScene = (
    Vec<Vec<[f32; 3]>>,
    Vec<[u8; 3]>,
    Vec<[f32; 3]>,
    Vec<f64>,
    Vec<f64>,
);

/// Line strips (joints, shifted so the fibre's centre of mass lies in the box), colours by
/// σ², all joints, σ² and z1 per fibre.
fn fibres(s: &FiberGroupState, b: [f64; 3]) -> FibreScene {
    let mut strips = Vec::new();
    let mut colours = Vec::new();
    let mut joints = Vec::new();
    let mut s2s = Vec::new();
    let mut z1s = Vec::new();
    let mut seg = 0usize;
    for (f, &n) in s.segments_per_fiber.iter().enumerate() {
        let n = n as usize;
        let l = s.segment_length.get(f).copied().unwrap_or(0.0);
        let mut com = [0.0; 3];
        let mut zs = [0.0; 3];
        for i in seg..seg + n {
            for a in 0..3 {
                com[a] += s.centre[3 * i + a] / n as f64;
                zs[a] += s.axis[3 * i + a];
            }
        }
        let shift = [
            com[0].rem_euclid(b[0]) - com[0],
            0.0,
            com[2].rem_euclid(b[2]) - com[2],
        ];
        let norm = (zs[0] * zs[0] + zs[1] * zs[1] + zs[2] * zs[2])
            .sqrt()
            .max(1e-300);
        let mut s2 = 0.0;
        let mut strip = Vec::with_capacity(n + 1);
        for i in seg..seg + n {
            let c = &s.centre[3 * i..3 * i + 3];
            let z = &s.axis[3 * i..3 * i + 3];
            for a in 0..3 {
                s2 += (z[a] - zs[a] / norm).powi(2);
            }
            let start = [
                c[0] - 0.5 * l * z[0] + shift[0],
                c[1] - 0.5 * l * z[1],
                c[2] - 0.5 * l * z[2] + shift[2],
            ];
            strip.push([start[0] as f32, start[1] as f32, start[2] as f32]);
            if i + 1 == seg + n {
                let end = [
                    c[0] + 0.5 * l * z[0] + shift[0],
                    c[1] + 0.5 * l * z[1],
                    c[2] + 0.5 * l * z[2] + shift[2],
                ];
                strip.push([end[0] as f32, end[1] as f32, end[2] as f32]);
            }
        }
        let s2 = if n > 1 { s2 / (n - 1) as f64 } else { 0.0 };
        joints.extend_from_slice(&strip);
        strips.push(strip);
        colours.push(sigma2_colour(s2));
        s2s.push(s2);
        z1s.push(zs[0] / norm);
        seg += n;
    }
    (strips, colours, joints, s2s, z1s)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn colour_map_is_monotone_in_brightness() {
        let lum = |c: [u8; 3]| 0.3 * c[0] as f64 + 0.6 * c[1] as f64 + 0.1 * c[2] as f64;
        let mut prev = -1.0;
        for i in 0..=30 {
            let l = lum(sigma2_colour(i as f64 * 0.05));
            assert!(
                l >= prev,
                "luminance not monotone at σ² = {}",
                i as f64 * 0.05
            );
            prev = l;
        }
    }
}
