//! Audio decoding: the two encodings the contract allows — raw little-endian
//! PCM16 mono, and RIFF/WAVE (PCM 8/16/24/32-bit or IEEE float, any channel
//! count) — into mono `f32` samples in [-1, 1] at the recording's own rate.

use std::fmt;

/// Lowest and highest sample rates accepted (telephone to studio).
pub const MIN_SAMPLE_RATE: u32 = 4_000;
pub const MAX_SAMPLE_RATE: u32 = 384_000;
/// Most channels a WAV may carry (7.1 surround).
pub const MAX_CHANNELS: u16 = 8;
/// A WAV whose `data` chunk has not started this far into the file is rejected.
pub const MAX_WAV_HEADER_BYTES: usize = 1 << 20;

/// Mono samples in [-1, 1] at `sample_rate` Hz.
#[derive(Clone, Debug, PartialEq)]
pub struct Pcm {
    pub samples: Vec<f32>,
    pub sample_rate: u32,
}

impl Pcm {
    pub fn duration_s(&self) -> f64 {
        self.samples.len() as f64 / self.sample_rate as f64
    }
}

/// Why a byte stream is not audio we can use.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AudioError {
    #[error("the audio is empty (no samples)")]
    Empty,
    #[error("not a RIFF/WAVE file: {0}")]
    NotWav(String),
    #[error("unsupported WAV encoding: {0}; supported are PCM 8/16/24/32-bit integer and IEEE float 32/64-bit")]
    UnsupportedEncoding(String),
    #[error("malformed WAV: {0}")]
    MalformedWav(String),
    #[error("the audio stream ended early: the WAV header declares {declared} data bytes but only {received} arrived")]
    Truncated { declared: usize, received: usize },
    #[error("sample rate {0} Hz is outside the supported {MIN_SAMPLE_RATE}–{MAX_SAMPLE_RATE} Hz")]
    SampleRate(u32),
    #[error("PCM16 data must be whole 2-byte samples, got {0} bytes")]
    OddPcm16Length(usize),
}

/// How one sample of one channel is stored in a WAV `data` chunk.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SampleEncoding {
    U8,
    I16,
    I24,
    I32,
    F32,
    F64,
}

impl SampleEncoding {
    pub fn bytes(self) -> usize {
        match self {
            Self::U8 => 1,
            Self::I16 => 2,
            Self::I24 => 3,
            Self::I32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }

    fn decode(self, b: &[u8]) -> f32 {
        match self {
            Self::U8 => (b[0] as f32 - 128.0) / 128.0,
            Self::I16 => i16::from_le_bytes([b[0], b[1]]) as f32 / 32_768.0,
            Self::I24 => (i32::from_le_bytes([0, b[0], b[1], b[2]]) >> 8) as f32 / 8_388_608.0,
            Self::I32 => i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f32 / 2_147_483_648.0,
            Self::F32 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]).clamp(-1.0, 1.0),
            Self::F64 => (f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]) as f32).clamp(-1.0, 1.0),
        }
    }
}

impl fmt::Display for SampleEncoding {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::U8 => "PCM 8-bit",
            Self::I16 => "PCM 16-bit",
            Self::I24 => "PCM 24-bit",
            Self::I32 => "PCM 32-bit",
            Self::F32 => "float 32-bit",
            Self::F64 => "float 64-bit",
        })
    }
}

/// What the RIFF header says about the samples that follow.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct WavHeader {
    pub encoding: SampleEncoding,
    pub channels: u16,
    pub sample_rate: u32,
    /// Offset of the first sample byte in the file.
    pub data_offset: usize,
    /// Declared length of the `data` chunk; `None` when the writer did not
    /// know it (streaming writers put 0 or 0xFFFFFFFF there).
    pub data_len: Option<usize>,
}

impl WavHeader {
    /// Bytes of one frame (one sample of every channel).
    pub fn frame_bytes(&self) -> usize {
        self.encoding.bytes() * self.channels as usize
    }

    pub fn bytes_per_second(&self) -> f64 {
        self.frame_bytes() as f64 * self.sample_rate as f64
    }

    /// Seconds of audio in `data_bytes` bytes of the data chunk.
    pub fn seconds_in(&self, data_bytes: usize) -> f64 {
        (data_bytes / self.frame_bytes()) as f64 / self.sample_rate as f64
    }
}

fn u16_at(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([b[at], b[at + 1]])
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

fn format_tag_name(tag: u16) -> String {
    let name = match tag {
        0x0002 => "Microsoft ADPCM",
        0x0006 => "A-law",
        0x0007 => "µ-law",
        0x0011 => "IMA ADPCM",
        0x0031 => "GSM 6.10",
        0x0050 => "MPEG",
        0x0055 => "MPEG layer 3",
        _ => "unknown",
    };
    format!("format tag {tag:#06x} ({name})")
}

fn describe_magic(b: &[u8]) -> String {
    let head = &b[..b.len().min(4)];
    if head.starts_with(b"ID3") || head.starts_with(&[0xFF, 0xFB]) {
        "it looks like MP3".into()
    } else if head.starts_with(b"OggS") {
        "it looks like Ogg".into()
    } else if head.starts_with(b"fLaC") {
        "it looks like FLAC".into()
    } else {
        format!("it starts with bytes {head:02x?} instead of \"RIFF\"")
    }
}

/// Parses the RIFF header from the start of a (possibly partial) WAV file.
/// `Ok(None)` means more bytes are needed before the `data` chunk begins.
pub fn parse_wav_header(bytes: &[u8]) -> Result<Option<WavHeader>, AudioError> {
    let magic_len = bytes.len().min(4);
    if bytes[..magic_len] != b"RIFF"[..magic_len] {
        return Err(AudioError::NotWav(describe_magic(bytes)));
    }
    if bytes.len() >= 12 && &bytes[8..12] != b"WAVE" {
        return Err(AudioError::NotWav(format!(
            "the RIFF form type is {:?}, not \"WAVE\"",
            String::from_utf8_lossy(&bytes[8..12])
        )));
    }
    let mut at = 12;
    let mut fmt: Option<(SampleEncoding, u16, u32)> = None;
    loop {
        if at > MAX_WAV_HEADER_BYTES {
            return Err(AudioError::MalformedWav(format!(
                "no data chunk within the first {MAX_WAV_HEADER_BYTES} bytes"
            )));
        }
        if bytes.len() < at + 8 {
            return Ok(None);
        }
        let id = &bytes[at..at + 4];
        let size = u32_at(bytes, at + 4) as usize;
        let body = at + 8;
        if id == b"fmt " {
            if size < 16 {
                return Err(AudioError::MalformedWav(format!("fmt chunk is {size} bytes, at least 16 expected")));
            }
            if bytes.len() < body + size {
                return Ok(None);
            }
            fmt = Some(parse_fmt(&bytes[body..body + size])?);
        } else if id == b"data" {
            let (encoding, channels, sample_rate) =
                fmt.ok_or_else(|| AudioError::MalformedWav("the data chunk comes before any fmt chunk".into()))?;
            let data_len = (size != 0 && size < 0x7FFF_0000).then_some(size);
            return Ok(Some(WavHeader { encoding, channels, sample_rate, data_offset: body, data_len }));
        }
        // Chunks are padded to an even length.
        at = body + size + (size & 1);
    }
}

fn parse_fmt(b: &[u8]) -> Result<(SampleEncoding, u16, u32), AudioError> {
    let mut tag = u16_at(b, 0);
    let channels = u16_at(b, 2);
    let sample_rate = u32_at(b, 4);
    let bits = u16_at(b, 14);
    if tag == 0xFFFE {
        // WAVE_FORMAT_EXTENSIBLE: the real tag is the first two bytes of the sub-format GUID.
        if b.len() < 40 {
            return Err(AudioError::MalformedWav("extensible fmt chunk shorter than 40 bytes".into()));
        }
        tag = u16_at(b, 24);
    }
    let encoding = match (tag, bits) {
        (1, 8) => SampleEncoding::U8,
        (1, 16) => SampleEncoding::I16,
        (1, 24) => SampleEncoding::I24,
        (1, 32) => SampleEncoding::I32,
        (3, 32) => SampleEncoding::F32,
        (3, 64) => SampleEncoding::F64,
        (1 | 3, _) => {
            let kind = if tag == 1 { "integer PCM" } else { "float" };
            return Err(AudioError::UnsupportedEncoding(format!("{bits}-bit {kind}")));
        }
        _ => return Err(AudioError::UnsupportedEncoding(format_tag_name(tag))),
    };
    if channels == 0 || channels > MAX_CHANNELS {
        return Err(AudioError::UnsupportedEncoding(format!("{channels} channels (1 to {MAX_CHANNELS} supported)")));
    }
    if !(MIN_SAMPLE_RATE..=MAX_SAMPLE_RATE).contains(&sample_rate) {
        return Err(AudioError::SampleRate(sample_rate));
    }
    Ok((encoding, channels, sample_rate))
}

/// Decodes a complete WAV file, averaging all channels into one.
pub fn decode_wav(bytes: &[u8]) -> Result<Pcm, AudioError> {
    if bytes.is_empty() {
        return Err(AudioError::Empty);
    }
    let header = parse_wav_header(bytes)?.ok_or_else(|| {
        AudioError::MalformedWav(format!("the file ends after {} bytes, before its data chunk", bytes.len()))
    })?;
    let available = bytes.len() - header.data_offset;
    let data_len = match header.data_len {
        Some(declared) if declared > available => {
            return Err(AudioError::Truncated { declared, received: available });
        }
        Some(declared) => declared,
        None => available,
    };
    let data = &bytes[header.data_offset..header.data_offset + data_len];
    let frame = header.frame_bytes();
    let width = header.encoding.bytes();
    let channels = header.channels as usize;
    let samples: Vec<f32> = data
        .chunks_exact(frame)
        .map(|f| f.chunks_exact(width).map(|s| header.encoding.decode(s)).sum::<f32>() / channels as f32)
        .collect();
    if samples.is_empty() {
        return Err(AudioError::Empty);
    }
    Ok(Pcm { samples, sample_rate: header.sample_rate })
}

/// Decodes raw little-endian signed 16-bit mono samples.
pub fn decode_pcm16_mono(bytes: &[u8], sample_rate: u32) -> Result<Pcm, AudioError> {
    if !(MIN_SAMPLE_RATE..=MAX_SAMPLE_RATE).contains(&sample_rate) {
        return Err(AudioError::SampleRate(sample_rate));
    }
    if bytes.is_empty() {
        return Err(AudioError::Empty);
    }
    if !bytes.len().is_multiple_of(2) {
        return Err(AudioError::OddPcm16Length(bytes.len()));
    }
    let samples = bytes.chunks_exact(2).map(|b| i16::from_le_bytes([b[0], b[1]]) as f32 / 32_768.0).collect();
    Ok(Pcm { samples, sample_rate })
}

/// Writes mono or interleaved multi-channel `f32` samples as a WAV file in
/// the given encoding (used to build test inputs and by tools).
pub fn encode_wav(interleaved: &[f32], channels: u16, sample_rate: u32, encoding: SampleEncoding) -> Vec<u8> {
    let width = encoding.bytes();
    let data_len = interleaved.len() * width;
    let tag: u16 = if matches!(encoding, SampleEncoding::F32 | SampleEncoding::F64) { 3 } else { 1 };
    let mut out = Vec::with_capacity(44 + data_len);
    out.extend_from_slice(b"RIFF");
    out.extend_from_slice(&((36 + data_len) as u32).to_le_bytes());
    out.extend_from_slice(b"WAVEfmt ");
    out.extend_from_slice(&16u32.to_le_bytes());
    out.extend_from_slice(&tag.to_le_bytes());
    out.extend_from_slice(&channels.to_le_bytes());
    out.extend_from_slice(&sample_rate.to_le_bytes());
    out.extend_from_slice(&(sample_rate * (width * channels as usize) as u32).to_le_bytes());
    out.extend_from_slice(&((width * channels as usize) as u16).to_le_bytes());
    out.extend_from_slice(&((width * 8) as u16).to_le_bytes());
    out.extend_from_slice(b"data");
    out.extend_from_slice(&(data_len as u32).to_le_bytes());
    for &s in interleaved {
        let s = s.clamp(-1.0, 1.0);
        match encoding {
            SampleEncoding::U8 => out.push((s * 127.0 + 128.0).round() as u8),
            SampleEncoding::I16 => out.extend_from_slice(&((s * 32_767.0).round() as i16).to_le_bytes()),
            SampleEncoding::I24 => out.extend_from_slice(&((s * 8_388_607.0).round() as i32).to_le_bytes()[..3]),
            SampleEncoding::I32 => out.extend_from_slice(&((s as f64 * 2_147_483_647.0).round() as i32).to_le_bytes()),
            SampleEncoding::F32 => out.extend_from_slice(&s.to_le_bytes()),
            SampleEncoding::F64 => out.extend_from_slice(&(s as f64).to_le_bytes()),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp(n: usize) -> Vec<f32> {
        (0..n).map(|i| (i as f32 / n as f32) * 1.6 - 0.8).collect()
    }

    #[test]
    fn every_supported_encoding_round_trips() {
        let mono = ramp(1000);
        for (enc, tol) in [
            (SampleEncoding::U8, 1.0 / 100.0),
            (SampleEncoding::I16, 1e-4),
            (SampleEncoding::I24, 1e-6),
            (SampleEncoding::I32, 1e-6),
            (SampleEncoding::F32, 0.0),
            (SampleEncoding::F64, 0.0),
        ] {
            let wav = encode_wav(&mono, 1, 22_050, enc);
            let pcm = decode_wav(&wav).unwrap();
            assert_eq!(pcm.sample_rate, 22_050);
            assert_eq!(pcm.samples.len(), mono.len(), "{enc}");
            let err = pcm.samples.iter().zip(&mono).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
            assert!(err <= tol, "{enc}: max error {err}");
        }
    }

    #[test]
    fn stereo_is_averaged_to_mono() {
        let interleaved = [0.5, -0.5, 1.0, 0.0, -0.25, -0.75];
        let pcm = decode_wav(&encode_wav(&interleaved, 2, 48_000, SampleEncoding::F32)).unwrap();
        assert_eq!(pcm.samples, vec![0.0, 0.5, -0.5]);
        assert_eq!(pcm.sample_rate, 48_000);
    }

    #[test]
    fn extra_chunks_before_data_are_skipped() {
        let wav = encode_wav(&[0.25, 0.5], 1, 16_000, SampleEncoding::F32);
        let mut with_list = wav[..36].to_vec();
        with_list.extend_from_slice(b"LIST");
        with_list.extend_from_slice(&3u32.to_le_bytes());
        with_list.extend_from_slice(b"abc\0"); // odd size + pad byte
        with_list.extend_from_slice(&wav[36..]);
        assert_eq!(decode_wav(&with_list).unwrap().samples, vec![0.25, 0.5]);
    }

    #[test]
    fn header_parsing_waits_for_enough_bytes() {
        let wav = encode_wav(&ramp(100), 1, 16_000, SampleEncoding::I16);
        for cut in [0, 3, 11, 20, 43] {
            assert_eq!(parse_wav_header(&wav[..cut]).unwrap(), None, "cut at {cut}");
        }
        let h = parse_wav_header(&wav[..44]).unwrap().unwrap();
        assert_eq!((h.data_offset, h.data_len, h.channels), (44, Some(200), 1));
        assert_eq!(h.bytes_per_second(), 32_000.0);
    }

    #[test]
    fn a_truncated_file_says_how_much_is_missing() {
        let wav = encode_wav(&ramp(100), 1, 16_000, SampleEncoding::I16);
        assert_eq!(decode_wav(&wav[..100]), Err(AudioError::Truncated { declared: 200, received: 56 }));
        assert!(matches!(decode_wav(&wav[..30]), Err(AudioError::MalformedWav(_))));
    }

    #[test]
    fn an_unknown_data_length_reads_to_the_end() {
        let mut wav = encode_wav(&ramp(10), 1, 16_000, SampleEncoding::I16);
        wav[40..44].copy_from_slice(&0xFFFF_FFFFu32.to_le_bytes());
        assert_eq!(decode_wav(&wav).unwrap().samples.len(), 10);
    }

    #[test]
    fn unsupported_and_foreign_inputs_are_named() {
        let mut alaw = encode_wav(&ramp(10), 1, 8_000, SampleEncoding::U8);
        alaw[20..22].copy_from_slice(&6u16.to_le_bytes());
        let err = decode_wav(&alaw).unwrap_err();
        assert!(err.to_string().contains("A-law"), "{err}");

        let err = decode_wav(b"ID3\x04\0\0\0\0\0\0\0\0\0\0").unwrap_err();
        assert!(matches!(err, AudioError::NotWav(ref m) if m.contains("MP3")), "{err}");
        assert!(matches!(decode_wav(b"RIFF\0\0\0\0AVI LIST"), Err(AudioError::NotWav(_))));

        let mut slow = encode_wav(&ramp(10), 1, 16_000, SampleEncoding::I16);
        slow[24..28].copy_from_slice(&1_000u32.to_le_bytes());
        assert_eq!(decode_wav(&slow), Err(AudioError::SampleRate(1_000)));
        assert_eq!(decode_wav(&[]), Err(AudioError::Empty));
        assert_eq!(decode_wav(&encode_wav(&[], 1, 16_000, SampleEncoding::I16)), Err(AudioError::Empty));
    }

    #[test]
    fn raw_pcm16_is_checked_and_scaled() {
        let bytes = [0x00, 0x80, 0xFF, 0x7F, 0x00, 0x00];
        let pcm = decode_pcm16_mono(&bytes, 16_000).unwrap();
        assert_eq!(pcm.samples, vec![-1.0, 32_767.0 / 32_768.0, 0.0]);
        assert_eq!(decode_pcm16_mono(&bytes[..3], 16_000), Err(AudioError::OddPcm16Length(3)));
        assert_eq!(decode_pcm16_mono(&[], 16_000), Err(AudioError::Empty));
        assert_eq!(decode_pcm16_mono(&bytes, 0), Err(AudioError::SampleRate(0)));
    }
}
