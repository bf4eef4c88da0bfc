//! The stages, one per file: `load` (scene), `encode` (Morton / EMC codes and the sorted primitive
//! order, for the bottom-up builders), `build` (BVH), `optimize` (ibo or Kensler rotations on the
//! built BVH), `compact` (SAH collapse of the built or optimized BVH; after the optimizer, as
//! Bittner 2013 3.6 orders them), `layout` (the final BVH, or the scene for octrees, stored in a
//! memory layout of Kilian 2021, traced by measure with its own traversal; `auto` searches in
//! `auto.rs`), `measure` (ray set traced through the final BVH or the layout), `focus` (SAH cost
//! around a focus box in the final BVH). Each file declares its stage's node (version, canonical
//! parameters, inputs), its artifacts and its compute function; `chain.rs` lists them in chain
//! order and assembles the result row; `run.rs` evaluates any of them with the cache.
//!
//! Bump a stage's version when its implementation changes what it produces: its artifacts and
//! everything downstream get new keys. A change of one method (builder, encoder, optimizer,
//! layout) bumps that method's own version instead (`registry.rs`, `layout::LAYOUT_VERSIONS`).
use crate::error::Result;
use bvhlab_bvh::{Aabb, Bvh, CostParams, Metrics};
use bvhlab_geom::{LoadError, Scene, Triangle};
use bvhlab_layout::{Layout, LayoutSpec};
use bvhlab_morton::{EncodeConfig, Encoding};
use bvhlab_trace::Camera;
use std::collections::BTreeMap;
use std::path::PathBuf;

mod auto;
pub(crate) mod build;
pub(crate) mod chain;
pub(crate) mod compact;
pub(crate) mod encode;
pub(crate) mod focus;
pub(crate) mod layout;
pub(crate) mod load;
pub(crate) mod measure;
pub(crate) mod optimize;

pub use build::{BvhArtifact, BvhSummary, BUILD_VERSION};
pub use chain::Versions;
pub use compact::{check_compact, COMPACT_METHODS, COMPACT_VERSION};
pub use encode::{EncodeArtifact, EncodeSummary, ENCODE_VERSION};
pub use focus::{focus_box, focus_canonical, parse_focus, FocusSummary, FOCUS_VERSION};
pub use layout::{
    auto_candidates, layout_version, parse_layout, AutoCandidate, AutoChoice, AutoSpec,
    LayoutArtifact, LayoutRequest, LayoutSummary, AUTO_BUDGET, AUTO_MAX_SLOWDOWN, AUTO_RAYS,
    AUTO_RUNS, AUTO_SEED, LAYOUT_VERSION, LAYOUT_VERSIONS,
};
pub use load::{precision_warning, SceneSummary, LOAD_VERSION, PRECISION_LOSS_WARN};
pub use measure::{
    camera_canonical, paired_ratios, MeasureSummary, RaySpec, DEFAULT_RANDOM_RAYS,
    DEFAULT_RESOLUTION, MEASURE_VERSION, RANDOM_SEED,
};
pub use optimize::{OptimizeInfo, OPTIMIZE_VERSION};

/// The functions stages call from other crates; injectable so the cache logic can be tested on its
/// own (and so a stage can be swapped without touching the runner).
#[derive(Clone, Copy)]
pub struct Ops {
    pub load: fn(&str) -> Result<Scene, LoadError>,
    /// Canonical form of a generator spec (after `gen:`), so equivalent spellings share a key.
    pub canonical_gen: fn(&str) -> Result<String, LoadError>,
    pub metrics: fn(&Bvh, CostParams) -> Metrics,
    pub validate: fn(&Bvh, &[Aabb], bvhlab_bvh::Refs) -> Result<(), String>,
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
            validate: bvhlab_bvh::validate_refs,
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names() {
        assert_eq!(
            scene_name("../shared/scenes/stanford_bunny.obj.gz"),
            "stanford_bunny"
        );
        assert_eq!(scene_name("gen:sphere:n=10"), "sphere:n=10");
    }
}
