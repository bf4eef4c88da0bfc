//! Per-scene charts: build time vs SAH cost (Pareto), SAH cost per method, traversal steps and
//! intersections per ray. One point or bar per build chain: the layouts of one build share its
//! tree, so they are charted in the layouts section, not stacked on the build's point.
use super::summary::build_label;
use crate::analysis::{self, method_key};
use crate::plots::bars::{Bar, BarsFigure, Panel};
use crate::plots::pareto::{ParetoFigure, ParetoPoint};
use crate::plots::Plot;
use crate::sweeps::PlotFn;
use crate::{machine_name, TimingGroup};
use bvhlab_pipeline::ResultRow;

fn first_per<'a>(rows: &[&'a ResultRow], key: impl Fn(&ResultRow) -> String) -> Vec<&'a ResultRow> {
    let mut seen = std::collections::HashSet::new();
    rows.iter().copied().filter(|r| seen.insert(key(r))).collect()
}

/// (Pareto plots, SAH bar charts, per-ray bar charts).
pub fn per_scene(
    rows: &[ResultRow],
    build_groups: &[TimingGroup],
    multi_build: bool,
    plot: &mut PlotFn,
    problems: &mut Vec<String>,
) -> (Vec<Plot>, Vec<Plot>, Vec<Plot>) {
    let mut scenes: Vec<&str> = Vec::new();
    for r in rows {
        if !scenes.contains(&r.scene.as_str()) {
            scenes.push(&r.scene);
        }
    }
    let mut builds_all: Vec<String> = Vec::new();
    for r in rows {
        let k = build_label(r).to_string();
        if !builds_all.contains(&k) {
            builds_all.push(k);
        }
    }
    let color_of = |r: &ResultRow| builds_all.iter().position(|b| b == build_label(r)).unwrap_or(0);
    let (mut pareto, mut sah, mut rays) = (Vec::new(), Vec::new(), Vec::new());
    // With more than a few scenes, the SAH costs are one figure of small multiples (a panel per
    // scene, the build chains named once) instead of a figure per scene.
    let mut multiples: Vec<Panel> = Vec::new();
    for scene in &scenes {
        let scene_rows: Vec<&ResultRow> = rows.iter().filter(|r| r.scene == *scene).collect();
        let name = scene_rows[0].scene_name.as_str();
        let chains = first_per(&scene_rows, method_key);
        // With a focus box (far outlier, huge ground plane) the object's cost is what matters; the
        // whole-scene cost is still in the bar chart below.
        let focus = chains.iter().any(|r| r.focus_sah_cost.is_some_and(f64::is_finite));
        let cost_label = if focus { "focus SAH cost" } else { "SAH cost" };
        // Build time only: grouped by the construction stages' model.
        for g in build_groups {
            let timed: Vec<&ResultRow> = g.rows.iter().copied().filter(|r| r.scene == *scene).collect();
            let chains = first_per(&timed, method_key);
            if chains.is_empty() {
                continue;
            }
            let fig = ParetoFigure {
                scene: name.to_string(),
                cost_label: cost_label.to_string(),
                time_label: if chains.iter().any(|r| r.optimizer.is_some()) {
                    "encode + build + optimize + compact time [s]".to_string()
                } else {
                    "encode + build + compact time [s]".to_string()
                },
                points: chains
                    .iter()
                    .map(|r| ParetoPoint {
                        label: build_label(r).to_string(),
                        method_index: color_of(r),
                        // Encode + build + optimize + compaction: Morton builders pay for their
                        // codes and sort, optimizer chains for their passes.
                        seconds: analysis::total_build_seconds(r),
                        seconds_range: analysis::total_build_range(r),
                        sah_cost: if focus { r.focus_sah_cost.unwrap_or(f64::NAN) } else { r.sah_cost },
                        peer: r.library.is_some(),
                    })
                    .collect(),
            };
            let (stem, tag) = if multi_build {
                (format!("pareto_{name}_{}", machine_name(&g.machine)), format!(" [{}]", machine_name(&g.machine)))
            } else {
                (format!("pareto_{name}"), String::new())
            };
            pareto.extend(plot(&fig, &stem, &format!("{name}: build time vs {cost_label}{tag}"), problems));
        }

        let bars = |v: &dyn Fn(&ResultRow) -> Option<f64>, rs: &[&ResultRow], label: &dyn Fn(&ResultRow) -> String| -> Vec<Bar> {
            rs.iter()
                .filter_map(|r| v(r).map(|value| Bar { label: label(r), value, color_index: color_of(r) }))
                .collect()
        };
        let blabel = |r: &ResultRow| build_label(r).to_string();
        if scenes.len() > SMALL_MULTIPLES_FROM {
            let cost = |r: &ResultRow| if focus { r.focus_sah_cost.unwrap_or(f64::NAN) } else { r.sah_cost };
            multiples.push(Panel {
                title: format!("{name}{}", if focus { " (focus SAH)" } else { "" }),
                x_desc: cost_label.into(),
                bars: builds_all
                    .iter()
                    .enumerate()
                    .map(|(i, b)| Bar {
                        label: b.clone(),
                        value: chains.iter().find(|r| build_label(r) == b).map_or(f64::NAN, |r| cost(r)),
                        color_index: i,
                    })
                    .collect(),
            });
        } else {
        let fig = BarsFigure {
            shared_labels: false,
            caption: format!("{name}: SAH cost per method"),
            panels: {
                let mut p = vec![Panel {
                    title: format!("c_T = {}, c_I = {}", scene_rows[0].c_t, scene_rows[0].c_i),
                    x_desc: "SAH cost".into(),
                    bars: bars(&|r| Some(r.sah_cost), &chains, &blabel),
                }];
                if focus {
                    p.push(Panel {
                        title: "focus box: object subtree".into(),
                        x_desc: "focus SAH cost".into(),
                        bars: bars(&|r| r.focus_sah_cost, &chains, &blabel),
                    });
                }
                p
            },
        };
        sah.extend(plot(&fig, &format!("sah_{name}"), &format!("{name}: SAH cost"), problems));
        }

        let mut kinds: Vec<&str> = Vec::new();
        for k in scene_rows.iter().filter_map(|r| r.rays_kind.as_deref()) {
            if !kinds.contains(&k) {
                kinds.push(k);
            }
        }
        for kind in kinds {
            let kind_rows: Vec<&ResultRow> =
                scene_rows.iter().copied().filter(|r| r.rays_kind.as_deref() == Some(kind)).collect();
            let kind_rows = first_per(&kind_rows, |r| r.method.clone());
            let mlabel = |r: &ResultRow| r.method.clone();
            let steps = bars(&|r| r.traversal_steps_per_ray, &kind_rows, &mlabel);
            let isects = bars(&|r| r.intersections_per_ray, &kind_rows, &mlabel);
            if steps.is_empty() && isects.is_empty() {
                continue;
            }
            let fig = BarsFigure {
                shared_labels: false,
                caption: format!("{name}, {kind} rays"),
                panels: vec![
                    Panel { title: "traversal steps per ray".into(), x_desc: "steps / ray".into(), bars: steps },
                    Panel { title: "intersections per ray".into(), x_desc: "intersections / ray".into(), bars: isects },
                ],
            };
            rays.extend(plot(&fig, &format!("rays_{name}_{kind}"), &format!("{name}: {kind} rays"), problems));
        }
    }
    if !multiples.is_empty() {
        let c = (rows[0].c_t, rows[0].c_i);
        let fig = BarsFigure {
            caption: format!("SAH cost per build chain and scene (c_T = {}, c_I = {})", c.0, c.1),
            panels: multiples,
            shared_labels: true,
        };
        sah.extend(plot(&fig, "sah_all_scenes", "SAH cost per build chain, all scenes", problems));
    }
    (pareto, sah, rays)
}

/// More scenes than this: SAH costs as small multiples.
const SMALL_MULTIPLES_FROM: usize = 2;
