//! Quantization and key stream checks.

use super::quant::{write_key, Bytes8, Grid, KeyReader, Packed};
use bvhlab_geom::{Aabb, Vec3};

#[test]
fn dequantize_hits_the_frame_ends_and_keys_are_conservative() {
    for bits in [1u32, 2, 4, 8, 12, 16] {
        let m = (1u32 << bits) - 1;
        let inv = 1.0 / m as f32;
        for f in [
            Aabb::new(Vec3::new(-1.0, 0.0, 1e6), Vec3::new(3.0, 0.0, 1e6 + 0.125)),
            Aabb::new(Vec3::splat(-3.0e38), Vec3::splat(3.0e38)),
            Aabb::new(Vec3::splat(1e-30), Vec3::splat(2e-30)),
        ] {
            let g = Grid::new(&f, inv);
            for a in 0..3 {
                assert_eq!(g.deq(a, 0, m), f.min[a]);
                assert_eq!(g.deq(a, m, m), f.max[a]);
            }
            for i in 0..=100 {
                let s = i as f32 / 100.0;
                let e = f.min * (1.0 - s) + f.max * s;
                let e = e.clamp(f.min, f.max);
                let b = Aabb::new(e, e);
                let k = g.quantize(&b, m);
                assert!(g.dequantize(&k, m).contains(&b), "bits {bits} {f:?} {e}");
            }
        }
    }
}

#[test]
fn packed_reader_matches_writer() {
    for bits in 1..=16u32 {
        let n = 7;
        let mut keys = vec![0u8; (n * 6 * bits as usize).div_ceil(8)];
        let m = (1u32 << bits) - 1;
        let key = |i: usize| {
            std::array::from_fn::<u32, 6, _>(|c| {
                ((i * 31 + c * 7) as u32).wrapping_mul(2654435761u32) >> 7 & m
            })
        };
        for i in 0..n {
            write_key(&mut keys, bits, i, &key(i));
        }
        let kr = Packed { bits };
        for i in 0..n - 1 {
            let p = kr.pair(&keys, i);
            assert_eq!(&p[..6], &key(i)[..]);
            assert_eq!(&p[6..], &key(i + 1)[..]);
            if bits == 8 {
                assert_eq!(Bytes8.pair(&keys, i), p);
            }
        }
    }
}
