//! Horizontal bar charts, one bar per method: SAH cost per scene, traversal steps and intersections
//! per ray per scene and ray set. Horizontal so long method labels stay readable.
use super::{bar_range, color, err, fmt_num, Figure};
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
}

impl BarsFigure {
    fn label_width(&self) -> u32 {
        let chars =
            self.panels.iter().flat_map(|p| p.bars.iter()).map(|b| b.label.chars().count()).max();
        (chars.unwrap_or(4) as u32 * 7 + 16).clamp(60, 320)
    }
}

impl Figure for BarsFigure {
    fn size(&self) -> (u32, u32) {
        let n = self.panels.iter().map(|p| p.bars.len()).max().unwrap_or(1) as u32;
        let w = self.panels.len().max(1) as u32 * (self.label_width() + 480);
        (w.min(2400), (n * 34 + 150).clamp(260, 1600))
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String> {
        let root = root.titled(&self.caption, ("sans-serif", 22)).map_err(err)?;
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
    let labels: Vec<String> = panel.bars.iter().map(|b| b.label.clone()).collect();
    // One category per unit; the label tick sits at the centre. Bar 0 on top, as in a table.
    
    let yr = super::Categories(n);
    let xr = bar_range(panel.bars.iter().map(|b| b.value));
    let mut chart = ChartBuilder::on(area)
        .caption(&panel.title, ("sans-serif", 17))
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(label_width)
        .build_cartesian_2d(xr, yr)
        .map_err(err)?;
    let label_of = |v: &f64| {
        let i = n as f64 - v;
        if i < 0.0 {
            return String::new();
        }
        labels.get(i.floor() as usize).cloned().unwrap_or_default()
    };
    chart
        .configure_mesh()
        .disable_y_mesh()
        .x_desc(&panel.x_desc)
        .x_label_formatter(&|v| fmt_num(*v))
        .y_label_formatter(&label_of)
        .y_label_style(("sans-serif", 13))
        .draw()
        .map_err(err)?;
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
        let text = if b.value.is_finite() { fmt_num(b.value) } else { "n/a".into() };
        let x = if b.value.is_finite() { b.value } else { 0.0 };
        chart
            .draw_series(std::iter::once(
                EmptyElement::at((x, (n - i) as f64 - 0.5))
                    + Text::new(text, (4, -7), ("sans-serif", 13).into_font()),
            ))
            .map_err(err)?;
    }
    Ok(())
}
