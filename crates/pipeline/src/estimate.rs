//! Memory estimate of a chain, checked before anything is loaded, so a scene too large for the
//! machine fails early with the estimate in the message (exit 2) instead of being killed by the
//! kernel's OOM killer halfway through a sweep.
//!
//! Model: `peak = BASE_BYTES + triangles * sum(bytes_per_triangle[stage] for the chain's stages)
//! + rays * BYTES_PER_RAY`. Each constant is the growth of the peak resident set per triangle when
//! the stage is added to a chain (the runner keeps the scene and every BVH of a chain in memory
//! until the next scene, so the stages' shares add up rather than overlap).
//!
//! Calibration (release build, `/usr/bin/time -v` "Maximum resident set size" of `bvhlab eval
//! --no-cache --repeat 1 --threads 2`, 2026-11-22; gen:sphere at n = 1k, 200k, 800k): baseline 12.5
//! MiB at 1k triangles. Load + build, growth per triangle 200k -> 800k: binned-sah 222 B, sweep-sah
//! 226, ploc 227, lbvh (+ encode) 231, aac (+ encode) 242; at 200k from the baseline: binned 186,
//! sweep-sah leaf=1 259. Files (binned-sah): stanford_bunny 213, conference 226 (tobj's arrays add
//! ~40 over a generated scene). +collapse: 13-40. +ibo (max_passes=2, after sweep-sah leaf=1): 156
//! at 200k, 163 at 50k. Random rays: nothing per triangle, ~37 B per ray. The constants below are
//! these shares rounded up by ~20% (binned 800k: estimate 264 MB, measured 179 MB; sweep leaf=1 +
//! ibo 200k: 117 vs 93). `layout` was first derived from the layouts' sizes (Kilian 6.2: at most
//! the BVH2's 32 bytes per node, ~2 nodes per triangle, plus build buffers); measured since for
//! bvh8's optimal collapse (see its constant).
use crate::error::{Error, Result};
use crate::registry::Registry;
use crate::stages::{ChainSpec, RaySpec, SceneSource};
use serde::Serialize;
use std::collections::BTreeMap;
use std::io::{BufRead, Read};

/// The stages with a per-triangle share, in chain order.
pub const STAGES: [&str; 7] = [
    "load", "encode", "build", "optimize", "compact", "layout", "measure",
];

/// Process baseline (binary, rayon pools, allocator): 12.5 MiB measured, rounded up.
pub const BASE_BYTES: u64 = 16 << 20;

/// Per ray traced (ray, hit record, counters, heat map pixel; shadow rays include their primary
/// pass): ~37 B measured, rounded up.
pub const BYTES_PER_RAY: u64 = 64;

/// Text bytes per triangle of an OBJ file: 33-47 on the shared scenes (bunny 34.7, armadillo 46.7,
/// sibenik 33.2, breakfast_room 36.9, conference 37.5); the low end overestimates the count.
pub const OBJ_TEXT_BYTES_PER_TRIANGLE: u64 = 30;

/// Peak growth per triangle when `stage` is in the chain (see the module comment).
pub fn bytes_per_triangle(stage: &str) -> f64 {
    match stage {
        // The scene (36 B/triangle), its serialized artifact while it is written, and for files
        // tobj's vertex and index arrays while parsing (~40).
        "load" => 110.0,
        // Codes + order (12-16 B) and the radix sort's buffers (aac/lbvh minus binned: 9-20).
        "encode" => 25.0,
        // Boxes + centres (36 B), the builder's work arrays, the BVH (~2 nodes x 32 B + 4 B index
        // for leaf=1) and its artifact bytes (load + build: 186-259 measured).
        "build" => 200.0,
        // DynTree (explicit children, parents, boxes), the search queues and the output BVH (156-163).
        "optimize" => 190.0,
        // The collapsed BVH and its artifact (13-40).
        "compact" => 45.0,
        // Derived (see the module comment); since the SAH-optimal wide collapse, measured for bvh8
        // of a leaf=1 tree (gen:sphere:n=200000, `eval --layout bvh8`): 108 (the programme's
        // 40 bytes per binary node, two per triangle, plus the wide tree).
        "layout" => 130.0,
        // Traversal reads the scene and BVH counted above (rays are counted per ray); the timed
        // path copies the triangles into leaf order (48 bytes per triangle, `TriStore`; the wide
        // layouts' packs of four, 40 bytes per triangle and a partly filled pack per leaf).
        "measure" => 60.0,
        _ => 0.0,
    }
}

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MemoryEstimate {
    pub triangles: u64,
    /// Whether `triangles` is exact (generators with an exact count, uncompressed OBJ files) or an
    /// estimate (approximate generator counts, `.obj.gz` from its uncompressed size).
    pub triangles_exact: bool,
    /// Stages of the chain -> bytes per triangle.
    pub bytes_per_triangle: BTreeMap<String, f64>,
    pub rays: u64,
    pub peak_bytes: u64,
}

/// The chain's stages that have a per-triangle share. `layout` is added by callers whose chain has a
/// layout stage.
pub fn chain_stages(spec: &ChainSpec, registry: &Registry) -> Vec<&'static str> {
    let mut out = vec!["load"];
    let codes = registry
        .get(&spec.build)
        .map(|b| b.codes.is_some())
        .unwrap_or(false);
    if codes {
        out.push("encode");
    }
    out.push("build");
    if spec.optimize.is_some() {
        out.push("optimize");
    }
    if spec.compact != "none" {
        out.push("compact");
    }
    if spec.layout.is_some() {
        out.push("layout");
    }
    if spec.rays.is_some() {
        out.push("measure");
    }
    out
}

pub fn ray_count(r: &RaySpec) -> u64 {
    match *r {
        RaySpec::Primary { width, height } => width as u64 * height as u64,
        // Primary rays first, then one shadow ray per hit.
        RaySpec::Shadow { width, height } => 2 * width as u64 * height as u64,
        RaySpec::Random { count } => count as u64,
    }
}

/// Estimate for a chain; None when the triangle count cannot be told without loading the scene
/// (a generator without an `n`-like parameter; such generators are small).
pub fn chain_estimate(spec: &ChainSpec, stages: &[&str]) -> Result<Option<MemoryEstimate>> {
    Ok(triangle_count(&spec.source)?.map(|count| estimate(spec, stages, count)))
}

/// Estimate for a chain over a scene of `(triangles, exact)` (from `triangle_count`).
pub fn estimate(
    spec: &ChainSpec,
    stages: &[&str],
    (triangles, exact): (u64, bool),
) -> MemoryEstimate {
    let bpt: BTreeMap<String, f64> = stages
        .iter()
        .map(|s| (s.to_string(), bytes_per_triangle(s)))
        .collect();
    let rays = spec.rays.as_ref().map(ray_count).unwrap_or(0);
    let per_tri: f64 = bpt.values().sum();
    let peak = BASE_BYTES as f64 + triangles as f64 * per_tri + (rays * BYTES_PER_RAY) as f64;
    MemoryEstimate {
        triangles,
        triangles_exact: exact,
        bytes_per_triangle: bpt,
        rays,
        peak_bytes: peak.ceil() as u64,
    }
}

/// Triangles of a scene without loading it: generators from their parameters, `.obj` files by
/// streaming their `f` lines (a face of k vertices is k - 2 triangles), `.obj.gz` files from the
/// uncompressed size in the gzip trailer (ISIZE, mod 2^32; at least 3x the compressed size) over
/// `OBJ_TEXT_BYTES_PER_TRIANGLE`.
pub fn triangle_count(source: &SceneSource) -> Result<Option<(u64, bool)>> {
    match source {
        SceneSource::Gen(g) => {
            let canon = bvhlab_geom::gen::canonical_spec(g)?;
            Ok(gen_triangles(&canon))
        }
        SceneSource::File(path) => {
            let err = |e: std::io::Error| crate::catalogue::read_error(path, &e);
            let mut f = std::fs::File::open(path).map_err(err)?;
            let mut magic = [0u8; 2];
            let n = f.read(&mut magic).map_err(err)?;
            if n == 2 && magic == [0x1f, 0x8b] {
                use std::io::{Seek, SeekFrom};
                let len = f.seek(SeekFrom::End(0)).map_err(err)?;
                let mut isize = [0u8; 4];
                let trailer = if len >= 4 {
                    f.seek(SeekFrom::End(-4)).map_err(err)?;
                    f.read_exact(&mut isize).map_err(err)?;
                    u32::from_le_bytes(isize) as u64
                } else {
                    0
                };
                let text = trailer.max(3 * len);
                return Ok(Some((text / OBJ_TEXT_BYTES_PER_TRIANGLE, false)));
            }
            let f = std::fs::File::open(path).map_err(err)?;
            let r = std::io::BufReader::with_capacity(1 << 16, f);
            Ok(Some((count_faces(r).map_err(err)?.0, true)))
        }
    }
}

/// Triangles of OBJ text (a face of k vertices is k - 2 triangles) and its length in bytes.
fn count_faces(mut r: impl BufRead) -> std::io::Result<(u64, u64)> {
    let mut line = Vec::new();
    let (mut tris, mut bytes) = (0u64, 0u64);
    loop {
        line.clear();
        let n = r.read_until(b'\n', &mut line)?;
        if n == 0 {
            break;
        }
        // A UTF-8 byte-order mark before the first statement (the loader skips it too).
        let l = if bytes == 0 {
            line.strip_prefix(b"\xef\xbb\xbf").unwrap_or(&line)
        } else {
            &line
        };
        bytes += n as u64;
        if l.starts_with(b"f ") || l.starts_with(b"f\t") {
            let verts = l[1..]
                .split(|b| b.is_ascii_whitespace())
                .filter(|t| !t.is_empty())
                .count() as u64;
            tris += verts.saturating_sub(2);
        }
    }
    Ok((tris, bytes))
}

/// `check` for a chain over `source`: an `.obj.gz` whose estimate (from its gzip size trailer)
/// exceeds the limit is decompressed (streamed) before the refusal, because a truncated or
/// corrupt file's last four bytes are not a size at all (issue 15: a truncated file was refused
/// as "not enough memory"). A stream that ends early is reported as such; a sound one is judged
/// again by its exact face count. The happy path still reads only the trailer.
pub fn check_source(
    scene: &str,
    source: &SceneSource,
    est: &MemoryEstimate,
    limit: Option<&(u64, String)>,
) -> Result<MemoryEstimate> {
    let refused = match check(scene, est, limit) {
        Ok(()) => return Ok(est.clone()),
        Err(e) => e,
    };
    let SceneSource::File(path) = source else {
        return Err(refused);
    };
    if est.triangles_exact {
        return Err(refused);
    }
    let (tris, _) = gzip_face_count(path)?;
    let exact = MemoryEstimate {
        triangles: tris,
        triangles_exact: true,
        peak_bytes: (est.peak_bytes as f64
            + (tris as f64 - est.triangles as f64) * est.bytes_per_triangle.values().sum::<f64>())
        .max(BASE_BYTES as f64)
        .ceil() as u64,
        ..est.clone()
    };
    check(scene, &exact, limit)?;
    Ok(exact)
}

/// Exact triangles and text bytes of a gzip-compressed OBJ, by streaming it; a truncated or
/// corrupt stream is an input error naming the file and how much text it held.
pub fn gzip_face_count(path: &std::path::Path) -> Result<(u64, u64)> {
    let f = std::fs::File::open(path)
        .map_err(|e| crate::catalogue::read_error(path, &e))?;
    let len = f.metadata().map(|m| m.len()).unwrap_or(0);
    let mut counted = CountingReader { inner: f, bytes: 0 };
    let gz = flate2::read::MultiGzDecoder::new(&mut counted);
    let mut text = CountingReader {
        inner: gz,
        bytes: 0,
    };
    let r = std::io::BufReader::with_capacity(1 << 16, &mut text);
    match count_faces(r) {
        Ok(x) => Ok(x),
        Err(e) => {
            let what = if e.kind() == std::io::ErrorKind::UnexpectedEof {
                "truncated gzip file: the compressed stream ends early"
            } else {
                "corrupt or truncated gzip file"
            };
            let read = text.bytes;
            Err(Error::input(format!(
                "{}: {what} ({e}) after {read} bytes of OBJ text from {len} compressed bytes; its size \
                 trailer cannot be trusted, so no estimate or load is possible (re-download or re-compress it)",
                path.display()
            )))
        }
    }
}

struct CountingReader<R> {
    inner: R,
    bytes: u64,
}

impl<R: Read> Read for CountingReader<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.bytes += n as u64;
        Ok(n)
    }
}

/// Triangle count of a canonical generator spec `name:k=v,...` (see `bvhlab scenes`).
fn gen_triangles(canon: &str) -> Option<(u64, bool)> {
    let (name, rest) = canon.split_once(':').unwrap_or((canon, ""));
    let params: BTreeMap<&str, f64> = rest
        .split(',')
        .filter_map(|kv| kv.split_once('='))
        .filter_map(|(k, v)| v.parse::<f64>().ok().map(|v| (k, v)))
        .collect();
    let p = |k: &str| params.get(k).copied();
    // Same rounding as the generators' grid size (gen.rs grid_k).
    let grid = |n: f64, per: f64| ((n / per).sqrt().round().max(1.0)) as u64;
    Some(match name {
        "sphere" => {
            let k = grid(p("n")?, 12.0);
            (12 * k * k, true)
        }
        "outlier" => {
            let k = grid(p("n")?, 12.0);
            (12 * k * k + 1, true)
        }
        "terrain" => {
            let k = grid(p("n")?, 2.0);
            (2 * k * k, true)
        }
        "hairball" | "degenerate" => (p("n")? as u64, true),
        "city" => {
            let b = p("blocks")? as u64;
            (12 * b * b + 2, true)
        }
        // Generators added later: their `n` is a triangle count or close to one.
        _ => (p("n")? as u64, false),
    })
}

/// `MemAvailable` from /proc/meminfo (Linux), in bytes.
pub fn mem_available() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = s.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

/// `123`, `512K`, `64M`, `2G`, `1.5G` (binary units, optional `B`/`iB`).
pub fn parse_bytes(s: &str) -> Result<u64> {
    let t = s.trim();
    let upper = t.to_ascii_uppercase();
    let body = upper
        .strip_suffix("IB")
        .or_else(|| upper.strip_suffix('B'))
        .unwrap_or(&upper);
    let (num, mult) = match body.chars().last() {
        Some('K') => (&body[..body.len() - 1], 1u64 << 10),
        Some('M') => (&body[..body.len() - 1], 1 << 20),
        Some('G') => (&body[..body.len() - 1], 1 << 30),
        Some('T') => (&body[..body.len() - 1], 1 << 40),
        _ => (body, 1),
    };
    let v: f64 = num.trim().parse().map_err(|_| {
        Error::input(format!(
            "memory size `{s}`: expected bytes, e.g. 1000000, 512M or 2G"
        ))
    })?;
    if !v.is_finite() || v < 0.0 {
        return Err(Error::input(format!("memory size `{s}` must be positive")));
    }
    Ok((v * mult as f64) as u64)
}

/// The memory a chain may use: `--max-memory` > `BVHLAB_MAX_MEMORY` > MemAvailable; None when
/// none is known (no check).
pub fn memory_limit(cli: Option<&str>) -> Result<Option<(u64, String)>> {
    if let Some(s) = cli {
        return Ok(Some((parse_bytes(s)?, "--max-memory".into())));
    }
    if let Ok(s) = std::env::var("BVHLAB_MAX_MEMORY") {
        if !s.trim().is_empty() {
            return Ok(Some((parse_bytes(&s)?, "BVHLAB_MAX_MEMORY".into())));
        }
    }
    Ok(mem_available().map(|b| (b, "MemAvailable".into())))
}

fn mib(b: u64) -> String {
    format!("{:.1} MiB", b as f64 / (1u64 << 20) as f64)
}

/// An input error (exit 2) when the estimate exceeds the limit, naming the estimate and its parts.
pub fn check(scene: &str, est: &MemoryEstimate, limit: Option<&(u64, String)>) -> Result<()> {
    let Some((limit, source)) = limit else {
        return Ok(());
    };
    if est.peak_bytes <= *limit {
        return Ok(());
    }
    let parts: Vec<String> = est
        .bytes_per_triangle
        .iter()
        .map(|(s, b)| format!("{s} {b:.0}"))
        .collect();
    Err(Error::input(format!(
        "{scene}: not enough memory: estimated peak {} for {}{} triangles (bytes per triangle: {}; \
         + {} rays) exceeds {} ({source}); use a smaller scene or fewer stages, or raise the limit \
         with --max-memory / BVHLAB_MAX_MEMORY",
        mib(est.peak_bytes),
        if est.triangles_exact { "" } else { "~" },
        est.triangles,
        parts.join(", "),
        est.rays,
        mib(*limit),
    )))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn generator_counts_match_the_generators() {
        for spec in [
            "sphere:n=20000",
            "sphere:n=7",
            "terrain:n=5000",
            "hairball:n=1000",
            "city:blocks=7",
            "outlier:n=3000,e=4",
            "degenerate:n=333",
        ] {
            let canon = bvhlab_geom::gen::canonical_spec(spec).unwrap();
            let (n, exact) = gen_triangles(&canon).unwrap();
            let real = bvhlab_geom::gen::generate(spec).unwrap().triangles.len() as u64;
            assert!(exact);
            assert_eq!(n, real, "{spec}");
        }
    }

    #[test]
    fn obj_faces_are_counted_by_streaming() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.obj");
        std::fs::write(
            &p,
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 1 2 4 3\n# f 1 2 3\n",
        )
        .unwrap();
        let n = triangle_count(&SceneSource::File(p)).unwrap();
        assert_eq!(n, Some((3, true)));
    }

    #[test]
    fn truncated_gzip_is_reported_as_truncated_not_as_memory() {
        use std::io::Write;
        let dir = tempfile::tempdir().unwrap();
        let mut text = String::from("\u{feff}f 1 2 3\n");
        for i in 0..20_000 {
            text.push_str(&format!(
                "v {i} {} 0.5\nv 1 {i} 0\nv 0 1 {i}\nf -3 -2 -1\n",
                i * 7 % 13
            ));
        }
        let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
        gz.write_all(text.as_bytes()).unwrap();
        let whole = gz.finish().unwrap();
        let good = dir.path().join("good.obj.gz");
        std::fs::write(&good, &whole).unwrap();
        // The BOM does not hide the first face from the count.
        assert_eq!(gzip_face_count(&good).unwrap(), (20_001, text.len() as u64));
        // Cut in the middle, then with 4 bytes that read as a huge size trailer.
        let cut = dir.path().join("cut.obj.gz");
        let mut bytes = whole[..whole.len() / 2].to_vec();
        bytes.extend_from_slice(&[0xff, 0xff, 0xff, 0x7f]);
        std::fs::write(&cut, &bytes).unwrap();
        let reg = Registry::standard();
        for (p, truncated) in [(&good, false), (&cut, true)] {
            let src = SceneSource::File(p.clone());
            let spec = ChainSpec::new(p.to_str().unwrap(), "binned-sah");
            let est = estimate(
                &spec,
                &chain_stages(&spec, &reg),
                triangle_count(&src).unwrap().unwrap(),
            );
            let limit = (256u64 << 20, "--max-memory".to_string());
            let r = check_source("s", &src, &est, Some(&limit));
            if truncated {
                // The trailer promised ~2 GB of text: refused by the estimate, then found truncated.
                assert!(check("s", &est, Some(&limit)).is_err());
                let e = r.unwrap_err();
                assert_eq!(e.exit_code(), 2);
                assert!(
                    e.message().contains("cut.obj.gz: ")
                        && e.message().contains("truncated gzip file"),
                    "{e}"
                );
                assert!(!e.message().contains("not enough memory"), "{e}");
            } else {
                assert!(r.is_ok(), "{r:?}");
            }
        }
    }

    #[test]
    fn byte_sizes_parse() {
        assert_eq!(parse_bytes("1000").unwrap(), 1000);
        assert_eq!(parse_bytes("2K").unwrap(), 2048);
        assert_eq!(parse_bytes("1.5G").unwrap(), 3 << 29);
        assert_eq!(parse_bytes("64MiB").unwrap(), 64 << 20);
        assert!(parse_bytes("lots").is_err());
    }

    #[test]
    fn too_large_is_an_input_error_with_the_estimate() {
        let spec = ChainSpec::new("gen:sphere:n=20000", "binned-sah");
        let reg = Registry::standard();
        let est = chain_estimate(&spec, &chain_stages(&spec, &reg))
            .unwrap()
            .unwrap();
        assert_eq!(est.triangles, 12 * 41 * 41);
        assert!(est.peak_bytes > BASE_BYTES);
        assert!(check("s", &est, Some(&(u64::MAX, "x".into()))).is_ok());
        let e = check("s", &est, Some(&(1000, "--max-memory".into()))).unwrap_err();
        assert_eq!(e.exit_code(), 2);
        assert!(e.message().contains("estimated peak"), "{e}");
        assert!(e.message().contains("build 200"), "{e}");
    }
}

// ---- time ------------------------------------------------------------------------------------

/// Estimated wall seconds to compute one node (all `repeat` runs, each at least
/// `batch::MIN_RUN_SECONDS` where timed, validation and writing), for
/// plans and shard balancing (`crate::plan`). Deterministic: it depends only on the node's stage
/// and parameters, the scene's triangle count and the rays, never on the machine or the cache.
///
/// Calibration (release build, 2026-11-25, this 2-core AMD EPYC VM), from the `compute_seconds` of
/// every manifest of two cold sweeps: `experiments/quick.toml` (445 nodes, 1k-20k triangles, 2
/// threads) and the Slurm test experiment (crates/cli/tests/slurm.rs: 148 nodes, 3k-120k
/// triangles, 1 thread, as shards run with `--cpus-per-task 1`). Per (stage, method) the median of
/// seconds / (repeat x triangles), 1-thread figures where both exist; measure per ray x
/// log2(triangles). In ns per triangle per repeat: load 164-169 (generated scenes; files parse
/// slower, taken as 3x), encode morton 64 / emc64 92, build lbvh 241, spatial-median 215, binned-sah
/// 318, bonsai 245 (2 threads), ploc 347, aac 578, sweep-sah 614, incremental 533 (2 threads),
/// compact 115, optimize ibo 2442 (232-14934: passes vary), kensler 597, layout bvh2 60, qbvh_chunks 359,
/// octree_1bit 562, auto 3104 (once, not per repeat: x5 there). Measure, ns per ray per log2(triangles)
/// per repeat: random 48.8 (1 thread; 13.0 on 2 threads), primary about a third of random; with a
/// layout (traced beside bvh2, 2 threads): bvh2 25, qbvh_chunks 43, octree/octree_1bit 58, auto 35 for random
/// rays, taken as multiples of the plain measure. The spread within a method is 2-5x, and 50x for
/// the hairball's rays (its boxes overlap), so a node's estimate is good to a factor of a few; the
/// shards balance many nodes of similar kind, whose errors are alike, so LPT still spreads them
/// evenly. Cold `cluster-test` (1 thread): 4.2 s estimated with the 2-thread constants, 19.0 s
/// measured (16.2 s of it measure); the constants above are the refit. Measure nodes of the scenes
/// whose rays visit far more than log2(triangles) nodes (hairball; city through an octree) are
/// scaled by `trace_factor` (`scene` is the chain's scene spec).
pub fn node_seconds(
    stage: &str,
    params: &BTreeMap<String, String>,
    triangles: u64,
    rays: u64,
    layout: Option<&str>,
    scene: &str,
) -> f64 {
    let t = triangles.max(1) as f64;
    let repeat: f64 = params
        .get("repeat")
        .and_then(|r| r.parse().ok())
        .unwrap_or(1.0f64)
        .max(1.0);
    let p = |k: &str| params.get(k).map(String::as_str).unwrap_or("");
    // Every node but a load reads its inputs from the cache (scene, BVH): ~20 ns per triangle,
    // plus process-level overhead per node.
    let overhead = 0.01 + if stage == "load" { 0.0 } else { 20e-9 * t };
    let ns_per_tri = |ns: f64| ns * 1e-9 * t * repeat;
    let work = match stage {
        "load" => {
            // Generated scenes are keyed by `gen`, files by `content`.
            if params.contains_key("content") {
                500e-9 * t
            } else {
                170e-9 * t
            }
        }
        "encode" => ns_per_tri(if p("encoder") == "morton" { 64.0 } else { 92.0 }),
        "build" => ns_per_tri(match p("builder") {
            "lbvh" => 240.0,
            "spatial-median" => 215.0,
            "binned-sah" => 320.0,
            "bonsai" => 350.0,
            "ploc" => {
                // PLOC's search window grows with the radius (thesis 3.6): r = 10 calibrated.
                let r: f64 = p("radius").parse().unwrap_or(10.0);
                350.0 * (0.5 + 0.05 * r)
            }
            "aac" => 580.0,
            "sweep-sah" => 615.0,
            "incremental" => 750.0,
            // Lookahead sweeps near the root (docs/decisions.md, SBVH): conference 37 us, breakfast_room
            // 57 us per triangle (2 threads, 2026-11-26).
            "sbvh" => 45_000.0,
            _ => 400.0,
        }),
        "optimize" => ns_per_tri(match p("optimizer") {
            "ibo" => 2500.0,
            _ => 600.0,
        }),
        "compact" => ns_per_tri(115.0),
        "layout" => match p("layout") {
            "auto" => 15_000e-9 * t,
            "bvh2" => ns_per_tri(60.0),
            // Not measured yet: one pass over the binary tree like bvh2 plus the node rows.
            "bvh4" | "bvh8" | "cwbvh" => ns_per_tri(100.0),
            "qbvh_chunks" => ns_per_tri(360.0),
            _ => ns_per_tri(600.0),
        },
        "measure" => {
            let kind = p("rays").split(':').next().unwrap_or("");
            let base = if kind == "random" { 45.0 } else { 14.0 };
            let per_ray = match layout {
                None => base,
                Some("bvh2") => 2.0 * base,
                // Not measured yet: the untimed counting pass plus the fast timed runs.
                Some("bvh4" | "bvh8" | "cwbvh") => 2.0 * base,
                Some("qbvh_chunks") => 3.3 * base,
                Some("auto") => 2.7 * base,
                Some(_) => 4.5 * base,
            };
            per_ray * 1e-9 * rays as f64 * t.log2().max(1.0) * repeat
                * trace_factor(scene, layout, p("rays"), triangles)
        }
        "focus" => 30e-9 * t,
        _ => 100e-9 * t,
    };
    // A timed run lasts at least `batch::MIN_RUN_SECONDS` (short calls are batched); a measure
    // with a layout times the layout and bvh2 (a layout `bvh2` times one side).
    let timed = matches!(stage, "encode" | "build" | "optimize" | "compact" | "measure")
        || (stage == "layout" && p("layout") != "auto");
    let sides = if stage == "measure" && layout.is_some_and(|l| l != "bvh2") { 2.0 } else { 1.0 };
    let floor = if timed { repeat * sides * crate::batch::MIN_RUN_SECONDS } else { 0.0 };
    overhead + work.max(floor)
}

/// Factor on a measure node's estimate for the generated scenes whose rays do not follow the
/// `log2(triangles)` traversal model of `node_seconds` (measured on the quick sweep, 2026-11-25:
/// every other scene and layout within 0.1-1x of the model, these 17-70x above it):
/// - `gen:hairball`: long thin strands whose boxes all overlap, so a ray tests a fixed fraction of
///   the scene (~0.2 n intersections at n = 1000) instead of ~log2 n;
/// - `gen:city` traced through an octree layout: the ground plane is repeated in every leaf above
///   it (Kilian 2021 6.4's failure case), about 19000 triangle tests per random ray at 10802
///   triangles; primary rays from the default camera are unaffected.
pub fn trace_factor(scene: &str, layout: Option<&str>, rays: &str, triangles: u64) -> f64 {
    let generator = scene
        .strip_prefix("gen:")
        .map(|g| g.split(':').next().unwrap_or(""));
    let t = triangles.max(2) as f64;
    match generator {
        Some("hairball") => (0.2 * t / t.log2()).max(1.0),
        Some("city")
            if layout.is_some_and(|l| l.starts_with("octree")) && rays.starts_with("random") =>
        {
            70.0
        }
        _ => 1.0,
    }
}
