//! The one RGB decoder: the contract's image encodings (raw RGB8, PNG, JPEG)
//! into 8-bit RGB, with the size capped and every refusal a typed
//! [`ImageError`] (all of them the caller's mistake: `INVALID_ARGUMENT`).
//!
//! Decoding a JPEG or PNG takes milliseconds of CPU; async callers use
//! [`decode_off_thread`] / [`decode_all_off_thread`], which run it on
//! tokio's blocking pool instead of an async worker thread.
//!
//! The one JPEG encoder too ([`encode_jpeg`]: the edge agent's colour
//! uplink, the live view), and a header check ([`header_size`]) that reads
//! the size a PNG or JPEG declares without decoding it.
//!
//! Also the one photometric jitter ([`jitter_colour`]) the calibration and
//! the ReID tests apply to cut-out photos.

use image::RgbImage;

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
    #[error("unknown image encoding {0}; use RGB8, PNG or JPEG")]
    UnknownEncoding(i32),
}

/// Why [`encode_jpeg`] could not encode an image.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum EncodeError {
    #[error("JPEG quality {0} is outside 1..=100 (1 is the smallest, 100 the finest)")]
    Quality(u8),
    /// The pixels are not `width`×`height` RGB8, or the image is too large.
    #[error(transparent)]
    Size(ImageError),
    #[error("cannot encode the image as JPEG: {0}")]
    Encoder(String),
}

/// Largest side accepted (a D455 frame is 1280×800 at most; photos are larger).
pub const MAX_SIDE: u32 = 8192;

/// Photometric jitter as training pipelines apply it: scale by
/// `brightness`, move each channel toward or away from the pixel's grey
/// (ITU-R BT.601 luma) by `saturation`, and stretch around mid-grey by
/// `contrast`; 1.0 leaves a factor out.
pub fn jitter_colour(img: &mut RgbImage, brightness: f32, contrast: f32, saturation: f32) {
    for p in img.pixels_mut() {
        let [r, g, b] = p.0.map(|c| c as f32 * brightness);
        let grey = 0.299 * r + 0.587 * g + 0.114 * b;
        p.0 = [r, g, b].map(|c| {
            let c = grey + (c - grey) * saturation;
            (128.0 + (c - 128.0) * contrast).clamp(0.0, 255.0) as u8
        });
    }
}

/// Decodes an image into 8-bit RGB. PNG and JPEG in grey, grey+alpha, RGB or
/// RGBA are converted (alpha dropped); a non-zero `width`/`height` must match
/// the decoded size. No side may exceed [`MAX_SIDE`].
pub fn decode(encoding: Encoding, width: u32, height: u32, data: &[u8]) -> Result<RgbImage, ImageError> {
    if width > MAX_SIDE || height > MAX_SIDE {
        return Err(ImageError::TooLarge { width, height, max: MAX_SIDE });
    }
    match encoding {
        Encoding::Rgb8 => {
            check_rgb8(width, height, data.len())?;
            Ok(RgbImage::from_raw(width, height, data.to_vec()).expect("length checked"))
        }
        Encoding::Png | Encoding::Jpeg => {
            let (format, name) = match encoding {
                Encoding::Png => (image::ImageFormat::Png, "PNG"),
                _ => (image::ImageFormat::Jpeg, "JPEG"),
            };
            // The JPEG decoder fills a cut-off scan with grey instead of failing; a truncated
            // upload must not be mistaken for a picture, so the end-of-image marker is required.
            if encoding == Encoding::Jpeg {
                require_complete_jpeg(data)?;
            }
            // The header's size first (cheap): a few bytes that claim a large picture are
            // refused before the decoder allocates for it (or fills it with grey).
            let (hw, hh) = image::ImageReader::with_format(std::io::Cursor::new(data), format)
                .into_dimensions()
                .map_err(|e| ImageError::Decode { format: name, reason: e.to_string() })?;
            if (width != 0 && width != hw) || (height != 0 && height != hh) {
                return Err(ImageError::SizeMismatch { format: name, width, height, decoded_w: hw, decoded_h: hh });
            }
            let least = least_encoded_len(encoding, hw, hh, data);
            if (data.len() as u64) < least {
                return Err(ImageError::Decode {
                    format: name,
                    reason: format!(
                        "the data ({} bytes) is too short for the {hw}×{hh} picture its header declares \
                         (at least {least} bytes)",
                        data.len()
                    ),
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

/// Raw RGB8 of `width`×`height` must be exactly 3 bytes a pixel.
fn check_rgb8(width: u32, height: u32, len: usize) -> Result<(), ImageError> {
    if width == 0 || height == 0 {
        return Err(ImageError::MissingSize { width, height });
    }
    let pixels = width as usize * height as usize;
    let expected = pixels * 3;
    if len != expected {
        let hint = match len.checked_div(pixels) {
            Some(c) if len.is_multiple_of(pixels) && c != 3 => {
                format!(" ({c} bytes per pixel: that is {c}-channel data, not RGB)")
            }
            _ => String::new(),
        };
        return Err(ImageError::WrongLength { width, height, got: len, expected, hint });
    }
    Ok(())
}

/// Encodes row-major 8-bit RGB of `width`×`height` as a baseline JPEG at
/// `quality`, 1–100 on libjpeg's scale, with full chroma (4:4:4), by the
/// `jpeg-encoder` crate with AVX2 where the CPU has it. Halving the chroma
/// (4:2:0, libjpeg's default below 90) saved 17 % of the bytes at 85 but
/// lost the segmenter a fifth of the lab's cable pixels and NanoDet 4 % of
/// its detections (`vlnav bench jpeg`; docs/architecture.md, "Frames").
/// The size is checked first, as [`decode`] checks it: the encoder itself
/// would panic on a buffer of the wrong length.
pub fn encode_jpeg(width: u32, height: u32, rgb: &[u8], quality: u8) -> Result<Vec<u8>, EncodeError> {
    if !(1..=100).contains(&quality) {
        return Err(EncodeError::Quality(quality));
    }
    if width > MAX_SIDE || height > MAX_SIDE {
        return Err(EncodeError::Size(ImageError::TooLarge { width, height, max: MAX_SIDE }));
    }
    check_rgb8(width, height, rgb.len()).map_err(EncodeError::Size)?;
    let mut out = Vec::with_capacity(rgb.len() / 10);
    // The sides fit: both are at most MAX_SIDE (checked above).
    let mut encoder = jpeg_encoder::Encoder::new(&mut out, quality);
    encoder.set_sampling_factor(jpeg_encoder::SamplingFactor::F_1_1);
    encoder
        .encode(rgb, width as u16, height as u16, jpeg_encoder::ColorType::Rgb)
        .map_err(|e| EncodeError::Encoder(e.to_string()))?;
    Ok(out)
}

/// The size a PNG (its IHDR chunk) or a JPEG (its frame header) declares,
/// read without decoding and without allocating, so that every frame can be
/// checked where it enters; `None` for raw RGB8, which has no header. A JPEG
/// must also end with its end-of-image marker (see [`decode`]). A stream
/// that passes may still fail to decode: only [`decode`] reads the pixels.
pub fn header_size(encoding: Encoding, data: &[u8]) -> Result<Option<(u32, u32)>, ImageError> {
    let size = match encoding {
        Encoding::Rgb8 => return Ok(None),
        Encoding::Png => png_ihdr_size(data).ok_or_else(|| ImageError::Decode {
            format: "PNG",
            reason: format!("the data ({} bytes) does not start with the PNG signature and an IHDR chunk", data.len()),
        })?,
        Encoding::Jpeg => {
            let size = jpeg_frame_size(data).ok_or_else(|| ImageError::Decode {
                format: "JPEG",
                reason: format!(
                    "the data ({} bytes) has no frame header (SOF marker) before its first scan",
                    data.len()
                ),
            })?;
            require_complete_jpeg(data)?;
            size
        }
    };
    Ok(Some(size))
}

/// A JPEG must end with its end-of-image marker: the decoder fills a
/// cut-off scan with grey instead of failing.
fn require_complete_jpeg(data: &[u8]) -> Result<(), ImageError> {
    if jpeg_is_complete(data) {
        return Ok(());
    }
    Err(ImageError::Decode {
        format: "JPEG",
        reason: format!("the data ({} bytes) ends without the end-of-image marker FF D9", data.len()),
    })
}

fn png_ihdr_size(data: &[u8]) -> Option<(u32, u32)> {
    const SIGNATURE: [u8; 8] = [0x89, b'P', b'N', b'G', 0x0D, 0x0A, 0x1A, 0x0A];
    if data.get(..8)? != SIGNATURE || data.get(12..16)? != *b"IHDR" {
        return None;
    }
    let be = |at: usize| data.get(at..at + 4).map(|b| u32::from_be_bytes([b[0], b[1], b[2], b[3]]));
    Some((be(16)?, be(20)?))
}

/// Walks a JPEG's marker segments from its start-of-image marker to the
/// first frame header (SOF0–SOF15 but DHT, JPG and DAC) and reads its size.
fn jpeg_frame_size(data: &[u8]) -> Option<(u32, u32)> {
    if data.get(..2)? != [0xFF, 0xD8] {
        return None;
    }
    let mut i = 2;
    loop {
        if *data.get(i)? != 0xFF {
            return None;
        }
        let marker = *data.get(i + 1)?;
        i += 2;
        match marker {
            // Fill byte before a marker.
            0xFF => i -= 1,
            // Markers without a segment (TEM, RST0–7, SOI).
            0x01 | 0xD0..=0xD8 => {}
            // End of image or a scan before any frame header.
            0xD9 | 0xDA => return None,
            _ => {
                let len = usize::from(u16::from_be_bytes([*data.get(i)?, *data.get(i + 1)?]));
                if len < 2 {
                    return None;
                }
                if matches!(marker, 0xC0..=0xCF) && !matches!(marker, 0xC4 | 0xC8 | 0xCC) {
                    // Length (2), precision (1), lines (2), samples per line (2), …
                    let h = u16::from_be_bytes([*data.get(i + 3)?, *data.get(i + 4)?]);
                    let w = u16::from_be_bytes([*data.get(i + 5)?, *data.get(i + 6)?]);
                    return Some((u32::from(w), u32::from(h)));
                }
                i += len;
            }
        }
    }
}

/// The fewest bytes a PNG or JPEG of `width`×`height` can be encoded in:
/// - PNG: the filtered rows (a filter byte and the packed pixels, bit depth
///   and channels read from the IHDR chunk, 1 bit a pixel if absent), deflated
///   at best 1032:1 (deflate's ceiling);
/// - JPEG: one bit of entropy-coded data per 8×8 luma block at the least
///   (the shortest Huffman code for its DC coefficient).
fn least_encoded_len(encoding: Encoding, width: u32, height: u32, data: &[u8]) -> u64 {
    let (w, h) = (u64::from(width), u64::from(height));
    match encoding {
        Encoding::Png => {
            let bits_per_pixel = match data.get(24..26) {
                Some(&[depth, colour]) => {
                    let channels = match colour {
                        2 => 3,
                        4 => 2,
                        6 => 4,
                        _ => 1,
                    };
                    u64::from(depth.max(1)) * channels
                }
                _ => 1,
            };
            h * (1 + (w * bits_per_pixel).div_ceil(8)) / 1032
        }
        Encoding::Jpeg => w.div_ceil(8) * h.div_ceil(8) / 8,
        Encoding::Rgb8 => 0,
    }
}

/// A JPEG stream ends with the EOI marker (FF D9); zero padding after it is tolerated.
fn jpeg_is_complete(data: &[u8]) -> bool {
    let end = data.iter().rposition(|&b| b != 0).map_or(0, |i| i + 1);
    end >= 4 && data[..2] == [0xFF, 0xD8] && data[end - 2..end] == [0xFF, 0xD9]
}

/// An image still encoded, sharing its bytes with the request it came in
/// (no copy) so it can move to another thread.
#[derive(Clone, Debug, PartialEq)]
pub struct EncodedImage {
    pub encoding: Encoding,
    /// Declared size; 0 leaves a PNG's or JPEG's own size unchecked.
    pub width: u32,
    pub height: u32,
    pub data: bytes::Bytes,
}

impl EncodedImage {
    pub fn decode(&self) -> Result<RgbImage, ImageError> {
        decode(self.encoding, self.width, self.height, &self.data)
    }
}

/// Decodes on tokio's blocking pool, keeping the async worker threads free.
pub async fn decode_off_thread(image: EncodedImage) -> Result<RgbImage, ImageError> {
    let mut all = decode_all_off_thread(vec![image]).await.map_err(|(_, e)| e)?;
    Ok(all.pop().expect("one image in, one out"))
}

/// Decodes several images in one trip to the blocking pool; the error says
/// which one (its index) failed first.
pub async fn decode_all_off_thread(images: Vec<EncodedImage>) -> Result<Vec<RgbImage>, (usize, ImageError)> {
    tokio::task::spawn_blocking(move || {
        images.iter().enumerate().map(|(i, im)| im.decode().map_err(|e| (i, e))).collect()
    })
    .await
    .unwrap_or_else(|join| {
        // The decoder panicked on these bytes (or the runtime is shutting down): still the input's fault.
        Err((0, ImageError::Decode { format: "image", reason: format!("the decoder failed: {join}") }))
    })
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
    fn sides_beyond_the_cap_are_refused_before_any_work() {
        for enc in [Encoding::Rgb8, Encoding::Png, Encoding::Jpeg] {
            let e = decode(enc, MAX_SIDE + 1, 1, &[]).unwrap_err();
            assert_eq!(e, ImageError::TooLarge { width: MAX_SIDE + 1, height: 1, max: MAX_SIDE });
        }
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

    /// A smooth picture with some edges, like a camera's.
    fn scene(w: u32, h: u32) -> RgbImage {
        RgbImage::from_fn(w, h, |x, y| {
            let edge = if (x / 16 + y / 16) % 2 == 0 { 60 } else { 0 };
            image::Rgb([(x * 255 / w) as u8, (y * 255 / h) as u8, 100 + edge])
        })
    }

    #[test]
    fn jpeg_encoding_round_trips_within_a_bounded_error() {
        let img = scene(64, 48);
        let jpeg = encode_jpeg(64, 48, img.as_raw(), 85).unwrap();
        assert!(jpeg.len() < img.as_raw().len() / 3, "{} bytes", jpeg.len());
        assert_eq!(header_size(Encoding::Jpeg, &jpeg).unwrap(), Some((64, 48)));
        let back = decode(Encoding::Jpeg, 64, 48, &jpeg).unwrap();
        let errors: Vec<i32> =
            img.as_raw().iter().zip(back.as_raw()).map(|(a, b)| (i32::from(*a) - i32::from(*b)).abs()).collect();
        let mean = errors.iter().sum::<i32>() as f64 / errors.len() as f64;
        assert!(mean < 3.0 && errors.iter().all(|e| *e < 48), "mean {mean}, max {:?}", errors.iter().max());
        // A lower quality is fewer bytes.
        assert!(encode_jpeg(64, 48, img.as_raw(), 30).unwrap().len() < jpeg.len());
    }

    #[test]
    fn jpeg_encoding_refuses_what_it_cannot_encode_without_panicking() {
        assert_eq!(encode_jpeg(2, 2, &[0; 12], 0).unwrap_err(), EncodeError::Quality(0));
        assert!(encode_jpeg(2, 2, &[0; 12], 101).unwrap_err().to_string().contains("outside 1..=100"));
        let short = encode_jpeg(2, 2, &[0; 11], 85).unwrap_err();
        assert!(matches!(short, EncodeError::Size(ImageError::WrongLength { got: 11, .. })), "{short}");
        assert!(short.to_string().starts_with("RGB8 data has 11 bytes"), "{short}");
        assert!(matches!(encode_jpeg(0, 2, &[], 85), Err(EncodeError::Size(ImageError::MissingSize { .. }))));
        assert!(matches!(encode_jpeg(MAX_SIDE + 1, 1, &[], 85), Err(EncodeError::Size(ImageError::TooLarge { .. }))));
        assert!(encode_jpeg(1, 1, &[1, 2, 3], 1).is_ok() && encode_jpeg(1, 1, &[1, 2, 3], 100).is_ok());
    }

    #[test]
    fn header_sizes_are_read_without_decoding() {
        let img = scene(40, 30);
        let mut png = Vec::new();
        img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png).unwrap();
        assert_eq!(header_size(Encoding::Png, &png).unwrap(), Some((40, 30)));
        assert_eq!(header_size(Encoding::Rgb8, &[]).unwrap(), None);
        let jpeg = encode_jpeg(40, 30, img.as_raw(), 85).unwrap();
        // Fill bytes before a marker are allowed.
        let mut filled = jpeg[..2].to_vec();
        filled.extend_from_slice(&[0xFF, 0xFF]);
        filled.extend_from_slice(&jpeg[2..]);
        assert_eq!(header_size(Encoding::Jpeg, &filled).unwrap(), Some((40, 30)));
        // A header that lies is read as it lies (the decoder then refuses the stream).
        let mut rng = vlnav_fuzzgen::case_rng(9, 0);
        let claiming = vlnav_fuzzgen::frames::jpeg_claiming(&mut rng, 640, 480, 10);
        assert_eq!(header_size(Encoding::Jpeg, &claiming).unwrap(), Some((640, 480)));
        for bad in [&jpeg[..jpeg.len() - 2], &jpeg[..40], &png[..], &[0xFF, 0xD8, 0xFF][..], &[][..]] {
            let e = header_size(Encoding::Jpeg, bad).unwrap_err();
            assert!(matches!(e, ImageError::Decode { format: "JPEG", .. }), "{e}");
        }
        for bad in [&png[..20], &jpeg[..]] {
            assert!(matches!(header_size(Encoding::Png, bad), Err(ImageError::Decode { format: "PNG", .. })));
        }
    }

    #[test]
    fn a_png_larger_than_the_cap_is_refused_by_the_decoder_limits() {
        // Declared 0×0 (unchecked), but the header says 9000×1.
        let img = image::GrayImage::new(MAX_SIDE + 808, 1);
        let mut png = Vec::new();
        img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png).unwrap();
        let e = decode(Encoding::Png, 0, 0, &png).unwrap_err();
        assert!(matches!(e, ImageError::Decode { format: "PNG", .. }), "{e}");
    }

    #[tokio::test]
    async fn off_thread_decoding_names_the_failing_image() {
        let good = EncodedImage { encoding: Encoding::Rgb8, width: 1, height: 1, data: vec![1, 2, 3].into() };
        let bad = EncodedImage { data: vec![1, 2].into(), ..good.clone() };
        assert_eq!(decode_off_thread(good.clone()).await.unwrap().into_raw(), vec![1, 2, 3]);
        let (i, e) = decode_all_off_thread(vec![good.clone(), bad, good]).await.unwrap_err();
        assert_eq!(i, 1);
        assert!(matches!(e, ImageError::WrongLength { got: 2, .. }), "{e}");
    }
}
