//! RVL, the lossless depth codec of A. D. Wilson, "Fast Lossless Depth Image
//! Compression" (ACM ISS 2017), for depth sent from a robot
//! (`DepthImage.encoding = DEPTH_ENCODING_RVL`, proto/vlnav/v1/common.proto;
//! docs/architecture.md, "Frames").
//!
//! The image is read in row-major order as alternating runs: a run of zeros
//! (no return) and a run of valid pixels, each run's length written as a
//! variable-length number, then each valid pixel as the zigzag-coded
//! difference to the previous valid pixel. Variable-length numbers are
//! written three bits at a time, low bits first, in nibbles whose high bit
//! says another nibble follows. As in the paper, nibbles are packed
//! high-first; here into bytes (two nibbles a byte), so a stream is a byte
//! string and its last byte may hold one unused low nibble of zero.
//!
//! Depth images are smooth with holes, so most differences fit a nibble or
//! two: a valid pixel costs half a byte at best, a quarter of its raw two
//! bytes, and a run of holes a nibble or two. On the simulator's noisy
//! 640×480 depth a frame shrinks to 33 % (`demo`) and 48 % (`lab`) of its raw
//! 614,400 bytes, encoded or decoded in about 1.1–1.5 ms
//! (`cargo bench -p vlnav-sim --bench depth_codec`).

/// Why an RVL stream cannot be decoded.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RvlError {
    #[error("the RVL stream ends after {decoded} of {expected} pixels")]
    Truncated { decoded: usize, expected: usize },
    #[error("the RVL stream runs past the image: {run} more pixels at pixel {at} of {expected}")]
    Overrun { run: u64, at: usize, expected: usize },
    #[error("the RVL stream holds a number too large for a 16-bit depth at pixel {at}")]
    Overflow { at: usize },
    #[error("the RVL stream has {extra} bytes after the last of its {expected} pixels")]
    Trailing { extra: usize, expected: usize },
}

struct NibbleWriter {
    out: Vec<u8>,
    half: bool,
}

impl NibbleWriter {
    fn nibble(&mut self, n: u8) {
        if self.half {
            *self.out.last_mut().expect("a half byte was started") |= n & 0x0F;
        } else {
            self.out.push(n << 4);
        }
        self.half = !self.half;
    }

    fn vle(&mut self, mut value: u64) {
        loop {
            let bits = (value & 0x7) as u8;
            value >>= 3;
            if value == 0 {
                self.nibble(bits);
                return;
            }
            self.nibble(bits | 0x8);
        }
    }
}

/// Compresses `depth` (millimetres, 0 = no return).
pub fn encode(depth: &[u16]) -> Vec<u8> {
    let mut w = NibbleWriter { out: Vec::with_capacity(depth.len() / 2), half: false };
    let mut previous = 0i32;
    let mut i = 0;
    while i < depth.len() {
        let zeros = depth[i..].iter().take_while(|&&d| d == 0).count();
        w.vle(zeros as u64);
        i += zeros;
        let valid = depth[i..].iter().take_while(|&&d| d != 0).count();
        w.vle(valid as u64);
        for &d in &depth[i..i + valid] {
            let delta = d as i32 - previous;
            w.vle(((delta << 1) ^ (delta >> 31)) as u32 as u64);
            previous = d as i32;
        }
        i += valid;
    }
    w.out
}

struct NibbleReader<'a> {
    data: &'a [u8],
    /// Nibbles read so far.
    pos: usize,
}

impl NibbleReader<'_> {
    fn nibble(&mut self) -> Option<u8> {
        let byte = *self.data.get(self.pos / 2)?;
        let n = if self.pos.is_multiple_of(2) { byte >> 4 } else { byte & 0x0F };
        self.pos += 1;
        Some(n)
    }

    /// A number of at most 33 bits (a run length or a zigzag difference).
    fn vle(&mut self) -> Option<Result<u64, ()>> {
        let mut value = 0u64;
        for shift in (0..36).step_by(3) {
            let n = self.nibble()?;
            value |= u64::from(n & 0x7) << shift;
            if n & 0x8 == 0 {
                return Some(Ok(value));
            }
        }
        Some(Err(()))
    }
}

/// Decompresses an RVL stream of exactly `pixels` pixels. Never allocates
/// more than `pixels` values, whatever the stream says.
pub fn decode(data: &[u8], pixels: usize) -> Result<Vec<u16>, RvlError> {
    let mut out = Vec::with_capacity(pixels);
    let mut r = NibbleReader { data, pos: 0 };
    let mut previous = 0i64;
    let truncated = |decoded| RvlError::Truncated { decoded, expected: pixels };
    let run = |r: &mut NibbleReader, at: usize| -> Result<usize, RvlError> {
        match r.vle() {
            None => Err(truncated(at)),
            Some(Err(())) => Err(RvlError::Overflow { at }),
            Some(Ok(run)) if run > (pixels - at) as u64 => Err(RvlError::Overrun { run, at, expected: pixels }),
            Some(Ok(run)) => Ok(run as usize),
        }
    };
    while out.len() < pixels {
        let zeros = run(&mut r, out.len())?;
        out.resize(out.len() + zeros, 0);
        if out.len() == pixels {
            // An encoder ends a trailing run of zeros with an empty run of valid pixels.
            if r.pos.div_ceil(2) < data.len() {
                let _ = run(&mut r, out.len())?;
            }
            break;
        }
        let valid = run(&mut r, out.len())?;
        for _ in 0..valid {
            let at = out.len();
            let z = match r.vle() {
                None => return Err(truncated(at)),
                Some(Err(())) => return Err(RvlError::Overflow { at }),
                Some(Ok(z)) => z as i64,
            };
            let delta = (z >> 1) ^ -(z & 1);
            let value = previous + delta;
            if !(1..=u16::MAX as i64).contains(&value) {
                return Err(RvlError::Overflow { at });
            }
            out.push(value as u16);
            previous = value;
        }
    }
    let used = r.pos.div_ceil(2);
    if used < data.len() {
        return Err(RvlError::Trailing { extra: data.len() - used, expected: pixels });
    }
    Ok(out)
}

/// [`decode`], as the little-endian bytes a raw `DepthImage` holds.
pub fn decode_le_bytes(data: &[u8], pixels: usize) -> Result<Vec<u8>, RvlError> {
    Ok(decode(data, pixels)?.iter().flat_map(|v| v.to_le_bytes()).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn round_trip(depth: &[u16]) -> usize {
        let packed = encode(depth);
        assert_eq!(decode(&packed, depth.len()).unwrap(), depth, "round trip of {depth:?}");
        packed.len()
    }

    #[test]
    fn every_kind_of_image_round_trips() {
        round_trip(&[]);
        round_trip(&[0]);
        round_trip(&[0, 0, 0]);
        round_trip(&[1]);
        round_trip(&[u16::MAX, 1, u16::MAX, 0, 0, 1, 0]);
        round_trip(&[500, 501, 499, 0, 0, 0, 7000, 7001]);
        let noise: Vec<u16> = (0..10_000u32).map(|i| (i.wrapping_mul(2_654_435_761) >> 16) as u16).collect();
        round_trip(&noise);
    }

    #[test]
    fn a_smooth_depth_image_with_holes_shrinks_to_under_a_third() {
        let (w, h) = (640usize, 480usize);
        let depth: Vec<u16> = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                // A floor getting farther up the image, a box, holes at its edges.
                if (300..304).contains(&x) && y > 200 {
                    0
                } else if (304..400).contains(&x) && y > 200 {
                    1500 + (y as u16 % 3)
                } else {
                    (800 + 40_000 / (y as u32 + 60)) as u16
                }
            })
            .collect();
        let bytes = round_trip(&depth);
        let raw = depth.len() * 2;
        // Half a byte a valid pixel at best: a quarter of the raw two bytes.
        assert!(bytes * 3 < raw, "{bytes} bytes against {raw} raw");
    }

    #[test]
    fn malformed_streams_are_refused_without_allocating_what_they_claim() {
        let depth = [1000u16, 1001, 0, 0, 1002];
        let good = encode(&depth);
        // Cut anywhere: refused, never a panic.
        for cut in 0..good.len() {
            assert!(decode(&good[..cut], depth.len()).is_err(), "cut at {cut}");
        }
        assert!(matches!(decode(&good, 4), Err(RvlError::Overrun { .. })));
        assert!(matches!(decode(&good, 6), Err(RvlError::Truncated { .. })));
        let mut long = good.clone();
        long.push(0);
        assert!(matches!(decode(&long, depth.len()), Err(RvlError::Trailing { extra: 1, .. })));
        // A run claiming billions of pixels, and a number that never ends.
        assert!(matches!(decode(&[0xFF, 0xFF, 0xFF, 0x70], 16), Err(RvlError::Overrun { .. })));
        assert!(matches!(decode(&[0xFF; 64], 16), Err(RvlError::Overflow { .. })));
        // A difference that leaves the u16 range.
        let mut w = NibbleWriter { out: Vec::new(), half: false };
        w.vle(0);
        w.vle(1);
        w.vle(1); // zigzag 1 = -1: depth -1
        assert!(matches!(decode(&w.out, 1), Err(RvlError::Overflow { at: 0 })));
    }

    #[test]
    fn random_bytes_never_panic() {
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        for _ in 0..20_000 {
            state = state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            let len = (state >> 58) as usize;
            let bytes: Vec<u8> = (0..len).map(|k| (state >> (k % 8 * 8)) as u8).collect();
            let _ = decode(&bytes, (state >> 40) as usize % 64);
        }
    }
}
