//! Ray generation: deterministic and geometrically right.
mod common;
use bvhlab_geom::{Aabb, Vec3};
use bvhlab_trace::{primary_rays, random_rays, shadow_rays, Camera, Ray};

fn scene_box() -> Aabb {
    Aabb::new(Vec3::new(-3.0, 1.0, 10.0), Vec3::new(5.0, 2.0, 14.0))
}

#[test]
fn camera_frames_the_box() {
    let b = scene_box();
    let cam = Camera::from_bounds(&b);
    assert_eq!(cam.target, b.center());
    assert!((cam.fov_y_deg - 50.0).abs() < 1e-6);
    let fwd = (cam.target - cam.eye).normalize();
    assert!(cam.up.normalize().dot(fwd).abs() < 0.99);
    // Every box corner projects inside the vertical and horizontal half-angle (square image).
    let right = fwd.cross(cam.up).normalize();
    let up = right.cross(fwd);
    let tan_half = (cam.fov_y_deg.to_radians() * 0.5).tan();
    for i in 0..8 {
        let p = Vec3::new(
            if i & 1 == 0 { b.min.x } else { b.max.x },
            if i & 2 == 0 { b.min.y } else { b.max.y },
            if i & 4 == 0 { b.min.z } else { b.max.z },
        );
        let v = p - cam.eye;
        let z = v.dot(fwd);
        assert!(z > 0.0);
        assert!(
            (v.dot(right) / z).abs() <= tan_half,
            "corner {p} outside horizontally"
        );
        assert!(
            (v.dot(up) / z).abs() <= tan_half,
            "corner {p} outside vertically"
        );
    }
    // Light: above the camera by the scene radius.
    let l = cam.light(&b);
    let r = 0.5 * b.extent().length();
    assert!(((l - cam.eye).length() - r).abs() < 1e-4 * r);
    assert!((l - cam.eye).normalize().dot(Vec3::Y) > 0.99);
}

#[test]
fn degenerate_bounds_give_usable_cameras() {
    let flat_y = Aabb::new(Vec3::new(0.0, 1.0, 0.0), Vec3::new(4.0, 1.0, 4.0));
    let cam = Camera::from_bounds(&flat_y);
    let fwd = (cam.target - cam.eye).normalize();
    assert_ne!(cam.up, Vec3::Y, "flat-in-Y scene picks another up");
    assert!(cam.up.dot(fwd).abs() < 0.99);
    for b in [
        Aabb::EMPTY,
        Aabb::from_point(Vec3::ONE),
        Aabb::new(Vec3::ZERO, Vec3::new(0.0, 0.0, 3.0)),
    ] {
        let cam = Camera::from_bounds(&b);
        assert!(cam.eye.is_finite() && cam.target.is_finite() && cam.eye != cam.target);
        let rays = primary_rays(&cam, 4, 3);
        assert!(rays
            .iter()
            .all(|r| r.dir.is_finite() && (r.dir.length() - 1.0).abs() < 1e-5));
        assert!(cam.light(&b).is_finite());
    }
}

#[test]
fn primary_rays_row_major_from_top_left() {
    let cam = Camera::from_bounds(&scene_box());
    let (w, h) = (9u32, 5u32);
    let rays = primary_rays(&cam, w, h);
    assert_eq!(rays.len(), 45);
    let fwd = (cam.target - cam.eye).normalize();
    // The centre pixel (odd sizes) looks straight at the box centre.
    let c = rays[(2 * w + 4) as usize];
    assert!(
        c.dir.dot(fwd) > 1.0 - 1e-6,
        "centre ray {:?} vs {fwd}",
        c.dir
    );
    assert!(rays
        .iter()
        .all(|r| r.origin == cam.eye && (r.dir.length() - 1.0).abs() < 1e-5));
    let right = fwd.cross(cam.up).normalize();
    let up = right.cross(fwd);
    let tl = rays[0].dir;
    let br = rays[(w * h - 1) as usize].dir;
    assert!(
        tl.dot(up) > 0.0 && tl.dot(right) < 0.0,
        "first ray is top-left"
    );
    assert!(
        br.dot(up) < 0.0 && br.dot(right) > 0.0,
        "last ray is bottom-right"
    );
    // Second ray is to the right of the first in the same row.
    assert!(rays[1].dir.dot(right) > tl.dot(right));
    // Same image-plane height in one row (compare before normalization: dot(up) / dot(fwd)).
    let v = |d: Vec3| d.dot(up) / d.dot(fwd);
    assert!((v(rays[1].dir) - v(tl)).abs() < 1e-5);
    // Aspect = w / h: the horizontal half-angle at pixel centres exceeds the vertical one.
    let hx = tl.dot(right).abs() / tl.dot(fwd);
    let hy = tl.dot(up).abs() / tl.dot(fwd);
    let tan_half = (cam.fov_y_deg.to_radians() * 0.5).tan();
    assert!((hy - tan_half * (1.0 - 1.0 / h as f32)).abs() < 1e-4);
    assert!((hx - tan_half * (w as f32 / h as f32) * (1.0 - 1.0 / w as f32)).abs() < 1e-4);
    assert!(primary_rays(&cam, 0, 10).is_empty());
}

#[test]
fn shadow_rays_point_at_the_light() {
    let cam = Camera::from_bounds(&scene_box());
    let light = cam.light(&scene_box());
    let prim = primary_rays(&cam, 6, 4);
    let ts: Vec<f32> = (0..prim.len())
        .map(|i| {
            if i % 3 == 0 {
                f32::INFINITY
            } else {
                5.0 + i as f32
            }
        })
        .collect();
    let sh = shadow_rays(&prim, &ts, light);
    assert_eq!(sh.len(), prim.len() - prim.len().div_ceil(3));
    let mut k = 0;
    for (i, p) in prim.iter().enumerate() {
        if i % 3 == 0 {
            continue;
        }
        let s = sh[k];
        k += 1;
        let hit = p.origin + p.dir * ts[i];
        // Origin nudged back toward the camera, by a small amount.
        let off = s.origin - hit;
        assert!(off.dot(p.dir) < 0.0);
        assert!(off.length() < 1e-3 * (light - hit).length());
        assert!((s.dir.length() - 1.0).abs() < 1e-5);
        let end = s.origin + s.dir * s.tmax;
        let d = (light - s.origin).length();
        assert!(s.tmax < d && s.tmax > d * (1.0 - 1e-3));
        assert!((end - light).length() < 1e-3 * d);
    }
}

#[test]
fn random_rays_lie_on_the_sphere_and_are_deterministic() {
    let b = scene_box();
    let r = 4.2f32;
    let a = random_rays(&b, r, 5000, 42);
    assert_eq!(a, random_rays(&b, r, 5000, 42));
    assert_ne!(a, random_rays(&b, r, 5000, 43));
    // Prefixes agree: ray i does not depend on the count.
    assert_eq!(&a[..100], &random_rays(&b, r, 100, 42)[..]);
    let c = b.center();
    let mut mean = Vec3::ZERO;
    let mut band = [0u32; 10];
    for ray in &a {
        let p0 = ray.origin;
        let p1 = ray.origin + ray.dir * ray.tmax;
        assert!(((p0 - c).length() - r).abs() < 1e-4 * r * 10.0);
        assert!(((p1 - c).length() - r).abs() < 1e-4 * r * 10.0);
        assert!((ray.dir.length() - 1.0).abs() < 1e-5);
        assert!(ray.tmax > 0.0);
        mean += (p0 - c) / r;
        let z = ((p0 - c).z / r + 1.0) * 0.5;
        band[((z * 10.0) as usize).min(9)] += 1;
    }
    // Uniform on the sphere: mean near the centre, equal-area z bands equally filled.
    mean /= a.len() as f32;
    assert!(mean.length() < 0.05, "mean {mean}");
    assert!(
        band.iter().all(|&n| (450..=550).contains(&n)),
        "bands {band:?}"
    );
    // Degenerate radius falls back to the box sphere instead of looping or producing NaN.
    let d: Vec<Ray> = random_rays(&b, 0.0, 10, 1);
    assert!(d
        .iter()
        .all(|r| r.origin.is_finite() && r.dir.is_finite() && r.tmax > 0.0));
    let e = random_rays(&Aabb::EMPTY, f32::NAN, 10, 1);
    assert!(e.iter().all(|r| r.origin.is_finite() && r.tmax > 0.0));
}
