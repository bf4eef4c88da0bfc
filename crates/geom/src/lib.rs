//! Geometry shared by every bvhlab crate: boxes, triangles, scenes; loading OBJ files and
//! generating deterministic test scenes. No crate below the pipeline knows about files or caches
//! except through [`load_scene`].

pub mod aabb;
pub mod gen;
pub mod obj;
pub mod rng;
pub mod scene;
pub mod stats;

pub use aabb::Aabb;
pub use glam::Vec3;
pub use scene::{load_scene, LoadError, Scene, Triangle};
