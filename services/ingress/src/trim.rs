//! Energy-based silence trimming: frames whose RMS level is within
//! `relative_db` of the loudest frame (and above an absolute floor) count as
//! speech; everything before the first and after the last such frame, less a
//! short margin, is dropped.

use std::ops::Range;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrimConfig {
    /// Analysis frame length, seconds.
    pub frame_s: f64,
    /// Frames quieter than the loudest frame by more than this are silence, dB.
    pub relative_db: f64,
    /// Frames below this level are silence whatever the loudest frame, dBFS.
    pub floor_dbfs: f64,
    /// Kept before the first and after the last speech frame (soft onsets
    /// and trailing consonants), seconds.
    pub margin_s: f64,
}

impl Default for TrimConfig {
    fn default() -> Self {
        Self { frame_s: 0.02, relative_db: 40.0, floor_dbfs: -55.0, margin_s: 0.2 }
    }
}

/// RMS level of `x` in dB relative to full scale (−∞ for digital silence).
pub fn rms_dbfs(x: &[f32]) -> f64 {
    if x.is_empty() {
        return f64::NEG_INFINITY;
    }
    let ms = x.iter().map(|v| (*v as f64) * (*v as f64)).sum::<f64>() / x.len() as f64;
    10.0 * ms.log10()
}

/// The sample range that holds speech, or `None` when every frame is silence.
pub fn speech_range(samples: &[f32], sample_rate: u32, cfg: &TrimConfig) -> Option<Range<usize>> {
    let frame = ((cfg.frame_s * sample_rate as f64).round() as usize).max(1);
    let levels: Vec<f64> = samples.chunks(frame).map(rms_dbfs).collect();
    let peak = levels.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let threshold = cfg.floor_dbfs.max(peak - cfg.relative_db);
    let first = levels.iter().position(|&l| l > threshold)?;
    let last = levels.iter().rposition(|&l| l > threshold)?;
    let margin = (cfg.margin_s * sample_rate as f64).round() as usize;
    let start = (first * frame).saturating_sub(margin);
    let end = ((last + 1) * frame + margin).min(samples.len());
    Some(start..end)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn burst(rate: u32, silence_s: f64, tone_s: f64, tail_s: f64, noise: f32) -> Vec<f32> {
        let n = |s: f64| (s * rate as f64) as usize;
        let mut x = Vec::new();
        let mut seed = 1u32;
        let mut hiss = || {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            ((seed >> 8) as f32 / (1u32 << 24) as f32 - 0.5) * 2.0 * noise
        };
        for _ in 0..n(silence_s) {
            x.push(hiss());
        }
        for i in 0..n(tone_s) {
            x.push((i as f32 * 0.07).sin() * 0.3 + hiss());
        }
        for _ in 0..n(tail_s) {
            x.push(hiss());
        }
        x
    }

    #[test]
    fn leading_and_trailing_silence_is_cut_with_a_margin() {
        let rate = 16_000;
        let x = burst(rate, 1.0, 2.0, 1.5, 1e-4);
        let r = speech_range(&x, rate, &TrimConfig::default()).unwrap();
        let (start_s, end_s) = (r.start as f64 / rate as f64, r.end as f64 / rate as f64);
        assert!((start_s - 0.8).abs() < 0.03, "start {start_s}");
        assert!((end_s - 3.2).abs() < 0.03, "end {end_s}");
    }

    #[test]
    fn background_noise_close_to_the_speech_level_is_kept() {
        // 20 dB signal-to-noise: nothing is trimmed.
        let x = burst(16_000, 1.0, 1.0, 1.0, 0.05);
        let r = speech_range(&x, 16_000, &TrimConfig::default()).unwrap();
        assert_eq!(r, 0..x.len());
    }

    #[test]
    fn silence_only_has_no_speech() {
        assert_eq!(speech_range(&vec![0.0; 16_000], 16_000, &TrimConfig::default()), None);
        assert_eq!(speech_range(&burst(16_000, 1.0, 0.0, 0.0, 1e-4), 16_000, &TrimConfig::default()), None);
        assert_eq!(speech_range(&[], 16_000, &TrimConfig::default()), None);
    }

    #[test]
    fn levels_are_in_dbfs() {
        assert!((rms_dbfs(&[1.0, -1.0]) - 0.0).abs() < 1e-9);
        assert!((rms_dbfs(&[0.1; 8]) + 20.0).abs() < 1e-6);
        assert_eq!(rms_dbfs(&[0.0; 4]), f64::NEG_INFINITY);
    }
}
