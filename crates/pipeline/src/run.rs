//! Runs chains against the store, computing only nodes whose keys are not cached.
//!
//! Keys are computed up front from parameters and input keys (never from artifact contents,
//! except a scene file's bytes), then each node is resolved lazily: a row needs only the small
//! summaries, so a warm run reads `.sum` files and never decodes scenes or BVHs. A node is counted
//! once per run, as `computed` or `cached` (read from disk).
use crate::error::{Error, Result};
use crate::key::{params_string, stage_key, Key};
use crate::registry::{fmt_f32, Registry, Resolved, ResolvedEncoder, ResolvedOptimizer};
use crate::stages::*;
use crate::store::{now_unix, Machine, Manifest, Store};
use crate::ResultRow;
use bvhlab_bvh::Bvh;
use bvhlab_geom::stats::{median, spread};
use bvhlab_geom::Scene;
use bvhlab_trace::Camera;
use serde::Serialize;
use std::collections::{BTreeMap, HashMap};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct StageCount {
    pub computed: u64,
    pub cached: u64,
}

#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct Counts {
    pub computed: u64,
    pub cached: u64,
    pub per_stage: BTreeMap<String, StageCount>,
}

impl Counts {
    pub fn stage(&self, stage: &str) -> StageCount {
        self.per_stage.get(stage).copied().unwrap_or_default()
    }
}

#[derive(Clone, Debug)]
struct NodeDef {
    stage: &'static str,
    version: u32,
    params: BTreeMap<String, String>,
    inputs: Vec<(&'static str, Key)>,
    key: Key,
}

impl NodeDef {
    fn new(
        stage: &'static str,
        version: u32,
        params: BTreeMap<String, String>,
        inputs: Vec<(&'static str, Key)>,
    ) -> Self {
        let keys: Vec<Key> = inputs.iter().map(|(_, k)| *k).collect();
        let key = stage_key(stage, version, &params, &keys);
        NodeDef {
            stage,
            version,
            params,
            inputs,
            key,
        }
    }
}

/// One node of a chain's stage graph: `Runner::chain_nodes`.
#[derive(Clone, Debug, PartialEq)]
pub struct NodeInfo {
    pub stage: &'static str,
    pub key: Key,
    /// Input nodes (stage, key), strictly upstream.
    pub inputs: Vec<(&'static str, Key)>,
    /// Canonical parameters (what the key hashes besides stage, version and inputs).
    pub params: BTreeMap<String, String>,
}

struct Plan {
    spec: ChainSpec,
    resolved: Resolved,
    /// Encoder of a code-using builder.
    encoder: Option<ResolvedEncoder>,
    optimizer: Option<ResolvedOptimizer>,
    load: NodeDef,
    encode: Option<NodeDef>,
    build: NodeDef,
    optimize: Option<NodeDef>,
    compact: Option<NodeDef>,
    measure: Option<(NodeDef, RaySpec)>,
    focus: Option<NodeDef>,
    layout: Option<(NodeDef, LayoutRequest)>,
}

#[derive(Clone, Copy, PartialEq)]
enum Which {
    Build,
    Optimize,
    Compact,
}

impl Plan {
    /// The stage whose BVH is final (what measure and focus read).
    fn final_which(&self) -> Which {
        if self.compact.is_some() {
            Which::Compact
        } else if self.optimize.is_some() {
            Which::Optimize
        } else {
            Which::Build
        }
    }
}

pub struct Runner {
    pub store: Store,
    pub versions: Versions,
    pub registry: Registry,
    pub ops: Ops,
    pub counts: Counts,
    counted: HashMap<(&'static str, Key), bool>,
    scenes: HashMap<Key, Arc<Scene>>,
    scene_sums: HashMap<Key, SceneSummary>,
    bvhs: HashMap<Key, Arc<BvhArtifact>>,
    bvh_sums: HashMap<Key, BvhSummary>,
    encodings: HashMap<Key, Arc<EncodeArtifact>>,
    encode_sums: HashMap<Key, EncodeSummary>,
    opt_infos: HashMap<Key, OptimizeInfo>,
    layouts: HashMap<Key, Arc<LayoutArtifact>>,
    layout_sums: HashMap<Key, LayoutSummary>,
    file_hashes: HashMap<PathBuf, String>,
    /// CPU model per node, read from its manifest once per run.
    cpu_models: HashMap<(&'static str, Key), String>,
}

fn param(k: &str, v: impl ToString) -> (String, String) {
    (k.to_string(), v.to_string())
}

fn secs(t: Instant) -> f64 {
    t.elapsed().as_secs_f64()
}

impl Runner {
    pub fn new(store: Store) -> Runner {
        Runner {
            store,
            versions: Versions::default(),
            registry: Registry::standard(),
            ops: Ops::default(),
            counts: Counts::default(),
            counted: HashMap::new(),
            scenes: HashMap::new(),
            scene_sums: HashMap::new(),
            bvhs: HashMap::new(),
            bvh_sums: HashMap::new(),
            encodings: HashMap::new(),
            encode_sums: HashMap::new(),
            opt_infos: HashMap::new(),
            layouts: HashMap::new(),
            layout_sums: HashMap::new(),
            file_hashes: HashMap::new(),
            cpu_models: HashMap::new(),
        }
    }

    /// Drops in-memory artifacts (call between scenes of a sweep to bound memory). Counting is
    /// unaffected: a node already counted in this run is not counted again.
    pub fn forget(&mut self) {
        self.scenes.clear();
        self.bvhs.clear();
        self.encodings.clear();
        self.layouts.clear();
    }

    fn note(&mut self, stage: &'static str, key: Key, computed: bool) {
        let prev = self.counted.get(&(stage, key)).copied();
        let c = self.counts.per_stage.entry(stage.to_string()).or_default();
        match (prev, computed) {
            (None, true) => {
                c.computed += 1;
                self.counts.computed += 1;
            }
            (None, false) => {
                c.cached += 1;
                self.counts.cached += 1;
            }
            // Read from disk earlier in this run, recomputed now (its full artifact was corrupt).
            (Some(false), true) => {
                c.cached -= 1;
                c.computed += 1;
                self.counts.cached -= 1;
                self.counts.computed += 1;
            }
            _ => {}
        }
        self.counted
            .insert((stage, key), prev.unwrap_or(false) || computed);
    }

    /// Validates a chain and computes every key without running anything.
    fn plan(&mut self, spec: &ChainSpec) -> Result<Plan> {
        if spec.repeat == 0 {
            return Err(Error::input("repeat must be at least 1"));
        }
        check_compact(&spec.compact)?;
        let chain = self.registry.resolve_chain(
            &spec.build,
            spec.encode.as_deref(),
            spec.optimize.as_deref(),
            &spec.params,
            spec.cost,
        )?;
        let (resolved, encoder, optimizer) = (chain.build, chain.encoder, chain.optimizer);
        let load_params: BTreeMap<String, String> = match &spec.source {
            SceneSource::Gen(g) => [param("gen", (self.ops.canonical_gen)(g)?)].into(),
            SceneSource::File(path) => {
                let h = match self.file_hashes.get(path) {
                    Some(h) => h.clone(),
                    None => {
                        // Keyed by content, not path: editing the file invalidates its artifacts.
                        let bytes = std::fs::read(path)
                            .map_err(|e| crate::catalogue::read_error(path, &e))?;
                        let h = blake3::hash(&bytes).to_hex().to_string();
                        self.file_hashes.insert(path.clone(), h.clone());
                        h
                    }
                };
                [param("content", h)].into()
            }
        };
        let load = NodeDef::new("load", self.versions.load, load_params, vec![]);
        // Encoder parameters are canonical with `bits=auto` resolved for the builder, so chains
        // whose codes are identical (e.g. emc64-var for aac and ploc) share the encode node.
        let encode = encoder.as_ref().map(|e| {
            let mut p = e.params.clone();
            p.insert("encoder".into(), e.encoder.clone());
            p.insert("repeat".into(), spec.repeat.to_string());
            NodeDef::new("encode", self.versions.encode, p, vec![("load", load.key)])
        });
        let mut bp = resolved.key_params();
        bp.insert("builder".into(), resolved.builder.clone());
        bp.insert("repeat".into(), spec.repeat.to_string());
        let mut build_inputs = vec![("load", load.key)];
        if let Some(e) = &encode {
            build_inputs.push(("encode", e.key));
        }
        let build = NodeDef::new("build", self.versions.build, bp, build_inputs);
        let optimize = optimizer.as_ref().map(|o| {
            let mut p = o.params.clone();
            p.insert("optimizer".into(), o.optimizer.clone());
            p.insert("c_t".into(), fmt_f32(o.cost.c_t));
            p.insert("c_i".into(), fmt_f32(o.cost.c_i));
            p.insert("repeat".into(), spec.repeat.to_string());
            NodeDef::new(
                "optimize",
                self.versions.optimize,
                p,
                vec![("build", build.key)],
            )
        });
        let before_compact = optimize.as_ref().unwrap_or(&build);
        let compact = (spec.compact != "none").then(|| {
            let p = [
                param("method", &spec.compact),
                param("c_t", fmt_f32(resolved.cost.c_t)),
                param("c_i", fmt_f32(resolved.cost.c_i)),
                param("repeat", spec.repeat),
            ]
            .into();
            NodeDef::new(
                "compact",
                self.versions.compact,
                p,
                vec![(before_compact.stage, before_compact.key)],
            )
        });
        let final_node = compact.as_ref().unwrap_or(before_compact);
        let layout = match &spec.layout {
            None => None,
            Some(s) => {
                let req = parse_layout(s)?;
                let cost = [
                    param("c_t", fmt_f32(resolved.cost.c_t)),
                    param("c_i", fmt_f32(resolved.cost.c_i)),
                    param("repeat", spec.repeat),
                ];
                let (mut p, inputs): (BTreeMap<String, String>, _) = match &req {
                    LayoutRequest::Fixed(l) => {
                        let mut p = l.params.clone();
                        p.insert("layout".into(), l.name.clone());
                        // Octrees are built from the triangles alone: keyed by the scene, so every
                        // builder's chain shares one octree node.
                        let inputs = if bvhlab_layout::uses_bvh(&l.name) {
                            vec![("load", load.key), (final_node.stage, final_node.key)]
                        } else {
                            vec![("load", load.key)]
                        };
                        (p, inputs)
                    }
                    LayoutRequest::Auto(a) => {
                        let p = [
                            param("layout", "auto"),
                            param("max_slowdown", a.max_slowdown),
                            param("rays", a.rays),
                            param("seed", AUTO_SEED),
                            param("runs", AUTO_RUNS),
                            param("budget", a.budget),
                            param("candidates", auto_candidates().join(";")),
                        ]
                        .into();
                        (
                            p,
                            vec![("load", load.key), (final_node.stage, final_node.key)],
                        )
                    }
                };
                p.extend(cost);
                Some((NodeDef::new("layout", self.versions.layout, p, inputs), req))
            }
        };
        let measure = spec.rays.map(|rays| {
            let mut p: BTreeMap<String, String> = [
                param("rays", rays.canonical()),
                param(
                    "camera",
                    spec.camera
                        .as_ref()
                        .map(camera_canonical)
                        .unwrap_or_else(|| "auto".into()),
                ),
                param("repeat", spec.repeat),
            ]
            .into();
            if let RaySpec::Random { .. } = rays {
                p.insert("seed".into(), RANDOM_SEED.to_string());
            }
            let mut inputs = vec![("load", load.key), (final_node.stage, final_node.key)];
            if let Some((l, _)) = &layout {
                inputs.push(("layout", l.key));
            }
            (
                NodeDef::new("measure", self.versions.measure, p, inputs),
                rays,
            )
        });
        let focus = spec.focus.map(|b| {
            let p = [
                param("box", focus_canonical(&b)),
                param("c_t", fmt_f32(resolved.cost.c_t)),
                param("c_i", fmt_f32(resolved.cost.c_i)),
            ]
            .into();
            let inputs = vec![("load", load.key), (final_node.stage, final_node.key)];
            NodeDef::new("focus", self.versions.focus, p, inputs)
        });
        Ok(Plan {
            spec: spec.clone(),
            resolved,
            encoder,
            optimizer,
            load,
            encode,
            build,
            optimize,
            compact,
            measure,
            focus,
            layout,
        })
    }

    fn commit(&self, node: &NodeDef, files: BTreeMap<String, String>, seconds: f64) -> Result<()> {
        let mut versions = BTreeMap::new();
        versions.insert("bvhlab".to_string(), env!("CARGO_PKG_VERSION").to_string());
        versions.insert(
            "artifact_format".to_string(),
            crate::codec::FORMAT_VERSION.to_string(),
        );
        self.store.commit(&Manifest {
            key: node.key.hex(),
            stage: node.stage.to_string(),
            version: node.version,
            params: node.params.clone(),
            inputs: node
                .inputs
                .iter()
                .map(|(s, k)| format!("{s}:{}", k.hex()))
                .collect(),
            files,
            versions,
            machine: Machine::current(),
            time_unix: now_unix(),
            compute_seconds: seconds,
        })?;
        // Complete: other processes waiting on this node now read it as a hit.
        self.store.unlock(node.stage, &node.key);
        Ok(())
    }

    /// Data file `ext` of `node` if its entry is complete and intact (`Store::get_entry`: manifest
    /// of this stage and key, file blake3 as listed, codec checksum), else None: the caller computes
    /// the node and `commit`s it.
    ///
    /// Two processes on one cache compute each node once: on a miss this takes the node's compute
    /// lock (`cache/locks/<stage>/<key>.lock`, blocking while another process holds it) and checks
    /// again under the lock; if the other process committed meanwhile, that is a hit. Otherwise the
    /// lock is held until `commit` (or the end of the chain, `run_chain`'s `release_on_drop`, also on
    /// error), so nobody else computes the node meanwhile. A hit releases the node's lock if held
    /// (e.g. summary missing, full artifact intact). Only the locked re-check reports and
    /// quarantines bad files: the unlocked first look might see another process's half-replaced
    /// entry (new file, old manifest) and must not touch it.
    ///
    /// No deadlock: a process holds locks only of nodes it is computing. Computing node N needs
    /// only N's inputs, which are strictly upstream of N (a key hashes its input keys, so the node
    /// graph is acyclic), and inputs are resolved inside N's computation, so the held locks form a
    /// path N1 <- N2 <- ... <- Nk and the next lock waited for is an input of Nk: strictly upstream
    /// of every lock held. Fix any topological order of the node graph: every process acquires
    /// locks in strictly decreasing order (downstream to upstream). In a wait cycle P1 -> P2 ->
    /// ... -> P1, each lock waited for would be strictly upstream of the previous one, so the first
    /// would be upstream of itself: impossible. A hit never keeps a lock, and a failed chain drops
    /// all of its locks, so a lock is never held while waiting for something downstream.
    fn cached<T: serde::de::DeserializeOwned>(&self, node: &NodeDef, ext: &str) -> Option<T> {
        self.cached_with(node, ext, &[])
    }

    /// `cached`, with the entry's raw files `also` checked too (`Store::get_entry_with`).
    fn cached_with<T: serde::de::DeserializeOwned>(
        &self,
        node: &NodeDef,
        ext: &str,
        also: &[&str],
    ) -> Option<T> {
        if let Some(v) = self
            .store
            .get_entry_with(node.stage, &node.key, ext, also, false)
        {
            self.store.unlock(node.stage, &node.key);
            return Some(v);
        }
        self.store.lock(node.stage, &node.key);
        let v = self
            .store
            .get_entry_with(node.stage, &node.key, ext, also, true);
        if v.is_some() {
            self.store.unlock(node.stage, &node.key);
        }
        v
    }

    // ---- load -------------------------------------------------------------------------------

    fn scene_full(&mut self, plan: &Plan) -> Result<Arc<Scene>> {
        let node = &plan.load;
        if let Some(s) = self.scenes.get(&node.key) {
            return Ok(s.clone());
        }
        if let Some(s) = self.cached::<Scene>(node, "bin") {
            self.note("load", node.key, false);
            let s = Arc::new(s);
            self.scenes.insert(node.key, s.clone());
            return Ok(s);
        }
        let t0 = Instant::now();
        let scene = (self.ops.load)(&plan.spec.source.load_spec())?;
        if scene.triangles.is_empty() {
            return Err(Error::input(format!(
                "{}: scene has no finite triangles ({} dropped)",
                plan.spec.scene, scene.dropped_triangles
            )));
        }
        let sum = SceneSummary {
            triangles: scene.triangles.len() as u64,
            dropped_triangles: scene.dropped_triangles,
            bounds: scene.bounds(),
            precision_loss: scene.precision_loss(),
        };
        let mut files = BTreeMap::new();
        files.insert(
            "bin".into(),
            self.store.put("load", &node.key, "bin", &scene)?,
        );
        files.insert(
            "sum".into(),
            self.store.put("load", &node.key, "sum", &sum)?,
        );
        self.commit(node, files, secs(t0))?;
        self.note("load", node.key, true);
        let s = Arc::new(scene);
        self.scenes.insert(node.key, s.clone());
        self.scene_sums.insert(node.key, sum);
        Ok(s)
    }

    fn scene_summary(&mut self, plan: &Plan) -> Result<SceneSummary> {
        let key = plan.load.key;
        if let Some(s) = self.scene_sums.get(&key) {
            return Ok(s.clone());
        }
        if let Some(s) = self.cached::<SceneSummary>(&plan.load, "sum") {
            self.note("load", key, false);
            self.scene_sums.insert(key, s.clone());
            return Ok(s);
        }
        let scene = self.scene_full(plan)?;
        let sum = match self.scene_sums.get(&key) {
            Some(s) => s.clone(),
            None => {
                // Scene read from its full artifact because the summary was missing or corrupt:
                // restore the summary (same bytes as before, so the manifest stays right).
                let s = SceneSummary {
                    triangles: scene.triangles.len() as u64,
                    dropped_triangles: scene.dropped_triangles,
                    bounds: scene.bounds(),
                    precision_loss: scene.precision_loss(),
                };
                self.store.put("load", &key, "sum", &s)?;
                self.scene_sums.insert(key, s.clone());
                s
            }
        };
        Ok(sum)
    }

    // ---- encode -------------------------------------------------------------------------------

    fn encode_full(&mut self, plan: &Plan) -> Result<Arc<EncodeArtifact>> {
        let node = plan
            .encode
            .clone()
            .ok_or_else(|| Error::internal("chain has no encode stage"))?;
        let enc = plan
            .encoder
            .clone()
            .ok_or_else(|| Error::internal("chain has no encoder"))?;
        if let Some(a) = self.encodings.get(&node.key) {
            return Ok(a.clone());
        }
        if let Some(a) = self.cached::<EncodeArtifact>(&node, "bin") {
            self.note("encode", node.key, false);
            let a = Arc::new(a);
            self.encode_sums.insert(node.key, a.summary.clone());
            self.encodings.insert(node.key, a.clone());
            return Ok(a);
        }
        let t0 = Instant::now();
        let scene = self.scene_full(plan)?;
        let (boxes, centers) = scene.boxes_and_centers();
        let mut seconds = Vec::new();
        let mut first: Option<bvhlab_morton::Encoding> = None;
        for run in 0..plan.spec.repeat {
            // Only encode() is timed (codes + sort); boxes and centres are shared preparation.
            let t = Instant::now();
            let e = (self.ops.encode)(&boxes, &centers, &enc.config, enc.cell_frame);
            seconds.push(secs(t));
            match &first {
                None => first = Some(e),
                Some(e0) if *e0 != e => {
                    return Err(Error::internal(format!(
                        "encoder `{}` is not deterministic: run {} produced different codes than run 1 on {}",
                        enc.encoder,
                        run + 1,
                        plan.spec.scene
                    )));
                }
                _ => {}
            }
        }
        let encoding = first.ok_or_else(|| Error::internal("repeat = 0"))?;
        if encoding.order.len() != boxes.len() || encoding.codes.len() != boxes.len() {
            return Err(Error::internal(format!(
                "encoder `{}` returned {} codes for {} primitives",
                enc.encoder,
                encoding.codes.len(),
                boxes.len()
            )));
        }
        let summary = EncodeSummary {
            code_bits: encoding.code_bits,
            duplicate_fraction: encoding.duplicate_fraction(),
            layout: encoding.layout.clone(),
            median_seconds: median(&seconds),
            seconds,
        };
        let art = EncodeArtifact { encoding, summary };
        let mut files = BTreeMap::new();
        files.insert(
            "bin".into(),
            self.store.put("encode", &node.key, "bin", &art)?,
        );
        files.insert(
            "sum".into(),
            self.store.put("encode", &node.key, "sum", &art.summary)?,
        );
        self.commit(&node, files, secs(t0))?;
        self.note("encode", node.key, true);
        let art = Arc::new(art);
        self.encode_sums.insert(node.key, art.summary.clone());
        self.encodings.insert(node.key, art.clone());
        Ok(art)
    }

    fn encode_summary(&mut self, plan: &Plan) -> Result<Option<EncodeSummary>> {
        let Some(node) = plan.encode.as_ref() else {
            return Ok(None);
        };
        let key = node.key;
        if let Some(s) = self.encode_sums.get(&key) {
            return Ok(Some(s.clone()));
        }
        if let Some(s) = self.cached::<EncodeSummary>(node, "sum") {
            self.note("encode", key, false);
            self.encode_sums.insert(key, s.clone());
            return Ok(Some(s));
        }
        let art = self.encode_full(plan)?;
        if !self.store.path("encode", &key, "sum").exists() {
            // Full artifact intact, summary not: restore it (identical bytes).
            self.store.put("encode", &key, "sum", &art.summary)?;
        }
        Ok(Some(art.summary.clone()))
    }

    // ---- build / compact ----------------------------------------------------------------------

    fn node(plan: &Plan, which: Which) -> &NodeDef {
        match which {
            Which::Build => &plan.build,
            Which::Optimize => plan.optimize.as_ref().expect("optimize node"),
            Which::Compact => plan.compact.as_ref().expect("compact node"),
        }
    }

    fn bvh_full(&mut self, plan: &Plan, which: Which) -> Result<Arc<BvhArtifact>> {
        let node = Self::node(plan, which).clone();
        if let Some(a) = self.bvhs.get(&node.key) {
            return Ok(a.clone());
        }
        if let Some(a) = self.cached::<BvhArtifact>(&node, "bin") {
            self.note(node.stage, node.key, false);
            let a = Arc::new(a);
            self.bvh_sums.insert(node.key, a.summary.clone());
            self.bvhs.insert(node.key, a.clone());
            return Ok(a);
        }
        let t0 = Instant::now();
        let scene = self.scene_full(plan)?;
        let (boxes, centers) = scene.boxes_and_centers();
        let repeat = plan.spec.repeat as usize;
        let cost = plan.resolved.cost;
        let mut seconds = Vec::with_capacity(repeat);
        let mut first: Option<(Bvh, blake3::Hash)> = None;
        let input = match which {
            Which::Build => None,
            Which::Optimize => Some(self.bvh_full(plan, Which::Build)?),
            Which::Compact => Some(self.bvh_full(
                plan,
                if plan.optimize.is_some() {
                    Which::Optimize
                } else {
                    Which::Build
                },
            )?),
        };
        let optimizer = match which {
            Which::Optimize => {
                let o = plan
                    .optimizer
                    .clone()
                    .ok_or_else(|| Error::internal("chain has no optimizer"))?;
                Some((self.registry.optimizer(&o.optimizer)?.run, o))
            }
            _ => None,
        };
        let mut opt_info: Option<OptimizeInfo> = None;
        let encoding = match (which, &plan.encode) {
            (Which::Build, Some(_)) => Some(self.encode_full(plan)?),
            _ => None,
        };
        let codes = encoding.as_ref().map(|e| bvhlab_builders::SortedCodes {
            order: &e.encoding.order,
            codes: &e.encoding.codes,
            code_bits: e.encoding.code_bits,
        });
        let info = self.registry.get(&plan.resolved.builder)?.clone();
        if which == Which::Build && info.codes.is_some() != codes.is_some() {
            return Err(Error::internal(format!(
                "builder `{}`: codes expected iff it uses codes",
                info.name
            )));
        }
        for run in 0..repeat {
            // Only the method itself is timed; boxes and centres are shared input preparation.
            // Bottom-up builders include their SAH compaction (thesis: part of AAC / PLOC).
            let t = Instant::now();
            let bvh = match (&input, &optimizer) {
                (None, _) => {
                    let bvh = (info.run)(&boxes, &centers, codes.as_ref(), &plan.resolved);
                    if info.collapse {
                        (self.ops.collapse)(&bvh, cost)
                    } else {
                        bvh
                    }
                }
                (Some(built), Some((run, o))) => {
                    let out = run(&built.bvh, o);
                    if opt_info.is_none() {
                        opt_info = Some(OptimizeInfo {
                            trace: out.trace,
                            stop: out.stop.as_str().to_string(),
                            returned_pass: out.returned_pass,
                        });
                    }
                    out.bvh
                }
                (Some(built), None) => (self.ops.collapse)(&built.bvh, cost),
            };
            seconds.push(secs(t));
            let h = blake3::hash(&bvh.canonical_bytes());
            // A time-capped optimizer stops wherever the clock says: its runs may differ, and the
            // first run's tree is kept (the row says `optimize_stop = max_seconds`).
            let time_capped = optimizer.as_ref().is_some_and(|(_, o)| o.time_capped());
            match &first {
                None => first = Some((bvh, h)),
                Some(_) if time_capped => {}
                Some((_, h0)) if *h0 != h => {
                    return Err(Error::internal(format!(
                        "{} `{}` is not deterministic: run {} produced a different BVH than run 1 on {}",
                        node.stage,
                        node.params.get("builder").or(node.params.get("method")).cloned().unwrap_or_default(),
                        run + 1,
                        plan.spec.scene
                    )));
                }
                _ => {}
            }
        }
        let (bvh, hash) = first.ok_or_else(|| Error::internal("repeat = 0"))?;
        let metrics = (self.ops.metrics)(&bvh, cost);
        let validation = (self.ops.validate)(&bvh, &boxes);
        let summary = BvhSummary {
            metrics,
            valid: validation.is_ok(),
            invalid_reason: validation.err(),
            bvh_hash: hash.to_hex().to_string(),
            median_seconds: median(&seconds),
            seconds,
        };
        let art = BvhArtifact { bvh, summary };
        let mut files = BTreeMap::new();
        files.insert(
            "bin".into(),
            self.store.put(node.stage, &node.key, "bin", &art)?,
        );
        files.insert(
            "sum".into(),
            self.store.put(node.stage, &node.key, "sum", &art.summary)?,
        );
        if let Some(info) = opt_info {
            files.insert(
                "opt".into(),
                self.store.put(node.stage, &node.key, "opt", &info)?,
            );
            self.opt_infos.insert(node.key, info);
        }
        self.commit(&node, files, secs(t0))?;
        self.note(node.stage, node.key, true);
        let art = Arc::new(art);
        self.bvh_sums.insert(node.key, art.summary.clone());
        self.bvhs.insert(node.key, art.clone());
        Ok(art)
    }

    fn bvh_summary(&mut self, plan: &Plan, which: Which) -> Result<BvhSummary> {
        let node = Self::node(plan, which);
        let key = node.key;
        if let Some(s) = self.bvh_sums.get(&key) {
            return Ok(s.clone());
        }
        if let Some(s) = self.cached::<BvhSummary>(node, "sum") {
            self.note(node.stage, key, false);
            self.bvh_sums.insert(key, s.clone());
            return Ok(s);
        }
        let art = self.bvh_full(plan, which)?;
        let path = self.store.path(node.stage, &key, "sum");
        if !path.exists() {
            // Full artifact was intact but its summary was not: restore it (identical bytes).
            self.store.put(node.stage, &key, "sum", &art.summary)?;
        }
        Ok(art.summary.clone())
    }

    /// The optimize stage's trace and stop reason (read from `.opt`; recomputes the stage when that
    /// file is missing or corrupt).
    fn optimize_info(&mut self, plan: &Plan) -> Result<Option<OptimizeInfo>> {
        let Some(node) = plan.optimize.clone() else {
            return Ok(None);
        };
        if let Some(i) = self.opt_infos.get(&node.key) {
            return Ok(Some(i.clone()));
        }
        if let Some(i) = self.cached::<OptimizeInfo>(&node, "opt") {
            self.opt_infos.insert(node.key, i.clone());
            return Ok(Some(i));
        }
        // Artifact present but its trace unreadable: drop the in-memory copy and recompute the stage.
        self.bvhs.remove(&node.key);
        let path = self.store.path("optimize", &node.key, "bin");
        if path.exists() {
            self.store.quarantine(&path);
        }
        self.bvh_full(plan, Which::Optimize)?;
        self.opt_infos
            .get(&node.key)
            .cloned()
            .map(Some)
            .ok_or_else(|| Error::internal("optimize stage produced no trace"))
    }

    // ---- layout -------------------------------------------------------------------------------

    fn layout_full(&mut self, plan: &Plan) -> Result<Arc<LayoutArtifact>> {
        let (node, req) = plan
            .layout
            .clone()
            .ok_or_else(|| Error::internal("chain has no layout stage"))?;
        if let Some(a) = self.layouts.get(&node.key) {
            return Ok(a.clone());
        }
        if let Some(a) = self.cached::<LayoutArtifact>(&node, "bin") {
            self.note("layout", node.key, false);
            let a = Arc::new(a);
            self.layout_sums.insert(node.key, a.summary.clone());
            self.layouts.insert(node.key, a.clone());
            return Ok(a);
        }
        let t0 = Instant::now();
        let scene = self.scene_full(plan)?;
        let tris = &scene.triangles;
        let cost = plan.resolved.cost;
        let needs_bvh = match &req {
            LayoutRequest::Fixed(l) => bvhlab_layout::uses_bvh(&l.name),
            LayoutRequest::Auto(_) => true,
        };
        // Octrees ignore the BVH: do not load (or compute) it for them.
        let final_bvh = if needs_bvh {
            Some(self.bvh_full(plan, plan.final_which())?)
        } else {
            None
        };
        let empty = Bvh {
            nodes: Vec::new(),
            prim_indices: Vec::new(),
        };
        let bvh = final_bvh.as_ref().map(|a| &a.bvh).unwrap_or(&empty);
        let (spec, choice) = match req {
            LayoutRequest::Fixed(l) => (l, None),
            LayoutRequest::Auto(a) => {
                let (l, c) = self.auto_search(plan, a, bvh, &scene)?;
                (l, Some(c))
            }
        };
        let mut seconds = Vec::new();
        let mut first: Option<(bvhlab_layout::Layout, blake3::Hash)> = None;
        let mut peak = 0;
        for run in 0..plan.spec.repeat {
            // Peak heap of the first build only (later builds reuse freed memory the same way).
            let mark = (run == 0).then(crate::memtrack::reset_peak);
            let t = Instant::now();
            let l = (self.ops.layout)(&spec, bvh, tris, None).map_err(|e| {
                Error::internal(format!(
                    "layout `{}` on {}: {e}",
                    spec.name, plan.spec.scene
                ))
            })?;
            seconds.push(secs(t));
            if let Some(m) = mark {
                peak = crate::memtrack::peak_since(m);
            }
            let bytes = crate::codec::encode(&l).map_err(Error::internal)?;
            let h = blake3::hash(&bytes);
            match &first {
                None => first = Some((l, h)),
                Some((_, h0)) if *h0 != h => {
                    return Err(Error::internal(format!(
                        "layout `{}` is not deterministic: run {} produced a different layout than run 1 on {}",
                        spec.name,
                        run + 1,
                        plan.spec.scene
                    )));
                }
                _ => {}
            }
        }
        let (layout, hash) = first.ok_or_else(|| Error::internal("repeat = 0"))?;
        let validation = layout.validate(tris);
        let summary = LayoutSummary {
            layout: spec.name.clone(),
            params: spec.params_string(),
            memory: layout.memory(),
            median_seconds: median(&seconds),
            seconds,
            sah_cost: layout.sah_cost(cost),
            valid: validation.is_ok(),
            invalid_reason: validation.err(),
            peak_build_bytes: peak,
            layout_hash: hash.to_hex().to_string(),
            choice,
        };
        let art = LayoutArtifact { layout, summary };
        let mut files = BTreeMap::new();
        files.insert(
            "bin".into(),
            self.store.put("layout", &node.key, "bin", &art)?,
        );
        files.insert(
            "sum".into(),
            self.store.put("layout", &node.key, "sum", &art.summary)?,
        );
        self.commit(&node, files, secs(t0))?;
        self.note("layout", node.key, true);
        let art = Arc::new(art);
        self.layout_sums.insert(node.key, art.summary.clone());
        self.layouts.insert(node.key, art.clone());
        Ok(art)
    }

    fn layout_summary(&mut self, plan: &Plan) -> Result<Option<LayoutSummary>> {
        let Some((node, _)) = plan.layout.as_ref() else {
            return Ok(None);
        };
        let key = node.key;
        if let Some(s) = self.layout_sums.get(&key) {
            return Ok(Some(s.clone()));
        }
        if let Some(s) = self.cached::<LayoutSummary>(node, "sum") {
            self.note("layout", key, false);
            self.layout_sums.insert(key, s.clone());
            return Ok(Some(s));
        }
        let art = self.layout_full(plan)?;
        if !self.store.path("layout", &key, "sum").exists() {
            // Full artifact intact, summary not: restore it (identical bytes).
            self.store.put("layout", &key, "sum", &art.summary)?;
        }
        Ok(Some(art.summary.clone()))
    }

    /// `layout=auto`: the candidate of `auto_candidates()` with the fewest total bytes whose trace
    /// of a random ray sample takes at most `max_slowdown` times bvh2's on the same BVH (bvh2, the
    /// baseline, always qualifies). Timing-dependent, hence machine dependent: the decision and the
    /// measured table are stored.
    ///
    /// Bounded (issue 15: over 300 s on thin hair, where one bvh2 trace of the sample takes 36 s
    /// and the old search traced ~100 times, and on a huge ground plane, whose octree build never
    /// ends): the search may spend `budget` times one bvh2 trace of its rays. It is an anytime
    /// search: candidates are built in list order and only one smaller than the best qualifying
    /// so far (bvh2 first) is validated, checked against bvh2's hits and timed (median of
    /// `AUTO_RUNS` alternated runs), so the best so far is always a measured choice. Once the
    /// budget is spent nothing more is built or timed (`budget_cut`); octree builds stop at the
    /// deadline, a timing starts only if its traces are predicted to fit (from the last slowdown,
    /// then from the candidate's own first trace), so the overrun is at most one build of a BVH
    /// layout or one trace.
    fn auto_search(
        &self,
        plan: &Plan,
        a: AutoSpec,
        bvh: &Bvh,
        scene: &Scene,
    ) -> Result<(bvhlab_layout::LayoutSpec, AutoChoice)> {
        let t_search = Instant::now();
        let tris = &scene.triangles;
        let rays = random_ray_set(scene, a.rays, AUTO_SEED);
        let t = Instant::now();
        let reference = bvhlab_trace::trace(bvh, tris, &rays);
        let bvh2_trace_seconds = secs(t);
        let budget_seconds = a.budget * bvh2_trace_seconds;
        let t_budget = Instant::now();
        let left = || budget_seconds - t_budget.elapsed().as_secs_f64();
        // One untimed and AUTO_RUNS timed traces of a candidate at slowdown `s`, and AUTO_RUNS of bvh2.
        let cost = |s: f64| bvh2_trace_seconds * ((1 + AUTO_RUNS) as f64 * s + AUTO_RUNS as f64);
        let tri_count = tris.len().max(1) as f64;
        let mut specs = Vec::new();
        let mut candidates: Vec<AutoCandidate> = Vec::new();
        let mut budget_cut = false;
        let mut best: Option<usize> = None;
        let mut last_slowdown = 1.0f64;
        for (i, c) in auto_candidates().into_iter().enumerate() {
            let spec = match parse_layout(&c)? {
                LayoutRequest::Fixed(l) => l,
                LayoutRequest::Auto(_) => return Err(Error::internal("auto candidate `auto`")),
            };
            let mut cand = AutoCandidate {
                layout: spec.name.clone(),
                params: spec.params_string(),
                total_bytes: 0,
                total_bytes_per_triangle: 0.0,
                seconds: Vec::new(),
                bvh2_seconds: Vec::new(),
                slowdown: 0.0,
                error: None,
                build_seconds: 0.0,
                skipped: None,
            };
            let is_bvh2 = spec.name == "bvh2";
            specs.push(spec);
            // bvh2 (first) is the fallback: always built, whatever the budget.
            if !is_bvh2 && left() <= 0.0 {
                cand.skipped = Some("budget spent before its build".into());
                budget_cut = true;
                candidates.push(cand);
                continue;
            }
            let spec = &specs[i];
            let t = Instant::now();
            let deadline = (!is_bvh2)
                .then(|| t_budget + std::time::Duration::from_secs_f64(budget_seconds.min(1e9)));
            let built = (self.ops.layout)(spec, bvh, tris, deadline);
            cand.build_seconds = secs(t);
            let l = match built {
                Err(e) if e.starts_with(bvhlab_layout::DEADLINE_REACHED) => {
                    cand.skipped = Some(format!("budget spent during its build ({e})"));
                    budget_cut = true;
                    candidates.push(cand);
                    continue;
                }
                Err(e) => {
                    cand.error = Some(e);
                    candidates.push(cand);
                    continue;
                }
                Ok(l) => l,
            };
            let mem = l.memory();
            cand.total_bytes = mem.total_bytes;
            cand.total_bytes_per_triangle = mem.total_bytes as f64 / tri_count;
            if is_bvh2 {
                // The baseline itself (the input BVH, validated by its own stage): slowdown 1
                // by definition, no timing needed.
                cand.slowdown = 1.0;
                candidates.push(cand);
                best = Some(i);
                continue;
            }
            if let Some(b) = best {
                if cand.total_bytes >= candidates[b].total_bytes {
                    cand.skipped = Some(format!(
                        "not smaller than {} {} (cannot win)",
                        candidates[b].layout, candidates[b].params
                    ));
                    candidates.push(cand);
                    continue;
                }
            }
            if let Err(e) = l.validate(tris) {
                cand.error = Some(format!("invalid: {e}"));
                candidates.push(cand);
                continue;
            }
            // A slow layout (an octree on hair at 2.2x) overran a prediction made with 1 by
            // 200 s: predict from the last slowdown, then again from its own first trace.
            if cost(last_slowdown) > left() {
                cand.skipped = Some(format!(
                    "budget: its timing (~{:.2} s predicted) does not fit in the {:.2} s left",
                    cost(last_slowdown),
                    left().max(0.0)
                ));
                budget_cut = true;
                candidates.push(cand);
                continue;
            }
            // Untimed first run (warms caches) doubles as an exactness check.
            let t = Instant::now();
            let st = l.trace(tris, &rays);
            let own = secs(t) / bvh2_trace_seconds.max(1e-9);
            let bad = hit_mismatches(&st.hits, &reference.hits);
            if bad > 0 {
                cand.error = Some(format!("{bad} hits differ from bvh2"));
                candidates.push(cand);
                continue;
            }
            let rest = bvh2_trace_seconds * AUTO_RUNS as f64 * (own + 1.0);
            if rest > left() {
                cand.skipped = Some(format!(
                    "budget: its timed runs (~{rest:.2} s predicted from its first trace, {own:.2}x bvh2) \
                     do not fit in the {:.2} s left",
                    left().max(0.0)
                ));
                budget_cut = true;
                candidates.push(cand);
                continue;
            }
            for run in 0..AUTO_RUNS {
                // Alternate which goes first so neither side always runs warm.
                for layout_turn in [run % 2 == 0, run % 2 == 1] {
                    let t = Instant::now();
                    if layout_turn {
                        std::hint::black_box(l.trace(tris, &rays));
                        cand.seconds.push(secs(t));
                    } else {
                        std::hint::black_box(bvhlab_trace::trace(bvh, tris, &rays));
                        cand.bvh2_seconds.push(secs(t));
                    }
                }
            }
            let b = median(&cand.bvh2_seconds);
            cand.slowdown = if b > 0.0 {
                median(&cand.seconds) / b
            } else {
                1.0
            };
            last_slowdown = cand.slowdown.max(0.5);
            if cand.slowdown <= a.max_slowdown {
                best = Some(i);
            }
            candidates.push(cand);
        }
        let chosen = best.ok_or_else(|| {
            Error::internal(format!(
                "layout auto on {}: no usable candidate (bvh2 failed)",
                plan.spec.scene
            ))
        })?;
        let search_seconds = secs(t_search);
        let c = &candidates[chosen];
        let over_limit = c.slowdown > a.max_slowdown;
        let label = |c: &AutoCandidate| {
            if c.params.is_empty() {
                c.layout.clone()
            } else {
                format!("{} {}", c.layout, c.params)
            }
        };
        let skipped: Vec<String> = candidates
            .iter()
            .filter(|c| {
                c.skipped
                    .as_deref()
                    .is_some_and(|s| s.starts_with("budget"))
            })
            .map(label)
            .collect();
        let table: Vec<String> = candidates
            .iter()
            .map(|c| match (&c.error, &c.skipped) {
                (Some(e), _) => format!("{} (unusable: {e})", label(c)),
                (None, Some(why)) if c.total_bytes == 0 => format!("{} ({why})", label(c)),
                (None, Some(why)) => format!(
                    "{} ({:.2} B/tri, not timed: {why})",
                    label(c),
                    c.total_bytes_per_triangle
                ),
                (None, None) => format!(
                    "{} ({:.2} B/tri, {:.2}x)",
                    label(c),
                    c.total_bytes_per_triangle,
                    c.slowdown
                ),
            })
            .collect();
        let cut = if budget_cut {
            format!(
                "; BUDGET CUT: {} candidate(s) not measured ({}), the choice is the best of the rest",
                skipped.len(),
                skipped.join(", ")
            )
        } else {
            String::new()
        };
        let over = if over_limit {
            format!(
                "; OVER LIMIT: slowdown {:.2}x > max_slowdown {}",
                c.slowdown, a.max_slowdown
            )
        } else {
            String::new()
        };
        let reason = format!(
            "{}: fewest total bytes ({:.2} B/tri) with slowdown {:.2}x <= max_slowdown {} (bvh2 always qualifies; \
             {} random rays, median of {} alternated runs, smallest first); search {:.2} s of a budget of {} x \
             {:.4} s bvh2 trace = {:.2} s{cut}{over}; candidates: {}",
            label(c),
            c.total_bytes_per_triangle,
            c.slowdown,
            a.max_slowdown,
            a.rays,
            AUTO_RUNS,
            search_seconds,
            a.budget,
            bvh2_trace_seconds,
            budget_seconds,
            table.join("; ")
        );
        let choice = AutoChoice {
            max_slowdown: a.max_slowdown,
            rays: a.rays,
            candidates,
            chosen,
            reason,
            budget: a.budget,
            bvh2_trace_seconds,
            budget_seconds,
            search_seconds,
            budget_cut,
            skipped,
            over_limit,
        };
        Ok((specs.swap_remove(chosen), choice))
    }

    // ---- measure ------------------------------------------------------------------------------

    fn measure(&mut self, plan: &Plan) -> Result<MeasureSummary> {
        let (node, rays_spec) = plan.measure.clone().expect("measure node");
        // Primary rays leave a heat map the report copies: checked like the summary.
        let also: &[&str] = match rays_spec {
            RaySpec::Primary { .. } => &["png"],
            _ => &[],
        };
        if let Some(m) = self.cached_with::<MeasureSummary>(&node, "sum", also) {
            self.note("measure", node.key, false);
            return Ok(m);
        }
        let t0 = Instant::now();
        let scene = self.scene_full(plan)?;
        let final_bvh = self.bvh_full(plan, plan.final_which())?;
        let layout = match plan.layout {
            Some(_) => Some(self.layout_full(plan)?),
            None => None,
        };
        let bvh = &final_bvh.bvh;
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
        let mut seconds = Vec::new();
        let mut bvh2_seconds = Vec::new();
        let mut first = None;
        for run in 0..plan.spec.repeat {
            match &layout {
                None => {
                    let t = Instant::now();
                    let st = bvhlab_trace::trace(bvh, tris, &rays);
                    seconds.push(secs(t));
                    first.get_or_insert(st);
                }
                Some(l) if matches!(l.layout, bvhlab_layout::Layout::Bvh2(_)) => {
                    // bvh2 against bvh2 is the same traversal of the same tree: one timing per
                    // run stands for both sides, so the slowdown is exactly 1 by construction
                    // (timing it twice measured only noise: 5.1 was seen on a loaded machine).
                    let t = Instant::now();
                    let st = l.layout.trace(tris, &rays);
                    let s = secs(t);
                    seconds.push(s);
                    bvh2_seconds.push(s);
                    first.get_or_insert(st);
                }
                Some(l) => {
                    // The bvh2 anchor runs beside the layout on the same rays, alternating which
                    // goes first, so slowdown compares runs under the same machine conditions.
                    let mut time_layout = || {
                        let t = Instant::now();
                        let st = l.layout.trace(tris, &rays);
                        seconds.push(secs(t));
                        first.get_or_insert(st);
                    };
                    let mut time_bvh2 = || {
                        let t = Instant::now();
                        std::hint::black_box(bvhlab_trace::trace(bvh, tris, &rays));
                        bvh2_seconds.push(secs(t));
                    };
                    if run % 2 == 0 {
                        time_layout();
                        time_bvh2();
                    } else {
                        time_bvh2();
                        time_layout();
                    }
                }
            }
        }
        let st = first.ok_or_else(|| Error::internal("repeat = 0"))?;
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
                let path = self.store.path("measure", &node.key, "png");
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
        };
        files.insert(
            "sum".into(),
            self.store.put("measure", &node.key, "sum", &m)?,
        );
        self.commit(&node, files, secs(t0))?;
        self.note("measure", node.key, true);
        Ok(m)
    }

    // ---- focus ----------------------------------------------------------------------------------

    fn focus(&mut self, plan: &Plan) -> Result<Option<FocusSummary>> {
        let (Some(node), Some(focus_box)) = (plan.focus.clone(), plan.spec.focus) else {
            return Ok(None);
        };
        if let Some(f) = self.cached::<FocusSummary>(&node, "sum") {
            self.note("focus", node.key, false);
            return Ok(Some(f));
        }
        let t0 = Instant::now();
        let scene = self.scene_full(plan)?;
        let final_bvh = self.bvh_full(plan, plan.final_which())?;
        let (boxes, centers) = scene.boxes_and_centers();
        // A triangle is in focus when its centroid (box centre, as the builders see it) is inside.
        let in_focus: Vec<bool> = centers
            .iter()
            .map(|c| focus_box.min.cmple(*c).all() && c.cmple(focus_box.max).all())
            .collect();
        let result =
            bvhlab_bvh::focus::focus_cost(&final_bvh.bvh, &in_focus, &boxes, plan.resolved.cost);
        let f = FocusSummary {
            triangles: in_focus.iter().filter(|&&x| x).count() as u64,
            sah_cost: result.map(|(_, c)| c),
        };
        let mut files = BTreeMap::new();
        files.insert("sum".into(), self.store.put("focus", &node.key, "sum", &f)?);
        self.commit(&node, files, secs(t0))?;
        self.note("focus", node.key, true);
        Ok(Some(f))
    }

    /// CPU model a node was computed on (its manifest's; "" if unknown).
    fn node_cpu_model(&mut self, node: &NodeDef) -> String {
        if let Some(m) = self.cpu_models.get(&(node.stage, node.key)) {
            return m.clone();
        }
        let m = self
            .store
            .read_manifest(node.stage, &node.key)
            .map(|m| m.machine.cpu_model)
            .unwrap_or_default();
        self.cpu_models.insert((node.stage, node.key), m.clone());
        m
    }

    /// The row's `machine`, `machine_mixed` and `build_machine` from the timed nodes of the chain
    /// (unknown models are compatible with any: caches written before models were recorded are
    /// not flagged).
    fn timing_machine(&mut self, plan: &Plan) -> (String, bool, String) {
        let mut build: Vec<NodeDef> = Vec::new();
        build.extend(plan.encode.clone());
        build.push(plan.build.clone());
        build.extend(plan.optimize.clone());
        build.extend(plan.compact.clone());
        let mut trace: Vec<NodeDef> = Vec::new();
        trace.extend(plan.layout.as_ref().map(|(n, _)| n.clone()));
        trace.extend(plan.measure.as_ref().map(|(n, _)| n.clone()));
        let mut models: Vec<String> = Vec::new();
        let mut build_models = 0;
        for (i, n) in build.iter().chain(&trace).enumerate() {
            let m = self.node_cpu_model(n);
            if !m.is_empty() && !models.contains(&m) {
                models.push(m);
            }
            if i + 1 == build.len() {
                build_models = models.len();
            }
        }
        (
            models.join(" + "),
            models.len() > 1,
            models[..build_models].join(" + "),
        )
    }

    // ---- single nodes (plans and shards, crate::plan) --------------------------------------------

    /// The nodes of `spec`'s stage graph in chain order (load, encode, build, optimize, compact,
    /// layout, measure, focus; absent stages skipped), with keys, inputs and parameters. Runs
    /// nothing and reads nothing but a scene file's bytes (its key hashes the content).
    pub fn chain_nodes(&mut self, spec: &ChainSpec) -> Result<Vec<NodeInfo>> {
        let p = self.plan(spec)?;
        let mut v = vec![p.load];
        v.extend(p.encode);
        v.push(p.build);
        v.extend(p.optimize);
        v.extend(p.compact);
        v.extend(p.layout.map(|(n, _)| n));
        v.extend(p.measure.map(|(n, _)| n));
        v.extend(p.focus);
        Ok(v.into_iter()
            .map(|n| NodeInfo {
                stage: n.stage,
                key: n.key,
                inputs: n.inputs,
                params: n.params,
            })
            .collect())
    }

    /// Makes sure the node of `spec` at `stage` is in the cache (computing it, and any missing
    /// input, if needed), at the level a result row needs (summaries), under the same per-key
    /// protocol as `run_chain`: a node another process is computing is waited for, not computed
    /// twice. Errors if the chain has no such stage.
    pub fn ensure_node(&mut self, spec: &ChainSpec, stage: &str) -> Result<()> {
        let _locks = self.store.release_on_drop();
        let plan = self.plan(spec)?;
        let missing = || Error::internal(format!("chain has no {stage} stage"));
        match stage {
            "load" => {
                self.scene_summary(&plan)?;
            }
            "encode" => {
                self.encode_summary(&plan)?.ok_or_else(missing)?;
            }
            "build" => {
                self.bvh_summary(&plan, Which::Build)?;
            }
            "optimize" => {
                plan.optimize.as_ref().ok_or_else(missing)?;
                self.bvh_summary(&plan, Which::Optimize)?;
                self.optimize_info(&plan)?;
            }
            "compact" => {
                plan.compact.as_ref().ok_or_else(missing)?;
                self.bvh_summary(&plan, Which::Compact)?;
            }
            "layout" => {
                self.layout_summary(&plan)?.ok_or_else(missing)?;
            }
            "measure" => {
                plan.measure.as_ref().ok_or_else(missing)?;
                self.measure(&plan)?;
            }
            "focus" => {
                self.focus(&plan)?.ok_or_else(missing)?;
            }
            _ => return Err(missing()),
        }
        Ok(())
    }

    // ---- chain ----------------------------------------------------------------------------------

    /// Runs (or reads from the cache) every stage of `spec` and returns its result row.
    pub fn run_chain(&mut self, spec: &ChainSpec, experiment: &str) -> Result<ResultRow> {
        let _locks = self.store.release_on_drop(); // compute locks end with the chain (cached)
        let plan = self.plan(spec)?;
        let scene = self.scene_summary(&plan)?;
        let encode = self.encode_summary(&plan)?;
        let build = self.bvh_summary(&plan, Which::Build)?;
        let optimized = match plan.optimize {
            Some(_) => Some(self.bvh_summary(&plan, Which::Optimize)?),
            None => None,
        };
        let opt_info = self.optimize_info(&plan)?;
        let compact = match plan.compact {
            Some(_) => Some(self.bvh_summary(&plan, Which::Compact)?),
            None => None,
        };
        let layout = self.layout_summary(&plan)?;
        let measure = match plan.measure {
            Some(_) => Some(self.measure(&plan)?),
            None => None,
        };
        let focus = self.focus(&plan)?;
        let fin = compact.as_ref().or(optimized.as_ref()).unwrap_or(&build);
        let m = &fin.metrics;
        let (machine, machine_mixed, build_machine) = self.timing_machine(&plan);
        let mut keys = BTreeMap::new();
        keys.insert("load".to_string(), plan.load.key.hex());
        if let Some(e) = &plan.encode {
            keys.insert("encode".to_string(), e.key.hex());
        }
        keys.insert("build".to_string(), plan.build.key.hex());
        if let Some(o) = &plan.optimize {
            keys.insert("optimize".to_string(), o.key.hex());
        }
        if let Some(c) = &plan.compact {
            keys.insert("compact".to_string(), c.key.hex());
        }
        if let Some((n, _)) = &plan.measure {
            keys.insert("measure".to_string(), n.key.hex());
        }
        if let Some(n) = &plan.focus {
            keys.insert("focus".to_string(), n.key.hex());
        }
        if let Some((n, _)) = &plan.layout {
            keys.insert("layout".to_string(), n.key.hex());
        }
        let mut method = self.registry.label(&plan.resolved);
        if let Some(e) = &plan.encoder {
            method.push_str(&format!(" \u{b7} {}", self.registry.encoder_label(e)));
        }
        if let Some(o) = &plan.optimizer {
            method.push_str(&format!(" +{}", self.registry.optimizer_label(o)));
        }
        if spec.compact != "none" {
            method.push_str(&format!(" +{}", spec.compact));
        }
        // `auto` keeps its request in the label (scene independent, so plots group its rows); the
        // layout it picked per scene is in `layout` / `layout_params`.
        match &plan.layout {
            Some((_, LayoutRequest::Fixed(l))) if l.params.is_empty() => {
                method.push_str(&format!(" @{}", l.name))
            }
            Some((_, LayoutRequest::Fixed(l))) => {
                method.push_str(&format!(" @{} {}", l.name, l.params_string()))
            }
            Some((_, LayoutRequest::Auto(a))) => {
                method.push_str(&format!(
                    " @auto max_slowdown={},rays={}",
                    a.max_slowdown, a.rays
                ));
                // Only a non-default budget shows: labels of earlier reports stay the same.
                if a.budget != AUTO_BUDGET {
                    method.push_str(&format!(",budget={}", a.budget));
                }
            }
            None => {}
        }
        let per_ray = |total: u64, rays: u64| {
            if rays == 0 {
                0.0
            } else {
                total as f64 / rays as f64
            }
        };
        let mut row = ResultRow {
            experiment: experiment.to_string(),
            scene: spec.scene.clone(),
            scene_name: scene_name(&spec.scene),
            triangles: scene.triangles,
            dropped_triangles: scene.dropped_triangles,
            precision_loss: Some(scene.precision_loss),
            precision_warning: crate::stages::precision_warning(&spec.scene, scene.precision_loss),
            builder: plan.resolved.builder.clone(),
            build_params: params_string(&plan.resolved.params),
            compact: spec.compact.clone(),
            method,
            c_t: plan.resolved.cost.c_t as f64,
            c_i: plan.resolved.cost.c_i as f64,
            sah_cost: m.sah_cost,
            inner_sa_ratio: m.inner_sa_ratio,
            leaf_sa_ratio: m.leaf_sa_ratio,
            refs_per_leaf: m.refs_per_leaf,
            inner_nodes: m.inner_nodes,
            leaves: m.leaves,
            depth: m.depth,
            bytes: m.bytes,
            bytes_per_triangle: m.bytes as f64 / scene.triangles.max(1) as f64,
            valid: build.valid
                && optimized.as_ref().is_none_or(|o| o.valid)
                && fin.valid
                && layout.as_ref().is_none_or(|l| l.valid),
            bvh_hash: fin.bvh_hash.clone(),
            build_seconds: build.median_seconds,
            encoder: plan.encoder.as_ref().map(|e| e.encoder.clone()),
            encode_params: plan.encoder.as_ref().map(|e| params_string(&e.params)),
            encode_seconds: encode.as_ref().map(|e| e.median_seconds),
            code_bits: encode.as_ref().map(|e| e.code_bits),
            duplicate_code_fraction: encode.as_ref().map(|e| e.duplicate_fraction),
            total_build_seconds: encode.as_ref().map(|e| e.median_seconds).unwrap_or(0.0)
                + build.median_seconds
                + optimized.as_ref().map(|o| o.median_seconds).unwrap_or(0.0),
            build_sah_cost: Some(build.metrics.sah_cost),
            optimizer: plan.optimizer.as_ref().map(|o| o.optimizer.clone()),
            optimize_params: plan.optimizer.as_ref().map(|o| params_string(&o.params)),
            optimize_seconds: optimized.as_ref().map(|o| o.median_seconds),
            optimized_sah_cost: optimized.as_ref().map(|o| o.metrics.sah_cost),
            optimize_passes: opt_info
                .as_ref()
                .map(|i| i.trace.len().saturating_sub(1) as u32),
            optimize_stop: opt_info.as_ref().map(|i| i.stop.clone()),
            optimize_trace: opt_info.map(|i| i.trace),
            threads: rayon::current_num_threads() as u32,
            machine,
            machine_mixed,
            build_machine,
            focus_triangles: focus.as_ref().map(|f| f.triangles),
            focus_sah_cost: focus.as_ref().and_then(|f| f.sah_cost),
            compact_seconds: compact.as_ref().map(|c| c.median_seconds).unwrap_or(0.0),
            rays_kind: measure.as_ref().map(|x| x.rays_kind.clone()),
            rays: measure.as_ref().map(|x| x.rays),
            hits: measure.as_ref().map(|x| x.hits),
            traversal_steps_per_ray: measure.as_ref().map(|x| per_ray(x.total_steps, x.rays)),
            intersections_per_ray: measure
                .as_ref()
                .map(|x| per_ray(x.total_intersections, x.rays)),
            trace_seconds: measure.as_ref().map(|x| x.median_seconds),
            mrays_per_s: measure.as_ref().map(|x| {
                if x.median_seconds > 0.0 {
                    x.rays as f64 / x.median_seconds / 1e6
                } else {
                    0.0
                }
            }),
            heatmap: measure
                .as_ref()
                .and_then(|x| x.heatmap.as_ref())
                .map(|h| self.store.root().join(h).to_string_lossy().to_string()),
            layout: layout.as_ref().map(|l| l.layout.clone()),
            layout_params: layout.as_ref().map(|l| l.params.clone()),
            topology_bytes: layout.as_ref().map(|l| l.memory.topology_bytes),
            total_bytes: layout.as_ref().map(|l| l.memory.total_bytes),
            topology_bytes_per_triangle: layout
                .as_ref()
                .map(|l| l.memory.topology_bytes as f64 / scene.triangles.max(1) as f64),
            total_bytes_per_triangle: layout
                .as_ref()
                .map(|l| l.memory.total_bytes as f64 / scene.triangles.max(1) as f64),
            topology_bits_per_node: layout.as_ref().map(|l| l.memory.topology_bits_per_node()),
            layout_nodes: layout.as_ref().map(|l| l.memory.nodes),
            chunks: layout.as_ref().map(|l| l.memory.chunks),
            chunk_fill: layout.as_ref().map(|l| l.memory.chunk_fill),
            prim_refs: layout.as_ref().map(|l| l.memory.prim_refs),
            peak_build_bytes: layout.as_ref().map(|l| l.peak_build_bytes),
            layout_seconds: layout.as_ref().map(|l| l.median_seconds),
            layout_sah_cost: layout.as_ref().map(|l| l.sah_cost),
            extra_box_hits_per_ray: measure.as_ref().and_then(|x| x.extra_box_hits_per_ray),
            extra_tests_per_ray: measure.as_ref().and_then(|x| x.extra_tests_per_ray),
            bvh2_trace_seconds: measure.as_ref().and_then(|x| x.bvh2_median_seconds),
            slowdown: measure.as_ref().and_then(|x| {
                x.bvh2_median_seconds
                    .filter(|&b| b > 0.0)
                    .map(|b| x.median_seconds / b)
            }),
            layout_choice: layout
                .as_ref()
                .and_then(|l| l.choice.as_ref().map(|c| c.reason.clone())),
            auto_budget_cut: layout
                .as_ref()
                .and_then(|l| l.choice.as_ref().map(|c| c.budget_cut)),
            auto_max_slowdown: layout
                .as_ref()
                .and_then(|l| l.choice.as_ref().map(|c| c.max_slowdown)),
            ..Default::default()
        };
        row.keys = keys;
        // Issue 16: every timed quantity keeps its runs and their spread beside the median.
        let runs = |v: &[f64]| Some(v.to_vec());
        row.build_seconds_spread = spread(&build.seconds);
        row.build_seconds_runs = runs(&build.seconds);
        if let Some(e) = &encode {
            row.encode_seconds_spread = spread(&e.seconds);
            row.encode_seconds_runs = runs(&e.seconds);
        }
        if let Some(o) = &optimized {
            row.optimize_seconds_spread = spread(&o.seconds);
            row.optimize_seconds_runs = runs(&o.seconds);
        }
        if let Some(c) = &compact {
            row.compact_seconds_spread = spread(&c.seconds);
            row.compact_seconds_runs = runs(&c.seconds);
        }
        row.total_build_seconds_spread = {
            let stages: Vec<&[f64]> = [
                encode.as_ref().map(|e| e.seconds.as_slice()),
                Some(build.seconds.as_slice()),
                optimized.as_ref().map(|o| o.seconds.as_slice()),
            ]
            .into_iter()
            .flatten()
            .collect();
            let range = |v: &[f64]| {
                v.iter().copied().fold(f64::NEG_INFINITY, f64::max)
                    - v.iter().copied().fold(f64::INFINITY, f64::min)
            };
            (stages.iter().all(|v| spread(v).is_some()) && row.total_build_seconds > 0.0)
                .then(|| stages.iter().map(|v| range(v)).sum::<f64>() / row.total_build_seconds)
        };
        if let Some(x) = &measure {
            row.trace_seconds_spread = spread(&x.seconds);
            row.trace_seconds_runs = runs(&x.seconds);
            let mrays: Vec<f64> = x
                .seconds
                .iter()
                .filter(|&&t| t > 0.0)
                .map(|t| x.rays as f64 / t / 1e6)
                .collect();
            row.mrays_per_s_spread = (mrays.len() == x.seconds.len())
                .then(|| spread(&mrays))
                .flatten();
            if let Some(b) = &x.bvh2_seconds {
                row.bvh2_trace_seconds_spread = spread(b);
                row.bvh2_trace_seconds_runs = runs(b);
                let r = paired_ratios(&x.seconds, b);
                if !r.is_empty() {
                    row.slowdown_spread = spread(&r);
                    row.slowdown_runs = Some(r);
                }
            }
        }
        if let Some(l) = &layout {
            row.layout_seconds_spread = spread(&l.seconds);
            row.layout_seconds_runs = runs(&l.seconds);
            if let Some(c) = &l.choice {
                let chosen = &c.candidates[c.chosen];
                row.auto_search_slowdown = Some(chosen.slowdown);
                row.auto_search_slowdown_spread = if chosen.layout == "bvh2" {
                    Some(0.0)
                } else {
                    spread(&paired_ratios(&chosen.seconds, &chosen.bvh2_seconds))
                };
            }
        }
        // The choice was judged on the search's random rays; this row's slowdown is measured
        // again on the chain's own rays (often primary, where compressed layouts lose more) and
        // under other machine load. Either one above the limit is flagged, never silent.
        row.auto_over_limit = layout
            .as_ref()
            .and_then(|l| l.choice.as_ref())
            .map(|c| c.over_limit || row.slowdown.is_some_and(|s| s > c.max_slowdown));
        Ok(row)
    }
}

/// Runs `f` in a rayon pool of `threads` threads (None: rayon's default pool).
pub fn with_threads<T: Send>(threads: Option<usize>, f: impl FnOnce() -> T + Send) -> Result<T> {
    match threads {
        None => Ok(f()),
        Some(0) => Err(Error::input("--threads must be at least 1")),
        Some(n) => {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .map_err(|e| Error::internal(format!("cannot start {n} threads: {e}")))?;
            Ok(pool.install(f))
        }
    }
}

/// Random rays (thesis 4.4) on a sphere around the scene box centre enclosing every triangle
/// centroid.
fn random_ray_set(scene: &Scene, count: u32, seed: u64) -> Vec<bvhlab_trace::Ray> {
    let bounds = scene.bounds();
    let r = bounds.enclosing_radius(scene.triangles.iter().map(|t| t.bounds().center()));
    bvhlab_trace::random_rays(&bounds, r, count as usize, seed)
}

/// Rays whose closest hit differs: another triangle, or t off by more than 1e-6 relative.
fn hit_mismatches(a: &[bvhlab_trace::Hit], b: &[bvhlab_trace::Hit]) -> usize {
    if a.len() != b.len() {
        return a.len().max(b.len());
    }
    a.iter()
        .zip(b)
        .filter(|(x, y)| {
            let same_t = x.t == y.t || (x.t - y.t).abs() <= 1e-6 * x.t.abs().max(y.t.abs());
            x.is_hit() != y.is_hit() || (x.is_hit() && !(x.prim == y.prim || same_t))
        })
        .count()
}
