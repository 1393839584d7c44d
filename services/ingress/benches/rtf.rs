//! Real-time factor of speech recognition: seconds of computation per
//! second of speech, for the spoken test instructions (espeak-ng).
//!
//!     cargo bench -p vlnav-ingress --bench rtf
//!
//! Reports, per sentence, the front end (WAV decode, resampling to 16 kHz,
//! silence trimming) and Whisper (mel features, encoder, greedy decoding)
//! separately, each the median of `VLNAV_RTF_RUNS` runs (default 3).
//! `VLNAV_INGRESS_DEVICE` picks the device (cpu, cuda, cuda:N);
//! `VLNAV_INGRESS_PROMPT` (empty: none), `VLNAV_INGRESS_BEAM_SIZE` and
//! `VLNAV_INGRESS_WINDOW_MARGIN_S` (`none`: always 30 s) change decoding
//! from the service's defaults, to compare.

#[path = "../tests/common/mod.rs"]
mod common;

use std::time::Instant;

use vlnav_ingress::input::{AudioAssembler, Encoding};
use vlnav_ingress::trim::TrimConfig;
use vlnav_ingress::whisper::device_from_name;
use vlnav_ingress::{ModelFiles, SpeechRecognizer};

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    // `cargo bench` passes --bench; nothing else is configurable by flags.
    let runs: usize = std::env::var("VLNAV_RTF_RUNS").ok().and_then(|v| v.parse().ok()).unwrap_or(3).max(1);
    let device_name = std::env::var("VLNAV_INGRESS_DEVICE").unwrap_or_else(|_| "cpu".into());
    let opts = common::options();
    let device = device_from_name(&device_name).expect("device");
    let load_start = Instant::now();
    let mut recognizer =
        SpeechRecognizer::load(&ModelFiles::in_dir(&opts.whisper_dir()), &device).expect("load Whisper");
    let mut decode = vlnav_ingress::whisper::DecodeOptions::default();
    if let Ok(p) = std::env::var("VLNAV_INGRESS_PROMPT") {
        decode.prompt = p;
    }
    if let Ok(b) = std::env::var("VLNAV_INGRESS_BEAM_SIZE") {
        decode.beam_size = b.parse().expect("VLNAV_INGRESS_BEAM_SIZE: a whole number");
    }
    if let Ok(m) = std::env::var("VLNAV_INGRESS_WINDOW_MARGIN_S") {
        decode.window_margin_s =
            if m == "none" { None } else { Some(m.parse().expect("VLNAV_INGRESS_WINDOW_MARGIN_S: seconds or none")) };
    }
    recognizer.set_options(decode.clone()).expect("decoding options");
    let load_s = load_start.elapsed().as_secs_f64();
    let threads = candle_core::utils::get_num_threads();
    println!("Whisper tiny.en on {device_name} ({threads} threads), model load {load_s:.2} s, median of {runs} runs");
    println!(
        "prompt {} tokens, beam {}, window {}",
        recognizer.prompt_len(),
        decode.beam_size,
        decode.window_margin_s.map_or("30 s always".to_string(), |m| format!("speech + {m} s"))
    );
    println!(
        "{:>8} {:>9} {:>9} {:>9} {:>7} {:>9} {:>8} {:>7}  sentence",
        "speech s", "front ms", "encode s", "decode s", "tokens", "whisper s", "total s", "RTF"
    );

    let wavs: Vec<Vec<u8>> = common::INSTRUCTIONS.iter().map(|t| common::speak(t)).collect();
    // Warm-up: first use allocates buffers and thread pools.
    let warm = {
        let mut a = AudioAssembler::new(Encoding::Wav, 60.0).unwrap();
        a.push(&wavs[3]).unwrap();
        a.finish(&TrimConfig::default()).unwrap()
    };
    recognizer.recognize(&warm.samples, &mut || true).unwrap();

    let (mut total_speech, mut total_compute) = (0.0, 0.0);
    for (text, wav) in common::INSTRUCTIONS.iter().zip(&wavs) {
        let mut front = Vec::new();
        let mut model = Vec::new();
        let (mut enc, mut dec, mut tokens) = (Vec::new(), Vec::new(), 0);
        let mut speech_s = 0.0;
        for _ in 0..runs {
            let t0 = Instant::now();
            let mut a = AudioAssembler::new(Encoding::Wav, 60.0).unwrap();
            a.push(wav).unwrap();
            let speech = a.finish(&TrimConfig::default()).unwrap();
            front.push(t0.elapsed().as_secs_f64());
            let t1 = Instant::now();
            let r = recognizer.recognize(&speech.samples, &mut || true).unwrap();
            enc.push(r.encode_s);
            dec.push(r.decode_s);
            tokens = r.tokens;
            model.push(t1.elapsed().as_secs_f64());
            speech_s = speech.seconds();
        }
        let (f, m) = (median(front), median(model));
        total_speech += speech_s;
        total_compute += f + m;
        let short: String = text.chars().take(48).collect();
        println!(
            "{speech_s:>8.2} {:>9.1} {:>9.3} {:>9.3} {tokens:>7} {m:>9.3} {:>8.3} {:>7.3}  {short}…",
            f * 1e3,
            median(enc),
            median(dec),
            f + m,
            (f + m) / speech_s
        );
    }
    println!(
        "overall RTF {:.3} ({total_compute:.2} s for {total_speech:.1} s of speech)",
        total_compute / total_speech
    );
}
