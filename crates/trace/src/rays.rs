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

impl Camera {
    /// Default camera derived from the scene bounds: looks at the centre from the front-diagonal,
    /// far enough that the whole bounding sphere fits the view.
    pub fn from_bounds(bounds: &Aabb) -> Camera {
        let _ = bounds;
        todo!()
    }
    /// Light for shadow rays: above the camera (thesis 4.4), offset by the scene radius along `up`.
    pub fn light(&self, bounds: &Aabb) -> Vec3 {
        let _ = bounds;
        todo!()
    }
}

/// `width * height` rays, row-major from the top-left pixel, through pixel centres.
pub fn primary_rays(camera: &Camera, width: u32, height: u32) -> Vec<Ray> {
    let _ = (camera, width, height);
    todo!()
}

/// For every primary ray that hit (`hit_t` finite), a ray from the hit point (nudged off the
/// surface) to `light`, with tmax just short of the light. Order follows the primary rays.
pub fn shadow_rays(primary: &[Ray], hit_t: &[f32], light: Vec3) -> Vec<Ray> {
    let _ = (primary, hit_t, light);
    todo!()
}

/// `count` rays between pairs of uniform points on the bounding sphere centred at the scene box
/// centre with radius enclosing every triangle centroid (thesis 4.4). Deterministic in `seed`.
pub fn random_rays(bounds: &Aabb, centroid_radius: f32, count: usize, seed: u64) -> Vec<Ray> {
    let _ = (bounds, centroid_radius, count, seed);
    todo!()
}
