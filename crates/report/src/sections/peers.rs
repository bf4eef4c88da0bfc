//! "bvhlab vs production libraries" (issue 18): per scene, each bvhlab builder beside its nearest
//! peer (binned to binned, Morton to Morton, PLOC to PLOC, SAH sweep to spatial splits), as ratios
//! of build time, SAH cost and trace speed. Peers are rows like any other (crates/peers).
use crate::plots::fmt_num;
use bvhlab_pipeline::ResultRow;
use maud::{html, Markup};

/// bvhlab builder -> the peer of the same family.
pub const PAIRS: &[(&str, &str)] = &[
    ("binned-sah", "embree-binned"),
    ("lbvh", "embree-morton"),
    ("ploc", "obvhs"),
    ("sbvh", "embree-sbvh"),
];

/// The chain standing for a builder on a scene: the first without optimizer and layout in the
/// experiment's order (its label is shown, so the reader sees which).
fn pick<'a>(rows: &[&'a ResultRow], scene: &str, builder: &str) -> Option<&'a ResultRow> {
    rows.iter().copied().find(|r| r.scene == scene && r.builder == builder && r.optimizer.is_none() && r.layout.is_none())
}

pub struct PeerPair<'a> {
    pub scene: &'a str,
    pub ours: &'a ResultRow,
    pub peer: &'a ResultRow,
}

pub fn pairs<'a>(rows: &'a [ResultRow]) -> Vec<PeerPair<'a>> {
    let all: Vec<&ResultRow> = rows.iter().filter(|r| r.valid || r.library.is_some()).collect();
    let mut scenes: Vec<&str> = Vec::new();
    for r in &all {
        if !scenes.contains(&r.scene.as_str()) {
            scenes.push(&r.scene);
        }
    }
    let mut out = Vec::new();
    for scene in scenes {
        for (ours, peer) in PAIRS {
            if let (Some(o), Some(p)) = (pick(&all, scene, ours), pick(&all, scene, peer)) {
                out.push(PeerPair { scene, ours: o, peer: p });
            }
        }
    }
    out
}

fn ratio(a: Option<f64>, b: Option<f64>) -> String {
    match (a, b) {
        (Some(a), Some(b)) if b > 0.0 && a.is_finite() && b.is_finite() => format!("{:.2}", a / b),
        _ => String::new(),
    }
}

fn num(v: Option<f64>) -> String {
    v.filter(|x| x.is_finite()).map(fmt_num).unwrap_or_default()
}

/// The table; empty markup without a pair.
pub fn table(rows: &[ResultRow]) -> Markup {
    let ps = pairs(rows);
    if ps.is_empty() {
        return html! {};
    }
    let build = |r: &ResultRow| Some(crate::analysis::total_build_seconds(r));
    html! {
        p {
            "Ratios are bvhlab / library: below 1 means bvhlab builds faster or a cheaper tree; for trace \
             speed above 1 means bvhlab traces faster. Build times are medians of the timed runs (a peer's \
             is its own library call, without the import); trace speeds are bvhlab's traversal of its own tree \
             (" code { "mrays_per_s" } ") and the library's own traversal of its tree (" code { "peer_mrays_per_s" }
             ": obvhs traces the imported tree, Embree a scene committed at the same build quality), same rays, \
             one thread when the sweep ran with " code { "--threads 1" } "."
        }
        div.wide {
            table {
                tr {
                    th { "scene" } th { "bvhlab chain" } th { "library chain" }
                    th { "build [s] bvhlab" } th { "library" } th { "ratio" }
                    th { "SAH bvhlab" } th { "library" } th { "ratio" }
                    th { "Mrays/s bvhlab" } th { "library, own traversal" } th { "ratio" }
                    th { "peer hit mismatches" }
                }
                @for p in &ps {
                    tr {
                        td { (p.ours.scene_name) }
                        td { (super::summary::build_label(p.ours)) }
                        td { (super::summary::build_label(p.peer)) " (" (p.peer.library.as_deref().unwrap_or("")) ")" }
                        td.n { (num(build(p.ours))) }
                        td.n { (num(build(p.peer))) }
                        td.n { (ratio(build(p.ours), build(p.peer))) }
                        td.n { (fmt_num(p.ours.sah_cost)) }
                        td.n { (fmt_num(p.peer.sah_cost)) }
                        td.n { (ratio(Some(p.ours.sah_cost), Some(p.peer.sah_cost))) }
                        td.n { (num(p.ours.mrays_per_s)) }
                        td.n { (num(p.peer.peer_mrays_per_s)) }
                        td.n { (ratio(p.ours.mrays_per_s, p.peer.peer_mrays_per_s)) }
                        td.n { (p.peer.peer_hit_mismatches.map(|m| m.to_string()).unwrap_or_default()) }
                    }
                }
            }
        }
    }
}
