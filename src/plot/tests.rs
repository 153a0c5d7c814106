//! Tests of the figures: every figure type on ordinary and degenerate data.

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
    let fig = landscape_figure(false);
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

#[test]
fn a_one_point_line_series_keeps_its_marker() {
    // A line series of a single point (one setting of a knob in an
    // accuracy chart) has no segment, but its marker must be drawn and its
    // legend entry must not say "(no data)".
    let layer = |points: Vec<(f64, f64)>| Layer {
        label: "one".into(),
        color: palette(0),
        points,
        line: Some(LineKind::Solid(2)),
        marker: Some((Marker::ALL[0], 5)),
        include_in_range: true,
        guide: false,
    };
    let layers = vec![layer(vec![(2.0, 0.5)]), layer(vec![(1.0, 0.1), (3.0, 0.9)])];
    let fig = landscape_figure(true);
    let layout = xy_layout(&fig, &layers).unwrap();
    let geom = layer_geometry(&fig, &layers, &layout.x_axis, &layout.y_axis);
    assert_eq!(geom[0], vec![vec![(2.0_f64.log10(), 0.5_f64.log10())]]);
    assert_eq!(geom[1].len(), 1);
    assert_eq!(geom[1][0].len(), 2);
}

#[test]
fn parity_legend_never_covers_data() {
    // Points in all four corners of a shared (square) range.
    let corners = vec![
        (1.0, 1.0),
        (1.0, 10.0),
        (10.0, 1.0),
        (10.0, 10.0),
        (5.0, 5.0),
    ];
    let layers = vec![Layer {
        label: "a long legend entry for the measured points".to_string(),
        color: palette(0),
        points: corners,
        line: None,
        marker: Some((Marker::ALL[0], 5)),
        include_in_range: true,
        guide: false,
    }];
    let fig = XyFigure {
        size: (1000, 1000),
        title: "t",
        x_label: "x",
        y_label: "y",
        log_x: false,
        log_y: false,
        square: true,
        x_pad: 0.0,
    };
    let layout = xy_layout(&fig, &layers).unwrap();
    assert_eq!(layout.x_axis.hi, layout.y_axis.hi, "the axes stay equal");
    let side = (layout.size.0 - XY_MARGIN - layout.left - layout.right) as f64;
    let (lw, lh) = legend_extent(&layers, side, side).unwrap();
    let lines: Vec<Vec<Vec<(f64, f64)>>> = layers
        .iter()
        .map(|l| polylines(&l.points, false, false))
        .collect();
    assert_eq!(
        legend_corner(&lines, &layout.x_axis, &layout.y_axis, lw, lh).1,
        0
    );
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

/// A 1200 × 800 chart with both axes linear or both logarithmic.
fn landscape_figure(log: bool) -> XyFigure<'static> {
    XyFigure {
        size: (1200, 800),
        title: "t",
        x_label: "x",
        y_label: "y",
        log_x: log,
        log_y: log,
        square: false,
        x_pad: 0.02,
    }
}
