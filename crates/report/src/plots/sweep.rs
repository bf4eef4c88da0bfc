//! A metric over a scene-parameter sweep (e.g. the outlier distance exponent e), one curve per
//! method, one panel per builder, like Riemersma 2024's performance-drop figures. Vertical markers
//! show measured drops (solid) and predicted drops (dashed, Riemersma eq. 14).
use super::{color, err, Figure};
use bvhlab_pipeline::stats::min_max;
use super::Axis;
use plotters::coord::Shift;
use plotters::prelude::*;

pub struct Curve {
    pub label: String,
    pub color_index: usize,
    /// Dashed, darker: reference methods drawn in every panel (top-down builders).
    pub reference: bool,
    pub points: Vec<(f64, f64)>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MarkerKind {
    Measured,
    Predicted,
}

pub struct Marker {
    pub x: f64,
    pub color_index: usize,
    pub kind: MarkerKind,
    pub label: String,
}

pub struct SweepPanel {
    pub title: String,
    pub curves: Vec<Curve>,
    pub markers: Vec<Marker>,
}

pub struct SweepFigure {
    pub caption: String,
    pub x_desc: String,
    pub y_desc: String,
    pub panels: Vec<SweepPanel>,
}

const REF_COLORS: [RGBColor; 4] = [
    RGBColor(40, 40, 40),
    RGBColor(120, 120, 120),
    RGBColor(90, 60, 30),
    RGBColor(0, 90, 90),
];

fn curve_color(c: &Curve) -> RGBColor {
    if c.reference {
        REF_COLORS[c.color_index % REF_COLORS.len()]
    } else {
        color(c.color_index)
    }
}

impl SweepFigure {
    fn cols(&self) -> usize {
        self.panels.len().clamp(1, 3)
    }

    /// Shared y range of every finite point (and marker-free): `(lo, hi, log)`. Log when all values
    /// are positive and span more than a factor 20 (a cost that explodes at large e would flatten
    /// everything else).
    pub fn y_range(&self) -> Option<(f64, f64, bool)> {
        let ys = self
            .panels
            .iter()
            .flat_map(|p| p.curves.iter())
            .flat_map(|c| c.points.iter())
            .map(|p| p.1);
        let (lo, hi) = min_max(ys.filter(|y| y.is_finite()));
        if !lo.is_finite() {
            return None;
        }
        if lo > 0.0 && hi / lo > 20.0 {
            return Some((lo / 1.3, hi * 1.5, true));
        }
        let span = if hi > lo { hi - lo } else { hi.abs().max(1e-3) };
        let lo = if lo >= 0.0 && lo - 0.08 * span < 0.0 {
            0.0
        } else {
            lo - 0.08 * span
        };
        Some((lo, hi + 0.15 * span, false))
    }

    fn x_range(&self) -> (f64, f64) {
        let xs = self.panels.iter().flat_map(|p| {
            p.curves
                .iter()
                .flat_map(|c| c.points.iter().map(|p| p.0))
                .chain(p.markers.iter().map(|m| m.x))
        });
        let (lo, hi) = min_max(xs.filter(|x| x.is_finite()));
        if !lo.is_finite() {
            return (0.0, 1.0);
        }
        let pad = if hi > lo { 0.03 * (hi - lo) } else { 0.5 };
        (lo - pad, hi + pad)
    }
}

impl Figure for SweepFigure {
    fn size(&self) -> (u32, u32) {
        let cols = self.cols() as u32;
        let rows = self.panels.len().max(1).div_ceil(self.cols()) as u32;
        let legend =
            self.panels.iter().map(legend_rows).max().unwrap_or(0) as u32 * LEGEND_ROW as u32 + 10;
        (cols * 620, rows * (480 + legend) + 50)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String> {
        let root = root
            .titled(&self.caption, ("sans-serif", 22))
            .map_err(err)?;
        let Some((ylo, yhi, log)) = self.y_range() else {
            return super::draw_nothing(&root, "no finite values".into());
        };
        let (xlo, xhi) = self.x_range();
        let rows = self.panels.len().max(1).div_ceil(self.cols());
        let areas = root.split_evenly((rows, self.cols()));
        for (panel, area) in self.panels.iter().zip(areas.iter()) {
            if log {
                draw_panel(
                    area,
                    panel,
                    xlo..xhi,
                    (ylo..yhi).log_scale(),
                    (ylo, yhi),
                    &self.x_desc,
                    &self.y_desc,
                )?;
            } else {
                draw_panel(
                    area,
                    panel,
                    xlo..xhi,
                    ylo..yhi,
                    (ylo, yhi),
                    &self.x_desc,
                    &self.y_desc,
                )?;
            }
        }
        Ok(())
    }
}

/// Rows of the legend under a panel (two entries per row).
fn legend_rows(panel: &SweepPanel) -> usize {
    let kinds = [MarkerKind::Measured, MarkerKind::Predicted];
    let n = panel.curves.len()
        + kinds
            .iter()
            .filter(|k| panel.markers.iter().any(|m| m.kind == **k))
            .count();
    n.div_ceil(2)
}

const LEGEND_ROW: i32 = 17;

/// Swatch + label, two columns. Style: 0 solid line, 1 dashed line, 2 thin vertical, 3 dashed vertical.
fn draw_legend<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    entries: &[(String, RGBColor, u8)],
) -> Result<(), String> {
    let (w, _) = area.dim_in_pixel();
    let col_w = (w as i32 - 80) / 2;
    for (i, (label, c, style)) in entries.iter().enumerate() {
        let x = 80 + (i as i32 % 2) * col_w;
        let y = 6 + (i as i32 / 2) * LEGEND_ROW;
        let mid = y + 6;
        match style {
            0 => area
                .draw(&PathElement::new(
                    vec![(x, mid), (x + 24, mid)],
                    c.stroke_width(2),
                ))
                .map_err(err)?,
            1 => {
                for k in 0..3 {
                    area.draw(&PathElement::new(
                        vec![(x + 9 * k, mid), (x + 9 * k + 5, mid)],
                        c.stroke_width(2),
                    ))
                    .map_err(err)?;
                }
            }
            2 => area
                .draw(&PathElement::new(
                    vec![(x + 12, y), (x + 12, y + 12)],
                    c.stroke_width(1),
                ))
                .map_err(err)?,
            _ => {
                area.draw(&PathElement::new(
                    vec![(x + 12, y), (x + 12, y + 4)],
                    c.stroke_width(2),
                ))
                .map_err(err)?;
                area.draw(&PathElement::new(
                    vec![(x + 12, y + 8), (x + 12, y + 12)],
                    c.stroke_width(2),
                ))
                .map_err(err)?;
            }
        }
        area.draw(&Text::new(
            label.clone(),
            (x + 30, y),
            ("sans-serif", 13).into_font(),
        ))
        .map_err(err)?;
    }
    Ok(())
}

fn draw_panel<DB, Y>(
    area: &DrawingArea<DB, Shift>,
    panel: &SweepPanel,
    xr: std::ops::Range<f64>,
    yr: Y,
    (ylo, yhi): (f64, f64),
    x_desc: &str,
    y_desc: &str,
) -> Result<(), String>
where
    DB: DrawingBackend,
    Y: Axis,
{
    let (_, h) = area.dim_in_pixel();
    let legend_h = legend_rows(panel) as i32 * LEGEND_ROW + 10;
    let (area, legend_area) = area.split_vertically((h as i32 - legend_h).max(h as i32 / 2));
    let legend_area = &legend_area;
    let mut chart = super::panel_chart(&area, &panel.title, xr, yr)?;
    let (x, y) = (chart.x_range(), chart.y_range());
    super::draw_axes(&mut chart, (x_desc, y_desc), (x.start, x.end), (y.start, y.end))?;

    // Markers first, so curves stay on top.
    let mut any = [false, false];
    let mut marker_labels: Vec<(f64, String)> = Vec::new();
    for m in panel.markers.iter() {
        if !m.x.is_finite() {
            continue;
        }
        let c = color(m.color_index);
        let line = vec![(m.x, ylo), (m.x, yhi)];
        match m.kind {
            MarkerKind::Measured => {
                chart
                    .draw_series(LineSeries::new(line, c.mix(0.8).stroke_width(1)))
                    .map_err(err)?;
                any[0] = true;
            }
            MarkerKind::Predicted => {
                chart
                    .draw_series(DashedLineSeries::new(line, 8, 5, c.stroke_width(2)))
                    .map_err(err)?;
                any[1] = true;
            }
        }
        marker_labels.push((m.x, m.label.clone()));
    }

    // Methods often coincide (concise bounds = scene bounds for a tiny outlier): earlier curves are
    // wider, so a later one drawn on top leaves them visible; marker shapes differ too.
    let mut k = 0usize;
    for c in &panel.curves {
        let col = curve_color(c);
        let pts: Vec<(f64, f64)> = c
            .points
            .iter()
            .copied()
            .filter(|p| p.0.is_finite() && p.1.is_finite())
            .collect();
        if c.reference {
            chart
                .draw_series(DashedLineSeries::new(pts, 6, 4, col.stroke_width(2)))
                .map_err(err)?;
            continue;
        }
        let width = 4u32.saturating_sub(k.min(2) as u32);
        chart
            .draw_series(LineSeries::new(pts.clone(), col.stroke_width(width)))
            .map_err(err)?;
        match k % 4 {
            0 => chart
                .draw_series(pts.iter().map(|&p| Circle::new(p, 4, col.filled())))
                .map(|_| ()),
            1 => chart
                .draw_series(pts.iter().map(|&p| TriangleMarker::new(p, 5, col.filled())))
                .map(|_| ()),
            2 => chart
                .draw_series(pts.iter().map(|&p| Cross::new(p, 4, col.stroke_width(2))))
                .map(|_| ()),
            _ => chart
                .draw_series(pts.iter().map(|&p| {
                    EmptyElement::at(p) + Rectangle::new([(-3, -3), (3, 3)], col.filled())
                }))
                .map(|_| ()),
        }
        .map_err(err)?;
        k += 1;
    }
    // Marker labels near the top of their line, wherever they collide with nothing (issue 16).
    let (px, py) = chart.plotting_area().get_pixel_range();
    let mut placer = super::labels::Placer::new(super::labels::plot_rect(px, py.clone()), Vec::new());
    for (x, label) in &marker_labels {
        let (ax, _) = chart.backend_coord(&(*x, yhi));
        placer.place(&area, label, 12.0, (ax, py.start + 10))?;
    }
    // Legend below the chart (not over the data or the marker labels): curves, then marker kinds.
    let mut entries: Vec<(String, RGBColor, u8)> = panel
        .curves
        .iter()
        .map(|c| {
            (
                c.label.clone(),
                curve_color(c),
                if c.reference { 1 } else { 0 },
            )
        })
        .collect();
    if any[0] {
        entries.push(("solid vertical: measured drop".into(), BLACK, 2));
    }
    if any[1] {
        entries.push(("dashed vertical: predicted drop (eq. 14)".into(), BLACK, 3));
    }
    draw_legend(legend_area, &entries)?;
    Ok(())
}
