//! The layout a first open shows: the gallery and the channel view on the left; on the
//! right one tab per time series (σ² first) with one plot per case, and the legend and
//! coiling events below them. Every fibre entity gets, in the channel view and in its
//! case's plots, a visualizer that maps its custom components (`fiber:*`) onto the standard
//! strip and series visualizers; its series name, colour and width are data on the entity.

use crate::paths;
use crate::ViewerError;
use rerun::blueprint::{
    Blueprint, BlueprintActivation, ContainerLike, Grid, Horizontal, Spatial2DView, Spatial3DView,
    Tabs, TextDocumentView, TextLogView, TimePanel, TimeSeriesView, Vertical,
};
use rerun::external::re_log_types::{BlueprintActivationCommand, LogMsg, StoreKind};
use rerun::external::re_sdk_types::blueprint::archetypes::{EyeControls3D, PlotLegend};
use rerun::external::re_sdk_types::blueprint::components::VisualizerComponentMapping as Mapping;
use rerun::external::re_sdk_types::blueprint::datatypes::VisualizerComponentMapping as MappingData;
use rerun::external::re_sdk_types::Visualizer;
use rerun::AsComponents;

/// A fibre entity as the blueprint refers to it.
pub struct FiberEntity {
    pub path: String,
    /// Its case (fibre group): its lines go into that case's plots.
    pub case: String,
}

/// A tab of plots: one series, one plot per case.
pub struct PlotTab<'a> {
    pub title: &'static str,
    pub component: &'static str,
    pub plots: Vec<CasePlot<'a>>,
}

/// One case's plot of one series: its title, its entity filter and the fibres whose
/// custom component it maps onto the series visualizer.
pub struct CasePlot<'a> {
    pub title: String,
    pub contents: String,
    pub fibers: Vec<&'a str>,
}

/// The plot tabs for `fibres`: one tab per series of [`paths::SERIES`], in it one plot per
/// case (cases in order of first appearance). A case's plot holds only its own fibres, so
/// the wider line of a selected fibre is not buried under hundreds of others.
pub fn plot_tabs(fibers: &[FiberEntity]) -> Vec<PlotTab<'_>> {
    let mut cases: Vec<&str> = Vec::new();
    for f in fibers {
        if !cases.contains(&f.case.as_str()) {
            cases.push(&f.case);
        }
    }
    paths::SERIES
        .iter()
        .map(|series| PlotTab {
            title: series.title,
            component: series.component,
            plots: cases
                .iter()
                .map(|case| CasePlot {
                    title: format!("{} · {case}", series.short),
                    contents: format!("+ /fibres/{case}/**"),
                    fibers: fibers
                        .iter()
                        .filter(|f| f.case == *case)
                        .map(|f| f.path.as_str())
                        .collect(),
                })
                .collect(),
        })
        .collect()
}

fn mapped(visualizer: &str, target: &str, source: &str) -> Visualizer {
    Visualizer::new(visualizer).with_mappings([Mapping(MappingData::new_source_component(
        target,
        paths::component(source),
    ))])
}

/// The views of a caught blueprint: (entity path `view/<id>`, view class), read from the
/// `ViewBlueprint` chunks (the builder API does not expose view ids).
fn view_classes(msgs: &[LogMsg]) -> Vec<(String, String)> {
    use rerun::external::arrow::array::{Array, ListArray, StringArray};
    let mut out = Vec::new();
    for m in msgs {
        let LogMsg::ArrowMsg(_, a) = m else { continue };
        let schema = a.batch.schema();
        let path = schema
            .metadata()
            .get("rerun:entity_path")
            .cloned()
            .unwrap_or_default();
        let path = path.trim_start_matches('/');
        if !(path.starts_with("view/") && path.matches('/').count() == 1) {
            continue;
        }
        for (i, field) in schema.fields().iter().enumerate() {
            if !field.name().ends_with("class_identifier") {
                continue;
            }
            let col = a.batch.column(i);
            let class = col
                .as_any()
                .downcast_ref::<ListArray>()
                .filter(|l| !l.is_empty())
                .map(|l| l.value(0))
                .and_then(|v| {
                    v.as_any()
                        .downcast_ref::<StringArray>()
                        .filter(|s| !s.is_empty())
                        .map(|s| s.value(0).to_string())
                });
            if let Some(class) = class {
                out.push((path.to_string(), class));
            }
        }
    }
    out
}

/// The camera a first open of the channel view starts from: above the lower half of the
/// channel, close enough that fibres show their shapes.
pub struct Eye {
    pub position: [f32; 3],
    pub look_target: [f32; 3],
}

/// Sends the layout for `fibres` to `rec`.
pub fn send(
    rec: &rerun::RecordingStream,
    fibers: &[FiberEntity],
    eye: &Eye,
) -> Result<(), ViewerError> {
    let gallery = Spatial2DView::new(
        "Gallery: each fibre at its centre of mass, side view (rows: cases; colour: σ²)",
    )
    .with_origin("/gallery")
    .with_contents(["+ /gallery/**", "+ /fibres/**"]);
    let mut channel = Spatial3DView::new("Channel (x1 streamwise, x2 wall-normal)")
        .with_origin("/")
        .with_contents(["+ /world/**", "+ /fibres/**"]);
    for f in fibers {
        // the channel strip, in the gallery strip's colour (σ²)
        let vis = Visualizer::new("Lines3D")
            .with_mappings([
                Mapping(MappingData::new_source_component(
                    "LineStrips3D:strips",
                    paths::component(paths::CHANNEL_STRIP),
                )),
                Mapping(MappingData::new_source_component(
                    "LineStrips3D:colors",
                    "LineStrips2D:colors",
                )),
            ])
            .with_overrides(
                &rerun::LineStrips3D::update_fields()
                    .with_radii([rerun::Radius::new_scene_units(1.0)]),
            );
        channel = channel.with_override(f.path.as_str(), vis);
    }
    let tabs: Vec<ContainerLike> = plot_tabs(fibers)
        .into_iter()
        .map(|tab| {
            let views = tab.plots.into_iter().map(|plot| {
                let mut v = TimeSeriesView::new(plot.title)
                    .with_origin("/")
                    .with_contents([plot.contents]);
                for path in plot.fibers {
                    v = v.with_override(
                        path,
                        mapped("SeriesLines", "Scalars:scalars", tab.component),
                    );
                }
                ContainerLike::from(v)
            });
            Grid::new(views)
                .with_name(tab.title)
                .with_grid_columns(2)
                .into()
        })
        .collect();
    // extra view properties the builder API does not offer, per view class: plot legends
    // off (hundreds of series), the channel camera (the only 3-D view)
    let props: Vec<(&str, &str, Vec<rerun::SerializedComponentBatch>)> = vec![
        (
            "TimeSeries",
            "PlotLegend",
            PlotLegend::new()
                .with_visible(false)
                .as_serialized_batches(),
        ),
        (
            "3D",
            "EyeControls3D",
            EyeControls3D::new()
                .with_position(eye.position)
                .with_look_target(eye.look_target)
                .with_eye_up([0.0, 1.0, 0.0])
                .as_serialized_batches(),
        ),
    ];
    let notes: Vec<ContainerLike> = vec![
        TextDocumentView::new("Legend").with_origin("legend").into(),
        TextLogView::new("Coiling events")
            .with_origin("events")
            .into(),
    ];
    let root = Horizontal::new([
        Vertical::new(vec![ContainerLike::from(gallery), channel.into()])
            .with_row_shares([0.58, 0.42])
            .into(),
        Vertical::new(vec![Tabs::new(tabs).into(), Tabs::new(notes).into()])
            .with_row_shares([0.68, 0.32])
            .into(),
    ])
    .with_column_shares([0.58, 0.42]);
    // open at the end of the run, where fibres have coiled
    let bp = Blueprint::new(root).with_time_panel(
        TimePanel::new()
            .with_timeline("t+")
            .with_play_state(rerun::blueprint::components::PlayState::Following),
    );
    send_with_properties(rec, &bp, &props)
}

/// Sends `bp` with `props` (view class, property name, batches) logged into the same
/// blueprint for every view of that class.
fn send_with_properties(
    rec: &rerun::RecordingStream,
    bp: &Blueprint,
    props: &[(&str, &str, Vec<rerun::SerializedComponentBatch>)],
) -> Result<(), ViewerError> {
    use crate::err;
    // the builder's messages, caught in memory
    let (cap, storage) = rerun::RecordingStreamBuilder::new("fiberflow")
        .memory()
        .map_err(err)?;
    bp.send(&cap, BlueprintActivation::default()).map_err(err)?;
    cap.flush_blocking().map_err(err)?;
    let mut msgs: Vec<LogMsg> = storage
        .take()
        .into_iter()
        .filter(|m| {
            m.store_id().kind() == StoreKind::Blueprint
                && !matches!(m, LogMsg::BlueprintActivationCommand(_))
        })
        .collect();
    let Some(bp_id) = msgs.first().map(|m| m.store_id().clone()) else {
        return Err(ViewerError::Rerun(
            "the blueprint produced no messages".into(),
        ));
    };
    // the properties, logged to a blueprint stream of their own and moved into this one
    let (extra, extra_storage) = rerun::RecordingStreamBuilder::new("fiberflow")
        .blueprint()
        .memory()
        .map_err(err)?;
    extra.set_time_sequence("blueprint", 0);
    let views = view_classes(&msgs);
    for (class, name, batches) in props {
        for (path, _) in views.iter().filter(|(_, c)| c == class) {
            extra
                .log_serialized_batches(format!("{path}/{name}"), false, batches.iter().cloned())
                .map_err(err)?;
        }
    }
    extra.flush_blocking().map_err(err)?;
    for mut m in extra_storage.take() {
        if let LogMsg::ArrowMsg(..) = m {
            m.set_store_id(bp_id.clone());
            msgs.push(m);
        }
    }
    let activation = BlueprintActivation::default();
    rec.send_blueprint(
        msgs,
        BlueprintActivationCommand {
            blueprint_id: bp_id,
            make_active: activation.make_active,
            make_default: activation.make_default,
        },
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The ids the builder gave its views can be read back, with their classes: the
    /// extra properties land on real views.
    #[test]
    fn view_classes_are_read_from_the_blueprint() {
        let root = Horizontal::new(vec![
            ContainerLike::from(Spatial3DView::new("a")),
            TimeSeriesView::new("b").into(),
            TimeSeriesView::new("c").into(),
        ]);
        let (cap, storage) = rerun::RecordingStreamBuilder::new("t").memory().unwrap();
        Blueprint::new(root)
            .send(&cap, BlueprintActivation::default())
            .unwrap();
        cap.flush_blocking().unwrap();
        let msgs: Vec<LogMsg> = storage.take();
        let mut classes: Vec<String> = view_classes(&msgs).into_iter().map(|v| v.1).collect();
        classes.sort();
        assert_eq!(classes, vec!["3D", "TimeSeries", "TimeSeries"]);
    }

    /// Each tab is one series; each fibre is in exactly one plot of each tab, its case's,
    /// whose filter takes that case's entities only.
    #[test]
    fn every_fiber_is_plotted_once_per_series_in_its_case() {
        let fibers: Vec<FiberEntity> = [("case2", 3), ("case1", 2), ("case2", 1)]
            .iter()
            .enumerate()
            .flat_map(|(k, &(case, n))| {
                (0..n).map(move |i| FiberEntity {
                    path: format!("fibers/{case}/next/f{k}{i}"),
                    case: case.to_string(),
                })
            })
            .collect();
        let tabs = plot_tabs(&fibers);
        let components: Vec<&str> = tabs.iter().map(|t| t.component).collect();
        assert_eq!(components, ["sigma2", "abs_z1", "end_to_end", "x2_plus"]);
        for tab in &tabs {
            let titles: Vec<&str> = tab.plots.iter().map(|p| p.title.as_str()).collect();
            assert_eq!(titles.len(), 2, "one plot per case");
            assert!(titles[0].ends_with("· case2") && titles[1].ends_with("· case1"));
            for f in &fibers {
                let holding: Vec<&CasePlot> = tab
                    .plots
                    .iter()
                    .filter(|p| p.fibers.contains(&f.path.as_str()))
                    .collect();
                assert_eq!(holding.len(), 1, "{} in {}", f.path, tab.title);
                assert_eq!(holding[0].contents, format!("+ /fibres/{}/**", f.case));
            }
            assert_eq!(tab.plots[0].fibers.len(), 4);
            assert_eq!(tab.plots[1].fibers.len(), 2);
        }
    }
}
