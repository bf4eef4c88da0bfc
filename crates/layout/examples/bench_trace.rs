//! Trace throughput of bvh2, bvh4 and bvh8 beside Embree and tinybvh, in one invocation (issue 19):
//! `cargo run --release -p bvhlab-layout --example bench_trace -- [--runs N] [--procs P] [--rays N] [--tools DIR] [--axes all] [--bins N] [--tinybvh-serve PROGRAM] SCENE...`
//!
//! Per scene: binned SAH (16 bins, leaf 2, c_T = 3, c_I = 2: `eval --build binned-sah`'s defaults;
//! `--axes all`: 8 bins on all three axes, `binned-sah:axes=all:bins=8`, the tree tinybvh's BVH8_CPU
//! is built from: its BuildAVX; `--bins N`: N bins instead, e.g. 32: the configuration whose build
//! passes issue 19's build target on the dragon, `just bench-binned`; `just bench-trace` passes
//! `--axes all` unless `AXES` says otherwise, so its ratios compare traversals over trees built alike),
//! then bvhlab's timed paths (watertight f32 test, no counters) on 10^6 random rays of the anchors'
//! kind: pairs of uniform points on the sphere around the scene box (radius half its diagonal, as
//! `../shared/tools/*_anchor.cpp`), the ray starting at the first point towards the second with an
//! infinite tmax (the anchors' tfar). The points come from bvhlab's generator (seed 7), not the
//! anchors' mt19937, so the rays are of the same kind but not the same rays: the hit fractions
//! printed beside each other say how close the sets are. 1 thread: median of `--runs` rounds, the
//! configurations alternated within each round; 2 threads for bvh8. `embree-anchor SCENE 1 1` and
//! `tinybvh-anchor SCENE 1` (their builds run once per invocation; their traces are one pass over
//! 10^6 rays each) run once at the end of every round, and their medians give the ratios.
//! `--tinybvh-serve PROGRAM` (`scripts/anchors/tinybvh_trace_serve.cpp`, built by
//! `scripts/anchors/build.sh`) also has tinybvh's BVH8_CPU trace these very rays: at the end of every
//! round a warm pass of it and a warm extra pass of bvh8 run side by side, the order alternating, and
//! `bvh8/Ts` is the median of those paired ratios. Embree's `rtcIntersect1` (through
//! `bvhlab_peers`, its scene of the anchor's build quality committed once) traces them the same way
//! (`E-same`, `bvh8/Es`; Embree picks an 8-wide tree with an AVX-512 intersector here, so bvh8 is
//! its like; `bvh2/Es`, `bvh4/Es` are ratios of medians).
//! Every side traces on transparent huge pages where the kernel offers them: bvhlab's timed layouts
//! and Embree advise their memory, and the tinybvh programs run with `glibc.malloc.hugetlb=1`
//! (`BVHLAB_THP=0`: none of them, `PR_SET_THP_DISABLE` for this process and its children; the
//! stderr line says how many MiB bvhlab and the served tinybvh got).
//! `--procs P`: the whole measurement in P processes one after the other (each `--runs` rounds),
//! their rounds pooled per scene before the medians (`just bench-trace` runs 3): one process's
//! bvh8 median on the dragon ranged 2.79-3.62 Mrays/s over six processes ([`Raw`]).
//! Before timing, the fast hits of 10^4 rays are checked against the exact traversal
//! (`bvhlab_trace::check_agreement`).
use bvhlab_builders::{binned_sah, TopDownConfig};
use bvhlab_geom::stats::median;
use bvhlab_layout::cwbvh::CwBvh;
use bvhlab_layout::wide::WideBvh;
use bvhlab_trace::{check_agreement, random_rays, FastBvh2, Hit, Ray};
use rayon::prelude::*;
use std::process::Command;

/// The machine's control for `2T/1T`: a pass shaped like a trace (the same rays in the same rayon
/// chunks, the same serial `vec![Hit::NONE; n]` before them, a `Hit` written per ray) whose work
/// per ray is a chain of `steps` dependent xorshift-multiply steps in registers (splitmix64's
/// mixing step; an affine step such as `x * a + b` would not do: LLVM folds a chain of them into
/// one multiply-add). `steps` is calibrated per scene so that the control's 1-thread pass lasts as
/// long as bvh8's ([`calibrate_steps`]): the serial part of the two passes then weighs alike. Read
/// `2T/1T` against it: the traversal cannot be blamed for scaling the way register-only work does
/// on the same machine.
fn alu_pass(rays: &[Ray], steps: u32) -> Vec<Hit> {
    let mut hits = vec![Hit::NONE; rays.len()];
    hits.par_chunks_mut(1024).zip(rays.par_chunks(1024)).for_each(|(h, r)| {
        for (h, r) in h.iter_mut().zip(r) {
            let mut x = u64::from(r.origin.x.to_bits()) | 1;
            for _ in 0..steps {
                x ^= x >> 29;
                x = x.wrapping_mul(0xbf58_476d_1ce4_e5b9);
            }
            h.prim = (x >> 32) as u32;
        }
    });
    hits
}

/// Steps per ray for [`alu_pass`] such that its 1-thread pass takes as long as `reference`'s (one
/// timed pass of each after a warm-up, 1 thread; at least 8).
fn calibrate_steps(rays: &[Ray], reference: impl Fn() -> Vec<Hit> + Sync) -> u32 {
    let one = pool(1);
    let time = |f: &(dyn Fn() -> Vec<Hit> + Sync)| {
        one.install(|| std::hint::black_box(f()));
        let s = std::time::Instant::now();
        one.install(|| std::hint::black_box(f()));
        s.elapsed().as_secs_f64()
    };
    let (t_ref, t64) = (time(&reference), time(&|| alu_pass(rays, 64)));
    ((64.0 * t_ref / t64).round() as u32).max(8)
}

fn pool(n: usize) -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new().num_threads(n).build().expect("thread pool")
}

/// Nanoseconds the calling thread has run on a CPU (/proc/thread-self/schedstat, Linux), if readable.
fn thread_cpu_ns() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    s.split_whitespace().next()?.parse().ok()
}

/// One timed configuration: a traversal on a thread count.
type Job<'a> = (usize, Box<dyn Fn() -> Vec<Hit> + Sync + 'a>);

/// Seconds of each job in each of `runs` rounds, the jobs alternated within a round (so a slow
/// phase of the machine falls on every job alike, not on the one that happened to run then): by
/// wall time, and (1 thread) by the worker thread's own CPU time, which a loaded machine inflates
/// less (the wall time is what compares with the anchors, which report wall time). `after_round`
/// runs at the end of every round (the anchors: alternated with bvhlab's jobs the same way).
/// `partners`: passes of other libraries timed by themselves (seconds), each paired at the end of every round
/// with an extra pass of job `pair_with`: each side runs an untimed pass and then its timed one (so
/// both are timed warm, whichever ran before), ours first in even rounds and theirs first in odd
/// ones; the per-round seconds of both come back for paired ratios. Separate from the job's own
/// passes, so the partner's evictions never fall on one of the columns' timings.
struct Paired<'a> {
    pair_with: usize,
    pass: Box<dyn FnMut() -> Option<f64> + 'a>,
}

/// Per round: the partner's seconds and the paired job's.
type PairedRuns = Vec<(f64, f64)>;

fn mrays(
    runs: usize,
    round0: usize,
    jobs: &[Job],
    mut partners: Vec<Paired>,
    mut after_round: impl FnMut(),
) -> (Vec<Vec<f64>>, Vec<Vec<f64>>, Vec<PairedRuns>) {
    let pools: Vec<rayon::ThreadPool> = jobs.iter().map(|(n, _)| pool(*n)).collect();
    let mut t = vec![Vec::new(); jobs.len()];
    let mut c = vec![Vec::new(); jobs.len()];
    let mut paired = vec![Vec::new(); partners.len()];
    for round in 0..runs {
        for (j, (_, f)) in jobs.iter().enumerate() {
            let s = std::time::Instant::now();
            let cpu = pools[j].install(|| {
                let c0 = thread_cpu_ns();
                std::hint::black_box(f());
                Some(thread_cpu_ns()? - c0?)
            });
            t[j].push(s.elapsed().as_secs_f64());
            if let Some(ns) = cpu {
                c[j].push(ns as f64 * 1e-9);
            }
        }
        for (p, paired) in partners.iter_mut().zip(paired.iter_mut()) {
            let (j, f) = (p.pair_with, &jobs[p.pair_with].1);
            let ours = || {
                pools[j].install(|| std::hint::black_box(f()));
                let s = std::time::Instant::now();
                pools[j].install(|| std::hint::black_box(f()));
                s.elapsed().as_secs_f64()
            };
            let mut theirs = || (p.pass)().and_then(|_| (p.pass)());
            // `round0`: this process's first round among all processes' (`--procs`), so the order
            // alternates over the pooled rounds too.
            let pair = if (round0 + round).is_multiple_of(2) {
                let a = ours();
                theirs().map(|b| (b, a))
            } else {
                let b = theirs();
                let a = ours();
                b.map(|b| (b, a))
            };
            paired.extend(pair);
        }
        after_round();
    }
    (t, c, paired)
}

/// Threads of each timed job, in the order `main` lists them: bvh2, bvh4, bvh8, bvh8 on 2
/// threads, the register-only control on 1 and 2, cwbvh.
const THREADS: [usize; 7] = [1, 1, 1, 2, 1, 2, 1];

/// One process's measurements of one scene, everything the table is computed from; with
/// `--procs P` every process prints its own (`--raw`) and the parent pools them ([`Raw::merge`]):
/// on the dragon one process's medians moved from process to process (bvh8 2.79-3.62
/// Mrays/s over six processes, Embree's in those processes 3.13-3.98, their paired ratio 0.70-1.01,
/// 2026-11-29) with the timed buffers on huge pages alike in each (smaps), while the anchors run a
/// process per round anyway.
#[derive(serde::Serialize, serde::Deserialize)]
struct Raw {
    /// The scene as given (pooled on this, not on the name: two paths may share a file name).
    spec: String,
    name: String,
    tris: usize,
    rays: usize,
    hit_frac: f64,
    /// Per job ([`THREADS`]), per round: wall seconds and the worker's CPU seconds (1 thread).
    secs: Vec<Vec<f64>>,
    cpu: Vec<Vec<f64>>,
    /// Per round: (their seconds, bvh8's) for tinybvh's served BVH8_CPU and for Embree.
    tiny_pairs: PairedRuns,
    embree_pairs: PairedRuns,
    /// The anchors' JSON, one per invocation.
    e_runs: Vec<String>,
    t_runs: Vec<String>,
    tiny_hit: Option<f64>,
    embree_hit: Option<f64>,
    /// MiB on huge pages, one per process: bvhlab's timed layouts, the served tinybvh.
    huge_ours: Vec<f64>,
    huge_tiny: Vec<f64>,
    /// The control's steps per ray, one per process.
    steps: Vec<u32>,
    /// Per process: its median bvh8 Mrays/s and its medians of bvh8/Es and bvh8/Ts ([`Raw::own`]).
    per_proc: Vec<(f64, Option<f64>, Option<f64>)>,
    procs: usize,
}

/// bvh8's paired ratio against a partner: the median over the rounds of the partner's seconds over
/// bvh8's (None without rounds).
fn paired_ratio(p: &PairedRuns) -> Option<f64> {
    (!p.is_empty()).then(|| median(&p.iter().map(|(th, ours)| th / ours).collect::<Vec<_>>()))
}

/// A figure with two decimals, or "-".
fn num(v: Option<f64>) -> String {
    v.map_or("-".to_string(), |v| format!("{v:.2}"))
}

impl Raw {
    /// This process's own figures, for the spread between processes (`per_proc`).
    fn own(&self) -> (f64, Option<f64>, Option<f64>) {
        (self.rays as f64 / median(&self.secs[2]) / 1e6, paired_ratio(&self.embree_pairs), paired_ratio(&self.tiny_pairs))
    }

    /// Pools another process's rounds of the same scene (the same rays: hit fractions kept).
    fn merge(&mut self, o: Raw) {
        assert!(self.tris == o.tris && self.rays == o.rays, "{}: processes measured different inputs", self.spec);
        for (a, b) in self.secs.iter_mut().zip(o.secs) {
            a.extend(b);
        }
        for (a, b) in self.cpu.iter_mut().zip(o.cpu) {
            a.extend(b);
        }
        self.tiny_pairs.extend(o.tiny_pairs);
        self.embree_pairs.extend(o.embree_pairs);
        self.e_runs.extend(o.e_runs);
        self.t_runs.extend(o.t_runs);
        self.tiny_hit = self.tiny_hit.or(o.tiny_hit);
        self.embree_hit = self.embree_hit.or(o.embree_hit);
        self.huge_ours.extend(o.huge_ours);
        self.huge_tiny.extend(o.huge_tiny);
        self.steps.extend(o.steps);
        self.per_proc.extend(o.per_proc);
        self.procs += o.procs;
    }
}

/// tinybvh's BVH8_CPU traversal served by `scripts/anchors/tinybvh_trace_serve.cpp` (see there): it
/// traces bvhlab's rays, one pass per request, timed by itself.
struct TinyServe {
    child: std::process::Child,
    out: std::io::BufReader<std::process::ChildStdout>,
    /// The last pass' hit fraction.
    hit_fraction: f64,
}

impl TinyServe {
    fn start(program: &str, scene: &str, rays: &[Ray]) -> Result<TinyServe, String> {
        use std::process::Stdio;
        let mut child = tool_command(program)
            .arg(scene)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .map_err(|e| format!("cannot start {program}: {e}"))?;
        let out = std::io::BufReader::new(child.stdout.take().ok_or("no stdout")?);
        let mut me = TinyServe { child, out, hit_fraction: 0.0 };
        let ready = me.answer()?;
        if !ready.starts_with("ready") {
            return Err(format!("{program} did not load {scene}: {ready:?}"));
        }
        let path = std::env::temp_dir().join(format!("bvhlab-bench-rays-{}.bin", std::process::id()));
        let bytes: Vec<u8> = rays
            .iter()
            .flat_map(|r| [r.origin.to_array(), r.dir.to_array()].concat())
            .flat_map(f32::to_le_bytes)
            .collect();
        std::fs::write(&path, bytes).map_err(|e| format!("{}: {e}", path.display()))?;
        let ok = me.request(&format!("rays {}", path.display()));
        std::fs::remove_file(&path).ok();
        let ok = ok?;
        if ok != format!("ok {}", rays.len()) {
            return Err(format!("{program} took the rays as {ok:?}"));
        }
        Ok(me)
    }
    fn answer(&mut self) -> Result<String, String> {
        use std::io::BufRead;
        let mut line = String::new();
        self.out.read_line(&mut line).map_err(|e| e.to_string())?;
        Ok(line.trim().to_string())
    }
    fn request(&mut self, req: &str) -> Result<String, String> {
        use std::io::Write;
        let stdin = self.child.stdin.as_mut().ok_or("no stdin")?;
        writeln!(stdin, "{req}").and_then(|_| stdin.flush()).map_err(|e| e.to_string())?;
        self.answer()
    }
    /// MiB of the server's memory on transparent huge pages, if readable.
    fn huge_mib(&self) -> Option<f64> {
        anon_huge_mib(&format!("/proc/{}/smaps_rollup", self.child.id()))
    }
    /// One pass: its seconds.
    fn pass(&mut self) -> Option<f64> {
        let a = self.request("trace").ok()?;
        let v: Vec<f64> = a.split_whitespace().filter_map(|t| t.parse().ok()).collect();
        let [secs, hits] = v[..] else { return None };
        self.hit_fraction = hits;
        Some(secs)
    }
}

/// `AnonHugePages` of a /proc/PID/smaps_rollup file, in MiB.
fn anon_huge_mib(path: &str) -> Option<f64> {
    let s = std::fs::read_to_string(path).ok()?;
    let kb: f64 = s.lines().find(|l| l.starts_with("AnonHugePages:"))?.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

/// The number after `"key":` in a one-line JSON object, after `after` if given.
fn field(json: &str, after: &str, key: &str) -> Option<f64> {
    let from = json.find(after)?;
    let rest = &json[from..];
    let i = rest.find(&format!("\"{key}\":"))? + key.len() + 3;
    let end = rest[i..].find(|c: char| !(c.is_ascii_digit() || ".-+eE".contains(c)))?;
    rest[i..i + end].parse().ok()
}

/// A tool (an anchor, or the served tinybvh) with the huge-page help bvhlab's timed layouts get
/// (`bvhlab_trace::thp`) where it is on: glibc's malloc then advises its large allocations for huge
/// pages (`glibc.malloc.hugetlb=1`, glibc >= 2.35, also read by the statically linked
/// tinybvh-anchor). Embree advises its BVHs itself. Without it tinybvh alone would trace on 4 KiB
/// pages (dragon: 2.68 -> 2.82 Mrays/s with it, one invocation each, 2026-11-29).
fn tool_command(program: &str) -> Command {
    let mut cmd = Command::new(program);
    if bvhlab_trace::thp::enabled() {
        cmd.env("GLIBC_TUNABLES", "glibc.malloc.hugetlb=1");
    }
    cmd
}

fn anchor(tool: &str, args: &[&str]) -> Option<String> {
    let out = tool_command(tool).args(args).output().ok()?;
    if !out.status.success() {
        eprintln!("{tool}: exit {:?}: {}", out.status.code(), String::from_utf8_lossy(&out.stderr));
        return None;
    }
    String::from_utf8(out.stdout).ok()?.lines().last().map(str::to_string)
}

/// The table row of one scene (and its stderr lines) from its measurements, pooled or not.
fn summarize(r: &Raw) {
    // Median Mrays/s of each job by wall time and (1 thread, every round timed) by CPU time.
    let m: Vec<(f64, Option<f64>)> = (0..THREADS.len())
        .map(|j| {
            let cpu = (THREADS[j] == 1 && r.cpu[j].len() == r.secs[j].len()).then(|| r.rays as f64 / median(&r.cpu[j]) / 1e6);
            (r.rays as f64 / median(&r.secs[j]) / 1e6, cpu)
        })
        .collect();
    let [(m2, c2), (m4, c4), (m8, c8), (m8x2, _), (malu, _), (malu2, _), (mcw, ccw)] = m[..] else { unreachable!() };
    let (name, secs, rays) = (&r.name, &r.secs, r.rays);
    // bvh8's 2-thread speed-up paired by round (its 1-thread seconds over its 2-thread seconds
    // in the same round, median over the rounds): a slow phase of the machine within a round
    // falls on both, where the ratio of the two medians took it on one side only.
    let on_one = |one: &[f64], two: &[f64]| median(&one.iter().zip(two).map(|(one, two)| one / two).collect::<Vec<_>>());
    let two_on_one = on_one(&secs[2], &secs[3]);
    let alu_two_on_one = on_one(&secs[4], &secs[5]);
    // Rounds in which bvh8 gained at least as much from the second thread as the control did.
    let beat_alu = (0..secs[2].len()).filter(|&r| secs[2][r] / secs[3][r] >= secs[4][r] / secs[5][r]).count();
    let (tiny_pairs, embree_pairs) = (&r.tiny_pairs, &r.embree_pairs);
    // A partner's Mrays/s (its median pass), bvh8's paired ratio against it (median over the
    // rounds of the partner's seconds over bvh8's) and in how many rounds bvh8 was faster.
    let paired_stats = |p: &PairedRuns| {
        let mr = (!p.is_empty()).then(|| rays as f64 / median(&p.iter().map(|p| p.0).collect::<Vec<_>>()) / 1e6);
        (mr, paired_ratio(p), p.iter().filter(|(th, ours)| ours < th).count())
    };
    let (es, r8e, r8e_faster) = paired_stats(embree_pairs);
    // Median of a field over the anchor's runs (None when no run gave it).
    let med = |runs: &[String], after: &str, key: &str| {
        let v: Vec<f64> = runs.iter().filter_map(|j| field(j, after, key)).collect();
        (!v.is_empty()).then(|| median(&v))
    };
    let (e_runs, t_runs) = (&r.e_runs, &r.t_runs);
    let em = med(e_runs, "scene_commit_ms", "mrays_per_s_1thread");
    let eh = med(e_runs, "scene_commit_ms", "hit_fraction");
    let tm = med(t_runs, "trace_bvh8_cpu", "mrays_per_s_1thread");
    let th = med(t_runs, "trace_bvh8_cpu", "hit_fraction");
    // Same rays: tinybvh's Mrays/s (median pass), its hit fraction, and the median over the rounds
    // of bvh8's paired ratio (tinybvh's seconds over bvh8's in the same round).
    let (ts, r8s, r8s_faster) = paired_stats(tiny_pairs);
    let tsh = r.tiny_hit.filter(|_| ts.is_some());
    let each = |runs: &[String], after: &str| {
        runs.iter().filter_map(|j| field(j, after, "mrays_per_s_1thread")).map(|v| format!("{v:.2}")).collect::<Vec<_>>()
    };
    let mib = |v: &[f64]| if v.is_empty() { "-".to_string() } else { v.iter().map(|v| format!("{v:.0}")).collect::<Vec<_>>().join("/") };
    eprintln!(
        "{name}: anchor runs, Mrays/s: embree {:?}, tinybvh {:?}; Embree on the same rays: hit% {}; MiB on huge pages: bvhlab {}, tinybvh-serve {} (BVHLAB_THP={})",
        each(e_runs, "scene_commit_ms"),
        each(t_runs, "trace_bvh8_cpu"),
        r.embree_hit.map_or("-".into(), |h| format!("{:.2}", 100.0 * h)),
        mib(&r.huge_ours),
        mib(&r.huge_tiny),
        if bvhlab_trace::thp::enabled() { "on" } else { "0" }
    );
    let pct = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{:.2}", 100.0 * v));
    let ratio = |a: f64, b: Option<f64>| b.map_or("-".to_string(), |b| format!("{:.2}x", a / b));
    println!(
        "{:<16} {:>8} {:>7.2} {:>7} {:>7} {:>7} | {:>7.2} {:>7.2} {:>7.2} {:>8.2} {:>7.2} | {:>7} {:>7} {:>7} {:>7} | {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>7.2}x {:>7.2}x {:>7.2}x",
        name,
        r.tris,
        100.0 * r.hit_frac,
        pct(eh),
        pct(th),
        pct(tsh),
        m2,
        m4,
        m8,
        m8x2,
        mcw,
        num(em),
        num(es),
        num(tm),
        num(ts),
        ratio(m2, em),
        ratio(m4, em),
        ratio(m2, es),
        ratio(m4, es),
        r8e.map_or("-".to_string(), |r| format!("{r:.2}x")),
        ratio(m8, tm),
        r8s.map_or("-".to_string(), |r| format!("{r:.2}x")),
        two_on_one,
        alu_two_on_one,
        mcw / m8
    );
    println!("{:<16} {:>41} | {:>7} {:>7} {:>7} {:>8} {:>7}   (by the worker's CPU time)", "", "", num(c2), num(c4), num(c8), "", num(ccw));
    if r8s.is_some() {
        eprintln!("{name}: bvh8 vs tinybvh on the same rays, paired per round: faster in {r8s_faster} of {} rounds", tiny_pairs.len());
    }
    eprintln!(
        "{name}: bvh8 2 threads over 1: paired by round {two_on_one:.2}x, ratio of the medians {:.2}x; the register-only control ({} steps per ray; {malu:.2} / {malu2:.2} Mrays/s on 1 / 2 threads) {alu_two_on_one:.2}x, bvh8 at or above it in {beat_alu} of {} rounds",
        m8x2 / m8,
        r.steps.iter().map(|s| s.to_string()).collect::<Vec<_>>().join("/"),
        secs[2].len()
    );
    if r8e.is_some() {
        eprintln!("{name}: bvh8 vs Embree on the same rays, paired per round: faster in {r8e_faster} of {} rounds", embree_pairs.len());
    }
    if r.procs > 1 {
        let each: Vec<String> = r.per_proc.iter().map(|(m, e, t)| format!("{m:.2} Mrays/s, bvh8/Es {}, bvh8/Ts {}", num(*e), num(*t))).collect();
        eprintln!("{name}: pooled over {} processes, {} rounds; bvh8 per process: {}", r.procs, secs[2].len(), each.join("; "));
    }
}

/// The table's legend, after the last scene.
fn print_legend() {
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    println!("# targets: bvh2/E >= 0.8x, bvh4/E >= 1.0x, bvh8/T >= 1.0x, 2T/1T >= 1.8x; E = embree-anchor (its timing includes its ray generation), Es = Embree's rtcIntersect1 on the same rays (its scene committed once, generation untimed; median of one pass per round, each paired with a pass of bvh8 as Ts: bvh8/Es); T = tinybvh-anchor (its own rays, one pass per invocation), Ts = tinybvh's BVH8_CPU on the same rays (--tinybvh-serve), bvh8/Ts = median over the rounds of the paired ratio (an extra warm pass of bvh8 next to a warm pass of tinybvh, the order alternating); every side on transparent huge pages unless BVHLAB_THP=0 (bvhlab's timed layouts and Embree advise their memory, the tinybvh programs get glibc.malloc.hugetlb=1); 2T/1T = median over the rounds of bvh8's 1-thread over its 2-thread seconds in the same round (with --procs P: over every process's rounds); alu2T/1T = the same for a control pass right after it, shaped like a trace but register-only work per ray (dependent xorshift-multiply steps, as many as make its 1-thread pass as long as bvh8's): how the machine scales work that never waits on memory; loadavg at end: {}", load.trim());
}

fn main() {
    // Decided before anything is allocated: with BVHLAB_THP=0 huge pages are off for the whole
    // process (Embree's scene too) and the anchors it starts.
    bvhlab_trace::thp::enabled();
    let argv: Vec<String> = std::env::args().skip(1).collect();
    let mut args = argv.iter().cloned();
    let (mut runs, mut n_rays, mut tools) = (3usize, 1_000_000usize, "../shared/tools".to_string());
    let (mut procs, mut raw_index) = (1usize, None::<usize>);
    let mut all_axes = false;
    let mut bins: Option<u32> = None;
    let mut serve: Option<String> = None;
    let mut scenes = Vec::new();
    while let Some(a) = args.next() {
        match a.as_str() {
            "--runs" => runs = args.next().and_then(|v| v.parse().ok()).expect("--runs N"),
            "--rays" => n_rays = args.next().and_then(|v| v.parse().ok()).expect("--rays N"),
            "--tools" => tools = args.next().expect("--tools DIR"),
            "--axes" => {
                all_axes = match args.next().as_deref() {
                    Some("all") => true,
                    Some("largest") => false,
                    other => panic!("--axes largest|all, got {other:?}"),
                }
            }
            "--bins" => bins = Some(args.next().and_then(|v| v.parse().ok()).expect("--bins N")),
            "--tinybvh-serve" => serve = Some(args.next().expect("--tinybvh-serve PROGRAM")),
            "--procs" => procs = args.next().and_then(|v| v.parse::<usize>().ok()).expect("--procs N").max(1),
            // A child of `--procs`: its measurements as JSON lines, no table.
            "--raw" => raw_index = Some(args.next().and_then(|v| v.parse().ok()).expect("--raw I")),
            _ => scenes.push(a),
        }
    }
    if scenes.is_empty() {
        eprintln!("usage: bench_trace [--runs N] [--procs P] [--rays N] [--tools DIR] [--axes largest|all] [--bins N] [--tinybvh-serve PROGRAM] SCENE...");
        std::process::exit(2);
    }
    let avx2 = {
        #[cfg(target_arch = "x86_64")]
        {
            std::is_x86_feature_detected!("avx2")
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            false
        }
    };
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    let bins = bins.unwrap_or(if all_axes { 8 } else { 16 }).max(2);
    let tree = if all_axes {
        format!("binned-sah:axes=all:bins={bins}")
    } else {
        format!("binned-sah (bins={bins}, largest axis)")
    };
    if raw_index.is_none() {
        let rounds = if procs > 1 { format!("{procs} processes x {runs} rounds, pooled") } else { format!("{runs} runs") };
        println!("# bench-trace: {n_rays} random rays, 1 thread unless said, median of {rounds}; tree: {tree}; AVX2: {avx2}; loadavg at start: {}", load.trim());
        println!(
            "{:<16} {:>8} {:>7} {:>7} {:>7} {:>7} | {:>7} {:>7} {:>7} {:>8} {:>7} | {:>7} {:>7} {:>7} {:>7} | {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>8} {:>8} {:>8}",
            "scene", "tris", "hit%", "hit%E", "hit%T", "hit%Ts", "bvh2", "bvh4", "bvh8", "bvh8x2T", "cwbvh", "embree", "E-same", "tinybvh", "T-same",
            "bvh2/E", "bvh4/E", "bvh2/Es", "bvh4/Es", "bvh8/Es", "bvh8/T", "bvh8/Ts", "2T/1T", "alu2T/1T", "cw/bvh8"
        );
    }
    if procs > 1 {
        // Each process measures every scene in turn (`--raw`); their rounds are pooled per scene.
        let exe = std::env::current_exe().expect("own path");
        let mut child_args = Vec::new();
        let mut it = argv.iter();
        while let Some(a) = it.next() {
            if a == "--procs" {
                it.next();
            } else {
                child_args.push(a.clone());
            }
        }
        let mut pooled: Vec<Raw> = Vec::new();
        let mut failed = false;
        for i in 0..procs {
            let out = Command::new(&exe)
                .args(&child_args)
                .args(["--raw", &i.to_string()])
                .stderr(std::process::Stdio::inherit())
                .output()
                .expect("bench_trace child");
            if !out.status.success() {
                // Its rounds are lost; the others' are still pooled, and the exit status says so.
                eprintln!("bench_trace: process {i} failed ({}); pooling the others", out.status);
                failed = true;
                continue;
            }
            for line in String::from_utf8_lossy(&out.stdout).lines() {
                let Some(json) = line.strip_prefix("RAW ") else { continue };
                let r: Raw = match serde_json::from_str(json) {
                    Ok(r) => r,
                    Err(e) => {
                        eprintln!("bench_trace: process {i}: unreadable measurements: {e}");
                        failed = true;
                        continue;
                    }
                };
                match pooled.iter_mut().find(|p| p.spec == r.spec) {
                    Some(p) => p.merge(r),
                    None => pooled.push(r),
                }
            }
        }
        pooled.iter().for_each(summarize);
        print_legend();
        if failed {
            std::process::exit(1);
        }
        return;
    }
    for spec in &scenes {
        let scene = match bvhlab_geom::load_scene(spec) {
            Ok(s) => s,
            Err(e) => {
                eprintln!("{spec}: {e}");
                continue;
            }
        };
        let name = std::path::Path::new(spec)
            .file_name()
            .map(|f| f.to_string_lossy().trim_end_matches(".gz").trim_end_matches(".obj").to_string())
            .unwrap_or_else(|| spec.clone());
        let tris = &scene.triangles;
        let (boxes, centers) = scene.boxes_and_centers();
        let opts = if all_axes {
            binned_sah::BinnedOptions { axes: binned_sah::Axes::All, ..binned_sah::BinnedOptions::new(bins) }
        } else {
            binned_sah::BinnedOptions::new(bins)
        };
        let bvh = binned_sah::build_with_options(&boxes, &centers, &opts, &TopDownConfig::default());
        let b = scene.bounds();
        // The anchors' sphere: half the box diagonal; their rays have an infinite tfar.
        let radius = (0.5 * b.extent_f64().length()) as f32;
        let rays: Vec<Ray> = random_rays(&b, radius, n_rays, 7)
            .into_iter()
            .map(|r| Ray { tmax: f32::INFINITY, ..r })
            .collect();
        let f2 = FastBvh2::new(&bvh, tris);
        // The timed copies (node memory advised for huge pages, as the pipeline's measure stage
        // traces: `bvhlab_trace::thp`; `BVHLAB_THP=0` for ordinary pages).
        let w4 = WideBvh::build(&bvh, 4).expect("bvh4").timed_copy();
        let w8 = WideBvh::build(&bvh, 8).expect("bvh8").timed_copy();
        let s4 = w4.store(tris);
        let s8 = w8.store(tris);
        let cw = CwBvh::build(&bvh).expect("cwbvh").timed_copy();
        // Oracle on a sample: fast hits against the exact traversal.
        let sample = &rays[..rays.len().min(10_000)];
        let exact = bvhlab_trace::trace(&bvh, tris, sample).hits;
        for (label, got) in [
            ("bvh2", f2.hits(sample)),
            ("bvh4", w4.hits(&s4, sample)),
            ("bvh8", w8.hits(&s8, sample)),
            ("cwbvh", cw.hits(&s8, sample)),
        ] {
            if let Err(e) = check_agreement(tris, sample, &got, &exact, sample.len() / 1000 + 1) {
                eprintln!("{name} {label}: fast path disagrees with the exact traversal: {e}");
                std::process::exit(1);
            }
        }
        // Counters of the sample (untimed, exact traversal): nodes entered and triangle tests per ray.
        let per_ray = |st: bvhlab_trace::TraceStats| {
            let n = sample.len().max(1) as f64;
            format!("{:.1}/{:.1}", st.total_steps as f64 / n, st.total_intersections as f64 / n)
        };
        if raw_index.is_none_or(|i| i == 0) {
            eprintln!(
            "{name}: steps/tests per ray: bvh2 {}, bvh4 {}, bvh8 {}, cwbvh {}; total bytes/triangle: bvh8 {:.1}, cwbvh {:.1}",
            per_ray(bvhlab_trace::trace(&bvh, tris, sample)),
            per_ray(w4.trace(tris, sample)),
            per_ray(w8.trace(tris, sample)),
            per_ray(cw.trace(tris, sample)),
            w8.memory().total_bytes as f64 / tris.len() as f64,
            cw.memory().total_bytes as f64 / tris.len() as f64,
            );
        }
        let hit_frac = f2.hits(&rays).iter().filter(|h| h.is_hit()).count() as f64 / rays.len() as f64;
        // The control's work per ray, so that its 1-thread pass lasts as long as bvh8's.
        let steps = calibrate_steps(&rays, || w8.hits(&s8, &rays));
        let jobs: Vec<Job> = vec![
            (1, Box::new(|| f2.hits(&rays))),
            (1, Box::new(|| w4.hits(&s4, &rays))),
            (1, Box::new(|| w8.hits(&s8, &rays))),
            (2, Box::new(|| w8.hits(&s8, &rays))),
            // The register-only control's 2-thread scaling, right after bvh8's (same phase of the machine).
            (1, Box::new(|| alu_pass(&rays, steps))),
            (2, Box::new(|| alu_pass(&rays, steps))),
            (1, Box::new(|| cw.hits(&s8, &rays))),
        ];
        // The anchors once per round (`embree-anchor SCENE 1 1`, `tinybvh-anchor SCENE 1`: each
        // traces its 10^6 rays once per invocation), so their figures are medians of as many runs
        // as bvhlab's, taken in the same rounds: one invocation's figure moved by 10-15 % between
        // invocations (tinybvh on breakfast_room 11.3-12.9 Mrays/s, 2026-11-28).
        let (mut e_runs, mut t_runs) = (Vec::new(), Vec::new());
        // tinybvh on these very rays, paired with a pass of bvh8 on 1 thread at the end of every round.
        let mut tiny = serve.as_deref().and_then(|p| {
            TinyServe::start(p, spec, &rays).map_err(|e| eprintln!("{name}: tinybvh-serve: {e}")).ok()
        });
        // How much of bvhlab's memory the kernel backed with huge pages (its timed layouts; before
        // Embree's scene joins this process).
        let huge_ours = anon_huge_mib("/proc/self/smaps_rollup");
        // Embree's rtcIntersect1 on these very rays, one thread, its scene (MEDIUM, what the
        // anchor commits) committed once, untimed: the anchor's own figure also times its ray
        // generation (mt19937, sin, cos, sqrt). Paired like tinybvh, with bvh8 (Embree picks an
        // 8-wide tree here, docs/decisions.md).
        let embree = bvhlab_peers::Peer::EmbreeBinned.embree_scene(tris).map_err(|e| eprintln!("{name}: Embree: {e}")).ok();
        let embree_hits = std::cell::Cell::new(0usize);
        let mut partners = Vec::new();
        let tiny_at = tiny.as_mut().map(|t| {
            partners.push(Paired { pair_with: 2, pass: Box::new(move || t.pass()) });
            partners.len() - 1
        });
        let embree_at = embree.as_ref().map(|e| {
            let (rays, hits) = (&rays, &embree_hits);
            partners.push(Paired {
                pair_with: 2,
                pass: Box::new(move || {
                    let (h, secs) = e.trace(rays).map_err(|err| eprintln!("Embree pass: {err}")).ok()?;
                    hits.set(h.iter().filter(|h| h.is_hit()).count());
                    Some(secs)
                }),
            });
            partners.len() - 1
        });
        let (secs, cpu, paired) = mrays(runs, raw_index.unwrap_or(0) * runs, &jobs, partners, || {
            e_runs.extend(anchor(&format!("{tools}/embree-anchor"), &[spec, "1", "1"]));
            t_runs.extend(anchor(&format!("{tools}/tinybvh-anchor"), &[spec, "1"]));
        });
        let pairs_of = |at: Option<usize>| at.map_or_else(Vec::new, |i| paired[i].clone());
        let (tiny_pairs, embree_pairs) = (pairs_of(tiny_at), pairs_of(embree_at));
        let raw = Raw {
            spec: spec.clone(),
            name: name.clone(),
            tris: tris.len(),
            rays: rays.len(),
            hit_frac,
            secs,
            cpu,
            tiny_hit: tiny.as_ref().filter(|_| !tiny_pairs.is_empty()).map(|t| t.hit_fraction),
            embree_hit: (!embree_pairs.is_empty()).then(|| embree_hits.get() as f64 / rays.len() as f64),
            tiny_pairs,
            embree_pairs,
            e_runs,
            t_runs,
            huge_ours: huge_ours.into_iter().collect(),
            huge_tiny: tiny.as_ref().and_then(|t| t.huge_mib()).into_iter().collect(),
            steps: vec![steps],
            per_proc: Vec::new(),
            procs: 1,
        };
        let raw = Raw { per_proc: vec![raw.own()], ..raw };
        if raw_index.is_some() {
            println!("RAW {}", serde_json::to_string(&raw).expect("measurements as JSON"));
        } else {
            summarize(&raw);
        }
    }
    if raw_index.is_none() {
        print_legend();
    }
}
