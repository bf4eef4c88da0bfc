//! The report: every result row in a polars DataFrame (results.parquet, results.csv), plots made with
//! plotters (PNG and SVG), and index.html. Polars lives only here so algorithm crates build fast.
use bvhlab_pipeline::ResultRow;
use std::path::{Path, PathBuf};

/// Writes `out_dir/{results.parquet, results.csv, *.png, *.svg, index.html}` and returns the path
/// of index.html. `reference_dir` is ../shared/reference when present (papers' tables as TSV).
pub fn write_report(
    out_dir: &Path,
    experiment: &str,
    rows: &[ResultRow],
    reference_dir: Option<&Path>,
) -> Result<PathBuf, String> {
    let _ = (out_dir, experiment, rows, reference_dir);
    todo!()
}
