//! The pipeline: content-hashed stages (load, build, compact, measure) cached on disk, experiment
//! files, and the flat result rows the report and `eval --json` are made from. The only crate that
//! knows about hashing, caching and files (besides scene loading).

pub mod row;

pub use row::ResultRow;
