//! Crop + resize + normalise, the input side of every embedder: a box of an
//! RGB image is resampled bilinearly (half-pixel centres, edge clamped — what
//! OpenCV's `INTER_LINEAR` resize does on the cropped patch) to the network's
//! input size and normalised with the ImageNet mean and deviation, CHW order.

use image::RgbImage;

/// ImageNet channel statistics on 0–1 values (torchvision, DeepSORT, torchreid).
pub const IMAGENET_MEAN: [f32; 3] = [0.485, 0.456, 0.406];
pub const IMAGENET_STD: [f32; 3] = [0.229, 0.224, 0.225];

/// A region of an image in pixel coordinates (x right, y down; max exclusive).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CropBox {
    pub x_min: f32,
    pub y_min: f32,
    pub x_max: f32,
    pub y_max: f32,
}

impl CropBox {
    /// The whole image.
    pub fn full(image: &RgbImage) -> Self {
        Self { x_min: 0.0, y_min: 0.0, x_max: image.width() as f32, y_max: image.height() as f32 }
    }

    /// This box clipped to a `width`×`height` image; `None` if less than one
    /// pixel of it remains in either direction.
    pub fn clip(self, width: u32, height: u32) -> Option<Self> {
        let c = Self {
            x_min: self.x_min.max(0.0),
            y_min: self.y_min.max(0.0),
            x_max: self.x_max.min(width as f32),
            y_max: self.y_max.min(height as f32),
        };
        (c.x_max - c.x_min >= 1.0 && c.y_max - c.y_min >= 1.0).then_some(c)
    }

    pub fn width(&self) -> f32 {
        self.x_max - self.x_min
    }

    pub fn height(&self) -> f32 {
        self.y_max - self.y_min
    }
}

/// Writes the `region` of `image` resized to `out_w`×`out_h`, normalised,
/// as planar CHW floats into `out` (length 3·out_w·out_h).
pub fn crop_resize_normalize(image: &RgbImage, region: CropBox, out_w: usize, out_h: usize, out: &mut [f32]) {
    assert_eq!(out.len(), 3 * out_w * out_h, "output buffer size");
    let (iw, ih) = (image.width() as usize, image.height() as usize);
    let raw = image.as_raw();
    let sx = region.width() / out_w as f32;
    let sy = region.height() / out_h as f32;
    // Horizontal sample positions and weights are the same for every row.
    let cols: Vec<(usize, usize, f32)> = (0..out_w)
        .map(|ox| {
            let x = (region.x_min + (ox as f32 + 0.5) * sx - 0.5).clamp(0.0, (iw - 1) as f32);
            let x0 = x.floor() as usize;
            (x0, (x0 + 1).min(iw - 1), x - x0 as f32)
        })
        .collect();
    let plane = out_w * out_h;
    let scale: [f32; 3] = std::array::from_fn(|c| 1.0 / (255.0 * IMAGENET_STD[c]));
    let shift: [f32; 3] = std::array::from_fn(|c| IMAGENET_MEAN[c] / IMAGENET_STD[c]);
    for oy in 0..out_h {
        let y = (region.y_min + (oy as f32 + 0.5) * sy - 0.5).clamp(0.0, (ih - 1) as f32);
        let y0 = y.floor() as usize;
        let y1 = (y0 + 1).min(ih - 1);
        let fy = y - y0 as f32;
        let (r0, r1) = (&raw[y0 * iw * 3..(y0 + 1) * iw * 3], &raw[y1 * iw * 3..(y1 + 1) * iw * 3]);
        for (ox, &(x0, x1, fx)) in cols.iter().enumerate() {
            for c in 0..3 {
                let top = r0[x0 * 3 + c] as f32 * (1.0 - fx) + r0[x1 * 3 + c] as f32 * fx;
                let bottom = r1[x0 * 3 + c] as f32 * (1.0 - fx) + r1[x1 * 3 + c] as f32 * fx;
                let v = top * (1.0 - fy) + bottom * fy;
                out[c * plane + oy * out_w + ox] = v * scale[c] - shift[c];
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identity_resize_reproduces_the_normalised_pixels() {
        let img = RgbImage::from_fn(4, 3, |x, y| image::Rgb([(x * 60) as u8, (y * 100) as u8, 7]));
        let mut out = vec![0.0; 3 * 4 * 3];
        crop_resize_normalize(&img, CropBox::full(&img), 4, 3, &mut out);
        for y in 0..3 {
            for x in 0..4 {
                let p = img.get_pixel(x, y).0;
                for c in 0..3 {
                    let want = (p[c] as f32 / 255.0 - IMAGENET_MEAN[c]) / IMAGENET_STD[c];
                    let got = out[c * 12 + y as usize * 4 + x as usize];
                    assert!((got - want).abs() < 1e-5, "({x},{y},{c}): {got} vs {want}");
                }
            }
        }
    }

    #[test]
    fn downsampling_by_two_averages_pixel_pairs() {
        // Half-pixel centres: output pixel 0 samples between input pixels 0 and 1.
        let img = RgbImage::from_fn(4, 1, |x, _| image::Rgb([[0, 100, 200, 250][x as usize], 0, 0]));
        let mut out = vec![0.0; 3 * 2];
        crop_resize_normalize(&img, CropBox::full(&img), 2, 1, &mut out);
        let red = |v: f32| v * IMAGENET_STD[0] * 255.0 + IMAGENET_MEAN[0] * 255.0;
        assert!((red(out[0]) - 50.0).abs() < 1e-3, "{}", red(out[0]));
        assert!((red(out[1]) - 225.0).abs() < 1e-3, "{}", red(out[1]));
    }

    #[test]
    fn crops_read_only_their_region() {
        let img = RgbImage::from_fn(10, 10, |x, _| image::Rgb(if x < 5 { [0, 0, 0] } else { [255, 255, 255] }));
        let mut out = vec![0.0; 3 * 4];
        crop_resize_normalize(&img, CropBox { x_min: 5.0, y_min: 2.0, x_max: 10.0, y_max: 8.0 }, 2, 2, &mut out);
        let white = (1.0 - IMAGENET_MEAN[0]) / IMAGENET_STD[0];
        assert!(out[..4].iter().all(|v| (v - white).abs() < 1e-5), "{out:?}");
    }

    #[test]
    fn clipping_drops_boxes_outside_the_image() {
        let b = CropBox { x_min: -5.0, y_min: 2.0, x_max: 3.0, y_max: 50.0 };
        assert_eq!(b.clip(10, 10), Some(CropBox { x_min: 0.0, y_min: 2.0, x_max: 3.0, y_max: 10.0 }));
        assert_eq!(CropBox { x_min: 12.0, y_min: 0.0, x_max: 20.0, y_max: 5.0 }.clip(10, 10), None);
        assert_eq!(CropBox { x_min: 2.0, y_min: 2.0, x_max: 2.5, y_max: 5.0 }.clip(10, 10), None);
    }
}
