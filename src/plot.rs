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

/// DejaVu Sans (Bitstream Vera license, see assets/fonts/LICENSE).
const FONT_BYTES: &[u8] = include_bytes!("../assets/fonts/DejaVuSans.ttf");
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

/// Encodes an 8-bit RGB buffer as PNG.
fn encode_png(rgb: &[u8], w: u32, h: u32) -> anyhow::Result<Vec<u8>> {
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, w, h);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_compression(png::Compression::Balanced);
    let mut writer = enc.write_header().context("PNG header")?;
    writer.write_image_data(rgb).context("PNG data")?;
    writer.finish().context("PNG end")?;
    Ok(out)
}

// ---------------------------------------------------------------------------
// Public API
// ---------------------------------------------------------------------------

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

// ---------------------------------------------------------------------------
// Colours
// ---------------------------------------------------------------------------

/// Viridis control points (matplotlib's map sampled every 1/16).
const VIRIDIS: [[u8; 3]; 17] = [
    [68, 1, 84],
    [72, 26, 108],
    [71, 47, 125],
    [65, 68, 135],
    [57, 86, 140],
    [49, 104, 142],
    [42, 120, 142],
    [35, 136, 142],
    [31, 152, 139],
    [34, 168, 132],
    [53, 183, 121],
    [84, 197, 104],
    [122, 209, 81],
    [165, 219, 54],
    [210, 226, 27],
    [236, 229, 27],
    [253, 231, 37],
];

/// Viridis colour at `t` in [0, 1] (clamped); grey for NaN.
pub fn viridis(t: f64) -> [u8; 3] {
    if t.is_nan() {
        return [150, 150, 150];
    }
    let s = t.clamp(0.0, 1.0) * (VIRIDIS.len() - 1) as f64;
    let i = (s.floor() as usize).min(VIRIDIS.len() - 2);
    let f = s - i as f64;
    let (a, b) = (VIRIDIS[i], VIRIDIS[i + 1]);
    std::array::from_fn(|k| (a[k] as f64 + f * (b[k] as f64 - a[k] as f64)).round() as u8)
}

/// Categorical colours (matplotlib's tab10).
fn palette(i: usize) -> RGBColor {
    const TAB10: [(u8, u8, u8); 10] = [
        (31, 119, 180),
        (255, 127, 14),
        (44, 160, 44),
        (214, 39, 40),
        (148, 103, 189),
        (140, 86, 75),
        (227, 119, 194),
        (127, 127, 127),
        (188, 189, 34),
        (23, 190, 207),
    ];
    let (r, g, b) = TAB10[i % TAB10.len()];
    RGBColor(r, g, b)
}

fn colour_range(panels: &[ParticlePanel], vmin: f64, vmax: f64) -> (f64, f64) {
    if vmin.is_finite() && vmax.is_finite() && vmin < vmax {
        return (vmin, vmax);
    }
    let vals = panels
        .iter()
        .flat_map(|p| p.particles.iter().map(|q| q.3))
        .filter(|v| v.is_finite());
    let (lo, hi) = vals.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
        (a.min(v), b.max(v))
    });
    if lo < hi {
        (lo, hi)
    } else if lo.is_finite() {
        (lo - 0.5, lo + 0.5)
    } else {
        (0.0, 1.0)
    }
}

// ---------------------------------------------------------------------------
// Axes and ticks
// ---------------------------------------------------------------------------

/// Maps a data value to axis space (log10 on log axes); `None` if it cannot
/// be shown.
fn to_axis(v: f64, log: bool) -> Option<f64> {
    if !v.is_finite() {
        None
    } else if log {
        (v > 0.0).then(|| v.log10())
    } else {
        Some(v)
    }
}

/// Range (in axis space) of `vals`, widened by `pad` of its span on both
/// sides; a default range when empty, a small interval around a single
/// value.
fn padded_range(vals: impl Iterator<Item = f64>, log: bool, pad: f64) -> (f64, f64) {
    let (lo, hi) = vals.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
        (a.min(v), b.max(v))
    });
    if !(lo.is_finite() && hi.is_finite()) {
        return (0.0, 1.0);
    }
    if hi - lo <= 1e-12 * lo.abs().max(hi.abs()).max(1e-300) {
        let d = if log {
            0.5
        } else if lo == 0.0 {
            1.0
        } else {
            0.1 * lo.abs()
        };
        return (lo - d, hi + d);
    }
    let d = pad * (hi - lo);
    (lo - d, hi + d)
}

/// A 1-D axis in axis space (log10 of the value on log axes) with its tick
/// positions; a plotters coordinate whose labels are formatted by
/// [`Axis::label`].
#[derive(Clone, Debug)]
struct Axis {
    lo: f64,
    hi: f64,
    log: bool,
    major: Vec<f64>,
    minor: Vec<f64>,
    /// Decimals of linear tick labels.
    decimals: usize,
    /// Scientific notation for linear tick labels.
    sci: bool,
    /// Step between major ticks (linear axes).
    step: f64,
}

impl Axis {
    /// A linear axis on [lo, hi] with about `target` ticks.
    fn linear(lo: f64, hi: f64, target: usize) -> Axis {
        let span = hi - lo;
        let mut step = nice_step(span / target.max(1) as f64);
        let mut major = ticks_with_step(lo, hi, step);
        for _ in 0..6 {
            if major.len() >= 2 {
                break;
            }
            step = smaller_nice(step);
            major = ticks_with_step(lo, hi, step);
        }
        let m = lo.abs().max(hi.abs());
        let sci = !(1e-3..1e5).contains(&m);
        let decimals = (-(step.log10() + 1e-9).floor()).max(0.0) as usize;
        Axis {
            lo,
            hi,
            log: false,
            major,
            minor: Vec::new(),
            decimals,
            sci,
            step,
        }
    }

    /// A log axis on [lo, hi] (log10 values).
    fn log(lo: f64, hi: f64) -> Axis {
        let mut major = Vec::new();
        let mut minor = Vec::new();
        let k0 = (lo - 1e-9).floor() as i64;
        let k1 = (hi + 1e-9).ceil() as i64;
        let decades: Vec<f64> = (k0..=k1)
            .map(|k| k as f64)
            .filter(|&k| k >= lo - 1e-9 && k <= hi + 1e-9)
            .collect();
        let inside = |v: f64| v >= lo - 1e-9 && v <= hi + 1e-9;
        let mantissas = |ms: &[f64]| -> Vec<f64> {
            (k0..=k1)
                .flat_map(|k| ms.iter().map(move |m| k as f64 + m.log10()))
                .filter(|&v| inside(v))
                .collect()
        };
        if decades.len() >= 2 {
            // Every decade, or every 2nd, 5th, 10th, ... for wide ranges.
            let stride = nice_step(decades.len() as f64 / 8.0).max(1.0) as i64;
            for &k in &decades {
                if (k as i64).rem_euclid(stride) == 0 {
                    major.push(k);
                } else {
                    minor.push(k);
                }
            }
            if major.len() < 2 {
                major = decades.iter().step_by(stride as usize).copied().collect();
            }
            if stride == 1 {
                minor = mantissas(&[2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0]);
            }
        } else {
            major = mantissas(&[1.0, 2.0, 5.0]);
            if major.len() < 2 {
                major = mantissas(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0]);
            }
            minor = mantissas(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0]);
        }
        Axis {
            lo,
            hi,
            log: true,
            major,
            minor,
            decimals: 0,
            sci: false,
            step: 1.0,
        }
    }

    /// An axis fitted to `vals` (data values) with `pad` margins.
    fn fit(vals: impl Iterator<Item = f64>, log: bool, pad: f64, target: usize) -> Axis {
        let (lo, hi) = padded_range(vals.filter_map(|v| to_axis(v, log)), log, pad);
        if log {
            Axis::log(lo, hi)
        } else {
            Axis::linear(lo, hi, target)
        }
    }

    /// As [`Axis::fit`], with the top `top_fraction` of the axis left
    /// free (room for a legend above the data).
    fn fit_below(
        vals: impl Iterator<Item = f64>,
        log: bool,
        pad: f64,
        target: usize,
        top_fraction: f64,
    ) -> Axis {
        let (lo, hi) = padded_range(vals.filter_map(|v| to_axis(v, log)), log, pad);
        let hi = lo + (hi - lo) / (1.0 - top_fraction);
        if log {
            Axis::log(lo, hi)
        } else {
            Axis::linear(lo, hi, target)
        }
    }

    fn contains(&self, v: f64) -> bool {
        v >= self.lo && v <= self.hi
    }

    /// Tick label of axis-space value `v`.
    fn label(&self, v: f64) -> String {
        let s = if self.log {
            // Powers of ten as 10ⁿ on axes spanning three decades or more;
            // on shorter ones every label as a plain number (0.05, 0.1).
            if (v - v.round()).abs() < 1e-6 && self.hi - self.lo >= 3.0 {
                format!("10{}", superscript(v.round() as i64))
            } else {
                format_general(10f64.powf(v))
            }
        } else if v.abs() < 1e-9 * self.step {
            if self.sci {
                "0".to_string()
            } else {
                format!("{:.prec$}", 0.0, prec = self.decimals)
            }
        } else if self.sci {
            let e = v.abs().log10().floor();
            let d = (e - (self.step.log10() + 1e-9).floor()).max(0.0) as usize;
            format!("{v:.d$e}")
        } else {
            format!("{v:.prec$}", prec = self.decimals)
        };
        s.replace('-', "\u{2212}")
    }
}

impl Ranged for Axis {
    type FormatOption = DefaultFormatting;
    type ValueType = f64;

    fn map(&self, v: &f64, limit: (i32, i32)) -> i32 {
        let frac = (v - self.lo) / (self.hi - self.lo);
        let p = limit.0 as f64 + frac * (limit.1 - limit.0) as f64;
        if p.is_finite() {
            p.round().clamp(-1e6, 1e6) as i32
        } else {
            limit.0
        }
    }

    fn key_points<H: KeyPointHint>(&self, hint: H) -> Vec<f64> {
        if hint.weight().allow_light_points() {
            self.minor.clone()
        } else {
            self.major.clone()
        }
    }

    fn range(&self) -> Range<f64> {
        self.lo..self.hi
    }
}

/// The smallest of 1, 2, 5 × 10^k that is ≥ `raw`.
fn nice_step(raw: f64) -> f64 {
    if !(raw.is_finite() && raw > 0.0) {
        return 1.0;
    }
    let e = raw.log10().floor();
    let p = 10f64.powf(e);
    let f = raw / p;
    let n = if f <= 1.0 + 1e-9 {
        1.0
    } else if f <= 2.0 + 1e-9 {
        2.0
    } else if f <= 5.0 + 1e-9 {
        5.0
    } else {
        10.0
    };
    n * p
}

/// The next smaller step of the 1-2-5 sequence.
fn smaller_nice(step: f64) -> f64 {
    let e = (step.log10() + 1e-9).floor();
    let p = 10f64.powf(e);
    match (step / p).round() as i64 {
        5 => 2.0 * p,
        2 => p,
        _ => 0.5 * p,
    }
}

fn ticks_with_step(lo: f64, hi: f64, step: f64) -> Vec<f64> {
    if !(step > 0.0 && lo.is_finite() && hi.is_finite()) {
        return Vec::new();
    }
    let k0 = (lo / step - 1e-9).ceil();
    let k1 = (hi / step + 1e-9).floor();
    if !(k1 - k0 < 1000.0 && k0.abs() < 1e15) {
        return Vec::new();
    }
    (0..=(k1 - k0).max(-1.0) as i64)
        .map(|i| {
            let v = (k0 + i as f64) * step;
            if v.abs() < 1e-9 * step { 0.0 } else { v }
        })
        .collect()
}

/// Compact label for a number (log-axis ticks that are not powers of ten).
fn format_general(x: f64) -> String {
    let a = x.abs();
    if (1e-3..1e5).contains(&a) {
        let d = (-(a.log10() + 1e-9).floor()).max(0.0) as usize;
        format!("{x:.d$}")
    } else {
        format!("{x:.0e}")
    }
}

fn superscript(k: i64) -> String {
    k.to_string()
        .chars()
        .map(|c| match c {
            '-' => '⁻',
            '0' => '⁰',
            '1' => '¹',
            '2' => '²',
            '3' => '³',
            '4' => '⁴',
            '5' => '⁵',
            '6' => '⁶',
            '7' => '⁷',
            '8' => '⁸',
            _ => '⁹',
        })
        .collect()
}

// ---------------------------------------------------------------------------
// Markers and legend glyphs
// ---------------------------------------------------------------------------

#[derive(Clone, Copy, Debug, PartialEq)]
enum Marker {
    Circle,
    Square,
    TriangleUp,
    Diamond,
    TriangleDown,
    Cross,
    Plus,
}

impl Marker {
    const ALL: [Marker; 7] = [
        Marker::Circle,
        Marker::Square,
        Marker::TriangleUp,
        Marker::Diamond,
        Marker::TriangleDown,
        Marker::Cross,
        Marker::Plus,
    ];
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum LineKind {
    /// Solid with this width (px).
    Solid(u32),
    Dashed,
}

/// A marker at a point, or (as a legend sample) a short line with an
/// optional marker starting at the point.
struct Glyph<C> {
    at: C,
    legend_line: Option<(LineKind, RGBColor)>,
    marker: Option<(Marker, i32, RGBColor)>,
}

impl<'a, C: 'a> PointCollection<'a, C> for &'a Glyph<C> {
    type Point = &'a C;
    type IntoIter = std::iter::Once<&'a C>;
    fn point_iter(self) -> Self::IntoIter {
        std::iter::once(&self.at)
    }
}

/// Legend sample length (px).
const LEGEND_SAMPLE: i32 = 36;

impl<C, DB: DrawingBackend> Drawable<DB> for Glyph<C> {
    fn draw<I: Iterator<Item = BackendCoord>>(
        &self,
        mut pos: I,
        b: &mut DB,
        _: (u32, u32),
    ) -> Result<(), DrawingErrorKind<DB::ErrorType>> {
        let Some((mut x, y)) = pos.next() else {
            return Ok(());
        };
        if let Some((kind, color)) = self.legend_line {
            match kind {
                LineKind::Solid(w) => {
                    let st = color.stroke_width(w);
                    b.draw_line((x, y), (x + LEGEND_SAMPLE, y), &st)?;
                }
                LineKind::Dashed => {
                    let st = color.stroke_width(2);
                    for k in 0..3 {
                        let x0 = x + k * 13;
                        b.draw_line((x0, y), (x0 + 8, y), &st)?;
                    }
                }
            }
            x += LEGEND_SAMPLE / 2;
        }
        if let Some((m, s, color)) = self.marker {
            let fill = color.filled();
            let edge = color.stroke_width(2);
            let f = |v: f64| v.round() as i32;
            let sf = s as f64;
            match m {
                Marker::Circle => b.draw_circle((x, y), s as u32, &fill, true)?,
                Marker::Square => {
                    let h = f(sf * 0.85);
                    b.draw_rect((x - h, y - h), (x + h, y + h), &fill, true)?
                }
                Marker::TriangleUp | Marker::TriangleDown => {
                    let d = if m == Marker::TriangleUp { 1 } else { -1 };
                    let t = f(sf * 1.2);
                    b.fill_polygon(
                        vec![
                            (x, y - d * t),
                            (x - t, y + d * f(sf * 0.75)),
                            (x + t, y + d * f(sf * 0.75)),
                        ],
                        &fill,
                    )?
                }
                Marker::Diamond => {
                    let t = f(sf * 1.25);
                    b.fill_polygon(vec![(x, y - t), (x + t, y), (x, y + t), (x - t, y)], &fill)?
                }
                Marker::Cross => {
                    b.draw_line((x - s, y - s), (x + s, y + s), &edge)?;
                    b.draw_line((x - s, y + s), (x + s, y - s), &edge)?;
                }
                Marker::Plus => {
                    let t = f(sf * 1.2);
                    b.draw_line((x - t, y), (x + t, y), &edge)?;
                    b.draw_line((x, y - t), (x, y + t), &edge)?;
                }
            }
        }
        Ok(())
    }
}

// ---------------------------------------------------------------------------
// x-y figures
// ---------------------------------------------------------------------------

/// A series as drawn: style and points (data space).
struct Layer {
    label: String,
    color: RGBColor,
    points: Vec<(f64, f64)>,
    line: Option<LineKind>,
    marker: Option<(Marker, i32)>,
    /// Whether the points set the axis ranges.
    include_in_range: bool,
    /// A reference (y = x, a theoretical curve), not data: it does not count
    /// as data for the "no data" notes.
    guide: bool,
}

struct XyFigure<'a> {
    /// Image size (px); with `square` the height follows from the width.
    size: (u32, u32),
    title: &'a str,
    x_label: &'a str,
    y_label: &'a str,
    log_x: bool,
    log_y: bool,
    /// Equal x and y axes (parity plot).
    square: bool,
    /// Horizontal margin (fraction of the data span).
    x_pad: f64,
}

const TITLE_H: u32 = 64;
const TITLE_FONT: f64 = 30.0;
const DESC_FONT: f64 = 24.0;
const TICK_FONT: f64 = 20.0;
const LEGEND_FONT: f64 = 20.0;

/// The polylines of `points` in axis space, broken at points that cannot
/// be shown.
fn polylines(points: &[(f64, f64)], log_x: bool, log_y: bool) -> Vec<Vec<(f64, f64)>> {
    let mut out: Vec<Vec<(f64, f64)>> = vec![Vec::new()];
    for &(x, y) in points {
        match (to_axis(x, log_x), to_axis(y, log_y)) {
            (Some(a), Some(b)) => out.last_mut().expect("non-empty").push((a, b)),
            _ => {
                if !out.last().expect("non-empty").is_empty() {
                    out.push(Vec::new());
                }
            }
        }
    }
    out.retain(|l| !l.is_empty());
    out
}

/// Clips segment p–q to the box (Liang–Barsky); `None` if outside.
fn clip_segment(
    p: (f64, f64),
    q: (f64, f64),
    x: &Axis,
    y: &Axis,
) -> Option<((f64, f64), (f64, f64))> {
    let (dx, dy) = (q.0 - p.0, q.1 - p.1);
    let mut t0 = 0.0f64;
    let mut t1 = 1.0f64;
    for (pk, qk) in [
        (-dx, p.0 - x.lo),
        (dx, x.hi - p.0),
        (-dy, p.1 - y.lo),
        (dy, y.hi - p.1),
    ] {
        if pk == 0.0 {
            if qk < 0.0 {
                return None;
            }
        } else {
            let r = qk / pk;
            if pk < 0.0 {
                t0 = t0.max(r);
            } else {
                t1 = t1.min(r);
            }
        }
    }
    (t0 <= t1).then_some((
        (p.0 + t0 * dx, p.1 + t0 * dy),
        (p.0 + t1 * dx, p.1 + t1 * dy),
    ))
}

/// Splits polylines at the box edges, keeping the inside parts.
fn clip_polyline(line: &[(f64, f64)], x: &Axis, y: &Axis) -> Vec<Vec<(f64, f64)>> {
    let mut out: Vec<Vec<(f64, f64)>> = Vec::new();
    let mut cur: Vec<(f64, f64)> = Vec::new();
    for w in line.windows(2) {
        match clip_segment(w[0], w[1], x, y) {
            Some((a, b)) => {
                if cur.last() != Some(&a) {
                    if cur.len() >= 2 {
                        out.push(std::mem::take(&mut cur));
                    }
                    cur.clear();
                    cur.push(a);
                }
                cur.push(b);
            }
            None => {
                if cur.len() >= 2 {
                    out.push(std::mem::take(&mut cur));
                }
                cur.clear();
            }
        }
    }
    if cur.len() >= 2 {
        out.push(cur);
    }
    out
}

/// The legend's width and height as fractions of a plotting area of
/// `plot_w` × `plot_h` px; `None` without entries.
fn legend_extent(layers: &[Layer], plot_w: f64, plot_h: f64) -> Option<(f64, f64)> {
    let labelled = layers.iter().filter(|l| !l.label.is_empty());
    let entries = labelled.clone().count();
    let longest = labelled
        .map(|l| l.label.chars().count() + if l.points.is_empty() { 10 } else { 0 })
        .max()?;
    let w = LEGEND_SAMPLE as f64 + 40.0 + longest as f64 * LEGEND_FONT * 0.6;
    let h = entries as f64 * (LEGEND_FONT + 12.0) + 30.0;
    Some((w / plot_w.max(1.0), h / plot_h.max(1.0)))
}

/// The legend corner that covers the fewest drawn points, and how many it
/// covers.
fn legend_corner(
    lines: &[Vec<Vec<(f64, f64)>>],
    x: &Axis,
    y: &Axis,
    legend_w: f64,
    legend_h: f64,
) -> (SeriesLabelPosition, usize) {
    // Sample every polyline densely in normalised [0,1]² coordinates.
    let mut pts = Vec::new();
    for l in lines.iter().flatten() {
        let n = |p: &(f64, f64)| ((p.0 - x.lo) / (x.hi - x.lo), (p.1 - y.lo) / (y.hi - y.lo));
        if l.len() == 1 {
            pts.push(n(&l[0]));
        }
        for w in l.windows(2) {
            let (a, b) = (n(&w[0]), n(&w[1]));
            for k in 0..=16 {
                let t = k as f64 / 16.0;
                pts.push((a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1)));
            }
        }
    }
    let candidates = [
        (SeriesLabelPosition::UpperRight, true, true),
        (SeriesLabelPosition::UpperLeft, false, true),
        (SeriesLabelPosition::LowerRight, true, false),
        (SeriesLabelPosition::LowerLeft, false, false),
    ];
    let count = |right: bool, upper: bool| {
        pts.iter()
            .filter(|&&(u, v)| {
                let in_x = if right {
                    u >= 1.0 - legend_w
                } else {
                    u <= legend_w
                };
                let in_y = if upper {
                    v >= 1.0 - legend_h
                } else {
                    v <= legend_h
                };
                in_x && in_y
            })
            .count()
    };
    let mut best = (SeriesLabelPosition::UpperRight, usize::MAX);
    for (pos, right, upper) in candidates {
        let c = count(right, upper);
        if c < best.1 {
            best = (pos, c);
        }
    }
    best
}

/// Axes and label-area sizes of an x-y figure.
struct XyLayout {
    size: (u32, u32),
    x_axis: Axis,
    y_axis: Axis,
    left: u32,
    bottom: u32,
    right: u32,
}

const XY_TOP_MARGIN: u32 = 16;
const XY_MARGIN: u32 = 10;

fn xy_layout(fig: &XyFigure, layers: &[Layer]) -> anyhow::Result<XyLayout> {
    ensure_font()?;
    let range_pts = || {
        layers
            .iter()
            .filter(|l| l.include_in_range)
            .flat_map(|l| l.points.iter().copied())
            .filter(|&(x, y)| to_axis(x, fig.log_x).is_some() && to_axis(y, fig.log_y).is_some())
    };
    let (x_axis, mut y_axis) = if fig.square {
        // The first layer (y = x) spans the shared range exactly.
        let x = Axis::fit(range_pts().flat_map(|(x, y)| [x, y]), fig.log_x, 0.0, 8);
        let y = x.clone();
        (x, y)
    } else {
        (
            Axis::fit(range_pts().map(|p| p.0), fig.log_x, fig.x_pad, 9),
            Axis::fit(range_pts().map(|p| p.1), fig.log_y, 0.05, 8),
        )
    };
    // Label areas sized to their contents.
    let left = y_area_width(&y_axis, TICK_FONT, Some(DESC_FONT));
    let bottom = (TICK_FONT * 1.2 + 2.0 * TICK as f64 + 12.0 + DESC_FONT * 1.25).ceil() as u32;
    let last_x = x_axis
        .major
        .last()
        .map_or(0, |&v| text_width(TICK_FONT, &x_axis.label(v)));
    let right = (last_x / 2 + 12).max(30);
    let (w, mut h) = fig.size;
    if fig.square {
        // Height making the plotting area square.
        let side = w.saturating_sub(XY_MARGIN + left + right).max(100);
        h = TITLE_H + XY_TOP_MARGIN + side + bottom + XY_MARGIN;
    } else {
        // When every corner of the legend would cover data, raise the top
        // of the y axis so that the legend's band above the data is empty.
        let plot_w = w.saturating_sub(XY_MARGIN + left + right) as f64;
        let plot_h = h.saturating_sub(TITLE_H + XY_TOP_MARGIN + bottom + XY_MARGIN) as f64;
        if let Some((lw, lh)) = legend_extent(layers, plot_w, plot_h) {
            let lines: Vec<Vec<Vec<(f64, f64)>>> = layers
                .iter()
                .map(|l| polylines(&l.points, fig.log_x, fig.log_y))
                .collect();
            if legend_corner(&lines, &x_axis, &y_axis, lw, lh).1 > 0 && lh < 0.6 {
                y_axis = Axis::fit_below(range_pts().map(|p| p.1), fig.log_y, 0.05, 8, lh + 0.02);
            }
        }
    }
    Ok(XyLayout {
        size: (w, h),
        x_axis,
        y_axis,
        left,
        bottom,
        right,
    })
}

fn plot_xy(path: &Path, fig: &XyFigure, layers: &[Layer]) -> anyhow::Result<()> {
    let layout = xy_layout(fig, layers)?;
    render_png(path, layout.size, |buf| draw_xy(buf, fig, &layout, layers))
}

/// Long function: one figure drawn in painter's order (geometry per layer,
/// axes and ticks, series, legend, frame), about 160 lines; not split in
/// the issue-10 refactor.
fn draw_xy(
    buf: &mut [u8],
    fig: &XyFigure,
    layout: &XyLayout,
    layers: &[Layer],
) -> anyhow::Result<()> {
    let (w, h) = layout.size;
    let root = BitMapBackend::with_buffer(buf, (w, h)).into_drawing_area();
    root.fill(&WHITE)?;
    let (top, body) = root.split_vertically(TITLE_H);
    top.draw(&Text::new(
        fig.title.to_string(),
        (w as i32 / 2, TITLE_H as i32 / 2 + 4),
        text_style(TITLE_FONT).pos(Pos::new(HPos::Center, VPos::Center)),
    ))?;
    let (x_axis, y_axis) = (&layout.x_axis, &layout.y_axis);
    let mut chart = ChartBuilder::on(&body)
        .margin_top(XY_TOP_MARGIN)
        .margin_right(layout.right)
        .margin_bottom(XY_MARGIN)
        .margin_left(XY_MARGIN)
        .set_label_area_size(LabelAreaPosition::Left, layout.left)
        .set_label_area_size(LabelAreaPosition::Bottom, layout.bottom)
        .build_cartesian_2d(x_axis.clone(), y_axis.clone())?;
    let (xa, ya) = (x_axis.clone(), y_axis.clone());
    let x_fmt = move |v: &f64| xa.label(*v);
    let y_fmt = move |v: &f64| ya.label(*v);
    chart
        .configure_mesh()
        .x_desc(fig.x_label)
        .y_desc(fig.y_label)
        .axis_desc_style(text_style(DESC_FONT))
        .label_style(text_style(TICK_FONT))
        .x_label_formatter(&x_fmt)
        .y_label_formatter(&y_fmt)
        .bold_line_style(RGBColor(218, 218, 218).stroke_width(1))
        .light_line_style(RGBColor(243, 243, 243).stroke_width(1))
        .axis_style(BLACK.stroke_width(1))
        .set_all_tick_mark_size(TICK)
        .draw()?;

    // Drawable geometry per layer.
    let lines: Vec<Vec<Vec<(f64, f64)>>> = layers
        .iter()
        .map(|l| {
            polylines(&l.points, fig.log_x, fig.log_y)
                .iter()
                .flat_map(|pl| {
                    if l.line.is_some() {
                        clip_polyline(pl, x_axis, y_axis)
                    } else {
                        vec![
                            pl.iter()
                                .copied()
                                .filter(|p| x_axis.contains(p.0) && y_axis.contains(p.1))
                                .collect(),
                        ]
                    }
                })
                .filter(|pl| !pl.is_empty())
                .collect()
        })
        .collect();
    let any_data = lines
        .iter()
        .zip(layers)
        .any(|(l, layer)| !layer.guide && !l.is_empty());

    for (layer, geom) in layers.iter().zip(&lines) {
        if let Some(kind) = layer.line {
            for pl in geom.iter().filter(|pl| pl.len() >= 2) {
                match kind {
                    LineKind::Solid(wd) => {
                        chart.draw_series(std::iter::once(PathElement::new(
                            pl.clone(),
                            layer.color.stroke_width(wd),
                        )))?;
                    }
                    LineKind::Dashed => {
                        chart.draw_series(DashedLineSeries::new(
                            pl.clone(),
                            10,
                            7,
                            layer.color.stroke_width(2),
                        ))?;
                    }
                }
            }
        }
        if let Some((m, s)) = layer.marker {
            let color = layer.color;
            chart.draw_series(geom.iter().flatten().map(|&p| Glyph {
                at: p,
                legend_line: None,
                marker: Some((m, s, color)),
            }))?;
        }
    }

    // Legend: one entry per layer, in order, including empty series.
    for (layer, geom) in layers.iter().zip(&lines) {
        if layer.label.is_empty() {
            continue;
        }
        let label = if geom.is_empty() && !layer.guide {
            format!("{} (no data)", layer.label)
        } else {
            layer.label.clone()
        };
        let (color, line, marker) = (layer.color, layer.line, layer.marker);
        chart
            .draw_series(std::iter::empty::<Glyph<(f64, f64)>>())?
            .label(label)
            .legend(move |(x, y)| Glyph {
                at: (x, y),
                legend_line: line.map(|k| (k, color)),
                marker: marker.map(|(m, s)| (m, s, color)),
            });
    }
    let (px, py) = chart.plotting_area().get_pixel_range();
    let (pw, ph) = ((px.end - px.start) as f64, (py.end - py.start) as f64);
    if let Some((lw, lh)) = legend_extent(layers, pw, ph) {
        let (pos, _) = legend_corner(&lines, x_axis, y_axis, lw, lh);
        chart
            .configure_series_labels()
            .position(pos)
            .margin(14)
            .legend_area_size(LEGEND_SAMPLE + 10)
            .label_font(text_style(LEGEND_FONT))
            .background_style(WHITE.mix(0.88))
            .border_style(RGBColor(160, 160, 160))
            .draw()?;
    }

    if !any_data {
        // Above the middle, clear of a y = x guide.
        let cx = (x_axis.lo + x_axis.hi) / 2.0;
        let cy = y_axis.lo + 0.7 * (y_axis.hi - y_axis.lo);
        chart.plotting_area().draw(&Text::new(
            "no data",
            (cx, cy),
            text_style(28.0)
                .color(&RGBColor(120, 120, 120))
                .pos(Pos::new(HPos::Center, VPos::Center)),
        ))?;
    }

    // Frame around the plotting area.
    let (px, py) = chart.plotting_area().get_pixel_range();
    root.draw(&Rectangle::new(
        [(px.start - 1, py.start - 1), (px.end, py.end)],
        BLACK.stroke_width(1),
    ))?;
    root.present()?;
    Ok(())
}

fn text_style(size: f64) -> TextStyle<'static> {
    TextStyle::from((FONT, size).into_font()).color(&BLACK)
}

// ---------------------------------------------------------------------------
// Particle panels
// ---------------------------------------------------------------------------

const P_TOP: u32 = 10;
const P_TITLE_H: u32 = 44;
const P_BOTTOM: u32 = 66;
const P_BOTTOM_PAD: u32 = 8;
const P_LEFT_PAD: u32 = 8;
const P_GAP: u32 = 22;
const P_CB_GAP: u32 = 36;
const P_CB_W: u32 = 28;
const P_RIGHT_PAD: u32 = 10;
const P_TARGET_H: u32 = 1200;
const P_MAX_H: u32 = 2400;
const P_MAX_W: u32 = 2400;
/// Narrowest plot width worth labelling (px).
const P_MIN_PLOT_W: f64 = 90.0;
const P_TITLE_FONT: f64 = 24.0;
const P_DESC_FONT: f64 = 20.0;
const P_TICK_FONT: f64 = 17.0;
/// Tick mark length (px); plotters puts labels at twice this from the axis.
const TICK: i32 = 6;

/// Width (px) of `s` in the bundled font at `size`.
fn text_width(size: f64, s: &str) -> u32 {
    (FONT, size)
        .into_font()
        .box_size(s)
        .map(|(w, _)| w)
        .unwrap_or((s.chars().count() as f64 * size * 0.6) as u32)
}

/// Width of a y label area: tick labels, gap, and (optionally) the rotated
/// axis description.
fn y_area_width(axis: &Axis, tick_font: f64, desc_font: Option<f64>) -> u32 {
    let labels = axis
        .major
        .iter()
        .map(|&v| text_width(tick_font, &axis.label(v)))
        .max()
        .unwrap_or(0);
    let desc = desc_font.map_or(0.0, |f| 14.0 + f * 1.25);
    labels + 2 * TICK as u32 + 4 + desc.ceil() as u32
}

struct PanelGeom {
    lo: [f64; 2],
    hi: [f64; 2],
    /// Plot rectangle (x, y, w, h) in pixels.
    rect: (i32, i32, i32, i32),
    x_axis: Axis,
    y_axis: Axis,
    /// Width of the y label area left of the plot (px).
    y_area: u32,
    /// Whether this panel shows the y description (the first panel, or a y
    /// range different from the previous panel's).
    y_desc: bool,
}

struct PanelLayout {
    width: u32,
    height: u32,
    panels: Vec<PanelGeom>,
    /// Colour bar rectangle (x, y, w, h) and the width of its label area.
    colour_bar: (i32, i32, i32, i32),
    cb_axis: Axis,
    cb_area: u32,
}

impl PanelLayout {
    fn new(panels: &[ParticlePanel], vmin: f64, vmax: f64) -> anyhow::Result<PanelLayout> {
        ensure_font()?;
        let domains: Vec<([f64; 2], [f64; 2])> = panels.iter().map(panel_domain).collect();
        let widths: Vec<f64> = domains.iter().map(|(lo, hi)| hi[0] - lo[0]).collect();
        let heights: Vec<f64> = domains.iter().map(|(lo, hi)| hi[1] - lo[1]).collect();
        let max_h = heights.iter().copied().fold(0.0, f64::max).max(1e-300);
        let fixed_h = (P_TOP + P_TITLE_H + P_BOTTOM + P_BOTTOM_PAD) as f64;
        // Pixels per metre: a ~1200 px tall image...
        let mut scale = (P_TARGET_H as f64 - fixed_h) / max_h;
        // ...taller if the narrowest panel would be too thin to label...
        let min_w = widths.iter().copied().fold(f64::INFINITY, f64::min);
        if min_w.is_finite() && min_w * scale < P_MIN_PLOT_W {
            scale = (P_MIN_PLOT_W / min_w).min((P_MAX_H as f64 - fixed_h) / max_h);
        }
        // ...and flatter if the panels would not fit side by side (the y
        // label areas are estimated at 90 px here).
        let fixed_w = (P_LEFT_PAD + P_CB_GAP + P_CB_W + 110 + P_RIGHT_PAD) as f64
            + panels.len() as f64 * (90 + P_GAP) as f64;
        let sum_w: f64 = widths.iter().sum();
        if sum_w > 0.0 && fixed_w + sum_w * scale > P_MAX_W as f64 {
            scale = ((P_MAX_W as f64 - fixed_w) / sum_w).max(1e-300);
        }
        let plot_h_max = (max_h * scale).round().clamp(60.0, P_MAX_H as f64) as i32;
        let plot_top = (P_TOP + P_TITLE_H) as i32;

        let mut x = P_LEFT_PAD as i32;
        let mut geoms: Vec<PanelGeom> = Vec::new();
        for (i, &(lo, hi)) in domains.iter().enumerate() {
            let pw = (widths[i] * scale).round().clamp(20.0, P_MAX_W as f64) as i32;
            let ph = (heights[i] * scale).round().clamp(20.0, P_MAX_H as f64) as i32;
            let x_axis = Axis::linear(lo[0], hi[0], ((pw as f64 / 85.0) as usize).max(2));
            let y_axis = Axis::linear(lo[1], hi[1], ((ph as f64 / 90.0) as usize).max(2));
            let y_desc = geoms
                .last()
                .is_none_or(|p| p.lo[1] != lo[1] || p.hi[1] != hi[1]);
            let y_area = y_area_width(&y_axis, P_TICK_FONT, y_desc.then_some(P_DESC_FONT));
            // The title is centred over the plot and may be wider than it.
            let overhang = (text_width(P_TITLE_FONT, &panels[i].title) as i32 - pw) / 2 + 6;
            let left = (y_area as i32).max(overhang);
            let col_w = left + pw + overhang.max(0);
            let px = x + left;
            let py = plot_top + plot_h_max - ph;
            geoms.push(PanelGeom {
                lo,
                hi,
                rect: (px, py, pw, ph),
                x_axis,
                y_axis,
                y_area,
                y_desc,
            });
            x += col_w + P_GAP as i32;
        }
        let cb_axis = Axis::linear(
            vmin,
            vmax,
            ((plot_h_max as f64 / 100.0) as usize).clamp(2, 10),
        );
        let cb_area = y_area_width(&cb_axis, P_TICK_FONT, Some(P_DESC_FONT));
        let cb_x = x - P_GAP as i32 + P_CB_GAP as i32;
        let width = (cb_x + (P_CB_W + cb_area + P_RIGHT_PAD) as i32).max(300) as u32;
        let height = (plot_top + plot_h_max) as u32 + P_BOTTOM + P_BOTTOM_PAD;
        Ok(PanelLayout {
            width,
            height,
            panels: geoms,
            colour_bar: (cb_x, plot_top, P_CB_W as i32, plot_h_max),
            cb_axis,
            cb_area,
        })
    }
}

/// The panel's domain, or (if degenerate) the particles' bounding box, or
/// the unit square.
fn panel_domain(p: &ParticlePanel) -> ([f64; 2], [f64; 2]) {
    let ok = |lo: [f64; 2], hi: [f64; 2]| {
        (0..2).all(|k| lo[k].is_finite() && hi[k].is_finite() && hi[k] > lo[k])
    };
    if ok(p.lo, p.hi) {
        return (p.lo, p.hi);
    }
    let mut lo = [f64::INFINITY; 2];
    let mut hi = [f64::NEG_INFINITY; 2];
    for &(x, y, r, _) in p.particles {
        if x.is_finite() && y.is_finite() {
            let r = if r.is_finite() { r.abs() } else { 0.0 };
            lo = [lo[0].min(x - r), lo[1].min(y - r)];
            hi = [hi[0].max(x + r), hi[1].max(y + r)];
        }
    }
    if ok(lo, hi) {
        (lo, hi)
    } else {
        ([0.0, 0.0], [1.0, 1.0])
    }
}

fn draw_particle_panels(
    buf: &mut [u8],
    layout: &PanelLayout,
    panels: &[ParticlePanel],
    value_label: &str,
    vmin: f64,
    vmax: f64,
) -> anyhow::Result<()> {
    let (w, h) = (layout.width, layout.height);
    {
        let root = BitMapBackend::with_buffer(buf, (w, h)).into_drawing_area();
        root.fill(&WHITE)?;
        for (panel, g) in panels.iter().zip(&layout.panels) {
            let (px, py, pw, ph) = g.rect;
            root.draw(&Text::new(
                panel.title.clone(),
                (px + pw / 2, py - P_TITLE_H as i32 / 2),
                text_style(P_TITLE_FONT).pos(Pos::new(HPos::Center, VPos::Center)),
            ))?;
            let area = root.clone().shrink(
                (px - g.y_area as i32, py),
                (pw as u32 + g.y_area, ph as u32 + P_BOTTOM),
            );
            let labels = AxesLabels {
                x_desc: Some("x (m)"),
                y_desc: g.y_desc.then_some("y (m)"),
                y_area: g.y_area,
                y_right: false,
            };
            axes_only(&area, g.x_axis.clone(), g.y_axis.clone(), &labels)?;
        }
        if panels.is_empty() {
            root.draw(&Text::new(
                "no data",
                (w as i32 / 2, h as i32 / 2),
                text_style(28.0)
                    .color(&RGBColor(120, 120, 120))
                    .pos(Pos::new(HPos::Center, VPos::Center)),
            ))?;
        }
        let (cx, cy, cw, ch) = layout.colour_bar;
        let area = root
            .clone()
            .shrink((cx, cy), (cw as u32 + layout.cb_area, ch as u32));
        let xa = Axis {
            major: Vec::new(),
            ..Axis::linear(0.0, 1.0, 2)
        };
        let labels = AxesLabels {
            x_desc: None,
            y_desc: Some(value_label),
            y_area: layout.cb_area,
            y_right: true,
        };
        axes_only(&area, xa, layout.cb_axis.clone(), &labels)?;
        root.present()?;
    }

    let mut canvas = Canvas {
        buf,
        w: w as usize,
        h: h as usize,
    };
    for (panel, g) in panels.iter().zip(&layout.panels) {
        let (px, py, pw, ph) = g.rect;
        let (lo, hi) = (g.lo, g.hi);
        canvas.fill_rect(px, py, pw, ph, [244, 244, 244]);
        // Pixel centres of plotters' ticks are at lo + (i + 0.5) px.
        let sx = (pw - 1) as f64 / (hi[0] - lo[0]);
        let sy = (ph - 1) as f64 / (hi[1] - lo[1]);
        for &(x, y, r, v) in panel.particles {
            if !(x.is_finite() && y.is_finite() && r.is_finite()) {
                continue;
            }
            let cx = px as f64 + 0.5 + (x - lo[0]) * sx;
            let cy = (py + ph) as f64 - 0.5 - (y - lo[1]) * sy;
            let rad = (r.abs() * sx).max(0.5);
            let color = viridis((v - vmin) / (vmax - vmin));
            canvas.disc(cx, cy, rad, color, g.rect);
        }
        canvas.frame(px, py, pw, ph);
    }
    let (cx, cy, cw, ch) = layout.colour_bar;
    for j in 0..ch {
        let t = 1.0 - j as f64 / (ch - 1).max(1) as f64;
        canvas.fill_rect(cx, cy + j, cw, 1, viridis(t));
    }
    canvas.frame(cx, cy, cw, ch);
    Ok(())
}

/// Labelling of [`axes_only`].
struct AxesLabels<'a> {
    /// x description; `None` hides the x axis.
    x_desc: Option<&'a str>,
    y_desc: Option<&'a str>,
    /// Width of the y label area (px).
    y_area: u32,
    /// y labels on the right of the plot (colour bar).
    y_right: bool,
}

/// Ticks, tick labels and axis descriptions around a plot rectangle, without
/// grid lines. `area` spans the plot plus its label areas.
fn axes_only(area: &Area, xa: Axis, ya: Axis, labels: &AxesLabels) -> anyhow::Result<()> {
    let mut b = ChartBuilder::on(area);
    if labels.y_right {
        b.set_label_area_size(LabelAreaPosition::Right, labels.y_area);
    } else {
        b.set_label_area_size(LabelAreaPosition::Left, labels.y_area);
    }
    if labels.x_desc.is_some() {
        b.set_label_area_size(LabelAreaPosition::Bottom, P_BOTTOM);
    }
    let mut chart = b.build_cartesian_2d(xa.clone(), ya.clone())?;
    let x_fmt = move |v: &f64| xa.label(*v);
    let y_fmt = move |v: &f64| ya.label(*v);
    let mut mesh = chart.configure_mesh();
    mesh.disable_mesh()
        .axis_desc_style(text_style(P_DESC_FONT))
        .label_style(text_style(P_TICK_FONT))
        .x_label_formatter(&x_fmt)
        .y_label_formatter(&y_fmt)
        .axis_style(BLACK.stroke_width(1))
        .set_all_tick_mark_size(TICK);
    if let Some(d) = labels.y_desc {
        mesh.y_desc(d);
    }
    match labels.x_desc {
        Some(d) => {
            mesh.x_desc(d);
        }
        None => {
            mesh.disable_x_axis();
        }
    }
    mesh.draw()?;
    Ok(())
}

/// Direct pixel access to an RGB buffer for particles and colour bars.
struct Canvas<'a> {
    buf: &'a mut [u8],
    w: usize,
    h: usize,
}

impl Canvas<'_> {
    fn blend(&mut self, x: i32, y: i32, c: [u8; 3], a: f64) {
        if x < 0 || y < 0 || x as usize >= self.w || y as usize >= self.h || a <= 0.0 {
            return;
        }
        let i = 3 * (y as usize * self.w + x as usize);
        let a = a.min(1.0);
        for (dst, &src) in self.buf[i..i + 3].iter_mut().zip(&c) {
            let old = *dst as f64;
            *dst = (old + a * (src as f64 - old)).round() as u8;
        }
    }

    fn fill_rect(&mut self, x: i32, y: i32, w: i32, h: i32, c: [u8; 3]) {
        for j in y..y + h {
            for i in x..x + w {
                self.blend(i, j, c, 1.0);
            }
        }
    }

    /// A 1-px black frame just outside the rectangle.
    fn frame(&mut self, x: i32, y: i32, w: i32, h: i32) {
        let k = [0, 0, 0];
        for i in x - 1..=x + w {
            self.blend(i, y - 1, k, 1.0);
            self.blend(i, y + h, k, 1.0);
        }
        for j in y - 1..=y + h {
            self.blend(x - 1, j, k, 1.0);
            self.blend(x + w, j, k, 1.0);
        }
    }

    /// An anti-aliased disc centred at (cx, cy) (pixel units, pixel (i, j)
    /// covering [i, i+1) × [j, j+1)), clipped to `clip` = (x, y, w, h).
    /// Discs of radius ≥ 3 px get a darker rim so touching particles stay
    /// distinguishable.
    fn disc(&mut self, cx: f64, cy: f64, r: f64, c: [u8; 3], clip: (i32, i32, i32, i32)) {
        let (x0, y0, w, h) = clip;
        let i0 = ((cx - r - 1.0).floor() as i32).max(x0);
        let i1 = ((cx + r + 1.0).ceil() as i32).min(x0 + w - 1);
        let j0 = ((cy - r - 1.0).floor() as i32).max(y0);
        let j1 = ((cy + r + 1.0).ceil() as i32).min(y0 + h - 1);
        // Sub-pixel discs: scale the coverage by their area.
        let area = (std::f64::consts::PI * r * r).min(1.0);
        let rim = r >= 3.0;
        let dark = c.map(|v| (v as f64 * 0.55) as u8);
        for j in j0..=j1 {
            for i in i0..=i1 {
                let d = ((i as f64 + 0.5 - cx).powi(2) + (j as f64 + 0.5 - cy).powi(2)).sqrt();
                let outer = (r + 0.5 - d).clamp(0.0, 1.0) * area;
                if outer <= 0.0 {
                    continue;
                }
                if rim {
                    self.blend(i, j, dark, outer);
                    let inner = (r - 0.5 - d).clamp(0.0, 1.0);
                    self.blend(i, j, c, inner);
                } else {
                    self.blend(i, j, c, outer);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small deterministic generator (xorshift64*), uniform in [0, 1).
    struct Rng(u64);
    impl Rng {
        fn uniform(&mut self) -> f64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
        }
        fn normal(&mut self) -> f64 {
            let (u, v) = (self.uniform().max(1e-300), self.uniform());
            (-2.0 * u.ln()).sqrt() * (2.0 * std::f64::consts::PI * v).cos()
        }
    }

    #[test]
    fn legend_never_covers_data_when_lines_fill_every_corner() {
        // Lines along the top and the bottom of the data range leave no free
        // corner: the layout must raise the y axis until one is free.
        let xs: Vec<f64> = (0..=50).map(|k| k as f64 / 50.0).collect();
        let layers: Vec<Layer> = [0.0, 0.5, 1.0]
            .iter()
            .enumerate()
            .map(|(i, &y)| Layer {
                label: format!("a long legend entry for the line at y = {y}"),
                color: palette(i),
                points: xs.iter().map(|&x| (x, y)).collect(),
                line: Some(LineKind::Solid(2)),
                marker: None,
                include_in_range: true,
                guide: false,
            })
            .collect();
        let fig = XyFigure {
            size: (1200, 800),
            title: "t",
            x_label: "x",
            y_label: "y",
            log_x: false,
            log_y: false,
            square: false,
            x_pad: 0.02,
        };
        let layout = xy_layout(&fig, &layers).unwrap();
        let (w, h) = layout.size;
        let plot_w = (w - XY_MARGIN - layout.left - layout.right) as f64;
        let plot_h = (h - TITLE_H - XY_TOP_MARGIN - layout.bottom - XY_MARGIN) as f64;
        let (lw, lh) = legend_extent(&layers, plot_w, plot_h).unwrap();
        let lines: Vec<Vec<Vec<(f64, f64)>>> = layers
            .iter()
            .map(|l| polylines(&l.points, false, false))
            .collect();
        let (_, covered) = legend_corner(&lines, &layout.x_axis, &layout.y_axis, lw, lh);
        assert_eq!(
            covered,
            0,
            "y axis {:?}",
            (layout.y_axis.lo, layout.y_axis.hi)
        );
        // Without the extra room every corner would cover a line.
        let tight = Axis::fit(
            layers.iter().flat_map(|l| l.points.iter().map(|p| p.1)),
            false,
            0.05,
            8,
        );
        assert!(legend_corner(&lines, &layout.x_axis, &tight, lw, lh).1 > 0);
    }

    fn tmp_dir(name: &str) -> std::path::PathBuf {
        let d = std::env::temp_dir().join(format!("edpm_plot_{}_{name}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    /// Decodes the PNG and returns (width, height, RGB pixels).
    fn decode(path: &Path) -> (u32, u32, Vec<u8>) {
        let bytes = std::fs::read(path).unwrap();
        assert!(bytes.starts_with(b"\x89PNG\r\n\x1a\n"), "PNG signature");
        let dec = png::Decoder::new(std::io::Cursor::new(bytes));
        let mut reader = dec.read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut buf).unwrap();
        buf.truncate(info.buffer_size());
        (info.width, info.height, buf)
    }

    fn distinct_colours(px: &[u8]) -> usize {
        let mut set = std::collections::HashSet::new();
        for c in px.chunks(3) {
            set.insert([c[0], c[1], c[2]]);
        }
        set.len()
    }

    fn gaussian_series(rng: &mut Rng, label: &str, n: usize, sigma: f64) -> Series {
        let (lo, hi, bins) = (-5.0, 5.0, 40);
        let dx = (hi - lo) / bins as f64;
        let mut counts = vec![0usize; bins];
        for _ in 0..n {
            let v = rng.normal() * sigma;
            let k = ((v - lo) / dx).floor();
            if k >= 0.0 && (k as usize) < bins {
                counts[k as usize] += 1;
            }
        }
        let points = counts
            .iter()
            .enumerate()
            .map(|(k, &c)| (lo + (k as f64 + 0.5) * dx, c as f64 / (n as f64 * dx)))
            .collect();
        Series::new(label, points)
    }

    fn unit_gaussian() -> Series {
        let pts = (0..=200)
            .map(|k| {
                let x = -5.0 + 0.05 * k as f64;
                (
                    x,
                    (-x * x / 2.0).exp() / (2.0 * std::f64::consts::PI).sqrt(),
                )
            })
            .collect();
        Series::new("exp(−x²/2)/√(2π)", pts)
    }

    #[test]
    fn font_is_registered_and_renders_text() {
        ensure_font().unwrap();
        let (w, h) = (200u32, 60u32);
        let mut buf = vec![255u8; (w * h * 3) as usize];
        {
            let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
            root.draw(&Text::new("Label 123 (m/s)", (5, 20), text_style(20.0)))
                .unwrap();
            root.present().unwrap();
        }
        let dark = buf.chunks(3).filter(|c| c[0] < 128).count();
        assert!(dark > 100, "text drew only {dark} dark pixels");
        let size = (FONT, 20.0).into_font().box_size("Label 123").unwrap();
        assert!(size.0 > 50 && size.1 > 10, "{size:?}");
    }

    #[test]
    fn viridis_ends_and_nan() {
        assert_eq!(viridis(0.0), [68, 1, 84]);
        assert_eq!(viridis(1.0), [253, 231, 37]);
        assert_eq!(viridis(-3.0), viridis(0.0));
        assert_eq!(viridis(f64::NAN), [150, 150, 150]);
        // Luminance increases monotonically (perceptual ordering).
        let lum = |c: [u8; 3]| 0.2126 * c[0] as f64 + 0.7152 * c[1] as f64 + 0.0722 * c[2] as f64;
        for k in 0..100 {
            assert!(lum(viridis(k as f64 / 100.0)) < lum(viridis((k + 1) as f64 / 100.0)));
        }
    }

    #[test]
    fn ticks_are_nice() {
        let a = Axis::linear(0.0, 0.08, 2);
        assert_eq!(a.major.len(), 2, "{:?}", a.major);
        assert_eq!(a.label(0.05), "0.05");
        let a = Axis::linear(-1.0, 1.0, 5);
        assert_eq!(a.label(-0.5), "\u{2212}0.5");
        assert_eq!(a.label(0.0), "0.0");
        let a = Axis::log(-6.2, 0.3);
        assert_eq!(a.major, vec![-6.0, -5.0, -4.0, -3.0, -2.0, -1.0, 0.0]);
        assert_eq!(a.label(-3.0), "10⁻³");
        let a = Axis::log(0.1, 0.6);
        assert!(a.major.len() >= 2, "{:?}", a.major);
        assert_eq!(a.label(2f64.log10()), "2");
    }

    #[test]
    fn particle_panels_riser_pair() {
        let mut rng = Rng(0x1234_5678);
        let (w, h, r) = (0.08, 1.0, 1.2e-3);
        let mut make = |cluster: bool| -> Vec<(f64, f64, f64, f64)> {
            (0..3000)
                .map(|_| {
                    let mut x = r + rng.uniform() * (w - 2.0 * r);
                    if cluster && rng.uniform() < 0.5 {
                        // Dense downward-moving wall layers.
                        let d = rng.uniform().powi(2) * 0.012;
                        x = if rng.uniform() < 0.5 {
                            r + d
                        } else {
                            w - r - d
                        };
                    }
                    let y = r + rng.uniform() * (h - 2.0 * r);
                    let xi = 2.0 * x / w - 1.0;
                    let v = 2.0 * (1.0 - xi * xi) - 0.8 + 0.2 * rng.normal();
                    (x, y, r, v)
                })
                .collect()
        };
        let ideal = make(false);
        let mut nonideal = make(true);
        nonideal[7].3 = f64::NAN;
        nonideal[8].0 = f64::NAN;
        let panels = [
            ParticlePanel {
                title: "ideal (e = 1)".into(),
                lo: [0.0, 0.0],
                hi: [w, h],
                particles: &ideal,
            },
            ParticlePanel {
                title: "non-ideal (e = 0.9)".into(),
                lo: [0.0, 0.0],
                hi: [w, h],
                particles: &nonideal,
            },
        ];
        let dir = tmp_dir("panels");
        let path = dir.join("riser.png");
        particle_panels(&path, &panels, "vertical velocity (m/s)", -1.5, 1.5).unwrap();
        let (pw, ph, px) = decode(&path);
        assert!((1100..=1300).contains(&ph), "height {ph}");
        assert!(pw > 300 && pw < 1000, "width {pw}");
        assert!(distinct_colours(&px) > 100);
        assert!(std::fs::metadata(&path).unwrap().len() > 20_000);

        // Large particles (drawn with a rim) in panels of different heights.
        let bed: Vec<(f64, f64, f64, f64)> = (0..600)
            .map(|k| {
                let (i, j) = (k % 15, k / 15);
                let x = 0.005 + 0.01 * i as f64 + 0.002 * rng.uniform();
                let y = 0.005 + 0.0087 * j as f64;
                (x, y, 0.004 + 0.001 * rng.uniform(), rng.normal())
            })
            .collect();
        let beds = [
            ParticlePanel {
                title: "bed, t = 0 s".into(),
                lo: [0.0, 0.0],
                hi: [0.16, 0.4],
                particles: &bed,
            },
            ParticlePanel {
                title: "freeboard".into(),
                lo: [0.0, 0.0],
                hi: [0.16, 0.25],
                particles: &bed[..200],
            },
        ];
        let path = dir.join("bed.png");
        particle_panels(&path, &beds, "granular temperature (m²/s²)", f64::NAN, 0.0).unwrap();
        let (_, bh, _) = decode(&path);
        assert!((1100..=1300).contains(&bh), "height {bh}");

        // Wide and degenerate domains, empty panel lists: still valid images.
        let wide = [ParticlePanel {
            title: "bed".into(),
            lo: [0.0, 0.0],
            hi: [2.0, 0.1],
            particles: &ideal[..10],
        }];
        particle_panels(&dir.join("wide.png"), &wide, "v (m/s)", 0.0, 0.0).unwrap();
        let (ww, _, _) = decode(&dir.join("wide.png"));
        assert!(ww <= P_MAX_W);
        let bad = [ParticlePanel {
            title: "degenerate".into(),
            lo: [f64::NAN, 0.0],
            hi: [0.0, 0.0],
            particles: &[],
        }];
        particle_panels(&dir.join("bad.png"), &bad, "v", f64::NAN, 1.0).unwrap();
        particle_panels(&dir.join("none.png"), &[], "v", 0.0, 1.0).unwrap();
        decode(&dir.join("none.png"));
    }

    #[test]
    fn line_plot_profiles_and_edge_cases() {
        let dir = tmp_dir("line");
        let xs: Vec<f64> = (0..=40).map(|k| k as f64 * 0.002).collect();
        let prof = |a: f64| -> Vec<(f64, f64)> {
            xs.iter()
                .map(|&x| {
                    let xi = 2.0 * x / 0.08 - 1.0;
                    (x, a * (1.0 - xi * xi) - 0.3)
                })
                .collect()
        };
        let mut broken = prof(1.5);
        broken[10].1 = f64::NAN;
        let series = [
            Series::new("ideal", prof(2.0)),
            Series::new("non-ideal (with a NaN)", broken),
            Series::new("empty", vec![]),
        ];
        let path = dir.join("profile.png");
        line_plot(
            &path,
            "Solids velocity profile",
            "x (m)",
            "vertical velocity (m/s)",
            &series,
            Scale::LINEAR,
        )
        .unwrap();
        let (w, h, px) = decode(&path);
        assert_eq!((w, h), (1200, 800));
        assert!(distinct_colours(&px) > 20);

        // Log y with zeros and negatives (skipped), a long time series.
        let ts: Vec<(f64, f64)> = (0..2000)
            .map(|k| (k as f64 * 1e-3, (-(k as f64) * 3e-3).exp() - 0.01))
            .collect();
        line_plot(
            &dir.join("log.png"),
            "Granular temperature",
            "t (s)",
            "T (m²/s²)",
            &[Series::new("T", ts)],
            Scale::LOG_Y,
        )
        .unwrap();
        decode(&dir.join("log.png"));
        // Nothing at all to draw.
        line_plot(&dir.join("empty.png"), "empty", "x", "y", &[], Scale::LOG_Y).unwrap();
        line_plot(
            &dir.join("nan.png"),
            "nan",
            "x",
            "y",
            &[Series::new(
                "nan",
                vec![(f64::NAN, 1.0), (1.0, f64::INFINITY)],
            )],
            Scale::LINEAR,
        )
        .unwrap();
        decode(&dir.join("nan.png"));
        // Extreme magnitudes, a degenerate range and an empty title.
        let extreme = [
            Series::new("", vec![(1e300, 1e-300), (1e300, 2e-300)]),
            Series::new("flat", vec![(0.0, 1e17), (1.0, 1e17)]),
        ];
        for scale in [Scale::LINEAR, Scale::LOG_Y, Scale::LOG_X] {
            line_plot(&dir.join("extreme.png"), "", "x", "y", &extreme, scale).unwrap();
            decode(&dir.join("extreme.png"));
        }
    }

    #[test]
    fn distribution_plot_gaussian() {
        let mut rng = Rng(42);
        let series = [
            gaussian_series(&mut rng, "f(Cₓ/σ)", 200_000, 1.0),
            gaussian_series(&mut rng, "f(C_y/σ)", 200_000, 1.05),
        ];
        let dir = tmp_dir("dist");
        for (log, name) in [(false, "dist.png"), (true, "dist_log.png")] {
            let path = dir.join(name);
            distribution_plot(
                &path,
                "Velocity distribution",
                "C/σ (−)",
                &series,
                &unit_gaussian(),
                log,
            )
            .unwrap();
            let (w, h, px) = decode(&path);
            assert_eq!((w, h), (1200, 800));
            assert!(distinct_colours(&px) > 20);
        }
        distribution_plot(
            &dir.join("empty.png"),
            "t",
            "x",
            &[],
            &Series::default(),
            true,
        )
        .unwrap();
        decode(&dir.join("empty.png"));
    }

    #[test]
    fn parity_plot_linear_and_log() {
        let mut rng = Rng(7);
        let pts = |rng: &mut Rng, k: f64| -> Vec<(f64, f64)> {
            (0..40)
                .map(|i| {
                    let x = 10f64.powf(-3.0 + 3.0 * i as f64 / 39.0);
                    (x, x * k * (1.0 + 0.1 * rng.normal()))
                })
                .collect()
        };
        let series = [
            Series::new("pressure", pts(&mut rng, 1.0)),
            Series::new("viscosity", pts(&mut rng, 1.2)),
        ];
        let dir = tmp_dir("parity");
        for (log, name) in [(false, "parity.png"), (true, "parity_log.png")] {
            let path = dir.join(name);
            parity_plot(
                &path,
                "KTGF: measured vs predicted",
                "measured (Pa)",
                "predicted (Pa)",
                &series,
                log,
            )
            .unwrap();
            let (w, h, _) = decode(&path);
            assert_eq!(w, 1000);
            assert!((950..1100).contains(&h), "height {h}");
        }
        parity_plot(&dir.join("empty.png"), "t", "x", "y", &[], false).unwrap();
        decode(&dir.join("empty.png"));
    }
}
