//! Heat map of traversal steps per pixel, blue (0) to red (>= 100), like Bittner 2013 figure 1.
//! Returns pixels; the pipeline encodes and writes the PNG files (`bvhlab_pipeline::heatmap`).

/// Step count at and above which a pixel is pure red (Bittner 2013, figure 1 (d)).
pub const HEAT_MAX_STEPS: u32 = 100;

/// Ramp stops, evenly spaced over [0, HEAT_MAX_STEPS]: blue, cyan, green, yellow, red.
const STOPS: [[f32; 3]; 5] = [
    [0.0, 0.0, 255.0],
    [0.0, 255.0, 255.0],
    [0.0, 255.0, 0.0],
    [255.0, 255.0, 0.0],
    [255.0, 0.0, 0.0],
];

/// Colour of one pixel: piecewise-linear blue -> cyan -> green -> yellow -> red.
pub fn heat_color(steps: u32) -> [u8; 3] {
    let s = steps.min(HEAT_MAX_STEPS) as f32 / HEAT_MAX_STEPS as f32 * (STOPS.len() - 1) as f32;
    let i = (s.floor() as usize).min(STOPS.len() - 2);
    let f = s - i as f32;
    let (a, b) = (STOPS[i], STOPS[i + 1]);
    let c = |k: usize| (a[k] + (b[k] - a[k]) * f).round().clamp(0.0, 255.0) as u8;
    [c(0), c(1), c(2)]
}

/// Row-major RGB8 buffer (3 bytes per pixel) of the heat map; errors if `steps` does not hold
/// exactly `width * height` values.
pub fn heatmap_rgb(steps: &[u32], width: u32, height: u32) -> Result<Vec<u8>, String> {
    let n = width as u64 * height as u64;
    if steps.len() as u64 != n {
        return Err(format!(
            "heat map: {} step values for a {width}x{height} image ({n} pixels)",
            steps.len()
        ));
    }
    Ok(steps.iter().flat_map(|&s| heat_color(s)).collect())
}
