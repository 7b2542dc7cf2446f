//! Charts as PNG files: training curves (line charts with several series, labelled axes and
//! a legend), labelled confusion matrices, and grouped bar charts for comparisons (an agent
//! and its baselines).
//!
//! Drawn with plotters' bitmap backend; text uses the DejaVu Sans font bundled in
//! `pipeline/assets/fonts` (through ab_glyph), so nothing outside the binary is needed. The
//! same data gives the same bytes.
//!
//! | function | file | used by |
//! | --- | --- | --- |
//! | [`segmenter_curves_png`] | `curves.png`: training loss per step and per epoch, validation mIoU per epoch | `segmenter train` |
//! | [`confusion_png`] | `confusion.png`: share of each true class's pixels per predicted class | `segmenter eval` |
//! | [`agent_curves_png`] | `curves.png`: episode return, reach and crash rates per step | agent training |
//! | [`agent_eval_png`] | `eval.png`: reach, crash and time-over rates of an agent and its baselines | agent evaluation |

use std::path::Path;
use std::sync::Once;

use anyhow::{Result, anyhow};
use image::RgbImage;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use crate::output::write_file_atomic;

/// The font family every chart uses (registered once from the bundled file).
const FONT: &str = "sans-serif";
static FONT_BYTES: &[u8] = include_bytes!("../assets/fonts/DejaVuSans.ttf");
static REGISTER: Once = Once::new();

fn register_font() {
    REGISTER.call_once(|| {
        // The bundled file is a valid TrueType font; a failure would show as missing text.
        let _ = plotters::style::register_font(FONT, FontStyle::Normal, FONT_BYTES);
    });
}

/// Series colours (Okabe and Ito's palette, distinguishable with colour blindness).
const COLOURS: [RGBColor; 7] = [
    RGBColor(0, 114, 178),
    RGBColor(213, 94, 0),
    RGBColor(0, 158, 115),
    RGBColor(204, 121, 167),
    RGBColor(230, 159, 0),
    RGBColor(86, 180, 233),
    RGBColor(0, 0, 0),
];

fn colour(i: usize) -> RGBColor {
    COLOURS[i % COLOURS.len()]
}

fn plot_error(e: impl std::fmt::Display) -> anyhow::Error {
    anyhow!("cannot draw the chart: {e}")
}

/// Draws into a `width` x `height` white canvas and encodes it as PNG.
fn render(
    width: u32,
    height: u32,
    draw: impl FnOnce(&DrawingArea<BitMapBackend<'_>, Shift>) -> Result<()>,
) -> Result<Vec<u8>> {
    register_font();
    let mut pixels = vec![255u8; width as usize * height as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut pixels, (width, height)).into_drawing_area();
        root.fill(&WHITE).map_err(plot_error)?;
        draw(&root)?;
        root.present().map_err(plot_error)?;
    }
    let image = RgbImage::from_raw(width, height, pixels)
        .ok_or_else(|| anyhow!("cannot draw the chart: wrong buffer size"))?;
    Ok(datasets::image_io::encode_rgb_png(&image))
}

/// One line of a chart.
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    pub name: String,
    /// (x, y); points whose y is not finite are left out.
    pub points: Vec<(f64, f64)>,
    /// Mark each point with a dot (for series of few points, e.g. one per epoch).
    pub markers: bool,
}

impl Series {
    pub fn new(name: impl Into<String>, points: Vec<(f64, f64)>) -> Series {
        let markers = points.len() <= 40;
        Series {
            name: name.into(),
            points,
            markers,
        }
    }
}

/// One panel of line charts.
#[derive(Debug, Clone, PartialEq)]
pub struct LineChart {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub series: Vec<Series>,
    /// Fixed y range (e.g. 0 to 1 for rates) [default: the data's, padded].
    pub y_range: Option<(f64, f64)>,
    /// Ticks only at whole numbers of x (epochs).
    pub integer_x: bool,
}

/// Width of the legend column right of a chart.
const LEGEND_WIDTH: u32 = 170;

/// What a legend entry shows beside its name.
#[derive(Debug, Clone, Copy)]
enum Key {
    Line(RGBColor),
    Box(RGBColor),
}

/// The legend, in a column of its own so it never hides data.
fn draw_legend(
    area: &DrawingArea<BitMapBackend<'_>, Shift>,
    entries: &[(&str, Key)],
) -> Result<()> {
    for (i, (name, key)) in entries.iter().enumerate() {
        let y = 58 + 24 * i as i32;
        match key {
            Key::Line(c) => area.draw(&PathElement::new(vec![(6, y), (30, y)], c.stroke_width(3))),
            Key::Box(c) => area.draw(&Rectangle::new([(10, y - 7), (24, y + 7)], c.filled())),
        }
        .map_err(plot_error)?;
        area.draw(&Text::new(
            (*name).to_owned(),
            (38, y),
            TextStyle::from((FONT, 14)).pos(Pos::new(HPos::Left, VPos::Center)),
        ))
        .map_err(plot_error)?;
    }
    Ok(())
}

/// The range of `values`, padded by 5 % (or ±1 when it is one value); (0, 1) when empty.
fn padded_range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
    if !lo.is_finite() {
        (0.0, 1.0)
    } else if hi - lo < 1e-12 {
        (lo - 1.0, hi + 1.0)
    } else {
        let pad = (hi - lo) * 0.05;
        (lo - pad, hi + pad)
    }
}

/// `panels` stacked one above the other in one PNG of `width` x (`panel_height` per panel).
pub fn line_charts_png(panels: &[LineChart], width: u32, panel_height: u32) -> Result<Vec<u8>> {
    let height = panel_height * panels.len().max(1) as u32;
    render(width, height, |root| {
        let areas = root.split_evenly((panels.len().max(1), 1));
        for (area, panel) in areas.iter().zip(panels) {
            draw_line_chart(area, panel)?;
        }
        Ok(())
    })
}

fn draw_line_chart(panel: &DrawingArea<BitMapBackend<'_>, Shift>, c: &LineChart) -> Result<()> {
    let width = panel.dim_in_pixel().0;
    let (area, legend) = panel.split_horizontally(width.saturating_sub(LEGEND_WIDTH));
    let entries: Vec<(&str, Key)> = c
        .series
        .iter()
        .enumerate()
        .filter(|(_, s)| !s.name.is_empty())
        .map(|(i, s)| (s.name.as_str(), Key::Line(colour(i))))
        .collect();
    draw_legend(&legend, &entries)?;
    let finite = |s: &Series| -> Vec<(f64, f64)> {
        s.points
            .iter()
            .copied()
            .filter(|(x, y)| x.is_finite() && y.is_finite())
            .collect()
    };
    let all: Vec<(f64, f64)> = c.series.iter().flat_map(finite).collect();
    let (x0, x1) = match padded_range(all.iter().map(|p| p.0)) {
        // Steps and epochs start at the left edge.
        (lo, hi) if all.iter().all(|p| p.0 >= 0.0) && lo < 0.0 && hi > 0.0 => (0.0, hi),
        range => range,
    };
    let (y0, y1) = c
        .y_range
        .unwrap_or_else(|| padded_range(all.iter().map(|p| p.1)));
    let mut chart = ChartBuilder::on(&area)
        .caption(&c.title, (FONT, 20))
        .margin(12)
        .x_label_area_size(46)
        .y_label_area_size(70)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(plot_error)?;
    // Whole-number ticks for epochs: as many as there are whole numbers, up to 10.
    let x_ticks = if c.integer_x {
        ((x1.floor() - x0.ceil()) as usize + 1).clamp(2, 10)
    } else {
        10
    };
    let integer_x = c.integer_x;
    chart
        .configure_mesh()
        .x_desc(&c.x_label)
        .y_desc(&c.y_label)
        .label_style((FONT, 14))
        .axis_desc_style((FONT, 15))
        .light_line_style(WHITE)
        .bold_line_style(RGBColor(222, 222, 222))
        .x_labels(x_ticks)
        .x_label_formatter(&|x| {
            if integer_x && (x - x.round()).abs() > 1e-9 {
                String::new()
            } else {
                short_number(*x)
            }
        })
        .y_label_formatter(&|y| short_number(*y))
        .draw()
        .map_err(plot_error)?;
    for (i, s) in c.series.iter().enumerate() {
        let points = finite(s);
        let style = colour(i).stroke_width(2);
        chart
            .draw_series(LineSeries::new(points.iter().copied(), style))
            .map_err(plot_error)?;
        if s.markers {
            chart
                .draw_series(
                    points
                        .iter()
                        .map(|p| Circle::new(*p, 3, colour(i).filled())),
                )
                .map_err(plot_error)?;
        }
    }
    Ok(())
}

/// A tick label: integers without decimals, others with up to three significant decimals.
fn short_number(v: f64) -> String {
    if (v == v.round() && v.abs() < 1e9) || v.abs() >= 100.0 {
        format!("{v:.0}")
    } else if v.abs() >= 1.0 {
        format!("{v:.2}")
            .trim_end_matches('0')
            .trim_end_matches('.')
            .to_owned()
    } else {
        format!("{v:.3}")
            .trim_end_matches('0')
            .trim_end_matches('.')
            .to_owned()
    }
}

/// A confusion matrix: rows are the true classes, columns the predicted ones; each cell
/// shows the share of its row (in %), shaded from white (0) to dark blue (all of the row),
/// with the class names on both axes and each row's pixel count on the right.
pub fn confusion_png(title: &str, classes: &[String], rows: &[Vec<u64>]) -> Result<Vec<u8>> {
    const CELL: i32 = 100;
    const LEFT: i32 = 150;
    const TOP: i32 = 110;
    const RIGHT: i32 = 110;
    const BOTTOM: i32 = 30;
    let n = classes.len() as i32;
    let width = (LEFT + n * CELL + RIGHT) as u32;
    let height = (TOP + n * CELL + BOTTOM) as u32;
    render(width, height, |root| {
        let text = |s: &str, x: i32, y: i32, size: u32, colour: &RGBColor, h: HPos| {
            root.draw(&Text::new(
                s.to_owned(),
                (x, y),
                TextStyle::from((FONT, size))
                    .color(colour)
                    .pos(Pos::new(h, VPos::Center)),
            ))
            .map_err(plot_error)
        };
        let grey = RGBColor(90, 90, 90);
        text(title, width as i32 / 2, 22, 20, &BLACK, HPos::Center)?;
        text(
            "predicted class",
            LEFT + n * CELL / 2,
            58,
            16,
            &grey,
            HPos::Center,
        )?;
        text("true class", LEFT - 12, 84, 16, &grey, HPos::Right)?;
        text("pixels", LEFT + n * CELL + 12, 84, 14, &grey, HPos::Left)?;
        for (c, name) in classes.iter().enumerate() {
            let c = c as i32;
            text(
                &name.replace('_', " "),
                LEFT + c * CELL + CELL / 2,
                TOP - 16,
                14,
                &BLACK,
                HPos::Center,
            )?;
            text(
                &name.replace('_', " "),
                LEFT - 12,
                TOP + c * CELL + CELL / 2,
                14,
                &BLACK,
                HPos::Right,
            )?;
        }
        for (t, row) in rows.iter().enumerate().take(classes.len()) {
            let total: u64 = row.iter().sum();
            let y = TOP + t as i32 * CELL;
            text(
                &compact_count(total),
                LEFT + n * CELL + 12,
                y + CELL / 2,
                14,
                &grey,
                HPos::Left,
            )?;
            for (p, &count) in row.iter().enumerate().take(classes.len()) {
                let x = LEFT + p as i32 * CELL;
                let share = if total == 0 {
                    None
                } else {
                    Some(count as f64 / total as f64)
                };
                let fill = share.map_or(RGBColor(245, 245, 245), shade);
                root.draw(&Rectangle::new(
                    [(x, y), (x + CELL, y + CELL)],
                    fill.filled(),
                ))
                .map_err(plot_error)?;
                let border = if t == p {
                    BLACK.stroke_width(2)
                } else {
                    RGBColor(200, 200, 200).stroke_width(1)
                };
                root.draw(&Rectangle::new([(x, y), (x + CELL, y + CELL)], border))
                    .map_err(plot_error)?;
                let (label, ink) = match share {
                    None => ("–".to_owned(), grey),
                    Some(s) => (
                        percent(s),
                        if s > 0.45 {
                            WHITE
                        } else {
                            RGBColor(20, 20, 20)
                        },
                    ),
                };
                text(&label, x + CELL / 2, y + CELL / 2, 17, &ink, HPos::Center)?;
            }
        }
        Ok(())
    })
}

/// White to dark blue.
fn shade(share: f64) -> RGBColor {
    let s = share.clamp(0.0, 1.0);
    let mix = |from: f64, to: f64| (from + (to - from) * s).round() as u8;
    RGBColor(mix(255.0, 8.0), mix(255.0, 48.0), mix(255.0, 107.0))
}

/// `93.1 %`, `0.4 %`, `<0.1 %`, `0 %`.
fn percent(share: f64) -> String {
    let p = share * 100.0;
    if p == 0.0 {
        "0 %".to_owned()
    } else if p < 0.05 {
        "<0.1 %".to_owned()
    } else {
        format!("{p:.1} %")
    }
}

/// `950`, `12.3 k`, `4.56 M`, `1.2 G`.
fn compact_count(n: u64) -> String {
    let v = n as f64;
    if v < 1e3 {
        n.to_string()
    } else if v < 1e6 {
        format!("{:.1} k", v / 1e3)
    } else if v < 1e9 {
        format!("{:.2} M", v / 1e6)
    } else {
        format!("{:.2} G", v / 1e9)
    }
}

/// A grouped bar chart: one group per category along x, one bar per series in each group
/// (named in the legend), each bar labelled with its value.
#[derive(Debug, Clone, PartialEq)]
pub struct BarChart {
    pub title: String,
    pub y_label: String,
    pub categories: Vec<String>,
    /// (name, one value per category); a value that is not finite leaves its bar out.
    pub series: Vec<(String, Vec<f64>)>,
    /// Fixed y range [default: 0 to the largest value, padded].
    pub y_range: Option<(f64, f64)>,
    /// How a bar's value is written above it.
    pub value_format: ValueFormat,
}

/// How [`BarChart`] writes values.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ValueFormat {
    /// A share 0..1 as `42 %`.
    Percent,
    /// The number, up to three decimals.
    Number,
}

pub fn bar_chart_png(c: &BarChart, width: u32, height: u32) -> Result<Vec<u8>> {
    render(width, height, |canvas| {
        let (area, legend) = canvas.split_horizontally(width.saturating_sub(LEGEND_WIDTH));
        let root = &area;
        let entries: Vec<(&str, Key)> = c
            .series
            .iter()
            .enumerate()
            .map(|(i, (name, _))| (name.as_str(), Key::Box(colour(i))))
            .collect();
        if entries.len() > 1 {
            draw_legend(&legend, &entries)?;
        }
        let groups = c.categories.len().max(1);
        let top = c
            .series
            .iter()
            .flat_map(|(_, v)| v.iter().copied())
            .filter(|v| v.is_finite())
            .fold(0.0f64, f64::max);
        let (y0, y1) = c
            .y_range
            .unwrap_or((0.0, if top > 0.0 { top * 1.12 } else { 1.0 }));
        let mut chart = ChartBuilder::on(root)
            .caption(&c.title, (FONT, 20))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(70)
            .build_cartesian_2d(0.0..groups as f64, y0..y1)
            .map_err(plot_error)?;
        chart
            .configure_mesh()
            .disable_x_mesh()
            .x_labels(0)
            .y_desc(&c.y_label)
            .label_style((FONT, 14))
            .axis_desc_style((FONT, 15))
            .light_line_style(WHITE)
            .bold_line_style(RGBColor(222, 222, 222))
            .y_label_formatter(&|y| match c.value_format {
                ValueFormat::Percent => format!("{:.0} %", y * 100.0),
                ValueFormat::Number => short_number(*y),
            })
            .draw()
            .map_err(plot_error)?;
        let bars = c.series.len().max(1) as f64;
        let slot = 0.8 / bars;
        for (s, (_, values)) in c.series.iter().enumerate() {
            let fill = colour(s);
            let rects: Vec<Rectangle<(f64, f64)>> = values
                .iter()
                .enumerate()
                .filter(|(_, v)| v.is_finite())
                .map(|(g, &v)| {
                    let x = g as f64 + 0.1 + s as f64 * slot;
                    Rectangle::new([(x + slot * 0.08, y0), (x + slot * 0.92, v)], fill.filled())
                })
                .collect();
            chart.draw_series(rects).map_err(plot_error)?;
        }
        // Values above the bars and category names under the groups, in pixels.
        for (s, (_, values)) in c.series.iter().enumerate() {
            for (g, &v) in values.iter().enumerate().filter(|(_, v)| v.is_finite()) {
                let x = g as f64 + 0.1 + (s as f64 + 0.5) * slot;
                let (px, py) = chart.backend_coord(&(x, v.max(y0)));
                let label = match c.value_format {
                    ValueFormat::Percent => format!("{:.0} %", v * 100.0),
                    ValueFormat::Number => short_number(v),
                };
                root.draw(&Text::new(
                    label,
                    (px, py - 10),
                    TextStyle::from((FONT, 13)).pos(Pos::new(HPos::Center, VPos::Center)),
                ))
                .map_err(plot_error)?;
            }
        }
        for (g, name) in c.categories.iter().enumerate() {
            let (px, py) = chart.backend_coord(&(g as f64 + 0.5, y0));
            root.draw(&Text::new(
                name.clone(),
                (px, py + 18),
                TextStyle::from((FONT, 15)).pos(Pos::new(HPos::Center, VPos::Center)),
            ))
            .map_err(plot_error)?;
        }
        Ok(())
    })
}

/// The curves of a segmenter training run.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SegmenterCurves {
    /// (optimiser step, loss) of each step.
    pub step_loss: Vec<(u64, f64)>,
    /// (step at the epoch's end, mean training loss of the epoch).
    pub epoch_loss: Vec<(u64, f64)>,
    /// (epoch, validation mIoU), (epoch, validation pixel accuracy).
    pub val_miou: Vec<(usize, f64)>,
    pub val_pixel_accuracy: Vec<(usize, f64)>,
}

/// `curves.png` of `segmenter train`: the training loss per step (and each epoch's mean),
/// and the validation mIoU and pixel accuracy per epoch.
pub fn segmenter_curves_png(c: &SegmenterCurves) -> Result<Vec<u8>> {
    let mut loss = vec![Series {
        name: "loss per step".into(),
        points: c.step_loss.iter().map(|&(s, l)| (s as f64, l)).collect(),
        markers: c.step_loss.len() <= 40,
    }];
    if !c.epoch_loss.is_empty() {
        loss.push(Series {
            name: "mean of the epoch".into(),
            points: c.epoch_loss.iter().map(|&(s, l)| (s as f64, l)).collect(),
            markers: true,
        });
    }
    let epochs = |v: &[(usize, f64)]| v.iter().map(|&(e, m)| (e as f64, m)).collect();
    line_charts_png(
        &[
            LineChart {
                title: "Training loss".into(),
                x_label: "optimiser step".into(),
                y_label: "loss".into(),
                series: loss,
                y_range: None,
                integer_x: false,
            },
            LineChart {
                title: "Validation".into(),
                x_label: "epoch".into(),
                y_label: "share".into(),
                series: vec![
                    Series {
                        name: "mIoU".into(),
                        points: epochs(&c.val_miou),
                        markers: true,
                    },
                    Series {
                        name: "pixel accuracy".into(),
                        points: epochs(&c.val_pixel_accuracy),
                        markers: true,
                    },
                ],
                y_range: Some((0.0, 1.0)),
                integer_x: true,
            },
        ],
        900,
        380,
    )
}

/// The curves of an agent's training: each finished episode's return, and the reach and
/// crash rates (e.g. over the last episodes, or of each validation), by environment step.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct AgentCurves {
    /// (step, return).
    pub returns: Vec<(u64, f64)>,
    /// (step, share of episodes that reached the goal), (step, share that crashed).
    pub reach_rate: Vec<(u64, f64)>,
    pub crash_rate: Vec<(u64, f64)>,
}

/// `curves.png` of an agent's training: return per step above, reach and crash rates per
/// step below.
pub fn agent_curves_png(c: &AgentCurves) -> Result<Vec<u8>> {
    let points = |v: &[(u64, f64)]| v.iter().map(|&(s, y)| (s as f64, y)).collect::<Vec<_>>();
    line_charts_png(
        &[
            LineChart {
                title: "Episode return".into(),
                x_label: "step".into(),
                y_label: "return".into(),
                series: vec![Series::new("return", points(&c.returns))],
                y_range: None,
                integer_x: false,
            },
            LineChart {
                title: "Outcomes".into(),
                x_label: "step".into(),
                y_label: "share of episodes".into(),
                series: vec![
                    Series::new("reached", points(&c.reach_rate)),
                    Series::new("crashed", points(&c.crash_rate)),
                ],
                y_range: Some((0.0, 1.0)),
                integer_x: false,
            },
        ],
        900,
        380,
    )
}

/// One policy's outcome shares in an evaluation.
#[derive(Debug, Clone, PartialEq)]
pub struct PolicyOutcomes {
    pub name: String,
    pub reach: f64,
    pub crash: f64,
    pub time_over: f64,
}

/// `eval.png` of an agent's evaluation: the reach, crash and time-over shares of the agent
/// and each baseline, one group of bars per policy.
pub fn agent_eval_png(title: &str, policies: &[PolicyOutcomes]) -> Result<Vec<u8>> {
    let column = |f: fn(&PolicyOutcomes) -> f64| policies.iter().map(f).collect::<Vec<_>>();
    let width = (220 + LEGEND_WIDTH + 170 * policies.len() as u32).max(700);
    bar_chart_png(
        &BarChart {
            title: title.to_owned(),
            y_label: "share of episodes".into(),
            categories: policies.iter().map(|p| p.name.clone()).collect(),
            series: vec![
                ("reached".into(), column(|p| p.reach)),
                ("crashed".into(), column(|p| p.crash)),
                ("time over".into(), column(|p| p.time_over)),
            ],
            y_range: Some((0.0, 1.1)),
            value_format: ValueFormat::Percent,
        },
        width,
        460,
    )
}

/// Writes PNG bytes to `path` atomically.
pub fn write_png(path: &Path, png: &[u8]) -> Result<()> {
    write_file_atomic(path, png)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decode(png: &[u8]) -> RgbImage {
        image::load_from_memory(png).expect("a PNG").to_rgb8()
    }

    /// Pixels that are neither white nor nearly white: something was drawn there.
    fn inked(img: &RgbImage, x0: u32, y0: u32, x1: u32, y1: u32) -> usize {
        let mut n = 0;
        for y in y0..y1.min(img.height()) {
            for x in x0..x1.min(img.width()) {
                if img.get_pixel(x, y).0.iter().any(|&v| v < 200) {
                    n += 1;
                }
            }
        }
        n
    }

    #[test]
    fn confusion_matrix_has_names_shares_and_shades() {
        let classes: Vec<String> = ["road", "lane_marking", "vehicle"]
            .iter()
            .map(|s| (*s).to_owned())
            .collect();
        let rows = vec![vec![90, 5, 5], vec![50, 50, 0], vec![0, 0, 0]];
        let png = confusion_png("Confusion", &classes, &rows).expect("drawn");
        let img = decode(&png);
        assert_eq!(
            (img.width(), img.height()),
            (150 + 300 + 110, 110 + 300 + 30)
        );
        // The road row's diagonal cell is dark (90 %), the one beside it light (5 %).
        let dark = img.get_pixel(150 + 10, 110 + 10).0;
        let light = img.get_pixel(150 + 100 + 10, 110 + 10).0;
        assert!(dark[0] < 60 && light[0] > 220, "{dark:?} {light:?}");
        // Class names on the left and above the columns, figures in the cells.
        assert!(inked(&img, 0, 110, 140, 410) > 200, "no row names");
        assert!(inked(&img, 150, 80, 450, 105) > 200, "no column names");
        assert!(
            inked(&img, 150 + 120, 110 + 30, 150 + 180, 110 + 70) > 20,
            "no share"
        );
        // Deterministic.
        assert_eq!(
            png,
            confusion_png("Confusion", &classes, &rows).expect("drawn")
        );
    }

    #[test]
    fn curves_and_bars_draw_text_and_lines() {
        let curves = SegmenterCurves {
            step_loss: (1..=30).map(|s| (s, 2.0 / s as f64)).collect(),
            epoch_loss: vec![(10, 0.5), (20, 0.2), (30, 0.1)],
            val_miou: vec![(1, 0.3), (2, 0.45), (3, 0.5)],
            val_pixel_accuracy: vec![(1, 0.7), (2, 0.8), (3, 0.85)],
        };
        let img = decode(&segmenter_curves_png(&curves).expect("drawn"));
        assert_eq!((img.width(), img.height()), (900, 760));
        // Title text at the top of each panel, and the series in colour.
        assert!(inked(&img, 300, 0, 600, 30) > 50, "no title");
        let blue = img.pixels().filter(|p| p.0 == [0, 114, 178]).count();
        assert!(blue > 100, "no line drawn ({blue} px)");

        let eval = agent_eval_png(
            "roundabout insertion",
            &[
                PolicyOutcomes {
                    name: "agent".into(),
                    reach: 0.9,
                    crash: 0.05,
                    time_over: 0.05,
                },
                PolicyOutcomes {
                    name: "gap 10 m".into(),
                    reach: 0.6,
                    crash: 0.3,
                    time_over: 0.1,
                },
            ],
        )
        .expect("drawn");
        let img = decode(&eval);
        let orange = img.pixels().filter(|p| p.0 == [213, 94, 0]).count();
        assert!(orange > 200, "no crash bars ({orange} px)");

        let agent = agent_curves_png(&AgentCurves {
            returns: vec![(100, -1.0), (200, 0.5), (300, 1.0)],
            reach_rate: vec![(100, 0.2), (300, 0.8)],
            crash_rate: vec![(100, 0.5), (300, 0.1)],
        })
        .expect("drawn");
        assert_eq!(decode(&agent).height(), 760);
    }

    #[test]
    fn empty_and_single_point_series_still_draw() {
        let png = segmenter_curves_png(&SegmenterCurves {
            step_loss: vec![(1, f64::NAN)],
            val_miou: vec![(1, 0.4)],
            ..SegmenterCurves::default()
        });
        assert!(png.is_ok());
        assert_eq!(short_number(3.0), "3");
        assert_eq!(short_number(0.25), "0.25");
        assert_eq!(percent(0.9312), "93.1 %");
        assert_eq!(percent(0.0001), "<0.1 %");
        assert_eq!(compact_count(1_234_567), "1.23 M");
    }
}
