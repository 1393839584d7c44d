//! Network input: the letterboxed, normalised NCHW tensor a network takes
//! (images arrive decoded by `vlnav_geometry::rgb`, the one RGB decoder).

use image::{RgbImage, imageops::FilterType};

use crate::detection::Letterbox;

/// How a network wants its input.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InputSpec {
    /// Square input side.
    pub size: u32,
    /// Canvas value around the letterboxed image (0–255).
    pub pad: u8,
    /// Channel order BGR instead of RGB.
    pub bgr: bool,
    /// Per-channel mean and standard deviation on 0–255 values, in the network's channel order.
    pub mean: [f32; 3],
    pub std: [f32; 3],
}

/// Letterboxes `img` into a `size`×`size` canvas (bilinear resize, centred)
/// and returns CHW floats normalised as `spec` says, with the geometry.
pub fn letterbox_chw(img: &RgbImage, spec: &InputSpec) -> (Vec<f32>, Letterbox) {
    let lb = Letterbox::new(img.width(), img.height(), spec.size);
    let resized;
    let src = if (lb.new_w, lb.new_h) == img.dimensions() {
        img
    } else {
        resized = image::imageops::resize(img, lb.new_w, lb.new_h, FilterType::Triangle);
        &resized
    };
    let s = spec.size as usize;
    let plane = s * s;
    let mut out = vec![0f32; 3 * plane];
    for c in 0..3 {
        let pad = (spec.pad as f32 - spec.mean[c]) / spec.std[c];
        out[c * plane..(c + 1) * plane].fill(pad);
    }
    let order: [usize; 3] = if spec.bgr { [2, 1, 0] } else { [0, 1, 2] };
    let inv_std = spec.std.map(|v| 1.0 / v);
    for (x, y, p) in src.enumerate_pixels() {
        let idx = (y + lb.pad_y) as usize * s + (x + lb.pad_x) as usize;
        for c in 0..3 {
            out[c * plane + idx] = (p.0[order[c]] as f32 - spec.mean[c]) * inv_std[c];
        }
    }
    (out, lb)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn letterbox_places_and_normalises_pixels() {
        // 4×2 image into 8×8: scale 2, 8×4 resized, padded 2 rows top and bottom.
        let img = RgbImage::from_pixel(4, 2, image::Rgb([10, 20, 30]));
        let spec = InputSpec { size: 8, pad: 0, bgr: true, mean: [1.0, 2.0, 3.0], std: [2.0, 2.0, 2.0] };
        let (chw, lb) = letterbox_chw(&img, &spec);
        assert_eq!((lb.pad_x, lb.pad_y, lb.new_w, lb.new_h), (0, 2, 8, 4));
        assert_eq!(chw.len(), 3 * 64);
        // Row 0 is padding: (0 − mean) / std.
        assert_eq!(chw[0], -0.5);
        // Row 3 is image: channel 0 is blue in BGR order.
        assert_eq!(chw[3 * 8], (30.0 - 1.0) / 2.0);
        assert_eq!(chw[64 + 3 * 8], (20.0 - 2.0) / 2.0);
        assert_eq!(chw[128 + 3 * 8], (10.0 - 3.0) / 2.0);
    }
}
