//! What the layout examples share: the scene they all start from (binned SAH, 16 bins, over a
//! loaded or generated scene, with random rays through its bounding sphere) and the hit comparison.
#![allow(dead_code)]
use bvhlab_builders::{binned_sah, TopDownConfig};
use bvhlab_bvh::Bvh;
use bvhlab_geom::{load_scene, Scene};
use bvhlab_trace::{random_rays, Hit, Ray};

/// A scene with its binned-SAH BVH (16 bins, leaf `leaf`) and `n_rays` random rays (seed `seed`).
pub struct Setup {
    pub name: String,
    pub scene: Scene,
    pub bvh: Bvh,
    pub rays: Vec<Ray>,
}

impl Setup {
    pub fn new(path: &str, leaf: u32, n_rays: usize, seed: u64) -> Setup {
        let scene = load_scene(path).unwrap_or_else(|e| panic!("{path}: {e:?}"));
        let (boxes, centers) = scene.boxes_and_centers();
        let cfg = TopDownConfig { leaf, ..Default::default() };
        let bvh = binned_sah::build(&boxes, &centers, 16, &cfg);
        let b = scene.bounds();
        let rays = random_rays(&b, b.enclosing_radius(centers.iter().copied()), n_rays, seed);
        Setup { name: scene_name(path), scene, bvh, rays }
    }
}

/// File stem without `.obj` / `.obj.gz`, or the generator spec.
pub fn scene_name(path: &str) -> String {
    let file = std::path::Path::new(path).file_name().map(|s| s.to_string_lossy().to_string());
    file.unwrap_or_else(|| path.to_string()).replace(".obj.gz", "").replace(".obj", "")
}

/// Same closest hit: the same triangle, or both hit at `t` within 1e-6 relative (ties).
pub fn same_hit(g: &Hit, w: &Hit) -> bool {
    g.prim == w.prim || (g.is_hit() && w.is_hit() && (g.t - w.t).abs() <= 1e-6 * w.t.abs())
}

/// Splits positional arguments into scenes (paths, `gen:...`) and layout specs, in order.
pub fn scenes_and_layouts(items: &[String]) -> (Vec<String>, Vec<bvhlab_layout::LayoutSpec>) {
    let is_scene = |s: &str| s.starts_with("gen:") || s.contains(".obj") || s.contains('/');
    let (scenes, specs): (Vec<&String>, Vec<&String>) = items.iter().partition(|s| is_scene(s));
    let specs = specs.iter().map(|s| bvhlab_layout::LayoutSpec::from_spec(s)).collect::<Result<Vec<_>, _>>();
    let specs = specs.unwrap_or_else(|e| panic!("{e}"));
    assert!(!scenes.is_empty() && !specs.is_empty(), "give at least one scene and one layout");
    (scenes.into_iter().cloned().collect(), specs)
}

/// Rays and timing rounds of the benchmarks.
#[derive(clap::Args)]
pub struct RunArgs {
    /// Random rays per scene.
    #[arg(long, default_value_t = 100_000)]
    pub rays: usize,
    /// Timed rounds (median reported; variants alternated inside a round).
    #[arg(long, default_value_t = 5)]
    pub rounds: usize,
    #[arg(long, default_value_t = 1)]
    pub threads: usize,
}
