//! Heat map of traversal steps per pixel, blue (0) to red (>= 100), like Bittner 2013 figure 1.
use std::path::Path;

/// Writes a `width x height` PNG; `steps` is row-major from the top-left pixel.
pub fn write_heatmap_png(path: &Path, steps: &[u32], width: u32, height: u32) -> Result<(), String> {
    let _ = (path, steps, width, height);
    todo!()
}
