//! Plots. Every figure is drawn once, generically over the plotters backend, and rendered twice:
//! PNG (BitMapBackend) for index.html and SVG (SVGBackend) for zooming and papers.
pub mod bars;
pub mod convergence;
pub mod labels;
pub mod pareto;
pub mod reference;
pub mod sweep;

use bvhlab_pipeline::atomic::write_atomic_with;
use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::coord::Shift;
use plotters::prelude::*;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;

/// A figure that can draw itself on any backend.
pub trait Figure {
    fn size(&self) -> (u32, u32);
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String>;
}

/// Files of one rendered figure, relative to the report directory.
#[derive(Clone, Debug)]
pub struct Plot {
    pub title: String,
    pub png: String,
    pub svg: String,
    /// Labels the figure placed itself (point labels, bar names and values; see `labels`), and
    /// how many of them overlap another or leave their plot area (both 0 by construction).
    pub labels: usize,
    pub label_overlaps: usize,
    pub labels_outside: usize,
}

/// Renders `fig` as `<out_dir>/<stem>.png` and `.svg`. Text rendering goes through the system's
/// fonts (fontconfig); if that fails, or plotters panics, the error comes back as `Err` so the rest
/// of the report is still written.
pub fn render<F: Figure>(fig: &F, out_dir: &Path, stem: &str, title: &str) -> Result<Plot, String> {
    let png_name = format!("{stem}.png");
    let svg_name = format!("{stem}.svg");
    let png = out_dir.join(&png_name);
    let svg = out_dir.join(&svg_name);
    let size = fig.size();
    let mut rec = labels::Record::default();
    let res = catch_unwind(AssertUnwindSafe(|| -> Result<(), String> {
        labels::start();
        let drawn = write_atomic_with(&png, |tmp| {
            let root = BitMapBackend::new(tmp, size).into_drawing_area();
            root.fill(&WHITE).map_err(err)?;
            fig.draw(&root)?;
            root.present().map_err(err)
        });
        rec = labels::take();
        drawn?;
        let r = write_atomic_with(&svg, |tmp| {
            let root = SVGBackend::new(tmp, size).into_drawing_area();
            root.fill(&WHITE).map_err(err)?;
            fig.draw(&root)?;
            root.present().map_err(err)
        });
        labels::take();
        r
    }));
    match res {
        Ok(Ok(())) => Ok(Plot {
            title: title.to_string(),
            png: png_name,
            svg: svg_name,
            labels: rec.labels.len(),
            label_overlaps: rec.overlaps(),
            labels_outside: rec.outside(),
        }),
        Ok(Err(e)) => Err(format!("plot '{title}': {e}")),
        Err(_) => Err(format!("plot '{title}': plotters panicked (fonts missing?)")),
    }
}

/// An f64 axis whose ticks can be labelled (linear or logarithmic): what every chart here draws on.
pub trait Axis: AsRangedCoord<Value = f64, CoordDescType: ValueFormatter<f64>> {}
impl<T: AsRangedCoord<Value = f64, CoordDescType: ValueFormatter<f64>>> Axis for T {}

/// One panel of a figure of panels: its title above a chart over `x` and `y`.
pub fn panel_chart<'a, DB: DrawingBackend, X: Axis, Y: Axis>(
    area: &'a DrawingArea<DB, Shift>,
    title: &str,
    x: X,
    y: Y,
) -> Result<ChartContext<'a, DB, Cartesian2d<X::CoordDescType, Y::CoordDescType>>, String> {
    ChartBuilder::on(area)
        .caption(title, ("sans-serif", 17))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d(x, y)
        .map_err(err)
}

/// A figure with nothing to draw says so in its top-left corner.
pub fn draw_nothing<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, what: String) -> Result<(), String> {
    area.draw(&Text::new(what, (20, 20), ("sans-serif", 18).into_font())).map_err(err)
}

/// The grid and axes of a chart: the axis descriptions and tick labels (`labels::axis_format`
/// over the value ranges `x` and `y`).
pub fn draw_axes<DB, X, Y>(
    chart: &mut ChartContext<'_, DB, Cartesian2d<X, Y>>,
    (xdesc, ydesc): (&str, &str),
    x: (f64, f64),
    y: (f64, f64),
) -> Result<(), String>
where
    DB: DrawingBackend,
    X: Ranged<ValueType = f64> + ValueFormatter<f64>,
    Y: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    let (xf, yf) = (labels::axis_format(x.0, x.1), labels::axis_format(y.0, y.1));
    chart
        .configure_mesh()
        .x_desc(xdesc)
        .y_desc(ydesc)
        .x_label_formatter(&xf)
        .y_label_formatter(&yf)
        .draw()
        .map_err(err)
}

pub fn err<E: std::fmt::Display>(e: E) -> String {
    e.to_string()
}

/// Stable colour of the i-th method, the same in every figure.
pub fn color(i: usize) -> RGBColor {
    // Tableau 10: distinguishable and print-friendly.
    const C: [(u8, u8, u8); 10] = [
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
    let (r, g, b) = C[i % C.len()];
    RGBColor(r, g, b)
}

/// Compact number for labels: 3-4 significant digits, scientific outside [1e-3, 1e6), no trailing
/// zeros.
pub fn fmt_num(v: f64) -> String {
    let s = fmt_fixed(v);
    if s.contains('.') && !s.contains('e') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

fn fmt_fixed(v: f64) -> String {
    if !v.is_finite() {
        return format!("{v}");
    }
    let a = v.abs();
    if a == 0.0 {
        "0".into()
    } else if !(1e-3..1e6).contains(&a) {
        format!("{v:.2e}")
    } else if a >= 100.0 {
        format!("{v:.1}")
    } else if a >= 10.0 {
        format!("{v:.2}")
    } else if a >= 1.0 {
        format!("{v:.3}")
    } else {
        let digits = (-a.log10()).floor() as usize + 3;
        format!("{v:.digits$}")
    }
}

/// Range that contains every finite value in `vs` and `0` (bars start at zero), with headroom for
/// value labels; never empty.
pub fn bar_range(vs: impl Iterator<Item = f64>) -> std::ops::Range<f64> {
    let (lo, hi) = vs
        .filter(|v| v.is_finite())
        .fold((0.0f64, 0.0f64), |(lo, hi), v| (lo.min(v), hi.max(v)));
    let span = if hi - lo > 0.0 { hi - lo } else { 1.0 };
    let lo = if lo < 0.0 { lo - 0.18 * span } else { 0.0 };
    lo..hi + 0.18 * span
}

/// Category axis for horizontal bar charts: `n` slots of height 1, one tick (label) at each slot
/// centre. plotters' own `WithKeyPoints<RangedCoordf64>` cannot take a custom label formatter.
pub struct Categories(pub usize);

impl plotters::coord::ranged1d::Ranged for Categories {
    type FormatOption = plotters::coord::ranged1d::DefaultFormatting;
    type ValueType = f64;

    fn map(&self, v: &f64, limit: (i32, i32)) -> i32 {
        let n = self.0.max(1) as f64;
        let span = (limit.1 - limit.0) as f64;
        limit.0 + (span * (v / n) + 1e-3).floor() as i32
    }

    fn key_points<H: plotters::coord::ranged1d::KeyPointHint>(&self, hint: H) -> Vec<f64> {
        if hint.weight().allow_light_points() || hint.max_num_points() == 0 {
            return Vec::new();
        }
        // Every slot: a bar without its name cannot be identified (issue 16); figures give each
        // slot room for one line of text.
        (0..self.0).map(|i| i as f64 + 0.5).collect()
    }

    fn range(&self) -> std::ops::Range<f64> {
        0.0..self.0.max(1) as f64
    }
}

#[cfg(test)]
mod tests {
    use super::fmt_num;

    #[test]
    fn numbers() {
        assert_eq!(fmt_num(0.001), "0.001");
        assert_eq!(fmt_num(20.0), "20");
        assert_eq!(fmt_num(138.25), "138.2");
        assert_eq!(fmt_num(0.012345), "0.0123");
        assert_eq!(fmt_num(1234567.0), "1.23e6");
        assert_eq!(fmt_num(f64::NAN), "NaN");
        assert_eq!(fmt_num(0.0), "0");
    }
}
