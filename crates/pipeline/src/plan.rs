//! Experiment plans and shards (issue 12): the whole stage graph of an experiment without running
//! it, a cost estimate per node, a deterministic cost-balanced partition into N shards, and the
//! execution of one shard against a (shared) cache.
//!
//! **Plan.** Every node of every chain (`Runner::chain_nodes`), deduplicated by (stage, key): load,
//! encode and build nodes are shared by many chains. Nodes are listed in first-use order (chain
//! order, then stage order within a chain), so the plan of an experiment file is the same list on
//! every machine. `cached` = the node's manifest exists (reads nothing else).
//!
//! **Partition.** All nodes, cached or not, are partitioned: the partition must not change while a
//! run is in progress (tasks start at different times and see different cache states) or when a
//! user resubmits after losing tasks, otherwise a node could fall between two partitions and be
//! computed by nobody. Balanced by estimated seconds with LPT (longest processing time first:
//! nodes by cost descending, ties by key; each goes to the least-loaded shard, ties to the lowest
//! index), which is within 4/3 of the optimal makespan. The estimate depends only on the experiment
//! and the scenes' triangle counts (`estimate::triangle_count`), never on the cache or the machine.
//!
//! **Shard execution.** A shard computes its nodes upstream stages first (all its loads, then
//! encodes, builds, optimizes, compactions, layouts, measures/focuses), scenes in plan order within
//! a stage, dropping in-memory artifacts when the scene changes. A node whose input belongs to
//! another shard resolves that input through the runner's per-key protocol: read it if cached, wait
//! on its lock while another process computes it, or compute it here (under the lock) if nobody
//! has started it. So no node is computed twice, whatever the timing; the partition only decides
//! who is *expected* to compute what. The protocol cannot deadlock (locks are taken downstream to
//! upstream only; see `run.rs`, `Runner::cached`).
use crate::error::{Error, Result};
use crate::estimate;
use crate::experiment::Experiment;
use crate::key::Key;
use crate::run::{Counts, Runner};
use crate::stages::{ChainSpec, RaySpec};
use serde::Serialize;
use std::collections::{BTreeMap, HashMap};
use std::time::Instant;

/// Execution rank of a stage inside a shard (upstream first).
pub fn stage_rank(stage: &str) -> u32 {
    match stage {
        "load" => 0,
        "encode" => 1,
        "build" => 2,
        "optimize" => 3,
        "compact" => 4,
        "layout" => 5,
        _ => 6,
    }
}

#[derive(Clone, Debug, Serialize)]
pub struct PlanNode {
    pub stage: &'static str,
    #[serde(serialize_with = "ser_key")]
    pub key: Key,
    /// Scene spec of the chains using the node.
    pub scene: String,
    /// Index of the scene in the experiment's scene order (first use).
    pub scene_index: usize,
    /// Indices (into `ExperimentPlan::chains`) of the chains that use this node.
    pub chains: Vec<usize>,
    #[serde(serialize_with = "ser_inputs")]
    pub inputs: Vec<(&'static str, Key)>,
    pub params: BTreeMap<String, String>,
    /// The node's manifest exists in the cache.
    pub cached: bool,
    pub est_seconds: f64,
    /// Estimated peak memory of computing the node (its chain up to this stage).
    pub est_bytes: u64,
    pub triangles: u64,
}

fn ser_key<S: serde::Serializer>(k: &Key, s: S) -> std::result::Result<S::Ok, S::Error> {
    s.serialize_str(&k.hex())
}

fn ser_inputs<S: serde::Serializer>(
    v: &[(&'static str, Key)],
    s: S,
) -> std::result::Result<S::Ok, S::Error> {
    s.collect_seq(v.iter().map(|(st, k)| format!("{st}:{}", k.hex())))
}

pub struct ExperimentPlan {
    pub chains: Vec<ChainSpec>,
    pub nodes: Vec<PlanNode>,
    /// Per chain, its nodes (indices into `nodes`) in chain order.
    pub chain_nodes: Vec<Vec<usize>>,
}

impl ExperimentPlan {
    pub fn missing(&self) -> impl Iterator<Item = &PlanNode> {
        self.nodes.iter().filter(|n| !n.cached)
    }
    pub fn total_seconds(&self) -> f64 {
        self.nodes.iter().map(|n| n.est_seconds).sum()
    }
    pub fn peak_bytes(&self) -> u64 {
        self.nodes.iter().map(|n| n.est_bytes).max().unwrap_or(0)
    }
}

/// A short label of a chain: builder, encoder, optimizer, compaction, layout, rays, parameters.
pub fn chain_label(c: &ChainSpec) -> String {
    let mut s = c.build.clone();
    if let Some(e) = &c.encode {
        s.push_str(&format!(" {e}"));
    }
    if let Some(o) = &c.optimize {
        s.push_str(&format!(" +{o}"));
    }
    if c.compact != "none" {
        s.push_str(&format!(" +{}", c.compact));
    }
    if let Some(l) = &c.layout {
        s.push_str(&format!(" @{l}"));
    }
    if let Some(r) = &c.rays {
        s.push_str(&format!(" {}", r.canonical()));
    }
    if !c.params.is_empty() {
        let p: Vec<String> = c.params.iter().map(|(k, v)| format!("{k}={v}")).collect();
        s.push_str(&format!(" {}", p.join(",")));
    }
    s
}

/// Triangles of a scene for the cost model: `estimate::triangle_count`, else (a generator whose
/// count its parameters do not tell) the generated scene's count, which is cheap and deterministic.
fn scene_triangles(c: &ChainSpec, runner: &Runner) -> Result<u64> {
    if let Some((n, _)) = estimate::triangle_count(&c.source)? {
        return Ok(n);
    }
    let scene = (runner.ops.load)(&c.source.load_spec())?;
    Ok(scene.triangles.len() as u64)
}

/// Rays a measure node traces (per repeat), from its canonical `rays` parameter.
fn node_rays(params: &BTreeMap<String, String>) -> u64 {
    params
        .get("rays")
        .and_then(|r| RaySpec::parse(r).ok())
        .map(|r| estimate::ray_count(&r))
        .unwrap_or(0)
}

/// The experiment's plan against `runner`'s store (see the module doc).
pub fn plan(exp: &Experiment, runner: &mut Runner) -> Result<ExperimentPlan> {
    let chains = exp.chains();
    let mut nodes: Vec<PlanNode> = Vec::new();
    let mut index: HashMap<(&'static str, Key), usize> = HashMap::new();
    let mut chain_nodes = Vec::with_capacity(chains.len());
    let mut triangles: HashMap<String, u64> = HashMap::new();
    let mut scene_order: HashMap<String, usize> = HashMap::new();
    for (ci, c) in chains.iter().enumerate() {
        let tris = match triangles.get(&c.scene) {
            Some(&t) => t,
            None => {
                let t = scene_triangles(c, runner)?;
                triangles.insert(c.scene.clone(), t);
                t
            }
        };
        let n_scenes = scene_order.len();
        let scene_index = *scene_order.entry(c.scene.clone()).or_insert(n_scenes);
        let infos = runner.chain_nodes(c)?;
        // Layout of this chain's measure node (bvh2 is timed beside it).
        let layout_name = infos
            .iter()
            .find(|n| n.stage == "layout")
            .and_then(|n| n.params.get("layout").cloned());
        let mut mine = Vec::with_capacity(infos.len());
        let mut stages_so_far: Vec<&str> = Vec::new();
        for info in infos {
            stages_so_far.push(info.stage);
            let id = match index.get(&(info.stage, info.key)) {
                Some(&i) => i,
                None => {
                    let rays = if info.stage == "measure" {
                        node_rays(&info.params)
                    } else {
                        0
                    };
                    let est_seconds = estimate::node_seconds(
                        info.stage,
                        &info.params,
                        tris,
                        rays,
                        layout_name.as_deref(),
                        &c.scene,
                    );
                    let mut upto = c.clone();
                    if info.stage != "measure" {
                        upto.rays = None;
                    }
                    let est_bytes =
                        estimate::estimate(&upto, &stages_so_far, (tris, true)).peak_bytes;
                    let cached = runner.store.has_manifest(info.stage, &info.key);
                    nodes.push(PlanNode {
                        stage: info.stage,
                        key: info.key,
                        scene: c.scene.clone(),
                        scene_index,
                        chains: Vec::new(),
                        inputs: info.inputs,
                        params: info.params,
                        cached,
                        est_seconds,
                        est_bytes,
                        triangles: tris,
                    });
                    index.insert((info.stage, info.key), nodes.len() - 1);
                    nodes.len() - 1
                }
            };
            nodes[id].chains.push(ci);
            mine.push(id);
        }
        chain_nodes.push(mine);
    }
    Ok(ExperimentPlan {
        chains,
        nodes,
        chain_nodes,
    })
}

/// Owner shard (0-based) of every node: LPT over estimated seconds (see the module doc).
pub fn partition(plan: &ExperimentPlan, shards: usize) -> Vec<usize> {
    let shards = shards.max(1);
    let mut order: Vec<usize> = (0..plan.nodes.len()).collect();
    order.sort_by(|&a, &b| {
        let (na, nb) = (&plan.nodes[a], &plan.nodes[b]);
        nb.est_seconds
            .total_cmp(&na.est_seconds)
            .then_with(|| na.stage.cmp(nb.stage))
            .then_with(|| na.key.0.cmp(&nb.key.0))
    });
    let mut load = vec![0.0f64; shards];
    let mut owner = vec![0usize; plan.nodes.len()];
    for i in order {
        let s = (0..shards)
            .min_by(|&a, &b| load[a].total_cmp(&load[b]).then(a.cmp(&b)))
            .unwrap_or(0);
        owner[i] = s;
        load[s] += plan.nodes[i].est_seconds;
    }
    owner
}

/// Estimated seconds per shard.
pub fn shard_seconds(plan: &ExperimentPlan, owner: &[usize], shards: usize) -> Vec<f64> {
    let mut v = vec![0.0; shards.max(1)];
    for (n, &s) in plan.nodes.iter().zip(owner) {
        v[s] += n.est_seconds;
    }
    v
}

/// Largest shard's estimated seconds over the mean (1 = perfect balance).
pub fn imbalance(seconds: &[f64]) -> f64 {
    let mean = seconds.iter().sum::<f64>() / seconds.len().max(1) as f64;
    let max = seconds.iter().cloned().fold(0.0, f64::max);
    if mean > 0.0 {
        max / mean
    } else {
        1.0
    }
}

/// `I/N` with 1 <= I <= N.
pub fn parse_shard(s: &str) -> Result<(usize, usize)> {
    let err = || {
        Error::input(format!(
            "--shard `{s}`: expected I/N with 1 <= I <= N, e.g. 3/16 (shards are numbered from 1)"
        ))
    };
    let (i, n) = s.split_once('/').ok_or_else(err)?;
    let i: usize = i.trim().parse().map_err(|_| err())?;
    let n: usize = n.trim().parse().map_err(|_| err())?;
    if n == 0 || i == 0 || i > n {
        return Err(err());
    }
    Ok((i, n))
}

/// The nodes shard `shard` (0-based) owns, in execution order: stage rank, scene, plan order.
pub fn shard_nodes(plan: &ExperimentPlan, owner: &[usize], shard: usize) -> Vec<usize> {
    let mut v: Vec<usize> = (0..plan.nodes.len())
        .filter(|&i| owner[i] == shard)
        .collect();
    v.sort_by_key(|&i| {
        let n = &plan.nodes[i];
        (stage_rank(n.stage), n.scene_index, i)
    });
    v
}

#[derive(Clone, Debug, Serialize)]
pub struct ShardResult {
    pub shard: usize,
    pub shards: usize,
    /// Nodes this shard owns, and how many of them were already cached when it started.
    pub owned: usize,
    pub owned_cached: usize,
    pub estimated_seconds: f64,
    pub counts: Counts,
    pub seconds: f64,
}

/// Computes shard `shard` (1-based) of `shards`: every node it owns that is not cached (inputs it
/// does not own are read, waited for or computed under the per-key protocol).
pub fn run_shard(
    exp: &Experiment,
    runner: &mut Runner,
    shard: usize,
    shards: usize,
    progress: crate::sweep::ProgressMode,
) -> Result<ShardResult> {
    let t0 = Instant::now();
    let before = runner.counts.clone();
    let plan = plan(exp, runner)?;
    let owner = partition(&plan, shards);
    let mine = shard_nodes(&plan, &owner, shard - 1);
    let est: f64 = mine.iter().map(|&i| plan.nodes[i].est_seconds).sum();
    let owned_cached = mine.iter().filter(|&&i| plan.nodes[i].cached).count();
    let missing = mine.iter().filter(|&&i| !plan.nodes[i].cached).count() as u64;
    let bar = crate::sweep::Progress::start(
        progress,
        &format!("{} shard {shard}/{shards}", exp.name),
        mine.len() as u64,
        missing,
        mine.iter()
            .filter(|&&i| !plan.nodes[i].cached)
            .map(|&i| plan.nodes[i].est_seconds)
            .sum(),
    );
    let mut last: Option<(u32, usize)> = None;
    for &i in &mine {
        let n = &plan.nodes[i];
        let here = (stage_rank(n.stage), n.scene_index);
        if last.is_some_and(|(r, s)| r != here.0 || s != here.1) {
            runner.forget();
        }
        last = Some(here);
        bar.set_message(format!(
            "{} {} {}",
            n.stage,
            crate::stages::scene_name(&n.scene),
            &n.key.hex()[..12]
        ));
        // Re-check: another shard (or an earlier run) may have completed it since the plan.
        if !runner.store.has_manifest(n.stage, &n.key) {
            let spec = &plan.chains[n.chains[0]];
            runner.ensure_node(spec, n.stage)?;
        }
        bar.advance(1, if n.cached { 0.0 } else { n.est_seconds });
    }
    bar.finish();
    runner.forget();
    Ok(ShardResult {
        shard,
        shards,
        owned: mine.len(),
        owned_cached,
        estimated_seconds: est,
        counts: crate::sweep::counts_since(&runner.counts, &before),
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// Per chain: whether every node is cached, and the missing nodes (index into `plan.nodes`).
pub fn chain_status(plan: &ExperimentPlan, store: &crate::Store) -> Vec<Vec<usize>> {
    plan.chain_nodes
        .iter()
        .map(|ns| {
            ns.iter()
                .copied()
                .filter(|&i| {
                    let n = &plan.nodes[i];
                    !store.has_manifest(n.stage, &n.key)
                })
                .collect()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn node(stage: &'static str, k: u8, secs: f64) -> PlanNode {
        PlanNode {
            stage,
            key: Key([k; 32]),
            scene: "gen:sphere".into(),
            scene_index: 0,
            chains: vec![0],
            inputs: vec![],
            params: BTreeMap::new(),
            cached: false,
            est_seconds: secs,
            est_bytes: 0,
            triangles: 0,
        }
    }

    fn synthetic(costs: &[f64]) -> ExperimentPlan {
        ExperimentPlan {
            chains: vec![],
            nodes: costs
                .iter()
                .enumerate()
                .map(|(i, &c)| node("build", i as u8, c))
                .collect(),
            chain_nodes: vec![],
        }
    }

    #[test]
    fn partition_covers_every_node_once_and_is_deterministic() {
        let costs: Vec<f64> = (0..200).map(|i| ((i * 37) % 23) as f64 + 0.5).collect();
        let p = synthetic(&costs);
        for n in [1, 3, 16] {
            let a = partition(&p, n);
            assert_eq!(a, partition(&p, n));
            assert!(a.iter().all(|&s| s < n));
            let per: usize = (0..n).map(|s| shard_nodes(&p, &a, s).len()).sum();
            assert_eq!(per, p.nodes.len(), "every node in exactly one shard");
            let secs = shard_seconds(&p, &a, n);
            let total: f64 = costs.iter().sum();
            assert!((secs.iter().sum::<f64>() - total).abs() < 1e-9);
            // LPT with many small items: close to perfect.
            assert!(imbalance(&secs) < 1.05, "{n}: {secs:?}");
        }
        // Same nodes in another order: same owner per node.
        let mut q = synthetic(&costs);
        q.nodes.reverse();
        let (a, b) = (partition(&p, 7), partition(&q, 7));
        for (i, n) in p.nodes.iter().enumerate() {
            let j = q.nodes.iter().position(|m| m.key == n.key).unwrap();
            assert_eq!(a[i], b[j]);
        }
    }

    #[test]
    fn partition_balances_by_cost_not_count() {
        // One expensive node and 30 cheap ones: by count each of 2 shards would get 16 nodes and
        // one of them the big node; by cost the big node's shard gets few others.
        let mut costs = vec![30.0];
        costs.extend(std::iter::repeat_n(1.0, 30));
        let p = synthetic(&costs);
        let a = partition(&p, 2);
        let secs = shard_seconds(&p, &a, 2);
        assert_eq!(secs, vec![30.0, 30.0]);
        let big = a[0];
        assert_eq!(shard_nodes(&p, &a, big).len(), 1);
    }

    #[test]
    fn shard_syntax() {
        assert_eq!(parse_shard("3/16").unwrap(), (3, 16));
        for bad in ["0/4", "5/4", "1/0", "x/4", "3", ""] {
            assert_eq!(parse_shard(bad).unwrap_err().exit_code(), 2, "{bad}");
        }
    }

    #[test]
    fn execution_order_is_upstream_first() {
        let mut p = synthetic(&[]);
        p.nodes = vec![
            node("measure", 1, 1.0),
            node("load", 2, 1.0),
            node("build", 3, 1.0),
            node("encode", 4, 1.0),
        ];
        let owner = vec![0; 4];
        let order: Vec<&str> = shard_nodes(&p, &owner, 0)
            .iter()
            .map(|&i| p.nodes[i].stage)
            .collect();
        assert_eq!(order, ["load", "encode", "build", "measure"]);
    }
}
