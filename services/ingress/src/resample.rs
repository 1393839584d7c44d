//! Band-limited sample-rate conversion: a polyphase windowed-sinc resampler
//! (Kaiser window) for any rational ratio. Downsampling low-passes at the new
//! Nyquist frequency first, so content above it is removed instead of being
//! folded back into the speech band.

/// Zero crossings of the sinc kept on each side of the centre tap.
const ZERO_CROSSINGS: f64 = 16.0;
/// Pass-band edge as a fraction of the lower Nyquist frequency.
const ROLL_OFF: f64 = 0.94;
/// Kaiser window shape: ~80 dB stop-band attenuation.
const KAISER_BETA: f64 = 8.0;

fn gcd(a: u64, b: u64) -> u64 {
    if b == 0 { a } else { gcd(b, a % b) }
}

/// Zeroth-order modified Bessel function of the first kind (power series).
fn bessel_i0(x: f64) -> f64 {
    let mut sum = 1.0;
    let mut term = 1.0;
    let q = x * x / 4.0;
    for k in 1..64 {
        term *= q / (k * k) as f64;
        sum += term;
        if term < sum * 1e-12 {
            break;
        }
    }
    sum
}

/// Converts `input` sampled at `from_hz` to `to_hz`. The output has
/// `ceil(len · to / from)` samples; sample `n` is the band-limited value of
/// the input at time `n / to_hz`.
pub fn resample(input: &[f32], from_hz: u32, to_hz: u32) -> Vec<f32> {
    assert!(from_hz > 0 && to_hz > 0, "sample rates must be positive");
    if from_hz == to_hz || input.is_empty() {
        return input.to_vec();
    }
    let g = gcd(from_hz as u64, to_hz as u64);
    let up = (to_hz as u64 / g) as usize; // L: output samples per period
    let down = (from_hz as u64 / g) as usize; // M: input samples per period
    // Cut-off in cycles per input sample.
    let cutoff = 0.5 * ROLL_OFF * (up as f64 / down as f64).min(1.0);
    let half_width = ZERO_CROSSINGS / (2.0 * cutoff); // input samples each side
    let reach = half_width.ceil() as isize;
    let taps = 2 * reach as usize;
    let norm = bessel_i0(KAISER_BETA);

    // One filter per output phase: output n sits at input time n·M/L =
    // base + p/L with p = n·M mod L; tap j (j = -reach+1 ..= reach) reads
    // input[base + j] at distance j − p/L.
    let mut table = vec![0f32; up * taps];
    for p in 0..up {
        let frac = p as f64 / up as f64;
        let row = &mut table[p * taps..(p + 1) * taps];
        let mut sum = 0.0;
        let mut weights = vec![0f64; taps];
        for (slot, w) in weights.iter_mut().enumerate() {
            let j = slot as isize - reach + 1;
            let t = j as f64 - frac;
            let r = t / half_width;
            if r.abs() >= 1.0 {
                continue;
            }
            let x = 2.0 * cutoff * t;
            let sinc =
                if x.abs() < 1e-12 { 1.0 } else { (std::f64::consts::PI * x).sin() / (std::f64::consts::PI * x) };
            let window = bessel_i0(KAISER_BETA * (1.0 - r * r).sqrt()) / norm;
            *w = 2.0 * cutoff * sinc * window;
            sum += *w;
        }
        // Unity gain at DC for every phase.
        for (dst, w) in row.iter_mut().zip(&weights) {
            *dst = (w / sum) as f32;
        }
    }

    let out_len = (input.len() as u64 * up as u64).div_ceil(down as u64) as usize;
    let mut out = Vec::with_capacity(out_len);
    let n_in = input.len() as isize;
    for n in 0..out_len {
        let pos = n as u64 * down as u64;
        let base = (pos / up as u64) as isize;
        let phase = (pos % up as u64) as usize;
        let row = &table[phase * taps..(phase + 1) * taps];
        let first = base - reach + 1;
        let acc = if first >= 0 && first + taps as isize <= n_in {
            let window = &input[first as usize..first as usize + taps];
            window.iter().zip(row).map(|(x, w)| x * w).sum::<f32>()
        } else {
            // Near the ends: samples outside the signal are zero.
            row.iter()
                .enumerate()
                .filter_map(|(k, w)| {
                    let i = first + k as isize;
                    (0..n_in).contains(&i).then(|| input[i as usize] * w)
                })
                .sum()
        };
        out.push(acc);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tone(freq: f64, rate: u32, seconds: f64) -> Vec<f32> {
        let n = (rate as f64 * seconds) as usize;
        (0..n).map(|i| (2.0 * std::f64::consts::PI * freq * i as f64 / rate as f64).sin() as f32 * 0.5).collect()
    }

    /// RMS of the middle half (away from the edge transients).
    fn mid_rms(x: &[f32]) -> f64 {
        let mid = &x[x.len() / 4..3 * x.len() / 4];
        (mid.iter().map(|v| (*v as f64).powi(2)).sum::<f64>() / mid.len() as f64).sqrt()
    }

    /// Amplitude of `freq` in `x` (correlation with a complex exponential).
    fn amplitude_at(x: &[f32], rate: u32, freq: f64) -> f64 {
        let mid = &x[x.len() / 4..3 * x.len() / 4];
        let (mut re, mut im) = (0.0, 0.0);
        for (i, v) in mid.iter().enumerate() {
            let ph = 2.0 * std::f64::consts::PI * freq * i as f64 / rate as f64;
            re += *v as f64 * ph.cos();
            im += *v as f64 * ph.sin();
        }
        2.0 * (re * re + im * im).sqrt() / mid.len() as f64
    }

    #[test]
    fn output_length_follows_the_ratio() {
        assert_eq!(resample(&vec![0.0; 44_100], 44_100, 16_000).len(), 16_000);
        assert_eq!(resample(&vec![0.0; 22_050], 22_050, 16_000).len(), 16_000);
        assert_eq!(resample(&vec![0.0; 8_000], 8_000, 16_000).len(), 16_000);
        assert_eq!(resample(&[0.0; 3], 48_000, 16_000).len(), 1);
        assert_eq!(resample(&[0.1, 0.2], 16_000, 16_000), vec![0.1, 0.2]);
    }

    #[test]
    fn a_pass_band_tone_keeps_its_frequency_and_level() {
        for from in [8_000, 22_050, 44_100, 48_000] {
            let x = tone(1_000.0, from, 1.0);
            let y = resample(&x, from, 16_000);
            let a = amplitude_at(&y, 16_000, 1_000.0);
            assert!((a - 0.5).abs() < 0.01, "{from} Hz: amplitude {a}");
            assert!((mid_rms(&y) - 0.5 / 2f64.sqrt()).abs() < 0.01, "{from} Hz: rms {}", mid_rms(&y));
        }
    }

    #[test]
    fn content_above_the_new_nyquist_is_removed_not_aliased() {
        // 10 kHz at 44.1 kHz would fold to 6 kHz at 16 kHz without the low-pass.
        let x = tone(10_000.0, 44_100, 1.0);
        let y = resample(&x, 44_100, 16_000);
        assert!(mid_rms(&y) < 0.5 * 1e-3, "residual rms {}", mid_rms(&y));
        assert!(amplitude_at(&y, 16_000, 6_000.0) < 1e-3);
    }

    #[test]
    fn dc_is_preserved_exactly_inside_the_signal() {
        let y = resample(&vec![0.3; 22_050], 22_050, 16_000);
        let mid = &y[1_000..15_000];
        assert!(mid.iter().all(|v| (v - 0.3).abs() < 1e-5));
    }
}
