//! The pipeline: content-hashed stages (load, encode, build, optimize, compact, layout, measure,
//! focus) cached on disk, experiment files, and the flat result rows the report and `eval --json`
//! are made from. The only crate that knows about hashing, caching and files (besides scene
//! loading). `memtrack` installs the counting global allocator (peak layout build memory).

pub mod atomic;
pub mod batch;
pub mod catalogue;
pub mod codec;
pub mod error;
pub mod estimate;
pub mod experiment;
pub mod heatmap;
pub mod key;
pub mod lockfile;
pub mod memtrack;
pub mod methods;
pub mod plan;
pub mod registry;
pub mod row;
pub mod run;
pub mod stages;
pub mod store;
pub mod sweep;

/// The layout crate, for callers listing layouts and their parameters (the CLI).
pub use bvhlab_layout;
/// Median, spread and range of repeated runs (shared with the report).
pub use bvhlab_geom::stats;
/// Step count at which heat maps saturate (the report draws their colour scale).
pub use bvhlab_trace::heatmap::HEAT_MAX_STEPS;
pub use error::{Error, Result};
pub use experiment::Experiment;
pub use key::Key;
pub use registry::Registry;
pub use row::ResultRow;
pub use run::{with_threads, Counts, NodeInfo, Runner};
pub use stages::{parse_layout, ChainSpec, LayoutRequest, RaySpec, SceneSource, Versions};
pub use store::Store;
