//! Our value beside the thesis' value, one pair of bars per (scene, method), labelled with the
//! difference in percent. One figure per metric (scales differ).
use super::{bar_range, err, fmt_num, Figure};
use crate::reference::Comparison;
use plotters::coord::Shift;
use plotters::prelude::*;

pub struct ReferenceFigure {
    pub metric: String,
    /// Whose table (`Frantal 2019`, `Bittner 2013`).
    pub source: String,
    pub items: Vec<Comparison>,
}

const OURS: RGBColor = RGBColor(31, 119, 180);
const PAPER: RGBColor = RGBColor(170, 170, 170);

impl ReferenceFigure {
    fn labels(&self) -> Vec<String> {
        self.items.iter().map(|c| format!("{} {} ({})", c.thesis_scene, c.abbrev, c.method)).collect()
    }
}

impl Figure for ReferenceFigure {
    fn size(&self) -> (u32, u32) {
        (1000, (self.items.len() as u32 * 60 + 160).max(280))
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String> {
        let n = self.items.len();
        if n == 0 {
            return Ok(());
        }
        let labels = self.labels();
        let label_width = (labels.iter().map(|l| l.chars().count()).max().unwrap_or(4) as u32 * 7 + 16)
            .clamp(80, 900);
        
        let yr = super::Categories(n);
        let xr = bar_range(self.items.iter().flat_map(|c| [c.ours, c.paper]));
        let mut chart = ChartBuilder::on(root)
            .caption(format!("{}: ours vs {}", self.metric, self.source), ("sans-serif", 22))
            .margin(15)
            .x_label_area_size(40)
            .y_label_area_size(label_width)
            .build_cartesian_2d(xr, yr)
            .map_err(err)?;
        let xf = super::labels::axis_format(chart.x_range().start, chart.x_range().end);
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
            .x_desc(self.metric.as_str())
            .x_label_formatter(&xf)
            .y_label_formatter(&label_of)
            .y_label_style(("sans-serif", 13))
            .draw()
            .map_err(err)?;
        for (i, c) in self.items.iter().enumerate() {
            // Row i from the top spans [n-i-1, n-i): ours in the upper half, paper in the lower.
            let top = (n - i) as f64;
            let ours = [(0.0, top - 0.48), (c.ours, top - 0.12)];
            let paper = [(0.0, top - 0.88), (c.paper, top - 0.52)];
            chart.draw_series(std::iter::once(Rectangle::new(ours, OURS.filled()))).map_err(err)?;
            chart.draw_series(std::iter::once(Rectangle::new(paper, PAPER.filled()))).map_err(err)?;
            let diff = if c.diff_percent.is_finite() {
                format!("{} ({:+.1}%)", fmt_num(c.ours), c.diff_percent)
            } else {
                fmt_num(c.ours)
            };
            chart
                .draw_series([
                    EmptyElement::at((c.ours, top - 0.3))
                        + Text::new(diff, (4, -7), ("sans-serif", 13).into_font()),
                    EmptyElement::at((c.paper, top - 0.7))
                        + Text::new(fmt_num(c.paper), (4, -7), ("sans-serif", 13).into_font()),
                ])
                .map_err(err)?;
        }
        // Legend by hand: two swatches in the upper right, beside the caption (never over bars).
        let (w, _) = root.dim_in_pixel();
        let x0 = w as i32 - 190;
        for (k, (name, col)) in [("ours", OURS), (self.source.as_str(), PAPER)].iter().enumerate() {
            let y = 6 + 18 * k as i32;
            root.draw(&Rectangle::new([(x0, y), (x0 + 16, y + 12)], col.filled())).map_err(err)?;
            root.draw(&Text::new(name.to_string(), (x0 + 22, y), ("sans-serif", 13).into_font())).map_err(err)?;
        }
        Ok(())
    }
}
