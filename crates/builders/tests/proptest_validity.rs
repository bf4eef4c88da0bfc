//! Property test: on arbitrary small inputs (including duplicates, flat and point boxes) every
//! builder yields a valid BVH, and leaf = 1 yields single-primitive leaves.
mod common;
use bvhlab_builders::TopDownConfig;
use bvhlab_bvh::{validate, Aabb, Vec3};
use common::*;
use proptest::prelude::*;

fn arb_box() -> impl Strategy<Value = Aabb> {
    // Coordinates on a coarse grid so coincident centres and zero extents are common.
    let coord = (-4i32..4).prop_map(|v| v as f32 * 0.25);
    let ext = prop_oneof![Just(0.0f32), (0i32..4).prop_map(|v| v as f32 * 0.5)];
    (
        (coord.clone(), coord.clone(), coord),
        (ext.clone(), ext.clone(), ext),
    )
        .prop_map(|((x, y, z), (a, b, c))| {
            let p = Vec3::new(x, y, z);
            Aabb::new(p, p + Vec3::new(a, b, c))
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]
    #[test]
    fn builders_are_valid(boxes in prop::collection::vec(arb_box(), 1..120), leaf in 1u32..5, bins in 2u32..20) {
        let centers = centers_of(&boxes);
        let cfg = TopDownConfig { leaf, ..Default::default() };
        for (name, build) in BUILDERS {
            let bvh = build(&boxes, &centers, &cfg);
            prop_assert!(validate(&bvh, &boxes).is_ok(), "{} leaf {}: {:?}", name, leaf, validate(&bvh, &boxes));
            if leaf == 1 {
                prop_assert_eq!(max_leaf_size(&bvh), 1);
            }
        }
        let bvh = bvhlab_builders::binned_sah::build(&boxes, &centers, bins, &cfg);
        prop_assert!(validate(&bvh, &boxes).is_ok(), "binned {} bins", bins);
        let opts = bvhlab_builders::binned_sah::BinnedOptions {
            axes: bvhlab_builders::binned_sah::Axes::All,
            ..bvhlab_builders::binned_sah::BinnedOptions::new(bins)
        };
        let bvh = bvhlab_builders::binned_sah::build_with_options(&boxes, &centers, &opts, &cfg);
        prop_assert!(validate(&bvh, &boxes).is_ok(), "binned axes=all {} bins", bins);
    }
}
