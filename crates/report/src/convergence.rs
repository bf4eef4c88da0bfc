//! Convergence of the optimize stage (Bittner 2013 figures 7 and 8), as plain functions over result
//! rows: one curve per optimizer (and measure) per (scene, initial tree), from `optimize_trace`, and
//! the pass at which a curve reaches a fraction (90%) of its final reduction.
use crate::analysis::method_key;
use bvhlab_pipeline::ResultRow;

/// The fraction of the final cost reduction whose first pass the report states per curve.
pub const REDUCTION_FRACTION: f64 = 0.9;

/// One trace point: pass, seconds since the optimizer started, SAH cost after the pass.
#[derive(Clone, Debug, PartialEq)]
pub struct TracePoint {
    pub pass: u32,
    pub seconds: f64,
    pub sah_cost: f64,
}

/// One optimizer run on one initial tree.
#[derive(Clone, Debug, PartialEq)]
pub struct Curve {
    /// `optimizer|optimize_params`: identity across scenes (colour).
    pub key: String,
    /// Display label, e.g. `ibo comb` or `kensler-sa` (the registry's optimizer label).
    pub label: String,
    pub optimizer: String,
    pub points: Vec<TracePoint>,
    /// Cost of the input tree (pass 0; the build stage's cost when the trace is empty).
    pub start_cost: f64,
    /// Cost of the returned tree before compaction (`optimized_sah_cost`: the best tree with
    /// keep_best, else the last).
    pub final_cost: f64,
    /// First pass (and its seconds) whose cost is at or below start - 0.9 (start - final); `None`
    /// when the optimizer did not reduce the cost.
    pub pass90: Option<(u32, f64)>,
    pub passes: u32,
    pub stop: String,
    pub optimize_seconds: f64,
    /// Build + optimize seconds (Bittner 2013's build_s).
    pub build_seconds: f64,
    /// Cost after SAH compaction (Bittner 2013's ocost), from a row of the chain that compacts.
    pub ocost: Option<f64>,
    pub valid: bool,
}

impl Curve {
    /// (start - final) / start in percent.
    pub fn reduction_percent(&self) -> f64 {
        if self.start_cost > 0.0 {
            100.0 * (self.start_cost - self.final_cost) / self.start_cost
        } else {
            f64::NAN
        }
    }
}

/// All optimizer runs on one initial tree of one scene.
#[derive(Clone, Debug, PartialEq)]
pub struct Group {
    pub scene: String,
    pub scene_name: String,
    /// `builder|build_params|encoder|encode_params`.
    pub initial_key: String,
    /// The builder part of the chain label, e.g. `sweep-sah leaf=1`.
    pub initial: String,
    pub curves: Vec<Curve>,
    /// The same initial tree without an optimizer: (cost as built, cost after compaction if a
    /// chain compacts, build seconds).
    pub baseline: Option<(f64, Option<f64>, f64)>,
}

/// The first pass whose cost reaches `start - frac (start - final)`; `None` if the cost did not
/// fall (final >= start) or no pass reaches it (a final cost from a tree the trace does not show).
pub fn pass_to_fraction(
    points: &[TracePoint],
    start: f64,
    fin: f64,
    frac: f64,
) -> Option<(u32, f64)> {
    let reduction = start - fin;
    if reduction.is_nan() || reduction <= 0.0 {
        return None;
    }
    let target = start - frac * reduction;
    points
        .iter()
        .find(|p| p.sah_cost <= target)
        .map(|p| (p.pass, p.seconds))
}

/// The parts of a chain label (`builder params [· encoder] +optimizer label [+compact]`): the
/// initial tree and the optimizer label. Falls back to the row's columns.
pub fn label_parts(r: &ResultRow) -> (String, String) {
    let parts: Vec<&str> = r.method.split(" +").collect();
    let opt = r.optimizer.as_deref().unwrap_or("");
    let opt_label = parts
        .iter()
        .skip(1)
        .find(|p| !opt.is_empty() && p.starts_with(opt))
        .map(|p| p.to_string())
        .unwrap_or_else(|| opt.to_string());
    (
        parts.first().map(|p| p.to_string()).unwrap_or_default(),
        opt_label,
    )
}

fn initial_key(r: &ResultRow) -> String {
    // method_key without the compaction and optimizer parts.
    let k = method_key(r);
    k.split('|').take(4).collect::<Vec<_>>().join("|")
}

/// Groups every row with an optimize stage by (scene, initial tree); one curve per optimizer key
/// (rows repeated per ray set or compaction share the optimize stage and count once). Scenes,
/// groups and curves in row order.
pub fn groups(rows: &[ResultRow]) -> Vec<Group> {
    let mut out: Vec<Group> = Vec::new();
    for r in rows {
        let Some(opt) = r.optimizer.as_deref() else {
            continue;
        };
        let ik = initial_key(r);
        let ck = format!("{opt}|{}", r.optimize_params.as_deref().unwrap_or(""));
        let gi = match out
            .iter()
            .position(|g| g.scene == r.scene && g.initial_key == ik)
        {
            Some(i) => i,
            None => {
                out.push(Group {
                    scene: r.scene.clone(),
                    scene_name: r.scene_name.clone(),
                    initial_key: ik,
                    initial: label_parts(r).0,
                    curves: Vec::new(),
                    baseline: None,
                });
                out.len() - 1
            }
        };
        let g = &mut out[gi];
        if let Some(c) = g.curves.iter_mut().find(|c| c.key == ck) {
            if c.ocost.is_none() && r.compact != "none" {
                c.ocost = Some(r.sah_cost);
            }
            c.valid &= r.valid;
            continue;
        }
        let points: Vec<TracePoint> = r
            .optimize_trace
            .as_deref()
            .unwrap_or(&[])
            .iter()
            .map(|p| TracePoint {
                pass: p.pass,
                seconds: p.seconds,
                sah_cost: p.sah_cost,
            })
            .collect();
        let start_cost = points
            .first()
            .map(|p| p.sah_cost)
            .or(r.build_sah_cost)
            .unwrap_or(f64::NAN);
        let final_cost = r
            .optimized_sah_cost
            .or_else(|| points.last().map(|p| p.sah_cost))
            .unwrap_or(f64::NAN);
        g.curves.push(Curve {
            key: ck,
            label: label_parts(r).1,
            optimizer: opt.to_string(),
            pass90: pass_to_fraction(&points, start_cost, final_cost, REDUCTION_FRACTION),
            passes: r
                .optimize_passes
                .unwrap_or_else(|| points.last().map_or(0, |p| p.pass)),
            stop: r.optimize_stop.clone().unwrap_or_default(),
            optimize_seconds: r.optimize_seconds.unwrap_or(f64::NAN),
            build_seconds: r.total_build_seconds,
            ocost: (r.compact != "none").then_some(r.sah_cost),
            valid: r.valid,
            points,
            start_cost,
            final_cost,
        });
    }
    // Baselines: rows of the same initial tree without an optimizer.
    for g in out.iter_mut() {
        for r in rows.iter().filter(|r| {
            r.optimizer.is_none() && r.scene == g.scene && initial_key(r) == g.initial_key
        }) {
            let built = r.build_sah_cost.unwrap_or(if r.compact == "none" {
                r.sah_cost
            } else {
                f64::NAN
            });
            let ocost = (r.compact != "none").then_some(r.sah_cost);
            match &mut g.baseline {
                None => g.baseline = Some((built, ocost, r.total_build_seconds)),
                Some(b) => {
                    if b.1.is_none() {
                        b.1 = ocost;
                    }
                    if !b.0.is_finite() {
                        b.0 = built;
                    }
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pts(costs: &[f64]) -> Vec<TracePoint> {
        costs
            .iter()
            .enumerate()
            .map(|(i, &c)| TracePoint {
                pass: i as u32,
                seconds: i as f64 * 0.5,
                sah_cost: c,
            })
            .collect()
    }

    #[test]
    fn ninety_percent_pass() {
        // 100 -> 50: 90% of the reduction = cost 55, first reached at pass 3.
        let p = pts(&[100.0, 80.0, 60.0, 55.0, 51.0, 50.0]);
        assert_eq!(pass_to_fraction(&p, 100.0, 50.0, 0.9), Some((3, 1.5)));
        // Oscillation: a later higher cost does not matter, the first crossing counts.
        let p = pts(&[100.0, 54.0, 70.0, 50.0]);
        assert_eq!(pass_to_fraction(&p, 100.0, 50.0, 0.9), Some((1, 0.5)));
        // No reduction (or a rise): none.
        assert_eq!(
            pass_to_fraction(&pts(&[100.0, 100.0]), 100.0, 100.0, 0.9),
            None
        );
        assert_eq!(
            pass_to_fraction(&pts(&[100.0, 101.0]), 100.0, 101.0, 0.9),
            None
        );
        assert_eq!(pass_to_fraction(&pts(&[100.0]), 100.0, f64::NAN, 0.9), None);
    }

    #[test]
    fn label_split() {
        let r = ResultRow {
            method: "sweep-sah leaf=1 +ibo comb +collapse".into(),
            optimizer: Some("ibo".into()),
            ..Default::default()
        };
        assert_eq!(
            label_parts(&r),
            ("sweep-sah leaf=1".to_string(), "ibo comb".to_string())
        );
        let r = ResultRow {
            method: "sweep-sah leaf=1 +collapse".into(),
            ..Default::default()
        };
        assert_eq!(label_parts(&r).0, "sweep-sah leaf=1");
    }
}
