//! Generated scenes: deterministic, requested size, finite, parameters honoured, bad specs rejected.
use bvhlab_geom::gen::{canonical_spec, generate, generators};
use bvhlab_geom::load_scene;

fn all_names() -> Vec<&'static str> {
    generators().iter().map(|g| g.name).collect()
}

#[test]
fn required_generators_exist_and_are_documented() {
    let names = all_names();
    for n in [
        "sphere",
        "terrain",
        "hairball",
        "city",
        "outlier",
        "degenerate",
        "huge-edge",
        "flat",
        "slivers",
        "dups",
        "same-centroid",
        "scale",
        "nonfinite",
        "single",
        "staircase",
    ] {
        assert!(names.contains(&n), "{n} missing from {names:?}");
    }
    for g in generators() {
        assert!(!g.about.is_empty());
        assert!(!g.params.is_empty());
        for (k, default, meaning) in g.params {
            assert!(!meaning.is_empty(), "{}:{k}", g.name);
            // Every documented default is accepted when given explicitly.
            generate(&format!("{}:{k}={default}", g.name)).unwrap();
        }
    }
}

#[test]
fn deterministic_and_finite() {
    for name in all_names() {
        let spec = format!("gen:{name}");
        let a = load_scene(&spec).unwrap();
        let b = load_scene(&spec).unwrap();
        assert!(!a.triangles.is_empty(), "{name}");
        // Only the non-finite stress scene has anything to drop.
        if name != "nonfinite" {
            assert_eq!(a.dropped_triangles, 0, "{name}");
        }
        assert!(a.triangles.iter().all(|t| t.is_finite()), "{name}");
        // Bit-identical, not merely approximately equal.
        let bits = |s: &bvhlab_geom::Scene| -> Vec<u32> {
            s.triangles
                .iter()
                .flat_map(|t| t.v.iter().flat_map(|v| v.to_array().map(f32::to_bits)))
                .collect()
        };
        assert_eq!(bits(&a), bits(&b), "{name}");
    }
}

#[test]
fn seeds_change_random_scenes() {
    for name in ["terrain", "hairball", "city", "degenerate"] {
        let a = generate(&format!("{name}:seed=1")).unwrap();
        let b = generate(&format!("{name}:seed=2")).unwrap();
        assert_eq!(a.triangles.len(), b.triangles.len());
        assert_ne!(a.triangles, b.triangles, "{name}");
    }
}

#[test]
fn requested_sizes() {
    for n in [100u64, 5_000, 30_000] {
        for name in ["sphere", "terrain", "hairball", "degenerate"] {
            let got = generate(&format!("{name}:n={n}")).unwrap().triangles.len() as f64;
            let rel = (got - n as f64).abs() / n as f64;
            assert!(rel < 0.15, "{name} n={n}: got {got}");
        }
        for name in ["hairball", "degenerate"] {
            assert_eq!(
                generate(&format!("{name}:n={n}")).unwrap().triangles.len() as u64,
                n
            );
        }
        // outlier = sphere + exactly one triangle.
        let s = generate(&format!("sphere:n={n}")).unwrap().triangles.len();
        let o = generate(&format!("outlier:n={n}")).unwrap().triangles.len();
        assert_eq!(o, s + 1);
    }
    for b in [1u64, 7, 20] {
        let c = generate(&format!("city:blocks={b}")).unwrap();
        assert_eq!(c.triangles.len() as u64, 12 * b * b + 2);
    }
}

#[test]
fn sphere_is_a_unit_sphere() {
    let s = generate("sphere:n=3000").unwrap();
    for t in &s.triangles {
        for v in t.v {
            assert!((v.length() - 1.0).abs() < 1e-6, "{v}");
        }
        assert!(t.area() > 0.0);
    }
    let area: f32 = s.triangles.iter().map(|t| t.area()).sum();
    let exact = 4.0 * std::f32::consts::PI;
    assert!(area < exact && area > 0.95 * exact, "{area}");
}

#[test]
fn terrain_is_flat_and_height_scales() {
    let s = generate("terrain:n=5000,h=0.05").unwrap();
    let e = s.bounds().extent();
    assert!(e.x > 0.99 && e.z > 0.99 && e.y > 0.0 && e.y <= 0.1, "{e}");
    let flat = generate("terrain:n=5000,h=0").unwrap();
    assert_eq!(flat.bounds().extent().y, 0.0);
    let tall = generate("terrain:n=5000,h=0.5").unwrap();
    assert!(tall.bounds().extent().y > 5.0 * e.y);
}

#[test]
fn hairball_is_long_and_thin_inside_the_unit_cube() {
    let s = generate("hairball:n=2000,width=0.001").unwrap();
    let b = s.bounds();
    assert!(b.min.min_element() >= 0.0 && b.max.max_element() <= 1.0);
    let (mut long, mut thin) = (0, 0);
    for t in &s.triangles {
        let l = (t.v[1] - t.v[0]).length();
        long += (l > 0.3) as usize;
        // area = base * height / 2, height <= width
        thin += (t.area() <= 0.5 * l * 0.001 * 1.001 + 1e-9) as usize;
    }
    assert!(long > 1500, "{long}");
    assert_eq!(thin, 2000);
}

#[test]
fn city_ground_is_far_larger_than_buildings() {
    let s = generate("city:blocks=10,ground=100").unwrap();
    let ground = s.triangles[0].bounds().union(&s.triangles[1].bounds());
    assert!((ground.extent().x - 1000.0).abs() < 1e-3, "{ground:?}");
    let biggest = s.triangles[2..]
        .iter()
        .map(|t| t.bounds().extent().max_element())
        .fold(0.0, f32::max);
    assert!(biggest <= 4.0 && ground.extent().x / biggest >= 250.0);
    // Buildings stand inside the ground, on or above it.
    for t in &s.triangles[2..] {
        assert!(ground.min.x <= t.bounds().min.x && t.bounds().max.x <= ground.max.x);
        assert!(t.bounds().min.y >= 0.0);
    }
}

#[test]
fn outlier_distance_scales_with_e() {
    let mut prev = 0.0f64;
    for e in [0u64, 5, 10, 20, 40] {
        let s = generate(&format!("outlier:n=2000,e={e}")).unwrap();
        let last = s.triangles.last().unwrap();
        let d = last.v[0].as_dvec3().length();
        let want = 2.0 * 2f64.powi(e as i32);
        assert!((d / want - 1.0).abs() < 1e-5, "e={e}: {d} vs {want}");
        assert!(d > prev);
        prev = d;
        // The rest of the scene is the unit sphere.
        let rest = s.triangles[..s.triangles.len() - 1]
            .iter()
            .fold(bvhlab_geom::Aabb::EMPTY, |b, t| b.union(&t.bounds()));
        assert!(rest.max.max_element() <= 1.0 + 1e-6);
        // The outlier is tiny relative to the object.
        assert!(last.bounds().extent().max_element() <= 0.01 || e > 15);
    }
}

#[test]
fn degenerate_contains_each_kind() {
    let s = generate("degenerate:n=600").unwrap();
    assert_eq!(s.triangles.len(), 600);
    let zero = s.triangles.iter().filter(|t| t.area() == 0.0).count();
    assert!(zero >= 200, "{zero}"); // collinear + points (+ duplicates of those)
    let points = s
        .triangles
        .iter()
        .filter(|t| t.v[0] == t.v[1] && t.v[1] == t.v[2])
        .count();
    assert!(points >= 100);
    let mut dups = 0;
    for (i, t) in s.triangles.iter().enumerate() {
        dups += s.triangles[..i].contains(t) as usize;
    }
    assert!(dups >= 100, "{dups}");
    let flat = s
        .triangles
        .iter()
        .filter(|t| t.bounds().extent().z == 0.0 && t.area() > 0.0)
        .count();
    assert!(flat >= 100, "{flat}");
}

#[test]
fn canonical_spec_fills_defaults_and_sorts() {
    let a = canonical_spec("sphere").unwrap();
    let n = generators()
        .into_iter()
        .find(|g| g.name == "sphere")
        .unwrap()
        .params[0]
        .1;
    assert_eq!(a, format!("sphere:n={n}"));
    assert_eq!(canonical_spec(&format!("sphere:n={n}")).unwrap(), a);
    assert_eq!(canonical_spec(&format!("sphere:n=0{n}")).unwrap(), a);
    let t1 = canonical_spec("terrain:seed=3,h=0.050").unwrap();
    let t2 = canonical_spec("terrain:h=5e-2,seed=3").unwrap();
    assert_eq!(t1, t2);
    let keys: Vec<&str> = t1
        .split_once(':')
        .unwrap()
        .1
        .split(',')
        .map(|kv| kv.split('=').next().unwrap())
        .collect();
    let mut sorted = keys.clone();
    sorted.sort();
    assert_eq!(keys, sorted);
    assert_eq!(keys.len(), 3);
    assert_ne!(
        canonical_spec("terrain:seed=4").unwrap(),
        canonical_spec("terrain:seed=3").unwrap()
    );
    // The canonical spec round-trips and generates the same scene.
    assert_eq!(canonical_spec(&t1).unwrap(), t1);
    assert_eq!(
        generate(&t1).unwrap().triangles,
        generate("terrain:seed=3,h=0.05").unwrap().triangles
    );
}

#[test]
fn bad_specs_are_errors_naming_the_spec_and_choices() {
    let cases: &[(&str, &[&str])] = &[
        ("nope", &["unknown generator", "sphere", "terrain"]),
        ("", &["unknown generator"]),
        ("sphere:m=3", &["unknown parameter", "\"m\"", "n"]),
        ("sphere:n=abc", &["n", "abc"]),
        ("sphere:n=-5", &["n"]),
        ("sphere:n=0", &["out of range"]),
        ("sphere:n=1e99", &["n"]),
        ("terrain:h=nan", &["out of range"]),
        ("terrain:h=inf", &["out of range"]),
        ("terrain:h=-1", &["out of range"]),
        ("outlier:e=1000", &["out of range"]),
        ("sphere:n", &["key=value"]),
        ("sphere:n=5,n=6", &["twice"]),
    ];
    for (spec, needles) in cases {
        let e = generate(spec).unwrap_err();
        assert_eq!(e.line, None);
        assert_eq!(e.file.to_str().unwrap(), format!("gen:{spec}"));
        for n in *needles {
            assert!(e.reason.contains(n), "{spec:?}: {:?} lacks {n:?}", e.reason);
        }
        assert!(canonical_spec(spec).is_err());
        assert!(e.to_string().contains(&format!("gen:{spec}")));
    }
}

#[test]
fn shuffle_permutes_deterministically() {
    let key = |t: &bvhlab_geom::Triangle| {
        let mut v = Vec::new();
        for p in t.v {
            v.extend(p.to_array().map(f32::to_bits));
        }
        v
    };
    for spec in ["outlier:n=2000,e=12", "city:blocks=6"] {
        let a = generate(spec).unwrap().triangles;
        let b = generate(&format!("{spec},shuffle=7")).unwrap().triangles;
        let c = generate(&format!("{spec},shuffle=7")).unwrap().triangles;
        assert_eq!(b, c, "{spec}: same seed, same order");
        assert_ne!(a, b, "{spec}: order changed");
        let mut ka: Vec<_> = a.iter().map(key).collect();
        let mut kb: Vec<_> = b.iter().map(key).collect();
        ka.sort();
        kb.sort();
        assert_eq!(ka, kb, "{spec}: same triangles");
    }
}

#[test]
fn stress_scenes_have_their_property() {
    use bvhlab_geom::Triangle;
    let g = |s: &str| generate(s).unwrap();
    // huge-edge: n small + huge sheets at x >= 1 whose extent dwarfs the content.
    let h = g("huge-edge:n=500,huge=3,size=1000");
    assert_eq!(h.triangles.len(), 503);
    for t in &h.triangles[500..] {
        assert!(t.bounds().min.x >= 1.0 && t.bounds().extent().y >= 2000.0);
    }
    assert!(h.triangles[..500]
        .iter()
        .all(|t| t.bounds().extent().max_element() < 0.05));
    // flat: all z equal.
    let f = g("flat:n=700");
    assert_eq!(f.triangles.len(), 700);
    assert!(f.triangles.iter().all(|t| t.v.iter().all(|v| v.z == 0.5)));
    assert_eq!(f.bounds().extent().z, 0.0);
    // slivers: long, thin, 1 in 8 collinear, all overlapping x = 0.5.
    let s = g("slivers:n=800,width=0.0001");
    assert_eq!(s.triangles.len(), 800);
    for t in &s.triangles {
        let b = t.bounds();
        assert!(b.extent().x > 0.85 && b.min.x <= 0.5 && b.max.x >= 0.5);
    }
    assert!(s.triangles.iter().filter(|t| t.area() == 0.0).count() >= 100);
    // dups: exactly `copies` copies of each distinct triangle, some zero-area.
    let d = g("dups:n=900,copies=9");
    assert_eq!(d.triangles.len(), 900);
    let key = |t: &Triangle| t.v.map(|v| v.to_array().map(f32::to_bits));
    let mut m = std::collections::BTreeMap::new();
    for t in &d.triangles {
        *m.entry(key(t)).or_insert(0) += 1;
    }
    assert!(m.len() <= 100 && m.values().all(|&c| c >= 9), "{}", m.len());
    assert!(d.triangles.iter().filter(|t| t.area() == 0.0).count() >= 200);
    // same-centroid: one box centre exactly, sizes spread over orders of magnitude.
    let c = g("same-centroid:n=500");
    assert!(c
        .triangles
        .iter()
        .all(|t| t.bounds().center() == bvhlab_geom::Vec3::splat(0.5)));
    let sizes: Vec<f32> = c
        .triangles
        .iter()
        .map(|t| t.bounds().extent().max_element())
        .collect();
    let (lo, hi) = sizes
        .iter()
        .fold((f32::MAX, 0f32), |(a, b), &s| (a.min(s), b.max(s)));
    assert!(hi / lo.max(1e-30) > 1e4, "{lo} {hi}");
    // scale: coordinates of magnitude s.
    for (s, lo, hi) in [(1e-30f64, 1e-33f32, 2e-30f32), (1e30, 1e27, 2e30)] {
        let sc = g(&format!("scale:n=300,s={s}"));
        assert_eq!(sc.dropped_triangles, 0);
        let b = sc.bounds();
        assert!(
            b.max.max_element() < hi && b.max.max_element() > lo,
            "{s}: {b:?}"
        );
    }
    // nonfinite: exactly `bad` dropped, the rest kept, every kind present.
    let all_bad = generate("nonfinite:n=10,bad=10").unwrap_err();
    assert!(all_bad.reason.contains("no triangles with finite coordinates"), "{all_bad}");
    for (n, bad) in [(2000u64, 200u64), (10, 9), (10, 0), (7, 3)] {
        let nf = g(&format!("nonfinite:n={n},bad={bad}"));
        assert_eq!(nf.dropped_triangles, bad, "n={n} bad={bad}");
        assert_eq!(nf.triangles.len() as u64, n - bad);
    }
    // single: one triangle.
    assert_eq!(g("single").triangles.len(), 1);
    assert_eq!(g("single:seed=5").triangles.len(), 1);
    // staircase: n steps climbing the diagonal, one triangle each.
    let st = g("staircase:n=1000");
    assert_eq!(st.triangles.len(), 1000);
    for w in st.triangles.windows(2) {
        assert!(w[1].v[0].x > w[0].v[0].x && w[1].v[0].y > w[0].v[0].y);
    }
    assert_eq!(
        canonical_spec("scale:s=1e30").unwrap(),
        "scale:n=2000,s=1e30,seed=1,t=0"
    );
    assert_eq!(canonical_spec("staircase").unwrap(), "staircase:n=100000");
}
