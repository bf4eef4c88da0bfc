//! The measure stage: a ray set (thesis 4.4) traced through the final BVH, or through the layout
//! with its own traversal, timed beside bvh2 of the same BVH; primary rays leave a heat map.
use super::build::final_bvh;
use super::chain::{param, Plan};
use super::layout::LayoutStage;
use super::load::Load;
use crate::batch::Batch;
use crate::error::{Error, Result};
use crate::run::{Artifact, Files, Node, Runner, Stage, Timing};
use crate::store::Store;
use bvhlab_geom::stats::median;
use bvhlab_geom::Scene;
use bvhlab_trace::Camera;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// 2: traversal keeps a popped node whose entry equals the best t within the slab margin (ties).
/// 3: optional layout input (its own traversal, bvh2 anchor timed alternately, extra hits/tests).
/// 4: ray-triangle t in f64 (far rays could disagree with brute force in f32); axis-parallel rays
///    on a box plane are inside the slab (were culled).
/// 5: ray sets at any scale: camera and ray lengths in f64 (1e-30 and 1e30 scenes got no hits).
/// 6: layout bvh2 is its own anchor: each run is timed once and stands for both sides
///    (`bvh2_seconds == seconds`, slowdown exactly 1); timing the same traversal twice measured
///    only noise (a bvh2-vs-bvh2 slowdown of 5.1 was seen on a loaded machine).
/// 7: timed runs use the fast path (issue 19: watertight f32 test, triangles in leaf-slot order, no
///    counters; bvh4/bvh8 their SIMD traversals); counters and hits come from one untimed exact pass.
/// 8: bvh2's timed traversal reads child pairs (`bvhlab_trace::pairs`): faster, same hits.
/// 9: bvh2's timed traversal prefetches both children of a pair before its box test (faster on
///    trees beyond the caches: dragon +30 %), same hits; every timed bvh2 anchor is re-measured.
/// 10: timed runs of calls shorter than 10 ms are batched (`crate::batch`): every time is re-measured.
/// 11: bvh2's timed traversal runs in an AVX2 build where the CPU has it (same hits, ~1-2 % faster):
///    every timed bvh2 anchor is re-measured.
/// 12: bvh2's timed traversal names children by offsets in one arena of pairs and triangles
///    (`bvhlab_trace::pairs::Arena`: same hits, 5-9 % faster): every timed bvh2 anchor is re-measured.
/// 13: the timed layouts' memory is advised for transparent huge pages (`bvhlab_trace::thp`, as
///    Embree's BVHs are; dragon +8-14 %, same hits): every timed anchor is re-measured.
/// 14: the compressed layouts and cwbvh's leaf table on huge pages too, buffers collapsed once
///    filled, and Embree's peer trace allocating its hits inside its timed region (changed on main
///    after 13 was first used): every timed value is re-measured.
pub const MEASURE_VERSION: u32 = 14;

/// A ray set of the measure stage (thesis 4.4).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RaySpec {
    Primary {
        width: u32,
        height: u32,
    },
    /// Shadow rays from the primary hits of a `width x height` image to a light above the camera.
    Shadow {
        width: u32,
        height: u32,
    },
    Random {
        count: u32,
    },
}

pub const DEFAULT_RESOLUTION: u32 = 256;
pub const DEFAULT_RANDOM_RAYS: u32 = 100_000;
/// Seed of the random ray set; part of the measure key.
pub const RANDOM_SEED: u64 = 0x5eed_b71a;

impl RaySpec {
    /// `primary[:WxH]`, `shadow[:WxH]`, `random[:COUNT]`.
    pub fn parse(s: &str) -> Result<RaySpec> {
        let bad = |why: &str| {
            Error::input(format!(
                "bad ray set `{s}`: {why}; expected primary[:WIDTHxHEIGHT], shadow[:WIDTHxHEIGHT] or random[:COUNT]"
            ))
        };
        let (kind, arg) = match s.split_once(':') {
            Some((k, a)) => (k, Some(a)),
            None => (s, None),
        };
        let res = |a: Option<&str>| -> Result<(u32, u32)> {
            let Some(a) = a else {
                return Ok((DEFAULT_RESOLUTION, DEFAULT_RESOLUTION));
            };
            let (w, h) = a
                .split_once('x')
                .ok_or_else(|| bad("resolution must be WIDTHxHEIGHT"))?;
            let p = |v: &str| {
                v.trim()
                    .parse::<u32>()
                    .ok()
                    .filter(|&n| (1..=16384).contains(&n))
            };
            match (p(w), p(h)) {
                (Some(w), Some(h)) => Ok((w, h)),
                _ => Err(bad("width and height must be integers in 1..=16384")),
            }
        };
        match kind.trim() {
            "primary" => res(arg).map(|(width, height)| RaySpec::Primary { width, height }),
            "shadow" => res(arg).map(|(width, height)| RaySpec::Shadow { width, height }),
            "random" => match arg {
                None => Ok(RaySpec::Random {
                    count: DEFAULT_RANDOM_RAYS,
                }),
                Some(a) => match a.trim().parse::<u32>() {
                    Ok(n) if n >= 1 => Ok(RaySpec::Random { count: n }),
                    _ => Err(bad("count must be a positive integer")),
                },
            },
            _ => Err(bad("unknown kind")),
        }
    }
    pub fn canonical(&self) -> String {
        match self {
            RaySpec::Primary { width, height } => format!("primary:{width}x{height}"),
            RaySpec::Shadow { width, height } => format!("shadow:{width}x{height}"),
            RaySpec::Random { count } => format!("random:{count}"),
        }
    }
}

pub fn camera_canonical(c: &Camera) -> String {
    let v = |v: bvhlab_geom::Vec3| format!("{},{},{}", v.x, v.y, v.z);
    format!(
        "eye={};target={};up={};fov={}",
        v(c.eye),
        v(c.target),
        v(c.up),
        c.fov_y_deg
    )
}

/// Result of the measure stage (`measure/<key>.sum`; there is no larger artifact).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MeasureSummary {
    pub rays_kind: String,
    pub rays: u64,
    pub hits: u64,
    pub total_steps: u64,
    pub total_intersections: u64,
    pub seconds: Vec<f64>,
    pub median_seconds: f64,
    /// Heat map file name relative to the store root, for primary rays.
    pub heatmap: Option<String>,
    /// With a layout stage: the layout traced (counters and `seconds` are its own traversal's).
    #[serde(default)]
    pub layout: Option<String>,
    /// With a layout stage: bvh2 of the same final BVH on the same rays, each run alternated
    /// with a run of the layout.
    #[serde(default)]
    pub bvh2_seconds: Option<Vec<f64>>,
    #[serde(default)]
    pub bvh2_median_seconds: Option<f64>,
    /// With a layout stage: (layout - uncompressed of the same topology) steps and triangle tests
    /// per ray (0 when the layout is uncompressed).
    #[serde(default)]
    pub extra_box_hits_per_ray: Option<f64>,
    #[serde(default)]
    pub extra_tests_per_ray: Option<f64>,
    /// A peer builder's own traversal of the same rays (obvhs: of the same tree; Embree: of its
    /// scene committed at the same build quality), one thread, `repeat` runs.
    #[serde(default)]
    pub peer: Option<PeerMeasure>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PeerMeasure {
    /// Library and version, e.g. `Embree 3.13.5`.
    pub library: String,
    pub seconds: Vec<f64>,
    pub median_seconds: f64,
    /// Untimed set-up of the traversal (Embree's scene commit).
    pub setup_seconds: f64,
    /// Rays whose peer hit disagrees with bvhlab's exact one (another triangle at a t more than
    /// 1e-4 relative away, or a hit against a miss): the oracle check of the peer's traversal.
    pub hit_mismatches: u64,
}

/// Per-run slowdowns of alternated runs: `layout[i] / bvh2[i]` (run i of each side were timed
/// back to back). Empty when the counts differ or a bvh2 run is not positive.
pub fn paired_ratios(layout: &[f64], bvh2: &[f64]) -> Vec<f64> {
    if layout.len() != bvh2.len() || bvh2.iter().any(|&b| !(b > 0.0)) {
        return Vec::new();
    }
    layout.iter().zip(bvh2).map(|(a, b)| a / b).collect()
}

/// Random rays (thesis 4.4) on a sphere around the scene box centre enclosing every triangle
/// centroid.
pub(crate) fn random_ray_set(scene: &Scene, count: u32, seed: u64) -> Vec<bvhlab_trace::Ray> {
    let bounds = scene.bounds();
    let r = bounds.enclosing_radius(scene.triangles.iter().map(|t| t.bounds().center()));
    bvhlab_trace::random_rays(&bounds, r, count as usize, seed)
}

pub(crate) struct Measure;

impl Stage for Measure {
    const NAME: &'static str = "measure";
    const TIMING: Timing = Timing::Trace;
    const FULL: bool = false;
    type Full = MeasureSummary;

    fn declare(rt: &mut Runner, plan: &mut Plan) -> Result<Option<Node>> {
        let Some(rays) = plan.spec.rays else {
            return Ok(None);
        };
        let camera = plan.spec.camera.as_ref().map(camera_canonical);
        let mut p: BTreeMap<String, String> = [
            param("rays", rays.canonical()),
            param("camera", camera.unwrap_or_else(|| "auto".into())),
            param("repeat", plan.spec.repeat),
        ]
        .into();
        if let RaySpec::Random { .. } = rays {
            p.insert("seed".into(), RANDOM_SEED.to_string());
        }
        let fin = plan.final_bvh();
        let mut inputs = vec![("load", plan.need("load")?.key), (fin.stage, fin.key)];
        if let Some(l) = plan.node("layout") {
            inputs.push(("layout", l.key));
        }
        Ok(Some(Node::new(Self::NAME, rt.versions.measure, p, inputs)))
    }


    /// Primary rays leave a heat map the report copies: checked like the summary.
    fn also(plan: &Plan) -> &'static [&'static str] {
        match plan.spec.rays {
            Some(RaySpec::Primary { .. }) => &["png"],
            _ => &[],
        }
    }

    fn compute(rt: &mut Runner, plan: &Plan, node: &Node) -> Result<(MeasureSummary, Files)> {
        let rays_spec = plan
            .spec
            .rays
            .ok_or_else(|| Error::internal("chain has no ray set"))?;
        let scene = rt.full::<Load>(plan)?;
        let input = final_bvh(rt, plan)?;
        let layout = match plan.node("layout") {
            Some(_) => Some(rt.full::<LayoutStage>(plan)?),
            None => None,
        };
        let bvh = &input.bvh;
        let tris = &scene.triangles;
        let bounds = scene.bounds();
        let camera = plan
            .spec
            .camera
            .unwrap_or_else(|| Camera::from_bounds(&bounds));
        let rays = match rays_spec {
            RaySpec::Primary { width, height } => {
                bvhlab_trace::primary_rays(&camera, width, height)
            }
            RaySpec::Shadow { width, height } => {
                // Shadow rays start at the primary hits (thesis 4.4), so trace primary rays first
                // (through the flat BVH also with a layout: every layout finds the same hits).
                let primary = bvhlab_trace::primary_rays(&camera, width, height);
                let st = bvhlab_trace::trace(bvh, tris, &primary);
                let t: Vec<f32> = st.hits.iter().map(|h| h.t).collect();
                bvhlab_trace::shadow_rays(&primary, &t, camera.light(&bounds))
            }
            RaySpec::Random { count } => random_ray_set(&scene, count, RANDOM_SEED),
        };
        // Counters and hits from one untimed pass with the exact (f64) test; the timed runs use
        // the fast path (issue 19: statistics must not slow what is timed): bvh2, bvh4 and bvh8
        // with their watertight f32 traversals, the compressed layouts with their own.
        let st = match &layout {
            None => bvhlab_trace::trace(bvh, tris, &rays),
            Some(l) => l.layout.trace(tris, &rays),
        };
        // Prepared outside the timed region (triangles copied into leaf-slot order).
        let fast_bvh2 = bvhlab_trace::FastBvh2::new(bvh, tris);
        let timed = layout.as_ref().map(|l| l.layout.timed(tris));
        let mut seconds = Vec::new();
        let mut bvh2_seconds = Vec::new();
        // Short traces are timed in batches of calls (`crate::batch`), each side its own.
        let (mut layout_batch, mut bvh2_batch) = (Batch::new(), Batch::new());
        for run in 0..plan.spec.repeat {
            match (&layout, &timed) {
                (Some(l), Some(tl)) if !matches!(l.layout, bvhlab_layout::Layout::Bvh2(_)) => {
                    // The bvh2 anchor runs beside the layout on the same rays, alternating which
                    // goes first, so slowdown compares runs under the same machine conditions.
                    let mut time_layout = || -> Result<()> {
                        let (_, s) = layout_batch.run(|| Ok((std::hint::black_box(tl.hits(tris, &rays)), None)))?;
                        seconds.push(s);
                        Ok(())
                    };
                    let mut time_bvh2 = || -> Result<()> {
                        let (_, s) = bvh2_batch.run(|| Ok((std::hint::black_box(fast_bvh2.hits(&rays)), None)))?;
                        bvh2_seconds.push(s);
                        Ok(())
                    };
                    if run % 2 == 0 {
                        time_layout()?;
                        time_bvh2()?;
                    } else {
                        time_bvh2()?;
                        time_layout()?;
                    }
                }
                _ => {
                    // No layout, or bvh2 against bvh2: the same traversal of the same tree, one
                    // timing per run stands for both sides (slowdown exactly 1 by construction;
                    // timing it twice measured only noise: 5.1 was seen on a loaded machine).
                    let (_, s) = bvh2_batch.run(|| Ok((std::hint::black_box(fast_bvh2.hits(&rays)), None)))?;
                    seconds.push(s);
                    if layout.is_some() {
                        bvh2_seconds.push(s);
                    }
                }
            }
        }
        if seconds.is_empty() {
            return Err(Error::internal("repeat = 0"));
        }
        let peer = match rt.registry.get(&plan.resolved.builder)?.peer {
            Some(p) => Some(peer_measure(p, bvh, tris, &rays, &st.hits, plan)?),
            None => None,
        };
        // Accuracy of compression: against the uncompressed layout of the same topology (untimed).
        let extras = layout
            .as_ref()
            .map(|l| match l.layout.uncompressed(bvh, tris) {
                None => (0.0, 0.0),
                Some(u) => {
                    let r = u.trace(tris, &rays);
                    let n = rays.len().max(1) as f64;
                    (
                        (st.total_steps as f64 - r.total_steps as f64) / n,
                        (st.total_intersections as f64 - r.total_intersections as f64) / n,
                    )
                }
            });
        let mut files = BTreeMap::new();
        let heatmap = match rays_spec {
            RaySpec::Primary { width, height } => {
                let path = rt.store.path(Self::NAME, &node.key, "png");
                let bytes = crate::heatmap::heatmap_png(&st.steps, width, height)
                    .map_err(|e| Error::internal(format!("{}: {e}", path.display())))?;
                Store::write_atomic(&path, &bytes)?;
                files.insert("png".to_string(), blake3::hash(&bytes).to_hex().to_string());
                Some(format!("measure/{}.png", node.key.hex()))
            }
            _ => None,
        };
        let m = MeasureSummary {
            rays_kind: rays_spec.canonical(),
            rays: rays.len() as u64,
            hits: st.hit_count,
            total_steps: st.total_steps,
            total_intersections: st.total_intersections,
            median_seconds: median(&seconds),
            seconds,
            heatmap,
            layout: layout.as_ref().map(|l| l.summary.layout.clone()),
            bvh2_median_seconds: layout.as_ref().map(|_| median(&bvh2_seconds)),
            bvh2_seconds: layout.as_ref().map(|_| bvh2_seconds),
            extra_box_hits_per_ray: extras.map(|e| e.0),
            extra_tests_per_ray: extras.map(|e| e.1),
            peer,
        };
        Ok((m, files))
    }
}

/// The peer's own traversal, `repeat` times, checked against bvhlab's exact hits.
fn peer_measure(
    p: bvhlab_peers::Peer,
    bvh: &bvhlab_bvh::Bvh,
    tris: &[bvhlab_geom::Triangle],
    rays: &[bvhlab_trace::Ray],
    ours: &[bvhlab_trace::Hit],
    plan: &Plan,
) -> Result<PeerMeasure> {
    let fail = |e: String| Error::input(format!("{} traversal on {}: {e}", p.method().name, plan.spec.scene));
    let mut seconds = Vec::new();
    let mut first = None;
    let mut batch = Batch::new();
    for _ in 0..plan.spec.repeat {
        let (t, s) = batch.run(|| {
            let t = p.trace(bvh, tris, rays).map_err(fail)?;
            let s = t.seconds;
            Ok((t, Some(s)))
        })?;
        seconds.push(s);
        first.get_or_insert(t);
    }
    let t = first.ok_or_else(|| Error::internal("repeat = 0"))?;
    let hit_mismatches = ours
        .iter()
        .zip(&t.hits)
        .filter(|(o, h)| !bvhlab_peers::hits_agree(o, h, 1e-4))
        .count() as u64;
    Ok(PeerMeasure {
        library: p.library(),
        median_seconds: median(&seconds),
        seconds,
        setup_seconds: t.setup_seconds,
        hit_mismatches,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ray_specs() {
        assert_eq!(
            RaySpec::parse("primary:800x600").unwrap(),
            RaySpec::Primary {
                width: 800,
                height: 600
            }
        );
        assert_eq!(
            RaySpec::parse("primary").unwrap().canonical(),
            "primary:256x256"
        );
        assert_eq!(
            RaySpec::parse("random:1000").unwrap(),
            RaySpec::Random { count: 1000 }
        );
        assert_eq!(
            RaySpec::parse("shadow:4x2").unwrap().canonical(),
            "shadow:4x2"
        );
        for bad in [
            "primary:0x5",
            "random:-3",
            "laser",
            "primary:12",
            "random:x",
        ] {
            let e = RaySpec::parse(bad).unwrap_err();
            assert_eq!(e.exit_code(), 2, "{bad}");
        }
    }

    #[test]
    fn paired() {
        assert_eq!(paired_ratios(&[2.0, 3.0], &[1.0, 2.0]), vec![2.0, 1.5]);
        assert!(paired_ratios(&[2.0, 3.0], &[1.0]).is_empty());
        assert!(paired_ratios(&[2.0], &[0.0]).is_empty());
    }
}

impl Artifact for MeasureSummary {
    type Sum = MeasureSummary;
    fn summary(&self) -> MeasureSummary {
    self.clone()
    }
}
