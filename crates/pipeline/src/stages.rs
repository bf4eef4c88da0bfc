//! Stage definitions: versions, the artifacts each stage stores, and the chain description.
//!
//! Stages: `load` (scene), `encode` (Morton / EMC codes and the sorted primitive order, for the
//! bottom-up builders), `build` (BVH), `optimize` (ibo or Kensler rotations on the built BVH),
//! `compact` (SAH collapse of the built or optimized BVH; after the optimizer, as Bittner 2013 3.6
//! orders them), `measure` (ray set traced through the final BVH), `focus` (SAH cost around a
//! focus box in the final BVH), `layout` (the final BVH, or the scene for octrees, stored in a
//! memory layout of Kilian 2021, traced by measure with its own traversal). Bump a stage's version when its implementation changes
//! what it produces: its artifacts and everything downstream get new keys.
use crate::error::{Error, Result};
use bvhlab_bvh::{Aabb, Bvh, CostParams, Metrics};
use bvhlab_geom::{LoadError, Scene, Triangle};
use bvhlab_layout::{Layout, LayoutSpec, Memory};
use bvhlab_morton::{EncodeConfig, Encoding};
use bvhlab_trace::Camera;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::PathBuf;

/// 2: the summary carries `precision_loss` (issue 15).
pub const LOAD_VERSION: u32 = 2;
/// 3: EMC size of boxes spanning more than the f32 range (issue 15).
pub const ENCODE_VERSION: u32 = 3;
/// 2: bottom-up builders (lbvh, aac, ploc) and the reworked (parallel) binned SAH.
/// 3: scale-free costs (issue 15): SAH areas and costs in f64, binned SAH bins in f64 and its
///    "centroids too close" threshold relative to the node box, PLOC/AAC distances of boxes
///    prescaled by a power of two; the SAH leaf test splits on equal costs (as the compaction
///    keeps such subtrees).
pub const BUILD_VERSION: u32 = 3;
/// 2: areas of boxes spanning more than the f32 range (issue 15).
pub const COMPACT_VERSION: u32 = 2;
/// 2: f64 areas in the insertion search and the measures (issue 15).
pub const OPTIMIZE_VERSION: u32 = 2;
/// 2: traversal keeps a popped node whose entry equals the best t within the slab margin (ties).
/// 3: optional layout input (its own traversal, bvh2 anchor timed alternately, extra hits/tests).
/// 4: ray-triangle t in f64 (far rays could disagree with brute force in f32); axis-parallel rays
///    on a box plane are inside the slab (were culled).
/// 5: ray sets at any scale: camera and ray lengths in f64 (1e-30 and 1e30 scenes got no hits).
/// 6: layout bvh2 is its own anchor: each run is timed once and stands for both sides
///    (`bvh2_seconds == seconds`, slowdown exactly 1); timing the same traversal twice measured
///    only noise (a bvh2-vs-bvh2 slowdown of 5.1 was seen on a loaded machine).
pub const MEASURE_VERSION: u32 = 6;
pub const FOCUS_VERSION: u32 = 1;
/// 3: layout names `qbvh` -> `qbvh_chunks`, `octree1` -> `octree_1bit` (issue 17); an `auto`
///    artifact records the chosen candidate by name. Layout contents are unchanged.
pub const LAYOUT_VERSION: u32 = 3;

/// Stage implementation versions; injectable so tests can simulate a version bump.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Versions {
    pub load: u32,
    pub encode: u32,
    pub build: u32,
    pub compact: u32,
    pub optimize: u32,
    pub measure: u32,
    pub focus: u32,
    pub layout: u32,
}

impl Default for Versions {
    fn default() -> Self {
        Versions {
            load: LOAD_VERSION,
            encode: ENCODE_VERSION,
            build: BUILD_VERSION,
            compact: COMPACT_VERSION,
            optimize: OPTIMIZE_VERSION,
            measure: MEASURE_VERSION,
            focus: FOCUS_VERSION,
            layout: LAYOUT_VERSION,
        }
    }
}

/// The functions stages call from other crates; injectable so the cache logic can be tested on its
/// own (and so a stage can be swapped without touching the runner).
#[derive(Clone, Copy)]
pub struct Ops {
    pub load: fn(&str) -> Result<Scene, LoadError>,
    /// Canonical form of a generator spec (after `gen:`), so equivalent spellings share a key.
    pub canonical_gen: fn(&str) -> Result<String, LoadError>,
    pub metrics: fn(&Bvh, CostParams) -> Metrics,
    pub validate: fn(&Bvh, &[Aabb]) -> Result<(), String>,
    pub collapse: fn(&Bvh, CostParams) -> Bvh,
    /// `bvhlab_morton::encode_cells`: the config plus the occupation grid's in-cell frame.
    pub encode:
        fn(&[Aabb], &[bvhlab_geom::Vec3], &EncodeConfig, bvhlab_morton::CellFrame) -> Encoding,
    /// `bvhlab_layout::build_until` (None: no deadline).
    pub layout:
        fn(&LayoutSpec, &Bvh, &[Triangle], Option<std::time::Instant>) -> Result<Layout, String>,
}

impl Default for Ops {
    fn default() -> Self {
        Ops {
            load: bvhlab_geom::load_scene,
            canonical_gen: bvhlab_geom::gen::canonical_spec,
            metrics: bvhlab_bvh::metrics,
            validate: bvhlab_bvh::validate,
            collapse: bvhlab_bvh::collapse::collapse,
            encode: bvhlab_morton::encode_cells,
            layout: bvhlab_layout::build_until,
        }
    }
}

/// Where a scene comes from.
#[derive(Clone, Debug, PartialEq)]
pub enum SceneSource {
    /// `gen:` spec (the part after `gen:`).
    Gen(String),
    File(PathBuf),
}

impl SceneSource {
    pub fn parse(spec: &str) -> SceneSource {
        match spec.strip_prefix("gen:") {
            Some(rest) => SceneSource::Gen(rest.to_string()),
            None => SceneSource::File(PathBuf::from(spec)),
        }
    }
    /// What `load_scene` takes.
    pub fn load_spec(&self) -> String {
        match self {
            SceneSource::Gen(s) => format!("gen:{s}"),
            SceneSource::File(p) => p.to_string_lossy().to_string(),
        }
    }
}

/// Short name for plots: file stem (without .obj / .obj.gz) or the generator spec.
pub fn scene_name(spec: &str) -> String {
    match spec.strip_prefix("gen:") {
        Some(rest) => rest.to_string(),
        None => {
            let file = std::path::Path::new(spec)
                .file_name()
                .map(|s| s.to_string_lossy().to_string());
            let f = file.unwrap_or_else(|| spec.to_string());
            f.trim_end_matches(".gz")
                .trim_end_matches(".obj")
                .to_string()
        }
    }
}

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

/// One chain: scene -> (encode) -> build -> optional compaction -> optional measurement / focus.
#[derive(Clone, Debug, PartialEq)]
pub struct ChainSpec {
    /// Scene spec as the user gave it (row `scene`).
    pub scene: String,
    pub source: SceneSource,
    pub build: String,
    /// Encoder for code-using builders (None: `morton`); an error with a top-down builder.
    pub encode: Option<String>,
    /// Optimizer run on the built BVH before the compaction (`ibo`, `kensler-hc`, `kensler-sa`).
    pub optimize: Option<String>,
    /// User-given parameters (builder params, c_t / c_i and encoder params, routed by name),
    /// validated by the registry.
    pub params: BTreeMap<String, String>,
    /// Default cost constants (experiment `[cost]`), overridden by `params`.
    pub cost: CostParams,
    /// `none` or `collapse`.
    pub compact: String,
    pub rays: Option<RaySpec>,
    /// None: derived from the scene bounds.
    pub camera: Option<Camera>,
    /// Timed runs per stage (median reported).
    pub repeat: u32,
    /// Focus box: triangles whose centroid lies inside (bounds included) form the focus object.
    pub focus: Option<Aabb>,
    /// Layout spec `NAME[:k=v,...]` (`bvh2`, `qbvh_chunks`, `octree`, `octree_1bit`, `auto`); None: no layout
    /// stage, measure traces the flat BVH.
    pub layout: Option<String>,
}

impl ChainSpec {
    pub fn new(scene: &str, build: &str) -> ChainSpec {
        ChainSpec {
            scene: scene.to_string(),
            source: SceneSource::parse(scene),
            build: build.to_string(),
            encode: None,
            optimize: None,
            params: BTreeMap::new(),
            cost: CostParams::default(),
            compact: "none".into(),
            rays: None,
            camera: None,
            repeat: 5,
            focus: None,
            layout: None,
        }
    }
}

pub const COMPACT_METHODS: [&str; 2] = ["none", "collapse"];

pub fn check_compact(name: &str) -> Result<()> {
    if COMPACT_METHODS.contains(&name) {
        Ok(())
    } else {
        Err(Error::input(format!(
            "unknown compaction `{name}`; valid: {}",
            COMPACT_METHODS.join(", ")
        )))
    }
}

/// Small summary of a loaded scene (`load/<key>.sum`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SceneSummary {
    pub triangles: u64,
    pub dropped_triangles: u64,
    pub bounds: Aabb,
    /// `Scene::precision_loss`: f32 spacing at the largest coordinate over the median edge length.
    pub precision_loss: f64,
}

/// Above this `precision_loss` (f32 spacing at the scene's largest coordinate > 1 % of its median
/// edge) rows carry a warning. Measured (tests/scale.rs): scenes moved from the origin keep every
/// BVH's SAH within 2 % up to it and not beyond (city at 0.018: binned -14 %, bonsai +60 %). The
/// conference room as shipped is at 0.0101: half its edges are below 1e-5 of its diagonal.
pub const PRECISION_LOSS_WARN: f64 = 0.01;

/// The warning for a scene whose coordinates f32 can no longer resolve finely enough.
pub fn precision_warning(scene: &str, loss: f64) -> Option<String> {
    (loss > PRECISION_LOSS_WARN).then(|| {
        format!(
            "{scene}: f32 precision: at the largest coordinate, f32 values are {:.3} median edge lengths apart \
             (warned from {PRECISION_LOSS_WARN}: scenes moved that far from the origin changed SAH costs by more than 2 % \
             in tests); costs and hits are those of the rounded vertices",
            loss
        )
    })
}

/// Summary of a BVH-producing stage (`build`, `compact`): metrics, validity, hash and timings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BvhSummary {
    pub metrics: Metrics,
    pub valid: bool,
    pub invalid_reason: Option<String>,
    /// blake3 of `Bvh::canonical_bytes`.
    pub bvh_hash: String,
    /// Seconds of each of the `repeat` runs.
    pub seconds: Vec<f64>,
    pub median_seconds: f64,
}

/// Full artifact of a BVH-producing stage (`<key>.bin`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BvhArtifact {
    pub bvh: Bvh,
    pub summary: BvhSummary,
}

/// What the optimize stage keeps beside its BVH (`optimize/<key>.opt`): the pass-by-pass trace the
/// report draws convergence curves from, and why the optimizer stopped.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct OptimizeInfo {
    /// Trace of the first timed run (later runs repeat the same tree; only their times differ).
    pub trace: Vec<bvhlab_opt::PassRecord>,
    /// `converged`, `max_passes` or `max_seconds`.
    pub stop: String,
    /// Pass whose tree was returned (the best one with `keep_best`).
    pub returned_pass: u32,
}

/// Summary of the encode stage (`encode/<key>.sum`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EncodeSummary {
    pub code_bits: u32,
    pub duplicate_fraction: f64,
    /// Bit layout, most significant bit first (`Encoding::layout`).
    pub layout: String,
    /// Seconds of each of the `repeat` runs of `encode()` (codes + sort).
    pub seconds: Vec<f64>,
    pub median_seconds: f64,
}

/// Full artifact of the encode stage (`encode/<key>.bin`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EncodeArtifact {
    pub encoding: Encoding,
    pub summary: EncodeSummary,
}

/// Result of the focus stage (`focus/<key>.sum`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FocusSummary {
    /// Triangles whose centroid lies in the focus box.
    pub triangles: u64,
    /// `bvhlab_bvh::focus::focus_cost`; None when no triangle is in focus.
    pub sah_cost: Option<f64>,
}

/// Parses `minx,miny,minz,maxx,maxy,maxz` (the CLI's `--focus`).
pub fn parse_focus(s: &str) -> Result<Aabb> {
    let v: Vec<f32> = s
        .split(',')
        .map(|x| x.trim().parse::<f32>())
        .collect::<Result<_, _>>()
        .map_err(|_| {
            Error::input(format!(
                "bad focus box `{s}`: expected six numbers minx,miny,minz,maxx,maxy,maxz"
            ))
        })?;
    if v.len() != 6 {
        return Err(Error::input(format!(
            "bad focus box `{s}`: expected six numbers minx,miny,minz,maxx,maxy,maxz, got {}",
            v.len()
        )));
    }
    focus_box([v[0], v[1], v[2]], [v[3], v[4], v[5]])
        .map_err(|why| Error::input(format!("bad focus box `{s}`: {why}")))
}

/// A focus box from its corners: finite, `min <= max` on every axis (a flat box is allowed).
pub fn focus_box(min: [f32; 3], max: [f32; 3]) -> Result<Aabb, String> {
    if min.iter().chain(max.iter()).any(|x| !x.is_finite()) {
        return Err("corners must be finite".into());
    }
    if (0..3).any(|i| min[i] > max[i]) {
        return Err(format!(
            "min {min:?} must not exceed max {max:?} on any axis"
        ));
    }
    Ok(Aabb::new(
        bvhlab_geom::Vec3::from(min),
        bvhlab_geom::Vec3::from(max),
    ))
}

/// Canonical text of a focus box for keys: `min=x,y,z;max=x,y,z` (shortest round-trip floats).
pub fn focus_canonical(b: &Aabb) -> String {
    let v = |v: bvhlab_geom::Vec3| format!("{},{},{}", v.x + 0.0, v.y + 0.0, v.z + 0.0);
    format!("min={};max={}", v(b.min), v(b.max))
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
}

/// A layout request: a layout with its parameters, or the `auto` search (Kilian 2021 layouts; the
/// chosen one then behaves as if it had been given).
#[derive(Clone, Debug, PartialEq)]
pub enum LayoutRequest {
    Fixed(LayoutSpec),
    Auto(AutoSpec),
}

/// `auto:max_slowdown=X,rays=N,budget=B`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AutoSpec {
    /// Largest accepted trace-time ratio against bvh2 of the same BVH (bvh2 always qualifies).
    pub max_slowdown: f64,
    /// Random rays the candidates are timed on.
    pub rays: u32,
    /// Time the search may spend, in multiples of one bvh2 trace of those rays (timed at the
    /// start of the search): once spent, no further candidate is built or timed.
    pub budget: f64,
}

pub const AUTO_MAX_SLOWDOWN: f64 = 1.25;
pub const AUTO_RAYS: u32 = 20_000;
pub const AUTO_BUDGET: f64 = 10.0;
/// Seed of the auto search's ray sample (part of its key through `rays`/the candidate list).
pub const AUTO_SEED: u64 = 0xa070_1a70;
/// Timed runs per candidate (each alternated with bvh2); the median is compared.
pub const AUTO_RUNS: usize = 3;

/// The `auto` search space, kept small (every candidate is built and timed per scene): bvh2; qbvh_chunks
/// with chunk_bytes 64/128 x frame chunk/parent x bits 4/6/8; octree_1bit in 16-byte chunks filled
/// breadth-first or densely.
pub fn auto_candidates() -> Vec<String> {
    let mut c = vec!["bvh2".to_string()];
    for chunk in [64, 128] {
        for frame in ["chunk", "parent"] {
            for bits in [4, 6, 8] {
                c.push(format!(
                    "qbvh_chunks:bits={bits},chunk_bytes={chunk},frame={frame}"
                ));
            }
        }
    }
    for fill in ["bfs", "dense"] {
        c.push(format!("octree_1bit:chunk_bytes=16,fill={fill}"));
    }
    c
}

/// Parses `NAME[:k=v,k=v]` (`bvh2`, `qbvh_chunks:chunk_bytes=128,frame=parent,bits=6`,
/// `octree_1bit:chunk_bytes=16`, `auto:max_slowdown=1.3,rays=20000`) against the standard layout
/// table (`crate::methods::layouts`). Unknown names, parameters and bad values are input errors;
/// defaults are filled in.
pub fn parse_layout(spec: &str) -> Result<LayoutRequest> {
    crate::methods::layouts::parse(crate::methods::layouts::standard_table(), spec)
}

/// One candidate of the auto search as measured.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AutoCandidate {
    pub layout: String,
    pub params: String,
    pub total_bytes: u64,
    pub total_bytes_per_triangle: f64,
    /// Candidate and bvh2 times of the alternated runs.
    pub seconds: Vec<f64>,
    pub bvh2_seconds: Vec<f64>,
    /// median(seconds) / median(bvh2_seconds) (bvh2 itself: 1, the baseline, not timed).
    pub slowdown: f64,
    /// Why the candidate could not be used (build error, invalid, hits differing from bvh2).
    pub error: Option<String>,
    /// Seconds its build (and validation) took inside the search.
    pub build_seconds: f64,
    /// Why it was not built or not timed (None: it was fully measured, or is unusable).
    pub skipped: Option<String>,
}

/// The auto search's decision, stored with the chosen layout (machine dependent: it depends on
/// timings).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AutoChoice {
    pub max_slowdown: f64,
    pub rays: u32,
    pub candidates: Vec<AutoCandidate>,
    /// Index into `candidates`.
    pub chosen: usize,
    /// Human-readable reason (the row's `layout_choice`).
    pub reason: String,
    /// The budget in multiples of the bvh2 trace, that trace's seconds, the budget in seconds and
    /// the seconds the search took (it can overrun by the one step that was running).
    pub budget: f64,
    pub bvh2_trace_seconds: f64,
    pub budget_seconds: f64,
    pub search_seconds: f64,
    /// The budget ran out before every candidate that could have won was measured: the choice
    /// is the best among those measured (`skipped` says which were not).
    pub budget_cut: bool,
    /// Labels of the candidates the budget cut (not built, or built but not timed).
    pub skipped: Vec<String>,
    /// The chosen layout's slowdown in the search exceeds max_slowdown (only possible for the
    /// bvh2 fallback with max_slowdown < 1); the row re-judges it on its own measured slowdown.
    pub over_limit: bool,
}

/// Summary of the layout stage (`layout/<key>.sum`): what a row needs.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LayoutSummary {
    /// Layout name and canonical parameters (with `auto`: the chosen ones).
    pub layout: String,
    pub params: String,
    pub memory: Memory,
    /// Seconds of each of the `repeat` builds.
    pub seconds: Vec<f64>,
    pub median_seconds: f64,
    /// `Layout::sah_cost` with the chain's c_t / c_i.
    pub sah_cost: f64,
    pub valid: bool,
    pub invalid_reason: Option<String>,
    /// Heap growth of the first build (process-wide counting allocator, see `memtrack`).
    pub peak_build_bytes: u64,
    /// blake3 of the encoded layout.
    pub layout_hash: String,
    pub choice: Option<AutoChoice>,
}

/// Full artifact of the layout stage (`layout/<key>.bin`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LayoutArtifact {
    pub layout: Layout,
    pub summary: LayoutSummary,
}

/// Per-run slowdowns of alternated runs: `layout[i] / bvh2[i]` (run i of each side were timed
/// back to back). Empty when the counts differ or a bvh2 run is not positive.
pub fn paired_ratios(layout: &[f64], bvh2: &[f64]) -> Vec<f64> {
    if layout.len() != bvh2.len() || bvh2.iter().any(|&b| !(b > 0.0)) {
        return Vec::new();
    }
    layout.iter().zip(bvh2).map(|(a, b)| a / b).collect()
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
    fn layout_specs() {
        let LayoutRequest::Fixed(l) = parse_layout("bvh2").unwrap() else {
            panic!()
        };
        assert_eq!((l.name.as_str(), l.params.len()), ("bvh2", 0));
        let LayoutRequest::Fixed(q) =
            parse_layout(" qbvh_chunks: frame=parent , chunk_bytes=128").unwrap()
        else {
            panic!()
        };
        assert_eq!(q.params["frame"], "parent");
        assert_eq!(q.params["chunk_bytes"], "128");
        // Defaults filled in: explicit defaults and omitted ones give the same canonical params.
        let LayoutRequest::Fixed(d) = parse_layout("qbvh_chunks").unwrap() else {
            panic!()
        };
        let all = format!("qbvh_chunks:{}", d.params_string());
        assert_eq!(parse_layout(&all).unwrap(), LayoutRequest::Fixed(d));
        assert_eq!(
            parse_layout("auto").unwrap(),
            LayoutRequest::Auto(AutoSpec {
                max_slowdown: AUTO_MAX_SLOWDOWN,
                rays: AUTO_RAYS,
                budget: AUTO_BUDGET,
            })
        );
        assert_eq!(
            parse_layout("auto:max_slowdown=1.5,rays=500,budget=40").unwrap(),
            LayoutRequest::Auto(AutoSpec {
                max_slowdown: 1.5,
                rays: 500,
                budget: 40.0,
            })
        );
        for (bad, needle) in [
            ("zip", "unknown layout"),
            ("qbvh_chunks:chunk_bytes", "KEY=VALUE"),
            ("qbvh_chunks:chunk_bytes=64,chunk_bytes=128", "twice"),
            ("qbvh_chunks:nope=1", "nope"),
            // Old names (issue 17) name the new one, with or without parameters.
            ("qbvh", "layout `qbvh` was renamed to `qbvh_chunks` (Kilian 2021 5.2)"),
            ("qbvh:bits=6", "renamed to `qbvh_chunks`"),
            ("octree1:fill=dense", "layout `octree1` was renamed to `octree_1bit` (Kilian 2021 4.2)"),
            ("bvh2:bits=4", "bits"),
            ("auto:max_slowdown=0", "max_slowdown"),
            ("auto:max_slowdown=nan", "max_slowdown"),
            ("auto:rays=5", "rays"),
            ("auto:budget=0", "`budget` of layout `auto`: expected a finite number > 0"),
            ("auto:budget=inf", "budget"),
            ("auto:chunk_bytes=64", "chunk_bytes"),
        ] {
            let e = parse_layout(bad).unwrap_err();
            assert_eq!(e.exit_code(), 2, "{bad}");
            assert!(e.message().contains(needle), "{bad}: {e}");
        }
        for c in auto_candidates() {
            assert!(
                matches!(parse_layout(&c), Ok(LayoutRequest::Fixed(_))),
                "{c}"
            );
        }
    }

    #[test]
    fn paired() {
        assert_eq!(paired_ratios(&[2.0, 3.0], &[1.0, 2.0]), vec![2.0, 1.5]);
        assert!(paired_ratios(&[2.0, 3.0], &[1.0]).is_empty());
        assert!(paired_ratios(&[2.0], &[0.0]).is_empty());
    }

    #[test]
    fn names() {
        assert_eq!(
            scene_name("../shared/scenes/stanford_bunny.obj.gz"),
            "stanford_bunny"
        );
        assert_eq!(scene_name("gen:sphere:n=10"), "sphere:n=10");
    }
}
