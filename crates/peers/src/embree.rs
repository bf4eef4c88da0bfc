//! Embree 3 as a peer: its standalone builders through `rtcBuildBVH` (LOW = Morton-based, MEDIUM =
//! binned SAH, HIGH = binned SAH with spatial splits), their trees imported into bvhlab's [`Bvh`],
//! and its own traversal (`rtcIntersect1` on a committed triangle scene of the same build quality).
//! The callbacks follow `../shared/tools/embree_anchor.cpp`, so the SAH of an import equals the
//! anchor's on the same scene and settings.
use crate::embree_sys::*;
use crate::{PeerBuild, PeerTrace};
use bvhlab_bvh::{Aabb, Bvh, Node, Vec3};
use bvhlab_geom::Triangle;
use bvhlab_trace::{Hit, Ray};
use std::collections::HashMap;
use std::ffi::{c_void, CString};
use std::sync::{Mutex, OnceLock};
use std::time::Instant;

/// A node as Embree's callbacks create it (in Embree's thread-local arena): children's boxes are
/// stored in the parent, as `rtcBuildBVH` hands them over.
#[repr(C)]
struct ENode {
    leaf: u32,
    count: u32,
    prims: *const u32,
    child: [*mut ENode; 2],
    bounds: [RTCBounds; 2],
}

unsafe extern "C" fn create_node(
    a: RTCThreadLocalAllocator,
    n: u32,
    _: *mut c_void,
) -> *mut c_void {
    let p = rtcThreadLocalAlloc(a, std::mem::size_of::<ENode>(), 16) as *mut ENode;
    p.write(ENode {
        leaf: 0,
        count: n,
        prims: std::ptr::null(),
        child: [std::ptr::null_mut(); 2],
        bounds: [RTCBounds::default(); 2],
    });
    p as *mut c_void
}

unsafe extern "C" fn set_children(np: *mut c_void, c: *mut *mut c_void, n: u32, _: *mut c_void) {
    let p = &mut *(np as *mut ENode);
    for i in 0..(n as usize).min(2) {
        p.child[i] = *c.add(i) as *mut ENode;
    }
    p.count = n.min(2);
}

unsafe extern "C" fn set_bounds(np: *mut c_void, b: *mut *const RTCBounds, n: u32, _: *mut c_void) {
    let p = &mut *(np as *mut ENode);
    for i in 0..(n as usize).min(2) {
        p.bounds[i] = **b.add(i);
    }
}

unsafe extern "C" fn create_leaf(
    a: RTCThreadLocalAllocator,
    prims: *const RTCBuildPrimitive,
    n: usize,
    _: *mut c_void,
) -> *mut c_void {
    // One allocation per leaf (as the anchor's one per node): the ids follow the node.
    let p = rtcThreadLocalAlloc(a, std::mem::size_of::<ENode>() + 4 * n, 16) as *mut ENode;
    let ids = p.add(1) as *mut u32;
    for i in 0..n {
        *ids.add(i) = (*prims.add(i)).primID;
    }
    p.write(ENode {
        leaf: 1,
        count: n as u32,
        prims: ids,
        child: [std::ptr::null_mut(); 2],
        bounds: [RTCBounds::default(); 2],
    });
    p as *mut c_void
}

/// Spatial splits (HIGH): the triangle's part on each side of the plane, clipped to the
/// reference's current box (Stich et al. 2009, 4.1: split the primitive, not its box).
unsafe extern "C" fn split_primitive(
    prim: *const RTCBuildPrimitive,
    dim: u32,
    pos: f32,
    left: *mut RTCBounds,
    right: *mut RTCBounds,
    user: *mut c_void,
) {
    let tris = &*(user as *const Vec<Triangle>);
    let p = &*prim;
    let tri = &tris[p.primID as usize];
    let (l, r) = crate::split_triangle(tri, dim as usize, pos);
    let cur = Aabb::new(
        Vec3::new(p.lower_x, p.lower_y, p.lower_z),
        Vec3::new(p.upper_x, p.upper_y, p.upper_z),
    );
    let clip = |b: Aabb, side: usize| {
        let mut c = Aabb::new(b.min.max(cur.min), b.max.min(cur.max));
        // The plane bounds each side even where rounding put a clipped vertex past it.
        if side == 0 {
            c.max[dim as usize] = c.max[dim as usize].min(pos);
        } else {
            c.min[dim as usize] = c.min[dim as usize].max(pos);
        }
        c
    };
    *left = to_bounds(&clip(l, 0));
    *right = to_bounds(&clip(r, 1));
}

fn to_bounds(b: &Aabb) -> RTCBounds {
    RTCBounds {
        lower_x: b.min.x,
        lower_y: b.min.y,
        lower_z: b.min.z,
        align0: 0.0,
        upper_x: b.max.x,
        upper_y: b.max.y,
        upper_z: b.max.z,
        align1: 0.0,
    }
}

fn from_bounds(b: &RTCBounds) -> Aabb {
    Aabb::new(
        Vec3::new(b.lower_x, b.lower_y, b.lower_z),
        Vec3::new(b.upper_x, b.upper_y, b.upper_z),
    )
}

/// One device per thread count for the life of the process: creating a device starts Embree's
/// task system, which is set-up cost, not build time (the anchor also reuses one device).
struct Device(RTCDevice);
unsafe impl Send for Device {}

fn device(threads: usize) -> Result<RTCDevice, String> {
    static DEVICES: OnceLock<Mutex<HashMap<usize, Device>>> = OnceLock::new();
    let mut m = DEVICES
        .get_or_init(Default::default)
        .lock()
        .map_err(|e| e.to_string())?;
    if let Some(d) = m.get(&threads) {
        return Ok(d.0);
    }
    let cfg = CString::new(format!("threads={threads}")).expect("no NUL");
    let d = unsafe { rtcNewDevice(cfg.as_ptr()) };
    if d.is_null() {
        return Err("rtcNewDevice failed (is libembree3 usable on this CPU?)".into());
    }
    let v = unsafe { rtcGetDeviceProperty(d, RTC_DEVICE_PROPERTY_VERSION) };
    if v != 31305 {
        return Err(format!(
            "Embree reports version {v}, bvhlab's bindings follow 3.13.5 (31305)"
        ));
    }
    m.insert(threads, Device(d));
    Ok(d)
}

/// Embree's build quality.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Quality {
    /// LOW: Morton-code based (Embree's "morton" builder).
    Low,
    /// MEDIUM: binned SAH.
    Medium,
    /// HIGH: binned SAH with spatial splits (references may repeat a triangle).
    High,
}

impl Quality {
    fn rtc(self) -> u32 {
        match self {
            Quality::Low => RTC_BUILD_QUALITY_LOW,
            Quality::Medium => RTC_BUILD_QUALITY_MEDIUM,
            Quality::High => RTC_BUILD_QUALITY_HIGH,
        }
    }
}

#[derive(Clone, Copy, Debug)]
pub struct EmbreeConfig {
    pub quality: Quality,
    pub max_leaf: u32,
    pub c_t: f32,
    pub c_i: f32,
    pub threads: usize,
}

/// `rtcBuildBVH` over the triangles' boxes; the time is that call's only. `tris` give the exact
/// split boxes for HIGH.
pub fn build(tris: &[Triangle], boxes: &[Aabb], cfg: &EmbreeConfig) -> Result<PeerBuild, String> {
    if boxes.is_empty() {
        return Err("no triangles".into());
    }
    if cfg.quality == Quality::High && tris.len() != boxes.len() {
        return Err("spatial splits need the triangles of every box".into());
    }
    let dev = device(cfg.threads.max(1))?;
    let mut prims: Vec<RTCBuildPrimitive> = boxes
        .iter()
        .enumerate()
        .map(|(i, b)| RTCBuildPrimitive {
            lower_x: b.min.x,
            lower_y: b.min.y,
            lower_z: b.min.z,
            geomID: 0,
            upper_x: b.max.x,
            upper_y: b.max.y,
            upper_z: b.max.z,
            primID: i as u32,
        })
        .collect();
    let count = prims.len();
    let spatial = cfg.quality == Quality::High;
    // Spatial splits need room for the new references (Embree stops splitting when the array is
    // full): bvhlab allows twice the triangles, the budget bvhlab's own `sbvh` starts from.
    if spatial {
        prims.resize(2 * count, RTCBuildPrimitive::default());
    }
    let tri_vec: Vec<Triangle> = if spatial { tris.to_vec() } else { Vec::new() };
    let bvh = unsafe { rtcNewBVH(dev) };
    if bvh.is_null() {
        return Err("rtcNewBVH failed".into());
    }
    let mut a = RTCBuildArguments::default_args();
    a.buildQuality = cfg.quality.rtc();
    a.maxBranchingFactor = 2;
    a.minLeafSize = 1;
    a.maxLeafSize = cfg.max_leaf.clamp(1, RTC_BUILD_MAX_PRIMITIVES_PER_LEAF);
    a.traversalCost = cfg.c_t;
    a.intersectionCost = cfg.c_i;
    a.bvh = bvh;
    a.primitives = prims.as_mut_ptr();
    a.primitiveCount = count;
    a.primitiveArrayCapacity = prims.len();
    a.createNode = Some(create_node);
    a.setNodeChildren = Some(set_children);
    a.setNodeBounds = Some(set_bounds);
    a.createLeaf = Some(create_leaf);
    if spatial {
        a.splitPrimitive = Some(split_primitive);
        a.userPtr = &tri_vec as *const Vec<Triangle> as *mut c_void;
    }
    let t = Instant::now();
    let root = unsafe { rtcBuildBVH(&a) } as *const ENode;
    let seconds = t.elapsed().as_secs_f64();
    let err = unsafe { rtcGetDeviceError(dev) };
    let out = if root.is_null() || err != 0 {
        Err(format!("rtcBuildBVH failed (RTCError {err})"))
    } else {
        let root_box = boxes.iter().fold(Aabb::EMPTY, |b, x| b.union(x));
        Ok(PeerBuild {
            bvh: unsafe { import(root, root_box) },
            seconds,
        })
    };
    unsafe { rtcReleaseBVH(bvh) };
    out
}

/// Depth first, siblings adjacent (left, right), leaf references in visiting order.
unsafe fn import(root: *const ENode, root_box: Aabb) -> Bvh {
    let mut out = Bvh {
        nodes: vec![Node::leaf(root_box, 0, 1)],
        prim_indices: Vec::new(),
    };
    let mut stack: Vec<(*const ENode, usize, Aabb)> = vec![(root, 0, root_box)];
    while let Some((mut n, slot, mut b)) = stack.pop() {
        // A one-child inner node (Embree never makes one for a binary tree; guarded anyway) is
        // replaced by its child.
        while (*n).leaf == 0 && (*n).count == 1 {
            b = from_bounds(&(*n).bounds[0]);
            n = (*n).child[0];
        }
        let e = &*n;
        if e.leaf != 0 {
            let first = out.prim_indices.len();
            // Spatial splits (HIGH) can leave two fragments of one triangle in the same leaf
            // (measured: dragon, leaf 726489, triangle 96128): one reference serves both, as a
            // tracer would keep it (bvhlab's invariant: at most one reference per leaf).
            for &p in std::slice::from_raw_parts(e.prims, e.count as usize) {
                if !out.prim_indices[first..].contains(&p) {
                    out.prim_indices.push(p);
                }
            }
            out.nodes[slot] = Node::leaf(b, first as u32, (out.prim_indices.len() - first) as u32);
        } else {
            let first = out.nodes.len();
            out.nodes.push(Node::leaf(b, 0, 1));
            out.nodes.push(Node::leaf(b, 0, 1));
            out.nodes[slot] = Node::inner(b, first as u32);
            stack.push((e.child[1], first + 1, from_bounds(&e.bounds[1])));
            stack.push((e.child[0], first, from_bounds(&e.bounds[0])));
        }
    }
    out
}

/// Embree's own traversal: a triangle scene committed at the build quality, one `rtcIntersect1`
/// per ray on one thread. `commit_seconds` is Embree's scene build (its own BVH4/8, not the
/// binary tree `build` returns: Embree traces only its own structures).
pub fn trace(tris: &[Triangle], rays: &[Ray], quality: Quality) -> Result<PeerTrace, String> {
    let (scene, setup_seconds) = TraceScene::new(tris, quality)?;
    let (hits, seconds) = scene.trace(rays)?;
    Ok(PeerTrace { hits, seconds, setup_seconds })
}

/// A committed Embree scene kept for several timed passes (a benchmark pairs them with its own
/// passes round by round instead of rebuilding the scene for each).
pub struct TraceScene {
    dev: RTCDevice,
    scene: RTCScene,
}

impl TraceScene {
    /// The scene of `tris` committed at `quality` (1-thread device), and the commit's seconds.
    pub fn new(tris: &[Triangle], quality: Quality) -> Result<(TraceScene, f64), String> {
        let dev = device(1)?;
        unsafe {
            let scene = rtcNewScene(dev);
            rtcSetSceneBuildQuality(scene, quality.rtc());
            let g = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_TRIANGLE);
            rtcSetGeometryBuildQuality(g, quality.rtc());
            let vb = rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 12, 3 * tris.len())
                as *mut f32;
            let ib = rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 12, tris.len()) as *mut u32;
            if vb.is_null() || ib.is_null() {
                rtcReleaseGeometry(g);
                rtcReleaseScene(scene);
                return Err(format!("Embree could not allocate buffers (RTCError {})", rtcGetDeviceError(dev)));
            }
            for (i, t) in tris.iter().enumerate() {
                for k in 0..3 {
                    for c in 0..3 {
                        *vb.add(9 * i + 3 * k + c) = t.v[k][c];
                    }
                    *ib.add(3 * i + k) = (3 * i + k) as u32;
                }
            }
            rtcCommitGeometry(g);
            rtcAttachGeometry(scene, g);
            rtcReleaseGeometry(g);
            let t0 = Instant::now();
            rtcCommitScene(scene);
            Ok((TraceScene { dev, scene }, t0.elapsed().as_secs_f64()))
        }
    }

    /// One pass over `rays` on the calling thread: the hits and the pass' seconds (the ray
    /// records are filled inside the timed loop, as the embree-anchor does).
    pub fn trace(&self, rays: &[Ray]) -> Result<(Vec<Hit>, f64), String> {
        let mut ctx = RTCIntersectContext {
            flags: 0,
            filter: std::ptr::null_mut(),
            instID: [RTC_INVALID_GEOMETRY_ID],
        };
        // The result allocated inside the timed region, as bvhlab's timed paths allocate theirs.
        let t1 = Instant::now();
        let mut hits = vec![Hit::NONE; rays.len()];
        for (r, h) in rays.iter().zip(hits.iter_mut()) {
            let mut rh = RTCRayHit::default();
            rh.ray.org_x = r.origin.x;
            rh.ray.org_y = r.origin.y;
            rh.ray.org_z = r.origin.z;
            rh.ray.dir_x = r.dir.x;
            rh.ray.dir_y = r.dir.y;
            rh.ray.dir_z = r.dir.z;
            rh.ray.tnear = 0.0;
            rh.ray.tfar = r.tmax;
            rh.ray.mask = u32::MAX;
            rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
            // SAFETY: the scene is committed and lives as long as `self`.
            unsafe { rtcIntersect1(self.scene, &mut ctx, &mut rh) };
            if rh.hit.geomID != RTC_INVALID_GEOMETRY_ID {
                *h = Hit { t: rh.ray.tfar, prim: rh.hit.primID };
            }
        }
        let seconds = t1.elapsed().as_secs_f64();
        let err = unsafe { rtcGetDeviceError(self.dev) };
        if err != 0 {
            return Err(format!("Embree traversal failed (RTCError {err})"));
        }
        Ok((hits, seconds))
    }
}

impl Drop for TraceScene {
    fn drop(&mut self) {
        // SAFETY: the scene was created by `new` and is released once.
        unsafe { rtcReleaseScene(self.scene) };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two fragments of one triangle in one leaf (what HIGH made on the dragon) become one reference.
    #[test]
    fn import_keeps_one_reference_per_leaf() {
        let ids = [5u32, 7, 5, 9];
        let leaf = |ids: &[u32]| ENode {
            leaf: 1,
            count: ids.len() as u32,
            prims: ids.as_ptr(),
            child: [std::ptr::null_mut(); 2],
            bounds: [RTCBounds::default(); 2],
        };
        let mut a = leaf(&ids);
        let mut b = leaf(&ids[3..]);
        let root = ENode {
            leaf: 0,
            count: 2,
            prims: std::ptr::null(),
            child: [&mut a, &mut b],
            bounds: [RTCBounds::default(); 2],
        };
        let bvh = unsafe { import(&root, Aabb::EMPTY) };
        let leaves: Vec<&[u32]> = bvh
            .nodes
            .iter()
            .filter(|n| n.is_leaf())
            .map(|n| &bvh.prim_indices[n.first as usize..(n.first + n.count) as usize])
            .collect();
        assert_eq!(leaves, [&[5u32, 7, 9][..], &[9][..]]);
    }
}
