//! The layout figure: panels of bytes per triangle against a cost, one curve per family, with
//! the Pareto front.
use super::{families, Case, Metric};
use crate::plots::labels;
use crate::plots::pareto::pareto_front;
use crate::plots::{color, err, Figure};
use bvhlab_pipeline::stats::min_max;
use crate::plots::Axis;
use plotters::coord::Shift;
use plotters::prelude::*;

// ---------------------------------------------------------------------------------------------
// Figure

pub struct Series {
    pub label: String,
    pub color_index: usize,
    /// (x, y, point label)
    pub points: Vec<(f64, f64, String)>,
    /// Per point, the fastest and slowest run of a timed y (drawn as an error bar).
    pub y_ranges: Vec<Option<(f64, f64)>>,
}

pub struct ScatterPanel {
    pub title: String,
    pub x_desc: String,
    pub y_desc: String,
    pub series: Vec<Series>,
}

/// Panels of bytes against a cost, one line per family; Pareto front (ringed points, black
/// line) over every point of the panel.
pub struct LayoutFigure {
    pub caption: String,
    pub panels: Vec<ScatterPanel>,
}

const LEGEND_ROW: i32 = 17;
const LEGEND_COLS: usize = 3;

impl LayoutFigure {
    fn legend(&self) -> Vec<(String, usize)> {
        let mut v: Vec<(String, usize)> = Vec::new();
        for s in self.panels.iter().flat_map(|p| p.series.iter()) {
            if !v.iter().any(|e| e.0 == s.label) {
                v.push((s.label.clone(), s.color_index));
            }
        }
        v
    }
}

impl Figure for LayoutFigure {
    fn size(&self) -> (u32, u32) {
        let cols = self.panels.len().clamp(1, 2) as u32;
        let rows = self.panels.len().max(1).div_ceil(2) as u32;
        let legend = (self.legend().len() + 1).div_ceil(LEGEND_COLS) as u32 * LEGEND_ROW as u32 + 16;
        (cols * 640, rows * 460 + legend + 40)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String> {
        let root = root.titled(&self.caption, ("sans-serif", 22)).map_err(err)?;
        let (w, h) = root.dim_in_pixel();
        let entries = self.legend();
        let legend_h = (entries.len() + 1).div_ceil(LEGEND_COLS) as i32 * LEGEND_ROW + 16;
        let (top, bottom) = root.split_vertically((h as i32 - legend_h).max(h as i32 / 2));
        let cols = self.panels.len().clamp(1, 2);
        let rows = self.panels.len().max(1).div_ceil(2);
        let areas = top.split_evenly((rows, cols));
        for (panel, area) in self.panels.iter().zip(areas.iter()) {
            draw_panel(area, panel)?;
        }
        // Legend: families, then the front.
        let col_w = (w as i32 - 40) / LEGEND_COLS as i32;
        let mut all: Vec<(String, Option<usize>)> = entries.into_iter().map(|(l, c)| (l, Some(c))).collect();
        all.push(("Pareto front (ringed; fewer bytes and lower cost)".into(), None));
        for (i, (label, c)) in all.iter().enumerate() {
            let x = 40 + (i % LEGEND_COLS) as i32 * col_w;
            let y = 6 + (i / LEGEND_COLS) as i32 * LEGEND_ROW;
            let col = c.map(color).unwrap_or(BLACK);
            bottom
                .draw(&PathElement::new(vec![(x, y + 6), (x + 24, y + 6)], col.stroke_width(2)))
                .map_err(err)?;
            if let Some(ci) = c {
                draw_marker(&bottom, (x + 12, y + 6), *ci, col)?;
            } else {
                bottom.draw(&Circle::new((x + 12, y + 6), 6, BLACK.stroke_width(1))).map_err(err)?;
            }
            bottom
                .draw(&Text::new(label.clone(), (x + 30, y), ("sans-serif", 13).into_font()))
                .map_err(err)?;
        }
        Ok(())
    }
}

/// Marker shape by colour index (so families stay apart in black and white too).
fn draw_marker<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    p: (i32, i32),
    ci: usize,
    col: RGBColor,
) -> Result<(), String> {
    match ci % 4 {
        0 => area.draw(&Circle::new(p, 4, col.filled())),
        1 => area.draw(&TriangleMarker::new(p, 5, col.filled())),
        2 => area.draw(&Cross::new(p, 4, col.stroke_width(2))),
        _ => area.draw(&Rectangle::new([(p.0 - 3, p.1 - 3), (p.0 + 3, p.1 + 3)], col.filled())),
    }
    .map_err(err)
}

fn range(vs: impl Iterator<Item = f64>, log_ratio: f64) -> Option<(f64, f64, bool)> {
    let (lo, hi) = min_max(vs.filter(|v| v.is_finite()));
    if !lo.is_finite() {
        return None;
    }
    if lo > 0.0 && hi / lo > log_ratio {
        return Some((lo / 1.25, hi * 1.35, true));
    }
    let span = if hi > lo { hi - lo } else { hi.abs().max(1e-3) };
    let lo2 = if lo >= 0.0 && lo - 0.1 * span < 0.0 { 0.0 } else { lo - 0.1 * span };
    Some((lo2, hi + 0.15 * span, false))
}

fn draw_panel<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, panel: &ScatterPanel) -> Result<(), String> {
    let all = || panel.series.iter().flat_map(|s| s.points.iter());
    let xr = range(all().map(|p| p.0), 8.0);
    let bars = || panel.series.iter().flat_map(|s| s.y_ranges.iter().flatten().flat_map(|(a, b)| [*a, *b]));
    let yr = range(all().map(|p| p.1).chain(bars()), 20.0);
    let (Some(xr), Some(yr)) = (xr, yr) else {
        area.draw(&Text::new(
            format!("{}: no data", panel.title),
            (20, 30),
            ("sans-serif", 16).into_font(),
        ))
        .map_err(err)?;
        return Ok(());
    };
    let xd = if xr.2 { format!("{} (log)", panel.x_desc) } else { panel.x_desc.clone() };
    let yd = if yr.2 { format!("{} (log)", panel.y_desc) } else { panel.y_desc.clone() };
    let lims = ((xr.0, xr.1), (yr.0, yr.1));
    match (xr.2, yr.2) {
        (false, false) => panel_with(area, panel, xr.0..xr.1, yr.0..yr.1, &xd, &yd, lims),
        (true, false) => panel_with(area, panel, (xr.0..xr.1).log_scale(), yr.0..yr.1, &xd, &yd, lims),
        (false, true) => panel_with(area, panel, xr.0..xr.1, (yr.0..yr.1).log_scale(), &xd, &yd, lims),
        (true, true) => panel_with(area, panel, (xr.0..xr.1).log_scale(), (yr.0..yr.1).log_scale(), &xd, &yd, lims),
    }
}

fn panel_with<DB, X, Y>(
    area: &DrawingArea<DB, Shift>,
    panel: &ScatterPanel,
    xr: X,
    yr: Y,
    xdesc: &str,
    ydesc: &str,
    lims: ((f64, f64), (f64, f64)),
) -> Result<(), String>
where
    DB: DrawingBackend,
    X: Axis,
    Y: Axis,
{
    let mut chart = crate::plots::panel_chart(area, &panel.title, xr, yr)?;
    crate::plots::draw_axes(&mut chart, (xdesc, ydesc), lims.0, lims.1)?;
    // Front over distinct finite points of every series.
    let mut pts: Vec<(f64, f64, String)> = Vec::new();
    for p in panel.series.iter().flat_map(|s| s.points.iter()) {
        if p.0.is_finite() && p.1.is_finite() && !pts.iter().any(|q| q.0 == p.0 && q.1 == p.1 && q.2 == p.2) {
            pts.push(p.clone());
        }
    }
    let xy: Vec<(f64, f64)> = pts.iter().map(|p| (p.0, p.1)).collect();
    let fr = pareto_front(&xy);
    chart
        .draw_series(LineSeries::new(fr.iter().map(|&i| xy[i]), BLACK.mix(0.6).stroke_width(1)))
        .map_err(err)?;
    for s in &panel.series {
        let col = color(s.color_index);
        let sp: Vec<(f64, f64)> = s
            .points
            .iter()
            .filter(|p| p.0.is_finite() && p.1.is_finite())
            .map(|p| (p.0, p.1))
            .collect();
        if sp.len() > 1 {
            chart.draw_series(LineSeries::new(sp.clone(), col.stroke_width(2))).map_err(err)?;
        }
        let ci = s.color_index;
        match ci % 4 {
            0 => chart.draw_series(sp.iter().map(|&p| Circle::new(p, 4, col.filled()))).map(|_| ()),
            1 => chart.draw_series(sp.iter().map(|&p| TriangleMarker::new(p, 5, col.filled()))).map(|_| ()),
            2 => chart.draw_series(sp.iter().map(|&p| Cross::new(p, 4, col.stroke_width(2)))).map(|_| ()),
            _ => chart
                .draw_series(sp.iter().map(|&p| EmptyElement::at(p) + Rectangle::new([(-3, -3), (3, 3)], col.filled())))
                .map(|_| ()),
        }
        .map_err(err)?;
    }
    for &i in &fr {
        chart
            .draw_series(std::iter::once(EmptyElement::at(xy[i]) + Circle::new((0, 0), 8, BLACK.stroke_width(1))))
            .map_err(err)?;
    }
    // Error bars: fastest to slowest run of a timed y (issue 16).
    let mut bar_boxes = Vec::new();
    for s in &panel.series {
        for (p, r) in s.points.iter().zip(&s.y_ranges) {
            let Some((lo, hi)) = r.filter(|(lo, hi)| *lo > 0.0 && hi.is_finite()) else { continue };
            chart
                .draw_series(std::iter::once(PathElement::new(vec![(p.0, lo), (p.0, hi)], BLACK.mix(0.45))))
                .map_err(err)?;
            for y in [lo, hi] {
                chart
                    .draw_series(std::iter::once(EmptyElement::at((p.0, y)) + PathElement::new(vec![(-4, 0), (4, 0)], BLACK.mix(0.45))))
                    .map_err(err)?;
            }
            let (x, a) = chart.backend_coord(&(p.0, hi));
            let (_, b) = chart.backend_coord(&(p.0, lo));
            bar_boxes.push(labels::Rect { x0: x - 5, y0: a.min(b) - 1, x1: x + 6, y1: a.max(b) + 2 });
        }
    }
    // Front points named where the name collides with no marker or other name (issue 16); the
    // legend says which family each marker is.
    let (px, py) = chart.plotting_area().get_pixel_range();
    let markers: Vec<labels::Rect> = xy
        .iter()
        .map(|p| {
            let (x, y) = chart.backend_coord(p);
            labels::Rect { x0: x - 9, y0: y - 9, x1: x + 9, y1: y + 9 }
        })
        .collect();
    let mut markers = markers;
    markers.extend(bar_boxes);
    let mut placer = labels::Placer::new(labels::plot_rect(px, py), markers);
    for &i in &fr {
        placer.place(area, &pts[i].2, 11.0, chart.backend_coord(&xy[i]))?;
    }
    Ok(())
}

/// Figure of one case: bytes per triangle (topology, total) against `ys`.
pub fn figure(case: &Case, caption: &str, ys: &[Metric]) -> LayoutFigure {
    let fams = families(case);
    let mut panels = Vec::new();
    for &y in ys {
        for x in [Metric::TopologyBytesPerTriangle, Metric::TotalBytesPerTriangle] {
            let series = fams
                .iter()
                .enumerate()
                .map(|(fi, f)| Series {
                    label: f.label.clone(),
                    color_index: fi,
                    points: f
                        .members
                        .iter()
                        .filter_map(|&i| {
                            let p = &case.points[i];
                            Some((x.of(p.row)?, y.of(p.row)?, p.label.clone()))
                        })
                        .collect(),
                    y_ranges: f
                        .members
                        .iter()
                        .filter_map(|&i| {
                            let p = &case.points[i];
                            x.of(p.row)?;
                            y.of(p.row)?;
                            Some(y.range(p.row))
                        })
                        .collect(),
                })
                .collect();
            panels.push(ScatterPanel {
                title: format!("{} vs {}", y.desc(), x.desc()),
                x_desc: x.desc().into(),
                y_desc: y.desc().into(),
                series,
            });
        }
    }
    LayoutFigure { caption: caption.to_string(), panels }
}
