//! Image input: decoding the contract's image encodings into RGB, and the
//! letterboxed, normalised NCHW input a network takes.

use image::{RgbImage, imageops::FilterType};

use crate::detection::Letterbox;

/// How an image's bytes are encoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Encoding {
    Rgb8,
    Png,
    Jpeg,
}

/// Why an image could not be used. Every variant is the caller's mistake.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ImageError {
    #[error("width and height are required for RGB8 images (got {width}×{height})")]
    MissingSize { width: u32, height: u32 },
    #[error(
        "RGB8 data has {got} bytes, but {width}×{height}×3 = {expected}{hint}; send row-major 8-bit RGB, 3 bytes per pixel"
    )]
    WrongLength { width: u32, height: u32, got: usize, expected: usize, hint: String },
    #[error("image is {width}×{height}; the largest accepted is {max}×{max}")]
    TooLarge { width: u32, height: u32, max: u32 },
    #[error("cannot decode the {format} image ({reason}); is it truncated or not a {format}?")]
    Decode { format: &'static str, reason: String },
    #[error("the {format} image decodes to {decoded_w}×{decoded_h}, but the request says {width}×{height}")]
    SizeMismatch { format: &'static str, width: u32, height: u32, decoded_w: u32, decoded_h: u32 },
    #[error("the image encoding is unspecified; use RGB8, PNG or JPEG")]
    Unspecified,
}

/// Largest side accepted (a D455 frame is 1280×800 at most; photos are larger).
pub const MAX_SIDE: u32 = 8192;

/// Decodes an image into 8-bit RGB. PNG and JPEG in grey, grey+alpha, RGB or
/// RGBA are converted (alpha dropped); a non-zero `width`/`height` must match
/// the decoded size.
pub fn decode(encoding: Encoding, width: u32, height: u32, data: &[u8]) -> Result<RgbImage, ImageError> {
    match encoding {
        Encoding::Rgb8 => {
            if width == 0 || height == 0 {
                return Err(ImageError::MissingSize { width, height });
            }
            if width > MAX_SIDE || height > MAX_SIDE {
                return Err(ImageError::TooLarge { width, height, max: MAX_SIDE });
            }
            let pixels = width as usize * height as usize;
            let expected = pixels * 3;
            if data.len() != expected {
                let hint = match data.len().checked_div(pixels) {
                    Some(c) if data.len().is_multiple_of(pixels) && c != 3 => {
                        format!(" ({c} bytes per pixel: that is {c}-channel data, not RGB)")
                    }
                    _ => String::new(),
                };
                return Err(ImageError::WrongLength { width, height, got: data.len(), expected, hint });
            }
            Ok(RgbImage::from_raw(width, height, data.to_vec()).expect("length checked"))
        }
        Encoding::Png | Encoding::Jpeg => {
            let (format, name) = match encoding {
                Encoding::Png => (image::ImageFormat::Png, "PNG"),
                _ => (image::ImageFormat::Jpeg, "JPEG"),
            };
            // The JPEG decoder fills a cut-off scan with grey instead of failing; a truncated
            // upload must not be mistaken for a picture, so the end-of-image marker is required.
            if encoding == Encoding::Jpeg && !jpeg_is_complete(data) {
                return Err(ImageError::Decode {
                    format: name,
                    reason: format!("the data ({} bytes) ends without the end-of-image marker FF D9", data.len()),
                });
            }
            let mut reader = image::ImageReader::with_format(std::io::Cursor::new(data), format);
            let mut limits = image::Limits::default();
            limits.max_image_width = Some(MAX_SIDE);
            limits.max_image_height = Some(MAX_SIDE);
            reader.limits(limits);
            let img = reader.decode().map_err(|e| ImageError::Decode { format: name, reason: e.to_string() })?;
            let (dw, dh) = (img.width(), img.height());
            if (width != 0 && width != dw) || (height != 0 && height != dh) {
                return Err(ImageError::SizeMismatch { format: name, width, height, decoded_w: dw, decoded_h: dh });
            }
            Ok(img.into_rgb8())
        }
    }
}

/// A JPEG stream ends with the EOI marker (FF D9); zero padding after it is tolerated.
fn jpeg_is_complete(data: &[u8]) -> bool {
    let end = data.iter().rposition(|&b| b != 0).map_or(0, |i| i + 1);
    end >= 4 && data[..2] == [0xFF, 0xD8] && data[end - 2..end] == [0xFF, 0xD9]
}

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
    fn raw_rgb_is_checked_with_a_helpful_message() {
        let ok = decode(Encoding::Rgb8, 2, 2, &[7u8; 12]).unwrap();
        assert_eq!(ok.dimensions(), (2, 2));
        let rgba = decode(Encoding::Rgb8, 2, 2, &[7u8; 16]).unwrap_err();
        assert!(rgba.to_string().contains("4-channel"), "{rgba}");
        let short = decode(Encoding::Rgb8, 2, 2, &[7u8; 11]).unwrap_err();
        assert!(matches!(short, ImageError::WrongLength { got: 11, expected: 12, .. }));
        assert_eq!(decode(Encoding::Rgb8, 0, 2, &[]).unwrap_err(), ImageError::MissingSize { width: 0, height: 2 });
    }

    #[test]
    fn png_round_trip_truncation_and_size_mismatch() {
        let img = RgbImage::from_fn(5, 3, |x, y| image::Rgb([x as u8 * 40, y as u8 * 80, 9]));
        let mut png = Vec::new();
        img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png).unwrap();
        assert_eq!(decode(Encoding::Png, 5, 3, &png).unwrap(), img);
        assert_eq!(decode(Encoding::Png, 0, 0, &png).unwrap(), img);
        let e = decode(Encoding::Png, 5, 3, &png[..png.len() / 2]).unwrap_err();
        assert!(matches!(e, ImageError::Decode { format: "PNG", .. }), "{e}");
        let e = decode(Encoding::Png, 6, 3, &png).unwrap_err();
        assert!(matches!(e, ImageError::SizeMismatch { decoded_w: 5, .. }), "{e}");
        let e = decode(Encoding::Jpeg, 5, 3, &png).unwrap_err();
        assert!(matches!(e, ImageError::Decode { format: "JPEG", .. }), "{e}");
        // A JPEG cut short is refused, a complete one (with zero padding) decodes.
        let mut jpeg = Vec::new();
        img.write_to(&mut std::io::Cursor::new(&mut jpeg), image::ImageFormat::Jpeg).unwrap();
        assert_eq!(decode(Encoding::Jpeg, 5, 3, &jpeg).unwrap().dimensions(), (5, 3));
        let e = decode(Encoding::Jpeg, 5, 3, &jpeg[..jpeg.len() - 10]).unwrap_err();
        assert!(e.to_string().contains("end-of-image"), "{e}");
        jpeg.extend_from_slice(&[0, 0, 0]);
        assert!(decode(Encoding::Jpeg, 5, 3, &jpeg).is_ok());
    }

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
