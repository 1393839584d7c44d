//! Spoken instructions (espeak-ng) through a real ingress server: the
//! transcripts must be close to what was said, in every accepted encoding.

mod common;

use common::{INSTRUCTIONS, chunks, options, serve, speak, transcribe};
use vlnav_ingress::audio::{SampleEncoding, decode_wav, encode_wav};
use vlnav_ingress::wer::{scoring_words, word_error_rate};
use vlnav_proto::v1::AudioFormat;

/// Largest word error rate accepted for one sentence (after normalisation).
const MAX_WER: f64 = 0.35;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn spoken_instructions_are_transcribed_closely() {
    let mut served = serve(options()).await;
    let mut rates = Vec::new();
    let mut report = String::from("\nword error rate per sentence (Whisper tiny.en, espeak-ng en-us):\n");
    for text in INSTRUCTIONS {
        let wav = speak(text);
        let input_s = decode_wav(&wav).unwrap().duration_s();
        let t = transcribe(&mut served.client, chunks(AudioFormat::Wav, 0, &wav, 8 * 1024)).await.unwrap();
        let wer = word_error_rate(text, &t.text);
        report.push_str(&format!(
            "  {wer:.3}  {:.1} s speech  said: {text}\n              heard: {}\n",
            t.audio_seconds, t.text
        ));
        assert_eq!(t.model, "whisper-tiny.en");
        assert!(t.audio_seconds > 0.5 && t.audio_seconds <= input_s, "speech {} s of {input_s} s", t.audio_seconds);
        rates.push(wer);
    }
    let mean = rates.iter().sum::<f64>() / rates.len() as f64;
    report.push_str(&format!("  mean {mean:.3} over {} sentences\n", rates.len()));
    eprintln!("{report}");
    for (wer, text) in rates.iter().zip(INSTRUCTIONS) {
        assert!(*wer <= MAX_WER, "WER {wer:.3} > {MAX_WER} for {text:?}{report}");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_accepted_encoding_gives_the_words() {
    let mut served = serve(options()).await;
    let text = INSTRUCTIONS[2];
    let wav = speak(text);
    let pcm = decode_wav(&wav).unwrap();
    assert_eq!(pcm.sample_rate, 22_050, "espeak-ng writes 22.05 kHz");

    // Raw PCM16 at the synthesiser's rate, in small chunks.
    let raw: Vec<u8> = pcm.samples.iter().flat_map(|s| ((s * 32_767.0).round() as i16).to_le_bytes()).collect();
    // A 44.1 kHz stereo float WAV (each sample held for two periods — a
    // crude upsampler, independent of the service's own).
    let stereo: Vec<f32> = pcm.samples.iter().flat_map(|s| [*s, *s, *s, *s]).collect();
    let float_stereo = encode_wav(&stereo, 2, 44_100, SampleEncoding::F32);
    // 24-bit mono at the original rate.
    let pcm24 = encode_wav(&pcm.samples, 1, 22_050, SampleEncoding::I24);

    for (what, request) in [
        ("raw PCM16 mono 22.05 kHz", chunks(AudioFormat::Pcm16Mono, 22_050, &raw, 3_000)),
        ("WAV float32 stereo 44.1 kHz", chunks(AudioFormat::Wav, 0, &float_stereo, 64 * 1024)),
        ("WAV PCM24 mono 22.05 kHz, 5-byte chunks for the header", {
            let mut c = chunks(AudioFormat::Wav, 0, &pcm24[..40], 5);
            c.extend(chunks(AudioFormat::Wav, 0, &pcm24[40..], 16 * 1024).into_iter().map(|mut k| {
                k.format = 0;
                k
            }));
            c
        }),
    ] {
        let t = transcribe(&mut served.client, request).await.unwrap_or_else(|s| panic!("{what}: {s:?}"));
        let wer = word_error_rate(text, &t.text);
        eprintln!("{what}: WER {wer:.3}: {}", t.text);
        assert!(wer <= MAX_WER, "{what}: WER {wer:.3}: heard {:?} ({:?})", t.text, scoring_words(&t.text));
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn speech_longer_than_one_window_is_decoded_window_by_window() {
    let mut served = serve(options()).await;
    // Four instructions with half a second between them: about 35 s, two 30 s windows.
    let said = [INSTRUCTIONS[0], INSTRUCTIONS[1], INSTRUCTIONS[4], INSTRUCTIONS[5]];
    let mut samples = Vec::new();
    for text in said {
        samples.extend(decode_wav(&speak(text)).unwrap().samples);
        samples.extend(std::iter::repeat_n(0.0, 11_025));
    }
    let wav = encode_wav(&samples, 1, 22_050, SampleEncoding::I16);
    let t = transcribe(&mut served.client, chunks(AudioFormat::Wav, 0, &wav, 64 * 1024)).await.unwrap();
    assert!(t.audio_seconds > 30.0, "{} s", t.audio_seconds);
    let reference = said.join(" ");
    let wer = word_error_rate(&reference, &t.text);
    eprintln!("{:.1} s in two windows: WER {wer:.3}: {}", t.audio_seconds, t.text);
    assert!(wer <= MAX_WER, "WER {wer:.3}: heard {:?}", t.text);
    // Words from both windows are there.
    let heard = t.text.to_lowercase();
    assert!(heard.contains("left turn") && heard.contains("pharmacy") && heard.contains("report back"), "{heard}");
}

#[test]
fn the_default_prompt_fits_whisper_context_whole() {
    use vlnav_ingress::whisper::{DecodeOptions, MAX_PROMPT_TOKENS};
    let opts = options();
    let mut r = vlnav_ingress::SpeechRecognizer::load(
        &vlnav_ingress::ModelFiles::in_dir(&opts.whisper_dir()),
        &candle_core::Device::Cpu,
    )
    .expect("load Whisper");
    // Loaded with the default prompt: COCO names and commands, not cut.
    assert!(r.prompt_len() > 150 && r.prompt_len() < MAX_PROMPT_TOKENS, "{} tokens", r.prompt_len());
    assert_eq!(opts.decode_options(), DecodeOptions::default());
    r.set_options(DecodeOptions { prompt: String::new(), ..DecodeOptions::default() }).unwrap();
    assert_eq!(r.prompt_len(), 0);
    // A prompt longer than Whisper takes keeps its last 223 tokens.
    r.set_options(DecodeOptions { prompt: "chair ".repeat(400), ..DecodeOptions::default() }).unwrap();
    assert_eq!(r.prompt_len(), MAX_PROMPT_TOKENS);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn short_speech_on_a_short_window_reads_like_the_full_window() {
    // The same short sentence through a service that always encodes 30 s and
    // one that encodes the speech plus the margin: the words agree.
    let text = INSTRUCTIONS[2];
    let wav = speak(text);
    let mut short = serve(options()).await;
    let mut full = serve(vlnav_ingress::Options { full_window: true, ..options() }).await;
    let a = transcribe(&mut short.client, chunks(AudioFormat::Wav, 0, &wav, 64 * 1024)).await.unwrap();
    let b = transcribe(&mut full.client, chunks(AudioFormat::Wav, 0, &wav, 64 * 1024)).await.unwrap();
    eprintln!("short window: {}\nfull window:  {}", a.text, b.text);
    assert_eq!(scoring_words(&a.text), scoring_words(&b.text));
    assert!(word_error_rate(text, &a.text) <= MAX_WER);
}
