//! Convergence of the optimizers on one initial tree (Bittner 2013 figures 7 and 8): SAH cost
//! against seconds (left) and against the pass (right), one curve per optimizer / measure, with a
//! ring at the pass that reaches 90% of the curve's final reduction.
use super::{color, err, Figure};
use super::Axis;
use plotters::coord::Shift;
use plotters::prelude::*;

pub struct ConvCurve {
    pub label: String,
    /// Index into the report-wide optimizer list (stable colour).
    pub color_index: usize,
    /// (pass, seconds, SAH cost).
    pub points: Vec<(u32, f64, f64)>,
    /// The point reaching 90% of the final reduction.
    pub mark: Option<(u32, f64, f64)>,
}

/// Maps a trace point (pass, seconds, cost) to panel coordinates.
type ToXy<'a> = &'a dyn Fn(&(u32, f64, f64)) -> (f64, f64);

pub struct ConvergenceFigure {
    pub caption: String,
    pub curves: Vec<ConvCurve>,
}

const LEGEND_ROW: i32 = 17;

impl ConvergenceFigure {
    fn finite(&self) -> impl Iterator<Item = &(u32, f64, f64)> {
        self.curves
            .iter()
            .flat_map(|c| c.points.iter())
            .filter(|p| p.1.is_finite() && p.2.is_finite())
    }

    /// y range `(lo, hi, log, clipped)`: from the lowest cost to the highest start (or final)
    /// cost, so an annealing run that climbs far above its start (a hot schedule) does not squash
    /// every other curve; points above are drawn at the top edge (`clipped`). Log when the costs
    /// span more than a factor 3 (a spatial-median start would flatten the interesting end).
    pub fn y_range(&self) -> Option<(f64, f64, bool, bool)> {
        let lo = self.finite().map(|p| p.2).fold(f64::INFINITY, f64::min);
        let ends = self
            .curves
            .iter()
            .flat_map(|c| [c.points.first(), c.points.last()])
            .flatten()
            .map(|p| p.2)
            .filter(|y| y.is_finite());
        let hi = ends.fold(f64::NEG_INFINITY, f64::max);
        if !lo.is_finite() || !hi.is_finite() {
            return None;
        }
        let top = self.finite().map(|p| p.2).fold(f64::NEG_INFINITY, f64::max);
        if lo > 0.0 && hi / lo > 3.0 {
            let yhi = hi * 1.1;
            return Some((lo / 1.05, yhi, true, top > yhi));
        }
        let span = if hi > lo {
            hi - lo
        } else {
            hi.abs().max(1e-3) * 0.05
        };
        let yhi = hi + 0.05 * span;
        Some((lo - 0.05 * span, yhi, false, top > yhi))
    }

    /// Time axis: log when the runs' lengths differ by more than 20x (a time-capped annealing run
    /// beside a 1-second ibo run); pass 0 (t = 0) is then drawn at the left edge.
    pub fn x_time(&self) -> (f64, f64, bool) {
        let pos: Vec<f64> = self.finite().map(|p| p.1).filter(|t| *t > 0.0).collect();
        let hi = pos.iter().copied().fold(0.0f64, f64::max);
        let lo = pos.iter().copied().fold(f64::INFINITY, f64::min);
        let ends: Vec<f64> = self
            .curves
            .iter()
            .filter_map(|c| c.points.last().map(|p| p.1))
            .filter(|t| *t > 0.0 && t.is_finite())
            .collect();
        let (emin, emax) = ends
            .iter()
            .fold((f64::INFINITY, 0.0f64), |(a, b), t| (a.min(*t), b.max(*t)));
        if hi <= 0.0 || !lo.is_finite() {
            return (0.0, 1.0, false);
        }
        if emin.is_finite() && emax / emin > 20.0 {
            (lo / 2.0, hi * 1.3, true)
        } else {
            (0.0, hi * 1.05, false)
        }
    }

    fn legend_rows(&self) -> i32 {
        (self.curves.len() as i32 + 2) / 2
    }
}

impl Figure for ConvergenceFigure {
    fn size(&self) -> (u32, u32) {
        (1300, 520 + (self.legend_rows() * LEGEND_ROW) as u32 + 10)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String> {
        let root = root
            .titled(&self.caption, ("sans-serif", 22))
            .map_err(err)?;
        let Some((ylo, yhi, ylog, clipped)) = self.y_range() else {
            return super::draw_nothing(&root, "no finite trace points".into());
        };
        let (_, h) = root.dim_in_pixel();
        let legend_h = (self.legend_rows() * LEGEND_ROW + 10) as u32;
        let (plots, legend) = root.split_vertically(h.saturating_sub(legend_h));
        let halves = plots.split_evenly((1, 2));
        let (tlo, thi, tlog) = self.x_time();
        let max_pass = self.finite().map(|p| p.0).max().unwrap_or(1).max(1) as f64;
        let ydesc = match (ylog, clipped) {
            (false, false) => "SAH cost",
            (true, false) => "SAH cost (log)",
            (false, true) => "SAH cost (higher values drawn at the top)",
            (true, true) => "SAH cost (log; higher values drawn at the top)",
        };
        let clamp_y = |y: f64| y.min(yhi);
        let time_desc = if tlog {
            "optimizer time [s] (log; pass 0 at the left edge)"
        } else {
            "optimizer time [s]"
        };
        // Time panel: pass 0 sits at t = 0, which a log axis cannot show: clamp it to the edge.
        let clamp_t = |t: f64| if tlog { t.max(tlo) } else { t };
        let time_xy = |p: &(u32, f64, f64)| (clamp_t(p.1), clamp_y(p.2));
        let pass_xy = |p: &(u32, f64, f64)| (p.0 as f64, clamp_y(p.2));
        macro_rules! panel {
            ($area:expr, $xr:expr, $xdesc:expr, $xy:expr) => {
                if ylog {
                    self.panel($area, $xr, (ylo..yhi).log_scale(), $xdesc, ydesc, $xy)?
                } else {
                    self.panel($area, $xr, ylo..yhi, $xdesc, ydesc, $xy)?
                }
            };
        }
        if tlog {
            panel!(&halves[0], (tlo..thi).log_scale(), time_desc, &time_xy);
        } else {
            panel!(&halves[0], tlo..thi, time_desc, &time_xy);
        }
        panel!(
            &halves[1],
            -0.02 * max_pass..max_pass * 1.03,
            "pass",
            &pass_xy
        );

        // Legend under both panels, two columns.
        let (w, _) = legend.dim_in_pixel();
        let col_w = (w as i32 - 120) / 2;
        let mut entries: Vec<(String, RGBColor, bool)> = self
            .curves
            .iter()
            .map(|c| (c.label.clone(), color(c.color_index), false))
            .collect();
        entries.push((
            "ring: 90% of the curve's final reduction".into(),
            RGBColor(0, 0, 0),
            true,
        ));
        for (i, (label, c, ring)) in entries.iter().enumerate() {
            let x = 100 + (i as i32 % 2) * col_w;
            let y = 4 + (i as i32 / 2) * LEGEND_ROW;
            let mid = y + 6;
            if *ring {
                legend
                    .draw(&Circle::new((x + 12, mid), 5, c.stroke_width(2)))
                    .map_err(err)?;
            } else {
                legend
                    .draw(&PathElement::new(
                        vec![(x, mid), (x + 24, mid)],
                        c.stroke_width(3),
                    ))
                    .map_err(err)?;
            }
            legend
                .draw(&Text::new(
                    label.clone(),
                    (x + 30, y),
                    ("sans-serif", 13).into_font(),
                ))
                .map_err(err)?;
        }
        Ok(())
    }
}

impl ConvergenceFigure {
    fn panel<DB, X, Y>(
        &self,
        area: &DrawingArea<DB, Shift>,
        xr: X,
        yr: Y,
        xdesc: &str,
        ydesc: &str,
        xy: ToXy,
    ) -> Result<(), String>
    where
        DB: DrawingBackend,
        X: Axis,
        Y: Axis,
    {
        let mut chart = ChartBuilder::on(area)
            .margin(12)
            .x_label_area_size(42)
            .y_label_area_size(64)
            .build_cartesian_2d(xr, yr)
            .map_err(err)?;
        let (x, y) = (chart.x_range(), chart.y_range());
        super::draw_axes(&mut chart, (xdesc, ydesc), (x.start, x.end), (y.start, y.end))?;
        for c in &self.curves {
            let col = color(c.color_index);
            let pts: Vec<(f64, f64)> = c
                .points
                .iter()
                .filter(|p| p.1.is_finite() && p.2.is_finite())
                .map(xy)
                .collect();
            chart
                .draw_series(LineSeries::new(pts.iter().copied(), col.stroke_width(2)))
                .map_err(err)?;
            // Small dots at every pass when there are few, so short runs stay visible.
            if pts.len() <= 60 {
                chart
                    .draw_series(pts.iter().map(|&p| Circle::new(p, 2, col.filled())))
                    .map_err(err)?;
            }
            if let Some(m) = c.mark.filter(|m| m.1.is_finite() && m.2.is_finite()) {
                chart
                    .draw_series(std::iter::once(Circle::new(xy(&m), 6, col.stroke_width(2))))
                    .map_err(err)?;
            }
        }
        Ok(())
    }
}
