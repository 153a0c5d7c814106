//! PNG figures: particle snapshots, line plots, distributions and parity
//! plots.
//!
//! Figures are drawn with plotters' bitmap backend into an in-memory RGB
//! buffer, encoded with the `png` crate and written with
//! [`write_atomic`], so a crash never leaves a partial image. Text uses the
//! DejaVu Sans font bundled in `assets/fonts` (embedded in the binary and
//! registered with plotters' `ab_glyph` text backend): no system fonts or
//! fontconfig are needed. Particles and the colour bar are rasterised
//! directly (anti-aliased, to scale); axes, ticks, labels and legends come
//! from plotters.
//!
//! Data handling: non-finite points (and non-positive values on log axes)
//! are skipped and break lines; a series without drawable points still gets
//! its legend entry, marked "(no data)"; a figure without any drawable point
//! is still a valid image with a "no data" note. Nothing here panics on
//! bad data.

use std::ops::Range;
use std::path::Path;
use std::sync::OnceLock;

use anyhow::Context;
use plotters::coord::Shift;
use plotters::coord::ranged1d::{DefaultFormatting, KeyPointHint, Ranged};
use plotters::element::{Drawable, PointCollection};
use plotters::prelude::*;
use plotters::style::FontStyle;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use plotters_backend::{BackendCoord, DrawingErrorKind};

use crate::io::output::write_atomic;

mod axis;
mod colour;
mod glyph;
mod panels;
mod xy;

use axis::*;
use colour::*;
use glyph::*;
use panels::*;
use xy::*;

pub use colour::viridis;

/// DejaVu Sans (Bitstream Vera license, see assets/fonts/LICENSE).
const FONT_BYTES: &[u8] = include_bytes!("../../assets/fonts/DejaVuSans.ttf");
/// Family name under which the bundled font is registered.
const FONT: &str = "sans-serif";

/// Registers the bundled font with plotters (once per process) under the
/// generic family names plotters uses, so every text element resolves to it.
pub fn ensure_font() -> anyhow::Result<()> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| {
        ["sans-serif", "serif", "monospace"]
            .iter()
            .all(|name| plotters::style::register_font(name, FontStyle::Normal, FONT_BYTES).is_ok())
    });
    anyhow::ensure!(
        ok,
        "the bundled font assets/fonts/DejaVuSans.ttf could not be parsed"
    );
    Ok(())
}

type Area<'a> = DrawingArea<BitMapBackend<'a>, Shift>;

/// A white `w`×`h` RGB canvas handed to `draw`, then PNG-encoded and
/// written atomically to `path`.
fn render_png(
    path: &Path,
    (w, h): (u32, u32),
    draw: impl FnOnce(&mut [u8]) -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    ensure_font()?;
    let mut buf = vec![255u8; w as usize * h as usize * 3];
    draw(&mut buf).with_context(|| format!("drawing {}", path.display()))?;
    let png = encode_png(&buf, w, h)?;
    write_atomic(path, &png)
}

/// Encodes an 8-bit RGB buffer as PNG, with the fast deflate: a
/// 1135 × 1200 particle picture takes 4 ms instead of the 52 ms of the
/// balanced level, for a file about 30 % larger (results/benchmarks.md,
/// sixteenth session).
fn encode_png(rgb: &[u8], w: u32, h: u32) -> anyhow::Result<Vec<u8>> {
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, w, h);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_compression(png::Compression::Fast);
    let mut writer = enc.write_header().context("PNG header")?;
    writer.write_image_data(rgb).context("PNG data")?;
    writer.finish().context("PNG end")?;
    Ok(out)
}

/// One snapshot panel of [`particle_panels`].
#[derive(Clone, Debug)]
pub struct ParticlePanel<'a> {
    pub title: String,
    /// Lower corner of the shown domain (m).
    pub lo: [f64; 2],
    /// Upper corner of the shown domain (m).
    pub hi: [f64; 2],
    /// x (m), y (m), radius (m), value; drawn in order (later on top).
    pub particles: &'a [(f64, f64, f64, f64)],
}

/// A named set of (x, y) points.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Series {
    pub label: String,
    pub points: Vec<(f64, f64)>,
}

impl Series {
    pub fn new(label: impl Into<String>, points: Vec<(f64, f64)>) -> Self {
        Series {
            label: label.into(),
            points,
        }
    }
}

/// Side-by-side snapshots (e.g. ideal vs non-ideal riser). Particles are
/// filled, anti-aliased circles to scale (never thinner than one pixel),
/// coloured by `value` with viridis on the shared scale vmin..vmax
/// (values outside are clamped; a non-finite value is drawn grey), with a
/// colour bar labelled `value_label`. All panels share one length scale and
/// keep their aspect ratio; tall domains give images about 1200 px high.
/// If `vmin < vmax` does not hold the scale is taken from the data.
pub fn particle_panels(
    path: &Path,
    panels: &[ParticlePanel],
    value_label: &str,
    vmin: f64,
    vmax: f64,
) -> anyhow::Result<()> {
    let (vmin, vmax) = colour_range(panels, vmin, vmax);
    let layout = PanelLayout::new(panels, vmin, vmax)?;
    render_png(path, (layout.width, layout.height), |buf| {
        draw_particle_panels(buf, &layout, panels, value_label, vmin, vmax)
    })
}

/// Linear or logarithmic axes of a line plot.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Scale {
    pub log_x: bool,
    pub log_y: bool,
}

impl Scale {
    pub const LINEAR: Scale = Scale {
        log_x: false,
        log_y: false,
    };
    pub const LOG_X: Scale = Scale {
        log_x: true,
        log_y: false,
    };
    pub const LOG_Y: Scale = Scale {
        log_x: false,
        log_y: true,
    };
}

/// Line plot of several series (lines, with markers when a series has few
/// points), axis labels and a legend that covers no data.
pub fn line_plot(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
    scale: Scale,
) -> anyhow::Result<()> {
    let layers: Vec<Layer> = series
        .iter()
        .enumerate()
        .map(|(i, s)| {
            let many = s.points.len() > 60;
            Layer {
                label: s.label.clone(),
                color: palette(i),
                points: s.points.clone(),
                line: Some(LineKind::Solid(2)),
                marker: (!many).then_some((Marker::ALL[i % Marker::ALL.len()], 5)),
                include_in_range: true,
                guide: false,
            }
        })
        .collect();
    let fig = XyFigure {
        size: (1200, 800),
        title,
        x_label,
        y_label,
        log_x: scale.log_x,
        log_y: scale.log_y,
        square: false,
        x_pad: 0.02,
    };
    plot_xy(path, &fig, &layers)
}

/// Histogram densities of several components (points are bin centres and
/// densities) against a reference curve such as the unit Gaussian
/// exp(−x²/2)/√(2π), drawn as a black line. With `log_y` the tails are
/// visible; the y range is then set by the series, and the reference is
/// clipped to it.
pub fn distribution_plot(
    path: &Path,
    title: &str,
    x_label: &str,
    series: &[Series],
    reference: &Series,
    log_y: bool,
) -> anyhow::Result<()> {
    let mut layers = vec![Layer {
        label: reference.label.clone(),
        color: RGBColor(0, 0, 0),
        points: reference.points.clone(),
        line: Some(LineKind::Solid(2)),
        marker: None,
        // On a log axis the reference would stretch the range to its far
        // tails; let the data decide (unless there is none).
        include_in_range: !log_y || series.iter().all(|s| s.points.is_empty()),
        guide: true,
    }];
    layers.extend(series.iter().enumerate().map(|(i, s)| Layer {
        label: s.label.clone(),
        color: palette(i),
        points: s.points.clone(),
        line: Some(LineKind::Solid(1)),
        marker: Some((Marker::ALL[i % Marker::ALL.len()], 5)),
        include_in_range: true,
        guide: false,
    }));
    let fig = XyFigure {
        size: (1200, 800),
        title,
        x_label,
        y_label: "probability density (−)",
        log_x: false,
        log_y,
        square: false,
        x_pad: 0.02,
    };
    plot_xy(path, &fig, &layers)
}

/// Measured (x) against predicted (y) as markers, with the y = x line, on
/// equal square axes; `log` makes both axes logarithmic.
pub fn parity_plot(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
    log: bool,
) -> anyhow::Result<()> {
    let mut layers: Vec<Layer> = series
        .iter()
        .enumerate()
        .map(|(i, s)| Layer {
            label: s.label.clone(),
            color: palette(i),
            points: s.points.clone(),
            line: None,
            marker: Some((
                Marker::ALL[i % Marker::ALL.len()],
                if s.points.len() > 300 { 3 } else { 5 },
            )),
            include_in_range: true,
            guide: false,
        })
        .collect();
    // Shared range of both axes, so that y = x is the diagonal.
    let (lo, hi) = {
        let vals = series
            .iter()
            .flat_map(|s| s.points.iter().flat_map(|&(x, y)| [x, y]))
            .filter_map(|v| to_axis(v, log));
        padded_range(vals, log, 0.05)
    };
    let (a, b) = if log {
        (10f64.powf(lo), 10f64.powf(hi))
    } else {
        (lo, hi)
    };
    // The y = x line spans the range exactly; as a hidden range-setter it
    // also makes the two axes identical.
    layers.insert(
        0,
        Layer {
            label: "y = x".into(),
            color: RGBColor(110, 110, 110),
            points: vec![(a, a), (b, b)],
            line: Some(LineKind::Dashed),
            marker: None,
            include_in_range: true,
            guide: true,
        },
    );
    let fig = XyFigure {
        size: (1000, 0),
        title,
        x_label,
        y_label,
        log_x: log,
        log_y: log,
        square: true,
        x_pad: 0.0,
    };
    plot_xy(path, &fig, &layers)
}

/// Width (px) of `s` in the bundled font at `size`.
fn text_width(size: f64, s: &str) -> u32 {
    (FONT, size)
        .into_font()
        .box_size(s)
        .map(|(w, _)| w)
        .unwrap_or((s.chars().count() as f64 * size * 0.6) as u32)
}

/// Text in the bundled font at `size` (px).
fn text_style(size: f64) -> TextStyle<'static> {
    TextStyle::from((FONT, size).into_font()).color(&BLACK)
}

#[cfg(test)]
mod tests;
