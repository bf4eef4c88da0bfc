//! Deterministic generated scenes, addressed as `gen:NAME[:key=value,...]`.
use crate::{LoadError, Scene};

/// A generator's name, its parameters (name, default, meaning) and what it models.
pub struct GeneratorInfo {
    pub name: &'static str,
    pub about: &'static str,
    pub params: &'static [(&'static str, &'static str, &'static str)],
}

pub fn generators() -> Vec<GeneratorInfo> {
    todo!()
}

/// `spec` is the part after `gen:`, e.g. `sphere:n=10000`.
pub fn generate(spec: &str) -> Result<Scene, LoadError> {
    let _ = spec;
    todo!()
}
