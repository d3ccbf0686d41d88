//! The viewer: logs a recording as a Rerun scene (SDK 0.36.3) for inspecting coiling.
//!
//! - **Gallery**: every shown fibre re-centred at its centre of mass on a grid, one band per
//!   case, ordered by initial layer and then final σ², coloured by σ² (paper §4.3).
//! - **Channel**: the same fibres in the periodic box, with the near-wall streaks and a
//!   cross-section of u' when the recording has flow slices.
//! - **Per-fibre series**: σ², |z1|, end-to-end distance and wall distance x2+ of each
//!   fibre; every fibre is one entity (`fibers/<case>/<layer>/f<i>`), so selecting it in any
//!   view highlights it in all of them.
//! - **Coiling events**: the first t+ each fibre's σ² reaches each threshold, in a text log
//!   and as a marker over the fibre in the gallery.
//!
//! Time: a `t+` timeline with one frame per whole t+ (frame `#20` is t+ = 20) and a `step`
//! timeline with every recorded step. At scale a stratified sample per case plus the most
//! coiled fibres is shown ([`select`]). Contacts and flocs are [`contacts`].
//!
//! Size (≈ 700 lines before the tests): one pass over a recording builds every view, and
//! the columns it logs share the shown fibres' rows.

pub mod blueprint;
mod contacts;
pub mod gallery;
pub mod paths;
pub mod read;
pub mod select;
pub mod shape;
pub mod slices;

pub use contacts::{floc_colour, folded_centre_line};
use contacts::{log_contacts, log_flocs};

use read::{GroupInfo, Item};
use std::collections::{BTreeMap, HashMap};
use std::path::Path;

#[derive(Debug, thiserror::Error)]
pub enum ViewerError {
    #[error("reading {path}: {reason}")]
    Read { path: String, reason: String },
    #[error("rerun: {0}")]
    Rerun(String),
    #[error("{0} has no fibre states to show")]
    Empty(String),
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

/// What to show.
#[derive(Debug, Clone)]
pub struct ViewOptions {
    /// Show fibre shapes every this many steps; 0 (the default) shows them at the steps on
    /// the `t+` timeline (one per whole t+). The first and last state are always shown; the
    /// per-fibre series have every step.
    pub every: u64,
    pub sampling: select::Sampling,
    /// σ² thresholds of the coiling events.
    pub coil_thresholds: Vec<f64>,
    /// Show where fibres touch (`world/contacts/<group>`, red points at the midpoints of
    /// touching centre-lines), the contact forces the states carry (`world/contact_forces/
    /// <group>`, orange arrows) and the fibres of every floc, each floc in its own colour
    /// (`world/flocs/<group>`), in every state whose shapes are shown: computed over all
    /// the group's fibres, so it costs a contact search per such state (docs/contact.md).
    pub contacts: bool,
}

impl Default for ViewOptions {
    fn default() -> Self {
        Self {
            every: 0,
            sampling: select::Sampling::default(),
            coil_thresholds: fiberflow_analysis::coiling::DEFAULT_THRESHOLDS.to_vec(),
            contacts: false,
        }
    }
}

/// What a scene holds.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SceneSummary {
    pub groups: usize,
    pub fibers: usize,
    pub shown: usize,
    pub events: usize,
    pub slices: usize,
    /// States whose contact points were logged (with [`ViewOptions::contacts`]).
    pub contact_states: usize,
    /// Fibres drawn in their floc's colour, summed over those states.
    pub floc_fibers: usize,
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

/// Line colours of the per-fibre series by initial layer: near wall, next, middle (other).
const LAYER_COLOURS: [[u8; 3]; 4] = [
    [31, 119, 180],
    [255, 127, 14],
    [44, 160, 44],
    [127, 127, 127],
];

/// Width (UI points) of a fibre's series lines. Below the viewer's 1.5-pixel minimum it
/// draws them 1.5 px wide and proportionally faint; a selected fibre's line is one point
/// wider in radius, so it is drawn opaque and clearly wider than the others.
const SERIES_WIDTH: f32 = 0.5;

/// How a fibre's lines look in its plots: name and colour (by initial layer).
struct SeriesStyle {
    label: String,
    colour: [u8; 3],
}

/// The fibre's styles, logged once as static data on its entity: its series name, colour
/// and width (every plot of it uses them, so the blueprint carries only the mapping of each
/// plot's series) and its gallery line width.
fn log_fiber_style(
    rec: &rerun::RecordingStream,
    path: &str,
    style: &SeriesStyle,
) -> Result<(), ViewerError> {
    let [r, g, b] = style.colour;
    rec.log_static(
        path,
        &[
            &rerun::SeriesLines::new()
                .with_names([style.label.as_str()])
                .with_colors([rerun::Color::from_rgb(r, g, b)])
                .with_widths([SERIES_WIDTH]) as &dyn rerun::AsComponents,
            &rerun::LineStrips2D::update_fields().with_radii([rerun::Radius::new_scene_units(0.7)]),
        ],
    )
    .map_err(err)
}

/// Onset marker colours, one per threshold (light to strong).
const ONSET_COLOURS: [[u8; 3]; 3] = [[200, 200, 200], [255, 165, 0], [255, 40, 40]];

pub(crate) fn err<E: std::fmt::Display>(e: E) -> ViewerError {
    ViewerError::Rerun(e.to_string())
}

/// Sets the `step` timeline, and the `t+` timeline when the step stands for a whole t+.
fn set_time(rec: &rerun::RecordingStream, step: u64, t_plus: f64, dt_plus: f64) {
    rec.set_time_sequence("step", step as i64);
    match shape::whole_t_plus(t_plus, dt_plus) {
        Some(n) => rec.set_time_sequence("t+", n),
        None => rec.disable_timeline("t+"),
    }
}

/// A shown fibre: its entity, gallery cell, its σ² over time (for the events) and its four
/// series, sent as columns once the recording is read.
struct Shown {
    path: String,
    cell: [f64; 3],
    sigma2: Vec<(u64, f64, f64)>,
    series: Vec<SeriesRow>,
    shapes: Vec<ShapeRow>,
}

/// One shown state of a fibre: step, whole t+ the step stands for, gallery strip, its
/// colour (σ²) and channel strip.
struct ShapeRow {
    step: u64,
    frame: Option<i64>,
    gallery: Vec<[f32; 2]>,
    colour: [u8; 3],
    channel: Vec<[f32; 3]>,
}

/// One step of a fibre's four series: step, whole t+ the step stands for, the values in
/// the order of [`paths::SERIES`].
type SeriesRow = (u64, Option<i64>, [f64; 4]);

/// One `send_columns` call: the time columns and the four series columns.
type SeriesChunk = (
    Vec<rerun::TimeColumn>,
    Vec<rerun::SerializedComponentColumn>,
);

/// Logs the recording at `mcap` (a file or run folder) to `sink`.
pub fn view(mcap: &Path, sink: &Sink, opts: &ViewOptions) -> Result<SceneSummary, ViewerError> {
    let Survey {
        groups,
        box_plus,
        dt_plus,
    } = survey(mcap)?;
    let h_plus = 0.5 * box_plus[1];

    let Chosen {
        gallery: g,
        mut shown,
        entities,
        styles,
    } = choose(&groups, opts);

    let rec = open_stream(sink)?;
    let eye = channel_camera(box_plus);
    blueprint::send(&rec, &entities, &eye)?;
    for (e, style) in entities.iter().zip(&styles) {
        log_fiber_style(&rec, &e.path, style)?;
    }
    log_static(&rec, box_plus, &groups, &g, opts)?;

    // pass 2: shapes, series, slices
    let mut log_err: Option<ViewerError> = None;
    let mut slices = 0usize;
    let mut contact_states = 0usize;
    let mut floc_fibers = 0usize;
    let mut slice_meshes = slices::Logged::default();
    read::for_each(mcap, |it| {
        if log_err.is_some() {
            return;
        }
        let r = match &it {
            Item::State(s) => {
                let last = groups.get(&s.group).map_or(0, |g| g.last_state_step);
                let wanted = match opts.every {
                    0 => shape::whole_t_plus(s.t_plus, dt_plus).is_some(),
                    k => s.step % k == 0,
                };
                let due = wanted || s.step == 0 || s.step == last;
                if let Some(m) = shown.get_mut(&s.group) {
                    if due {
                        collect_state(s, m, box_plus, dt_plus);
                    }
                }
                if opts.contacts && due {
                    contact_states += 1;
                    log_contacts(&rec, s, box_plus, dt_plus).and_then(|()| {
                        floc_fibers += log_flocs(&rec, s, box_plus)?;
                        Ok(())
                    })
                } else {
                    Ok(())
                }
            }
            Item::Metrics(mt) => {
                if let Some(m) = shown.get_mut(&mt.group) {
                    collect_metrics(mt, m, h_plus, dt_plus);
                }
                Ok(())
            }
            Item::Slice(sl) => {
                slices += 1;
                set_time(&rec, sl.step, sl.t_plus, dt_plus);
                slices::log(&rec, &mut slice_meshes, sl, h_plus)
            }
            Item::Announce(_) => Ok(()),
        };
        if let Err(e) = r {
            log_err = Some(e);
        }
    })?;
    if let Some(e) = log_err {
        return Err(e);
    }
    for fibers in shown.values() {
        for sh in fibers.values() {
            let chunks = series_columns(&sh.series)?
                .into_iter()
                .chain(shape_columns(&sh.shapes)?);
            for (indexes, columns) in chunks {
                rec.send_columns(sh.path.as_str(), indexes, columns)
                    .map_err(err)?;
            }
        }
    }
    let events = log_events(&rec, &shown, &opts.coil_thresholds, dt_plus, g.cell_plus)?;
    rec.flush_blocking().map_err(err)?;
    Ok(SceneSummary {
        groups: groups.len(),
        fibers: groups.values().map(|g| g.fibers).sum(),
        shown: entities.len(),
        events,
        slices,
        contact_states,
        floc_fibers,
    })
}

/// Floc colours (a qualitative palette; no red, which marks the contact points).
const FLOC_COLOURS: [[u8; 3]; 9] = [
    [31, 119, 180],
    [255, 127, 14],
    [44, 160, 44],
    [148, 103, 189],
    [140, 86, 75],
    [227, 119, 194],
    [188, 189, 34],
    [23, 190, 207],
    [127, 127, 127],
];

/// What the first pass over a recording finds: the groups (layers, final σ²), the box and
/// the coupling time step.
struct Survey {
    groups: BTreeMap<String, GroupInfo>,
    box_plus: [f64; 3],
    dt_plus: f64,
}

/// Pass 1: groups, layers, final σ², box and time step.
fn survey(mcap: &Path) -> Result<Survey, ViewerError> {
    let mut groups: BTreeMap<String, GroupInfo> = BTreeMap::new();
    let mut box_plus = [942.48, 300.0, 471.24];
    let mut dt_plus: Option<f64> = None;
    let mut dt_seen: Option<f64> = None;
    read::for_each(mcap, |it| match &it {
        Item::Announce(a) => {
            box_plus = [a.box_plus[0], a.box_plus[1], a.box_plus[2]];
            dt_plus = Some(a.dt_plus);
        }
        Item::State(s) => groups.entry(s.group.clone()).or_default().add(&it),
        Item::Metrics(m) => {
            if m.step > 0 && dt_seen.is_none() {
                dt_seen = Some(m.t_plus / m.step as f64);
            }
            groups.entry(m.group.clone()).or_default().add(&it)
        }
        Item::Slice(_) => {}
    })?;
    groups.retain(|_, g| !g.layer.is_empty());
    if groups.is_empty() {
        return Err(ViewerError::Empty(mcap.display().to_string()));
    }
    let dt_plus = dt_plus.or(dt_seen).unwrap_or(1.0);
    Ok(Survey {
        groups,
        box_plus,
        dt_plus,
    })
}

/// The fibres shown, where each sits in the gallery, and their entity paths and styles.
struct Chosen {
    gallery: gallery::Gallery,
    shown: HashMap<String, HashMap<usize, Shown>>,
    entities: Vec<blueprint::FiberEntity>,
    styles: Vec<SeriesStyle>,
}

/// Which fibres of each group are shown (`opts.sampling`) and where in the gallery.
fn choose(groups: &BTreeMap<String, GroupInfo>, opts: &ViewOptions) -> Chosen {
    let chosen: Vec<Vec<usize>> = groups
        .values()
        .map(|g| select::choose(&g.layer, &g.final_sigma2, opts.sampling))
        .collect();
    let longest = groups.values().map(|g| g.contour_plus).fold(0.0, f64::max);
    let g = gallery::layout(&chosen.iter().map(Vec::len).collect::<Vec<_>>(), longest);
    let mut shown: HashMap<String, HashMap<usize, Shown>> = HashMap::new();
    let mut entities = Vec::new();
    let mut styles = Vec::new();
    for (c, (name, info)) in groups.iter().enumerate() {
        let digits = paths::digits(info.fibers);
        let m = shown.entry(name.clone()).or_default();
        for (rank, &f) in chosen[c].iter().enumerate() {
            let layer = info.layer[f];
            let path = paths::fiber(name, layer, f, digits);
            entities.push(blueprint::FiberEntity {
                path: path.clone(),
                case: name.clone(),
            });
            styles.push(SeriesStyle {
                label: format!("{name} {} f{f}", paths::layer_name(layer)),
                colour: LAYER_COLOURS[usize::from(layer).min(LAYER_COLOURS.len() - 1)],
            });
            m.insert(
                f,
                Shown {
                    path,
                    cell: g.centres[c][rank],
                    sigma2: Vec::new(),
                    series: Vec::new(),
                    shapes: Vec::new(),
                },
            );
        }
    }
    Chosen {
        gallery: g,
        shown,
        entities,
        styles,
    }
}

/// The Rerun stream to a file, a spawned viewer or a running one.
fn open_stream(sink: &Sink) -> Result<rerun::RecordingStream, ViewerError> {
    let builder = rerun::RecordingStreamBuilder::new("fiberflow");
    Ok(match sink {
        Sink::Save(p) => builder.save(p).map_err(err)?,
        Sink::Spawn => builder.spawn().map_err(err)?,
        Sink::Connect(url) => builder.connect_grpc_opts(url.clone()).map_err(err)?,
    })
}

/// The channel camera: above the lower half, looking at a quarter of the box.
fn channel_camera(box_plus: [f64; 3]) -> blueprint::Eye {
    blueprint::Eye {
        position: [
            (0.22 * box_plus[0]) as f32,
            (0.1 * box_plus[1]) as f32,
            (0.95 * box_plus[2]) as f32,
        ],
        look_target: [
            (0.45 * box_plus[0]) as f32,
            (-0.35 * box_plus[1]) as f32,
            (0.5 * box_plus[2]) as f32,
        ],
    }
}

fn log_static(
    rec: &rerun::RecordingStream,
    box_plus: [f64; 3],
    groups: &BTreeMap<String, GroupInfo>,
    g: &gallery::Gallery,
    opts: &ViewOptions,
) -> Result<(), ViewerError> {
    rec.log_static("/", &rerun::ViewCoordinates::RIGHT_HAND_Y_UP())
        .map_err(err)?;
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
    for (c, (name, info)) in groups.iter().enumerate() {
        let l = g.labels[c];
        rec.log_static(
            paths::band_label(name),
            &rerun::Points2D::new([[l[0] as f32, l[1] as f32]])
                .with_labels([format!(
                    "{name}: N {} x l+ {:.1}, density ratio {:.0}",
                    info.segments, info.segment_length, info.density_ratio
                )])
                .with_colors([rerun::Color::from_rgb(220, 220, 220)])
                .with_radii([rerun::Radius::new_scene_units(0.15 * g.cell_plus as f32)])
                .with_show_labels(true),
        )
        .map_err(err)?;
    }
    let thresholds = opts
        .coil_thresholds
        .iter()
        .map(|t| format!("{t}"))
        .collect::<Vec<_>>()
        .join(", ");
    let text = format!(
        "# How to read this scene\n\n\
         **Colour of a fibre: its coiling σ² = Σ|z_i − z|²/(N−1)** (paper §4.3): dark blue = \
         straight (0), teal = 0.75, yellow = coiled (1.5 or more).\n\n\
         **Gallery** (top left): every shown fibre moved to its own cell at its centre of mass, \
         seen from the side (x1 streamwise to the right, x2 wall-normal up). One band of rows \
         per case, labelled with its fibres (segments N x segment length l+, density ratio). \
         In a band fibres go by initial layer (near wall, next, middle), then by final σ², \
         left to right and top to bottom: the most coiled of each layer come last.\n\n\
         **Channel** (bottom left): the same fibres in the periodic box (x1 wrapped); the grey \
         box is the channel, 2h = {:.0} wall units high. Where the recording has flow slices: \
         the streaks, u' at y+ ≈ 15 above the lower wall (drawn on the wall, under the fibres), \
         and a cross-section at x1 = 0; blue slow, red fast, white = the plane's mean, \
         ±4 u_tau. In two-way runs, beyond the channel (at lower x3): the fibres' \
         streamwise force on the fluid in the same plane, red pushing it forward, blue \
         holding it back (the strongest 1% saturate). With `--contacts`: red points where \
         fibres touch, orange arrows along the contact forces the solve recorded (the \
         largest of a state 6 wall units long), and the fibres of every floc (fibres joined by contacts) drawn in \
         their floc's colour, one colour per floc, from all of the group's fibres.\n\n\
         **Plots** (right): one tab per series (σ², |z1|, end-to-end distance, wall distance \
         x2+), in each one plot per case with every shown fibre of that case, coloured by \
         initial layer: blue near wall, orange next, green middle. **Click a fibre** in the \
         gallery (or a line in a plot): it is one entity `fibers/<case>/<layer>/f<i>`; its \
         line in its case's plot is drawn opaque and wider in every tab, and the Selection \
         panel shows its σ², |z1|, end-to-end distance and x2+ at the time cursor.\n\n\
         **Coiling events**: the first t+ a fibre's σ² reaches {thresholds}; listed under \
         *Coiling events* and marked over the fibre in the gallery (grey, orange, red = \
         lowest to highest threshold).\n\n\
         **Time**: the `t+` timeline has one frame per whole t+ (frame #20 = t+ 20); the \
         `step` timeline has every recorded step.",
        box_plus[1]
    );
    rec.log_static("legend", &rerun::TextDocument::from_markdown(text))
        .map_err(err)
}

/// Keeps the shapes of every shown fibre at this state (sent as columns later, like the
/// series).
fn collect_state(
    s: &fiberflow_messages::FiberGroupState,
    shown: &mut HashMap<usize, Shown>,
    box_plus: [f64; 3],
    dt_plus: f64,
) {
    let firsts = shape::first_segments(s);
    let frame = shape::whole_t_plus(s.t_plus, dt_plus);
    for (&f, sh) in shown.iter_mut() {
        if f >= firsts.len() {
            continue;
        }
        let fiber = shape::shape(s, f, firsts[f]);
        sh.shapes.push(ShapeRow {
            step: s.step,
            frame,
            gallery: shape::side_view(&fiber, sh.cell),
            colour: sigma2_colour(fiber.sigma2),
            channel: shape::in_box(&fiber, box_plus),
        });
    }
}

/// The time columns of the rows that stand for a whole t+ (`on_t_plus`: on the `step` and
/// `t+` timelines) or of the others (`step` only), as a row-wise log with [`set_time`]
/// would place them.
fn time_columns(
    rows: &[(u64, Option<i64>)],
    on_t_plus: bool,
) -> Option<(Vec<usize>, Vec<rerun::TimeColumn>)> {
    let part: Vec<usize> = (0..rows.len())
        .filter(|&i| rows[i].1.is_some() == on_t_plus)
        .collect();
    if part.is_empty() {
        return None;
    }
    let mut indexes = vec![rerun::TimeColumn::new_sequence(
        "step",
        part.iter().map(|&i| rows[i].0 as i64),
    )];
    if on_t_plus {
        indexes.push(rerun::TimeColumn::new_sequence(
            "t+",
            part.iter().filter_map(|&i| rows[i].1),
        ));
    }
    Some((part, indexes))
}

/// Serialized batches as columns of one-element rows.
fn unit_columns(
    batches: Vec<rerun::SerializedComponentBatch>,
) -> Result<Vec<rerun::SerializedComponentColumn>, ViewerError> {
    batches
        .into_iter()
        .map(|b| b.column_of_unit_batches().map_err(err))
        .collect()
}

/// A fibre's shown states as `send_columns` input: per row its gallery strip (the standard
/// `LineStrips2D`, with its σ² colour) and its channel strip (`fiber:channel_strip`).
fn shape_columns(rows: &[ShapeRow]) -> Result<Vec<SeriesChunk>, ViewerError> {
    let times: Vec<(u64, Option<i64>)> = rows.iter().map(|r| (r.step, r.frame)).collect();
    let mut out = Vec::new();
    for on_t_plus in [true, false] {
        let Some((part, indexes)) = time_columns(&times, on_t_plus) else {
            continue;
        };
        let gallery = rerun::LineStrips2D::update_fields()
            .with_strips(part.iter().map(|&i| rows[i].gallery.clone()))
            .with_colors(part.iter().map(|&i| {
                let [r, g, b] = rows[i].colour;
                rerun::Color::from_rgb(r, g, b)
            }));
        let channel = rerun::DynamicArchetype::new(paths::ARCHETYPE)
            .with_component::<rerun::components::LineStrip3D>(
                paths::CHANNEL_STRIP,
                part.iter().map(|&i| rows[i].channel.clone()),
            );
        let mut columns = unit_columns(rerun::AsComponents::as_serialized_batches(&gallery))?;
        columns.extend(unit_columns(rerun::AsComponents::as_serialized_batches(
            &channel,
        ))?);
        out.push((indexes, columns));
    }
    Ok(out)
}

/// Keeps the four series of every shown fibre at this step (sent as columns later: one
/// chunk per fibre instead of a row per fibre and step, several times smaller).
fn collect_metrics(
    m: &fiberflow_messages::FiberGroupMetrics,
    shown: &mut HashMap<usize, Shown>,
    h_plus: f64,
    dt_plus: f64,
) {
    let n = m.sigma2.len();
    let frame = shape::whole_t_plus(m.t_plus, dt_plus);
    for (&f, sh) in shown.iter_mut() {
        if f >= n || 3 * f + 2 >= m.centre_of_mass.len() {
            continue;
        }
        let vals = [
            m.sigma2[f],
            m.z1.get(f).map_or(f64::NAN, |z| z.abs()),
            m.end_to_end.get(f).copied().unwrap_or(f64::NAN),
            shape::wall_distance(m.centre_of_mass[3 * f + 1], h_plus),
        ];
        sh.series.push((m.step, frame, vals));
        sh.sigma2.push((m.step, m.t_plus, m.sigma2[f]));
    }
}

/// A fibre's series as `send_columns` input: the steps that stand for a whole t+ (on the
/// `step` and `t+` timelines) and the others (`step` only), as a row-wise log with
/// [`set_time`] would place them.
fn series_columns(rows: &[SeriesRow]) -> Result<Vec<SeriesChunk>, ViewerError> {
    let times: Vec<(u64, Option<i64>)> = rows.iter().map(|r| (r.0, r.1)).collect();
    let mut out = Vec::new();
    for on_t_plus in [true, false] {
        let Some((part, indexes)) = time_columns(&times, on_t_plus) else {
            continue;
        };
        let mut arch = rerun::DynamicArchetype::new(paths::ARCHETYPE);
        for (k, series) in paths::SERIES.iter().enumerate() {
            arch = arch.with_component::<rerun::components::Scalar>(
                series.component,
                part.iter().map(|&i| rows[i].2[k]),
            );
        }
        let columns = unit_columns(rerun::AsComponents::as_serialized_batches(&arch))?;
        out.push((indexes, columns));
    }
    Ok(out)
}

/// Coiling events of every shown fibre (onset as in `fiberflow_analysis::coiling`): a text
/// log line per event and a marker over the fibre in the gallery, at the first step at or
/// after the onset.
fn log_events(
    rec: &rerun::RecordingStream,
    shown: &HashMap<String, HashMap<usize, Shown>>,
    thresholds: &[f64],
    dt_plus: f64,
    cell_plus: f64,
) -> Result<usize, ViewerError> {
    let mut events = Vec::new();
    for (group, fibers) in shown {
        for (&f, sh) in fibers {
            let t: Vec<f64> = sh.sigma2.iter().map(|x| x.1).collect();
            let s2: Vec<f64> = sh.sigma2.iter().map(|x| x.2).collect();
            for (k, &thr) in thresholds.iter().enumerate() {
                if let Some(on) = fiberflow_analysis::coiling::first_crossing(&t, &s2, thr) {
                    let at = sh.sigma2.iter().find(|x| x.1 >= on).or(sh.sigma2.last());
                    if let Some(&(step, t_at, _)) = at {
                        events.push((step, t_at, on, group.clone(), f, k, thr, sh));
                    }
                }
            }
        }
    }
    events.sort_by(|a, b| (a.0, &a.3, a.4, a.5).cmp(&(b.0, &b.3, b.4, b.5)));
    for (step, t_at, on, group, _, k, thr, sh) in &events {
        set_time(rec, *step, *t_at, dt_plus);
        let text = format!("{} reached σ² = {thr} at t+ {on:.1}", sh.path);
        rec.log(
            paths::events(group),
            &rerun::TextLog::new(text).with_level(rerun::TextLogLevel::INFO),
        )
        .map_err(err)?;
        let c = ONSET_COLOURS[(*k).min(ONSET_COLOURS.len() - 1)];
        let cell = sh.cell;
        // a dot above the fibre's cell (gallery y points down)
        let above = [cell[0] as f32, (cell[1] - 0.42 * cell_plus) as f32];
        rec.log(
            paths::onset(&sh.path),
            &rerun::Points2D::new([above])
                .with_colors([rerun::Color::from_rgb(c[0], c[1], c[2])])
                .with_radii([rerun::Radius::new_scene_units(0.06 * cell_plus as f32)]),
        )
        .map_err(err)?;
    }
    Ok(events.len())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Steps standing for a whole t+ go into a chunk on both timelines, the others into one
    /// on `step` only; every chunk carries the four series with one value per row, in order.
    #[test]
    fn series_columns_split_by_timeline_and_keep_every_value() {
        use rerun::external::arrow::array::Array as _;
        let rows: Vec<SeriesRow> = (0..7u64)
            .map(|k| {
                let frame = (k % 5 == 0).then_some((k / 5) as i64);
                (k, frame, [k as f64, 0.5, 20.0 - k as f64, 10.0 + k as f64])
            })
            .collect();
        let chunks = series_columns(&rows).unwrap();
        assert_eq!(chunks.len(), 2);
        let (idx, cols) = &chunks[0];
        assert_eq!(idx.len(), 2);
        assert_eq!(idx[0].times_raw(), &[0, 5]);
        assert_eq!(idx[1].timeline().name().as_str(), "t+");
        assert_eq!(idx[1].times_raw(), &[0, 1]);
        assert_eq!(cols.len(), 4);
        let (idx, cols) = &chunks[1];
        assert_eq!(idx.len(), 1);
        assert_eq!(idx[0].times_raw(), &[1, 2, 3, 4, 6]);
        let sigma2 = cols
            .iter()
            .find(|c| c.descriptor.component.as_str() == paths::component("sigma2"))
            .expect("a sigma2 column");
        assert_eq!(sigma2.list_array.len(), 5, "one value per row");
        let values = sigma2
            .list_array
            .values()
            .as_any()
            .downcast_ref::<rerun::external::arrow::array::Float64Array>()
            .expect("scalars are f64");
        assert_eq!(values.values(), &[1.0, 2.0, 3.0, 4.0, 6.0]);
    }

    /// Shapes go out as one chunk per timeline set, each row one strip (all its points)
    /// with its colour, in the gallery and the channel column.
    #[test]
    fn shape_columns_keep_one_strip_and_colour_per_row() {
        use rerun::external::arrow::array::Array as _;
        let rows: Vec<ShapeRow> = (0..4u64)
            .map(|k| ShapeRow {
                step: 10 * k,
                frame: (k != 2).then_some(k as i64),
                gallery: vec![[k as f32, 0.0]; 3],
                colour: [k as u8, 0, 0],
                channel: vec![[0.0, k as f32, 1.0]; 3],
            })
            .collect();
        let chunks = shape_columns(&rows).unwrap();
        assert_eq!(chunks.len(), 2);
        let (idx, cols) = &chunks[0];
        assert_eq!(idx[0].times_raw(), &[0, 10, 30]);
        assert_eq!(idx[1].times_raw(), &[0, 1, 3]);
        let names: Vec<&str> = cols
            .iter()
            .map(|c| c.descriptor.component.as_str())
            .collect();
        for want in [
            "LineStrips2D:strips".to_string(),
            "LineStrips2D:colors".to_string(),
            paths::component(paths::CHANNEL_STRIP),
        ] {
            let col = cols
                .iter()
                .find(|c| c.descriptor.component.as_str() == want)
                .unwrap_or_else(|| panic!("no {want} column in {names:?}"));
            assert_eq!(col.list_array.len(), 3, "{want}: one entry per row");
            assert_eq!(
                col.list_array.value_length(1),
                1,
                "{want}: one strip per row"
            );
        }
        let (idx, cols) = &chunks[1];
        assert_eq!(idx.len(), 1);
        assert_eq!(idx[0].times_raw(), &[20]);
        assert!(cols.iter().all(|c| c.list_array.len() == 1));
    }

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
