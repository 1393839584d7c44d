//! Depth images on the wire: little-endian u16 millimetres, row-major, 0 = no return.
//! And the RealSense D455's depth error, which the simulator draws and the
//! local planner allows for (docs/perception.md).

/// The D455's depth noise σ = k·z²: its ≤ 2 % RMS error at 4 m (0.08 m;
/// Intel RealSense D400 series datasheet, "D455 depth module") gives
/// k = 0.08 / 4² m⁻¹.
pub const D455_NOISE_K: f64 = 0.005;

/// The D455's depth noise standard deviation at `range_m`, metres.
pub fn d455_sigma_m(range_m: f64) -> f64 {
    D455_NOISE_K * range_m * range_m
}

/// A borrowed depth image: little-endian u16 millimetres, row-major, 0 = no return.
#[derive(Clone, Copy, Debug)]
pub struct DepthView<'a> {
    width: usize,
    height: usize,
    data: &'a [u8],
}

/// The depth buffer does not hold `width × height` u16 samples.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("depth image is {width}x{height} so data_mm must hold {expected} bytes (little-endian u16 mm), got {actual}")]
pub struct DepthSizeError {
    pub width: u32,
    pub height: u32,
    pub expected: usize,
    pub actual: usize,
}

impl<'a> DepthView<'a> {
    pub fn new(width: u32, height: u32, data: &'a [u8]) -> Result<Self, DepthSizeError> {
        // A declared size near u32::MAX a side overflows; it matches no buffer.
        let expected =
            (width as usize).checked_mul(height as usize).and_then(|p| p.checked_mul(2)).unwrap_or(usize::MAX);
        if data.len() != expected || expected == 0 {
            return Err(DepthSizeError { width, height, expected, actual: data.len() });
        }
        Ok(Self { width: width as usize, height: height as usize, data })
    }

    pub fn width(&self) -> usize {
        self.width
    }

    pub fn height(&self) -> usize {
        self.height
    }

    /// Raw reading at `(u, v)`, millimetres (0 = no return).
    #[inline]
    pub fn mm(&self, u: usize, v: usize) -> u16 {
        let i = 2 * (v * self.width + u);
        u16::from_le_bytes([self.data[i], self.data[i + 1]])
    }

    /// Every reading, row-major, millimetres.
    pub fn to_mm(&self) -> Vec<u16> {
        le_u16(self.data)
    }
}

/// Little-endian u16 samples (depth in mm, instance ids) as numbers; a
/// trailing odd byte is ignored (callers check the length first).
pub fn le_u16(bytes: &[u8]) -> Vec<u16> {
    bytes.chunks_exact(2).map(|b| u16::from_le_bytes([b[0], b[1]])).collect()
}

/// Encodes depth in metres as the wire format (little-endian u16 mm; values
/// that do not fit, NaN or ≤ 0 become 0 = no return). Used by tests and tools.
pub fn encode_depth_mm(depth_m: &[f64]) -> Vec<u8> {
    let mut out = Vec::with_capacity(depth_m.len() * 2);
    for &d in depth_m {
        let mm = if d.is_finite() && d > 0.0 { (d * 1000.0).round().min(u16::MAX as f64) as u16 } else { 0 };
        out.extend_from_slice(&mm.to_le_bytes());
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn depth_view_reads_little_endian_mm_and_checks_size() {
        let bytes = encode_depth_mm(&[1.0, 0.0, 2.5, 70.0]);
        let d = DepthView::new(2, 2, &bytes).unwrap();
        assert_eq!((d.mm(0, 0), d.mm(1, 0), d.mm(0, 1), d.mm(1, 1)), (1000, 0, 2500, 65535));
        assert_eq!(d.to_mm(), vec![1000, 0, 2500, 65535]);
        let err = DepthView::new(3, 2, &bytes).unwrap_err();
        assert_eq!(err.expected, 12);
        assert!(err.to_string().contains("must hold 12 bytes"));
        assert!(DepthView::new(0, 0, &[]).is_err());
        // A declared size whose byte count overflows is refused, not a panic.
        assert!(DepthView::new(u32::MAX, u32::MAX, &[0; 4]).is_err());
    }

    #[test]
    fn encoding_depth_clamps_and_marks_unusable_values_as_no_return() {
        assert_eq!(le_u16(&encode_depth_mm(&[f64::NAN, -1.0, 0.0004, 0.0006, 1e9])), vec![0, 0, 0, 1, u16::MAX]);
        assert_eq!(le_u16(&[1, 2, 3]), vec![0x0201]);
    }
}
