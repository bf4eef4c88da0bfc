//! Builders: one registration line each (the [`Method`](super::Method) comes from the algorithm
//! file in `crates/builders/src/`; the closure calls it with the resolved parameters).
use super::{MethodInfo, MethodKind};
use crate::registry::Resolved;
use bvhlab_builders::{
    aac, binned_sah, bonsai, incremental, lbvh, ploc, sbvh, spatial_median, sweep_sah, SortedCodes,
};
use bvhlab_bvh::{Aabb, Bvh, Refs, Vec3};
use bvhlab_geom::Triangle;
use bvhlab_morton::AutoFor;
use bvhlab_peers::Peer;

/// Boxes, centres, and (for bottom-up builders) the primitives sorted by code.
pub type BuildFn = fn(&[Aabb], &[Vec3], Option<&SortedCodes>, &Resolved) -> Bvh;

/// A builder over the triangles themselves (spatial splits clip them: SBVH).
pub type TriBuildFn = fn(&[Triangle], &Resolved) -> Bvh;

/// What the pipeline needs to run a builder.
#[derive(Clone)]
pub struct Builder {
    /// The call over boxes and centres; for a builder over triangles ([`Builder::triangles`]) a
    /// stub that panics (use [`BuilderInfo::construct`], which has the triangles).
    pub run: BuildFn,
    /// `Some`: the builder needs the triangles (it clips them) and may repeat references
    /// ([`Builder::refs`] is `Refs::Split`).
    pub triangles: Option<TriBuildFn>,
    /// How often its trees reference a triangle: validation (`bvhlab_bvh::validate_refs`), and the
    /// stages after it, go by this.
    pub refs: Refs,
    /// `Some`: the builder consumes sorted codes from the encode stage; an encoder's `bits=auto`
    /// resolves to this builder's code length. Such a builder gets no centres (an empty slice).
    pub codes: Option<AutoFor>,
    /// The builder returns single-primitive leaves and is followed by the SAH compaction
    /// (`bvhlab_bvh::collapse`, thesis 3.8 / Bittner 3.6) inside the timed build: the thesis counts
    /// the compaction as part of AAC / PLOC construction.
    pub collapse: bool,
    /// A production library's builder (crates/peers): the build stage calls it with the scene's
    /// triangles and times the library's own call; its traversal runs beside bvhlab's in measure.
    pub peer: Option<Peer>,
}

impl MethodKind for Builder {
    const WHAT: &'static str = "builder";
}

pub type BuilderInfo = MethodInfo<Builder>;

/// The standard builders: one line each (the order of `bvhlab methods`).
#[rustfmt::skip]
pub fn standard() -> Vec<BuilderInfo> {
    vec![
        top_down(&spatial_median::METHOD, |b, c, _, r| spatial_median::build_in(b, c, &r.config(), r.get("frame"))),
        top_down(&sweep_sah::METHOD, |b, c, _, r| sweep_sah::build(b, c, &r.config())),
        // Parallel over the current rayon pool (thesis 3.1.2): the same tree bytes at any thread count.
        top_down(&binned_sah::METHOD, |b, c, _, r| binned_sah::build_parallel_with_options(b, c, &binned_sah::BinnedOptions { bins: r.get("bins"), term: r.get("centroid_stop"), axes: r.get("axes") }, &r.config())),
        top_down(&bonsai::METHOD, |b, c, _, r| bonsai::build(b, c, &bonsai::BonsaiConfig::from_params(&r.params, r.config()))),
        top_down(&incremental::METHOD, |b, _, _, r| incremental::build(b, &incremental::IncConfig::from_params(&r.params, r.cost))),
        // Stich et al. 2009: clips triangles, so it takes them instead of boxes; references repeat.
        over_triangles(&sbvh::METHOD, |t, r| sbvh::build(t, &sbvh::SbvhConfig::from_params(&r.params, r.config()))),
        // Each compacts its cluster tree directly (`build_compacted`: the bytes of the SAH compaction
        // of its single-triangle layout, without that layout in memory).
        bottom_up(&lbvh::METHOD, AutoFor::Lbvh, |b, _, s, r| lbvh::build_compacted(b, sorted(s), r.cost)),
        bottom_up(&aac::METHOD, AutoFor::Aac, |b, _, s, r| aac::build_compacted(b, sorted(s), &r.aac_config(), r.cost)),
        bottom_up(&ploc::METHOD, AutoFor::Ploc, |b, _, s, r| ploc::build_compacted(b, sorted(s), &ploc::PlocConfig::from_params(&r.params), r.cost)),
        // Production libraries (issue 18): Embree 3 where installed, obvhs always.
        peer(Peer::EmbreeMorton, |b, _, _, r| peer_run(Peer::EmbreeMorton, b, r)),
        peer(Peer::EmbreeBinned, |b, _, _, r| peer_run(Peer::EmbreeBinned, b, r)),
        peer(Peer::EmbreeSbvh, |b, _, _, r| peer_run(Peer::EmbreeSbvh, b, r)),
        peer(Peer::Obvhs, |b, _, _, r| peer_run(Peer::Obvhs, b, r)),
    ]
}

fn peer(p: Peer, run: BuildFn) -> BuilderInfo {
    let refs = if p.splits() { Refs::Split } else { Refs::Unique };
    MethodInfo::new(p.method(), Builder { peer: Some(p), refs, ..Builder::over_boxes(run) })
}

/// A peer over boxes only (tests, examples): the build stage goes through [`Peer::build`] with
/// the triangles instead, and reports a library's failure as that peer's error.
fn peer_run(p: Peer, boxes: &[Aabb], r: &Resolved) -> Bvh {
    match p.build(&[], boxes, &r.params, r.cost.c_t, r.cost.c_i) {
        Ok(b) => b.bvh,
        Err(e) => panic!("{}: {e}", p.method().name),
    }
}

impl Builder {
    /// A top-down builder over boxes and centres: no codes, no compaction.
    pub fn over_boxes(run: BuildFn) -> Builder {
        Builder {
            run,
            triangles: None,
            refs: Refs::Unique,
            codes: None,
            collapse: false,
            peer: None,
        }
    }

    /// A top-down builder over the triangles whose trees may reference a triangle several times.
    pub fn over_triangles(run: TriBuildFn) -> Builder {
        Builder {
            run: needs_triangles,
            triangles: Some(run),
            refs: Refs::Split,
            codes: None,
            collapse: false,
            peer: None,
        }
    }

    /// A bottom-up builder over codes sorted for `auto`, followed by the SAH compaction.
    pub fn over_codes(run: BuildFn, auto: AutoFor) -> Builder {
        Builder {
            run,
            triangles: None,
            refs: Refs::Unique,
            codes: Some(auto),
            collapse: true,
            peer: None,
        }
    }
}

impl BuilderInfo {
    /// A top-down builder described in place (test doubles).
    pub fn top_down(
        name: &'static str,
        about: &'static str,
        params: Vec<super::ParamSpec>,
        run: BuildFn,
    ) -> BuilderInfo {
        MethodInfo::custom(name, about, params, Builder::over_boxes(run))
    }

    /// The same builder over codes sorted for `auto`, followed by the SAH compaction.
    pub fn with_codes(self, auto: AutoFor) -> BuilderInfo {
        MethodInfo {
            kind: Builder::over_codes(self.run, auto),
            ..self
        }
    }

    /// What the build stage produces: the builder (over the triangles, or their boxes and
    /// centres), then (bottom-up builders) the SAH compaction.
    pub fn construct(
        &self,
        tris: &[Triangle],
        boxes: &[Aabb],
        centers: &[Vec3],
        codes: Option<&SortedCodes>,
        r: &Resolved,
    ) -> Bvh {
        let bvh = match self.triangles {
            Some(run) => run(tris, r),
            None => (self.run)(boxes, centers, codes, r),
        };
        if self.collapse {
            bvhlab_bvh::collapse::collapse(&bvh, r.cost)
        } else {
            bvh
        }
    }
}

fn top_down(m: &super::Method, run: BuildFn) -> BuilderInfo {
    MethodInfo::new(m, Builder::over_boxes(run))
}

fn over_triangles(m: &super::Method, run: TriBuildFn) -> BuilderInfo {
    MethodInfo::new(m, Builder::over_triangles(run))
}

/// `Builder::run` of a builder over triangles: calling it without them is a bug.
fn needs_triangles(_: &[Aabb], _: &[Vec3], _: Option<&SortedCodes>, r: &Resolved) -> Bvh {
    panic!("builder `{}` clips triangles: call `BuilderInfo::construct` with the scene's triangles", r.builder)
}

/// A bottom-up builder over codes whose call includes its SAH compaction.
fn bottom_up(m: &super::Method, auto: AutoFor, run: BuildFn) -> BuilderInfo {
    MethodInfo::new(m, Builder { collapse: false, ..Builder::over_codes(run, auto) })
}

/// The pipeline guarantees codes for code-using builders (`Builder::codes`).
fn sorted<'a>(s: Option<&'a SortedCodes<'a>>) -> &'a SortedCodes<'a> {
    s.expect("the pipeline passes sorted codes to every builder with `codes: Some(..)`")
}

#[cfg(test)]
mod tests {
    use crate::registry::tests::raw;
    use crate::registry::Registry;
    use bvhlab_builders::aac::AacConfig;
    use bvhlab_bvh::CostParams;

    #[test]
    fn aac_presets_share_keys_with_their_values() {
        let r = Registry::standard();
        let c = CostParams::default();
        let hq = r.resolve("aac", &raw(&[("preset", "hq")]), c).unwrap();
        let explicit = r
            .resolve("aac", &raw(&[("delta", "20"), ("epsilon", "0.10")]), c)
            .unwrap();
        let default = r.resolve("aac", &raw(&[]), c).unwrap();
        assert_eq!(hq, explicit);
        assert_eq!(hq, default);
        assert_eq!(
            crate::key::params_string(&hq.params),
            "delta=20,epsilon=0.1"
        );
        assert_eq!(r.label(&hq), "aac HQ");
        let fast = r
            .resolve("aac", &raw(&[("preset", "fast"), ("delta", "4")]), c)
            .unwrap();
        assert_eq!(fast.aac_config(), AacConfig::FAST);
        assert_eq!(r.label(&fast), "aac fast");
        let other = r
            .resolve("aac", &raw(&[("delta", "8"), ("epsilon", "0")]), c)
            .unwrap();
        assert_eq!(r.label(&other), "aac delta=8 epsilon=0");
        let e = r
            .resolve("aac", &raw(&[("preset", "fast"), ("delta", "20")]), c)
            .unwrap_err();
        assert!(
            e.message().contains("preset=fast sets delta=4") && e.exit_code() == 2,
            "{e}"
        );
        assert!(r.resolve("aac", &raw(&[("delta", "0")]), c).is_err());
        assert!(r.resolve("aac", &raw(&[("epsilon", "-0.1")]), c).is_err());
        assert!(r.resolve("aac", &raw(&[("preset", "best")]), c).is_err());
    }
}
