//! x-y figures: layers of lines and markers, clipping, the layout with a
//! legend that covers no data, and drawing.

use super::*;

/// A series as drawn: style and points (data space).
pub(super) struct Layer {
    pub(super) label: String,
    pub(super) color: RGBColor,
    pub(super) points: Vec<(f64, f64)>,
    pub(super) line: Option<LineKind>,
    pub(super) marker: Option<(Marker, i32)>,
    /// Whether the points set the axis ranges.
    pub(super) include_in_range: bool,
    /// A reference (y = x, a theoretical curve), not data: it does not count
    /// as data for the "no data" notes.
    pub(super) guide: bool,
}

pub(super) struct XyFigure<'a> {
    /// Image size (px); with `square` the height follows from the width.
    pub(super) size: (u32, u32),
    pub(super) title: &'a str,
    pub(super) x_label: &'a str,
    pub(super) y_label: &'a str,
    pub(super) log_x: bool,
    pub(super) log_y: bool,
    /// Equal x and y axes (parity plot).
    pub(super) square: bool,
    /// Horizontal margin (fraction of the data span).
    pub(super) x_pad: f64,
}

pub(super) const TITLE_H: u32 = 64;
pub(super) const TITLE_FONT: f64 = 30.0;
pub(super) const DESC_FONT: f64 = 24.0;
pub(super) const TICK_FONT: f64 = 20.0;
pub(super) const LEGEND_FONT: f64 = 20.0;

/// The polylines of `points` in axis space, broken at points that cannot
/// be shown.
pub(super) fn polylines(points: &[(f64, f64)], log_x: bool, log_y: bool) -> Vec<Vec<(f64, f64)>> {
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
pub(super) fn clip_segment(
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
pub(super) fn clip_polyline(line: &[(f64, f64)], x: &Axis, y: &Axis) -> Vec<Vec<(f64, f64)>> {
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
pub(super) fn legend_extent(layers: &[Layer], plot_w: f64, plot_h: f64) -> Option<(f64, f64)> {
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
pub(super) fn legend_corner(
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
pub(super) struct XyLayout {
    pub(super) size: (u32, u32),
    pub(super) x_axis: Axis,
    pub(super) y_axis: Axis,
    pub(super) left: u32,
    pub(super) bottom: u32,
    pub(super) right: u32,
}

pub(super) const XY_TOP_MARGIN: u32 = 16;
pub(super) const XY_MARGIN: u32 = 10;

pub(super) fn xy_layout(fig: &XyFigure, layers: &[Layer]) -> anyhow::Result<XyLayout> {
    ensure_font()?;
    let range_pts = || {
        layers
            .iter()
            .filter(|l| l.include_in_range)
            .flat_map(|l| l.points.iter().copied())
            .filter(|&(x, y)| to_axis(x, fig.log_x).is_some() && to_axis(y, fig.log_y).is_some())
    };
    let (mut x_axis, mut y_axis) = if fig.square {
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
    let lines = || -> Vec<Vec<Vec<(f64, f64)>>> {
        layers
            .iter()
            .map(|l| polylines(&l.points, fig.log_x, fig.log_y))
            .collect()
    };
    if fig.square {
        // Height making the plotting area square; when every corner of the
        // legend would cover data, both (shared) axes grow so that the band
        // above the data is empty.
        let side = w.saturating_sub(XY_MARGIN + left + right).max(100);
        h = TITLE_H + XY_TOP_MARGIN + side + bottom + XY_MARGIN;
        if let Some((lw, lh)) = legend_extent(layers, side as f64, side as f64)
            && legend_corner(&lines(), &x_axis, &y_axis, lw, lh).1 > 0
            && lh < 0.6
        {
            let values = range_pts().flat_map(|(x, y)| [x, y]);
            x_axis = Axis::fit_below(values, fig.log_x, 0.0, 8, lh + 0.02);
            y_axis = x_axis.clone();
        }
    } else {
        // When every corner of the legend would cover data, raise the top
        // of the y axis so that the legend's band above the data is empty.
        let plot_w = w.saturating_sub(XY_MARGIN + left + right) as f64;
        let plot_h = h.saturating_sub(TITLE_H + XY_TOP_MARGIN + bottom + XY_MARGIN) as f64;
        if let Some((lw, lh)) = legend_extent(layers, plot_w, plot_h)
            && legend_corner(&lines(), &x_axis, &y_axis, lw, lh).1 > 0
            && lh < 0.6
        {
            y_axis = Axis::fit_below(range_pts().map(|p| p.1), fig.log_y, 0.05, 8, lh + 0.02);
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

pub(super) fn plot_xy(path: &Path, fig: &XyFigure, layers: &[Layer]) -> anyhow::Result<()> {
    let layout = xy_layout(fig, layers)?;
    render_png(path, layout.size, |buf| draw_xy(buf, fig, &layout, layers))
}

/// Drawable geometry per layer: its polylines in axis space, clipped to the
/// axes (lines) or with the points outside left out (markers only).
pub(super) fn layer_geometry(
    fig: &XyFigure,
    layers: &[Layer],
    x_axis: &Axis,
    y_axis: &Axis,
) -> Vec<Vec<Vec<(f64, f64)>>> {
    layers
        .iter()
        .map(|l| {
            polylines(&l.points, fig.log_x, fig.log_y)
                .iter()
                .flat_map(|pl| {
                    // A lone point has no segment to clip: it is kept (for
                    // its marker) like the points of a marker-only series.
                    if l.line.is_some() && pl.len() >= 2 {
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
        .collect()
}

/// Draws one figure in painter's order: title, axes and ticks, series,
/// legend, the "no data" note, frame.
pub(super) fn draw_xy(
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

    let lines = layer_geometry(fig, layers, x_axis, y_axis);
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
