//! Encoder tests: radix sort against std, determinism across thread counts, Morton/EMC layouts,
//! concise bounds (Riemersma eq. 15), the occupation grid, the far-outlier scene and degenerate input.
use bvhlab_geom::rng::SplitMix64;
use bvhlab_geom::{Aabb, Vec3};
use bvhlab_morton::{
    bounds, encode, encode_cells, morton, radix, AutoFor, Bits, BoundsMode, CellFrame, EncodeConfig, Encoding, Scheme,
};

fn reference_sort(codes: &[u64]) -> (Vec<u64>, Vec<u32>) {
    let mut idx: Vec<u32> = (0..codes.len() as u32).collect();
    idx.sort_by_key(|&i| (codes[i as usize], i));
    (idx.iter().map(|&i| codes[i as usize]).collect(), idx)
}

fn check_radix(codes: Vec<u64>, what: &str) {
    let expect = reference_sort(&codes);
    let got = radix::sort_with_index(codes.clone());
    assert!(got == expect, "radix differs from std sort on {what} (n = {})", codes.len());
    // sort_pairs with explicit values (reversed indices) keeps ties in input order.
    let vals: Vec<u32> = (0..codes.len() as u32).rev().collect();
    let (k, v) = radix::sort_pairs(codes.clone(), vals.clone());
    let mut pos: Vec<usize> = (0..codes.len()).collect();
    pos.sort_by_key(|&i| (codes[i], i));
    assert_eq!(k, pos.iter().map(|&i| codes[i]).collect::<Vec<_>>(), "{what}: sort_pairs keys");
    assert_eq!(v, pos.iter().map(|&i| vals[i]).collect::<Vec<_>>(), "{what}: sort_pairs values");
}

fn random_codes(n: usize, seed: u64, mask: u64) -> Vec<u64> {
    let mut r = SplitMix64::new(seed);
    (0..n).map(|_| r.next_u64() & mask).collect()
}

#[test]
fn radix_matches_std_sort() {
    // Sizes cover the sequential path, the MSD + in-cache LSD path and the big-bucket path.
    for &n in &[0usize, 1, 2, 3, 100, 5000, 40_000, 300_000] {
        check_radix(random_codes(n, n as u64, u64::MAX), "random 64-bit");
        check_radix(random_codes(n, 7, (1 << 30) - 1), "random 30-bit");
        // Many ties: only 16 distinct values, so stability decides most of the order.
        check_radix(random_codes(n, 9, 0xf000_0000_0000_000f), "16 distinct values");
        check_radix(vec![42; n], "all equal");
        let sorted: Vec<u64> = (0..n as u64).map(|i| i * 3).collect();
        check_radix(sorted.clone(), "already sorted");
        check_radix(sorted.into_iter().rev().collect(), "reverse sorted");
    }
    // One huge outlier and a dense cluster: nearly everything lands in one first-pass bucket.
    let mut skew = random_codes(300_000, 3, (1 << 40) - 1);
    skew[123] = u64::MAX;
    skew[7] = 1 << 63;
    check_radix(skew, "dense cluster + outliers");
}

#[test]
fn radix_deterministic_across_threads() {
    let codes = random_codes(200_000, 11, 0x0000_ffff_0000_ffff);
    let run = |t: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(t)
            .build()
            .unwrap()
            .install(|| radix::sort_with_index(codes.clone()))
    };
    let one = run(1);
    assert_eq!(one, run(2));
    assert_eq!(one, run(3));
}

/// A small clustered scene: random triangles' boxes in a few clumps plus some spread.
fn scene(n: usize, seed: u64) -> (Vec<Aabb>, Vec<Vec3>) {
    let mut r = SplitMix64::new(seed);
    let mut boxes = Vec::with_capacity(n);
    for i in 0..n {
        let c = if i % 3 == 0 {
            Vec3::new(r.f32() * 100.0, r.f32() * 20.0, r.f32() * 5.0)
        } else {
            Vec3::new(10.0 + r.f32(), 5.0 + r.f32(), 1.0 + r.f32())
        };
        let h = Vec3::new(r.f32(), r.f32(), r.f32()) * 0.05 * (1.0 + 20.0 * (i % 17 == 0) as u32 as f32);
        boxes.push(Aabb::new(c - h, c + h));
    }
    let centers = boxes.iter().map(|b| b.center()).collect();
    (boxes, centers)
}

fn all_configs() -> Vec<EncodeConfig> {
    let mut v = Vec::new();
    for scheme in [Scheme::Morton, Scheme::Emc64Sort, Scheme::Emc64Var] {
        for bounds in [BoundsMode::Scene, BoundsMode::Centroids, BoundsMode::Concise] {
            for grid_bits in [0, 6, 7, 9, 12] {
                for bits in [Bits::Fixed(10), Bits::Fixed(21), Bits::Auto(AutoFor::Aac), Bits::Fixed(1)] {
                    if scheme != Scheme::Morton && bits != Bits::Fixed(10) {
                        continue;
                    }
                    v.push(EncodeConfig { scheme, bits, bounds, grid_bits });
                }
            }
        }
    }
    v
}

fn check_valid(enc: &Encoding, n: usize, what: &str) {
    assert_eq!(enc.order.len(), n, "{what}");
    assert_eq!(enc.codes.len(), n, "{what}");
    let mut seen = vec![false; n];
    for &i in &enc.order {
        assert!(!seen[i as usize], "{what}: primitive {i} twice");
        seen[i as usize] = true;
    }
    for w in 0..n.saturating_sub(1) {
        let (a, b) = (enc.codes[w], enc.codes[w + 1]);
        assert!(a < b || (a == b && enc.order[w] < enc.order[w + 1]), "{what}: not sorted by (code, index) at {w}");
    }
    assert!((1..=64).contains(&enc.code_bits), "{what}: code_bits {}", enc.code_bits);
    if enc.code_bits < 64 {
        assert!(enc.codes.iter().all(|&c| c >> enc.code_bits == 0), "{what}: code wider than code_bits");
    }
    assert_eq!(enc.layout.chars().count(), enc.code_bits as usize, "{what}: layout {}", enc.layout);
}

#[test]
fn encodings_valid_and_deterministic_across_threads() {
    let (boxes, centers) = scene(3000, 5);
    for cfg in all_configs() {
        let run = |t: usize| {
            rayon::ThreadPoolBuilder::new().num_threads(t).build().unwrap().install(|| encode(&boxes, &centers, &cfg))
        };
        let one = run(1);
        check_valid(&one, boxes.len(), &format!("{cfg:?}"));
        assert!(one == run(2), "{cfg:?}: 1 vs 2 threads");
        // Enough bits keep the clustered scene's primitives apart.
        if cfg.bits == Bits::Fixed(21) || cfg.scheme == Scheme::Emc64Var {
            assert!(one.duplicate_fraction() < 0.05, "{cfg:?}: {}", one.duplicate_fraction());
        }
        if cfg.grid_bits > 0 {
            let tight = |t: usize| {
                rayon::ThreadPoolBuilder::new()
                    .num_threads(t)
                    .build()
                    .unwrap()
                    .install(|| encode_cells(&boxes, &centers, &cfg, CellFrame::Tight))
            };
            let one = tight(1);
            check_valid(&one, boxes.len(), &format!("tight {cfg:?}"));
            assert!(one == tight(2), "tight {cfg:?}: 1 vs 2 threads");
        }
    }
}

#[test]
fn morton_order_is_the_quantized_interleave() {
    // bits = 2: a 4x4x4 lattice over [0,4]^3; centroids at cell centres, one primitive per cell.
    let mut boxes = Vec::new();
    let mut cells = Vec::new();
    let mut r = SplitMix64::new(1);
    for _ in 0..64 {
        let (x, y, z) = (r.below(4), r.below(4), r.below(4));
        let c = Vec3::new(x as f32 + 0.5, y as f32 + 0.5, z as f32 + 0.5);
        boxes.push(Aabb::new(c - 0.25, c + 0.25));
        cells.push((x, y, z));
    }
    // Pin the frame to [0,4]^3.
    boxes.push(Aabb::new(Vec3::ZERO, Vec3::ZERO));
    cells.push((0, 0, 0));
    boxes.push(Aabb::new(Vec3::splat(4.0), Vec3::splat(4.0)));
    cells.push((3, 3, 3));
    let centers: Vec<Vec3> = boxes.iter().map(|b| b.center()).collect();
    let cfg = EncodeConfig { bits: Bits::Fixed(2), ..Default::default() };
    let enc = encode(&boxes, &centers, &cfg);
    assert_eq!(enc.code_bits, 6);
    assert_eq!(enc.layout, "xyzxyz");
    for (k, &i) in enc.order.iter().enumerate() {
        let (x, y, z) = cells[i as usize];
        // x1 y1 z1 x0 y0 z0 by hand.
        let expect = ((x >> 1) << 5) | ((y >> 1) << 4) | ((z >> 1) << 3) | ((x & 1) << 2) | ((y & 1) << 1) | (z & 1);
        assert_eq!(enc.codes[k], expect, "primitive {i} in cell {:?}", cells[i as usize]);
    }
    assert_eq!(morton::interleave(0b10, 0b01, 0b11), 0b101_011);
}

#[test]
fn emc_layouts_put_size_bits_where_the_thesis_says() {
    let (boxes, centers) = scene(500, 2); // extents: x ~100 > y ~20 > z ~5
    let sort = encode(&boxes, &centers, &EncodeConfig { scheme: Scheme::Emc64Sort, ..Default::default() });
    assert_eq!(sort.code_bits, 64);
    assert_eq!(sort.layout, "xyzs".repeat(16));
    let var = encode(&boxes, &centers, &EncodeConfig { scheme: Scheme::Emc64Var, ..Default::default() });
    assert_eq!(var.code_bits, 64);
    for (i, ch) in var.layout.chars().enumerate() {
        assert_eq!(ch == 's', (i + 1) % 7 == 0, "EMC-64-var size bit positions: {}", var.layout);
    }
    // The halving box: x (100) takes the first bits until it is below y (20): 100, 50, 25 -> x x x,
    // then 12.5 < 20 -> y. So the layout starts "xxxy".
    assert!(var.layout.starts_with("xxxy"), "{}", var.layout);
    // Per-axis counts follow the scene's shape: x gets the most bits, z the fewest.
    let count = |c| var.layout.chars().filter(|&x| x == c).count();
    assert!(count('x') > count('y') && count('y') > count('z'), "{}", var.layout);
    assert_eq!(count('s'), 9);

    // EMC-64-sort orders the axes by extent: a scene long in z, then x, then y.
    let yzx = |v: Vec3| Vec3::new(v.y, v.z, v.x);
    let swizzled: Vec<Aabb> = boxes.iter().map(|b| Aabb::new(yzx(b.min), yzx(b.max))).collect();
    let sc: Vec<Vec3> = swizzled.iter().map(|b| b.center()).collect();
    let sort = encode(&swizzled, &sc, &EncodeConfig { scheme: Scheme::Emc64Sort, ..Default::default() });
    assert!(sort.layout.starts_with("zxyszxys"), "{}", sort.layout);

    // The size bit separates small from large primitives at the same place.
    let small = Aabb::new(Vec3::splat(0.49), Vec3::splat(0.51));
    let big = Aabb::new(Vec3::splat(0.0), Vec3::splat(1.0));
    let b = [small, big, small];
    let c = [Vec3::splat(0.5); 3];
    let e = encode(&b, &c, &EncodeConfig { scheme: Scheme::Emc64Sort, ..Default::default() });
    assert_eq!(e.order, vec![0, 2, 1], "the big primitive sorts after the small ones");
    assert_eq!(e.codes[0], e.codes[1]);
}

#[test]
fn concise_bounds_eq15() {
    let a = Aabb::new(Vec3::new(0.0, 0.0, 0.0), Vec3::new(2.0, 2.0, 2.0)); // centre (1, 1, 1)
    let b = Aabb::new(Vec3::new(6.0, 3.0, 3.0), Vec3::new(10.0, 4.0, 4.0)); // centre (8, 3.5, 3.5)
    let boxes = [a, b];
    let centers = [a.center(), b.center()];
    // bounds (0,0,0)-(10,4,4); centroids (1,1,1)-(8,3.5,3.5);
    // difference = min((1,1,1), (2,0.5,0.5)) = (1, 0.5, 0.5).
    let expect = Aabb::new(Vec3::new(1.0, 0.5, 0.5), Vec3::new(9.0, 3.5, 3.5));
    let got = bounds::frame(&boxes, &centers, BoundsMode::Concise);
    assert_eq!(got, expect);
    let enc = encode(&boxes, &centers, &EncodeConfig { bounds: BoundsMode::Concise, ..Default::default() });
    assert_eq!(enc.frame, expect);
    assert_eq!(bounds::frame(&boxes, &centers, BoundsMode::Scene), Aabb::new(Vec3::ZERO, Vec3::new(10.0, 4.0, 4.0)));
    assert_eq!(bounds::frame(&boxes, &centers, BoundsMode::Centroids), Aabb::new(Vec3::ONE, Vec3::new(8.0, 3.5, 3.5)));
}

#[test]
fn grid_keeps_cell_order_and_is_prefix_free() {
    // With the grid, primitives must still come in the order of their plain b-bit cell codes
    // (the concise index only drops splits), and inside a cell by the in-cell code.
    let (boxes, centers) = scene(4000, 3);
    for grid_bits in [3, 6, 7, 9, 12] {
        let cfg = EncodeConfig { bits: Bits::Fixed(21), grid_bits, ..Default::default() };
        let enc = encode(&boxes, &centers, &cfg);
        check_valid(&enc, boxes.len(), &format!("grid {grid_bits}"));
        let frame = bounds::Frame::new(&enc.frame);
        // Plain Morton cell code with grid_bits bits (top bits of a 21-bit-per-axis code).
        let cell = |i: u32| morton::code(frame.normalize(centers[i as usize]), 21) >> (63 - grid_bits);
        let cells: Vec<u64> = enc.order.iter().map(|&i| cell(i)).collect();
        assert!(cells.windows(2).all(|w| w[0] <= w[1]), "grid {grid_bits}: cells out of curve order");
        // Different cells never share a code (prefix-freeness keeps them apart).
        for w in 0..cells.len() - 1 {
            if cells[w] != cells[w + 1] {
                assert_ne!(enc.codes[w], enc.codes[w + 1], "grid {grid_bits}: two cells, one code");
            }
        }
        assert!(enc.layout.starts_with('g') && enc.layout.matches('g').count() <= grid_bits as usize);
    }
}

fn dup(spec: &str, cfg: EncodeConfig) -> f64 {
    dup_cells(spec, cfg, CellFrame::Lattice)
}

fn dup_cells(spec: &str, cfg: EncodeConfig, cf: CellFrame) -> f64 {
    let scene = bvhlab_geom::load_scene(spec).unwrap();
    let (boxes, centers) = scene.boxes_and_centers();
    encode_cells(&boxes, &centers, &cfg, cf).duplicate_fraction()
}

#[test]
fn outlier_duplicates() {
    let m = |bits, grid_bits| EncodeConfig { bits: Bits::Fixed(bits), grid_bits, ..Default::default() };
    let spec = "gen:outlier:n=5000,e=20";
    let plain30 = dup(spec, m(10, 0));
    let plain63 = dup(spec, m(21, 0));
    let grid63 = dup(spec, m(21, 12));
    // Plain 30-bit Morton: the whole sphere in a handful of cells.
    assert!(plain30 > 0.99, "plain 30-bit {plain30}");
    // Even 63 bits leave the sphere a few cells at 2^20 object sizes...
    assert!(plain63 > 0.9, "plain 63-bit {plain63}");
    // ... and the grid (concise index of 1 bit + in-cell code in a cell 2^4 smaller per axis)
    // gives it about 7.7 bits per axis back.
    assert!(grid63 < plain63 - 0.2, "grid12 {grid63} vs plain {plain63}");
    let grid30 = dup(spec, m(10, 12));
    assert!(grid30 <= plain30);
    // The tight-cell extension gives the sphere the whole in-cell code, even with 30 bits.
    let tight30 = dup_cells(spec, m(10, 6), CellFrame::Tight);
    assert!(tight30 < 0.1, "tight grid6 30-bit {tight30}");
    // At e = 10 the grid helps even the 30-bit code.
    let spec = "gen:outlier:n=5000,e=10";
    let (p, g) = (dup(spec, m(10, 0)), dup(spec, m(10, 12)));
    assert!(g < p - 0.05, "e=10: grid12 {g} vs plain {p}");
}

#[test]
fn degenerate_inputs() {
    let cfgs = all_configs();
    let p = Vec3::new(1.0, 2.0, 3.0);
    let mut cases: Vec<(&str, Vec<Aabb>)> = vec![
        ("empty", vec![]),
        ("one", vec![Aabb::new(p, p + 1.0)]),
        ("all centroids equal", vec![Aabb::new(p - 1.0, p + 1.0), Aabb::new(p - 2.0, p + 2.0), Aabb::from_point(p)]),
        (
            "huge coordinates",
            vec![
                Aabb::new(Vec3::splat(-1e30), Vec3::splat(-1e30 + 1e24)),
                Aabb::from_point(Vec3::splat(1e30)),
                Aabb::from_point(Vec3::ZERO),
            ],
        ),
        ("zero-extent axis", (0..50).map(|i| Aabb::from_point(Vec3::new(i as f32, 0.5 * i as f32, 7.0))).collect()),
        (
            "max floats",
            vec![
                Aabb::from_point(Vec3::splat(f32::MAX)),
                Aabb::from_point(Vec3::splat(-f32::MAX)),
                Aabb::from_point(Vec3::ONE),
            ],
        ),
        ("empty box", vec![Aabb::EMPTY, Aabb::from_point(p)]),
    ];
    cases.push(("coincident many", vec![Aabb::from_point(p); 1000]));
    for (what, boxes) in cases {
        let centers: Vec<Vec3> = boxes.iter().map(|b| if b.is_empty() { p } else { b.center() }).collect();
        for cfg in &cfgs {
            let enc = encode(&boxes, &centers, cfg);
            check_valid(&enc, boxes.len(), &format!("{what} {cfg:?}"));
        }
    }
    // Distinct points on a line with a flat z axis still get distinct codes.
    let boxes: Vec<Aabb> = (0..50).map(|i| Aabb::from_point(Vec3::new(i as f32, 0.5 * i as f32, 7.0))).collect();
    let centers: Vec<Vec3> = boxes.iter().map(|b| b.center()).collect();
    for scheme in [Scheme::Morton, Scheme::Emc64Var] {
        let enc = encode(&boxes, &centers, &EncodeConfig { scheme, ..Default::default() });
        assert_eq!(enc.duplicate_fraction(), 0.0, "{scheme:?}");
        assert_eq!(enc.order, (0..50).collect::<Vec<u32>>(), "{scheme:?}: points on a line sort along it");
    }
}

#[test]
fn codes_match_an_independent_computation() {
    let (boxes, centers) = scene(2000, 8);
    // Plain Morton: codes[k] is the interleave of the quantized centroid of order[k].
    for bits in [1u32, 3, 10, 21] {
        let enc = encode(&boxes, &centers, &EncodeConfig { bits: Bits::Fixed(bits), ..Default::default() });
        let frame = bounds::Frame::new(&enc.frame);
        for (k, &i) in enc.order.iter().enumerate() {
            let u = frame.normalize(centers[i as usize]);
            let q = u.map(|x| morton::quantize(x, bits));
            let mut expect = 0u64;
            for b in (0..bits).rev() {
                expect = (expect << 3) | ((q[0] >> b) & 1) << 2 | ((q[1] >> b) & 1) << 1 | ((q[2] >> b) & 1);
            }
            assert_eq!(enc.codes[k], expect, "bits {bits}, primitive {i}");
        }
    }
    // EMC: reading the code back along the layout string gives each quantized value.
    for scheme in [Scheme::Emc64Sort, Scheme::Emc64Var] {
        let enc = encode(&boxes, &centers, &EncodeConfig { scheme, ..Default::default() });
        let frame = bounds::Frame::new(&enc.frame);
        let letters: Vec<usize> = enc.layout.chars().map(|c| "xyzs".find(c).unwrap()).collect();
        let mut counts = [0u32; 4];
        letters.iter().for_each(|&l| counts[l] += 1);
        for (k, &i) in enc.order.iter().enumerate() {
            let mut got = [0u64; 4];
            for (p, &l) in letters.iter().enumerate() {
                got[l] = (got[l] << 1) | (enc.codes[k] >> (63 - p)) & 1;
            }
            let u = frame.normalize(centers[i as usize]);
            let s = bounds::size(&boxes[i as usize], frame.diag);
            let expect = [
                morton::quantize(u[0], counts[0]),
                morton::quantize(u[1], counts[1]),
                morton::quantize(u[2], counts[2]),
                morton::quantize(s, counts[3]),
            ];
            assert_eq!(got, expect, "{scheme:?} primitive {i} layout {}", enc.layout);
        }
    }
}
