//! Rays and traversal: ray sets (thesis 4.4), closest-hit traversal with per-ray counters,
//! the brute-force oracle every builder is checked against, and traversal-step heat maps; `fast`:
//! the timed path (slot-ordered triangles, watertight f32 test, no counters).

pub mod fast;
pub mod heatmap;
pub mod packs;
pub mod pairs;
pub mod rays;
pub mod thp;
pub mod traverse;

pub use fast::{agrees, check_agreement, FastBvh2, TriStore, WTri};
pub use packs::{PackStore, Tri4};
pub use rays::{primary_rays, random_rays, shadow_rays, Camera, Ray};
pub use traverse::{
    accept, brute_force, brute_force_one, intersect_triangle, trace, trace_with, Hit, Pending,
    RayBox, Stack, TraceStats, SLAB_ROBUST,
};
