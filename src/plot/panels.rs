//! Particle panels: particles to scale, side by side, with a colour bar.

use super::*;

pub(super) const P_TOP: u32 = 10;
pub(super) const P_TITLE_H: u32 = 44;
pub(super) const P_BOTTOM: u32 = 66;
pub(super) const P_BOTTOM_PAD: u32 = 8;
pub(super) const P_LEFT_PAD: u32 = 8;
pub(super) const P_GAP: u32 = 22;
pub(super) const P_CB_GAP: u32 = 36;
pub(super) const P_CB_W: u32 = 28;
pub(super) const P_RIGHT_PAD: u32 = 10;
pub(super) const P_TARGET_H: u32 = 1200;
pub(super) const P_MAX_H: u32 = 2400;
pub(super) const P_MAX_W: u32 = 2400;
/// Narrowest plot width worth labelling (px).
pub(super) const P_MIN_PLOT_W: f64 = 90.0;
pub(super) const P_TITLE_FONT: f64 = 24.0;
pub(super) const P_DESC_FONT: f64 = 20.0;
pub(super) const P_TICK_FONT: f64 = 17.0;

pub(super) struct PanelGeom {
    pub(super) lo: [f64; 2],
    pub(super) hi: [f64; 2],
    /// Plot rectangle (x, y, w, h) in pixels.
    pub(super) rect: (i32, i32, i32, i32),
    pub(super) x_axis: Axis,
    pub(super) y_axis: Axis,
    /// Width of the y label area left of the plot (px).
    pub(super) y_area: u32,
    /// Whether this panel shows the y description (the first panel, or a y
    /// range different from the previous panel's).
    pub(super) y_desc: bool,
}

pub(super) struct PanelLayout {
    pub(super) width: u32,
    pub(super) height: u32,
    pub(super) panels: Vec<PanelGeom>,
    /// Colour bar rectangle (x, y, w, h) and the width of its label area.
    pub(super) colour_bar: (i32, i32, i32, i32),
    pub(super) cb_axis: Axis,
    pub(super) cb_area: u32,
}

impl PanelLayout {
    pub(super) fn new(
        panels: &[ParticlePanel],
        vmin: f64,
        vmax: f64,
    ) -> anyhow::Result<PanelLayout> {
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
pub(super) fn panel_domain(p: &ParticlePanel) -> ([f64; 2], [f64; 2]) {
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

pub(super) fn draw_particle_panels(
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
pub(super) struct AxesLabels<'a> {
    /// x description; `None` hides the x axis.
    pub(super) x_desc: Option<&'a str>,
    pub(super) y_desc: Option<&'a str>,
    /// Width of the y label area (px).
    pub(super) y_area: u32,
    /// y labels on the right of the plot (colour bar).
    pub(super) y_right: bool,
}

/// Ticks, tick labels and axis descriptions around a plot rectangle, without
/// grid lines. `area` spans the plot plus its label areas.
pub(super) fn axes_only(
    area: &Area,
    xa: Axis,
    ya: Axis,
    labels: &AxesLabels,
) -> anyhow::Result<()> {
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
pub(super) struct Canvas<'a> {
    pub(super) buf: &'a mut [u8],
    pub(super) w: usize,
    pub(super) h: usize,
}

impl Canvas<'_> {
    pub(super) fn blend(&mut self, x: i32, y: i32, c: [u8; 3], a: f64) {
        if x < 0 || y < 0 || x as usize >= self.w || y as usize >= self.h || a <= 0.0 {
            return;
        }
        let i = 3 * (y as usize * self.w + x as usize);
        let a = a.min(1.0);
        for (dst, &src) in self.buf[i..i + 3].iter_mut().zip(&c) {
            let old = *dst as f64;
            // Rounded by adding one half and truncating (the value is in
            // [0, 255]): `f64::round` is a library call on baseline x86-64.
            *dst = (old + a * (src as f64 - old) + 0.5) as u8;
        }
    }

    pub(super) fn fill_rect(&mut self, x: i32, y: i32, w: i32, h: i32, c: [u8; 3]) {
        for j in y..y + h {
            for i in x..x + w {
                self.blend(i, j, c, 1.0);
            }
        }
    }

    /// A 1-px black frame just outside the rectangle.
    pub(super) fn frame(&mut self, x: i32, y: i32, w: i32, h: i32) {
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
    pub(super) fn disc(
        &mut self,
        cx: f64,
        cy: f64,
        r: f64,
        c: [u8; 3],
        clip: (i32, i32, i32, i32),
    ) {
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
