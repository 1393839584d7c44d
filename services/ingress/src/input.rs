//! From streamed bytes to what Whisper hears: chunks are assembled with the
//! duration limit enforced as soon as it is crossed (a long upload is
//! refused early, not buffered), then decoded, mixed to mono, resampled to
//! 16 kHz and trimmed of leading and trailing silence.

use crate::audio::{self, AudioError, Pcm, WavHeader};
use crate::resample::resample;
use crate::trim::{TrimConfig, speech_range};
use crate::whisper::SAMPLE_RATE;

/// How the streamed bytes are encoded (from the first chunk).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Encoding {
    /// Raw little-endian signed 16-bit mono samples at this rate.
    Pcm16Mono { sample_rate: u32 },
    /// A RIFF/WAVE file; the header names rate, sample format and channels.
    Wav,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum InputError {
    #[error(transparent)]
    Audio(#[from] AudioError),
    #[error("the audio is {seconds:.1} s long; at most {limit_s:.0} s is accepted")]
    TooLong { seconds: f64, limit_s: f64 },
    #[error(
        "no speech found: all {seconds:.1} s are silence (quieter than {floor_dbfs} dBFS or {relative_db} dB below the loudest part)"
    )]
    NoSpeech { seconds: f64, floor_dbfs: f64, relative_db: f64 },
}

/// Speech ready for the recogniser.
#[derive(Clone, Debug, PartialEq)]
pub struct Speech {
    /// Mono, 16 kHz, silence trimmed.
    pub samples: Vec<f32>,
    /// Length of the recording as received, seconds.
    pub input_seconds: f64,
}

impl Speech {
    /// Length after silence trimming, seconds.
    pub fn seconds(&self) -> f64 {
        self.samples.len() as f64 / SAMPLE_RATE as f64
    }
}

/// Collects the chunks of one upload.
#[derive(Debug)]
pub struct AudioAssembler {
    encoding: Encoding,
    max_seconds: f64,
    bytes: Vec<u8>,
    header: Option<WavHeader>,
}

impl AudioAssembler {
    pub fn new(encoding: Encoding, max_seconds: f64) -> Result<Self, InputError> {
        if let Encoding::Pcm16Mono { sample_rate } = encoding
            && !(audio::MIN_SAMPLE_RATE..=audio::MAX_SAMPLE_RATE).contains(&sample_rate)
        {
            return Err(AudioError::SampleRate(sample_rate).into());
        }
        Ok(Self { encoding, max_seconds, bytes: Vec::new(), header: None })
    }

    pub fn received_bytes(&self) -> usize {
        self.bytes.len()
    }

    /// Seconds of audio received so far (0 while a WAV header is incomplete).
    pub fn received_seconds(&self) -> f64 {
        match (self.encoding, &self.header) {
            (Encoding::Pcm16Mono { sample_rate }, _) => (self.bytes.len() / 2) as f64 / sample_rate as f64,
            (Encoding::Wav, Some(h)) => h.seconds_in(self.bytes.len() - h.data_offset),
            (Encoding::Wav, None) => 0.0,
        }
    }

    /// Appends a chunk; fails as soon as the bytes cannot be valid audio or
    /// the recording is longer than the limit (by its header or by what arrived).
    pub fn push(&mut self, chunk: &[u8]) -> Result<(), InputError> {
        self.bytes.extend_from_slice(chunk);
        if self.encoding == Encoding::Wav && self.header.is_none() && !self.bytes.is_empty() {
            self.header = audio::parse_wav_header(&self.bytes)?;
            if let Some(h) = &self.header
                && let Some(declared) = h.data_len
            {
                let seconds = h.seconds_in(declared);
                if seconds > self.max_seconds {
                    return Err(InputError::TooLong { seconds, limit_s: self.max_seconds });
                }
            }
        }
        let seconds = self.received_seconds();
        if seconds > self.max_seconds {
            return Err(InputError::TooLong { seconds, limit_s: self.max_seconds });
        }
        Ok(())
    }

    /// Decodes what arrived: mono 16 kHz speech with silence trimmed.
    pub fn finish(self, trim: &TrimConfig) -> Result<Speech, InputError> {
        let pcm = match self.encoding {
            Encoding::Pcm16Mono { sample_rate } => audio::decode_pcm16_mono(&self.bytes, sample_rate)?,
            Encoding::Wav => audio::decode_wav(&self.bytes)?,
        };
        prepare(pcm, self.max_seconds, trim)
    }
}

/// Checks the duration, resamples to 16 kHz and trims silence.
pub fn prepare(pcm: Pcm, max_seconds: f64, trim: &TrimConfig) -> Result<Speech, InputError> {
    let input_seconds = pcm.duration_s();
    if input_seconds > max_seconds {
        return Err(InputError::TooLong { seconds: input_seconds, limit_s: max_seconds });
    }
    let mono16k = resample(&pcm.samples, pcm.sample_rate, SAMPLE_RATE);
    let range = speech_range(&mono16k, SAMPLE_RATE, trim).ok_or(InputError::NoSpeech {
        seconds: input_seconds,
        floor_dbfs: trim.floor_dbfs,
        relative_db: trim.relative_db,
    })?;
    Ok(Speech { samples: mono16k[range].to_vec(), input_seconds })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::audio::{SampleEncoding, encode_wav};

    fn speechlike(rate: u32, silence_s: f64, voiced_s: f64) -> Vec<f32> {
        let n = |s: f64| (s * rate as f64) as usize;
        let mut x = vec![0.0; n(silence_s)];
        x.extend((0..n(voiced_s)).map(|i| (i as f32 * 2.0 * std::f32::consts::PI * 220.0 / rate as f32).sin() * 0.4));
        x.extend(vec![0.0; n(silence_s)]);
        x
    }

    #[test]
    fn a_wav_in_small_chunks_becomes_trimmed_16k_speech() {
        let wav = encode_wav(&speechlike(44_100, 1.0, 2.0), 1, 44_100, SampleEncoding::I16);
        let mut a = AudioAssembler::new(Encoding::Wav, 60.0).unwrap();
        for chunk in wav.chunks(7) {
            a.push(chunk).unwrap();
        }
        assert!((a.received_seconds() - 4.0).abs() < 1e-3);
        let speech = a.finish(&TrimConfig::default()).unwrap();
        assert!((speech.input_seconds - 4.0).abs() < 1e-3);
        assert!((speech.seconds() - 2.4).abs() < 0.05, "trimmed to {} s", speech.seconds());
    }

    #[test]
    fn raw_pcm16_is_accepted_at_its_own_rate() {
        let samples = speechlike(8_000, 0.5, 1.0);
        let bytes: Vec<u8> = samples.iter().flat_map(|s| ((s * 32_767.0) as i16).to_le_bytes()).collect();
        let mut a = AudioAssembler::new(Encoding::Pcm16Mono { sample_rate: 8_000 }, 60.0).unwrap();
        a.push(&bytes).unwrap();
        let speech = a.finish(&TrimConfig::default()).unwrap();
        assert!((speech.seconds() - 1.4).abs() < 0.05);
        assert_eq!(
            AudioAssembler::new(Encoding::Pcm16Mono { sample_rate: 0 }, 60.0).unwrap_err(),
            InputError::Audio(AudioError::SampleRate(0))
        );
    }

    #[test]
    fn an_over_long_recording_is_refused_by_its_header_before_the_data_arrives() {
        let wav = encode_wav(&vec![0.1; 16_000 * 61], 1, 16_000, SampleEncoding::I16);
        let mut a = AudioAssembler::new(Encoding::Wav, 60.0).unwrap();
        let err = a.push(&wav[..64]).unwrap_err();
        assert!(matches!(err, InputError::TooLong { seconds, .. } if (seconds - 61.0).abs() < 1e-6), "{err}");
    }

    #[test]
    fn an_over_long_stream_is_refused_once_the_limit_is_crossed() {
        let mut a = AudioAssembler::new(Encoding::Pcm16Mono { sample_rate: 16_000 }, 2.0).unwrap();
        let second = vec![0u8; 32_000];
        a.push(&second).unwrap();
        a.push(&second).unwrap();
        assert!(matches!(a.push(&second[..2]), Err(InputError::TooLong { .. })));
    }

    #[test]
    fn silence_and_emptiness_are_errors_that_say_so() {
        let mut a = AudioAssembler::new(Encoding::Wav, 60.0).unwrap();
        a.push(&encode_wav(&vec![0.0; 16_000], 1, 16_000, SampleEncoding::I16)).unwrap();
        assert!(matches!(a.finish(&TrimConfig::default()), Err(InputError::NoSpeech { .. })));
        let a = AudioAssembler::new(Encoding::Wav, 60.0).unwrap();
        assert_eq!(a.finish(&TrimConfig::default()), Err(InputError::Audio(AudioError::Empty)));
        let mut a = AudioAssembler::new(Encoding::Wav, 60.0).unwrap();
        assert!(matches!(a.push(b"OggS\0\0\0\0"), Err(InputError::Audio(AudioError::NotWav(_)))));
    }
}
