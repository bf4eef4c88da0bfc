use crate::Aabb;
use glam::Vec3;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Triangle {
    pub v: [Vec3; 3],
}

impl Triangle {
    #[inline]
    pub fn new(a: Vec3, b: Vec3, c: Vec3) -> Self {
        Self { v: [a, b, c] }
    }
    #[inline]
    pub fn bounds(&self) -> Aabb {
        Aabb { min: self.v[0].min(self.v[1]).min(self.v[2]), max: self.v[0].max(self.v[1]).max(self.v[2]) }
    }
    #[inline]
    pub fn is_finite(&self) -> bool {
        self.v.iter().all(|p| p.is_finite())
    }
    #[inline]
    pub fn area(&self) -> f32 {
        0.5 * (self.v[1] - self.v[0]).cross(self.v[2] - self.v[0]).length()
    }
}

/// A triangle soup plus what loading it dropped. Triangles with any non-finite coordinate are
/// dropped and counted (DEVELOPERS.md, Standards); zero-area triangles are kept.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Scene {
    pub triangles: Vec<Triangle>,
    pub dropped_triangles: u64,
}

impl Scene {
    /// Build a scene from triangles, dropping non-finite ones.
    pub fn from_triangles(tris: impl IntoIterator<Item = Triangle>) -> Scene {
        let mut dropped = 0u64;
        // From a Vec this filters in place (the collect reuses its buffer) instead of growing a
        // second Vec beside the input.
        let triangles = tris
            .into_iter()
            .filter(|t| {
                let ok = t.is_finite();
                dropped += !ok as u64;
                ok
            })
            .collect();
        Scene { triangles, dropped_triangles: dropped }
    }
    pub fn bounds(&self) -> Aabb {
        let mut b = Aabb::EMPTY;
        for t in &self.triangles {
            b.grow(&t.bounds());
        }
        b
    }
    /// How much f32 rounds this scene's geometry: the spacing of f32 values at the largest
    /// coordinate magnitude (one ulp there) over the median length of the non-zero triangle edges
    /// (over at most about 100k triangles, evenly strided). A scene far from the origin relative to
    /// its detail (issue 15: a model moved by 10^6 of its size) has lost its shape to rounding when
    /// this approaches 1; 0 for a scene without edges. Scale-free: a scene times 2^k gives the same
    /// value.
    pub fn precision_loss(&self) -> f64 {
        let mut max_abs = 0.0f32;
        for t in &self.triangles {
            for v in t.v {
                max_abs = max_abs.max(v.abs().max_element());
            }
        }
        let stride = (self.triangles.len() / 100_000).max(1);
        let mut edges: Vec<f64> = Vec::new();
        for t in self.triangles.iter().step_by(stride) {
            for (a, b) in [(0, 1), (1, 2), (2, 0)] {
                let d = t.v[a].as_dvec3() - t.v[b].as_dvec3();
                let l = d.length();
                if l > 0.0 {
                    edges.push(l);
                }
            }
        }
        if edges.is_empty() || !(max_abs > 0.0) {
            return 0.0;
        }
        let mid = edges.len() / 2;
        let median = *edges.select_nth_unstable_by(mid, f64::total_cmp).1;
        // One ulp at max_abs: the next float up minus it (f32::MAX: the ulp below).
        let m = max_abs as f64;
        let up = f32::from_bits(max_abs.to_bits() + 1);
        let ulp = if up.is_finite() { up as f64 - m } else { m - f32::from_bits(max_abs.to_bits() - 1) as f64 };
        ulp / median
    }

    /// Per-primitive boxes and centres: the only input builders see (bvh v2 style).
    pub fn boxes_and_centers(&self) -> (Vec<Aabb>, Vec<Vec3>) {
        let boxes = self.boxes();
        let centers = boxes.iter().map(|b| b.center()).collect();
        (boxes, centers)
    }

    /// The triangles' boxes (for consumers that need no centres).
    pub fn boxes(&self) -> Vec<Aabb> {
        self.triangles.iter().map(|t| t.bounds()).collect()
    }
}

/// A load failure: which file, which line (1-based, when the failure has one), and why.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{}{}: {reason}", file.display(), line.map(|l| format!(":{l}")).unwrap_or_default())]
pub struct LoadError {
    pub file: PathBuf,
    pub line: Option<usize>,
    pub reason: String,
}

/// Load a scene from a spec: `gen:NAME[:key=value,...]` or a path to `.obj` / `.obj.gz`.
pub fn load_scene(spec: &str) -> Result<Scene, LoadError> {
    if let Some(rest) = spec.strip_prefix("gen:") {
        crate::gen::generate(rest)
    } else {
        crate::obj::load_obj(std::path::Path::new(spec))
    }
}
