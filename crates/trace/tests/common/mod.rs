//! Test helpers: deterministic random triangles and hand-made BVHs (no builder crate needed).
#![allow(dead_code)]
use bvhlab_bvh::{Bvh, Node};
use bvhlab_geom::{Aabb, Triangle, Vec3};

pub use bvhlab_geom::rng::SplitMix64 as Rng;

/// A uniform point in the unit cube.
pub fn rand_vec(r: &mut Rng) -> Vec3 {
    Vec3::new(r.f32(), r.f32(), r.f32())
}

/// `n` small random triangles in the unit cube (sizes up to `size`).
pub fn random_triangles(n: usize, size: f32, seed: u64) -> Vec<Triangle> {
    let mut r = Rng(seed);
    (0..n)
        .map(|_| {
            let c = rand_vec(&mut r);
            let a = c + (rand_vec(&mut r) - 0.5) * size;
            let b = c + (rand_vec(&mut r) - 0.5) * size;
            let d = c + (rand_vec(&mut r) - 0.5) * size;
            Triangle::new(a, b, d)
        })
        .collect()
}

pub fn bounds_of(tris: &[Triangle], idx: &[u32]) -> Aabb {
    let mut b = Aabb::EMPTY;
    for &i in idx {
        b.grow(&tris[i as usize].bounds());
    }
    b
}

/// Everything in one leaf: trivially a valid BVH.
pub fn one_leaf(tris: &[Triangle]) -> Bvh {
    let idx: Vec<u32> = (0..tris.len() as u32).collect();
    Bvh {
        nodes: vec![Node::leaf(bounds_of(tris, &idx), 0, tris.len() as u32)],
        prim_indices: idx,
    }
}

/// Object-median split on the largest centroid axis, down to `leaf` primitives: a simple
/// hand-made builder giving deep trees with overlapping siblings.
pub fn median_bvh(tris: &[Triangle], leaf: usize) -> Bvh {
    let mut idx: Vec<u32> = (0..tris.len() as u32).collect();
    let mut nodes = vec![Node::leaf(Aabb::EMPTY, 0, 1)];
    fn rec(
        tris: &[Triangle],
        idx: &mut [u32],
        off: u32,
        node: usize,
        nodes: &mut Vec<Node>,
        leaf: usize,
    ) {
        let b = bounds_of(tris, idx);
        if idx.len() <= leaf {
            nodes[node] = Node::leaf(b, off, idx.len() as u32);
            return;
        }
        let mut cb = Aabb::EMPTY;
        for &i in idx.iter() {
            cb.grow_point(tris[i as usize].bounds().center());
        }
        let ax = cb.largest_axis();
        idx.sort_by(|&a, &c| {
            let ka = tris[a as usize].bounds().center()[ax];
            let kc = tris[c as usize].bounds().center()[ax];
            ka.total_cmp(&kc).then(a.cmp(&c))
        });
        let l = nodes.len();
        nodes.push(Node::leaf(Aabb::EMPTY, 0, 1));
        nodes.push(Node::leaf(Aabb::EMPTY, 0, 1));
        nodes[node] = Node::inner(b, l as u32);
        let mid = idx.len() / 2;
        let (a, c) = idx.split_at_mut(mid);
        rec(tris, a, off, l, nodes, leaf);
        rec(tris, c, off + mid as u32, l + 1, nodes, leaf);
    }
    if !tris.is_empty() {
        rec(tris, &mut idx, 0, 0, &mut nodes, leaf);
    }
    Bvh {
        nodes,
        prim_indices: idx,
    }
}

/// A "caterpillar" of depth `n - 1` (n >= 2): chain node k has chain node k+1 on the left and a
/// leaf with triangle k on the right; every box is the whole scene box. Entry distances tie, so
/// traversal descends the chain and pushes every leaf: the stack grows as deep as the tree.
/// Layout: chain node 0 at index 0, chain node k >= 1 at 2k-1, the leaf of triangle k at 2k+2,
/// and the last chain node (a leaf with triangle n-1) at 2n-3.
pub fn caterpillar(tris: &[Triangle]) -> Bvh {
    let n = tris.len();
    assert!(n >= 2);
    let idx: Vec<u32> = (0..n as u32).collect();
    let all = bounds_of(tris, &idx);
    let mut nodes = vec![Node::leaf(all, 0, 1); 2 * n - 1];
    nodes[0] = Node::inner(all, 1);
    for k in 1..n - 1 {
        nodes[2 * k - 1] = Node::inner(all, (2 * k + 1) as u32);
    }
    for k in 0..n - 1 {
        nodes[2 * k + 2] = Node::leaf(all, k as u32, 1);
    }
    nodes[2 * n - 3] = Node::leaf(all, (n - 1) as u32, 1);
    Bvh {
        nodes,
        prim_indices: idx,
    }
}
