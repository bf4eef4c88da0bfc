//! Kilian 4.1: the basic octree. The world box (bounds of all triangles) is split at its centre
//! into 8 octants, index `b_z b_y b_x` (4.1.3), recursively until a node becomes a leaf (4.1.2).
//! Only the world box, the topology (`nodes_list`, one u32 per node) and the leaf arrays
//! (`sizes_list`, `primitives_list`) are stored: every other box is implicit and recomputed by
//! [`child_box`], the one function construction and traversal share, so both see bit-identical
//! boxes. A triangle goes into every octant whose closed box it touches (plus a small margin, see
//! [`Octree::margin`]), so references may repeat; that is what makes the exact closest hit
//! possible: the hit point lies in some leaf box, and that leaf references the triangle.
//!
//! Decisions where Kilian is inconsistent or silent (docs/decisions.md, "Kilian 2021: inconsistencies"):
//! - leaf iff `n < prim_threshold` (Alg. 1 and the text of 4.1.2; 4.1.4 says "<="), or
//!   `num_dupl > mult_threshold * n` (Alg. 1; the text's "interior iff num_dupl < mult * n" differs
//!   only at equality; Alg. 1 makes `mult_threshold = 1` mean "split only without duplication"),
//!   or the node is empty, at `max_depth`, has a box no axis of which can be split in f32, or every
//!   child would get every primitive;
//! - an axis whose centre rounds onto the box's min or max (zero or 1-ulp extent) is *collapsed*:
//!   primitives go only to the child that spans the whole extent on that axis (the other child's
//!   box is a face of it), so a flat scene does not duplicate every primitive at every level;
//! - triangle/octant overlap: separating-axis test (Akenine-Möller 2001) in f64 against the octant
//!   box grown by `margin` on every side: conservative for the exact triangle and for the f32
//!   ray-triangle test's near-edge hits, far tighter than the triangle's bounding box on long
//!   diagonal triangles;
//! - traversal: children ordered by their slab entry (the AGL89 entry child and plane crossings
//!   give the same order; the slab values of the 8 children share 9 plane distances), explicit
//!   stack of (node, box, entry); popped nodes entered beyond `best.t * SLAB_ROBUST` are culled,
//!   which replaces Kilian's "hit inside the leaf: stop" test and stays exact when the hit lies
//!   outside the leaf that found it.
use crate::{LayoutSpec, Memory};
use bvhlab_bvh::CostParams;
use bvhlab_geom::{Aabb, Triangle, Vec3};
use bvhlab_params::{Kind, Method, ParamSpec};
use bvhlab_trace::{
    accept, intersect_triangle, trace_with, Hit, Ray, RayBox, TraceStats, SLAB_ROBUST,
};
use glam::DVec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

pub const METHOD: Method = Method::new(
    "octree",
    "Kilian 4.1 basic octree, 32-bit nodes, built from the triangles (ignores the BVH; references may repeat)",
    "Kilian 2021 4.1",
    &PARAMS,
);

/// The construction parameters ([`Config`]), shared with the 1-bit octree.
pub const PARAMS: [ParamSpec; 4] = [
    ParamSpec {
        name: "max_depth",
        default: "24",
        kind: Kind::UInt { min: 0, max: MAX_DEPTH_LIMIT },
        about: "a node at this depth becomes a leaf",
        in_label: false,
    },
    ParamSpec {
        name: "mult_threshold",
        default: "2.0",
        kind: Kind::FloatAtLeast(1.0),
        about: "a node becomes a leaf when its children would hold more than this many times its references (Kilian alg. 1)",
        in_label: false,
    },
    ParamSpec {
        name: "overlap",
        default: "sat",
        kind: Kind::Choice(&["sat", "aabb"]),
        about: "triangle/octant test: separating axes (exact) or the triangle's box, both with a margin",
        in_label: false,
    },
    ParamSpec {
        name: "prim_threshold",
        default: "20",
        kind: Kind::UInt { min: 0, max: u32::MAX },
        about: "a node with fewer references becomes a leaf (Kilian 4.1.2)",
        in_label: false,
    },
];

/// Deepest `max_depth` accepted (f32 boxes collapse long before: 2^-40 of the world box).
pub const MAX_DEPTH_LIMIT: u32 = 40;

/// Margin of the overlap test relative to the scene's coordinate scale (2^-19: 32 f32 ulps of the
/// largest coordinate), far above the f64 rounding of the test and the f32 ray-triangle test's
/// near-edge error, far below any octant that geometry can still separate.
pub const MARGIN_REL: f64 = 1.0 / 524288.0;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Config {
    pub prim_threshold: u32,
    pub mult_threshold: f64,
    pub max_depth: u32,
    /// Triangle/octant test: exact separating axes (`sat`, default) or the triangle's bounding
    /// box (`aabb`, the simple conservative test; more references), both with the margin.
    pub overlap: Overlap,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Overlap {
    Sat,
    Aabb,
}

/// Parses the `overlap` parameter.
pub fn parse_overlap(spec: &LayoutSpec) -> Result<Overlap, String> {
    match spec.get::<String>("overlap")?.as_str() {
        "sat" => Ok(Overlap::Sat),
        "aabb" => Ok(Overlap::Aabb),
        o => Err(format!(
            "layout `{}`: overlap must be `sat` or `aabb` (got `{o}`)",
            spec.name
        )),
    }
}

impl Default for Config {
    fn default() -> Self {
        Config {
            prim_threshold: 20,
            mult_threshold: 2.0,
            max_depth: 24,
            overlap: Overlap::Sat,
        }
    }
}

impl Config {
    pub fn from_spec(spec: &LayoutSpec) -> Result<Config, String> {
        let cfg = Config {
            prim_threshold: spec.get("prim_threshold")?,
            mult_threshold: spec.get("mult_threshold")?,
            max_depth: spec.get("max_depth")?,
            overlap: parse_overlap(spec)?,
        };
        cfg.check(&spec.name)?;
        Ok(cfg)
    }

    pub fn check(&self, name: &str) -> Result<(), String> {
        if !(self.mult_threshold.is_finite() && self.mult_threshold >= 1.0) {
            return Err(format!(
                "layout `{name}`: mult_threshold must be a finite number >= 1 (got {})",
                self.mult_threshold
            ));
        }
        if self.max_depth > MAX_DEPTH_LIMIT {
            return Err(format!(
                "layout `{name}`: max_depth must be at most {MAX_DEPTH_LIMIT} (got {})",
                self.max_depth
            ));
        }
        Ok(())
    }
}

/// The centre of a box, clamped into it (min/2 + max/2 cannot overflow at +-f32::MAX; the clamp
/// keeps a subnormal rounding inside). Shared by construction, traversal, validation.
#[inline(always)]
pub fn centre(b: &Aabb) -> Vec3 {
    (b.min * 0.5 + b.max * 0.5).max(b.min).min(b.max)
}

/// Box of octant `k` (bits `b_z b_y b_x`, Kilian 4.1.3) of `b` split at `c = centre(b)`. Siblings
/// share the centre planes exactly, so the 8 boxes cover `b`.
#[inline(always)]
pub fn child_box(b: &Aabb, c: Vec3, k: usize) -> Aabb {
    let pick = |bit: usize, lo: f32, mid: f32, hi: f32| {
        if k >> bit & 1 == 1 {
            (mid, hi)
        } else {
            (lo, mid)
        }
    };
    let (x0, x1) = pick(0, b.min.x, c.x, b.max.x);
    let (y0, y1) = pick(1, b.min.y, c.y, b.max.y);
    let (z0, z1) = pick(2, b.min.z, c.z, b.max.z);
    Aabb::new(Vec3::new(x0, y0, z0), Vec3::new(x1, y1, z1))
}

/// Conservative overlap of a triangle and the closed box `[lo, hi]` (already grown by the margin):
/// the 13 separating axes of Akenine-Möller 2001, in f64 (f32 inputs are exact in f64; products of
/// coordinates up to 1e38 stay finite).
pub fn tri_box_overlap(v: &[DVec3; 3], lo: DVec3, hi: DVec3) -> bool {
    let c = (lo + hi) * 0.5;
    let h = (hi - lo) * 0.5;
    let p = [v[0] - c, v[1] - c, v[2] - c];
    // Box normals = the bounding boxes overlap.
    let mn = p[0].min(p[1]).min(p[2]);
    let mx = p[0].max(p[1]).max(p[2]);
    if mn.x > h.x || mn.y > h.y || mn.z > h.z || mx.x < -h.x || mx.y < -h.y || mx.z < -h.z {
        return false;
    }
    let e = [p[1] - p[0], p[2] - p[1], p[0] - p[2]];
    let axes = [DVec3::X, DVec3::Y, DVec3::Z];
    for ed in &e {
        for ax in &axes {
            let a = ax.cross(*ed);
            let (d0, d1, d2) = (a.dot(p[0]), a.dot(p[1]), a.dot(p[2]));
            let r = h.dot(a.abs());
            if d0.min(d1).min(d2) > r || d0.max(d1).max(d2) < -r {
                return false;
            }
        }
    }
    let n = e[0].cross(e[1]);
    let r = h.dot(n.abs());
    n.dot(p[0]).abs() <= r || !n.dot(p[0]).is_finite()
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Octree {
    /// Bounds of all triangles (the empty box for an empty scene).
    pub world: Aabb,
    /// Overlap margin (absolute, world units): `MARGIN_REL` times the largest coordinate magnitude
    /// or extent of the world box. A triangle is referenced by every leaf whose box grown by it the
    /// triangle touches.
    pub margin: f64,
    /// Kilian's `nodes_list`: bit 0 = interior, bits 1..32 = first of 8 consecutive children
    /// (interior) or first reference in `prims` (leaf). Breadth-first order, root at 0.
    pub nodes: Vec<u32>,
    /// Kilian's `sizes_list`: references per node (0 for interior nodes).
    pub sizes: Vec<u32>,
    /// Kilian's `primitives_list`: triangle indices, leaves in node order (references repeat).
    pub prims: Vec<u32>,
    pub config: Config,
}

struct Pending {
    node: u32,
    bounds: Aabb,
    depth: u32,
    start: usize,
    end: usize,
}

/// Children's references of a split node: 8 lists concatenated, `counts[k]` each.
struct Split {
    refs: Vec<u32>,
    counts: [u32; 8],
}

fn dv(v: Vec3) -> DVec3 {
    DVec3::new(v.x as f64, v.y as f64, v.z as f64)
}

/// Margin for a world box (see `Octree::margin`).
pub fn margin_for(world: &Aabb) -> f64 {
    if world.is_empty() {
        return 0.0;
    }
    let m = dv(world.min)
        .abs()
        .max(dv(world.max).abs())
        .max(dv(world.max) - dv(world.min));
    m.max_element() * MARGIN_REL
}

/// Kilian Alg. 1 plus the termination rules of the module doc: `None` = leaf.
fn split_node(
    p: &Pending,
    refs: &[u32],
    tris: &[Triangle],
    tb: &[Aabb],
    margin: f64,
    cfg: &Config,
) -> Option<Split> {
    let n = refs.len();
    if n == 0 || n < cfg.prim_threshold as usize || p.depth >= cfg.max_depth {
        return None;
    }
    let b = &p.bounds;
    let c = centre(b);
    // Per axis: which sides may receive primitives (collapsed axes: only the full side).
    let mut allow = [[true; 2]; 3];
    let mut splittable = false;
    for a in 0..3 {
        if c[a] >= b.max[a] {
            allow[a] = [true, false];
        } else if c[a] <= b.min[a] {
            allow[a] = [false, true];
        } else {
            splittable = true;
        }
    }
    if !splittable {
        return None;
    }
    let boxes: [(DVec3, DVec3); 8] = std::array::from_fn(|k| {
        let cb = child_box(b, c, k);
        (dv(cb.min) - margin, dv(cb.max) + margin)
    });
    let cd = dv(c);
    let mut lists: [Vec<u32>; 8] = Default::default();
    for &t in refs {
        let bb = &tb[t as usize];
        let (lo, hi) = (dv(bb.min), dv(bb.max));
        let mut side = [[false; 2]; 3];
        for a in 0..3 {
            side[a][0] = allow[a][0] && lo[a] <= cd[a] + margin;
            side[a][1] = allow[a][1] && hi[a] >= cd[a] - margin;
        }
        let mut cand = [0usize; 8];
        let mut nc = 0;
        for k in 0..8 {
            if side[0][k & 1] && side[1][k >> 1 & 1] && side[2][k >> 2 & 1] {
                cand[nc] = k;
                nc += 1;
            }
        }
        let cand = &cand[..nc];
        if cand.len() == 1 || cfg.overlap == Overlap::Aabb {
            // Aabb: the side flags are exactly "bounds overlap the grown child box" (the bounds
            // already overlap the grown parent).
            for &k in cand {
                lists[k].push(t);
            }
            continue;
        }
        if cand.len() == 1 {
            // The triangle touches the parent and lies on one side of every centre plane (within
            // the margin): it touches that child. No separating-axis test needed.
            lists[cand[0]].push(t);
            continue;
        }
        let v = tris[t as usize].v.map(dv);
        let mut any = false;
        for &k in cand {
            if tri_box_overlap(&v, boxes[k].0, boxes[k].1) {
                lists[k].push(t);
                any = true;
            }
        }
        if !any {
            // Touches the parent only within rounding of the margin: keep it conservatively in
            // every candidate (never drop a reference).
            for &k in cand {
                lists[k].push(t);
            }
        }
    }
    let dupl: usize = lists.iter().map(|l| l.len()).sum();
    // Useless split: every child that may receive primitives would get all of them.
    let useless = (0..8).all(|k| {
        let ok = allow[0][k & 1] && allow[1][k >> 1 & 1] && allow[2][k >> 2 & 1];
        !ok || lists[k].len() == n
    });
    if useless || dupl as f64 > cfg.mult_threshold * n as f64 {
        return None;
    }
    let mut counts = [0u32; 8];
    let mut out = Vec::with_capacity(dupl);
    for (k, l) in lists.iter().enumerate() {
        counts[k] = l.len() as u32;
        out.extend_from_slice(l);
    }
    Some(Split { refs: out, counts })
}

/// Largest offset that fits the 31 offset bits of a node.
const MAX_OFFSET: usize = (1 << 31) - 1;

impl Octree {
    /// Builds level by level (breadth-first, no recursion), so `nodes` is in breadth-first order
    /// with the 8 children of each interior node consecutive, and leaves' references are in node
    /// order. Nodes of a level are decided in parallel and appended in order (deterministic).
    pub fn build(tris: &[Triangle], cfg: &Config) -> Result<Octree, String> {
        Self::build_until(tris, cfg, None)
    }

    /// `build`, given up (an error starting with [`crate::DEADLINE_REACHED`]) when a level ends
    /// after `deadline`: on some scenes (a huge ground plane under a small dense city) the levels
    /// multiply references for minutes, and a time-bounded caller (`layout=auto`) must not wait.
    pub fn build_until(
        tris: &[Triangle],
        cfg: &Config,
        deadline: Option<std::time::Instant>,
    ) -> Result<Octree, String> {
        cfg.check("octree")?;
        if let Some(i) = tris.iter().position(|t| !t.is_finite()) {
            return Err(format!("octree: triangle {i} has non-finite coordinates"));
        }
        if tris.len() > MAX_OFFSET {
            return Err(format!("octree: {} triangles exceed 2^31 - 1", tris.len()));
        }
        let tb: Vec<Aabb> = tris.iter().map(|t| t.bounds()).collect();
        let mut world = Aabb::EMPTY;
        for b in &tb {
            world.grow(b);
        }
        let margin = margin_for(&world);
        let mut nodes = vec![0u32];
        let mut sizes = vec![0u32];
        let mut prims: Vec<u32> = Vec::new();
        let mut buf: Vec<u32> = (0..tris.len() as u32).collect();
        let mut level = vec![Pending {
            node: 0,
            bounds: world,
            depth: 0,
            start: 0,
            end: buf.len(),
        }];
        let mut depth = 0;
        while !level.is_empty() {
            if deadline.is_some_and(|d| std::time::Instant::now() >= d) {
                return Err(format!(
                    "{}: octree build stopped after {depth} levels ({} nodes, {} references so far)",
                    crate::DEADLINE_REACHED,
                    nodes.len(),
                    prims.len() + buf.len()
                ));
            }
            depth += 1;
            let splits: Vec<Option<Split>> = level
                .par_iter()
                .with_min_len(64)
                .map(|p| split_node(p, &buf[p.start..p.end], tris, &tb, margin, cfg))
                .collect();
            let mut next = Vec::new();
            let mut nbuf = Vec::new();
            for (p, s) in level.iter().zip(splits) {
                match s {
                    None => {
                        if prims.len() > MAX_OFFSET {
                            return Err("octree: more than 2^31 - 1 primitive references".into());
                        }
                        nodes[p.node as usize] = (prims.len() as u32) << 1;
                        sizes[p.node as usize] = (p.end - p.start) as u32;
                        prims.extend_from_slice(&buf[p.start..p.end]);
                    }
                    Some(s) => {
                        let base = nodes.len();
                        if base + 8 > MAX_OFFSET {
                            return Err("octree: more than 2^31 - 1 nodes".into());
                        }
                        nodes[p.node as usize] = (base as u32) << 1 | 1;
                        nodes.extend_from_slice(&[0; 8]);
                        sizes.extend_from_slice(&[0; 8]);
                        let c = centre(&p.bounds);
                        let mut at = 0usize;
                        for k in 0..8 {
                            let cnt = s.counts[k] as usize;
                            let start = nbuf.len();
                            nbuf.extend_from_slice(&s.refs[at..at + cnt]);
                            at += cnt;
                            next.push(Pending {
                                node: (base + k) as u32,
                                bounds: child_box(&p.bounds, c, k),
                                depth: p.depth + 1,
                                start,
                                end: nbuf.len(),
                            });
                        }
                    }
                }
            }
            if prims.len() > MAX_OFFSET || nbuf.len() > MAX_OFFSET {
                return Err("octree: more than 2^31 - 1 primitive references".into());
            }
            level = next;
            buf = nbuf;
        }
        Ok(Octree {
            world,
            margin,
            nodes,
            sizes,
            prims,
            config: cfg.clone(),
        })
    }

    pub fn leaves(&self) -> usize {
        self.nodes.iter().filter(|&&n| n & 1 == 0).count()
    }

    /// Topology = `nodes_list` (Kilian 6.2); total adds `sizes_list`, `primitives_list` and the
    /// 24-byte world box.
    pub fn memory(&self) -> Memory {
        let topology = 4 * self.nodes.len() as u64;
        Memory {
            topology_bytes: topology,
            total_bytes: topology + 4 * self.sizes.len() as u64 + 4 * self.prims.len() as u64 + 24,
            nodes: self.nodes.len() as u64,
            chunks: 0,
            chunk_fill: 0.0,
            prim_refs: self.prims.len() as u64,
        }
    }

    pub fn trace(&self, tris: &[Triangle], rays: &[Ray]) -> TraceStats {
        trace_topo(self, &self.world, tris, rays)
    }

    pub fn sah_cost(&self, cost: CostParams) -> f64 {
        sah_topo(self, &self.world, cost)
    }

    pub fn validate(&self, tris: &[Triangle]) -> Result<(), String> {
        if self.nodes.len() != self.sizes.len() {
            return Err("octree: nodes_list and sizes_list lengths differ".into());
        }
        let mut seen = vec![false; self.nodes.len()];
        let mut stack = vec![0u32];
        while let Some(n) = stack.pop() {
            let s = seen
                .get_mut(n as usize)
                .ok_or_else(|| format!("octree: node {n} out of range"))?;
            if *s {
                return Err(format!("octree: node {n} reached twice"));
            }
            *s = true;
            let v = self.nodes[n as usize];
            if v & 1 == 1 {
                let b = (v >> 1) as usize;
                if b + 8 > self.nodes.len() || b <= n as usize {
                    return Err(format!(
                        "octree: node {n} has children at {b} (out of order/range)"
                    ));
                }
                if self.sizes[n as usize] != 0 {
                    return Err(format!("octree: interior node {n} has a size"));
                }
                stack.extend((b..b + 8).map(|c| c as u32));
            }
        }
        if let Some(i) = seen.iter().position(|s| !s) {
            return Err(format!("octree: node {i} unreachable"));
        }
        validate_topo(self, &self.world, self.margin, tris, self.prims.len())
    }
}

/// What traversal, validation and the SAH need from an octree topology: the basic octree and the
/// 1-bit octree's two fills implement it, so all share one traversal (same child order, same
/// culling: the same per-ray steps and tests).
pub trait Topo {
    type N: Copy;
    fn root(&self) -> Self::N;
    /// Interior: the node of octant 0 (`child(base, k)` gives octant k). Leaf: its references.
    fn expand(&self, n: Self::N) -> Expand<'_, Self::N>;
    fn child(&self, base: Self::N, k: usize) -> Self::N;
}

pub enum Expand<'a, N> {
    Interior(N),
    Leaf(&'a [u32]),
}

impl Topo for Octree {
    type N = u32;
    #[inline(always)]
    fn root(&self) -> u32 {
        0
    }
    #[inline(always)]
    fn expand(&self, n: u32) -> Expand<'_, u32> {
        let v = self.nodes[n as usize];
        if v & 1 == 1 {
            Expand::Interior(v >> 1)
        } else {
            let s = (v >> 1) as usize;
            let e = s + self.sizes[n as usize] as usize;
            Expand::Leaf(self.prims.get(s..e).unwrap_or(&[]))
        }
    }
    #[inline(always)]
    fn child(&self, base: u32, k: usize) -> u32 {
        base + k as u32
    }
}

/// Closest hit of one ray (see the module doc): (hit, nodes entered, triangle tests).
#[inline]
pub fn trace_one<T: Topo>(
    topo: &T,
    world: &Aabb,
    tris: &[Triangle],
    ray: &Ray,
    stack: &mut Vec<(T::N, Aabb, f32)>,
) -> (Hit, u32, u32) {
    use bvhlab_geom::aabb::{fmax as mx, fmin as mn};
    let mut best = Hit::within(ray.tmax);
    if ray.tmax.is_nan() || ray.tmax <= 0.0 || world.is_empty() {
        return (Hit::NONE, 0, 0);
    }
    let rb = RayBox::new(ray);
    // Axes the ray runs parallel to (RayBox's huge finite inverse): their slab is all or nothing
    // by the origin, exactly. The product form gives a ray lying in a box's upper face
    // (direction +0) the interval [-huge, 0] there, i.e. a miss of everything beyond t = 0.
    let par = [
        !(1.0 / ray.dir.x).is_finite(),
        !(1.0 / ray.dir.y).is_finite(),
        !(1.0 / ray.dir.z).is_finite(),
    ];
    let any_par = par[0] || par[1] || par[2];
    let (o, inv) = (rb.origin, rb.inv_dir);
    // (near, far) of slab [lo, hi] on axis a.
    let slab = |a: usize, lo: f32, hi: f32| -> (f32, f32) {
        if any_par && par[a] {
            if lo <= o[a] && o[a] <= hi {
                (f32::NEG_INFINITY, f32::INFINITY)
            } else {
                (f32::INFINITY, f32::NEG_INFINITY)
            }
        } else {
            let (p, q) = ((lo - o[a]) * inv[a], (hi - o[a]) * inv[a]);
            (mn(p, q), mx(p, q))
        }
    };
    let t0 = {
        let (x, y, z) = (
            slab(0, world.min.x, world.max.x),
            slab(1, world.min.y, world.max.y),
            slab(2, world.min.z, world.max.z),
        );
        let near = mx(mx(x.0, y.0), mx(z.0, 0.0));
        let far = mn(mn(x.1, y.1), mn(z.1, best.t)) * SLAB_ROBUST;
        if near.partial_cmp(&far).is_none_or(|o| o.is_gt()) {
            return (Hit::NONE, 0, 0);
        }
        near
    };
    let (mut steps, mut tests) = (0u32, 0u32);
    stack.clear();
    stack.push((topo.root(), *world, t0));
    while let Some((n, b, entry)) = stack.pop() {
        if entry > best.t * SLAB_ROBUST {
            continue;
        }
        steps += 1;
        match topo.expand(n) {
            Expand::Leaf(refs) => {
                for &p in refs {
                    if let Some(tri) = tris.get(p as usize) {
                        tests += 1;
                        if let Some(t) = intersect_triangle(ray.origin, ray.dir, tri) {
                            accept(t, p, &mut best);
                        }
                    }
                }
            }
            Expand::Interior(base) => {
                let c = centre(&b);
                // The slabs of the 8 children share the 3 planes per axis: RayBox::hit's
                // arithmetic on child_box(b, c, k) from 9 plane distances.
                let sx = [slab(0, b.min.x, c.x), slab(0, c.x, b.max.x)];
                let sy = [slab(1, b.min.y, c.y), slab(1, c.y, b.max.y)];
                let sz = [slab(2, b.min.z, c.z), slab(2, c.z, b.max.z)];
                let mut hits: [(f32, u8); 8] = [(0.0, 0); 8];
                let mut nh = 0;
                for k in 0..8 {
                    let (x, y, z) = (sx[k & 1], sy[k >> 1 & 1], sz[k >> 2 & 1]);
                    let near = mx(mx(x.0, y.0), mx(z.0, 0.0));
                    let far = mn(mn(x.1, y.1), mn(z.1, best.t)) * SLAB_ROBUST;
                    if near <= far {
                        // Insertion by (entry descending, octant descending): pushed in this
                        // order, the nearest child (lowest octant on ties) is popped first.
                        let mut j = nh;
                        while j > 0 && hits[j - 1].0 <= near {
                            hits[j] = hits[j - 1];
                            j -= 1;
                        }
                        hits[j] = (near, k as u8);
                        nh += 1;
                    }
                }
                for &(near, k) in &hits[..nh] {
                    let k = k as usize;
                    stack.push((topo.child(base, k), child_box(&b, c, k), near));
                }
            }
        }
    }
    let hit = best.found();
    (hit, steps, tests)
}

pub fn trace_topo<T: Topo + Sync>(
    topo: &T,
    world: &Aabb,
    tris: &[Triangle],
    rays: &[Ray],
) -> TraceStats
where
    T::N: Send,
{
    trace_with(
        rays,
        || Vec::with_capacity(256),
        |stack, ray| trace_one(topo, world, tris, ray, stack),
    )
}

/// Thesis eq. 4 on the implicit boxes: (c_T sum_inner SA + c_I sum_leaves SA refs) / SA(root);
/// a zero-area world box counts every node with ratio 1 (as `bvhlab_bvh::metrics`).
pub fn sah_topo<T: Topo>(topo: &T, world: &Aabb, cost: CostParams) -> f64 {
    if world.is_empty() {
        return 0.0;
    }
    let root_sa = world.area_f64();
    let degenerate = root_sa.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater);
    let ratio = |b: &Aabb| {
        if degenerate {
            1.0
        } else {
            b.area_f64() / root_sa
        }
    };
    let (mut inner, mut leaf) = (0.0f64, 0.0f64);
    let mut stack = vec![(topo.root(), *world)];
    while let Some((n, b)) = stack.pop() {
        match topo.expand(n) {
            Expand::Leaf(r) => leaf += ratio(&b) * r.len() as f64,
            Expand::Interior(base) => {
                inner += ratio(&b);
                let c = centre(&b);
                for k in 0..8 {
                    stack.push((topo.child(base, k), child_box(&b, c, k)));
                }
            }
        }
    }
    cost.c_t as f64 * inner + cost.c_i as f64 * leaf
}

/// Every triangle referenced at least once; every reference in range and its triangle's bounds
/// overlap its leaf box grown by the margin (closed); children tile the parent; `refs` references
/// in total. Walks the topology with an explicit stack (call after a structural check that makes
/// `expand` safe).
pub fn validate_topo<T: Topo>(
    topo: &T,
    world: &Aabb,
    margin: f64,
    tris: &[Triangle],
    refs: usize,
) -> Result<(), String> {
    let mut covered = vec![false; tris.len()];
    let mut counted = 0usize;
    let mut stack = vec![(topo.root(), *world)];
    let slack = margin * 1.5;
    while let Some((n, b)) = stack.pop() {
        match topo.expand(n) {
            Expand::Leaf(r) => {
                counted += r.len();
                for &p in r {
                    let t = tris
                        .get(p as usize)
                        .ok_or_else(|| format!("reference to triangle {p} of {}", tris.len()))?;
                    let tb = t.bounds();
                    let (lo, hi) = (dv(b.min) - slack, dv(b.max) + slack);
                    if dv(tb.min).cmpgt(hi).any() || dv(tb.max).cmplt(lo).any() {
                        return Err(format!(
                            "triangle {p} (bounds {tb:?}) referenced by a leaf with box {b:?}"
                        ));
                    }
                    covered[p as usize] = true;
                }
            }
            Expand::Interior(base) => {
                let c = centre(&b);
                if c.cmplt(b.min).any() || c.cmpgt(b.max).any() {
                    return Err(format!("centre {c:?} outside box {b:?}"));
                }
                let mut u = Aabb::EMPTY;
                for k in 0..8 {
                    let cb = child_box(&b, c, k);
                    if !b.contains(&cb) {
                        return Err(format!("octant {k} of {b:?} not inside it"));
                    }
                    u.grow(&cb);
                    stack.push((topo.child(base, k), cb));
                }
                if u != b {
                    return Err(format!("octants of {b:?} do not tile it"));
                }
            }
        }
    }
    if counted != refs {
        return Err(format!("{counted} references reached, {refs} stored"));
    }
    if let Some(i) = covered.iter().position(|c| !c) {
        return Err(format!("triangle {i} is not referenced by any leaf"));
    }
    Ok(())
}
