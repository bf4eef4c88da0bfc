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
        let mut s = Scene::default();
        for t in tris {
            if t.is_finite() {
                s.triangles.push(t);
            } else {
                s.dropped_triangles += 1;
            }
        }
        s
    }
    pub fn bounds(&self) -> Aabb {
        let mut b = Aabb::EMPTY;
        for t in &self.triangles {
            b.grow(&t.bounds());
        }
        b
    }
    /// Per-primitive boxes and centres: the only input builders see (bvh v2 style).
    pub fn boxes_and_centers(&self) -> (Vec<Aabb>, Vec<Vec3>) {
        let boxes: Vec<Aabb> = self.triangles.iter().map(|t| t.bounds()).collect();
        let centers = boxes.iter().map(|b| b.center()).collect();
        (boxes, centers)
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
