//! Colours: the viridis map of particle values and the palette of series.

use super::*;

/// Viridis control points (matplotlib's map sampled every 1/16).
pub(super) const VIRIDIS: [[u8; 3]; 17] = [
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
pub(super) fn palette(i: usize) -> RGBColor {
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

pub(super) fn colour_range(panels: &[ParticlePanel], vmin: f64, vmax: f64) -> (f64, f64) {
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
