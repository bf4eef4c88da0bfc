//! End to end on a generated convex scene and (when present) a real one: primary, shadow and
//! random rays through a built BVH agree with brute force, and shadow rays show no self-shadowing.
use bvhlab_builders::{binned_sah, TopDownConfig};
use bvhlab_geom::{load_scene, Scene};
use bvhlab_trace::{brute_force, primary_rays, random_rays, shadow_rays, trace, Camera};

fn check_scene(
    scene: &Scene,
    side: u32,
) -> (
    f64,
    Vec<bvhlab_trace::Ray>,
    Vec<bvhlab_trace::Hit>,
    Vec<bvhlab_trace::Ray>,
) {
    let (boxes, centers) = scene.boxes_and_centers();
    let bvh = binned_sah::build(&boxes, &centers, 16, &TopDownConfig::default());
    let b = scene.bounds();
    let cam = Camera::from_bounds(&b);
    let prim = primary_rays(&cam, side, side);
    let s = trace(&bvh, &scene.triangles, &prim);
    assert_eq!(s.hits, brute_force(&scene.triangles, &prim));
    let ts: Vec<f32> = s.hits.iter().map(|h| h.t).collect();
    let sh = shadow_rays(&prim, &ts, cam.light(&b));
    assert_eq!(sh.len() as u64, s.hit_count);
    let ss = trace(&bvh, &scene.triangles, &sh);
    assert_eq!(ss.hits, brute_force(&scene.triangles, &sh));
    let r = centers
        .iter()
        .map(|c| (*c - b.center()).length())
        .fold(0.0, f32::max);
    let rnd = random_rays(&b, r, 2000, 5);
    let rs = trace(&bvh, &scene.triangles, &rnd);
    assert_eq!(rs.hits, brute_force(&scene.triangles, &rnd));
    (s.hit_count as f64 / prim.len() as f64, prim, s.hits, sh)
}

#[test]
fn convex_sphere_lit_side_is_unshadowed_and_dark_side_shadowed() {
    let scene = load_scene("gen:sphere:n=5000").unwrap();
    let b = scene.bounds();
    let c = b.center();
    let (boxes, centers) = scene.boxes_and_centers();
    let bvh = binned_sah::build(&boxes, &centers, 16, &TopDownConfig::default());
    let (rate, prim, hits, sh) = check_scene(&scene, 48);
    assert!(
        rate > 0.2,
        "camera should frame the sphere, hit rate {rate}"
    );
    let light = Camera::from_bounds(&b).light(&b);
    let ss = trace(&bvh, &scene.triangles, &sh);
    let (mut lit, mut dark) = (0, 0);
    let mut k = 0;
    for (p, h) in prim.iter().zip(&hits) {
        if !h.is_hit() {
            continue;
        }
        let x = p.origin + p.dir * h.t;
        let n = (x - c).normalize();
        let cos = n.dot((light - x).normalize());
        let blocked = ss.hits[k].is_hit();
        k += 1;
        // Convex: a point facing the light sees it; one facing away is behind its own surface.
        // Skip the terminator band, where facets and the ideal sphere disagree.
        if cos > 0.1 {
            assert!(!blocked, "lit point {x} self-shadowed (cos {cos})");
            lit += 1;
        } else if cos < -0.1 {
            assert!(
                blocked,
                "point {x} facing away from the light is unshadowed (cos {cos})"
            );
            dark += 1;
        }
    }
    assert!(lit > 100, "lit {lit}");
    let _ = dark; // the light sits above the camera, so few visible points face away from it
}

#[test]
fn real_scene_when_available() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../../shared/scenes/stanford_bunny.obj.gz"
    );
    if !std::path::Path::new(path).exists() {
        eprintln!("skipped: {path} not present");
        return;
    }
    let scene = load_scene(path).unwrap();
    let (rate, ..) = check_scene(&scene, 24);
    assert!(rate > 0.1, "camera should frame the bunny, hit rate {rate}");
}
