//! A depth codec with a bounded error for the robot link
//! (`DepthImage.encoding = DEPTH_ENCODING_DISPARITY`,
//! proto/vlnav/v1/common.proto; docs/architecture.md, "Frames").
//!
//! A stereo camera measures disparity, not depth: its noise is the same
//! everywhere in disparity (1/z), which is why depth noise grows as z²
//! (the D455's σ = k·z², k = 0.005 m⁻¹; `crates/simulator/src/camera_config.rs`).
//! So the codec quantises disparity with a fixed step `s` (m⁻¹): a pixel of
//! depth z becomes the integer `round(1/(z·s))`, and decodes to within `s/2`
//! of its disparity, that is within about `s/2 · z²` of its depth
//! ([`max_error_mm`]): with `s` = k, half the camera's own noise at every
//! range (2.5 mm at 1 m, 10 mm at 2 m, 40 mm at 4 m). A pixel with no
//! return (0) stays 0 and every other pixel stays a valid depth.
//!
//! The integers are then coded losslessly: each is predicted from its
//! decoded left and upper neighbours, and the differences, one byte each
//! for the common small ones, are compressed with zstd. On a surface the
//! difference is the camera noise in units of the step, the same at every
//! range, so a few bits a pixel.

use std::io;

/// The D455's depth noise in disparity, m⁻¹ (σ_z = k·z²): the default step,
/// which keeps every pixel within half the camera's own noise.
pub const D455_STEP_PER_M: f32 = 0.005;
/// Steps outside this range are refused: below it the integers outgrow what
/// the link needs; above it far pixels would round to no disparity at all.
pub const MIN_STEP_PER_M: f32 = 1e-4;
pub const MAX_STEP_PER_M: f32 = 0.03;

/// zstd's level: 1 is its fastest, and higher levels gain little on noise.
const ZSTD_LEVEL: i32 = 1;
/// Byte of a pixel with no return.
const HOLE: u8 = 0;
/// Byte that introduces a difference too large for one byte; four
/// little-endian bytes of the zigzag-coded difference follow.
const ESCAPE: u8 = 255;
/// Zigzag differences below this take one byte (`1 + difference`).
const SHORT: u32 = (ESCAPE - 1) as u32;

/// Why a stream cannot be decoded, or a step is refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DisparityError {
    #[error(
        "the disparity step {0} m⁻¹ is outside [{MIN_STEP_PER_M}, {MAX_STEP_PER_M}] (the D455's own noise is {D455_STEP_PER_M})"
    )]
    Step(f32),
    #[error("the zstd stream does not decode: {0}")]
    Zstd(String),
    #[error("the stream ends after {decoded} of {expected} pixels")]
    Truncated { decoded: usize, expected: usize },
    #[error("the stream has {extra} bytes after the last of its {expected} pixels")]
    Trailing { extra: usize, expected: usize },
    #[error("the stream's difference at pixel {at} leads outside the disparities a 16-bit depth can have")]
    OutOfRange { at: usize },
}

/// Checks a step (m⁻¹).
pub fn check_step(step_per_m: f32) -> Result<f64, DisparityError> {
    if step_per_m.is_finite() && (MIN_STEP_PER_M..=MAX_STEP_PER_M).contains(&step_per_m) {
        Ok(step_per_m as f64)
    } else {
        Err(DisparityError::Step(step_per_m))
    }
}

/// The quantised disparity of a depth in millimetres (0 for no return).
fn quantise(mm: u16, step: f64) -> u32 {
    if mm == 0 { 0 } else { ((1000.0 / (mm as f64 * step)).round() as u32).max(1) }
}

/// The depth in millimetres of a quantised disparity (0 for no return).
fn dequantise(q: u32, step: f64) -> u16 {
    if q == 0 { 0 } else { (1000.0 / (q as f64 * step)).round().clamp(1.0, u16::MAX as f64) as u16 }
}

/// The largest quantised disparity of a step (that of 1 mm).
fn max_code(step: f64) -> u32 {
    quantise(1, step)
}

/// The most a depth of `mm` can move through the codec with `step_per_m`:
/// half a step of disparity, and half a millimetre of rounding.
pub fn max_error_mm(mm: u16, step_per_m: f32) -> f64 {
    if mm == 0 {
        return 0.0;
    }
    let z = mm as f64 / 1000.0;
    let half = step_per_m as f64 / 2.0;
    // 1/z' = 1/z ± s/2, so z' - z ≤ z²·(s/2) / (1 - z·s/2) on the far side.
    let far = z * z * half / (1.0 - z * half).max(1e-9);
    (far * 1000.0).min(u16::MAX as f64) + 0.5
}

/// The prediction of pixel `i` of row width `width` from the decoded
/// integers before it: the mean of the left and upper neighbours that have a
/// return, else whichever has one, else the upper-left or upper-right one,
/// else the last pixel with a return in scan order.
#[inline]
fn predict(q: &[u32], i: usize, width: usize, last: u32) -> u32 {
    let x = i % width;
    let left = if x > 0 { q[i - 1] } else { 0 };
    let up = if i >= width { q[i - width] } else { 0 };
    match (left, up) {
        (0, 0) => {
            let upleft = if x > 0 && i >= width { q[i - width - 1] } else { 0 };
            let upright = if x + 1 < width && i >= width { q[i - width + 1] } else { 0 };
            if upleft != 0 {
                upleft
            } else if upright != 0 {
                upright
            } else {
                last
            }
        }
        (l, 0) => l,
        (0, u) => u,
        (l, u) => (l + u).div_ceil(2),
    }
}

#[inline]
fn zigzag(d: i64) -> u32 {
    ((d << 1) ^ (d >> 63)) as u32
}

#[inline]
fn unzigzag(z: u32) -> i64 {
    (z >> 1) as i64 ^ -((z & 1) as i64)
}

/// Compresses `depth` (millimetres, 0 = no return), rows of `width` pixels,
/// quantising disparity with `step_per_m`.
pub fn encode(depth: &[u16], width: usize, step_per_m: f32) -> Result<Vec<u8>, DisparityError> {
    let step = check_step(step_per_m)?;
    let width = width.max(1);
    let mut q = Vec::with_capacity(depth.len());
    let mut bytes = Vec::with_capacity(depth.len() + depth.len() / 8);
    let mut last = 0u32;
    for (i, &mm) in depth.iter().enumerate() {
        let code = quantise(mm, step);
        if code == 0 {
            bytes.push(HOLE);
        } else {
            let z = zigzag(code as i64 - predict(&q, i, width, last) as i64);
            if z < SHORT {
                bytes.push(1 + z as u8);
            } else {
                bytes.push(ESCAPE);
                bytes.extend_from_slice(&z.to_le_bytes());
            }
            last = code;
        }
        q.push(code);
    }
    zstd::bulk::compress(&bytes, ZSTD_LEVEL).map_err(|e| DisparityError::Zstd(e.to_string()))
}

/// Decompresses a stream of exactly `width`·`height` pixels written with
/// `step_per_m`. Never allocates more than the image's worst case, whatever
/// the stream says.
pub fn decode(data: &[u8], width: usize, height: usize, step_per_m: f32) -> Result<Vec<u16>, DisparityError> {
    let step = check_step(step_per_m)?;
    let pixels = width * height;
    let width = width.max(1);
    // Every pixel escaped is the most a valid stream can hold.
    let bytes = zstd::bulk::decompress(data, pixels * 5).map_err(|e: io::Error| DisparityError::Zstd(e.to_string()))?;
    let top = max_code(step);
    let mut q: Vec<u32> = Vec::with_capacity(pixels);
    let mut out = Vec::with_capacity(pixels);
    let mut last = 0u32;
    let mut at = 0;
    while q.len() < pixels {
        let i = q.len();
        let truncated = || DisparityError::Truncated { decoded: i, expected: pixels };
        let b = *bytes.get(at).ok_or_else(truncated)?;
        at += 1;
        if b == HOLE {
            q.push(0);
            out.push(0);
            continue;
        }
        let z = if b == ESCAPE {
            let four = bytes.get(at..at + 4).ok_or_else(truncated)?;
            at += 4;
            u32::from_le_bytes(four.try_into().expect("four bytes"))
        } else {
            (b - 1) as u32
        };
        let code = predict(&q, i, width, last) as i64 + unzigzag(z);
        if !(1..=top as i64).contains(&code) {
            return Err(DisparityError::OutOfRange { at: i });
        }
        let code = code as u32;
        q.push(code);
        out.push(dequantise(code, step));
        last = code;
    }
    if at != bytes.len() {
        return Err(DisparityError::Trailing { extra: bytes.len() - at, expected: pixels });
    }
    Ok(out)
}

/// [`decode`] into little-endian bytes, as `DepthImage.data_mm` holds raw depth.
pub fn decode_le_bytes(data: &[u8], width: usize, height: usize, step_per_m: f32) -> Result<Vec<u8>, DisparityError> {
    Ok(decode(data, width, height, step_per_m)?.iter().flat_map(|d| d.to_le_bytes()).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng, rngs::StdRng};

    #[test]
    fn every_depth_comes_back_within_its_bound_and_holes_stay_holes() {
        for step in [MIN_STEP_PER_M, 0.001, D455_STEP_PER_M, 0.01, MAX_STEP_PER_M] {
            let all: Vec<u16> = (0..=u16::MAX).collect();
            let back = decode(&encode(&all, 256, step).unwrap(), 256, 256, step).unwrap();
            for (&d, &b) in all.iter().zip(&back) {
                assert_eq!(d == 0, b == 0, "step {step}: {d} mm came back as {b} mm");
                let err = (d as f64 - b as f64).abs();
                assert!(err <= max_error_mm(d, step), "step {step}: {d} mm came back as {b} mm");
            }
        }
    }

    #[test]
    fn the_bound_is_half_the_d455_noise() {
        // σ = k·z² with k = 0.005 m⁻¹: 5 mm at 1 m, 20 mm at 2 m, 80 mm at 4 m.
        for (mm, sigma) in [(1000u16, 5.0), (2000, 20.0), (4000, 80.0)] {
            let bound = max_error_mm(mm, D455_STEP_PER_M);
            assert!(bound <= sigma / 2.0 * 1.02 + 0.5, "{mm} mm: ±{bound} mm");
        }
    }

    /// A tilted plane with camera-like noise and holes, as a floor looks.
    fn noisy_floor(width: usize, height: usize, seed: u64) -> Vec<u16> {
        let mut rng = StdRng::seed_from_u64(seed);
        (0..width * height)
            .map(|i| {
                let (x, y) = ((i % width) as f64, (i / width) as f64);
                let z = 1.0 + 6.0 * (1.0 - y / height as f64) + 0.002 * x;
                if rng.random::<f64>() < 0.03 {
                    return 0;
                }
                let n: f64 = rng.random::<f64>() + rng.random::<f64>() + rng.random::<f64>() - 1.5;
                ((z + n * 0.005 * z * z) * 1000.0).round() as u16
            })
            .collect()
    }

    #[test]
    fn a_noisy_surface_takes_a_fraction_of_its_raw_bytes() {
        let (w, h) = (160, 120);
        let depth = noisy_floor(w, h, 7);
        let packed = encode(&depth, w, D455_STEP_PER_M).unwrap();
        assert!(packed.len() * 5 < depth.len() * 2, "{} of {} raw bytes", packed.len(), depth.len() * 2);
        let back = decode(&packed, w, h, D455_STEP_PER_M).unwrap();
        assert!(
            depth.iter().zip(&back).all(|(&d, &b)| (d as f64 - b as f64).abs() <= max_error_mm(d, D455_STEP_PER_M))
        );
    }

    #[test]
    fn broken_streams_and_steps_are_refused_not_trusted() {
        let (w, h) = (32, 24);
        let depth = noisy_floor(w, h, 3);
        let packed = encode(&depth, w, D455_STEP_PER_M).unwrap();
        // Another size: too few or too many pixels in the stream.
        assert!(matches!(decode(&packed, w, h + 1, D455_STEP_PER_M), Err(DisparityError::Truncated { .. })));
        assert!(matches!(decode(&packed, w, h - 1, D455_STEP_PER_M), Err(DisparityError::Trailing { .. })));
        // Not zstd at all.
        assert!(matches!(decode(&[1, 2, 3], w, h, D455_STEP_PER_M), Err(DisparityError::Zstd(_))));
        // A difference that leaves the range of depths.
        let wild = zstd::bulk::compress(&[ESCAPE, 0xFF, 0xFF, 0xFF, 0x7F], 1).unwrap();
        assert_eq!(decode(&wild, 1, 1, D455_STEP_PER_M), Err(DisparityError::OutOfRange { at: 0 }));
        for step in [0.0, -1.0, f32::NAN, 1.0] {
            assert!(matches!(encode(&depth, w, step), Err(DisparityError::Step(_))));
            assert!(matches!(decode(&packed, w, h, step), Err(DisparityError::Step(_))));
        }
    }

    #[test]
    fn random_bytes_never_panic_nor_allocate_past_the_image() {
        let mut rng = StdRng::seed_from_u64(11);
        for _ in 0..500 {
            let len = rng.random_range(0..64);
            let junk: Vec<u8> = (0..len).map(|_| rng.random()).collect();
            let _ = decode(&junk, 8, 8, D455_STEP_PER_M);
            let framed = zstd::bulk::compress(&junk, 1).unwrap();
            if let Ok(d) = decode(&framed, 8, 8, D455_STEP_PER_M) {
                assert_eq!(d.len(), 64);
            }
        }
    }
}
