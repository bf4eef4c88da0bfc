//! Production BVH libraries as bvhlab methods (issue 18): their builders run on the same boxes as
//! bvhlab's, their trees are imported into bvhlab's [`Bvh`] (leaves of several triangles as built),
//! so every metric, layout, heat map and oracle check applies unchanged; their own traversals run
//! beside bvhlab's on the same rays.
//!
//! - [`embree`]: Embree 3.13 (`rtcBuildBVH` LOW / MEDIUM / HIGH, `rtcIntersect1`), when the library
//!   is installed (`scripts/setup.sh`) and the `embree` feature is on ([`EMBREE_AVAILABLE`]).
//! - [`obvhs_ploc`]: obvhs (pure Rust): PLOC with its reinsertion optimizer and presets.
use bvhlab_bvh::{Aabb, Bvh};
use bvhlab_geom::Triangle;
use bvhlab_trace::Hit;

#[cfg(has_embree)]
pub mod embree;
#[cfg(has_embree)]
mod embree_sys;
pub mod methods;
pub mod obvhs_ploc;

/// Whether this binary was linked against Embree.
pub const EMBREE_AVAILABLE: bool = cfg!(has_embree);
/// The Embree release the bindings follow (checked against the library at run time).
pub const EMBREE_VERSION: &str = "3.13.5";
/// The pinned obvhs release (Cargo.toml `=0.4.0`).
pub const OBVHS_VERSION: &str = "0.4.0";

/// How to get Embree where it is missing: the planning error of an embree-* method.
pub const EMBREE_MISSING: &str = "this bvhlab was built without Embree 3: install it with \
    scripts/setup.sh (Debian's libembree-dev 3.13) and rebuild (the `embree` feature of \
    bvhlab-peers is on by default and links Embree wherever libembree3.so is found)";

/// A peer's tree and the time of the peer's own build call (the import is not timed).
pub struct PeerBuild {
    pub bvh: Bvh,
    pub seconds: f64,
}

/// A peer's traversal of the rays: closest hits, the timed loop, and untimed set-up (e.g. Embree's
/// scene commit).
pub struct PeerTrace {
    pub hits: Vec<Hit>,
    pub seconds: f64,
    pub setup_seconds: f64,
}

/// A committed Embree scene for repeated passes of `rtcIntersect1` on one thread
/// ([`Peer::embree_scene`]).
pub struct EmbreeScene(#[cfg(has_embree)] embree::TraceScene);

impl EmbreeScene {
    /// One pass over `rays`: the hits and the pass' seconds.
    pub fn trace(&self, rays: &[bvhlab_trace::Ray]) -> Result<(Vec<Hit>, f64), String> {
        #[cfg(not(has_embree))]
        {
            let _ = rays;
            Err(EMBREE_MISSING.into())
        }
        #[cfg(has_embree)]
        {
            self.0.trace(rays)
        }
    }
}

/// The boxes of the parts of `tri` on each side of the plane `x[dim] = pos` (left: below).
/// Stich et al. 2009, 4.1: split the triangle, not its box, so both boxes are tight.
pub fn split_triangle(tri: &Triangle, dim: usize, pos: f32) -> (Aabb, Aabb) {
    let (mut l, mut r) = (Aabb::EMPTY, Aabb::EMPTY);
    for k in 0..3 {
        let (a, b) = (tri.v[k], tri.v[(k + 1) % 3]);
        if a[dim] <= pos {
            l.grow_point(a);
        }
        if a[dim] >= pos {
            r.grow_point(a);
        }
        if (a[dim] < pos && b[dim] > pos) || (a[dim] > pos && b[dim] < pos) {
            let t = (pos - a[dim]) / (b[dim] - a[dim]);
            let mut p = a + (b - a) * t;
            p[dim] = pos;
            l.grow_point(p);
            r.grow_point(p);
        }
    }
    (l, r)
}

/// Whether a peer's hit agrees with bvhlab's exact one: the same triangle, or (an exact tie, or a
/// peer testing in f32) the same distance within `rel` of it.
pub fn hits_agree(ours: &Hit, peer: &Hit, rel: f32) -> bool {
    match (ours.is_hit(), peer.is_hit()) {
        (false, false) => true,
        (true, true) => {
            ours.prim == peer.prim
                || (ours.t - peer.t).abs() <= rel * ours.t.abs().max(f32::MIN_POSITIVE)
        }
        _ => false,
    }
}

/// The peer methods (their [`bvhlab_params::Method`]s are in [`methods`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Peer {
    EmbreeMorton,
    EmbreeBinned,
    EmbreeSbvh,
    Obvhs,
}

impl Peer {
    pub const ALL: [Peer; 4] = [
        Peer::EmbreeMorton,
        Peer::EmbreeBinned,
        Peer::EmbreeSbvh,
        Peer::Obvhs,
    ];

    pub fn method(self) -> &'static bvhlab_params::Method {
        match self {
            Peer::EmbreeMorton => &methods::EMBREE_MORTON,
            Peer::EmbreeBinned => &methods::EMBREE_BINNED,
            Peer::EmbreeSbvh => &methods::EMBREE_SBVH,
            Peer::Obvhs => &methods::OBVHS,
        }
    }

    /// The library (name and version) for reports.
    pub fn library(self) -> String {
        match self {
            Peer::Obvhs => format!("obvhs {OBVHS_VERSION}"),
            _ => format!("Embree {EMBREE_VERSION}"),
        }
    }

    /// `Err` says how to enable a peer this binary lacks (checked when an experiment is planned).
    pub fn available(self) -> Result<(), &'static str> {
        match self {
            Peer::Obvhs => Ok(()),
            _ if EMBREE_AVAILABLE => Ok(()),
            _ => Err(EMBREE_MISSING),
        }
    }

    /// Whether the peer's references may repeat a triangle (spatial splits).
    pub fn splits(self) -> bool {
        self == Peer::EmbreeSbvh
    }

    /// Runs the peer's builder on the scene's triangles and boxes with its canonical parameters and
    /// the chain's SAH constants; a failure of the library is an `Err`, never a panic.
    pub fn build(
        self,
        tris: &[Triangle],
        boxes: &[Aabb],
        params: &bvhlab_params::Params,
        c_t: f32,
        c_i: f32,
    ) -> Result<PeerBuild, String> {
        self.available()?;
        let caught = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| match self {
            Peer::Obvhs => obvhs_ploc::build(boxes, methods::obvhs_params(params)?),
            #[cfg(has_embree)]
            _ => embree::build(tris, boxes, &self.embree_config(params, c_t, c_i)?),
            #[cfg(not(has_embree))]
            _ => {
                let _ = (tris, c_t, c_i);
                Err(EMBREE_MISSING.into())
            }
        }));
        caught.unwrap_or_else(|_| Err(format!("{} panicked", self.library())))
    }

    #[cfg(has_embree)]
    fn quality(self) -> embree::Quality {
        match self {
            Peer::EmbreeMorton => embree::Quality::Low,
            Peer::EmbreeBinned => embree::Quality::Medium,
            _ => embree::Quality::High,
        }
    }

    /// Embree's build settings from the canonical parameters and the chain's SAH constants.
    #[cfg(has_embree)]
    fn embree_config(self, params: &bvhlab_params::Params, c_t: f32, c_i: f32) -> Result<embree::EmbreeConfig, String> {
        let u = |k: &str| params.get(k).and_then(|v| v.parse::<u32>().ok()).ok_or(format!("embree: bad `{k}`"));
        Ok(embree::EmbreeConfig {
            quality: self.quality(),
            max_leaf: u("max_leaf")?,
            c_t,
            c_i,
            threads: u("threads")? as usize,
        })
    }

    /// The peer's own traversal of `rays` (one thread). obvhs traces the very tree bvhlab imported
    /// (converted back to its `Bvh2`); Embree traces only its own structures, so it commits a scene
    /// of the same build quality.
    pub fn trace(
        self,
        bvh: &Bvh,
        tris: &[Triangle],
        rays: &[bvhlab_trace::Ray],
    ) -> Result<PeerTrace, String> {
        self.available()?;
        let caught = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| match self {
            Peer::Obvhs => Ok(obvhs_ploc::trace(bvh, tris, rays)),
            _ => self.trace_embree(tris, rays),
        }));
        caught.unwrap_or_else(|_| Err(format!("{} traversal panicked", self.library())))
    }

    /// An Embree scene of this peer's build quality committed once for repeated timed passes
    /// ([`EmbreeScene::trace`]); an error for obvhs and without Embree in the build.
    pub fn embree_scene(self, tris: &[Triangle]) -> Result<EmbreeScene, String> {
        self.available()?;
        if self == Peer::Obvhs {
            return Err("obvhs has no Embree scene".into());
        }
        #[cfg(not(has_embree))]
        {
            let _ = tris;
            Err(EMBREE_MISSING.into())
        }
        #[cfg(has_embree)]
        {
            embree::TraceScene::new(tris, self.quality()).map(|(s, _)| EmbreeScene(s))
        }
    }

    fn trace_embree(
        self,
        tris: &[Triangle],
        rays: &[bvhlab_trace::Ray],
    ) -> Result<PeerTrace, String> {
        #[cfg(not(has_embree))]
        {
            let _ = (tris, rays);
            Err(EMBREE_MISSING.into())
        }
        #[cfg(has_embree)]
        {
            embree::trace(tris, rays, self.quality())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Without Embree in the build, its peers say how to get it; obvhs is always there.
    #[test]
    fn availability_follows_the_build() {
        assert!(Peer::Obvhs.available().is_ok());
        for p in [Peer::EmbreeMorton, Peer::EmbreeBinned, Peer::EmbreeSbvh] {
            match p.available() {
                Ok(()) => assert!(EMBREE_AVAILABLE),
                Err(how) => {
                    assert!(
                        !EMBREE_AVAILABLE && how.contains("scripts/setup.sh"),
                        "{how}"
                    );
                    assert!(p.build(&[], &[], &Default::default(), 3.0, 2.0).is_err());
                }
            }
        }
    }
}
