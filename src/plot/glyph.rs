//! Markers, line kinds and legend glyphs of x-y figures.

use super::*;

#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Marker {
    Circle,
    Square,
    TriangleUp,
    Diamond,
    TriangleDown,
    Cross,
    Plus,
}

impl Marker {
    pub(super) const ALL: [Marker; 7] = [
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
pub(super) enum LineKind {
    /// Solid with this width (px).
    Solid(u32),
    Dashed,
}

/// A marker at a point, or (as a legend sample) a short line with an
/// optional marker starting at the point.
pub(super) struct Glyph<C> {
    pub(super) at: C,
    pub(super) legend_line: Option<(LineKind, RGBColor)>,
    pub(super) marker: Option<(Marker, i32, RGBColor)>,
}

impl<'a, C: 'a> PointCollection<'a, C> for &'a Glyph<C> {
    type Point = &'a C;
    type IntoIter = std::iter::Once<&'a C>;
    fn point_iter(self) -> Self::IntoIter {
        std::iter::once(&self.at)
    }
}

/// Legend sample length (px).
pub(super) const LEGEND_SAMPLE: i32 = 36;

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
