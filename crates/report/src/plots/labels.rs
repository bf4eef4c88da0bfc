//! Text labels placed where they collide with nothing (issue 16: labels piled up on the Pareto
//! front and ran off the plot). Figures that place labels themselves go through a `Placer`, which
//! tries candidate positions around each anchor and refuses any that overlaps an earlier label or
//! a marker or leaves the plot area; every accepted box is recorded so `render` can count overlaps
//! (zero by construction; the test checks it, and `render` reports a plot that breaks it).
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::cell::RefCell;

/// Pixel rectangle, half-open: [x0, x1) x [y0, y1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rect {
    pub x0: i32,
    pub y0: i32,
    pub x1: i32,
    pub y1: i32,
}

impl Rect {
    pub fn overlaps(&self, o: &Rect) -> bool {
        self.x0 < o.x1 && o.x0 < self.x1 && self.y0 < o.y1 && o.y0 < self.y1
    }
    pub fn inside(&self, o: &Rect) -> bool {
        self.x0 >= o.x0 && self.x1 <= o.x1 && self.y0 >= o.y0 && self.y1 <= o.y1
    }
}

/// The labels one figure drew: their boxes and the area each had to stay inside.
#[derive(Clone, Debug, Default)]
pub struct Record {
    pub labels: Vec<(Rect, Rect)>,
}

impl Record {
    /// Pairs of labels that overlap.
    pub fn overlaps(&self) -> usize {
        let mut n = 0;
        for (i, (a, _)) in self.labels.iter().enumerate() {
            n += self.labels[i + 1..].iter().filter(|(b, _)| a.overlaps(b)).count();
        }
        n
    }
    /// Labels outside their area.
    pub fn outside(&self) -> usize {
        self.labels.iter().filter(|(l, area)| !l.inside(area)).count()
    }
}

thread_local! {
    static RECORD: RefCell<Record> = RefCell::new(Record::default());
}

/// Starts recording the labels of one rendering (called by `render`).
pub fn start() {
    RECORD.with(|r| *r.borrow_mut() = Record::default());
}

/// The labels recorded since `start`.
pub fn take() -> Record {
    RECORD.with(|r| std::mem::take(&mut *r.borrow_mut()))
}

fn record(label: Rect, area: Rect) {
    RECORD.with(|r| r.borrow_mut().labels.push((label, area)));
}

/// The plotting area of a chart in backend pixels.
pub fn plot_rect(x: std::ops::Range<i32>, y: std::ops::Range<i32>) -> Rect {
    Rect { x0: x.start, y0: y.start, x1: x.end, y1: y.end }
}

/// Size of `text` in `font` as the backend will draw it; a per-character estimate if the backend
/// cannot tell (no fonts).
pub fn text_size<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, text: &str, size: f64) -> (i32, i32) {
    match area.estimate_text_size(text, &TextStyle::from(("sans-serif", size).into_font())) {
        Ok((w, h)) => (w as i32 + 2, h as i32 + 2),
        Err(_) => ((text.chars().count() as f64 * size * 0.6) as i32 + 2, size as i32 + 4),
    }
}

/// Draws `text` with its box's top-left corner at `at` (backend pixels, as `backend_coord` gives
/// them, whatever part of the figure `area` is) and records the box.
pub fn draw_at<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    text: &str,
    size: f64,
    at: (i32, i32),
    within: Rect,
) -> Result<Rect, String> {
    let (w, h) = text_size(area, text, size);
    let style = TextStyle::from(("sans-serif", size).into_font()).pos(Pos::new(HPos::Left, VPos::Top));
    let (bx, by) = area.get_base_pixel();
    area.draw(&Text::new(text.to_string(), (at.0 + 1 - bx, at.1 + 1 - by), style)).map_err(super::err)?;
    let r = Rect { x0: at.0, y0: at.1, x1: at.0 + w, y1: at.1 + h };
    record(r, within);
    Ok(r)
}

/// Places labels around anchors without collisions, inside `bounds` (backend pixels).
pub struct Placer {
    pub bounds: Rect,
    taken: Vec<Rect>,
}

impl Placer {
    /// `obstacles`: what labels must not cover (markers).
    pub fn new(bounds: Rect, obstacles: Vec<Rect>) -> Placer {
        Placer { bounds, taken: obstacles }
    }

    /// First free box of size (w, h) near `anchor`: right, left, above, below at growing
    /// distances. Returns the box and whether it is far enough to need a leader line.
    pub fn find(&self, anchor: (i32, i32), w: i32, h: i32) -> Option<(Rect, bool)> {
        for (ring, d) in [9, 20, 34, 52].into_iter().enumerate() {
            let (ax, ay) = anchor;
            let cands = [
                (ax + d, ay - h / 2),
                (ax + d, ay - h - d / 2),
                (ax + d, ay + d / 2),
                (ax - d - w, ay - h / 2),
                (ax - d - w, ay - h - d / 2),
                (ax - d - w, ay + d / 2),
                (ax - w / 2, ay - d - h),
                (ax - w / 2, ay + d),
            ];
            for (x, y) in cands {
                let r = Rect { x0: x, y0: y, x1: x + w, y1: y + h };
                if r.inside(&self.bounds) && !self.taken.iter().any(|t| t.overlaps(&r)) {
                    return Some((r, ring > 0));
                }
            }
        }
        None
    }

    pub fn take(&mut self, r: Rect) {
        self.taken.push(r);
    }

    /// Places and draws `text` near `anchor` (with a leader line when it had to move away);
    /// false if there was no free place.
    pub fn place<DB: DrawingBackend>(
        &mut self,
        area: &DrawingArea<DB, Shift>,
        text: &str,
        size: f64,
        anchor: (i32, i32),
    ) -> Result<bool, String> {
        let (w, h) = text_size(area, text, size);
        let Some((r, far)) = self.find(anchor, w, h) else {
            return Ok(false);
        };
        if far {
            let tx = r.x0.max(anchor.0.min(r.x1));
            let ty = r.y0.max(anchor.1.min(r.y1));
            let (bx, by) = area.get_base_pixel();
            let path = vec![(anchor.0 - bx, anchor.1 - by), (tx - bx, ty - by)];
            area.draw(&PathElement::new(path, BLACK.mix(0.4))).map_err(super::err)?;
        }
        draw_at(area, text, size, (r.x0, r.y0), self.bounds)?;
        self.take(r);
        Ok(true)
    }
}

/// Formatter for one axis: one format for every tick (issue 16 found 5.00e-4 next to 0.001).
/// Plain decimals when the whole range is in [1e-3, 1e6), else scientific for all ticks.
pub fn axis_format(lo: f64, hi: f64) -> impl Fn(&f64) -> String {
    let (a, b) = (lo.abs().min(hi.abs()), lo.abs().max(hi.abs()));
    let plain = (a == 0.0 || a >= 1e-3) && b < 1e6;
    move |v: &f64| {
        if plain || *v == 0.0 {
            super::fmt_num(*v)
        } else {
            let s = format!("{v:.1e}");
            // 5.0e-4 -> 5e-4
            s.replace(".0e", "e")
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_format_per_axis() {
        let f = axis_format(4e-4, 0.2);
        assert_eq!(f(&5e-4), "5e-4");
        assert_eq!(f(&1e-3), "1e-3");
        assert_eq!(f(&0.01), "1e-2");
        let g = axis_format(1e-3, 0.2);
        assert_eq!(g(&0.001), "0.001");
        assert_eq!(g(&0.1), "0.1");
    }

    #[test]
    fn placer_never_overlaps() {
        let bounds = Rect { x0: 0, y0: 0, x1: 400, y1: 300 };
        let mut p = Placer::new(bounds, vec![]);
        let mut placed = Vec::new();
        // 60 labels at one anchor: each accepted box is free and inside, the rest are refused.
        for _ in 0..60 {
            if let Some((r, _)) = p.find((200, 150), 80, 14) {
                assert!(r.inside(&bounds));
                assert!(!placed.iter().any(|q: &Rect| q.overlaps(&r)));
                p.take(r);
                placed.push(r);
            }
        }
        assert!(placed.len() >= 8, "{}", placed.len());
        assert!(placed.len() < 60);
    }
}
