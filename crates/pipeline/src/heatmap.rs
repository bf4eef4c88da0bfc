//! Heat-map PNG files: `bvhlab_trace::heatmap` returns the pixels, this encodes them.

/// PNG bytes of the `width x height` heat map of `steps` (row-major from the top-left pixel). The
/// encoder is image's PNG encoder with its defaults, the one plotters' BitMapBackend used before
/// (so the bytes, and the cache's blake3 of them, are unchanged).
pub fn heatmap_png(steps: &[u32], width: u32, height: u32) -> Result<Vec<u8>, String> {
    use image::ImageEncoder;
    if width == 0 || height == 0 {
        return Err(format!("heat map: empty image {width}x{height}"));
    }
    let rgb = bvhlab_trace::heatmap::heatmap_rgb(steps, width, height)?;
    let mut png = Vec::new();
    image::codecs::png::PngEncoder::new(&mut png)
        .write_image(&rgb, width, height, image::ColorType::Rgb8)
        .map_err(|e| format!("heat map: {e}"))?;
    Ok(png)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn encodes_a_png() {
        let steps: Vec<u32> = (0..40 * 30).map(|i| i % 120).collect();
        let png = heatmap_png(&steps, 40, 30).unwrap();
        assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
        assert!(heatmap_png(&steps, 41, 30).is_err());
        assert!(heatmap_png(&[], 0, 30).is_err());
    }
}
