//! Whisper speech recognition on candle (tiny.en by default): 80-bin log-mel
//! features, the encoder once per 30 s window, then greedy decoding of the
//! English-only token stream with timestamps suppressed.

use std::path::{Path, PathBuf};

use candle_core::{D, DType, Device, IndexOp, Tensor};
use candle_nn::VarBuilder;
use candle_transformers::models::whisper::{self as w, audio};
use tokenizers::Tokenizer;

use crate::convert::WhisperConfig;
use crate::network::Network;

/// Whisper's input rate.
pub const SAMPLE_RATE: u32 = w::SAMPLE_RATE as u32;
/// A window whose "no speech" probability is above this and whose tokens
/// average a log-probability below [`LOGPROB_THRESHOLD`] is silence or noise.
pub const NO_SPEECH_THRESHOLD: f64 = w::NO_SPEECH_THRESHOLD;
pub const LOGPROB_THRESHOLD: f64 = w::LOGPROB_THRESHOLD;

/// The files one Whisper model directory holds.
#[derive(Clone, Debug)]
pub struct ModelFiles {
    pub weights: PathBuf,
    pub config: PathBuf,
    pub tokenizer: PathBuf,
    pub mel_filters: PathBuf,
}

impl ModelFiles {
    /// `model.safetensors`, `config.json`, `tokenizer.json` and
    /// `melfilters.bytes` in `dir` (what `deploy/models.d/50-whisper.sh` writes).
    pub fn in_dir(dir: &Path) -> Self {
        Self {
            weights: dir.join("model.safetensors"),
            config: dir.join("config.json"),
            tokenizer: dir.join("tokenizer.json"),
            mel_filters: dir.join("melfilters.bytes"),
        }
    }

    /// The first file that does not exist, if any.
    pub fn missing(&self) -> Option<&Path> {
        [&self.weights, &self.config, &self.tokenizer, &self.mel_filters].into_iter().find(|p| !p.is_file()).map(|p| p.as_path())
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    #[error("Whisper model file {0} is missing; run deploy/fetch-models.sh (it fetches and converts Whisper tiny.en into $VLNAV_MODELS_DIR/whisper)")]
    Missing(PathBuf),
    #[error("cannot load {path}: {reason}")]
    Load { path: PathBuf, reason: String },
    #[error("the tokenizer has no {0} token; is this a Whisper tokenizer?")]
    SpecialToken(&'static str),
    #[error("device {0:?}: {1}")]
    Device(String, String),
    #[error("Whisper inference failed: {0}")]
    Inference(#[from] candle_core::Error),
    #[error("cannot turn tokens into text: {0}")]
    Detokenize(String),
}

/// The compute device from its name: `cpu`, `cuda` or `cuda:N`.
pub fn device_from_name(name: &str) -> Result<Device, ModelError> {
    let fail = |e: candle_core::Error| ModelError::Device(name.to_string(), e.to_string());
    match name.trim() {
        "cpu" => Ok(Device::Cpu),
        "cuda" => Device::new_cuda(0).map_err(fail),
        other => match other.strip_prefix("cuda:").and_then(|n| n.parse::<usize>().ok()) {
            Some(n) => Device::new_cuda(n).map_err(fail),
            None => Err(ModelError::Device(name.into(), "expected cpu, cuda or cuda:N".into())),
        },
    }
}

/// What was recognised in a recording.
#[derive(Clone, Debug, PartialEq)]
pub struct Recognition {
    /// Raw decoded text (Whisper puts a space before the first word).
    pub text: String,
    /// Tokens generated, over all windows.
    pub tokens: usize,
    /// Highest "no speech" probability among the windows that were kept.
    pub no_speech_prob: f64,
    /// 30 s windows decoded.
    pub windows: usize,
    /// Time spent on mel features + encoder, and on decoding, seconds.
    pub encode_s: f64,
    pub decode_s: f64,
}

struct SpecialTokens {
    start_of_transcript: u32,
    end_of_text: u32,
    no_timestamps: u32,
    no_speech: Option<u32>,
}

/// A loaded Whisper model with its tokenizer and mel filter bank.
pub struct SpeechRecognizer {
    network: Network,
    config: WhisperConfig,
    tokenizer: Tokenizer,
    mel_filters: Vec<f32>,
    special: SpecialTokens,
    /// Additive logit masks (0 or −∞) over the vocabulary.
    suppress: Tensor,
    suppress_at_begin: Tensor,
    device: Device,
}

fn load_err(path: &Path, e: impl std::fmt::Display) -> ModelError {
    ModelError::Load { path: path.to_path_buf(), reason: e.to_string() }
}

impl SpeechRecognizer {
    pub fn load(files: &ModelFiles, device: &Device) -> Result<Self, ModelError> {
        if let Some(missing) = files.missing() {
            return Err(ModelError::Missing(missing.to_path_buf()));
        }
        let config: WhisperConfig = serde_json::from_slice(&std::fs::read(&files.config).map_err(|e| load_err(&files.config, e))?)
            .map_err(|e| load_err(&files.config, e))?;

        let raw = std::fs::read(&files.mel_filters).map_err(|e| load_err(&files.mel_filters, e))?;
        let expected = config.num_mel_bins * (w::N_FFT / 2 + 1);
        if raw.len() != expected * 4 {
            return Err(load_err(
                &files.mel_filters,
                format!("{} bytes, expected {expected} little-endian f32 ({} mel bins × {} FFT bins)", raw.len(), config.num_mel_bins, w::N_FFT / 2 + 1),
            ));
        }
        let mel_filters = raw.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();

        let tokenizer = Tokenizer::from_file(&files.tokenizer).map_err(|e| load_err(&files.tokenizer, e))?;
        let token = |t: &'static str| tokenizer.token_to_id(t).ok_or(ModelError::SpecialToken(t));
        let special = SpecialTokens {
            start_of_transcript: token(w::SOT_TOKEN)?,
            end_of_text: token(w::EOT_TOKEN)?,
            no_timestamps: token(w::NO_TIMESTAMPS_TOKEN)?,
            no_speech: w::NO_SPEECH_TOKENS.iter().find_map(|t| tokenizer.token_to_id(t)),
        };

        let bytes = std::fs::read(&files.weights).map_err(|e| load_err(&files.weights, e))?;
        let vb = VarBuilder::from_buffered_safetensors(bytes, DType::F32, device).map_err(|e| load_err(&files.weights, e))?;
        let network = Network::load(&config, vb).map_err(|e| load_err(&files.weights, e))?;

        // Never generated: the configured non-speech symbols and every special
        // token after end-of-text (task, language, timestamps, …), so the
        // English-only model emits plain text until end-of-text.
        let vocab = config.vocab_size;
        let mut mask = vec![0f32; vocab];
        for &t in &config.suppress_tokens {
            if (t as usize) < vocab {
                mask[t as usize] = f32::NEG_INFINITY;
            }
        }
        for m in mask.iter_mut().skip(special.start_of_transcript as usize) {
            *m = f32::NEG_INFINITY;
        }
        let mut begin = vec![0f32; vocab];
        for &t in &config.begin_suppress_tokens {
            if (t as usize) < vocab {
                begin[t as usize] = f32::NEG_INFINITY;
            }
        }
        let suppress = Tensor::from_vec(mask, vocab, device)?;
        let suppress_at_begin = Tensor::from_vec(begin, vocab, device)?;
        Ok(Self { network, config, tokenizer, mel_filters, special, suppress, suppress_at_begin, device: device.clone() })
    }

    pub fn config(&self) -> &WhisperConfig {
        &self.config
    }

    /// Recognises speech in mono 16 kHz samples. `keep_going` is asked before
    /// each window and each token; when it answers false the work stops early
    /// (the caller has gone) and what was decoded so far is returned.
    pub fn recognize(&mut self, pcm: &[f32], keep_going: &mut dyn FnMut() -> bool) -> Result<Recognition, ModelError> {
        let started = std::time::Instant::now();
        let cfg = self.config.to_candle();
        let mel = audio::pcm_to_mel(&cfg, pcm, &self.mel_filters);
        let n_frames = mel.len() / cfg.num_mel_bins;
        let mel = Tensor::from_vec(mel, (1, cfg.num_mel_bins, n_frames), &self.device)?;
        let content_frames = pcm.len().div_ceil(w::HOP_LENGTH).max(1);

        let mut result =
            Recognition { text: String::new(), tokens: 0, no_speech_prob: 0.0, windows: 0, encode_s: 0.0, decode_s: 0.0 };
        result.encode_s = started.elapsed().as_secs_f64();
        let mut seek = 0;
        while seek < content_frames && seek + w::N_FRAMES <= n_frames && keep_going() {
            let window = mel.narrow(2, seek, w::N_FRAMES)?;
            let decoded = self.decode_window(&window, keep_going)?;
            result.windows += 1;
            result.encode_s += decoded.encode_s;
            result.decode_s += decoded.decode_s;
            let avg_logprob = decoded.sum_logprob / (decoded.tokens.len() + 1) as f64;
            let silent = decoded.no_speech_prob > NO_SPEECH_THRESHOLD && avg_logprob < LOGPROB_THRESHOLD;
            if !silent {
                let text =
                    self.tokenizer.decode(&decoded.tokens, true).map_err(|e| ModelError::Detokenize(e.to_string()))?;
                result.text.push_str(&text);
                result.tokens += decoded.tokens.len();
                result.no_speech_prob = result.no_speech_prob.max(decoded.no_speech_prob);
            }
            seek += w::N_FRAMES;
        }
        Ok(result)
    }

    fn decode_window(&mut self, mel: &Tensor, keep_going: &mut dyn FnMut() -> bool) -> Result<DecodedWindow, ModelError> {
        let started = std::time::Instant::now();
        let audio = self.network.encoder.forward(mel)?;
        let mut state = self.network.decoder.start(&audio)?;
        // Materialise the encoder output so its time is not charged to decoding (CUDA is asynchronous).
        self.device.synchronize()?;
        let encode_s = started.elapsed().as_secs_f64();
        let started = std::time::Instant::now();
        let prompt = [self.special.start_of_transcript, self.special.no_timestamps];
        let max_new = self.config.max_target_positions / 2 - prompt.len();
        let mut tokens: Vec<u32> = Vec::new();
        let mut sum_logprob = 0.0;
        let mut no_speech_prob = 0.0;
        let mut feed: Vec<u32> = prompt.to_vec();
        for step in 0..max_new {
            if !keep_going() {
                break;
            }
            let hidden = self.network.decoder.forward(&feed, &mut state)?;
            if step == 0
                && let Some(no_speech) = self.special.no_speech
            {
                // Read at the start-of-transcript position, as Whisper does.
                let probs = candle_nn::ops::softmax_last_dim(&self.network.decoder.logits(&hidden, 0)?)?;
                no_speech_prob = probs.i(no_speech as usize)?.to_scalar::<f32>()? as f64;
            }
            let mut logits = self.network.decoder.logits(&hidden, feed.len() - 1)?.broadcast_add(&self.suppress)?;
            if step == 0 {
                logits = logits.broadcast_add(&self.suppress_at_begin)?;
            }
            let log_probs = candle_nn::ops::log_softmax(&logits, D::Minus1)?;
            let next = logits.argmax(D::Minus1)?.to_scalar::<u32>()?;
            sum_logprob += log_probs.i(next as usize)?.to_scalar::<f32>()? as f64;
            if next == self.special.end_of_text {
                break;
            }
            tokens.push(next);
            if let Some(keep) = repetition_cut(&tokens) {
                tokens.truncate(keep);
                break;
            }
            feed = vec![next];
        }
        let decode_s = started.elapsed().as_secs_f64();
        Ok(DecodedWindow { tokens, sum_logprob, no_speech_prob, encode_s, decode_s })
    }
}

struct DecodedWindow {
    tokens: Vec<u32>,
    sum_logprob: f64,
    no_speech_prob: f64,
    encode_s: f64,
    decode_s: f64,
}

/// Greedy decoding can fall into a loop ("the the the …"). When the tail of
/// `tokens` is one n-gram (n ≤ 16) repeated four times in a row, returns the
/// length to keep: everything up to and including its first occurrence.
pub fn repetition_cut(tokens: &[u32]) -> Option<usize> {
    const REPEATS: usize = 4;
    for n in 1..=16 {
        if tokens.len() < n * REPEATS {
            break;
        }
        let tail = &tokens[tokens.len() - n..];
        let all_same = (1..REPEATS).all(|k| {
            let end = tokens.len() - k * n;
            &tokens[end - n..end] == tail
        });
        if all_same {
            return Some(tokens.len() - (REPEATS - 1) * n);
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn loops_are_cut_after_their_first_occurrence() {
        assert_eq!(repetition_cut(&[1, 2, 3, 4]), None);
        assert_eq!(repetition_cut(&[9, 5, 5, 5, 5]), Some(2));
        assert_eq!(repetition_cut(&[9, 1, 2, 1, 2, 1, 2, 1, 2]), Some(3));
        assert_eq!(repetition_cut(&[1, 2, 1, 2, 1, 2]), None);
    }

    #[test]
    fn missing_files_name_the_setup_script() {
        let dir = tempfile::tempdir().unwrap();
        let err = SpeechRecognizer::load(&ModelFiles::in_dir(dir.path()), &Device::Cpu).err().unwrap();
        let msg = err.to_string();
        assert!(msg.contains("model.safetensors") && msg.contains("deploy/fetch-models.sh"), "{msg}");
    }

    #[test]
    fn device_names_are_checked() {
        assert!(matches!(device_from_name("cpu"), Ok(Device::Cpu)));
        assert!(matches!(device_from_name("tpu"), Err(ModelError::Device(..))));
    }
}
