//! Arbitrary bytes -> a triangle soup (non-finite, huge, tiny and grid-snapped coordinates, so ties,
//! duplicates and flat boxes are common) -> Scene (drops non-finite triangles) -> every registered
//! builder (default encoder) + compaction + every layout -> validation + closest hits of a few rays
//! against brute force. A panic, an invalid structure or a wrong hit is a crash.
#![no_main]
use bvhlab_geom::{Scene, Triangle, Vec3};
use libfuzzer_sys::fuzz_target;

#[path = "../../crates/pipeline/tests/methods/mod.rs"]
mod methods;

const MAX_TRIS: usize = 48;

/// Byte 0 picks the coordinate mode and scale; grid mode maps each byte to a lattice point
/// (high nibble values 0xF0.. are NaN, +-inf, +-f32::MAX, subnormals), raw mode reads f32s.
fn soup(data: &[u8]) -> Vec<Triangle> {
    let Some((&mode, rest)) = data.split_first() else {
        return Vec::new();
    };
    let scale = [1.0f32, 1e-30, 1e30, 1e-3, 1e3, 1e-38, 1e37, 0.5][(mode >> 1 & 7) as usize];
    let coords: Vec<f32> = if mode & 1 == 0 {
        rest.iter()
            .map(|&b| match b {
                0xF0 => f32::NAN,
                0xF1 => f32::INFINITY,
                0xF2 => f32::NEG_INFINITY,
                0xF3 => f32::MAX,
                0xF4 => -f32::MAX,
                0xF5 => f32::MIN_POSITIVE * 0.5,
                0xF6 => 1e30,
                0xF7 => -1e30,
                _ => ((b & 15) as f32 - 8.0) * scale + (b >> 4) as f32 * scale * 0.25,
            })
            .collect()
    } else {
        rest.chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect()
    };
    coords
        .chunks_exact(9)
        .take(MAX_TRIS)
        .map(|c| {
            Triangle::new(
                Vec3::new(c[0], c[1], c[2]),
                Vec3::new(c[3], c[4], c[5]),
                Vec3::new(c[6], c[7], c[8]),
            )
        })
        .collect()
}

fuzz_target!(|data: &[u8]| {
    let tris = soup(data);
    let total = tris.len();
    let scene = Scene::from_triangles(tris);
    assert_eq!(scene.triangles.len() + scene.dropped_triangles as usize, total);
    if scene.triangles.is_empty() {
        return;
    }
    let seed = data.iter().fold(0u64, |h, &b| h.wrapping_mul(31).wrapping_add(b as u64));
    let rays = methods::stress_rays(&scene.triangles, 8, seed);
    let want = bvhlab_trace::brute_force(&scene.triangles, &rays);
    let input = methods::Input::new(&scene, &rays);
    let opts = methods::Opts {
        all_encoders: false,
        variants: false,
        optimizers: false,
        max_passes: 1,
        layouts: true,
        collapse: true,
        skip_builders: &[],
    };
    let mut tally = methods::Tally::default();
    methods::run_all(&input, opts, &mut |label, o| tally.add("soup", label, o, &want));
    assert!(tally.failures.is_empty(), "{}", tally.summary());
});
