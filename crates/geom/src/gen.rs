//! Deterministic generated scenes, addressed as `gen:NAME[:key=value,...]`.
//!
//! Bit-identical output on every platform: randomness is a self-contained splitmix64, and
//! geometry uses only + - * / and sqrt (all correctly rounded in IEEE 754), never sin/cos/exp
//! whose results differ between libms. Coordinates are computed in f64, rounded once to f32.
//!
//! The scenes model the cases the papers stress: tessellated objects (sphere), flat geometry
//! (terrain), long thin overlapping triangles (hairball), small objects on a huge primitive
//! (city; Frantal thesis, architectural scenes with big polygons), a distant tiny outlier
//! (outlier; Riemersma 2024, Morton code precision), and degenerate input (degenerate).
//! The stress scenes of issue 6 (huge-edge, flat, slivers, dups, same-centroid, scale, nonfinite,
//! single, staircase) isolate one failure mode each: huge primitives, zero extents, overlap,
//! duplicates, coincident centroids, float range, NaN/inf input, n = 1 and very deep trees.
use crate::{LoadError, Scene, Triangle};
use glam::DVec3;
use std::collections::BTreeMap;
use std::path::PathBuf;

/// A generator's name, its parameters (name, default, meaning) and what it models.
pub struct GeneratorInfo {
    pub name: &'static str,
    pub about: &'static str,
    pub params: &'static [(&'static str, &'static str, &'static str)],
}

/// Value range of a parameter; checked before generating.
#[derive(Clone, Copy)]
enum Range {
    Int(u64, u64),
    Float(f64, f64),
}

struct Param {
    name: &'static str,
    default: &'static str,
    range: Range,
}

struct Gen {
    info: GeneratorInfo,
    ranges: &'static [Range],
    build: fn(&Values) -> Vec<Triangle>,
}

const N_MAX: u64 = 50_000_000;
const SEED: Range = Range::Int(0, u64::MAX);
const SHUFFLE_ABOUT: &str = "0: triangles in generation order (spatially coherent, like most files); \
    k > 0: randomly permuted with seed k, so that only the codes, not the input order, carry locality \
    (Morton failure studies: builders break ties between equal codes by input order)";

fn table() -> Vec<Gen> {
    vec![
        Gen {
            info: GeneratorInfo {
                name: "sphere",
                about: "unit sphere tessellated from a subdivided cube: a closed, evenly tessellated object",
                params: &[("n", "20000", "approximate triangle count (12 k^2 for a k x k grid per cube face)")],
            },
            ranges: &[Range::Int(1, N_MAX)],
            build: |p| sphere(p.int("n"), DVec3::ZERO, 1.0),
        },
        Gen {
            info: GeneratorInfo {
                name: "terrain",
                about: "flat heightfield on the unit square (y up): huge extent in x/z, small in y",
                params: &[
                    ("n", "20000", "approximate triangle count (2 k^2 for a k x k grid)"),
                    ("h", "0.05", "height amplitude relative to the side length"),
                    ("seed", "1", "random seed"),
                ],
            },
            ranges: &[Range::Int(1, N_MAX), Range::Float(0.0, 1e3), SEED],
            build: |p| terrain(p.int("n"), p.float("h"), p.int("seed")),
        },
        Gen {
            info: GeneratorInfo {
                name: "hairball",
                about: "random long thin triangles criss-crossing the unit cube: heavily overlapping boxes",
                params: &[
                    ("n", "20000", "triangle count (exact)"),
                    ("width", "0.001", "triangle width relative to the cube side"),
                    ("seed", "1", "random seed"),
                ],
            },
            ranges: &[Range::Int(1, N_MAX), Range::Float(0.0, 1.0), SEED],
            build: |p| hairball(p.int("n"), p.float("width"), p.int("seed")),
        },
        Gen {
            info: GeneratorInfo {
                name: "city",
                about: "blocks x blocks small box buildings on one ground quad far larger than them",
                params: &[
                    ("blocks", "30", "buildings per side (12 blocks^2 + 2 triangles)"),
                    ("ground", "100", "ground quad side relative to the city side"),
                    ("seed", "1", "random seed"),
                    ("shuffle", "0", SHUFFLE_ABOUT),
                ],
            },
            ranges: &[Range::Int(1, 2000), Range::Float(1.0, 1e6), SEED, SEED],
            build: |p| shuffled(city(p.int("blocks"), p.float("ground"), p.int("seed")), p.int("shuffle")),
        },
        Gen {
            info: GeneratorInfo {
                name: "outlier",
                about: "a dense unit sphere plus one tiny triangle 2^e object sizes away along the diagonal",
                params: &[
                    ("n", "20000", "approximate triangle count of the sphere"),
                    ("e", "10", "outlier distance from the sphere centre is 2^e sphere diameters"),
                    ("shuffle", "0", SHUFFLE_ABOUT),
                ],
            },
            ranges: &[Range::Int(1, N_MAX), Range::Int(0, 100), SEED],
            build: |p| shuffled(outlier(p.int("n"), p.int("e")), p.int("shuffle")),
        },
        Gen {
            info: GeneratorInfo {
                name: "degenerate",
                about: "robustness mix: zero-area (collinear, point) triangles, exact duplicates, \
                        triangles sharing one box centre, axis-aligned flat ones, ordinary ones",
                params: &[("n", "10000", "triangle count (exact)"), ("seed", "1", "random seed")],
            },
            ranges: &[Range::Int(1, N_MAX), SEED],
            build: |p| degenerate(p.int("n"), p.int("seed")),
        },
        // Stress scenes (issue 6): the inputs on which BVH libraries are known to break.
        Gen {
            info: GeneratorInfo {
                name: "huge-edge",
                about: "small triangles in the unit cube plus a few huge sheets at the scene edge (x = 1), \
                        size times larger, whose boxes overlap everything",
                params: &[
                    ("n", "2000", "small triangles (exact)"),
                    ("huge", "4", "huge triangles added after them"),
                    ("size", "1000", "half side of the huge triangles relative to the unit cube"),
                    ("seed", "1", "random seed"),
                ],
            },
            ranges: &[Range::Int(1, N_MAX), Range::Int(0, 1000), Range::Float(0.0, 1e30), SEED],
            build: |p| huge_edge(p.int("n"), p.int("huge"), p.float("size"), p.int("seed")),
        },
        Gen {
            info: GeneratorInfo {
                name: "flat",
                about: "random small triangles all in the plane z = 0.5 exactly: every box has zero z extent",
                params: &[("n", "2000", "triangle count (exact)"), ("seed", "1", "random seed")],
            },
            ranges: &[Range::Int(1, N_MAX), SEED],
            build: |p| flat(p.int("n"), p.int("seed")),
        },
        Gen {
            info: GeneratorInfo {
                name: "slivers",
                about: "long thin triangles spanning almost the whole x range, all overlapping the middle; \
                        every 8th exactly collinear (zero area)",
                params: &[
                    ("n", "2000", "triangle count (exact)"),
                    ("width", "0.0001", "sliver width relative to the unit cube"),
                    ("seed", "1", "random seed"),
                ],
            },
            ranges: &[Range::Int(1, N_MAX), Range::Float(0.0, 1.0), SEED],
            build: |p| slivers(p.int("n"), p.float("width"), p.int("seed")),
        },
        Gen {
            info: GeneratorInfo {
                name: "dups",
                about: "every triangle repeated exactly `copies` times (interleaved), a third of them zero-area \
                        (points, collinear, two equal vertices)",
                params: &[
                    ("n", "2000", "triangle count (exact)"),
                    ("copies", "8", "exact copies of each distinct triangle"),
                    ("seed", "1", "random seed"),
                ],
            },
            ranges: &[Range::Int(1, N_MAX), Range::Int(1, N_MAX), SEED],
            build: |p| dups(p.int("n"), p.int("copies"), p.int("seed")),
        },
        Gen {
            info: GeneratorInfo {
                name: "same-centroid",
                about: "triangles of very different sizes whose boxes all share one centre exactly \
                        (dyadic coordinates): centroid bounds of zero extent",
                params: &[("n", "2000", "triangle count (exact)"), ("seed", "1", "random seed")],
            },
            ranges: &[Range::Int(1, N_MAX), SEED],
            build: |p| same_centroid(p.int("n"), p.int("seed")),
        },
        Gen {
            info: GeneratorInfo {
                name: "scale",
                about: "random small triangles in the cube [0, s]^3 moved by t s along every axis: s = 1e-30 or \
                        1e30 tests float range (areas under- or overflow f32), t = 10^k precision far from the origin",
                params: &[
                    ("n", "2000", "triangle count (exact)"),
                    ("s", "1", "scale of every coordinate"),
                    ("t", "0", "translation in units of the cube side (the cube spans [t s, (t + 1) s])"),
                    ("seed", "1", "random seed"),
                ],
            },
            ranges: &[Range::Int(1, N_MAX), Range::Float(1e-37, 3.4e38), Range::Float(-1e30, 1e30), SEED],
            build: |p| scale(p.int("n"), p.float("s"), p.float("t"), p.int("seed")),
        },
        Gen {
            info: GeneratorInfo {
                name: "nonfinite",
                about: "random triangles of which `bad` (spread evenly) get a NaN, +inf, -inf or f32-overflowing \
                        coordinate: the scene drops and counts them (dropped_triangles = bad)",
                params: &[
                    ("n", "2000", "triangles generated, including the bad ones"),
                    ("bad", "200", "non-finite triangles among them (at most n)"),
                    ("seed", "1", "random seed"),
                ],
            },
            ranges: &[Range::Int(1, N_MAX), Range::Int(0, N_MAX), SEED],
            build: |p| nonfinite(p.int("n"), p.int("bad"), p.int("seed")),
        },
        Gen {
            info: GeneratorInfo {
                name: "single",
                about: "one triangle (seed 0: (0,0,0) (1,0,0) (0,1,0); otherwise random in the unit cube)",
                params: &[("seed", "0", "random seed (0: the fixed right triangle)")],
            },
            ranges: &[SEED],
            build: |p| single(p.int("seed")),
        },
        Gen {
            info: GeneratorInfo {
                name: "staircase",
                about: "n equal steps (one tread triangle each) climbing the diagonal of the unit square in x/y: \
                        a long, thin, one-dimensional scene; input-order insertion makes trees as deep as n",
                params: &[("n", "100000", "steps = triangles (exact)")],
            },
            ranges: &[Range::Int(1, N_MAX)],
            build: |p| staircase(p.int("n")),
        },
    ]
}

pub fn generators() -> Vec<GeneratorInfo> {
    table().into_iter().map(|g| g.info).collect()
}

/// `spec` is the part after `gen:`, e.g. `sphere:n=10000`.
pub fn generate(spec: &str) -> Result<Scene, LoadError> {
    let (g, values) = parse(spec)?;
    let scene = Scene::from_triangles((g.build)(&values));
    // Same rule as the OBJ loader: a scene with nothing finite left is an error, not an empty scene.
    if scene.triangles.is_empty() {
        return Err(spec_err(
            spec,
            format!(
                "no triangles with finite coordinates ({} non-finite dropped)",
                scene.dropped_triangles
            ),
        ));
    }
    Ok(scene)
}

/// `NAME:k=v,...` with every parameter (defaults filled in), keys sorted and values normalised,
/// so equal scenes get equal keys (`sphere` and `sphere:n=20000` alike). `spec` is after `gen:`.
pub fn canonical_spec(spec_after_gen: &str) -> Result<String, LoadError> {
    let (g, values) = parse(spec_after_gen)?;
    let kv: Vec<String> = values
        .0
        .iter()
        .map(|(k, v)| format!("{k}={}", v.canonical()))
        .collect();
    Ok(format!("{}:{}", g.info.name, kv.join(",")))
}

#[derive(Clone, Copy, Debug)]
enum Value {
    Int(u64),
    Float(f64),
}

impl Value {
    fn canonical(&self) -> String {
        match self {
            Value::Int(i) => i.to_string(),
            // Shortest round-trip form: "0.05", "100", "1e-7".
            Value::Float(f) => format!("{f:?}").trim_end_matches(".0").to_string(),
        }
    }
}

struct Values(BTreeMap<&'static str, Value>);

impl Values {
    fn int(&self, k: &str) -> u64 {
        match self.0.get(k) {
            Some(Value::Int(i)) => *i,
            _ => unreachable!("generator table declares {k} as an integer"),
        }
    }
    fn float(&self, k: &str) -> f64 {
        match self.0.get(k) {
            Some(Value::Float(f)) => *f,
            _ => unreachable!("generator table declares {k} as a number"),
        }
    }
}

fn spec_err(spec: &str, reason: String) -> LoadError {
    LoadError {
        file: PathBuf::from(format!("gen:{spec}")),
        line: None,
        reason,
    }
}

fn parse_value(name: &str, s: &str, range: Range) -> Result<Value, String> {
    match range {
        Range::Int(lo, hi) => {
            let v: u64 = s
                .parse()
                .map_err(|_| format!("parameter {name}: {s:?} is not a non-negative integer"))?;
            if v < lo || v > hi {
                return Err(format!(
                    "parameter {name} = {v} is out of range {lo}..={hi}"
                ));
            }
            Ok(Value::Int(v))
        }
        Range::Float(lo, hi) => {
            let v: f64 = s
                .parse()
                .map_err(|_| format!("parameter {name}: {s:?} is not a number"))?;
            if !v.is_finite() || v < lo || v > hi {
                return Err(format!(
                    "parameter {name} = {s} is out of range {lo}..={hi}"
                ));
            }
            Ok(Value::Float(v))
        }
    }
}

fn parse(spec: &str) -> Result<(Gen, Values), LoadError> {
    let (name, args) = match spec.split_once(':') {
        Some((n, a)) => (n, a),
        None => (spec, ""),
    };
    let names: Vec<&str> = table().iter().map(|g| g.info.name).collect();
    let g = table()
        .into_iter()
        .find(|g| g.info.name == name)
        .ok_or_else(|| {
            spec_err(
                spec,
                format!(
                    "unknown generator {name:?}; valid generators: {}",
                    names.join(", ")
                ),
            )
        })?;
    let params: Vec<Param> = g
        .info
        .params
        .iter()
        .zip(g.ranges)
        .map(|(&(name, default, _), &range)| Param {
            name,
            default,
            range,
        })
        .collect();
    let valid = || params.iter().map(|p| p.name).collect::<Vec<_>>().join(", ");
    let mut given: BTreeMap<&'static str, Value> = BTreeMap::new();
    for kv in args.split(',').filter(|s| !s.trim().is_empty()) {
        let (k, v) = kv.split_once('=').ok_or_else(|| {
            spec_err(
                spec,
                format!(
                    "expected key=value, got {kv:?} (parameters of {name}: {})",
                    valid()
                ),
            )
        })?;
        let (k, v) = (k.trim(), v.trim());
        let p = params.iter().find(|p| p.name == k).ok_or_else(|| {
            spec_err(
                spec,
                format!(
                    "unknown parameter {k:?} for generator {name}; valid parameters: {}",
                    valid()
                ),
            )
        })?;
        let val = parse_value(k, v, p.range).map_err(|r| spec_err(spec, r))?;
        if given.insert(p.name, val).is_some() {
            return Err(spec_err(spec, format!("parameter {k} given twice")));
        }
    }
    for p in &params {
        if !given.contains_key(p.name) {
            let v = parse_value(p.name, p.default, p.range)
                .map_err(|r| spec_err(spec, format!("internal: bad default: {r}")))?;
            given.insert(p.name, v);
        }
    }
    Ok((g, Values(given)))
}

use crate::rng::SplitMix64 as Rng;

fn point(rng: &mut Rng) -> DVec3 {
    DVec3::new(rng.f64(), rng.f64(), rng.f64())
}

fn tri(a: DVec3, b: DVec3, c: DVec3) -> Triangle {
    Triangle::new(a.as_vec3(), b.as_vec3(), c.as_vec3())
}

/// Grid resolution k with `per * k^2` close to n (at least 1).
fn grid_k(n: u64, per: u64) -> u64 {
    (((n as f64) / per as f64).sqrt().round() as u64).max(1)
}

/// Sphere from a cube whose faces carry a k x k grid, each vertex pushed onto the sphere.
/// Vertices are mapped to 3D before normalising (x*x + y*y + z*z in fixed order), so the
/// seams between cube faces produce bit-identical shared vertices.
fn sphere(n: u64, center: DVec3, radius: f64) -> Vec<Triangle> {
    let k = grid_k(n, 12);
    let mut out = Vec::with_capacity((12 * k * k) as usize);
    let on_sphere = |p: DVec3| {
        let len = (p.x * p.x + p.y * p.y + p.z * p.z).sqrt();
        center + p * (radius / len)
    };
    // Each face: normal axis, and two tangent axes chosen so triangles wind outward.
    let faces = [
        (DVec3::X, DVec3::Y, DVec3::Z),
        (DVec3::NEG_X, DVec3::Z, DVec3::Y),
        (DVec3::Y, DVec3::Z, DVec3::X),
        (DVec3::NEG_Y, DVec3::X, DVec3::Z),
        (DVec3::Z, DVec3::X, DVec3::Y),
        (DVec3::NEG_Z, DVec3::Y, DVec3::X),
    ];
    let coord = |i: u64| -1.0 + 2.0 * i as f64 / k as f64;
    for (nrm, t, b) in faces {
        let p = |i: u64, j: u64| on_sphere(nrm + t * coord(i) + b * coord(j));
        for i in 0..k {
            for j in 0..k {
                let (p00, p10, p01, p11) = (p(i, j), p(i + 1, j), p(i, j + 1), p(i + 1, j + 1));
                out.push(tri(p00, p10, p11));
                out.push(tri(p00, p11, p01));
            }
        }
    }
    out
}

/// Flat heightfield over [0,1]^2 in x/z: value noise (bilinear lattice octaves) of amplitude h.
fn terrain(n: u64, h: f64, seed: u64) -> Vec<Triangle> {
    let k = grid_k(n, 2);
    let mut rng = Rng::new(seed);
    // Three octaves of lattice noise: 4, 16 and 64 cells, weights 1, 1/4, 1/16.
    let octaves: Vec<(usize, f64, Vec<f64>)> = [(4usize, 1.0), (16, 0.25), (64, 0.0625)]
        .into_iter()
        .map(|(c, w)| {
            (
                c,
                w,
                (0..(c + 1) * (c + 1))
                    .map(|_| rng.range(-1.0, 1.0))
                    .collect(),
            )
        })
        .collect();
    let norm = h / (1.0 + 0.25 + 0.0625);
    let height = |x: f64, z: f64| {
        let mut y = 0.0;
        for (c, w, lat) in &octaves {
            let (fx, fz) = (x * *c as f64, z * *c as f64);
            let (ix, iz) = ((fx as usize).min(c - 1), (fz as usize).min(c - 1));
            let (tx, tz) = (fx - ix as f64, fz - iz as f64);
            let at = |a: usize, b: usize| lat[a * (c + 1) + b];
            let top = at(ix, iz) * (1.0 - tx) + at(ix + 1, iz) * tx;
            let bot = at(ix, iz + 1) * (1.0 - tx) + at(ix + 1, iz + 1) * tx;
            y += w * (top * (1.0 - tz) + bot * tz);
        }
        y * norm
    };
    let kk = k as usize;
    let s = 1.0 / k as f64;
    let mut grid = Vec::with_capacity((kk + 1) * (kk + 1));
    for i in 0..=kk {
        for j in 0..=kk {
            let (x, z) = (i as f64 * s, j as f64 * s);
            grid.push(DVec3::new(x, height(x, z), z));
        }
    }
    let g = |i: usize, j: usize| grid[i * (kk + 1) + j];
    let mut out = Vec::with_capacity(2 * kk * kk);
    for i in 0..kk {
        for j in 0..kk {
            out.push(tri(g(i, j), g(i, j + 1), g(i + 1, j + 1)));
            out.push(tri(g(i, j), g(i + 1, j + 1), g(i + 1, j)));
        }
    }
    out
}

/// Long thin triangles: a random segment through the unit cube, widened by `width` along a
/// random direction at the first end.
fn hairball(n: u64, width: f64, seed: u64) -> Vec<Triangle> {
    let mut rng = Rng::new(seed);
    (0..n)
        .map(|_| {
            let a = point(&mut rng);
            let b = point(&mut rng);
            let d = point(&mut rng) - DVec3::splat(0.5);
            let len = (d.x * d.x + d.y * d.y + d.z * d.z).sqrt().max(1e-12);
            let c = (a + d * (width / len)).clamp(DVec3::ZERO, DVec3::ONE);
            tri(a, b, c)
        })
        .collect()
}

/// Fisher-Yates permutation of the triangle order with seed `seed` (0: unchanged).
fn shuffled(mut tris: Vec<Triangle>, seed: u64) -> Vec<Triangle> {
    if seed != 0 {
        let mut rng = Rng::new(seed);
        for i in (1..tris.len()).rev() {
            let j = rng.below(i as u64 + 1) as usize;
            tris.swap(i, j);
        }
    }
    tris
}

/// A blocks x blocks grid of box buildings (unit cells, footprints 30-90 % of a cell, heights
/// 0.5-4 cells) centred on a ground quad `ground` times the city's side (y up, ground at y=0).
fn city(blocks: u64, ground: f64, seed: u64) -> Vec<Triangle> {
    let mut rng = Rng::new(seed);
    let b = blocks as f64;
    let mut out = Vec::with_capacity((12 * blocks * blocks + 2) as usize);
    let half = 0.5 * b * ground;
    let c = 0.5 * b;
    let q = |x: f64, z: f64| DVec3::new(c + x, 0.0, c + z);
    out.push(tri(q(-half, -half), q(-half, half), q(half, half)));
    out.push(tri(q(-half, -half), q(half, half), q(half, -half)));
    for i in 0..blocks {
        for j in 0..blocks {
            let (sx, sz) = (rng.range(0.3, 0.9), rng.range(0.3, 0.9));
            let (ox, oz) = (rng.range(0.0, 1.0 - sx), rng.range(0.0, 1.0 - sz));
            let hgt = rng.range(0.5, 4.0);
            let lo = DVec3::new(i as f64 + ox, 0.0, j as f64 + oz);
            let hi = lo + DVec3::new(sx, hgt, sz);
            push_box(&mut out, lo, hi);
        }
    }
    out
}

/// The 12 triangles of an axis-aligned box.
fn push_box(out: &mut Vec<Triangle>, lo: DVec3, hi: DVec3) {
    let v = |i: usize| {
        DVec3::new(
            if i & 1 == 0 { lo.x } else { hi.x },
            if i & 2 == 0 { lo.y } else { hi.y },
            if i & 4 == 0 { lo.z } else { hi.z },
        )
    };
    // Quads as corner index lists (bit 0 = x, bit 1 = y, bit 2 = z), wound outward.
    const QUADS: [[usize; 4]; 6] = [
        [0, 4, 6, 2],
        [1, 3, 7, 5],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 2, 3, 1],
        [4, 5, 7, 6],
    ];
    for [a, b, c, d] in QUADS {
        out.push(tri(v(a), v(b), v(c)));
        out.push(tri(v(a), v(c), v(d)));
    }
}

/// Unit sphere (diameter 2 = the object size) plus one triangle with edges of 1/1000 object
/// size, its first vertex 2^e object sizes from the sphere centre along (1,1,1)/sqrt(3)
/// (Riemersma 2024: a distant primitive squeezes the rest of the scene into few Morton cells).
/// At large e the tiny triangle collapses to zero area in f32; it stays finite and is kept.
fn outlier(n: u64, e: u64) -> Vec<Triangle> {
    let mut out = sphere(n, DVec3::ZERO, 1.0);
    let size = 2.0;
    let dist = size * 2f64.powi(e as i32);
    let dir = DVec3::ONE / 3f64.sqrt();
    let p = dir * dist;
    let t = size * 1e-3;
    out.push(tri(
        p,
        p + DVec3::new(t, 0.0, 0.0),
        p + DVec3::new(0.0, t, 0.0),
    ));
    out
}

/// Cycles through six kinds so every prefix has all of them: ordinary small triangles,
/// exactly collinear ones, single points, exact duplicates of an earlier triangle, triangles
/// whose boxes share one centre exactly (dyadic coordinates, so no rounding), and
/// axis-aligned flat ones (a zero box extent; nonzero area).
fn degenerate(n: u64, seed: u64) -> Vec<Triangle> {
    let mut rng = Rng::new(seed);
    let mut out: Vec<Triangle> = Vec::with_capacity(n as usize);
    // Shared centre on a 1/64 lattice; offsets on a 1/1024 lattice: sums are exact in f32.
    let dyadic = |rng: &mut Rng, den: u64, max: u64| rng.below(max + 1) as f64 / den as f64;
    let centre = DVec3::new(
        dyadic(&mut rng, 64, 63),
        dyadic(&mut rng, 64, 63),
        dyadic(&mut rng, 64, 63),
    );
    for i in 0..n {
        let a = point(&mut rng);
        let s = rng.range(0.001, 0.05);
        let t = match i % 6 {
            0 => tri(a, a + point(&mut rng) * s, a + point(&mut rng) * s),
            1 => {
                let d = DVec3::new(s, 0.0, 0.0);
                tri(a, a + d, a + d * 2.0)
            }
            2 => tri(a, a, a),
            3 if !out.is_empty() => out[rng.below(out.len() as u64) as usize],
            3 => tri(a, a, a),
            4 => {
                let r = DVec3::new(
                    dyadic(&mut rng, 1024, 32),
                    dyadic(&mut rng, 1024, 32),
                    dyadic(&mut rng, 1024, 32),
                );
                let w = DVec3::new(r.x, -r.y, 0.0) * 0.5;
                tri(centre + r, centre - r, centre + w)
            }
            _ => {
                let b = a + DVec3::new(s, rng.f64() * s, 0.0);
                let c = a + DVec3::new(rng.f64() * s, s, 0.0);
                tri(a, b, c)
            }
        };
        out.push(t);
    }
    out
}

/// A random triangle with vertices in [0, 1)^3 within `size` of its first vertex.
fn small_tri(rng: &mut Rng, size: f64) -> (DVec3, DVec3, DVec3) {
    let a = point(rng);
    let b = a + (point(rng) - DVec3::splat(0.5)) * size;
    let c = a + (point(rng) - DVec3::splat(0.5)) * size;
    (a, b, c)
}

/// `n` small triangles in the unit cube, then `huge` triangles in the planes x = 1 + k/1000,
/// spanning [-size, size] in y and z (a half-space-sized sheet at the edge of the content).
fn huge_edge(n: u64, huge: u64, size: f64, seed: u64) -> Vec<Triangle> {
    let mut rng = Rng::new(seed);
    let mut out: Vec<Triangle> = (0..n)
        .map(|_| {
            let (a, b, c) = small_tri(&mut rng, 0.02);
            tri(a, b, c)
        })
        .collect();
    for k in 0..huge {
        let x = 1.0 + k as f64 / 1000.0;
        let s = size * (1.0 + rng.f64());
        out.push(tri(
            DVec3::new(x, -s, -s),
            DVec3::new(x, s, -s),
            DVec3::new(x, -s, s),
        ));
    }
    out
}

/// Random small triangles in the plane z = 0.5 (exact in f32).
fn flat(n: u64, seed: u64) -> Vec<Triangle> {
    let mut rng = Rng::new(seed);
    (0..n)
        .map(|_| {
            let (a, b, c) = small_tri(&mut rng, 0.05);
            let z = |p: DVec3| DVec3::new(p.x, p.y, 0.5);
            tri(z(a), z(b), z(c))
        })
        .collect()
}

/// Long thin triangles from near x = 0 to near x = 1 inside a narrow y/z band, so every box
/// overlaps every other; the third vertex is `width` off the second (0 for every 8th: collinear).
fn slivers(n: u64, width: f64, seed: u64) -> Vec<Triangle> {
    let mut rng = Rng::new(seed);
    (0..n)
        .map(|i| {
            let band = |rng: &mut Rng| 0.45 + 0.1 * rng.f64();
            let a = DVec3::new(0.05 * rng.f64(), band(&mut rng), band(&mut rng));
            let b = DVec3::new(1.0 - 0.05 * rng.f64(), band(&mut rng), band(&mut rng));
            let (b, c) = if i % 8 == 7 {
                // Axis-aligned, so still exactly collinear after rounding to f32.
                (DVec3::new(b.x, a.y, a.z), DVec3::new(0.5, a.y, a.z))
            } else {
                let d = point(&mut rng) - DVec3::splat(0.5);
                let len = (d.x * d.x + d.y * d.y + d.z * d.z).sqrt().max(1e-12);
                (b, b + d * (width / len))
            };
            tri(a, b, c)
        })
        .collect()
}

/// `ceil(n / copies)` distinct triangles (every third zero-area), triangle i = distinct[i mod m],
/// so the copies are spread through the input, not adjacent.
fn dups(n: u64, copies: u64, seed: u64) -> Vec<Triangle> {
    let mut rng = Rng::new(seed);
    let m = n.div_ceil(copies.max(1)).max(1);
    let distinct: Vec<Triangle> = (0..m)
        .map(|i| {
            let (a, b, c) = small_tri(&mut rng, 0.05);
            match i % 9 {
                0 => tri(a, a, a),
                // Axis-aligned, so exactly collinear after rounding to f32.
                3 => tri(
                    a,
                    DVec3::new(b.x, a.y, a.z),
                    DVec3::new(0.5 * (a.x + b.x), a.y, a.z),
                ),
                6 => tri(a, b, b),
                _ => tri(a, b, c),
            }
        })
        .collect();
    (0..n).map(|i| distinct[(i % m) as usize]).collect()
}

/// Boxes sharing the centre (0.5, 0.5, 0.5) exactly: vertices c + r, c - r and c + w with
/// |w| <= |r| per axis on a dyadic lattice, sizes from 2^-20 to 1/2 (all exact in f32).
fn same_centroid(n: u64, seed: u64) -> Vec<Triangle> {
    let mut rng = Rng::new(seed);
    let c = DVec3::splat(0.5);
    (0..n)
        .map(|_| {
            let scale = 2f64.powi(-(rng.below(20) as i32) - 1);
            let q = |rng: &mut Rng| (rng.below(2049) as f64 - 1024.0) / 1024.0;
            let r = DVec3::new(q(&mut rng), q(&mut rng), q(&mut rng)) * scale;
            let f = |rng: &mut Rng| (rng.below(5) as f64 - 2.0) / 2.0; // -1, -1/2, 0, 1/2, 1
            let w = DVec3::new(r.x * f(&mut rng), r.y * f(&mut rng), r.z * f(&mut rng));
            tri(c + r, c - r, c + w)
        })
        .collect()
}

/// Random small triangles in the unit cube moved by `t`, every coordinate times `s` (in f64,
/// rounded once; coordinates beyond f32::MAX become infinite and are dropped by the scene).
fn scale(n: u64, s: f64, t: f64, seed: u64) -> Vec<Triangle> {
    let mut rng = Rng::new(seed);
    let o = DVec3::splat(t);
    (0..n)
        .map(|_| {
            let (a, b, c) = small_tri(&mut rng, 0.05);
            tri((a + o) * s, (b + o) * s, (c + o) * s)
        })
        .collect()
}

/// Random small triangles; `bad` of them, at indices floor(k n / bad), get one coordinate
/// replaced by NaN, +inf, -inf or 1e39 (finite in f64, infinite once rounded to f32), in turn.
fn nonfinite(n: u64, bad: u64, seed: u64) -> Vec<Triangle> {
    let mut rng = Rng::new(seed);
    let bad = bad.min(n);
    let mut next_bad = 0u64; // index k of the next bad triangle
    (0..n)
        .map(|i| {
            let (a, b, c) = small_tri(&mut rng, 0.05);
            let mut t = tri(a, b, c);
            if next_bad < bad && i == (next_bad as u128 * n as u128 / bad as u128) as u64 {
                let v = [f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 1e39][(next_bad % 4) as usize];
                let (vi, axis) = ((next_bad / 4 % 3) as usize, (next_bad / 12 % 3) as usize);
                t.v[vi][axis] = v as f32;
                next_bad += 1;
            }
            t
        })
        .collect()
}

fn single(seed: u64) -> Vec<Triangle> {
    if seed == 0 {
        return vec![tri(DVec3::ZERO, DVec3::X, DVec3::Y)];
    }
    let mut rng = Rng::new(seed);
    vec![tri(point(&mut rng), point(&mut rng), point(&mut rng))]
}

/// Step i: the tread triangle (x_i, y, 0) (x_i+1, y, 0) (x_i, y, 1) with x_i = y = i/n, in input
/// order along the stair (an incremental builder inserting in this order grows a chain).
fn staircase(n: u64) -> Vec<Triangle> {
    let s = 1.0 / n as f64;
    (0..n)
        .map(|i| {
            let (x, y) = (i as f64 * s, i as f64 * s);
            tri(
                DVec3::new(x, y, 0.0),
                DVec3::new(x + s, y, 0.0),
                DVec3::new(x, y, 1.0),
            )
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    #[test]
    fn dyadic_centres_are_exact() {
        let s = degenerate(600, 3);
        let centres: Vec<Vec3> = s
            .iter()
            .skip(4)
            .step_by(6)
            .map(|t| t.bounds().center())
            .collect();
        assert!(centres.len() >= 99);
        assert!(centres.iter().all(|c| *c == centres[0]));
    }
}
