//! Ray sets: primary (pinhole camera), shadow (hit point to a light above the camera), random
//! (pairs of uniform points on the scene's bounding sphere, Havran et al. 2000, thesis 4.4).
use bvhlab_geom::{Aabb, Vec3};
use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Ray {
    pub origin: Vec3,
    pub dir: Vec3,
    /// Closest hits are searched in (0, tmax].
    pub tmax: f32,
}

/// Pinhole camera. `fov_y_deg` is the vertical field of view.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Camera {
    pub eye: Vec3,
    pub target: Vec3,
    pub up: Vec3,
    pub fov_y_deg: f32,
}

/// Default vertical field of view of [`Camera::from_bounds`].
pub const DEFAULT_FOV_Y_DEG: f32 = 50.0;

/// Default viewing direction (from the target towards the eye): front-right-above diagonal, so
/// that all three box dimensions are visible in the image.
const VIEW_FROM: Vec3 = Vec3::new(1.0, 0.6, 1.3);

/// Centre and bounding-sphere radius of a box, with fallbacks so that empty, non-finite or
/// single-point bounds still give a usable camera (radius 1 around the box centre or the origin).
fn centre_radius(bounds: &Aabb) -> (Vec3, f32) {
    if bounds.is_empty() || !bounds.min.is_finite() || !bounds.max.is_finite() {
        return (Vec3::ZERO, 1.0);
    }
    let c = bounds.center();
    // f64: squared f32 extents underflow below 1e-19 and overflow above 1e19 (issue 15).
    let r = (0.5 * bounds.extent_f64().length()) as f32;
    let r = if r.is_finite() && r > 0.0 { r } else { 1.0 };
    (c, r)
}

impl Camera {
    /// Default camera derived from the scene bounds: looks at the centre from the front-diagonal
    /// direction (1, 0.6, 1.3), at the distance where the bounding sphere fits the vertical field of
    /// view ([`DEFAULT_FOV_Y_DEG`]; with images wider than tall it then fits horizontally too).
    /// World up is +Y, unless the scene is flat along Y (then +Z, so that the flat scene is not
    /// framed "edge up"); an up parallel to the view direction is never chosen.
    pub fn from_bounds(bounds: &Aabb) -> Camera {
        let (c, r) = centre_radius(bounds);
        let half = (DEFAULT_FOV_Y_DEG.to_radians() * 0.5).sin();
        let dist = r / half;
        let view = VIEW_FROM.normalize();
        let e = if bounds.is_empty() {
            Vec3::ZERO
        } else {
            bounds.extent()
        };
        let max_e = e.max_element();
        let flat_y = max_e > 0.0 && e.y <= 1e-6 * max_e;
        let mut up = if flat_y { Vec3::Z } else { Vec3::Y };
        for cand in [Vec3::Y, Vec3::Z, Vec3::X] {
            if up.dot(view).abs() < 0.99 {
                break;
            }
            up = cand;
        }
        Camera {
            eye: c + view * dist,
            target: c,
            up,
            fov_y_deg: DEFAULT_FOV_Y_DEG,
        }
    }

    /// Light for shadow rays: above the camera (thesis 4.4), offset by the scene radius along `up`.
    pub fn light(&self, bounds: &Aabb) -> Vec3 {
        let (_, r) = centre_radius(bounds);
        self.eye + self.up.normalize_or(Vec3::Y) * r
    }

    /// Orthonormal camera frame (forward, right, true up); falls back to axis frames when the
    /// camera's vectors are degenerate (eye == target, or up parallel to the view direction).
    fn frame(&self) -> (Vec3, Vec3, Vec3) {
        // Normalized in f64: the f32 squared length of a 1e-30-sized view vector underflows to 0.
        let fwd = (self.target.as_dvec3() - self.eye.as_dvec3())
            .normalize_or(glam::DVec3::NEG_Z)
            .as_vec3();
        let mut right = fwd.cross(self.up).normalize_or_zero();
        if right == Vec3::ZERO {
            let alt = if fwd.y.abs() < 0.9 { Vec3::Y } else { Vec3::Z };
            right = fwd.cross(alt).normalize();
        }
        let up = right.cross(fwd);
        (fwd, right, up)
    }
}

/// `width * height` rays, row-major from the top-left pixel, through pixel centres.
/// Aspect ratio is `width / height`; the vertical extent is set by `fov_y_deg`. Directions are
/// normalized and `tmax` is infinite.
pub fn primary_rays(camera: &Camera, width: u32, height: u32) -> Vec<Ray> {
    if width == 0 || height == 0 {
        return Vec::new();
    }
    let (fwd, right, up) = camera.frame();
    let tan_half = (camera.fov_y_deg.to_radians() * 0.5).tan();
    let aspect = width as f32 / height as f32;
    let mut rays = Vec::with_capacity(width as usize * height as usize);
    for y in 0..height {
        // +1 at the top row, -1 at the bottom row (pixel centres).
        let v = (1.0 - 2.0 * (y as f32 + 0.5) / height as f32) * tan_half;
        for x in 0..width {
            let u = (2.0 * (x as f32 + 0.5) / width as f32 - 1.0) * tan_half * aspect;
            let dir = (fwd + right * u + up * v).normalize();
            rays.push(Ray {
                origin: camera.eye,
                dir,
                tmax: f32::INFINITY,
            });
        }
    }
    rays
}

/// Relative size of the shadow-ray origin offset (see [`shadow_rays`]).
const SHADOW_NUDGE: f32 = 1e-4;

/// For every primary ray that hit (`hit_t` finite), a ray from the hit point (nudged off the
/// surface) to `light`, with tmax just short of the light. Order follows the primary rays.
///
/// The origin is moved back along the primary ray (towards the camera side of the surface) by
/// `1e-4 * |light - p|` (the light is about one scene radius from the camera, so this distance is
/// a scene-scale proxy), and at least `1e-6 * max|p_i|` so that float rounding of coordinates far
/// from the origin cannot put it behind the surface. A surface facing away from the light is then
/// still crossed by its own shadow ray and is correctly in shadow. Direction is normalized;
/// `tmax = |light - origin| * (1 - 1e-4)`. Rays whose hit point or light is non-finite are skipped.
pub fn shadow_rays(primary: &[Ray], hit_t: &[f32], light: Vec3) -> Vec<Ray> {
    let mut out = Vec::new();
    for (r, &t) in primary.iter().zip(hit_t) {
        if !t.is_finite() {
            continue;
        }
        let p = r.origin + r.dir * t;
        let scale = (light - p).as_dvec3().length() as f32;
        let nudge = (SHADOW_NUDGE * scale).max(1e-6 * p.abs().max_element());
        let back = r.dir.normalize_or_zero();
        let origin = p - back * nudge;
        let to_light = light - origin;
        let dist = to_light.as_dvec3().length() as f32;
        if !(dist.is_finite() && dist > 0.0 && origin.is_finite()) {
            continue;
        }
        out.push(Ray {
            origin,
            dir: to_light / dist,
            tmax: dist * (1.0 - 1e-4),
        });
    }
    out
}

use bvhlab_geom::rng::SplitMix64;

/// Number of equal-area latitude bands the sphere is partitioned into (thesis 4.4, "10 bands").
pub const RANDOM_RAY_BANDS: u32 = 10;

/// Uniform point on the unit sphere whose z lies in band `band` of [`RANDOM_RAY_BANDS`].
/// Since z is uniform for area-uniform points on a sphere (Archimedes), equal z-ranges are
/// equal-area bands, and cycling through them stratifies the samples without biasing them.
fn sphere_point(rng: &mut SplitMix64, band: u32) -> Vec3 {
    let nb = RANDOM_RAY_BANDS as f32;
    let z = -1.0 + 2.0 * (band as f32 + rng.f32()) / nb;
    let z = z.clamp(-1.0, 1.0);
    let phi = std::f32::consts::TAU * rng.f32();
    let s = (1.0 - z * z).max(0.0).sqrt();
    Vec3::new(s * phi.cos(), s * phi.sin(), z)
}

/// `count` rays between pairs of uniform points on the bounding sphere centred at the scene box
/// centre with radius enclosing every triangle centroid (thesis 4.4). Deterministic in `seed`.
///
/// Ray `i` goes from `p0` to `p1` (direction normalized, `tmax = |p1 - p0|`). Each ray has its
/// own PRNG stream (SplitMix64 seeded from `seed` and `i`), so ray `i` does not depend on `count`.
/// Stratification: the thesis used "10 bands partitioning the bounding sphere" with Havran's code,
/// which we do not have; our reading is 10 equal-area latitude bands (equal z ranges), with `p0`
/// in band `i mod 10` and `p1` in band `(i / 10) mod 10`, so every band pair is covered evenly.
/// Pairs closer than `1e-4 * radius` are redrawn (deterministically, from the same stream).
/// Generation is sequential; it is cheap next to tracing.
/// A non-positive or non-finite `centroid_radius` falls back to the box's bounding-sphere radius.
pub fn random_rays(bounds: &Aabb, centroid_radius: f32, count: usize, seed: u64) -> Vec<Ray> {
    let (c, box_r) = centre_radius(bounds);
    let r = if centroid_radius.is_finite() && centroid_radius > 0.0 {
        centroid_radius
    } else {
        box_r
    };
    let min_len = 1e-4 * r;
    (0..count)
        .map(|i| {
            let mut rng = SplitMix64(seed ^ (i as u64).wrapping_mul(0xD1B5_4A32_D192_ED03));
            let b0 = (i as u32) % RANDOM_RAY_BANDS;
            let b1 = (i as u32 / RANDOM_RAY_BANDS) % RANDOM_RAY_BANDS;
            // Bounded: only non-finite coordinates (a sphere near f32::MAX) can fail every time;
            // such a ray gets tmax 0 and hits nothing.
            for _ in 0..64 {
                let p0 = c + sphere_point(&mut rng, b0) * r;
                let p1 = c + sphere_point(&mut rng, b1) * r;
                let d = p1 - p0;
                let len = d.as_dvec3().length() as f32; // f64: no under/overflow of the squares
                if len > min_len && len.is_finite() {
                    return Ray {
                        origin: p0,
                        dir: d / len,
                        tmax: len,
                    };
                }
            }
            Ray {
                origin: c,
                dir: Vec3::X,
                tmax: 0.0,
            }
        })
        .collect()
}
