//! Build time against SAH cost, one point per (builder, parameters, compaction) of a scene, with the
//! Pareto front (DEVELOPERS.md principle 1: chart speed against quality).
use super::{color, err, labels, Figure};
use bvhlab_pipeline::stats::min_max;
use super::Axis;
use plotters::coord::Shift;
use plotters::prelude::*;

/// Indices of the points no other point dominates when minimizing both coordinates, sorted by
/// increasing x. `q` dominates `p` when `q.x <= p.x`, `q.y <= p.y` and one of them is strictly
/// smaller, so identical points are all on the front. Points with a NaN or infinite coordinate are
/// never on the front and never dominate.
pub fn pareto_front(points: &[(f64, f64)]) -> Vec<usize> {
    let mut idx: Vec<usize> = (0..points.len())
        .filter(|&i| points[i].0.is_finite() && points[i].1.is_finite())
        .collect();
    // x ascending, then y ascending, then index for determinism.
    idx.sort_by(|&a, &b| {
        let (pa, pb) = (points[a], points[b]);
        pa.0.total_cmp(&pb.0).then(pa.1.total_cmp(&pb.1)).then(a.cmp(&b))
    });
    let mut front: Vec<usize> = Vec::new();
    let mut best_y = f64::INFINITY;
    for i in idx {
        let p = points[i];
        let same_as_last = front.last().is_some_and(|&j| points[j] == p);
        // Everything before `p` has x <= p.x; p survives only with a strictly lower y than all of
        // them, or by being an exact copy of the last front point.
        if p.1 < best_y || same_as_last {
            front.push(i);
            best_y = best_y.min(p.1);
        }
    }
    front
}

pub struct ParetoPoint {
    pub label: String,
    /// Index into the report-wide method list (stable colour).
    pub method_index: usize,
    pub seconds: f64,
    pub sah_cost: f64,
    /// Fastest and slowest of the timed runs (an error bar); None with one run.
    pub seconds_range: Option<(f64, f64)>,
    /// A production library's builder (issue 18): drawn as a triangle, not a circle.
    pub peer: bool,
}

pub struct ParetoFigure {
    pub scene: String,
    /// What the y axis is: `SAH cost`, or `focus SAH cost` for scenes with a focus box.
    pub cost_label: String,
    /// x axis: what the time includes (`encode + build + optimize + compact time [s]`).
    pub time_label: String,
    pub points: Vec<ParetoPoint>,
}

/// Height of the chart; the numbered key goes below it.
const CHART_HEIGHT: u32 = 600;
const KEY_ROW: u32 = 18;
const KEY_COLUMNS: usize = 2;

impl ParetoFigure {
    /// Room for a key entry per point (an upper bound: front points labelled in place need none).
    fn key_height(&self) -> u32 {
        // The key holds the points that got a number, known only after placing the labels: place
        // them once on a throwaway SVG of the chart's size (the placement depends on it alone).
        let mut svg = String::new();
        let n = {
            let root = SVGBackend::with_string(&mut svg, (900, CHART_HEIGHT)).into_drawing_area();
            self.chart(&root).map(|k| k.len()).unwrap_or(self.points.len())
        };
        if n == 0 {
            0
        } else {
            n.div_ceil(KEY_COLUMNS) as u32 * KEY_ROW + 16
        }
    }

    /// Finite points (log axes need positive times too, handled in `draw`).
    fn finite(&self) -> Vec<&ParetoPoint> {
        self.points.iter().filter(|p| p.seconds.is_finite() && p.sah_cost.is_finite()).collect()
    }
}

impl Figure for ParetoFigure {
    fn size(&self) -> (u32, u32) {
        (900, CHART_HEIGHT + self.key_height())
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String> {
        let (chart, key_area) = root.split_vertically(CHART_HEIGHT);
        let key = self.chart(&chart)?;
        draw_key(&key_area, &key)
    }
}

impl ParetoFigure {
    /// Draws the chart; returns the numbered key.
    fn chart<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<Vec<String>, String> {
        let pts = self.finite();
        let title = format!("{}: build time vs {}", self.scene, self.cost_label);
        if pts.is_empty() {
            super::draw_nothing(root, format!("{title}: no finite (time, cost) points"))?;
            return Ok(Vec::new());
        }
        let (xmin, xmax) = min_max(pts.iter().flat_map(|p| {
            let (lo, hi) = p.seconds_range.filter(|(lo, _)| *lo > 0.0).unwrap_or((p.seconds, p.seconds));
            [p.seconds, lo, hi]
        }));
        let (ymin, ymax) = min_max(pts.iter().map(|p| p.sah_cost));
        // Log y when the costs span more than a factor 20 (a method that failed on a far outlier
        // would squash every other point onto one line).
        let key = if ymin > 0.0 && ymax / ymin > 20.0 {
            let yr = (ymin / 1.3..ymax * 1.5).log_scale();
            let ydesc = format!("{} (log)", self.cost_label);
            self.draw_x(root, &title, yr, &ydesc, (ymin, ymax), xmin, xmax)?
        } else {
            let ypad = if ymax > ymin { 0.08 * (ymax - ymin) } else { 0.05 * ymax.abs().max(1.0) };
            let yr = (ymin - ypad)..(ymax + ypad);
            self.draw_x(root, &title, yr, &self.cost_label, (ymin - ypad, ymax + ypad), xmin, xmax)?
        };
        Ok(key)
    }
}

impl ParetoFigure {
    /// Picks the x axis: log when the times span more than a decade (and are all positive), so
    /// that fast builders are not squashed against the axis.
    fn draw_x<DB, Y>(
        &self,
        root: &DrawingArea<DB, Shift>,
        title: &str,
        yr: Y,
        ydesc: &str,
        ylim: (f64, f64),
        xmin: f64,
        xmax: f64,
    ) -> Result<Vec<String>, String>
    where
        DB: DrawingBackend,
        Y: Axis,
    {
        if xmin > 0.0 && xmax / xmin > 10.0 {
            let xr = (xmin / 1.5..xmax * 1.5).log_scale();
            let lim = ((xmin / 1.5, xmax * 1.5), ylim);
            self.draw_with(root, title, xr, yr, &format!("{} (log)", self.time_label), ydesc, lim)
        } else {
            let xpad = if xmax > xmin { 0.1 * (xmax - xmin) } else { 0.05 * xmax.abs().max(1e-6) };
            let lo = if xmin >= 0.0 { 0.0 } else { xmin - xpad };
            let xr = lo..(xmax + xpad);
            let lim = ((lo, xmax + xpad), ylim);
            self.draw_with(root, title, xr, yr, &self.time_label, ydesc, lim)
        }
    }
}

impl ParetoFigure {
    /// Draws the chart and returns the numbered key (entry k-1 is point number k).
    #[allow(clippy::too_many_arguments)]
    fn draw_with<DB, X, Y>(
        &self,
        root: &DrawingArea<DB, Shift>,
        title: &str,
        xr: X,
        yr: Y,
        xdesc: &str,
        ydesc: &str,
        lim: ((f64, f64), (f64, f64)),
    ) -> Result<Vec<String>, String>
    where
        DB: DrawingBackend,
        Y: Axis,
        X: Axis,
    {
        let pts = self.finite();
        let mut chart = ChartBuilder::on(root)
            .caption(title, ("sans-serif", 22))
            .margin(15)
            .x_label_area_size(45)
            .y_label_area_size(70)
            .build_cartesian_2d(xr, yr)
            .map_err(err)?;
        super::draw_axes(&mut chart, (xdesc, ydesc), lim.0, lim.1)?;

        let xy: Vec<(f64, f64)> = pts.iter().map(|p| (p.seconds, p.sah_cost)).collect();
        let front = pareto_front(&xy);
        let mut on_front = vec![false; pts.len()];
        for &i in &front {
            on_front[i] = true;
        }
        // The front as a staircase would suggest interpolated configurations exist; a plain
        // polyline just connects the non-dominated points in time order.
        chart
            .draw_series(LineSeries::new(
                front.iter().map(|&i| xy[i]),
                ShapeStyle { color: BLACK.mix(0.7), filled: false, stroke_width: 2 },
            ))
            .map_err(err)?
            .label("Pareto front")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK.stroke_width(2)));

        // Error bars: from the fastest to the slowest run (issue 16: noise made visible).
        for p in &pts {
            if let Some((lo, hi)) = p.seconds_range.filter(|(lo, hi)| lo.is_finite() && hi.is_finite() && *lo > 0.0) {
                let y = p.sah_cost;
                chart
                    .draw_series(std::iter::once(PathElement::new(vec![(lo, y), (hi, y)], BLACK.mix(0.45).stroke_width(1))))
                    .map_err(err)?;
                for x in [lo, hi] {
                    chart
                        .draw_series(std::iter::once(
                            EmptyElement::at((x, y)) + PathElement::new(vec![(0, -4), (0, 4)], BLACK.mix(0.45)),
                        ))
                        .map_err(err)?;
                }
            }
        }
        let px: Vec<(i32, i32)> = xy.iter().map(|p| chart.backend_coord(p)).collect();
        let mut markers = Vec::new();
        for (k, p) in pts.iter().enumerate() {
            let c = color(p.method_index);
            let style = if on_front[k] { c.filled() } else { c.stroke_width(2) };
            let radius = if on_front[k] { 7 } else { 5 };
            if p.peer {
                chart
                    .draw_series(std::iter::once(TriangleMarker::new((p.seconds, p.sah_cost), radius + 2, style)))
                    .map_err(err)?;
            } else {
                chart
                    .draw_series(std::iter::once(Circle::new((p.seconds, p.sah_cost), radius, style)))
                    .map_err(err)?;
            }
            if on_front[k] {
                chart
                    .draw_series(std::iter::once(Circle::new(
                        (p.seconds, p.sah_cost),
                        radius + 2,
                        BLACK.stroke_width(1),
                    )))
                    .map_err(err)?;
            }
            let r = radius + 3;
            let (x, y) = px[k];
            markers.push(labels::Rect { x0: x - r, y0: y - r, x1: x + r, y1: y + r });
        }
        chart
            .draw_series(std::iter::empty::<Circle<(f64, f64), i32>>())
            .map_err(err)?
            .label("filled, ringed: on the front")
            .legend(|(x, y)| Circle::new((x + 10, y), 5, BLACK.filled()));
        if pts.iter().any(|p| p.peer) {
            chart
                .draw_series(std::iter::empty::<Circle<(f64, f64), i32>>())
                .map_err(err)?
                .label("triangle: production library (Embree, obvhs)")
                .legend(|(x, y)| TriangleMarker::new((x + 10, y), 7, BLACK.stroke_width(2)));
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK.mix(0.5))
            .label_font(("sans-serif", 13))
            .draw()
            .map_err(err)?;

        // Labels: points that coincide on screen share one; front points get their name where it
        // fits, every other point (and a front point whose name does not fit) a number from the
        // key below the chart. The legend box is an obstacle too.
        let (xr, yr) = chart.plotting_area().get_pixel_range();
        let bounds = labels::plot_rect(xr.clone(), yr.clone());
        let legend = labels::Rect { x0: xr.end - 260, y0: yr.start, x1: xr.end, y1: yr.start + 60 };
        markers.push(legend);
        // Error bars and the front's line are obstacles too: a label across a line is unreadable.
        for p in &pts {
            if let Some((lo, hi)) = p.seconds_range.filter(|(lo, hi)| lo.is_finite() && hi.is_finite() && *lo > 0.0) {
                let (a, y) = chart.backend_coord(&(lo, p.sah_cost));
                let (b, _) = chart.backend_coord(&(hi, p.sah_cost));
                markers.push(labels::Rect { x0: a - 1, y0: y - 5, x1: b + 2, y1: y + 6 });
            }
        }
        for w in front.windows(2) {
            let (a, b) = (px[w[0]], px[w[1]]);
            let steps = ((b.0 - a.0).abs().max((b.1 - a.1).abs()) / 4).max(1);
            for k in 0..=steps {
                let x = a.0 + (b.0 - a.0) * k / steps;
                let y = a.1 + (b.1 - a.1) * k / steps;
                markers.push(labels::Rect { x0: x - 2, y0: y - 2, x1: x + 3, y1: y + 3 });
            }
        }
        let mut placer = labels::Placer::new(bounds, markers);
        let mut groups: Vec<Vec<usize>> = Vec::new();
        let mut order: Vec<usize> = (0..pts.len()).collect();
        // Front first (in time order), then the rest by cost: the front's labels get the best spots.
        order.sort_by(|&a, &b| {
            on_front[b].cmp(&on_front[a]).then(xy[a].1.total_cmp(&xy[b].1)).then(xy[a].0.total_cmp(&xy[b].0))
        });
        for k in order {
            match groups.iter_mut().find(|g| {
                let (gx, gy) = px[g[0]];
                (gx - px[k].0).abs() <= 3 && (gy - px[k].1).abs() <= 3
            }) {
                Some(g) => g.push(k),
                None => groups.push(vec![k]),
            }
        }
        let mut key = Vec::new();
        for g in &groups {
            let anchor = px[g[0]];
            if g.iter().any(|&k| on_front[k]) {
                let name = g.iter().map(|&k| pts[k].label.as_str()).collect::<Vec<_>>().join("; ");
                if placer.place(root, &name, 13.0, anchor)? {
                    continue;
                }
            }
            let first = key.len() + 1;
            key.extend(g.iter().map(|&k| pts[k].label.clone()));
            let nums = if g.len() == 1 { first.to_string() } else { format!("{first}-{}", key.len()) };
            // A number that finds no free spot still has its key entry; the point is then the
            // unlabelled one nearest its numbered neighbours.
            placer.place(root, &nums, 12.0, anchor)?;
        }
        Ok(key)
    }
}

/// The numbered key under the chart, in columns.
fn draw_key<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, key: &[String]) -> Result<(), String> {
    if key.is_empty() {
        return Ok(());
    }
    let (bx, by) = area.get_base_pixel();
    let (w, h) = area.dim_in_pixel();
    let whole = labels::Rect { x0: bx, y0: by, x1: bx + w as i32, y1: by + h as i32 };
    let col_w = (w as i32 - 30) / KEY_COLUMNS as i32;
    let rows = key.len().div_ceil(KEY_COLUMNS);
    for (i, name) in key.iter().enumerate() {
        let (c, r) = (i / rows, i % rows);
        let mut text = format!("{}  {name}", i + 1);
        // Cut names longer than the column (the full name is in the tables and the SVG title).
        while labels::text_size(area, &text, 12.0).0 > col_w - 10 && text.chars().count() > 8 {
            let keep = text.chars().count() - 2;
            text = text.chars().take(keep).collect::<String>() + "…";
        }
        let at = (bx + 15 + c as i32 * col_w, by + 8 + r as i32 * KEY_ROW as i32);
        labels::draw_at(area, &text, 12.0, at, whole)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::pareto_front;

    /// Brute force: p is on the front iff no finite q dominates it.
    fn brute(points: &[(f64, f64)]) -> Vec<usize> {
        let fin = |p: &(f64, f64)| p.0.is_finite() && p.1.is_finite();
        let mut v: Vec<usize> = (0..points.len())
            .filter(|&i| fin(&points[i]))
            .filter(|&i| {
                let p = points[i];
                !points.iter().any(|q| {
                    fin(q) && q.0 <= p.0 && q.1 <= p.1 && (q.0 < p.0 || q.1 < p.1)
                })
            })
            .collect();
        v.sort();
        v
    }

    #[test]
    fn small_cases() {
        assert!(pareto_front(&[]).is_empty());
        assert_eq!(pareto_front(&[(1.0, 1.0)]), vec![0]);
        // (2,2) is dominated by (1,1); (0.5,3) and (3,0.5) trade off.
        let pts = [(2.0, 2.0), (1.0, 1.0), (0.5, 3.0), (3.0, 0.5)];
        assert_eq!(pareto_front(&pts), vec![2, 1, 3]);
        // Same x, higher y is dominated; identical points are both kept.
        assert_eq!(pareto_front(&[(1.0, 2.0), (1.0, 1.0)]), vec![1]);
        assert_eq!(pareto_front(&[(1.0, 1.0), (1.0, 1.0)]), vec![0, 1]);
        // Non-finite points are ignored.
        assert_eq!(pareto_front(&[(f64::NAN, 0.0), (1.0, f64::INFINITY), (2.0, 2.0)]), vec![2]);
    }

    #[test]
    fn matches_brute_force() {
        // Tiny LCG so the test needs no extra dependency; coarse grid to force ties.
        let mut s: u64 = 0x9E37_79B9_7F4A_7C15;
        let mut next = || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((s >> 33) % 8) as f64
        };
        for n in 0..40 {
            let pts: Vec<(f64, f64)> = (0..n).map(|_| (next(), next())).collect();
            let mut got = pareto_front(&pts);
            // Sorted by x on output.
            assert!(got.windows(2).all(|w| pts[w[0]].0 <= pts[w[1]].0));
            got.sort();
            assert_eq!(got, brute(&pts), "points {pts:?}");
        }
    }
}
