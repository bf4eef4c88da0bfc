//! Wavefront OBJ (and .obj.gz) through tobj: positions only, polygons triangulated.
use crate::{LoadError, Scene};
use std::path::Path;

pub fn load_obj(path: &Path) -> Result<Scene, LoadError> {
    let _ = path;
    todo!()
}
