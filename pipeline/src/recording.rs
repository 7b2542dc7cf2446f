//! The rerun recording of a command (rerun 0.36 SDK).
//!
//! One recording per command, application id `pipeline`. With `--rerun save` it is written to
//! `recording.rrd` in the command's (temporary) output folder; [`Recording::finish`] flushes
//! and closes it, which must happen before the folder is renamed into place, or the file
//! would be cut short. Maps are logged static under `world/map/...` in 3D (z up, metres of
//! the map's local frame), so the viewer shows them as a ground plane:
//!
//! | entity | what |
//! | --- | --- |
//! | `world/map/lanes` | centre lines of the lanes off the rings, coloured by road class |
//! | `world/map/lane_boundaries` | left and right lane edges |
//! | `world/map/junctions` | junction area outlines |
//! | `world/map/roundabouts/<id>/ring_lanes` | centre lines of every lane of a ring, coloured by its kind |
//! | `world/map/roundabouts/<id>/label` | a point at the ring's centre labelled with its kind, lanes across and priority |
//! | `world/map/stop_lines` | stop and give-way lines, red |
//! | `world/map/markings` | centre lines (yellow), lane dividers and edges (white) |
//!
//! A ring's colour tells its kind: a roundabout magenta, a circular junction teal, a
//! mini-roundabout violet. Its label reads like a line of `pipeline map info`, e.g.
//! `#3 roundabout, 2 lanes wide, ring first (assumed)`.
//!
//! Inside `pipeline run` every stage logs into the run's one recording, each under its own
//! entity path: commands log through [`Stream`] and open their recording with
//! [`crate::commands::Context::open_recording`], which hands out the shared one. A stage's
//! stream ([`Stream::stage`]) puts the stage's name before the paths of commands that log
//! outside a root of their own (`maps/campus/world/map/...`, the logs stage's
//! `logs/episode_000/...`), and leaves the paths under a command's root
//! ([`COMMAND_ROOTS`]: `dataset/generate/...`, `segmenter/...`, `agent/...`, `replay/...`)
//! as the command alone writes them, so no stage's name is repeated (`agent/agent/...`).
//!
//! A recording's bytes are not reproducible (rerun stamps chunk ids and times), unlike the
//! other outputs.

use std::path::Path;

use anyhow::{Context, Result};
use maps::geometry::Point;
use maps::{LaneId, Map, MarkingKind, Roundabout, RoundaboutKind, StopKind};
use rerun::{
    AsComponents, Color, LineStrips3D, Points3D, Radius, RecordingStream, RecordingStreamBuilder,
    RecordingStreamResult, TimelineName,
};

use crate::args::RerunMode;
use crate::error::CliError;

/// File name of the recording inside an output folder.
pub const RECORDING_FILE: &str = "recording.rrd";

/// The roots under which commands log (`dataset/...`, `segmenter/...`, `agent/...`,
/// `logs/...`, `replay/...`): paths under them name their stage already.
pub const COMMAND_ROOTS: [&str; 5] = ["dataset", "segmenter", "agent", "logs", "replay"];

/// A rerun stream whose entity paths all sit under a prefix (empty: none).
#[derive(Debug, Clone)]
pub struct Stream {
    inner: RecordingStream,
    prefix: String,
    /// Paths under one of [`COMMAND_ROOTS`] are logged as they are, without the prefix.
    keep_command_roots: bool,
}

impl Stream {
    /// The whole stream, no prefix.
    pub fn new(inner: RecordingStream) -> Stream {
        Stream {
            inner,
            prefix: String::new(),
            keep_command_roots: false,
        }
    }

    /// The same stream with `prefix` (itself under this stream's prefix) before every path.
    pub fn under(&self, prefix: &str) -> Stream {
        Stream {
            inner: self.inner.clone(),
            prefix: self.path(prefix),
            keep_command_roots: self.keep_command_roots,
        }
    }

    /// The stream of a `pipeline run` stage: `stage` before every path, except those under a
    /// command's root ([`COMMAND_ROOTS`]), which name their stage already.
    pub fn stage(&self, stage: &str) -> Stream {
        Stream {
            keep_command_roots: true,
            ..self.under(stage)
        }
    }

    fn path(&self, entity: &str) -> String {
        let root = entity.split('/').next().unwrap_or_default();
        if self.keep_command_roots && COMMAND_ROOTS.contains(&root) {
            return entity.to_owned();
        }
        match (self.prefix.is_empty(), entity.is_empty()) {
            (true, _) => entity.to_owned(),
            (false, true) => self.prefix.clone(),
            (false, false) => format!("{}/{entity}", self.prefix),
        }
    }

    pub fn log<AS: ?Sized + AsComponents>(
        &self,
        entity: impl AsRef<str>,
        archetype: &AS,
    ) -> RecordingStreamResult<()> {
        self.inner.log(self.path(entity.as_ref()), archetype)
    }

    pub fn log_static<AS: ?Sized + AsComponents>(
        &self,
        entity: impl AsRef<str>,
        archetype: &AS,
    ) -> RecordingStreamResult<()> {
        self.inner.log_static(self.path(entity.as_ref()), archetype)
    }

    pub fn set_time_sequence(&self, timeline: impl Into<TimelineName>, sequence: i64) {
        self.inner.set_time_sequence(timeline, sequence);
    }

    pub fn set_duration_secs(&self, timeline: impl Into<TimelineName>, secs: f64) {
        self.inner.set_duration_secs(timeline, secs);
    }

    /// Clears this thread's time cursor (a new stage starts its timelines afresh).
    pub fn reset_time(&self) {
        self.inner.reset_time();
    }
}

/// An open recording (or none, with `--rerun off`).
#[derive(Debug)]
pub struct Recording {
    stream: Option<Stream>,
    mode: RerunMode,
}

impl Recording {
    /// Opens the recording `mode` asks for. `save_dir` is the folder an `.rrd` goes into with
    /// `--rerun save`; commands without an output folder pass None and record nothing then.
    pub fn open(mode: &RerunMode, save_dir: Option<&Path>) -> Result<Recording> {
        let builder = || RecordingStreamBuilder::new("pipeline").enabled(true);
        let stream = match mode {
            RerunMode::Off => None,
            RerunMode::Save => match save_dir {
                None => None,
                Some(dir) => {
                    let path = dir.join(RECORDING_FILE);
                    Some(builder().save(&path).map_err(|e| {
                        CliError::file(
                            &path,
                            format!("cannot write the rerun recording: {e}"),
                            "use --rerun off to skip it",
                        )
                    })?)
                }
            },
            RerunMode::Spawn => Some(builder().spawn().map_err(|e| {
                CliError::new(
                    format!("cannot start the rerun viewer: {e}"),
                    "install it with `pip install rerun-sdk==0.36.3`, or use --rerun save",
                )
            })?),
            RerunMode::Connect(url) => {
                Some(builder().connect_grpc_opts(url.clone()).map_err(|e| {
                    CliError::new(
                        format!("cannot connect to the rerun viewer at {url}: {e}"),
                        "start a viewer with `rerun`, check the address, or use --rerun save",
                    )
                })?)
            }
        };
        Ok(Recording {
            stream: stream.map(Stream::new),
            mode: mode.clone(),
        })
    }

    /// A view into a larger recording: what each stage of `pipeline run` logs into. Its
    /// [`finish`](Self::finish) flushes; the sink stays open while the owner holds it.
    pub fn shared(stream: &Stream, mode: &RerunMode) -> Recording {
        let stream = stream.clone();
        stream.reset_time();
        Recording {
            stream: Some(stream),
            mode: mode.clone(),
        }
    }

    pub fn is_on(&self) -> bool {
        self.stream.is_some()
    }

    /// The stream, for logging.
    pub fn stream(&self) -> Option<&Stream> {
        self.stream.as_ref()
    }

    /// Flushes everything and closes the sink (writes the `.rrd` footer).
    pub fn finish(mut self) -> Result<()> {
        if let Some(stream) = self.stream.take() {
            stream.inner.flush_blocking().map_err(|e| match &self.mode {
                RerunMode::Connect(url) => CliError::new(
                    format!("rerun viewer at {url}: {e}"),
                    "start a viewer first (`rerun`), check the address, or use --rerun save",
                ),
                RerunMode::Spawn => CliError::new(
                    format!("rerun viewer: {e}"),
                    "check that `rerun` starts (pip install rerun-sdk==0.36.3), or use --rerun save",
                ),
                RerunMode::Save | RerunMode::Off => CliError::new(
                    format!("{RECORDING_FILE}: cannot finish the rerun recording: {e}"),
                    "check free disk space, or use --rerun off",
                ),
            })?;
            // Dropping the last handle joins the batcher and the file writer (a shared
            // recording's owner holds another handle, so its sink stays open).
            drop(stream);
        }
        Ok(())
    }
}

/// Height of each layer above the ground, so overlapping lines do not flicker.
const Z_LANES: f32 = 0.0;
const Z_BOUNDARIES: f32 = 0.01;
const Z_JUNCTIONS: f32 = 0.02;
const Z_MARKINGS: f32 = 0.03;
const Z_ROUNDABOUTS: f32 = 0.04;
const Z_STOP_LINES: f32 = 0.05;
/// Height of a roundabout's label point, above the ring so it is not hidden by it.
const Z_ROUNDABOUT_LABELS: f32 = 0.5;

fn strip(points: &[Point], z: f32) -> Vec<[f32; 3]> {
    points.iter().map(|p| [p.x as f32, p.y as f32, z]).collect()
}

fn closed(points: &[Point], z: f32) -> Vec<[f32; 3]> {
    let mut s = strip(points, z);
    if let Some(&first) = s.first() {
        s.push(first);
    }
    s
}

/// Colour of a road class: big roads warm, small roads cool.
fn class_color(highway: &str) -> Color {
    let base = highway.trim_end_matches("_link");
    match base {
        "motorway" => Color::from_rgb(230, 80, 80),
        "trunk" => Color::from_rgb(240, 130, 70),
        "primary" => Color::from_rgb(250, 170, 60),
        "secondary" => Color::from_rgb(240, 210, 80),
        "tertiary" => Color::from_rgb(200, 220, 120),
        "residential" | "unclassified" | "road" => Color::from_rgb(140, 180, 230),
        "living_street" => Color::from_rgb(150, 210, 200),
        "service" => Color::from_rgb(150, 150, 170),
        "lanelet" => Color::from_rgb(90, 200, 230),
        _ => Color::from_rgb(120, 200, 120),
    }
}

/// Colour of a ring's lanes and label: one per kind.
fn kind_color(kind: RoundaboutKind) -> Color {
    match kind {
        RoundaboutKind::Roundabout => Color::from_rgb(220, 60, 220),
        RoundaboutKind::Circular => Color::from_rgb(40, 200, 180),
        RoundaboutKind::MiniRoundabout => Color::from_rgb(160, 110, 255),
    }
}

/// A roundabout's label: id, kind, lanes across and who has priority (and how we know).
fn roundabout_label(r: &Roundabout) -> String {
    let kind = r.kind.words();
    let lanes = match r.lanes_across {
        1 => "1 lane".to_owned(),
        n => format!("{n} lanes"),
    };
    let priority = r.priority.words(r.priority_source);
    let guessed = if r.source == maps::RoundaboutSource::Guessed {
        ", guessed"
    } else {
        ""
    };
    format!("#{} {kind}, {lanes} wide, {priority}{guessed}", r.id)
}

/// Logs a map under `world/map/...`, static.
pub fn log_map(rec: &Stream, map: &Map) -> Result<()> {
    let err = |what: &str| format!("rerun: cannot log {what}");
    rec.log_static("world", &rerun::ViewCoordinates::RIGHT_HAND_Z_UP())
        .with_context(|| err("world"))?;

    // The rings' lanes are drawn under `world/map/roundabouts/<id>`, not with the others.
    let on_rings: std::collections::BTreeSet<LaneId> = map
        .roundabouts
        .values()
        .flat_map(|r| r.ring_lanes.iter().chain(&r.circulating_lanes).copied())
        .collect();
    let lanes: Vec<_> = map
        .lanes
        .values()
        .filter(|l| l.centre.len() >= 2 && !on_rings.contains(&l.id))
        .collect();
    let colors: Vec<Color> = lanes
        .iter()
        .map(|l| {
            map.roads
                .get(&l.road)
                .map_or(Color::from_rgb(200, 200, 200), |r| class_color(&r.highway))
        })
        .collect();
    rec.log_static(
        "world/map/lanes",
        &LineStrips3D::new(lanes.iter().map(|l| strip(&l.centre, Z_LANES)))
            .with_colors(colors)
            .with_radii([Radius::new_scene_units(0.15)]),
    )
    .with_context(|| err("lanes"))?;

    let boundaries = map
        .lanes
        .values()
        .flat_map(|l| [&l.left, &l.right])
        .filter(|b| b.len() >= 2);
    rec.log_static(
        "world/map/lane_boundaries",
        &LineStrips3D::new(boundaries.map(|b| strip(b, Z_BOUNDARIES)))
            .with_colors([Color::from_rgb(110, 110, 110)])
            .with_radii([Radius::new_scene_units(0.05)]),
    )
    .with_context(|| err("lane boundaries"))?;

    let junctions = map.junctions.values().filter(|j| j.polygon.len() >= 3);
    rec.log_static(
        "world/map/junctions",
        &LineStrips3D::new(junctions.map(|j| closed(&j.polygon, Z_JUNCTIONS)))
            .with_colors([Color::from_rgb(250, 220, 40)])
            .with_radii([Radius::new_scene_units(0.1)]),
    )
    .with_context(|| err("junctions"))?;

    for r in map.roundabouts.values() {
        let base = format!("world/map/roundabouts/{}", r.id);
        let color = kind_color(r.kind);
        let mut ids: Vec<LaneId> = r.ring_lanes.clone();
        ids.extend(
            r.circulating_lanes
                .iter()
                .filter(|id| !r.ring_lanes.contains(id)),
        );
        let ring: Vec<_> = ids
            .iter()
            .filter_map(|id| map.lanes.get(id))
            .filter(|l| l.centre.len() >= 2)
            .map(|l| strip(&l.centre, Z_ROUNDABOUTS))
            .collect();
        if !ring.is_empty() {
            rec.log_static(
                format!("{base}/ring_lanes"),
                &LineStrips3D::new(ring)
                    .with_colors([color])
                    .with_radii([Radius::new_scene_units(0.3)]),
            )
            .with_context(|| err("a roundabout's ring lanes"))?;
        }
        rec.log_static(
            format!("{base}/label"),
            &Points3D::new([[r.centre.x as f32, r.centre.y as f32, Z_ROUNDABOUT_LABELS]])
                .with_labels([roundabout_label(r)])
                .with_show_labels(true)
                .with_colors([color])
                .with_radii([Radius::new_scene_units(0.8)]),
        )
        .with_context(|| err("a roundabout's label"))?;
    }

    let stops: Vec<_> = map
        .stop_lines
        .values()
        .filter(|s| s.line.len() >= 2)
        .collect();
    let stop_colors: Vec<Color> = stops
        .iter()
        .map(|s| match s.kind {
            StopKind::Stop => Color::from_rgb(230, 20, 20),
            StopKind::GiveWay => Color::from_rgb(255, 90, 60),
        })
        .collect();
    rec.log_static(
        "world/map/stop_lines",
        &LineStrips3D::new(stops.iter().map(|s| strip(&s.line, Z_STOP_LINES)))
            .with_colors(stop_colors)
            .with_radii([Radius::new_scene_units(0.25)]),
    )
    .with_context(|| err("stop lines"))?;

    let markings: Vec<_> = map.markings.iter().filter(|m| m.line.len() >= 2).collect();
    let marking_colors: Vec<Color> = markings
        .iter()
        .map(|m| match m.kind {
            MarkingKind::CentreLine => Color::from_rgb(250, 200, 0),
            MarkingKind::Dashed => Color::from_rgb(235, 235, 235),
            MarkingKind::SolidEdge => Color::from_rgb(255, 255, 255),
        })
        .collect();
    rec.log_static(
        "world/map/markings",
        &LineStrips3D::new(markings.iter().map(|m| strip(&m.line, Z_MARKINGS)))
            .with_colors(marking_colors)
            .with_radii([Radius::new_scene_units(0.06)]),
    )
    .with_context(|| err("markings"))?;
    Ok(())
}

/// Entity under which dataset samples are logged; the class table is logged static here,
/// so every image below it gets the class names and colours.
pub const DATASET_ENTITY: &str = "dataset";

/// Logs the class table (0-4 and 255 ignore) as a static AnnotationContext on `dataset`.
pub fn log_class_context(rec: &Stream) -> Result<()> {
    log_class_context_at(rec, DATASET_ENTITY)
}

/// Logs the class table as a static AnnotationContext on `entity`, so every segmentation
/// image below it gets the class names and colours.
pub fn log_class_context_at(rec: &Stream, entity: &str) -> Result<()> {
    let table = datasets::classes::class_table();
    let context = rerun::AnnotationContext::new(table.iter().map(|c| {
        let [r, g, b] = c.color;
        (
            u16::from(c.id),
            c.name.as_str(),
            rerun::Rgba32::from_rgb(r, g, b),
        )
    }));
    rec.log_static(entity, &context)
        .context("rerun: cannot log the class table")?;
    Ok(())
}

/// Logs an RGB image under `entity` at the current time.
pub fn log_rgb(rec: &Stream, entity: &str, image: &image::RgbImage) -> Result<()> {
    let (w, h) = image.dimensions();
    rec.log(
        entity,
        &rerun::Image::from_rgb24(image.as_raw().clone(), [w, h]),
    )
    .with_context(|| format!("rerun: cannot log {entity}"))?;
    Ok(())
}

/// Logs a label of class ids as a SegmentationImage under `entity` at the current time
/// (coloured by the class table logged above it).
pub fn log_segmentation(rec: &Stream, entity: &str, label: &image::GrayImage) -> Result<()> {
    let (w, h) = label.dimensions();
    rec.log(
        entity,
        &rerun::SegmentationImage::new(
            label.as_raw().clone(),
            rerun::datatypes::ImageFormat::segmentation([w, h], rerun::ChannelDatatype::U8),
        ),
    )
    .with_context(|| format!("rerun: cannot log {entity}"))?;
    Ok(())
}

/// Logs one sample at `frame` on the `frame` timeline: the image under
/// `dataset/<name>/image` and its label as a SegmentationImage under `dataset/<name>/label`.
/// Call [`log_class_context`] once first.
pub fn log_sample(
    rec: &Stream,
    name: &str,
    frame: i64,
    image: &image::RgbImage,
    label: &image::GrayImage,
) -> Result<()> {
    rec.set_time_sequence("frame", frame);
    log_rgb(rec, &format!("{DATASET_ENTITY}/{name}/image"), image)?;
    log_segmentation(rec, &format!("{DATASET_ENTITY}/{name}/label"), label)
}

/// Logs a route's path under `world/route`.
pub fn log_route(rec: &Stream, points: &[Point]) -> Result<()> {
    rec.log_static(
        "world/route",
        &LineStrips3D::new([strip(points, 0.1)])
            .with_colors([Color::from_rgb(40, 230, 90)])
            .with_radii([Radius::new_scene_units(0.5)]),
    )
    .context("rerun: cannot log the route")?;
    Ok(())
}

/// Logs scalar series (`(entity, value)`) at the current time (training curves, Q-values).
pub fn log_scalars(rec: &Stream, series: &[(&str, f64)]) -> Result<()> {
    for (entity, value) in series {
        rec.log(*entity, &rerun::Scalars::single(*value))
            .with_context(|| format!("rerun: cannot log {entity}"))?;
    }
    Ok(())
}

/// Logs road users as boxes (1.5 m tall, on the ground) under `entity`, the ego highlighted.
pub fn log_actors(rec: &Stream, entity: &str, actors: &[sim::Actor], ego: usize) -> Result<()> {
    let centres = actors
        .iter()
        .map(|a| [a.position.x as f32, a.position.y as f32, 0.75]);
    let half_sizes = actors
        .iter()
        .map(|a| [a.length_m as f32 / 2.0, a.width_m as f32 / 2.0, 0.75]);
    let rotations = actors.iter().map(|a| {
        let half = a.heading_rad as f32 / 2.0;
        rerun::Quaternion::from_xyzw([0.0, 0.0, half.sin(), half.cos()])
    });
    let colors = (0..actors.len()).map(|i| {
        if i == ego {
            Color::from_rgb(40, 230, 90)
        } else {
            Color::from_rgb(230, 120, 40)
        }
    });
    rec.log(
        entity,
        &rerun::Boxes3D::from_centers_and_half_sizes(centres, half_sizes)
            .with_quaternions(rotations)
            .with_colors(colors),
    )
    .with_context(|| format!("rerun: cannot log {entity}"))?;
    Ok(())
}

/// Logs a path on the ground (an ego's trajectory so far) under `entity`.
pub fn log_path(rec: &Stream, entity: &str, points: &[Point]) -> Result<()> {
    rec.log(
        entity,
        &LineStrips3D::new([strip(points, 0.2)])
            .with_colors([Color::from_rgb(40, 230, 90)])
            .with_radii([Radius::new_scene_units(0.3)]),
    )
    .with_context(|| format!("rerun: cannot log {entity}"))?;
    Ok(())
}

/// Logs a layer-major `u8` frame (`[layer, height, width]`) as one grey image per layer under
/// `entity/<layer name>`.
pub fn log_layers(
    rec: &Stream,
    entity: &str,
    frame: &[u8],
    names: &[&str],
    width: usize,
    height: usize,
) -> Result<()> {
    let size = width * height;
    for (layer, name) in frame.chunks_exact(size.max(1)).zip(names) {
        rec.log(
            format!("{entity}/{name}"),
            &rerun::Image::from_l8(layer.to_vec(), [width as u32, height as u32]),
        )
        .with_context(|| format!("rerun: cannot log {entity}/{name}"))?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn saving_writes_an_rrd_that_starts_like_one() -> Result<()> {
        let dir = tempfile::tempdir()?;
        let rec = Recording::open(&RerunMode::Save, Some(dir.path()))?;
        assert!(rec.is_on());
        let map = Map::new(
            maps::Projection::local(maps::LatLon::new(0.0, 0.0)),
            maps::DrivingSide::Right,
            "car",
        );
        if let Some(stream) = rec.stream() {
            log_map(stream, &map)?;
        }
        rec.finish()?;
        let bytes = std::fs::read(dir.path().join(RECORDING_FILE))?;
        assert!(
            bytes.starts_with(b"RRF2") || bytes.starts_with(b"RRIO"),
            "{:?}",
            &bytes[..bytes.len().min(8)]
        );
        Ok(())
    }

    #[test]
    fn a_stage_prefixes_only_paths_outside_the_command_roots() {
        let run = Stream::new(RecordingStream::disabled());
        let maps = run.stage("maps").under("campus");
        assert_eq!(maps.path("world/map/lanes"), "maps/campus/world/map/lanes");
        let agent = run.stage("agent");
        assert_eq!(agent.path("agent/episode_0/ego"), "agent/episode_0/ego");
        let augment = run.stage("augment");
        assert_eq!(
            augment.path("dataset/augment/image"),
            "dataset/augment/image"
        );
        assert_eq!(augment.path("dataset"), "dataset");
        let logs = run.stage("logs");
        assert_eq!(logs.path("episode_000/layers"), "logs/episode_000/layers");
        // A standalone command's stream keeps every path as it is.
        assert_eq!(run.path("segmenter/train/loss"), "segmenter/train/loss");
        assert_eq!(run.under("x").path("agent/a"), "x/agent/a");
    }

    /// What logging a map writes, per entity path: its line strips, labels and colours.
    #[derive(Debug, Default)]
    struct Logged {
        strips: usize,
        labels: Vec<String>,
        colors: Vec<Color>,
    }

    fn log_into_memory(map: &Map) -> Result<std::collections::BTreeMap<String, Logged>> {
        let (inner, storage) = RecordingStreamBuilder::new("pipeline").memory()?;
        log_map(&Stream::new(inner.clone()), map)?;
        inner.flush_blocking()?;
        let mut out = std::collections::BTreeMap::<String, Logged>::new();
        for msg in storage.take() {
            let rerun::log::LogMsg::ArrowMsg(_, arrow) = msg else {
                continue;
            };
            let chunk = rerun::log::Chunk::from_arrow_msg(&arrow)?;
            let path = chunk.entity_path().to_string();
            let logged = out
                .entry(path.trim_start_matches('/').to_owned())
                .or_default();
            let strips = LineStrips3D::descriptor_strips().component;
            logged.strips += chunk
                .iter_component::<rerun::components::LineStrip3D>(strips)
                .map(|row| row.len())
                .sum::<usize>();
            for labels in [
                LineStrips3D::descriptor_labels().component,
                Points3D::descriptor_labels().component,
            ] {
                for row in chunk.iter_component::<rerun::components::Text>(labels) {
                    logged
                        .labels
                        .extend(row.iter().map(|t| t.as_str().to_owned()));
                }
            }
            for colors in [
                LineStrips3D::descriptor_colors().component,
                Points3D::descriptor_colors().component,
            ] {
                for row in chunk.iter_component::<Color>(colors) {
                    logged.colors.extend(row.iter().copied());
                }
            }
        }
        Ok(out)
    }

    #[test]
    fn ring_lanes_are_logged_apart_with_the_colour_and_label_of_their_kind() -> Result<()> {
        let osm = maps::osm::parse_xml(
            maps::samples::two_lane_ring(r#"<tag k="junction" v="circular"/>"#).as_bytes(),
        )?;
        let map = maps::import_osm(&osm, &Default::default())?;
        let r = map.roundabouts.values().next().context("a ring")?;
        assert_eq!((r.kind, r.lanes_across), (RoundaboutKind::Circular, 2));
        assert!(r.ring_lanes.len() > r.circulating_lanes.len());

        let logged = log_into_memory(&map)?;
        let ring = &logged[&format!("world/map/roundabouts/{}/ring_lanes", r.id)];
        assert_eq!(ring.strips, r.ring_lanes.len());
        assert_eq!(ring.colors, [kind_color(RoundaboutKind::Circular)]);
        let label = &logged[&format!("world/map/roundabouts/{}/label", r.id)];
        assert_eq!(
            label.labels,
            [format!(
                "#{} circular junction, 2 lanes wide, ring first (assumed)",
                r.id
            )]
        );
        assert_eq!(label.colors, [kind_color(RoundaboutKind::Circular)]);
        // The ring's lanes are not drawn again with the others.
        assert_eq!(
            logged["world/map/lanes"].strips,
            map.lanes.len() - r.ring_lanes.len()
        );
        let kinds = [
            RoundaboutKind::Roundabout,
            RoundaboutKind::Circular,
            RoundaboutKind::MiniRoundabout,
        ]
        .map(kind_color);
        assert!(kinds[0] != kinds[1] && kinds[1] != kinds[2] && kinds[0] != kinds[2]);
        Ok(())
    }

    #[test]
    fn off_and_folderless_save_record_nothing() -> Result<()> {
        assert!(!Recording::open(&RerunMode::Off, None)?.is_on());
        assert!(!Recording::open(&RerunMode::Save, None)?.is_on());
        Ok(())
    }
}
