//! Whisper speech recognition on candle (tiny.en by default): 80-bin log-mel
//! features, the encoder once per 30 s window (or, for a short utterance,
//! over the speech plus a margin only — whisper.cpp's `audio_ctx`), then
//! decoding of the English-only token stream with timestamps suppressed,
//! conditioned on a domain prompt (Whisper's `<|startofprev|>` context,
//! openai-whisper's `initial_prompt`).

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
        [&self.weights, &self.config, &self.tokenizer, &self.mel_filters]
            .into_iter()
            .find(|p| !p.is_file())
            .map(|p| p.as_path())
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    #[error(
        "Whisper model file {0} is missing; run deploy/fetch-models.sh (it fetches and converts Whisper tiny.en into $VLNAV_MODELS_DIR/whisper)"
    )]
    Missing(PathBuf),
    #[error("cannot load {path}: {reason}")]
    Load { path: PathBuf, reason: String },
    #[error("the tokenizer has no {0} token; is this a Whisper tokenizer?")]
    SpecialToken(&'static str),
    #[error("device {0:?}: {1}")]
    Device(String, String),
    #[error("Whisper inference failed: {0}")]
    Inference(#[from] candle_core::Error),
    #[error("invalid decoding options: {0}")]
    Options(String),
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

/// How recognition runs; [`DecodeOptions::default`] is what the service uses.
#[derive(Clone, Debug, PartialEq)]
pub struct DecodeOptions {
    /// Text given to the decoder as if it had been said just before
    /// (Whisper's previous-text context): vocabulary in it becomes more
    /// likely. Empty: no prompt. At most the last 223 tokens are used.
    pub prompt: String,
    /// Encode a recording shorter than one window over its length plus this
    /// margin (rounded up to whole seconds) instead of the full 30 s;
    /// `None` always encodes 30 s.
    pub window_margin_s: Option<f64>,
    /// Beam width of the temperature-0 beam search; 1 is greedy decoding.
    pub beam_size: usize,
}

impl Default for DecodeOptions {
    fn default() -> Self {
        Self { prompt: default_prompt(), window_margin_s: Some(DEFAULT_WINDOW_MARGIN_S), beam_size: DEFAULT_BEAM_SIZE }
    }
}

/// Default margin after the speech when encoding a short recording,
/// seconds. Tried on the spoken test instructions (2–13 s): a 3 s margin
/// loses words ("elephant statue" → "elephant's tube"), 6–10 s keep the
/// full-window transcripts.
pub const DEFAULT_WINDOW_MARGIN_S: f64 = 10.0;

/// Default beam width: 3 hears "visitor chair" and "bicycle" where greedy
/// decoding heard "visitor care" and "my sickle".
pub const DEFAULT_BEAM_SIZE: usize = 3;

/// Robot-command vocabulary, said the way people address the robot (the
/// paper's robot answers to "Buddy").
pub const COMMAND_WORDS: &str =
    "Buddy, go to the statue, take a left turn, move ahead, find the chair, follow the person.";

/// The default decoding prompt: every COCO-80 class name (the objects the
/// robot can look for), then robot-command vocabulary — last, nearest to
/// the transcript, where it weighs most.
pub fn default_prompt() -> String {
    format!("Objects: {}. {COMMAND_WORDS}", vlnav_proto::coco::CLASSES.join(", "))
}

/// Longest prompt in tokens (Whisper's limit: half the context, less one).
pub const MAX_PROMPT_TOKENS: usize = 223;

struct SpecialTokens {
    start_of_previous: Option<u32>,
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
    options: DecodeOptions,
    /// `<|startofprev|>` and the prompt's tokens; empty without a prompt.
    context: Vec<u32>,
}

fn load_err(path: &Path, e: impl std::fmt::Display) -> ModelError {
    ModelError::Load { path: path.to_path_buf(), reason: e.to_string() }
}

impl SpeechRecognizer {
    pub fn load(files: &ModelFiles, device: &Device) -> Result<Self, ModelError> {
        if let Some(missing) = files.missing() {
            return Err(ModelError::Missing(missing.to_path_buf()));
        }
        let config: WhisperConfig =
            serde_json::from_slice(&std::fs::read(&files.config).map_err(|e| load_err(&files.config, e))?)
                .map_err(|e| load_err(&files.config, e))?;

        let raw = std::fs::read(&files.mel_filters).map_err(|e| load_err(&files.mel_filters, e))?;
        let expected = config.num_mel_bins * (w::N_FFT / 2 + 1);
        if raw.len() != expected * 4 {
            return Err(load_err(
                &files.mel_filters,
                format!(
                    "{} bytes, expected {expected} little-endian f32 ({} mel bins × {} FFT bins)",
                    raw.len(),
                    config.num_mel_bins,
                    w::N_FFT / 2 + 1
                ),
            ));
        }
        let mel_filters = raw.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();

        let tokenizer = Tokenizer::from_file(&files.tokenizer).map_err(|e| load_err(&files.tokenizer, e))?;
        let token = |t: &'static str| tokenizer.token_to_id(t).ok_or(ModelError::SpecialToken(t));
        let special = SpecialTokens {
            start_of_previous: tokenizer.token_to_id("<|startofprev|>"),
            start_of_transcript: token(w::SOT_TOKEN)?,
            end_of_text: token(w::EOT_TOKEN)?,
            no_timestamps: token(w::NO_TIMESTAMPS_TOKEN)?,
            no_speech: w::NO_SPEECH_TOKENS.iter().find_map(|t| tokenizer.token_to_id(t)),
        };

        let bytes = std::fs::read(&files.weights).map_err(|e| load_err(&files.weights, e))?;
        let vb = VarBuilder::from_buffered_safetensors(bytes, DType::F32, device)
            .map_err(|e| load_err(&files.weights, e))?;
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
        let mut recognizer = Self {
            network,
            config,
            tokenizer,
            mel_filters,
            special,
            suppress,
            suppress_at_begin,
            device: device.clone(),
            options: DecodeOptions { prompt: String::new(), window_margin_s: None, beam_size: 1 },
            context: Vec::new(),
        };
        recognizer.set_options(DecodeOptions::default())?;
        Ok(recognizer)
    }

    /// Changes how recognition runs (prompt, window length).
    pub fn set_options(&mut self, options: DecodeOptions) -> Result<(), ModelError> {
        if let Some(m) = options.window_margin_s
            && !(m.is_finite() && m >= 0.0)
        {
            return Err(ModelError::Options(format!(
                "window margin must be a non-negative number of seconds, got {m}"
            )));
        }
        self.context = self.prompt_tokens(&options.prompt)?;
        self.options = options;
        Ok(())
    }

    pub fn options(&self) -> &DecodeOptions {
        &self.options
    }

    /// `<|startofprev|>` + the last [`MAX_PROMPT_TOKENS`] tokens of " prompt".
    fn prompt_tokens(&self, prompt: &str) -> Result<Vec<u32>, ModelError> {
        let prompt = prompt.trim();
        if prompt.is_empty() {
            return Ok(Vec::new());
        }
        let start = self.special.start_of_previous.ok_or(ModelError::SpecialToken("<|startofprev|>"))?;
        let encoding = self
            .tokenizer
            .encode(format!(" {prompt}"), false)
            .map_err(|e| ModelError::Options(format!("cannot tokenize the prompt: {e}")))?;
        let ids = encoding.get_ids();
        let mut context = vec![start];
        context.extend_from_slice(&ids[ids.len().saturating_sub(MAX_PROMPT_TOKENS)..]);
        Ok(context)
    }

    /// Tokens of the prompt as used (after `<|startofprev|>`, truncated).
    pub fn prompt_len(&self) -> usize {
        self.context.len().saturating_sub(1)
    }

    /// Mel frames to encode for a window starting where `remaining` frames
    /// of speech are left: the full window, or for short speech its length
    /// plus the margin, rounded up to whole seconds.
    pub fn window_frames(&self, remaining: usize) -> usize {
        window_frames(remaining, self.options.window_margin_s)
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

        let mut result = Recognition {
            text: String::new(),
            tokens: 0,
            no_speech_prob: 0.0,
            windows: 0,
            encode_s: 0.0,
            decode_s: 0.0,
        };
        result.encode_s = started.elapsed().as_secs_f64();
        let mut seek = 0;
        while seek < content_frames && seek + w::N_FRAMES <= n_frames && keep_going() {
            let frames = self.window_frames(content_frames - seek);
            let window = mel.narrow(2, seek, frames)?;
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

    fn decode_window(
        &mut self,
        mel: &Tensor,
        keep_going: &mut dyn FnMut() -> bool,
    ) -> Result<DecodedWindow, ModelError> {
        let started = std::time::Instant::now();
        let audio = self.network.encoder.forward(mel)?;
        let mut state = self.network.decoder.start(&audio)?;
        // Materialise the encoder output so its time is not charged to decoding (CUDA is asynchronous).
        self.device.synchronize()?;
        let encode_s = started.elapsed().as_secs_f64();
        let started = std::time::Instant::now();
        let mut prompt = self.context.clone();
        let sot_index = prompt.len();
        prompt.extend([self.special.start_of_transcript, self.special.no_timestamps]);
        let max_new = (self.config.max_target_positions / 2 - 2).min(self.config.max_target_positions - prompt.len());
        let beam_size = self.options.beam_size.max(1);

        let hidden = self.network.decoder.forward(&prompt, &mut state)?;
        let mut no_speech_prob = 0.0;
        if let Some(no_speech) = self.special.no_speech {
            // Read at the start-of-transcript position, as Whisper does.
            let probs = candle_nn::ops::softmax_last_dim(&self.network.decoder.logits(&hidden, sot_index)?)?;
            no_speech_prob = probs.i(no_speech as usize)?.to_scalar::<f32>()? as f64;
        }
        let first = self.log_probs(&hidden, prompt.len() - 1, true)?;
        // Temperature-0 beam search (openai-whisper's): every live beam
        // proposes its best continuations, the best `beam_size` that do not
        // end the text go on, those that end it are kept as finished, until
        // `beam_size` have finished. Width 1 is greedy decoding.
        let mut live = vec![Beam { tokens: Vec::new(), sum_logprob: 0.0, state, log_probs: first }];
        let mut finished: Vec<(Vec<u32>, f64)> = Vec::new();
        for _ in 0..max_new {
            if !keep_going() || live.is_empty() {
                break;
            }
            let mut candidates: Vec<(f64, usize, u32)> = Vec::new();
            for (b, beam) in live.iter().enumerate() {
                for (token, lp) in top_k(&beam.log_probs, beam_size + 1) {
                    candidates.push((beam.sum_logprob + lp as f64, b, token));
                }
            }
            candidates.sort_by(|a, b| b.0.total_cmp(&a.0));
            let mut next: Vec<Beam> = Vec::new();
            for (score, b, token) in candidates {
                if next.len() == beam_size || finished.len() >= beam_size {
                    break;
                }
                let parent = &live[b];
                let mut tokens = parent.tokens.clone();
                if token == self.special.end_of_text {
                    if finished.len() < beam_size {
                        finished.push((tokens, score));
                    }
                    continue;
                }
                tokens.push(token);
                if let Some(keep) = repetition_cut(&tokens) {
                    // A loop: keep its first occurrence and end there.
                    tokens.truncate(keep);
                    if finished.len() < beam_size {
                        finished.push((tokens, score));
                    }
                    continue;
                }
                if next.iter().any(|n| n.tokens == tokens) {
                    continue;
                }
                let mut state = parent.state.clone();
                let hidden = self.network.decoder.forward(&[token], &mut state)?;
                let log_probs = self.log_probs(&hidden, 0, false)?;
                next.push(Beam { tokens, sum_logprob: score, state, log_probs });
            }
            live = next;
            if finished.len() >= beam_size {
                break;
            }
        }
        if finished.is_empty() {
            // Out of room or stopped: the best unfinished beam.
            finished.extend(live.into_iter().map(|b| (b.tokens, b.sum_logprob)));
        }
        // The best by mean log-probability per token (openai-whisper's ranking without a length penalty).
        let (tokens, sum_logprob) = finished
            .into_iter()
            .max_by(|a, b| (a.1 / (a.0.len() + 1) as f64).total_cmp(&(b.1 / (b.0.len() + 1) as f64)))
            .unwrap_or_default();
        let decode_s = started.elapsed().as_secs_f64();
        Ok(DecodedWindow { tokens, sum_logprob, no_speech_prob, encode_s, decode_s })
    }

    /// Log-probabilities over the vocabulary at position `index` of `hidden`,
    /// with the never-generated tokens masked (and those not allowed first).
    fn log_probs(&self, hidden: &Tensor, index: usize, at_begin: bool) -> Result<Vec<f32>, ModelError> {
        let mut logits = self.network.decoder.logits(hidden, index)?.broadcast_add(&self.suppress)?;
        if at_begin {
            logits = logits.broadcast_add(&self.suppress_at_begin)?;
        }
        Ok(candle_nn::ops::log_softmax(&logits, D::Minus1)?.to_vec1::<f32>()?)
    }
}

struct Beam {
    tokens: Vec<u32>,
    sum_logprob: f64,
    state: crate::network::DecoderState,
    /// Log-probabilities of the next token.
    log_probs: Vec<f32>,
}

/// The `k` largest finite entries of `values` as (index, value), largest first.
pub fn top_k(values: &[f32], k: usize) -> Vec<(u32, f32)> {
    let mut best: Vec<(u32, f32)> = Vec::with_capacity(k + 1);
    for (i, &v) in values.iter().enumerate() {
        if !v.is_finite() || (best.len() == k && v <= best[k - 1].1) {
            continue;
        }
        let at = best.partition_point(|&(_, b)| b >= v);
        best.insert(at, (i as u32, v));
        best.truncate(k);
    }
    best
}

struct DecodedWindow {
    tokens: Vec<u32>,
    sum_logprob: f64,
    no_speech_prob: f64,
    encode_s: f64,
    decode_s: f64,
}

/// Mel frames (10 ms each) to encode when `remaining` frames of speech are
/// left: a full 30 s window, or with a margin, the speech plus the margin
/// rounded up to whole seconds when that is shorter.
pub fn window_frames(remaining: usize, margin_s: Option<f64>) -> usize {
    let Some(margin_s) = margin_s else { return w::N_FRAMES };
    let per_second = w::SAMPLE_RATE / w::HOP_LENGTH;
    let wanted = remaining + (margin_s * per_second as f64).ceil() as usize;
    (wanted.div_ceil(per_second) * per_second).clamp(per_second, w::N_FRAMES)
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
    fn top_k_keeps_the_largest_finite_values_in_order() {
        let v = [0.1, f32::NEG_INFINITY, 0.7, -3.0, 0.7, 0.5];
        assert_eq!(top_k(&v, 3), vec![(2, 0.7), (4, 0.7), (5, 0.5)]);
        assert_eq!(top_k(&v, 10).len(), 5);
        assert!(top_k(&[f32::NEG_INFINITY], 2).is_empty());
    }

    #[test]
    fn short_speech_gets_a_short_window() {
        assert_eq!(window_frames(250, None), 3000);
        assert_eq!(window_frames(250, Some(3.0)), 600);
        assert_eq!(window_frames(200, Some(0.0)), 200);
        assert_eq!(window_frames(0, Some(0.0)), 100);
        assert_eq!(window_frames(2_800, Some(3.0)), 3000);
        assert_eq!(window_frames(9_000, Some(3.0)), 3000);
    }

    #[test]
    fn the_default_prompt_names_every_coco_class() {
        let p = default_prompt();
        for c in vlnav_proto::coco::CLASSES {
            assert!(p.contains(c), "{c}");
        }
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
