//! Runs chains against the store, computing only nodes whose keys are not cached.
//!
//! One generic evaluator for every stage: a stage (`Stage`, one per file in `stages/`) declares its
//! node (version, canonical parameters, inputs) and its compute function; `Runner` owns the rest:
//! the in-memory memo, the key, the compute lock, the store, verification on read, the commit and
//! the counting. The stages and their order are the chain definition (`stages/chain.rs`).
//!
//! Keys are computed up front from parameters and input keys (never from artifact contents,
//! except a scene file's bytes), then each node is resolved lazily: a row needs only the small
//! summaries, so a warm run reads `.sum` files and never decodes scenes or BVHs. A node is counted
//! once per run, as `computed` or `cached` (read from disk).
use crate::error::{Error, Result};
use crate::key::{stage_key, Key};
use crate::registry::Registry;
use crate::stages::chain::{self, Plan};
use crate::stages::{ChainSpec, Ops, Versions};
use crate::store::{now_unix, Machine, Manifest, Store};
use crate::ResultRow;
use serde::de::DeserializeOwned;
use serde::Serialize;
use std::any::Any;
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

/// A node of a chain's stage graph: what its key hashes, and the key.
#[derive(Clone, Debug)]
pub(crate) struct Node {
    pub stage: &'static str,
    pub version: u32,
    pub params: BTreeMap<String, String>,
    pub inputs: Vec<(&'static str, Key)>,
    pub key: Key,
}

impl Node {
    pub fn new(
        stage: &'static str,
        version: u32,
        params: BTreeMap<String, String>,
        inputs: Vec<(&'static str, Key)>,
    ) -> Self {
        let keys: Vec<Key> = inputs.iter().map(|(_, k)| *k).collect();
        let key = stage_key(stage, version, &params, &keys);
        Node {
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

/// Raw files a stage's compute wrote itself beside its artifact (name -> blake3), for the manifest.
pub(crate) type Files = BTreeMap<String, String>;

/// Which timing side of a row a stage's times belong to (`machine`, `build_machine`).
#[derive(Clone, Copy, PartialEq, Eq)]
pub(crate) enum Timing {
    /// Not timed (load, focus).
    None,
    /// Construction (encode, build, optimize, compact).
    Build,
    /// Layout and tracing.
    Trace,
}

/// What a stage stores: the full artifact, which knows its summary.
pub(crate) trait Artifact: Serialize + DeserializeOwned + Send + Sync + 'static {
    /// What a result row needs (`<key>.sum`): a warm run reads only these.
    type Sum: Serialize + DeserializeOwned + Clone + Send + Sync + 'static;
    fn summary(&self) -> Self::Sum;
}

/// A stage's summary type.
pub(crate) type Sum<S> = <<S as Stage>::Full as Artifact>::Sum;

/// A cached stage: its node and how it is computed. Everything else (memo, key, lock, store,
/// verification, commit, counting) is `Runner`'s, the same for every stage.
pub(crate) trait Stage: Sized + 'static {
    /// The stage's name: its key's stage, its cache directory, its counter.
    const NAME: &'static str;
    const TIMING: Timing;
    /// The full artifact is stored as `<key>.bin` beside the summary and kept in memory until
    /// `Runner::forget`. Stages without one (measure, focus) set false and `Full = Sum`: they store
    /// only the summary and read it from the store at each use (with its `also` files checked).
    const FULL: bool = true;
    type Full: Artifact;

    /// The stage's node in `plan` (whose upstream nodes are planned already), or None when the
    /// chain has no such stage: version, canonical parameters (defaults filled in) and inputs,
    /// all the key hashes. May record what its compute needs in `plan`.
    fn declare(rt: &mut Runner, plan: &mut Plan) -> Result<Option<Node>>;
    /// Raw files of the entry checked with it before it is used (measure's heat map).
    fn also(_plan: &Plan) -> &'static [&'static str] {
        &[]
    }
    /// Computes the node's artifact from its inputs (`rt.full::<Input>(plan)`, which resolves
    /// them through the same protocol). Returns it with the raw files it wrote itself.
    fn compute(rt: &mut Runner, plan: &Plan, node: &Node) -> Result<(Self::Full, Files)>;
    /// Brings the node to what a row needs (`Runner::ensure_node`): its summary by default.
    fn ensure(rt: &mut Runner, plan: &Plan) -> Result<()> {
        rt.summary::<Self>(plan).map(drop)
    }
}

type Shared = Arc<dyn Any + Send + Sync>;

pub struct Runner {
    pub store: Store,
    pub versions: Versions,
    pub registry: Registry,
    pub ops: Ops,
    pub counts: Counts,
    counted: HashMap<(&'static str, Key), bool>,
    /// Full artifacts by node (dropped by `forget`).
    fulls: HashMap<(&'static str, Key), Shared>,
    /// Small files by node and extension: summaries (`sum`), the optimizer's trace (`opt`).
    parts: HashMap<(&'static str, Key, &'static str), Shared>,
    /// Content hash per scene file (a file's load key hashes its content).
    pub(crate) file_hashes: HashMap<PathBuf, String>,
    /// CPU model per node, read from its manifest once per run.
    pub(crate) cpu_models: HashMap<(&'static str, Key), String>,
}

pub(crate) fn secs(t: Instant) -> f64 {
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
            fulls: HashMap::new(),
            parts: HashMap::new(),
            file_hashes: HashMap::new(),
            cpu_models: HashMap::new(),
        }
    }

    /// Drops in-memory artifacts (call between scenes of a sweep to bound memory). Counting is
    /// unaffected: a node already counted in this run is not counted again.
    pub fn forget(&mut self) {
        self.fulls.clear();
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

    /// Writes the node's manifest (last: an entry without one is incomplete), then releases its
    /// compute lock.
    fn commit(&self, node: &Node, files: Files, seconds: f64) -> Result<()> {
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
    fn cached<T: DeserializeOwned>(&self, node: &Node, ext: &str) -> Option<T> {
        self.cached_with(node, ext, &[])
    }

    /// `cached`, with the entry's raw files `also` checked too (`Store::get_entry_with`).
    fn cached_with<T: DeserializeOwned>(&self, node: &Node, ext: &str, also: &[&str]) -> Option<T> {
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

    // ---- the evaluator ----------------------------------------------------------------------

    /// The full artifact of `plan`'s `S` node: from memory, else from the store (verified), else
    /// computed (under the node's lock), stored and committed. Counted once per run.
    pub(crate) fn full<S: Stage>(&mut self, plan: &Plan) -> Result<Arc<S::Full>> {
        let node = plan.need(S::NAME)?.clone();
        if S::FULL {
            if let Some(a) = self.fulls.get(&(S::NAME, node.key)) {
                return downcast(a.clone());
            }
        }
        let ext = if S::FULL { "bin" } else { "sum" };
        if let Some(a) = self.cached_with::<S::Full>(&node, ext, S::also(plan)) {
            self.note(S::NAME, node.key, false);
            return Ok(self.remember::<S>(&node, a, None));
        }
        let t0 = Instant::now();
        let (full, mut files) = S::compute(self, plan, &node)?;
        if S::FULL {
            files.insert(
                "bin".into(),
                self.store.put(S::NAME, &node.key, "bin", &full)?,
            );
        }
        let sum = full.summary();
        files.insert(
            "sum".into(),
            self.store.put(S::NAME, &node.key, "sum", &sum)?,
        );
        self.commit(&node, files, secs(t0))?;
        self.note(S::NAME, node.key, true);
        Ok(self.remember::<S>(&node, full, Some(sum)))
    }

    /// Keeps a full artifact and its summary in memory (a summary is then never read from the
    /// store while its artifact is in memory: no lock is taken for it); stages without a full
    /// artifact keep nothing (they are read at each use).
    fn remember<S: Stage>(
        &mut self,
        node: &Node,
        full: S::Full,
        sum: Option<Sum<S>>,
    ) -> Arc<S::Full> {
        let a = Arc::new(full);
        if S::FULL {
            let sum = sum.unwrap_or_else(|| a.summary());
            self.parts.insert((S::NAME, node.key, "sum"), Arc::new(sum));
            self.fulls.insert((S::NAME, node.key), a.clone());
        }
        a
    }

    /// The summary of `plan`'s `S` node: from memory, else its `.sum` from the store (not loading
    /// the full artifact), else from the full artifact (read or computed). A full artifact read
    /// intact whose summary is missing restores the summary (the same bytes: the manifest stays
    /// right).
    pub(crate) fn summary<S: Stage>(&mut self, plan: &Plan) -> Result<Sum<S>> {
        if !S::FULL {
            return Ok(self.full::<S>(plan)?.summary());
        }
        let node = plan.need(S::NAME)?.clone();
        let id = (S::NAME, node.key, "sum");
        if let Some(s) = self.parts.get(&id) {
            return downcast::<Sum<S>>(s.clone()).map(|s| (*s).clone());
        }
        if let Some(s) = self.cached::<Sum<S>>(&node, "sum") {
            self.note(S::NAME, node.key, false);
            self.parts.insert(id, Arc::new(s.clone()));
            return Ok(s);
        }
        self.full::<S>(plan)?; // remembers the summary too
        let sum = match self.parts.get(&id) {
            Some(s) => downcast::<Sum<S>>(s.clone())?,
            None => return Err(Error::internal(format!("{} summary not kept", S::NAME))),
        };
        if !self.store.path(S::NAME, &node.key, "sum").exists() {
            // Read from an intact full artifact whose summary was missing or corrupt: restore it.
            self.store.put(S::NAME, &node.key, "sum", &*sum)?;
        }
        Ok((*sum).clone())
    }

    /// A small file `ext` of `node` besides its summary (the optimizer's trace): from memory, else
    /// from the store (verified). Not counted: its node is counted by its artifact.
    pub(crate) fn part<T>(&mut self, node: &Node, ext: &'static str) -> Option<T>
    where
        T: DeserializeOwned + Clone + Send + Sync + 'static,
    {
        let id = (node.stage, node.key, ext);
        if let Some(v) = self.parts.get(&id) {
            return downcast::<T>(v.clone()).ok().map(|v| (*v).clone());
        }
        let v = self.cached::<T>(node, ext)?;
        self.parts.insert(id, Arc::new(v.clone()));
        Some(v)
    }

    /// Keeps a small file a compute wrote (`part`).
    pub(crate) fn remember_part<T: Send + Sync + 'static>(
        &mut self,
        node: &Node,
        ext: &'static str,
        v: T,
    ) {
        self.parts.insert((node.stage, node.key, ext), Arc::new(v));
    }

    /// Drops `node`'s full artifact from memory (it is recomputed at its next use).
    pub(crate) fn drop_full(&mut self, node: &Node) {
        self.fulls.remove(&(node.stage, node.key));
    }

    // ---- chains and single nodes -------------------------------------------------------------

    /// Runs (or reads from the cache) every stage of `spec` and returns its result row.
    pub fn run_chain(&mut self, spec: &ChainSpec, experiment: &str) -> Result<ResultRow> {
        let _locks = self.store.release_on_drop(); // compute locks end with the chain (cached)
        let plan = chain::plan(self, spec)?;
        chain::row(self, &plan, experiment)
    }

    /// The nodes of `spec`'s stage graph in chain order (load, encode, build, optimize, compact,
    /// layout, measure, focus; absent stages skipped), with keys, inputs and parameters. Runs
    /// nothing and reads nothing but a scene file's bytes (its key hashes the content).
    pub fn chain_nodes(&mut self, spec: &ChainSpec) -> Result<Vec<NodeInfo>> {
        let plan = chain::plan(self, spec)?;
        Ok(plan
            .nodes
            .into_iter()
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
        let plan = chain::plan(self, spec)?;
        let missing = || Error::internal(format!("chain has no {stage} stage"));
        let s = chain::stages()
            .into_iter()
            .find(|s| s.name == stage)
            .ok_or_else(missing)?;
        plan.node(stage).ok_or_else(missing)?;
        (s.ensure)(self, &plan)
    }
}

fn downcast<T: Send + Sync + 'static>(a: Shared) -> Result<Arc<T>> {
    a.downcast::<T>()
        .map_err(|_| Error::internal("in-memory artifact of another type"))
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
