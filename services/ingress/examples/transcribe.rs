//! Transcribes WAV files with the ingress pipeline (WAV decoding, 16 kHz,
//! silence trimming, Whisper), printing the text and timings of each:
//!
//!     cargo run --release -p vlnav-ingress --example transcribe -- a.wav b.wav
//!
//! `VLNAV_MODELS_DIR` locates the model (default `models`);
//! `VLNAV_INGRESS_PROMPT` replaces the decoding prompt (empty: none);
//! `VLNAV_INGRESS_WINDOW_MARGIN_S` sets the short-window margin (`none`:
//! always 30 s); `VLNAV_INGRESS_BEAM_SIZE` the beam width (1: greedy).

use std::time::Instant;

use vlnav_ingress::input::{AudioAssembler, Encoding};
use vlnav_ingress::trim::TrimConfig;
use vlnav_ingress::whisper::{DecodeOptions, device_from_name};
use vlnav_ingress::{ModelFiles, SpeechRecognizer};

fn main() -> anyhow::Result<()> {
    let models = std::env::var("VLNAV_MODELS_DIR").unwrap_or_else(|_| "models".into());
    let device = device_from_name(&std::env::var("VLNAV_INGRESS_DEVICE").unwrap_or_else(|_| "cpu".into()))?;
    let mut recognizer =
        SpeechRecognizer::load(&ModelFiles::in_dir(&std::path::Path::new(&models).join("whisper")), &device)?;
    let mut options = DecodeOptions::default();
    if let Ok(p) = std::env::var("VLNAV_INGRESS_PROMPT") {
        options.prompt = p;
    }
    if let Ok(m) = std::env::var("VLNAV_INGRESS_WINDOW_MARGIN_S") {
        options.window_margin_s = if m == "none" { None } else { Some(m.parse()?) };
    }
    if let Ok(b) = std::env::var("VLNAV_INGRESS_BEAM_SIZE") {
        options.beam_size = b.parse()?;
    }
    recognizer.set_options(options)?;
    eprintln!("prompt: {} tokens", recognizer.prompt_len());
    for path in std::env::args().skip(1) {
        let mut assembler = AudioAssembler::new(Encoding::Wav, 60.0)?;
        assembler.push(&std::fs::read(&path)?)?;
        let speech = assembler.finish(&TrimConfig::default())?;
        let started = Instant::now();
        let r = recognizer.recognize(&speech.samples, &mut || true)?;
        let s = started.elapsed().as_secs_f64();
        println!(
            "{path}: {:.2} s speech, encode {:.3} s, decode {:.3} s, RTF {:.3}\n  {}",
            speech.seconds(),
            r.encode_s,
            r.decode_s,
            s / speech.seconds(),
            r.text.trim()
        );
    }
    Ok(())
}
