//! Experiment files (TOML): scenes x chains (parameter grids, cartesian product) x ray sets.
//! The format is documented at the top of experiments/quick.toml.
//!
//! A `[[chain]]` table's keys other than `build`, `compact`, `encode`, `optimize` and `layout` are
//! parameters, routed by name to the builder, the encoder or the optimizer (see
//! `Registry::resolve_chain`). `encode`, `optimize` and `layout` (value or array) are more axes of
//! the cartesian product; a layout entry is a spec string `NAME[:k=v,...]` (its parameters are not
//! routed: `bits` would collide with the Morton encoder's), `none` for no layout stage. `[focus]` / `[focuses."SCENE"]` set a focus box.
use crate::error::{Error, Result};
use crate::registry::Registry;
use crate::stages::{check_compact, focus_box, ChainSpec, RaySpec, SceneSource};
use bvhlab_bvh::{Aabb, CostParams};
use bvhlab_geom::Vec3;
use bvhlab_trace::Camera;
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use toml::Spanned;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FileToml {
    name: String,
    #[serde(default)]
    #[allow(dead_code)]
    description: Option<String>,
    scenes: Vec<Spanned<String>>,
    repeat: Option<u32>,
    cost: Option<CostToml>,
    chain: Vec<Spanned<toml::Table>>,
    rays: Option<RaysToml>,
    camera: Option<CameraToml>,
    #[serde(default)]
    cameras: BTreeMap<String, CameraToml>,
    focus: Option<Spanned<FocusToml>>,
    #[serde(default)]
    focuses: BTreeMap<String, Spanned<FocusToml>>,
}

#[derive(Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct FocusToml {
    min: [f32; 3],
    max: [f32; 3],
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct CostToml {
    c_t: Option<f32>,
    c_i: Option<f32>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RaysToml {
    sets: Vec<Spanned<String>>,
}

#[derive(Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraToml {
    eye: [f32; 3],
    target: [f32; 3],
    up: Option<[f32; 3]>,
    fov: Option<f32>,
}

impl CameraToml {
    fn camera(&self) -> Camera {
        Camera {
            eye: Vec3::from(self.eye),
            target: Vec3::from(self.target),
            up: Vec3::from(self.up.unwrap_or([0.0, 1.0, 0.0])),
            fov_y_deg: self.fov.unwrap_or(45.0),
        }
    }
}

/// One `[[chain]]` table expanded into its grid points.
#[derive(Clone, Debug, PartialEq)]
pub struct ChainPoint {
    pub build: String,
    /// Encoder (None: the builder's default, `morton`, for code-using builders).
    pub encode: Option<String>,
    /// Optimizer run on the built tree, before the compaction (None: no optimize stage).
    pub optimize: Option<String>,
    pub compact: String,
    pub params: BTreeMap<String, String>,
    /// Layout spec (`qbvh_chunks:chunk_bytes=128`, `auto:max_slowdown=1.3`); None: no layout stage.
    pub layout: Option<String>,
}

#[derive(Clone, Debug)]
pub struct Experiment {
    pub name: String,
    pub path: PathBuf,
    /// (spec as written, resolved source).
    pub scenes: Vec<(String, SceneSource)>,
    pub repeat: u32,
    pub cost: CostParams,
    pub points: Vec<ChainPoint>,
    /// Empty: no measure stage.
    pub rays: Vec<RaySpec>,
    pub camera: Option<Camera>,
    /// Per-scene camera overrides, keyed by the scene spec as written.
    pub cameras: BTreeMap<String, Camera>,
    /// Focus box for every scene (`[focus]`), overridden per scene by `[focuses."SCENE"]`.
    pub focus: Option<Aabb>,
    pub focuses: BTreeMap<String, Aabb>,
}

fn line_col(src: &str, offset: usize) -> (usize, usize) {
    let before = &src[..offset.min(src.len())];
    let line = before.matches('\n').count() + 1;
    let col = before.len() - before.rfind('\n').map(|i| i + 1).unwrap_or(0) + 1;
    (line, col)
}

fn value_strings(key: &str, v: &toml::Value) -> std::result::Result<Vec<String>, String> {
    let scalar = |v: &toml::Value| match v {
        toml::Value::String(s) => Ok(s.clone()),
        toml::Value::Integer(i) => Ok(i.to_string()),
        toml::Value::Float(f) => Ok(f.to_string()),
        toml::Value::Boolean(b) => Ok(b.to_string()),
        _ => Err(format!("`{key}` must be a value or an array of values")),
    };
    match v {
        toml::Value::Array(a) if a.is_empty() => Err(format!("`{key}` is an empty array")),
        toml::Value::Array(a) => a.iter().map(scalar).collect(),
        v => scalar(v).map(|s| vec![s]),
    }
}

/// Resolves a relative scene path: against the working directory if it exists there, else
/// against the experiment file's directory, else its parent (the repository root for files in
/// `experiments/`).
fn resolve_scene_path(spec: &str, exp_path: &Path) -> Option<PathBuf> {
    let p = PathBuf::from(spec);
    if p.is_absolute() || p.exists() {
        return p.exists().then_some(p);
    }
    let dir = exp_path.parent().unwrap_or(Path::new("."));
    [dir.join(&p), dir.join("..").join(&p)]
        .into_iter()
        .find(|c| c.exists())
}

/// Configurations (chains: scene x grid point x ray set) an experiment may expand to unless the
/// user raises the limit (`--max-configs`): above it, a typo in a grid would otherwise allocate and
/// plan for minutes before anything runs.
pub const DEFAULT_MAX_CONFIGS: u64 = 10_000;

/// The number of configurations an experiment file expands to, counted from the grid's shape
/// (axis lengths multiplied, saturating) before anything is expanded, and the axes that multiply
/// to it, e.g. `scenes 10 x (chain 1: bins 1000 x leaf 100 + chain 2: 1) x rays 2`.
fn count_configs(
    scenes: usize,
    chains: &[Vec<(String, Vec<String>)>],
    rays: usize,
) -> (u128, String) {
    let mut per_chain = 0u128;
    let mut parts = Vec::new();
    for (i, axes) in chains.iter().enumerate() {
        let n = axes
            .iter()
            .fold(1u128, |n, (_, v)| n.saturating_mul(v.len() as u128));
        per_chain = per_chain.saturating_add(n);
        // Axes of length 1 do not multiply anything: leaving them out keeps the message short.
        let named: Vec<String> = axes
            .iter()
            .filter(|(_, v)| v.len() > 1)
            .map(|(k, v)| format!("{k} {}", v.len()))
            .collect();
        let named = if named.is_empty() {
            "1".to_string()
        } else {
            named.join(" x ")
        };
        parts.push(format!("chain {}: {named}", i + 1));
    }
    let rays = rays.max(1);
    let total = (scenes as u128)
        .saturating_mul(per_chain)
        .saturating_mul(rays as u128);
    let chains = if parts.len() == 1 {
        parts.remove(0)
    } else {
        format!("({})", parts.join(" + "))
    };
    (total, format!("scenes {scenes} x {chains} x rays {rays}"))
}

impl Experiment {
    /// Loads with the default configuration limit (`DEFAULT_MAX_CONFIGS`).
    pub fn load(path: &Path, registry: &Registry) -> Result<Experiment> {
        Self::load_limited(path, registry, DEFAULT_MAX_CONFIGS)
    }

    /// Loads an experiment that may expand to at most `max_configs` configurations; above it,
    /// an input error (exit 2) names the count and the axes, before anything is expanded.
    pub fn load_limited(path: &Path, registry: &Registry, max_configs: u64) -> Result<Experiment> {
        let src = std::fs::read_to_string(path).map_err(|e| {
            Error::input(format!("{}: cannot read experiment: {e}", path.display()))
        })?;
        Self::parse_limited(&src, path, registry, max_configs)
    }

    pub fn parse(src: &str, path: &Path, registry: &Registry) -> Result<Experiment> {
        Self::parse_limited(src, path, registry, DEFAULT_MAX_CONFIGS)
    }

    pub fn parse_limited(
        src: &str,
        path: &Path,
        registry: &Registry,
        max_configs: u64,
    ) -> Result<Experiment> {
        let at = |offset: usize, msg: String| {
            let (l, c) = line_col(src, offset);
            Error::input(format!("{}:{l}:{c}: {msg}", path.display()))
        };
        let f: FileToml = toml::from_str(src).map_err(|e| {
            let msg = e.message().trim().to_string();
            match e.span() {
                Some(s) => at(s.start, msg),
                None => Error::input(format!("{}: {msg}", path.display())),
            }
        })?;
        if f.name.is_empty() || f.name.contains(['/', '\\']) || f.name.starts_with('.') {
            return Err(Error::input(format!(
                "{}: `name` must be a plain directory name",
                path.display()
            )));
        }
        if f.scenes.is_empty() {
            return Err(Error::input(format!(
                "{}: `scenes` is empty",
                path.display()
            )));
        }
        if f.chain.is_empty() {
            return Err(Error::input(format!(
                "{}: no [[chain]] tables",
                path.display()
            )));
        }
        // Count before expanding anything (issue 15: a 10^9 grid grew memory with no output
        // until killed). Reading the axes is linear in the file's size.
        let mut chain_axes: Vec<Vec<(String, Vec<String>)>> = Vec::new();
        for (i, ch) in f.chain.iter().enumerate() {
            let err = |msg: String| at(ch.span().start, format!("chain #{}: {msg}", i + 1));
            let table = ch.get_ref();
            let mut axes: Vec<(String, Vec<String>)> = Vec::new();
            for (k, v) in table {
                axes.push((k.clone(), value_strings(k, v).map_err(err)?));
            }
            if !table.contains_key("build") {
                return Err(err("missing `build`".into()));
            }
            chain_axes.push(axes);
        }
        let ray_sets = f.rays.as_ref().map_or(0, |r| r.sets.len());
        let (configs, axes) = count_configs(f.scenes.len(), &chain_axes, ray_sets);
        if configs > u128::from(max_configs) {
            return Err(Error::input(format!(
                "{}: {configs} configurations ({axes}) exceed --max-configs {max_configs}; \
                 raise it with --max-configs N",
                path.display()
            )));
        }
        let mut scenes = Vec::new();
        for s in &f.scenes {
            let spec = s.get_ref().clone();
            let source = match SceneSource::parse(&spec) {
                SceneSource::Gen(g) => match bvhlab_geom::gen::canonical_spec(&g) {
                    Ok(_) => SceneSource::Gen(g),
                    Err(e) => return Err(at(s.span().start, e.to_string())),
                },
                SceneSource::File(_) => match resolve_scene_path(&spec, path) {
                    Some(p) => SceneSource::File(p),
                    None => {
                        let hint = crate::catalogue::missing_hint(
                            &crate::catalogue::experiment_scene_path(&spec, path),
                        );
                        return Err(at(s.span().start, format!("scene file not found: {spec}{hint}")));
                    }
                },
            };
            scenes.push((spec, source));
        }
        let d = CostParams::default();
        let cost = match &f.cost {
            Some(c) => CostParams {
                c_t: c.c_t.unwrap_or(d.c_t),
                c_i: c.c_i.unwrap_or(d.c_i),
            },
            None => d,
        };
        if !(cost.c_t.is_finite() && cost.c_t > 0.0 && cost.c_i.is_finite() && cost.c_i > 0.0) {
            return Err(Error::input(format!(
                "{}: [cost] c_t and c_i must be finite and > 0",
                path.display()
            )));
        }
        let repeat = f.repeat.unwrap_or(5);
        if repeat == 0 {
            return Err(Error::input(format!(
                "{}: `repeat` must be at least 1",
                path.display()
            )));
        }
        let mut points = Vec::new();
        for (i, (ch, axes)) in f.chain.iter().zip(&chain_axes).enumerate() {
            let err = |msg: String| at(ch.span().start, format!("chain #{}: {msg}", i + 1));
            // Cartesian product over all keys (sorted by name, so expansion order is stable).
            let mut combos: Vec<BTreeMap<String, String>> = vec![BTreeMap::new()];
            for (k, vals) in axes {
                combos = combos
                    .into_iter()
                    .flat_map(|c| {
                        vals.iter().map(move |v| {
                            let mut c = c.clone();
                            c.insert(k.clone(), v.clone());
                            c
                        })
                    })
                    .collect();
            }
            for mut c in combos {
                let build = c.remove("build").unwrap_or_default();
                let compact = c.remove("compact").unwrap_or_else(|| "none".into());
                let encode = c.remove("encode");
                // `optimize = ["none", "ibo"]` compares with and without an optimize stage.
                let optimize = c.remove("optimize").filter(|o| o != "none");
                // `layout = ["none", "qbvh_chunks"]` compares with and without a layout stage.
                let layout = c.remove("layout").filter(|l| l != "none");
                if let Some(l) = &layout {
                    registry.parse_layout(l).map_err(|e| err(e.message().to_string()))?;
                }
                check_compact(&compact).map_err(|e| err(e.message().to_string()))?;
                registry
                    .resolve_chain(&build, encode.as_deref(), optimize.as_deref(), &c, cost)
                    .map_err(|e| err(e.message().to_string()))?;
                points.push(ChainPoint {
                    build,
                    encode,
                    optimize,
                    compact,
                    params: c,
                    layout,
                });
            }
        }
        let mut rays = Vec::new();
        if let Some(r) = &f.rays {
            for s in &r.sets {
                rays.push(
                    RaySpec::parse(s.get_ref())
                        .map_err(|e| at(s.span().start, e.message().to_string()))?,
                );
            }
        }
        for k in f.cameras.keys() {
            if !scenes.iter().any(|(s, _)| s == k) {
                return Err(Error::input(format!(
                    "{}: [cameras.\"{k}\"] names a scene not in `scenes`",
                    path.display()
                )));
            }
        }
        let focus_of = |f: &Spanned<FocusToml>, what: &str| {
            let v = f.get_ref();
            focus_box(v.min, v.max).map_err(|why| at(f.span().start, format!("{what}: {why}")))
        };
        let focus = f
            .focus
            .as_ref()
            .map(|x| focus_of(x, "[focus]"))
            .transpose()?;
        let mut focuses = BTreeMap::new();
        for (k, v) in &f.focuses {
            if !scenes.iter().any(|(s, _)| s == k) {
                return Err(at(
                    v.span().start,
                    format!("[focuses.\"{k}\"] names a scene not in `scenes`"),
                ));
            }
            focuses.insert(k.clone(), focus_of(v, &format!("[focuses.\"{k}\"]"))?);
        }
        Ok(Experiment {
            name: f.name,
            path: path.to_path_buf(),
            scenes,
            repeat,
            cost,
            points,
            rays,
            camera: f.camera.as_ref().map(CameraToml::camera),
            cameras: f
                .cameras
                .iter()
                .map(|(k, v)| (k.clone(), v.camera()))
                .collect(),
            focus,
            focuses,
        })
    }

    /// Every chain of the experiment, scene-major (so a sweep can free a scene's data after it).
    pub fn chains(&self) -> Vec<ChainSpec> {
        let mut out = Vec::new();
        let rays: Vec<Option<RaySpec>> = if self.rays.is_empty() {
            vec![None]
        } else {
            self.rays.iter().copied().map(Some).collect()
        };
        for (spec, source) in &self.scenes {
            for p in &self.points {
                for r in &rays {
                    out.push(ChainSpec {
                        scene: spec.clone(),
                        source: source.clone(),
                        build: p.build.clone(),
                        encode: p.encode.clone(),
                        optimize: p.optimize.clone(),
                        params: p.params.clone(),
                        cost: self.cost,
                        compact: p.compact.clone(),
                        rays: *r,
                        camera: self.cameras.get(spec).copied().or(self.camera),
                        repeat: self.repeat,
                        focus: self.focuses.get(spec).copied().or(self.focus),
                        layout: p.layout.clone(),
                    });
                }
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(src: &str) -> Result<Experiment> {
        Experiment::parse(src, Path::new("exp.toml"), &Registry::standard())
    }

    const OK: &str = r#"
name = "t"
scenes = ["gen:sphere:n=100", "gen:city"]
repeat = 3
[cost]
c_t = 1.0
[[chain]]
build = "binned-sah"
bins = [4, 8, 16]
compact = ["none", "collapse"]
[[chain]]
build = ["sweep-sah", "spatial-median"]
leaf = 1
[rays]
sets = ["primary:32x16", "random:1000"]
[camera]
eye = [0, 0, 5]
target = [0, 0, 0]
[cameras."gen:city"]
eye = [1, 2, 3]
target = [0, 0, 0]
fov = 30
"#;

    #[test]
    fn grid_expansion() {
        let e = parse(OK).unwrap();
        assert_eq!(e.points.len(), 3 * 2 + 2);
        assert_eq!(
            e.points[0],
            ChainPoint {
                build: "binned-sah".into(),
                encode: None,
                optimize: None,
                compact: "none".into(),
                params: [("bins".to_string(), "4".to_string())].into(),
                layout: None,
            }
        );
        assert_eq!(e.points[1].compact, "collapse");
        assert_eq!(e.points[7].build, "spatial-median");
        assert_eq!(
            e.points[7].params.get("leaf").map(String::as_str),
            Some("1")
        );
        assert_eq!(e.cost, CostParams { c_t: 1.0, c_i: 2.0 });
        let chains = e.chains();
        assert_eq!(chains.len(), 2 * 8 * 2);
        assert_eq!(chains[0].repeat, 3);
        assert_eq!(
            chains[0].rays,
            Some(RaySpec::Primary {
                width: 32,
                height: 16
            })
        );
        assert_eq!(chains[0].camera.unwrap().eye, Vec3::new(0.0, 0.0, 5.0));
        let city = chains.iter().find(|c| c.scene == "gen:city").unwrap();
        assert_eq!(city.camera.unwrap().fov_y_deg, 30.0);
        assert!(chains[..16].iter().all(|c| c.scene == "gen:sphere:n=100"));
    }

    #[test]
    fn errors_name_file_and_line() {
        let e = parse("name = \"x\"\nscenes = [\"gen:sphere\"]\n[[chain]]\nbuild = \"nope\"\n")
            .unwrap_err();
        assert_eq!(e.exit_code(), 2);
        assert!(e.message().starts_with("exp.toml:3:"), "{e}");
        assert!(e.message().contains("binned-sah"), "{e}");

        let e = parse("name = \"x\"\nscenes = [\"gen:sphere\"]\n[[chain]]\nbuild = \"binned-sah\"\nbins = [1]\n").unwrap_err();
        assert!(e.message().contains("bins"), "{e}");

        let e = parse("name = \"x\"\nscenes = [\"gen:sphere\"\n").unwrap_err();
        assert!(e.message().starts_with("exp.toml:"), "{e}");

        let e = parse("name = \"x\"\nscenes = [\"gen:sphere\"]\nbogus = 1\n[[chain]]\nbuild = \"sweep-sah\"\n").unwrap_err();
        assert!(e.message().contains("bogus"), "{e}");

        let e = parse("name = \"x\"\nscenes = [\"gen:sphere\", \"missing/file.obj\"]\n[[chain]]\nbuild = \"sweep-sah\"\n")
            .unwrap_err();
        assert!(
            e.message().starts_with("exp.toml:2:") && e.message().contains("missing/file.obj"),
            "{e}"
        );

        let e = parse("name = \"x\"\nscenes = [\"gen:sphere\"]\n[[chain]]\nbuild = \"sweep-sah\"\n[rays]\nsets = [\"laser\"]\n")
            .unwrap_err();
        assert!(e.message().starts_with("exp.toml:6:"), "{e}");
    }

    #[test]
    fn encoders_are_an_axis_and_params_are_routed() {
        let e = parse(
            r#"
name = "m"
scenes = ["gen:outlier:e=20", "gen:city"]
[[chain]]
build = "ploc"
radius = [10, 25]
encode = ["morton", "emc64-var"]
bounds = "concise"
[[chain]]
build = "aac"
preset = ["hq", "fast"]
bits = 8
[[chain]]
build = "binned-sah"
[focus]
min = [-1.0, -1.0, -1.0]
max = [1, 1, 1]
[focuses."gen:city"]
min = [0.0, 0.0, 0.0]
max = [16.0, 4.0, 16.0]
"#,
        )
        .unwrap();
        assert_eq!(e.points.len(), 2 * 2 + 2 + 1);
        let encs: Vec<Option<&str>> = e.points.iter().map(|p| p.encode.as_deref()).collect();
        assert_eq!(
            encs[..4]
                .iter()
                .filter(|x| **x == Some("emc64-var"))
                .count(),
            2
        );
        assert_eq!(encs[4..], [None, None, None]);
        assert_eq!(
            e.points[0].params.get("bounds").map(String::as_str),
            Some("concise")
        );
        assert!(!e.points[0].params.contains_key("encode"));
        let reg = Registry::standard();
        for p in &e.points[..4] {
            let (b, enc) = reg
                .resolve_chain(&p.build, p.encode.as_deref(), None, &p.params, e.cost)
                .unwrap()
                .parts();
            assert!(b.params.contains_key("radius") && !b.params.contains_key("bounds"));
            assert_eq!(enc.unwrap().params["bounds"], "concise");
        }
        let (_, enc) = reg
            .resolve_chain("aac", None, None, &e.points[4].params, e.cost)
            .unwrap()
            .parts();
        assert_eq!(enc.unwrap().params["bits"], "8");
        let chains = e.chains();
        let outlier = chains
            .iter()
            .find(|c| c.scene == "gen:outlier:e=20")
            .unwrap();
        assert_eq!(
            outlier.focus,
            Some(Aabb::new(Vec3::splat(-1.0), Vec3::splat(1.0)))
        );
        let city = chains
            .iter()
            .find(|c| c.scene == "gen:city" && c.build == "ploc")
            .unwrap();
        assert_eq!(city.focus.unwrap().max, Vec3::new(16.0, 4.0, 16.0));
        assert_eq!(city.encode.as_deref(), Some("morton"));
    }

    #[test]
    fn encoder_errors_name_the_chain() {
        let head = "name = \"x\"\nscenes = [\"gen:sphere\"]\n[[chain]]\n";
        let cases: [(&str, &[&str]); 6] = [
            (
                "build = \"ploc\"\nencode = \"emc64-var\"\nbits = 10\n",
                &["`bits`", "emc64-var", "bounds, grid_bits"],
            ),
            (
                "build = \"sweep-sah\"\nencode = \"morton\"\n",
                &["sweep-sah", "takes no codes"],
            ),
            (
                "build = \"lbvh\"\nencode = [\"morton\", \"zcurve\"]\n",
                &["zcurve", "emc64-sort"],
            ),
            (
                "build = \"binned-sah\"\nbounds = \"concise\"\n",
                &["bounds", "encoder parameter"],
            ),
            (
                "build = \"aac\"\npreset = \"fast\"\ndelta = 7\n",
                &["preset=fast sets delta=4"],
            ),
            (
                "build = \"lbvh\"\ngrid_bits = 5\n",
                &["grid_bits", "0, 6, 9, 12"],
            ),
        ];
        for (chain, needles) in cases {
            let e = parse(&format!("{head}{chain}")).unwrap_err();
            assert_eq!(e.exit_code(), 2, "{chain}");
            assert!(
                e.message().starts_with("exp.toml:3:") && e.message().contains("chain #1"),
                "{e}"
            );
            for n in needles {
                assert!(e.message().contains(n), "`{n}` not in {e}");
            }
        }
        let e = parse(&format!(
            "{head}build = \"lbvh\"\n[focus]\nmin = [1, 1, 1]\nmax = [0, 0, 0]\n"
        ))
        .unwrap_err();
        assert!(e.exit_code() == 2 && e.message().contains("[focus]"), "{e}");
        let e = parse(&format!(
            "{head}build = \"lbvh\"\n[focuses.\"gen:city\"]\nmin = [0, 0, 0]\nmax = [1, 1, 1]\n"
        ))
        .unwrap_err();
        assert!(
            e.exit_code() == 2 && e.message().contains("not in `scenes`"),
            "{e}"
        );
        let e = parse(&format!(
            "{head}build = \"lbvh\"\n[focus]\nmin = [0, 0, 0]\n"
        ))
        .unwrap_err();
        assert!(e.exit_code() == 2 && e.message().contains("max"), "{e}");
    }

    #[test]
    fn layouts_are_an_axis() {
        let head = "name = \"x\"\nscenes = [\"gen:sphere\"]\n[[chain]]\nbuild = \"binned-sah\"\n";
        let e = parse(&format!(
            "{head}layout = [\"none\", \"bvh2\", \"qbvh_chunks:chunk_bytes=128,frame=parent\"]\nbins = 8\n"
        ))
        .unwrap();
        let layouts: Vec<Option<&str>> = e.points.iter().map(|p| p.layout.as_deref()).collect();
        assert_eq!(
            layouts,
            [
                None,
                Some("bvh2"),
                Some("qbvh_chunks:chunk_bytes=128,frame=parent")
            ]
        );
        assert!(e.points.iter().all(|p| !p.params.contains_key("layout")));
        assert_eq!(
            e.chains()[2].layout.as_deref(),
            Some("qbvh_chunks:chunk_bytes=128,frame=parent")
        );
        for (bad, needle) in [
            ("layout = \"zip\"\n", "zip"),
            ("layout = \"qbvh_chunks:wat=1\"\n", "wat"),
            ("layout = \"qbvh_chunks:frame=sideways\"\n", "frame"),
            ("layout = \"auto:max_slowdown=-1\"\n", "max_slowdown"),
            // Old names (issue 17): the error names the new one.
            (
                "layout = [\"bvh2\", \"qbvh:frame=parent\"]\n",
                "layout `qbvh` was renamed to `qbvh_chunks` (Kilian 2021 5.2)",
            ),
            (
                "layout = \"octree1\"\n",
                "layout `octree1` was renamed to `octree_1bit` (Kilian 2021 4.2)",
            ),
        ] {
            let e = parse(&format!("{head}{bad}")).unwrap_err();
            assert_eq!(e.exit_code(), 2, "{bad}");
            assert!(
                e.message().starts_with("exp.toml:3:") && e.message().contains(needle),
                "{e}"
            );
        }
    }

    /// Ten values per axis: `n` axes of `bins`-like parameters over 10 scenes.
    fn big_grid(axes: usize) -> String {
        let vals = "[2, 3, 4, 5, 6, 7, 8, 9, 10, 11]";
        let mut s = String::from("name = \"big\"\nscenes = [");
        let scenes: Vec<String> = (1..=10)
            .map(|i| format!("\"gen:sphere:n={}\"", 100 + i))
            .collect();
        s.push_str(&scenes.join(", "));
        s.push_str("]\n[[chain]]\nbuild = \"binned-sah\"\n");
        for k in ["bins", "leaf", "c_t", "c_i", "centroid_stop"]
            .iter()
            .take(axes)
        {
            let v = match *k {
                "centroid_stop" => "[\"split-axis\", \"any-axis\"]",
                _ => vals,
            };
            s.push_str(&format!("{k} = {v}\n"));
        }
        s
    }

    #[test]
    fn config_limit_counts_before_expanding() {
        // 10 scenes x 10^4 grid points = 10^5 configurations; counted, never expanded.
        let src = big_grid(4);
        let t0 = std::time::Instant::now();
        let e = parse(&src).unwrap_err();
        assert!(t0.elapsed().as_secs_f64() < 1.0);
        assert_eq!(e.exit_code(), 2);
        let m = e.message();
        assert!(
            m.starts_with("exp.toml: 100000 configurations (scenes 10 x chain 1: "),
            "{m}"
        );
        for needle in [
            "bins 10",
            "leaf 10",
            "c_t 10",
            "c_i 10",
            "exceed --max-configs 10000",
            "--max-configs N",
        ] {
            assert!(m.contains(needle), "`{needle}` not in {m}");
        }
        assert!(!m.contains("build 1"), "axes of length 1 are left out: {m}");
        // Raised: expands to exactly the count.
        let e =
            Experiment::parse_limited(&src, Path::new("exp.toml"), &Registry::standard(), 100_000)
                .unwrap();
        assert_eq!(e.chains().len(), 100_000);
        let e =
            Experiment::parse_limited(&src, Path::new("exp.toml"), &Registry::standard(), 99_999)
                .unwrap_err();
        assert!(e.message().contains("100000 configurations"), "{e}");
        // Several chains and ray sets: the sum of the chains' products times scenes and rays.
        let src = "name = \"x\"\nscenes = [\"gen:sphere\", \"gen:city\"]\n[[chain]]\nbuild = \"binned-sah\"\nbins = [4, 8, 16]\n\
                   [[chain]]\nbuild = [\"sweep-sah\", \"spatial-median\"]\n[rays]\nsets = [\"random:10\", \"primary:4x4\"]\n";
        let e = Experiment::parse_limited(src, Path::new("exp.toml"), &Registry::standard(), 19)
            .unwrap_err();
        assert!(
            e.message().contains(
                "20 configurations (scenes 2 x (chain 1: bins 3 + chain 2: build 2) x rays 2)"
            ),
            "{e}"
        );
        assert_eq!(
            Experiment::parse_limited(src, Path::new("exp.toml"), &Registry::standard(), 20)
                .unwrap()
                .chains()
                .len(),
            20
        );
    }

    #[test]
    fn config_count_saturates() {
        // 10^20 per chain x 10^20 x 10^20 overflows u64 and nearly u128: saturates, still refused.
        let axes: Vec<(String, Vec<String>)> = (0..20)
            .map(|i| (format!("p{i}"), vec![String::new(); 10]))
            .collect();
        let chains = vec![axes.clone(); 3];
        let (n, _) = count_configs(usize::MAX, &[axes, chains[0].clone()], usize::MAX);
        assert_eq!(n, u128::MAX);
        let (n, s) = count_configs(3, &chains, 0);
        assert_eq!(n, 3 * 3 * 10u128.pow(20));
        assert!(s.ends_with("x rays 1"), "{s}");
    }

    /// The experiment files shipped in `experiments/` parse with the current registry (a file whose
    /// scenes are missing on this machine is skipped for that reason only).
    #[test]
    fn shipped_experiments_parse() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../experiments");
        let Ok(entries) = std::fs::read_dir(&dir) else {
            return;
        };
        for f in entries
            .flatten()
            .map(|e| e.path())
            .filter(|p| p.extension().is_some_and(|x| x == "toml"))
            // The scene catalogue (crate::catalogue) is no experiment.
            .filter(|p| !p.ends_with("scenes.toml"))
        {
            match Experiment::load(&f, &Registry::standard()) {
                Ok(e) => assert!(!e.chains().is_empty(), "{}", f.display()),
                Err(e) if e.message().contains("scene file not found") => eprintln!("skipped: {e}"),
                Err(e) => panic!("{e}"),
            }
        }
    }
}
