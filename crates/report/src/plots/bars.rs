//! Horizontal bar charts, one bar per method: SAH cost per scene, traversal steps and intersections
//! per ray per scene and ray set. Horizontal so long method labels stay readable.
use super::{bar_range, color, err, fmt_num, labels, Figure};
use plotters::coord::Shift;
use plotters::prelude::*;

pub struct Bar {
    pub label: String,
    pub value: f64,
    /// Index into the report-wide method list (stable colour).
    pub color_index: usize,
}

pub struct Panel {
    pub title: String,
    pub x_desc: String,
    pub bars: Vec<Bar>,
}

/// Panels side by side under one caption.
pub struct BarsFigure {
    pub caption: String,
    pub panels: Vec<Panel>,
    /// Small multiples: every panel has the same bars in the same order (one panel per scene),
    /// named once, left of the first panel; the others are narrow.
    pub shared_labels: bool,
}

/// Width of a small-multiple panel.
const MULTIPLE_WIDTH: u32 = 260;

impl BarsFigure {
    /// Room for the longest bar name in full (13 px sans-serif, about 8 px per character; the
    /// names are drawn by `draw_panel`, which checks the real size).
    fn label_width(&self) -> u32 {
        let chars =
            self.panels.iter().flat_map(|p| p.bars.iter()).map(|b| b.label.chars().count()).max();
        (chars.unwrap_or(4) as u32 * 8 + 24).clamp(60, 900)
    }
}

impl Figure for BarsFigure {
    fn size(&self) -> (u32, u32) {
        let n = self.panels.iter().map(|p| p.bars.len()).max().unwrap_or(1) as u32;
        let panels = self.panels.len().max(1) as u32;
        let w = if self.shared_labels {
            self.label_width() + panels * MULTIPLE_WIDTH
        } else {
            panels * (self.label_width() + 420)
        };
        (w, n * 24 + 130)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String> {
        let root = root.titled(&self.caption, ("sans-serif", 22)).map_err(err)?;
        if self.shared_labels {
            let first = (self.label_width() + MULTIPLE_WIDTH) as i32;
            let (mut area, mut rest) = root.split_horizontally(first);
            for (i, panel) in self.panels.iter().enumerate() {
                draw_panel(&area, panel, if i == 0 { self.label_width() } else { 0 })?;
                let (a, r) = rest.split_horizontally(MULTIPLE_WIDTH as i32);
                area = a;
                rest = r;
            }
            return Ok(());
        }
        let areas = root.split_evenly((1, self.panels.len().max(1)));
        for (panel, area) in self.panels.iter().zip(areas.iter()) {
            draw_panel(area, panel, self.label_width())?;
        }
        Ok(())
    }
}

fn draw_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    panel: &Panel,
    label_width: u32,
) -> Result<(), String> {
    let n = panel.bars.len();
    if n == 0 {
        return Ok(());
    }
    // One category per unit, bar 0 on top as in a table; every bar named in full at its left
    // (plotters' tick labels skip categories when they get dense).
    let yr = super::Categories(n);
    let xr = bar_range(panel.bars.iter().map(|b| b.value));
    let mut chart = ChartBuilder::on(area)
        .caption(&panel.title, ("sans-serif", 17))
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(label_width.max(8))
        .build_cartesian_2d(xr.clone(), yr)
        .map_err(err)?;
    let fmt = labels::axis_format(xr.start, xr.end);
    chart
        .configure_mesh()
        .disable_y_mesh()
        .y_labels(0)
        .x_desc(&panel.x_desc)
        .x_label_formatter(&fmt)
        .draw()
        .map_err(err)?;
    let (px, py) = chart.plotting_area().get_pixel_range();
    let plot = labels::plot_rect(px.clone(), py);
    let (ax, ay) = area.get_base_pixel();
    let (aw, ah) = area.dim_in_pixel();
    let whole = labels::Rect { x0: ax, y0: ay, x1: ax + aw as i32, y1: ay + ah as i32 };
    for (i, b) in panel.bars.iter().enumerate() {
        // Row i from the top occupies [n-i-1, n-i).
        let top = (n - i) as f64 - 0.15;
        let bottom = (n - i - 1) as f64 + 0.15;
        if b.value.is_finite() {
            chart
                .draw_series(std::iter::once(Rectangle::new(
                    [(0.0, bottom), (b.value, top)],
                    color(b.color_index).filled(),
                )))
                .map_err(err)?;
        }
        let (_, cy) = chart.backend_coord(&(0.0, (n - i) as f64 - 0.5));
        if label_width > 0 {
            let (w, h) = labels::text_size(area, &b.label, 13.0);
            labels::draw_at(area, &b.label, 13.0, (px.start - 6 - w, cy - h / 2), whole)?;
        }
        let text = if b.value.is_finite() { fmt_num(b.value) } else { "n/a".into() };
        let (ex, _) = chart.backend_coord(&(if b.value.is_finite() { b.value.max(0.0) } else { 0.0 }, 0.0));
        let (w, h) = labels::text_size(area, &text, 12.0);
        // After the bar's end, or inside it when the end is at the right edge.
        let x = if ex + 4 + w <= plot.x1 { ex + 4 } else { (ex - 4 - w).max(plot.x0) };
        labels::draw_at(area, &text, 12.0, (x, cy - h / 2), plot)?;
    }
    Ok(())
}
