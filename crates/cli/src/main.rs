//! `bvhlab`: sweep experiments, evaluate one chain, inspect the cache, list scene generators and
//! methods (builders, encoders, optimizers, layouts).
use bvhlab_pipeline::{
    estimate, run::Runner, store, sweep::{closing_line, sweep, ProgressMode}, ChainSpec, Error, Experiment, RaySpec, Registry, Result, Store,
};
use clap::{Parser, Subcommand};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

mod fetch;
mod slurm;

#[derive(Parser)]
#[command(name = "bvhlab", version, about = "BVH research workbench: cached stage pipeline, sweeps and reports")]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Run every chain of an experiment file and write its report to reports/<name>/.
    Sweep {
        experiment: PathBuf,
        /// Cache directory (default: $BVHLAB_CACHE, else ./cache).
        #[arg(long)]
        cache: Option<PathBuf>,
        /// Rayon threads (default: all cores).
        #[arg(long)]
        threads: Option<usize>,
        /// Report directory (default: reports/<experiment name>).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Memory the largest chain may use (e.g. 4G; default: $BVHLAB_MAX_MEMORY, else
        /// MemAvailable). A sweep whose estimate exceeds it fails before loading anything (exit 2).
        #[arg(long, value_name = "BYTES")]
        max_memory: Option<String>,
        /// List every node of the experiment's stage graph (stage, key, cached or missing,
        /// estimated seconds and memory) without running anything; with --shards N also the owner
        /// shard of each node and the balance.
        #[arg(long, conflicts_with_all = ["shard", "status", "report_only"])]
        plan: bool,
        /// Compute only shard I of N (1 <= I <= N) of the stage graph, e.g. 3/16: the same plan and
        /// N give the same shards on any machine. Writes no report.
        #[arg(long, value_name = "I/N", conflicts_with_all = ["status", "report_only"])]
        shard: Option<String>,
        /// Number of shards for --plan and --status (owner of each node).
        #[arg(long, value_name = "N")]
        shards: Option<usize>,
        /// Read only the cache: done / missing per chain (and with --shards N the shard owning each
        /// missing node).
        #[arg(long, conflicts_with = "report_only")]
        status: bool,
        /// Build the report from the cache without computing anything; chains with a missing
        /// stage are left out and listed (exit 3 when any is missing).
        #[arg(long)]
        report_only: bool,
        /// With --plan / --status: print the nodes / chains as one JSON document.
        #[arg(long)]
        json: bool,
        /// Most configurations (scene x chain grid point x ray set) the experiment may expand to;
        /// a larger grid is refused (exit 2) before anything is expanded.
        #[arg(long, value_name = "N", default_value_t = bvhlab_pipeline::experiment::DEFAULT_MAX_CONFIGS)]
        max_configs: u64,
        /// Replace the report even if the new one has fewer rows than the one in the report
        /// directory (otherwise refused, exit 2, so an incomplete cache never wipes a good report).
        #[arg(long)]
        force: bool,
    },
    /// Write (and with --submit submit) a Slurm job array that runs the experiment's shards against
    /// one shared cache, plus a report job that runs after the array (afterany).
    Slurm {
        experiment: PathBuf,
        /// Array tasks: task i runs `sweep EXP --shard i/N`.
        #[arg(long)]
        tasks: u32,
        /// The shared cache every task reads and writes (default: $BVHLAB_CACHE, else ./cache);
        /// it must be on a filesystem all nodes see.
        #[arg(long)]
        cache: Option<PathBuf>,
        #[arg(long)]
        partition: Option<String>,
        /// Time limit per task (sbatch --time, e.g. 2:00:00).
        #[arg(long)]
        time: Option<String>,
        /// Node features to pin (sbatch --constraint), e.g. one CPU model so timings compare.
        #[arg(long)]
        constraint: Option<String>,
        #[arg(long)]
        account: Option<String>,
        /// Memory per task (sbatch --mem, e.g. 8G; default: the largest chain's estimate + 25%).
        #[arg(long)]
        mem: Option<String>,
        #[arg(long, default_value_t = 1)]
        cpus_per_task: u32,
        /// Any other sbatch option for both jobs, e.g. --sbatch-arg=--qos=short (repeatable).
        #[arg(long = "sbatch-arg", value_name = "OPTION", allow_hyphen_values = true)]
        sbatch_arg: Vec<String>,
        /// Where the scripts and task logs go (default: <out>/slurm).
        #[arg(long)]
        dir: Option<PathBuf>,
        /// Report directory (default: reports/<experiment name>).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Submit with sbatch (otherwise only write the scripts) and print the job ids.
        #[arg(long)]
        submit: bool,
        /// Most configurations the experiment may expand to (see `sweep --max-configs`); the
        /// tasks' sweeps are given the same limit.
        #[arg(long, value_name = "N", default_value_t = bvhlab_pipeline::experiment::DEFAULT_MAX_CONFIGS)]
        max_configs: u64,
    },
    /// Run one chain and print its result.
    Eval {
        /// Scene file (.obj / .obj.gz) or `gen:NAME[:k=v,...]`.
        #[arg(long)]
        scene: String,
        /// Builder name (see `bvhlab methods`).
        #[arg(long)]
        build: String,
        /// Encoder for the bottom-up builders (lbvh, aac, ploc): morton (default), emc64-sort, emc64-var.
        #[arg(long)]
        encode: Option<String>,
        /// Optimizer run on the built BVH before compaction: ibo, kensler-hc, kensler-sa (or none).
        #[arg(long)]
        optimize: Option<String>,
        /// Compaction after the build (and optimizer): `none` or `collapse`.
        #[arg(long, default_value = "none")]
        compact: String,
        /// Builder, encoder, optimizer or cost parameter, e.g. bins=16, leaf=1, radius=25, bits=10,
        /// bounds=concise, measure=sum, pt=10, c_t=3 (repeatable; routed by name).
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
        /// Ray set to trace: primary[:WxH], shadow[:WxH] or random[:COUNT].
        #[arg(long)]
        rays: Option<String>,
        /// Memory layout of the final BVH (Kilian 2021), traced by --rays with its own traversal
        /// beside bvh2: NAME[:k=v,...], e.g. bvh2, qbvh_chunks:chunk_bytes=128,frame=parent,bits=6,
        /// octree_1bit:chunk_bytes=16, auto:max_slowdown=1.3 (see `bvhlab methods`).
        #[arg(long)]
        layout: Option<String>,
        #[arg(long)]
        threads: Option<usize>,
        /// Focus box `minx,miny,minz,maxx,maxy,maxz`: reports focus_triangles and focus_sah_cost.
        #[arg(long, allow_hyphen_values = true)]
        focus: Option<String>,
        /// Timed runs per stage; the median is reported.
        #[arg(long, default_value_t = 5)]
        repeat: u32,
        #[arg(long, conflicts_with = "no_cache")]
        cache: Option<PathBuf>,
        /// Use a throw-away cache.
        #[arg(long)]
        no_cache: bool,
        /// Print one JSON object (otherwise `key: value` lines).
        #[arg(long)]
        json: bool,
        /// Memory the chain may use (e.g. 4G; default: $BVHLAB_MAX_MEMORY, else MemAvailable). A
        /// chain whose estimate exceeds it fails before loading the scene (exit 2).
        #[arg(long, value_name = "BYTES")]
        max_memory: Option<String>,
    },
    /// Inspect or clean the artifact cache.
    Cache {
        #[command(subcommand)]
        op: CacheOp,
        #[arg(long, global = true)]
        cache: Option<PathBuf>,
    },
    /// List scene generators and their parameters, and the catalogued real scenes; `scenes fetch`
    /// fetches and verifies real scenes.
    Scenes {
        #[command(subcommand)]
        op: Option<ScenesOp>,
    },
    /// List builders, encoders, optimizers and layouts with their parameters (defaults in brackets).
    Methods,
}

#[derive(Subcommand)]
enum ScenesOp {
    /// Fetch catalogued real scenes (experiments/scenes.toml) from a web server or a directory holding
    /// the stored files, verify size and BLAKE3, and move each verified file into the scene directory
    /// (a file failing verification is deleted, nothing in place is replaced). Files already present
    /// and verified are skipped; with neither --from nor $BVHLAB_SCENES_FROM only that check runs.
    Fetch {
        /// Scene names (see `bvhlab scenes`).
        names: Vec<String>,
        /// Every catalogued scene.
        #[arg(long)]
        all: bool,
        /// http(s):// base address (FILE is fetched from URL/FILE) or a directory holding the stored
        /// files (default: $BVHLAB_SCENES_FROM). The catalogue's origin sites serve the original models
        /// in other formats, never the stored bytes, so there is no built-in default.
        #[arg(long, value_name = "URL|DIR")]
        from: Option<String>,
        /// Scene directory (default: ../shared/scenes beside the checkout the command runs in, where
        /// the shipped experiments look for them).
        #[arg(long, value_name = "SCENE_DIR")]
        dir: Option<PathBuf>,
        /// Replace a present file that does not match the catalogue (only ever by a verified one).
        #[arg(long)]
        replace: bool,
    },
}

#[derive(Subcommand, Clone, Copy)]
enum CacheOp {
    /// List complete entries.
    Ls,
    /// Check every manifest and every file it lists (blake3, artifact header). Reports only; exit 0
    /// iff the cache is clean (no bad manifest or file). Temporary files of killed runs and
    /// unfinished entries are listed but harmless (never read; `--repair` / `gc` remove them).
    Verify {
        /// Quarantine bad files, drop them from their manifests (removing manifests left empty or
        /// bad) so the next run recomputes exactly them, and remove stale temporary files. The exit
        /// code still says whether the cache was clean before the repair.
        #[arg(long)]
        repair: bool,
    },
    /// Remove temporary, quarantined and incomplete files.
    Gc,
}

fn reference_dir(experiment: &Path) -> Option<PathBuf> {
    let mut candidates = vec![PathBuf::from("../shared/reference")];
    if let Some(dir) = experiment.parent() {
        candidates.push(dir.join("../../shared/reference"));
        candidates.push(dir.join("../shared/reference"));
    }
    candidates.into_iter().find(|p| p.is_dir())
}

fn parse_sets(set: &[String]) -> Result<BTreeMap<String, String>> {
    let mut out = BTreeMap::new();
    for s in set {
        let (k, v) = s
            .split_once('=')
            .ok_or_else(|| Error::input(format!("--set `{s}`: expected KEY=VALUE (e.g. bins=16)")))?;
        out.insert(k.trim().to_string(), v.trim().to_string());
    }
    Ok(out)
}

/// Estimates the memory of every chain before anything is loaded and fails (exit 2) if the largest
/// exceeds the limit (`--max-memory` > `BVHLAB_MAX_MEMORY` > MemAvailable). Returns the largest
/// estimate (None if no scene's size is known without loading it).
fn check_memory(chains: &[ChainSpec], max_memory: Option<&str>) -> Result<Option<estimate::MemoryEstimate>> {
    largest_estimate(chains, estimate::memory_limit(max_memory)?.as_ref())
}

/// The largest chain's memory estimate; with a limit, fails (exit 2) if a chain exceeds it.
fn largest_estimate(chains: &[ChainSpec], limit: Option<&(u64, String)>) -> Result<Option<estimate::MemoryEstimate>> {
    let registry = Registry::standard();
    let mut worst: Option<estimate::MemoryEstimate> = None;
    let mut counts: BTreeMap<String, Option<(u64, bool)>> = BTreeMap::new();
    for c in chains {
        // Count each scene's triangles once (files are streamed).
        if !counts.contains_key(&c.scene) {
            counts.insert(c.scene.clone(), estimate::triangle_count(&c.source)?);
        }
        let Some(count) = counts[&c.scene] else { continue };
        let est = estimate::estimate(c, &estimate::chain_stages(c, &registry), count);
        let est = estimate::check_source(&c.scene, &c.source, &est, limit)?;
        if worst.as_ref().is_none_or(|w| est.peak_bytes > w.peak_bytes) {
            worst = Some(est);
        }
    }
    Ok(worst)
}

fn run(cli: Cli) -> Result<()> {
    match cli.cmd {
        Cmd::Sweep { experiment, cache, threads, out, max_memory, plan, shard, shards, status, report_only, json, max_configs, force } => {
            let exp = Experiment::load_limited(&experiment, &Registry::standard(), max_configs)?;
            if shards == Some(0) {
                return Err(Error::input("--shards must be at least 1"));
            }
            if plan || status {
                let store = Store::open(store::resolve_root(cache.as_deref()))?;
                let mut runner = Runner::new(store);
                let p = bvhlab_pipeline::plan::plan(&exp, &mut runner)?;
                return if plan { print_plan(&exp, &p, shards, json) } else { print_status(&exp, &p, &runner, shards, json) };
            }
            if let Some(s) = shard {
                let (i, n) = bvhlab_pipeline::plan::parse_shard(&s)?;
                check_memory(&exp.chains(), max_memory.as_deref())?;
                let store = Store::open(store::resolve_root(cache.as_deref()))?;
                let mut runner = Runner::new(store);
                let progress = ProgressMode::stderr();
                let r = bvhlab_pipeline::with_threads(threads, || {
                    bvhlab_pipeline::plan::run_shard(&exp, &mut runner, i, n, progress)
                })??;
                println!(
                    "{}",
                    serde_json::json!({
                        "experiment": exp.name, "shard": r.shard, "shards": r.shards, "owned": r.owned,
                        "owned_cached": r.owned_cached, "estimated_seconds": r.estimated_seconds,
                        "computed": r.counts.computed, "cached": r.counts.cached, "per_stage": r.counts.per_stage,
                        "seconds": r.seconds,
                    })
                );
                eprintln!("{}", closing_line(&format!("{} shard {}/{}", exp.name, r.shard, r.shards), &r.counts, r.seconds, None));
                return Ok(());
            }
            if report_only {
                return report_only_sweep(&exp, &experiment, cache.as_deref(), threads, out, force);
            }
            let out_dir = out.unwrap_or_else(|| PathBuf::from("reports").join(&exp.name));
            // A sweep writes one row per chain: refuse before computing anything.
            keep_larger_report(&out_dir, exp.chains().len(), force)?;
            check_memory(&exp.chains(), max_memory.as_deref())?;
            let t_start = std::time::Instant::now();
            let store = Store::open(store::resolve_root(cache.as_deref()))?;
            let mut runner = Runner::new(store);
            let progress = ProgressMode::stderr();
            let res = bvhlab_pipeline::with_threads(threads, || sweep(&exp, &mut runner, progress))??;
            let warnings: std::collections::BTreeSet<&String> =
                res.rows.iter().filter_map(|r| r.precision_warning.as_ref()).collect();
            for w in warnings {
                eprintln!("warning: {w}");
            }
            let reference = reference_dir(&experiment);
            let report = bvhlab_report::write_report(&out_dir, &exp.name, &res.rows, reference.as_deref())
                .map_err(|e| Error::internal(format!("report: {e}")))?;
            let summary = serde_json::json!({
                "experiment": exp.name,
                "computed": res.counts.computed,
                "cached": res.counts.cached,
                "per_stage": res.counts.per_stage,
                "rows": res.rows.len(),
                "report": report.to_string_lossy(),
                "seconds": res.seconds,
            });
            println!("{summary}");
            eprintln!("{}", closing_line(&exp.name, &res.counts, t_start.elapsed().as_secs_f64(), Some(&report)));
            Ok(())
        }
        Cmd::Slurm {
            experiment, tasks, cache, partition, time, constraint, account, mem, cpus_per_task, sbatch_arg, dir, out, submit,
            max_configs,
        } => {
            let exp = Experiment::load_limited(&experiment, &Registry::standard(), max_configs)?;
            let peak = largest_estimate(&exp.chains(), None)?.map(|e| e.peak_bytes);
            let args = slurm::SlurmArgs {
                experiment,
                tasks,
                cache: store::resolve_root(cache.as_deref()),
                partition,
                time,
                constraint,
                account,
                mem,
                cpus_per_task,
                dir,
                out,
                sbatch_args: sbatch_arg,
                submit,
                max_configs,
            };
            // The plan against the shared cache: the largest shard's estimate (advice for --time).
            let store = Store::open(&args.cache)?;
            let mut runner = Runner::new(store);
            let p = bvhlab_pipeline::plan::plan(&exp, &mut runner)?;
            let owner = bvhlab_pipeline::plan::partition(&p, tasks.max(1) as usize);
            let per_shard = bvhlab_pipeline::plan::shard_seconds(&p, &owner, tasks.max(1) as usize);
            let max_shard_seconds = per_shard.iter().cloned().fold(None, |m: Option<f64>, x| Some(m.map_or(x, |m| m.max(x))));
            let derived = slurm::Derived { name: exp.name.clone(), peak_bytes: peak, max_shard_seconds };
            slurm::run(&args, &derived)
        }
        Cmd::Eval { scene, build, encode, optimize, compact, set, rays, layout, focus, threads, repeat, cache, no_cache, json, max_memory } => {
            let mut spec = ChainSpec::new(&scene, &build);
            spec.encode = encode;
            spec.optimize = optimize.filter(|o| o != "none");
            spec.params = parse_sets(&set)?;
            spec.focus = focus.as_deref().map(bvhlab_pipeline::stages::parse_focus).transpose()?;
            spec.compact = compact;
            spec.repeat = repeat;
            spec.rays = rays.as_deref().map(RaySpec::parse).transpose()?;
            spec.layout = layout.filter(|l| l != "none");
            let estimate = check_memory(std::slice::from_ref(&spec), max_memory.as_deref())?;
            let store = if no_cache { Store::temporary()? } else { Store::open(store::resolve_root(cache.as_deref()))? };
            let mut runner = Runner::new(store);
            let row = bvhlab_pipeline::with_threads(threads, || runner.run_chain(&spec, "eval"))??;
            if let Some(w) = &row.precision_warning {
                eprintln!("warning: {w}");
            }
            let mut v = serde_json::to_value(&row).map_err(|e| Error::internal(e.to_string()))?;
            if let Some(o) = v.as_object_mut() {
                o.insert("computed".into(), runner.counts.computed.into());
                o.insert("cached".into(), runner.counts.cached.into());
                o.insert("threads".into(), threads.unwrap_or_else(rayon::current_num_threads).into());
                o.insert(
                    "memory_estimate".into(),
                    serde_json::to_value(&estimate).map_err(|e| Error::internal(e.to_string()))?,
                );
                if no_cache {
                    // The throw-away cache (and the heat map in it) is deleted on exit.
                    o.insert("heatmap".into(), serde_json::Value::Null);
                }
            }
            if json {
                println!("{v}");
            } else if let Some(o) = v.as_object() {
                for (k, val) in o {
                    match (k.as_str(), val.as_array()) {
                        _ if LAYOUT_FIELDS.contains(&k.as_str()) => {}
                        // The per-pass trace is for plots and --json; one line here.
                        ("optimize_trace", Some(a)) => println!("{k}: {} passes (see --json)", a.len().saturating_sub(1)),
                        _ => println!("{k}: {val}"),
                    }
                }
                print_layout_block(o);
            }
            Ok(())
        }
        Cmd::Cache { op, cache } => {
            let store = Store::open(store::resolve_root(cache.as_deref()))?;
            match op {
                CacheOp::Ls => {
                    let entries = store.entries();
                    let mut per_stage: BTreeMap<String, (u64, u64)> = BTreeMap::new();
                    for m in &entries {
                        let key = bvhlab_pipeline::Key::from_hex(&m.key);
                        let bytes: u64 = m
                            .files
                            .keys()
                            .filter_map(|ext| key.map(|k| store.path(&m.stage, &k, ext)))
                            .filter_map(|p| std::fs::metadata(p).ok())
                            .map(|md| md.len())
                            .sum();
                        let e = per_stage.entry(m.stage.clone()).or_default();
                        e.0 += 1;
                        e.1 += bytes;
                        let params: Vec<String> = m.params.iter().map(|(k, v)| format!("{k}={v}")).collect();
                        println!("{:8} {} {:>10} {}", m.stage, &m.key[..16], bytes, params.join(","));
                    }
                    for (stage, (n, b)) in per_stage {
                        println!("# {stage}: {n} entries, {b} bytes");
                    }
                    println!("# cache: {}", store.root().display());
                    Ok(())
                }
                CacheOp::Verify { repair } => {
                    let r = store.check(repair);
                    for b in &r.bad {
                        println!("bad: {b}");
                    }
                    println!(
                        "{}",
                        serde_json::json!({
                            "entries": r.entries, "files_ok": r.files_ok, "bad": r.bad.len(),
                            "stale_temp": r.stale_temp, "incomplete": r.incomplete,
                            "manifests_fixed": r.manifests_fixed, "busy": r.busy, "repaired": repair,
                        })
                    );
                    if r.clean() {
                        Ok(())
                    } else if repair {
                        Err(Error::internal(format!(
                            "{} bad cache file(s) quarantined and dropped from their manifests; the next run recomputes them",
                            r.bad.len()
                        )))
                    } else {
                        Err(Error::internal(format!(
                            "{} bad cache file(s); `bvhlab cache verify --repair` quarantines them so the next run recomputes them \
                             (runs also detect and recompute them on their own)",
                            r.bad.len()
                        )))
                    }
                }
                CacheOp::Gc => {
                    let r = store.gc();
                    println!(
                        "{}",
                        serde_json::json!({"removed_files": r.removed_files, "removed_bytes": r.removed_bytes, "removed_locks": r.removed_locks})
                    );
                    Ok(())
                }
            }
        }
        Cmd::Scenes { op: Some(ScenesOp::Fetch { names, all, from, dir, replace }) } => {
            fetch::run(&names, all, from, dir, replace)
        }
        Cmd::Scenes { op: None } => {
            for g in bvhlab_geom::gen::generators() {
                println!("gen:{}  {}", g.name, g.about);
                for (name, default, about) in g.params {
                    println!("    {name}={default}  {about}");
                }
            }
            println!("files: path to .obj or .obj.gz");
            fetch::list();
            Ok(())
        }
        Cmd::Methods => {
            print!("{}", Registry::standard().describe());
            Ok(())
        }
    }
}

fn mib(b: u64) -> String {
    format!("{:.0} MiB", b as f64 / (1u64 << 20) as f64)
}

/// `sweep --plan`: every node, totals, and with N shards the owners and the balance.
fn print_plan(exp: &Experiment, p: &bvhlab_pipeline::plan::ExperimentPlan, shards: Option<usize>, json: bool) -> Result<()> {
    use bvhlab_pipeline::plan::{imbalance, partition, shard_seconds};
    let owner = shards.map(|n| partition(p, n));
    let missing: Vec<_> = p.missing().collect();
    let per_shard = owner.as_ref().map(|o| shard_seconds(p, o, shards.unwrap_or(1)));
    let summary = serde_json::json!({
        "experiment": exp.name,
        "chains": p.chains.len(),
        "nodes": p.nodes.len(),
        "cached": p.nodes.len() - missing.len(),
        "missing": missing.len(),
        "estimated_seconds": p.total_seconds(),
        "missing_estimated_seconds": missing.iter().fold(0.0, |a, n| a + n.est_seconds),
        "peak_memory_bytes": p.peak_bytes(),
        "shards": shards,
        "shard_seconds": per_shard,
        "imbalance": per_shard.as_ref().map(|s| imbalance(s)),
    });
    if json {
        let nodes: Vec<serde_json::Value> = p
            .nodes
            .iter()
            .enumerate()
            .map(|(i, n)| {
                let mut v = serde_json::to_value(n).unwrap_or_default();
                if let (Some(o), Some(m)) = (&owner, v.as_object_mut()) {
                    m.insert("shard".into(), (o[i] + 1).into());
                }
                v
            })
            .collect();
        println!("{}", serde_json::json!({"summary": summary, "nodes": nodes}));
        return Ok(());
    }
    println!("{:<9} {:<16} {:<7} {:>9} {:>9} {:>5}  scene / parameters", "stage", "key", "state", "est s", "est mem", "shard");
    for (i, n) in p.nodes.iter().enumerate() {
        let params: Vec<String> = n
            .params
            .iter()
            .filter(|(k, _)| !matches!(k.as_str(), "content" | "candidates" | "c_t" | "c_i" | "repeat"))
            .map(|(k, v)| format!("{k}={v}"))
            .collect();
        println!(
            "{:<9} {:<16} {:<7} {:>9.3} {:>9} {:>5}  {} {}",
            n.stage,
            &n.key.hex()[..16],
            if n.cached { "cached" } else { "missing" },
            n.est_seconds,
            mib(n.est_bytes),
            owner.as_ref().map(|o| (o[i] + 1).to_string()).unwrap_or_else(|| "-".into()),
            bvhlab_pipeline::stages::scene_name(&n.scene),
            params.join(",")
        );
    }
    let mut by_stage: BTreeMap<&str, (usize, usize, f64)> = BTreeMap::new();
    for n in &p.nodes {
        let e = by_stage.entry(n.stage).or_default();
        e.0 += 1;
        e.1 += usize::from(!n.cached);
        e.2 += n.est_seconds;
    }
    for (st, (all, miss, secs)) in &by_stage {
        println!("# {st}: {all} nodes, {miss} missing, {secs:.1} s estimated");
    }
    if let Some(ps) = &per_shard {
        let line: Vec<String> = ps.iter().map(|s| format!("{s:.1}")).collect();
        println!("# shards (estimated s): {}; largest / mean = {:.3}", line.join(" "), imbalance(ps));
    }
    println!("{summary}");
    Ok(())
}

/// `sweep --status`: done / missing per chain from the manifests alone.
fn print_status(
    exp: &Experiment,
    p: &bvhlab_pipeline::plan::ExperimentPlan,
    runner: &Runner,
    shards: Option<usize>,
    json: bool,
) -> Result<()> {
    use bvhlab_pipeline::plan::{chain_label, chain_status, partition};
    let owner = shards.map(|n| partition(p, n));
    let missing = chain_status(p, &runner.store);
    let mut chains = Vec::new();
    let mut per_shard: BTreeMap<usize, usize> = BTreeMap::new();
    let mut nodes_missing = std::collections::BTreeSet::new();
    for (ci, (c, miss)) in p.chains.iter().zip(&missing).enumerate() {
        let m: Vec<serde_json::Value> = miss
            .iter()
            .map(|&i| {
                nodes_missing.insert(i);
                let n = &p.nodes[i];
                serde_json::json!({"stage": n.stage, "key": n.key.hex(), "shard": owner.as_ref().map(|o| o[i] + 1)})
            })
            .collect();
        let label = chain_label(c);
        if !json {
            if miss.is_empty() {
                println!("done     {} {label}", bvhlab_pipeline::stages::scene_name(&c.scene));
            } else {
                let what: Vec<String> = miss
                    .iter()
                    .map(|&i| match &owner {
                        Some(o) => format!("{} (shard {})", p.nodes[i].stage, o[i] + 1),
                        None => p.nodes[i].stage.to_string(),
                    })
                    .collect();
                println!("missing  {} {label}: {}", bvhlab_pipeline::stages::scene_name(&c.scene), what.join(", "));
            }
        }
        chains.push(serde_json::json!({"chain": ci, "scene": c.scene, "label": label, "missing": m}));
    }
    if let Some(o) = &owner {
        for &i in &nodes_missing {
            *per_shard.entry(o[i] + 1).or_default() += 1;
        }
    }
    let done = missing.iter().filter(|m| m.is_empty()).count();
    let summary = serde_json::json!({
        "experiment": exp.name,
        "chains": p.chains.len(),
        "done": done,
        "missing": p.chains.len() - done,
        "nodes": p.nodes.len(),
        "nodes_missing": nodes_missing.len(),
        "shards": shards,
        "missing_per_shard": owner.as_ref().map(|_| per_shard.iter().map(|(k, v)| (k.to_string(), *v)).collect::<BTreeMap<_, _>>()),
    });
    if json {
        println!("{}", serde_json::json!({"summary": summary, "chains": chains}));
    } else {
        println!("{summary}");
    }
    Ok(())
}

/// `sweep --report-only`: the report from complete chains only; exit 3 when any is missing.
fn report_only_sweep(
    exp: &Experiment,
    experiment: &Path,
    cache: Option<&Path>,
    threads: Option<usize>,
    out: Option<PathBuf>,
    force: bool,
) -> Result<()> {
    use bvhlab_pipeline::plan::{chain_label, chain_status, plan};
    let store = Store::open(store::resolve_root(cache))?;
    let mut runner = Runner::new(store);
    let p = plan(exp, &mut runner)?;
    let missing = chain_status(&p, &runner.store);
    let t0 = std::time::Instant::now();
    let mut rows = Vec::new();
    let mut missing_chains = Vec::new();
    let mut last_scene: Option<&str> = None;
    for (c, miss) in p.chains.iter().zip(&missing) {
        if !miss.is_empty() {
            let stages: Vec<&str> = miss.iter().map(|&i| p.nodes[i].stage).collect();
            eprintln!("missing: {} {} ({})", c.scene, chain_label(c), stages.join(", "));
            missing_chains.push(format!("{} {}", c.scene, chain_label(c)));
            continue;
        }
        if last_scene.is_some_and(|s| s != c.scene) {
            runner.forget();
        }
        last_scene = Some(&c.scene);
        rows.push(bvhlab_pipeline::with_threads(threads, || runner.run_chain(c, &exp.name))??);
    }
    let out_dir = out.unwrap_or_else(|| PathBuf::from("reports").join(&exp.name));
    keep_larger_report(&out_dir, rows.len(), force)?;
    let reference = reference_dir(experiment);
    let options = bvhlab_report::ReportOptions { missing_chains: missing_chains.clone() };
    let report = bvhlab_report::write_report_with(&out_dir, &exp.name, &rows, reference.as_deref(), &options)
        .map_err(|e| Error::internal(format!("report: {e}")))?;
    println!(
        "{}",
        serde_json::json!({
            "experiment": exp.name,
            "computed": runner.counts.computed,
            "cached": runner.counts.cached,
            "rows": rows.len(),
            "missing_chains": missing_chains,
            "report": report.to_string_lossy(),
            "seconds": t0.elapsed().as_secs_f64(),
        })
    );
    let label = format!("{} (report only, {} of {} chains)", exp.name, rows.len(), p.chains.len());
    eprintln!("{}", closing_line(&label, &runner.counts, t0.elapsed().as_secs_f64(), Some(&report)));
    if missing_chains.is_empty() {
        Ok(())
    } else {
        Err(Error::incomplete(format!(
            "{} of {} chains are missing from the cache; the report holds the {} complete ones. Compute the rest \
             (resubmit the same `bvhlab slurm` command, or `bvhlab sweep`) and run --report-only again",
            missing_chains.len(),
            p.chains.len(),
            rows.len()
        )))
    }
}

/// Refuses (exit 2) to replace the report in `out_dir` by one with fewer rows unless `force`.
fn keep_larger_report(out_dir: &Path, new_rows: usize, force: bool) -> Result<()> {
    match bvhlab_report::existing_rows(out_dir) {
        Some(old) if old > new_rows && !force => Err(Error::input(format!(
            "{}: the existing report has {old} rows and the new one would have {new_rows}; not replacing it \
             (use --force to replace it anyway)",
            out_dir.display()
        ))),
        _ => Ok(()),
    }
}

/// Row fields of the layout stage, printed as their own block by `eval` (without --json).
const LAYOUT_FIELDS: [&str; 22] = [
    "layout",
    "layout_params",
    "topology_bytes",
    "total_bytes",
    "topology_bytes_per_triangle",
    "total_bytes_per_triangle",
    "topology_bits_per_node",
    "layout_nodes",
    "chunks",
    "chunk_fill",
    "prim_refs",
    "peak_build_bytes",
    "layout_seconds",
    "layout_sah_cost",
    "extra_box_hits_per_ray",
    "extra_tests_per_ray",
    "bvh2_trace_seconds",
    "slowdown",
    "auto_max_slowdown",
    "auto_budget_cut",
    "auto_over_limit",
    "layout_choice",
];

fn print_layout_block(o: &serde_json::Map<String, serde_json::Value>) {
    let Some(name) = o.get("layout").and_then(|v| v.as_str()) else {
        return;
    };
    println!("layout: {name} {}", o.get("layout_params").and_then(|v| v.as_str()).unwrap_or(""));
    for k in &LAYOUT_FIELDS[2..] {
        match o.get(*k) {
            None | Some(serde_json::Value::Null) => {}
            Some(serde_json::Value::String(s)) => println!("  {k}: {s}"),
            Some(v) => println!("  {k}: {v}"),
        }
    }
}

/// A closed pipe on stdout or stderr (`bvhlab scenes | head`) ends the process quietly, killed by
/// SIGPIPE like any Unix filter (status 141 in a shell). Rust ignores SIGPIPE, so writes failed with
/// EPIPE and `println!` panicked ("error: internal") from whichever output path hit it first;
/// restoring the default covers every path (threads, progress bars, stderr) at once. Cache writes
/// are atomic, so dying mid-run is as safe as any kill.
fn quiet_on_closed_pipe() {
    #[cfg(unix)]
    // SAFETY: setting a signal's disposition to the default, before any thread is started.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

fn main() {
    quiet_on_closed_pipe();
    let cli = Cli::parse();
    // Last resort: a panic inside a stage is an internal error, reported like any other.
    let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| run(cli)));
    let code = match outcome {
        Ok(Ok(())) => 0,
        Ok(Err(e)) => {
            eprintln!("error: {e}");
            e.exit_code()
        }
        Err(p) => {
            let msg = p
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_else(|| "panic".into());
            eprintln!("error: internal: {msg}");
            1
        }
    };
    std::process::exit(code);
}
