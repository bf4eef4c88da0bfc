//! obvhs 0.4 (DGriffin91/obvhs, pure Rust) as a peer: its `build_bvh2` (PLOC, Meister and Bittner
//! 2018, then its parallel-reinsertion optimizer, Meister and Bittner 2022, and its leaf collapse),
//! with its presets and parameters as the crate names them, and its own `Bvh2::ray_traverse`.
//! Built from the triangles' boxes (`pre_split`, its triangle pre-splitting, is not offered: it
//! needs references that repeat a triangle).
use crate::{PeerBuild, PeerTrace};
use bvhlab_bvh::{Aabb, Bvh, Node, Vec3};
use bvhlab_geom::Triangle;
use bvhlab_trace::{Hit, Ray};
use obvhs::bvh2::node::Bvh2Node;
use obvhs::bvh2::Bvh2;
use obvhs::ploc::{PlocSearchDistance, SortPrecision};
use obvhs::BvhBuildParams;
use obvhs_glam::Vec3A;
use std::time::{Duration, Instant};

/// obvhs' presets (`BvhBuildParams::fastest_build()` ... `very_slow_build()`).
pub const PRESETS: &[&str] = &[
    "fastest",
    "very_fast",
    "fast",
    "medium",
    "slow",
    "very_slow",
];

pub fn preset(name: &str) -> Option<BvhBuildParams> {
    Some(match name {
        "fastest" => BvhBuildParams::fastest_build(),
        "very_fast" => BvhBuildParams::very_fast_build(),
        "fast" => BvhBuildParams::fast_build(),
        "medium" => BvhBuildParams::medium_build(),
        "slow" => BvhBuildParams::slow_build(),
        "very_slow" => BvhBuildParams::very_slow_build(),
        _ => return None,
    })
}

/// obvhs' PLOC search distances (`PlocSearchDistance`), as their radius.
pub fn search_distance(r: u32) -> Option<PlocSearchDistance> {
    Some(match r {
        1 => PlocSearchDistance::Minimum,
        2 => PlocSearchDistance::VeryLow,
        6 => PlocSearchDistance::Low,
        14 => PlocSearchDistance::Medium,
        24 => PlocSearchDistance::High,
        32 => PlocSearchDistance::VeryHigh,
        _ => return None,
    })
}

pub fn search_radius(d: PlocSearchDistance) -> u32 {
    match d {
        PlocSearchDistance::Minimum => 1,
        PlocSearchDistance::VeryLow => 2,
        PlocSearchDistance::Low => 6,
        PlocSearchDistance::Medium => 14,
        PlocSearchDistance::High => 24,
        PlocSearchDistance::VeryHigh => 32,
    }
}

pub fn sort_bits(p: SortPrecision) -> u32 {
    match p {
        SortPrecision::U128 => 128,
        SortPrecision::U64 => 64,
    }
}

fn v3a(v: Vec3) -> Vec3A {
    Vec3A::new(v.x, v.y, v.z)
}

fn aabb(b: &Aabb) -> obvhs::aabb::Aabb {
    obvhs::aabb::Aabb::new(v3a(b.min), v3a(b.max))
}

/// `build_bvh2` over the boxes; the time is obvhs' own `core_build_time` (PLOC, reinsertion,
/// collapse; not its debug validation nor the import).
pub fn build(boxes: &[Aabb], params: BvhBuildParams) -> Result<PeerBuild, String> {
    if boxes.is_empty() {
        return Err("no triangles".into());
    }
    let prims: Vec<obvhs::aabb::Aabb> = boxes.iter().map(aabb).collect();
    let mut core = Duration::ZERO;
    let t = Instant::now();
    let b = obvhs::bvh2::builder::build_bvh2(&prims, params, &mut core);
    let wall = t.elapsed();
    // In a debug build obvhs validates its tree inside the call; its core time excludes that.
    let seconds = if cfg!(debug_assertions) {
        core
    } else {
        core.min(wall)
    }
    .as_secs_f64();
    Ok(PeerBuild {
        bvh: import(&b)?,
        seconds,
    })
}

fn import(b: &Bvh2) -> Result<Bvh, String> {
    let node_box = |n: &Bvh2Node| {
        Aabb::new(
            Vec3::new(n.aabb.min.x, n.aabb.min.y, n.aabb.min.z),
            Vec3::new(n.aabb.max.x, n.aabb.max.y, n.aabb.max.z),
        )
    };
    let root = b.nodes.first().ok_or("obvhs returned an empty tree")?;
    let mut out = Bvh {
        nodes: vec![Node::leaf(node_box(root), 0, 1)],
        prim_indices: Vec::new(),
    };
    let mut stack = vec![(0usize, 0usize)];
    while let Some((src, slot)) = stack.pop() {
        let n = b.nodes.get(src).ok_or("obvhs node index out of range")?;
        if n.prim_count > 0 {
            let (f, c) = (n.first_index as usize, n.prim_count as usize);
            let refs = b
                .primitive_indices
                .get(f..f + c)
                .ok_or("obvhs leaf range out of range")?;
            let first = out.prim_indices.len() as u32;
            out.prim_indices.extend_from_slice(refs);
            out.nodes[slot] = Node::leaf(node_box(n), first, c as u32);
        } else {
            let first = out.nodes.len();
            let c = n.first_index as usize;
            for k in 0..2 {
                let child = b.nodes.get(c + k).ok_or("obvhs child index out of range")?;
                out.nodes.push(Node::leaf(node_box(child), 0, 1));
            }
            out.nodes[slot] = Node::inner(node_box(n), first as u32);
            stack.push((c + 1, first + 1));
            stack.push((c, first));
        }
    }
    Ok(out)
}

/// bvhlab's BVH as obvhs' `Bvh2` (the same flat binary form: siblings adjacent, leaves index a
/// primitive-index list), so an obvhs tree built and cached by bvhlab is traced by obvhs' code.
pub fn to_bvh2(bvh: &Bvh) -> Bvh2 {
    let nodes = bvh
        .nodes
        .iter()
        .map(|n| Bvh2Node {
            aabb: aabb(&n.bounds),
            prim_count: n.count,
            first_index: n.first,
            ..Default::default()
        })
        .collect();
    Bvh2 {
        nodes,
        primitive_indices: bvh.prim_indices.clone(),
        // obvhs sizes its traversal stack by this (a heap stack beyond 192).
        max_depth: depth(bvh) + 2,
        ..Default::default()
    }
}

fn depth(bvh: &Bvh) -> usize {
    let mut max = 0;
    let mut stack = vec![(0usize, 1usize)];
    while let Some((i, d)) = stack.pop() {
        max = max.max(d);
        let n = &bvh.nodes[i];
        if !n.is_leaf() {
            stack.push((n.first as usize, d + 1));
            stack.push((n.first as usize + 1, d + 1));
        }
    }
    max
}

/// obvhs' `Bvh2::ray_traverse` with its ray-triangle test, one thread; set-up (the conversion and
/// its triangle form) is untimed.
pub fn trace(bvh: &Bvh, tris: &[Triangle], rays: &[Ray]) -> PeerTrace {
    let t0 = Instant::now();
    let b = to_bvh2(bvh);
    let otris: Vec<obvhs::triangle::Triangle> = tris
        .iter()
        .map(|t| obvhs::triangle::Triangle {
            v0: v3a(t.v[0]),
            v1: v3a(t.v[1]),
            v2: v3a(t.v[2]),
        })
        .collect();
    let setup_seconds = t0.elapsed().as_secs_f64();
    let mut hits = vec![Hit::NONE; rays.len()];
    let t1 = Instant::now();
    for (r, h) in rays.iter().zip(hits.iter_mut()) {
        let ray = obvhs::ray::Ray::new(v3a(r.origin), v3a(r.dir), 0.0, r.tmax);
        let mut rh = obvhs::ray::RayHit::none();
        if b.ray_traverse(ray, &mut rh, |ray, id| {
            otris[b.primitive_indices[id] as usize].intersect(ray)
        }) {
            *h = Hit {
                t: rh.t,
                prim: b.primitive_indices[rh.primitive_id as usize],
            };
        }
    }
    PeerTrace {
        hits,
        seconds: t1.elapsed().as_secs_f64(),
        setup_seconds,
    }
}
