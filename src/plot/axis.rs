//! Axes: ranges, nice ticks and tick labels, linear and logarithmic; a
//! plotters coordinate.

use super::*;

/// Maps a data value to axis space (log10 on log axes); `None` if it cannot
/// be shown.
pub(super) fn to_axis(v: f64, log: bool) -> Option<f64> {
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
pub(super) fn padded_range(vals: impl Iterator<Item = f64>, log: bool, pad: f64) -> (f64, f64) {
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
pub(super) struct Axis {
    pub(super) lo: f64,
    pub(super) hi: f64,
    pub(super) log: bool,
    pub(super) major: Vec<f64>,
    pub(super) minor: Vec<f64>,
    /// Decimals of linear tick labels.
    pub(super) decimals: usize,
    /// Scientific notation for linear tick labels.
    pub(super) sci: bool,
    /// Step between major ticks (linear axes).
    pub(super) step: f64,
}

impl Axis {
    /// A linear axis on [lo, hi] with about `target` ticks.
    pub(super) fn linear(lo: f64, hi: f64, target: usize) -> Axis {
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
    pub(super) fn log(lo: f64, hi: f64) -> Axis {
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
    pub(super) fn fit(vals: impl Iterator<Item = f64>, log: bool, pad: f64, target: usize) -> Axis {
        let (lo, hi) = padded_range(vals.filter_map(|v| to_axis(v, log)), log, pad);
        if log {
            Axis::log(lo, hi)
        } else {
            Axis::linear(lo, hi, target)
        }
    }

    /// As [`Axis::fit`], with the top `top_fraction` of the axis left
    /// free (room for a legend above the data).
    pub(super) fn fit_below(
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

    pub(super) fn contains(&self, v: f64) -> bool {
        v >= self.lo && v <= self.hi
    }

    /// Tick label of axis-space value `v`.
    pub(super) fn label(&self, v: f64) -> String {
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
pub(super) fn nice_step(raw: f64) -> f64 {
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
pub(super) fn smaller_nice(step: f64) -> f64 {
    let e = (step.log10() + 1e-9).floor();
    let p = 10f64.powf(e);
    match (step / p).round() as i64 {
        5 => 2.0 * p,
        2 => p,
        _ => 0.5 * p,
    }
}

pub(super) fn ticks_with_step(lo: f64, hi: f64, step: f64) -> Vec<f64> {
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
pub(super) fn format_general(x: f64) -> String {
    let a = x.abs();
    if (1e-3..1e5).contains(&a) {
        let d = (-(a.log10() + 1e-9).floor()).max(0.0) as usize;
        format!("{x:.d$}")
    } else {
        format!("{x:.0e}")
    }
}

pub(super) fn superscript(k: i64) -> String {
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

/// Tick mark length (px); plotters puts labels at twice this from the axis.
pub(super) const TICK: i32 = 6;

/// Width of a y label area: tick labels, gap, and (optionally) the rotated
/// axis description.
pub(super) fn y_area_width(axis: &Axis, tick_font: f64, desc_font: Option<f64>) -> u32 {
    let labels = axis
        .major
        .iter()
        .map(|&v| text_width(tick_font, &axis.label(v)))
        .max()
        .unwrap_or(0);
    let desc = desc_font.map_or(0.0, |f| 14.0 + f * 1.25);
    labels + 2 * TICK as u32 + 4 + desc.ceil() as u32
}
