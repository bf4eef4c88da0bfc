//! Heat map colour ramp and pixel buffer (the pipeline encodes the PNG).
use bvhlab_trace::heatmap::{heat_color, heatmap_rgb};

#[test]
fn ramp_endpoints_and_stops() {
    assert_eq!(heat_color(0), [0, 0, 255], "0 steps is blue");
    assert_eq!(heat_color(100), [255, 0, 0], "100 steps is red");
    assert_eq!(heat_color(5000), [255, 0, 0], "above 100 stays red");
    assert_eq!(heat_color(25), [0, 255, 255]);
    assert_eq!(heat_color(50), [0, 255, 0]);
    assert_eq!(heat_color(75), [255, 255, 0]);
    // Monotone through the ramp: red rises, blue falls.
    let cs: Vec<[u8; 3]> = (0..=100).map(heat_color).collect();
    assert!(cs
        .windows(2)
        .all(|w| w[1][0] >= w[0][0] && w[1][2] <= w[0][2]));
}

#[test]
fn rgb_buffer_layout() {
    let rgb = heatmap_rgb(&[0, 100, 50, 0, 0, 0], 3, 2).unwrap();
    assert_eq!(rgb.len(), 18);
    assert_eq!(&rgb[0..3], &[0, 0, 255]);
    assert_eq!(&rgb[3..6], &[255, 0, 0]);
    assert_eq!(&rgb[6..9], &[0, 255, 0]);
    assert!(heatmap_rgb(&[0; 5], 3, 2).is_err());
}
