//! Bad audio and text get a clear status from a real server, and nothing
//! hangs: every call below is bounded by a timeout.

mod common;

use std::time::Duration;

use common::{CALL_TIMEOUT, chunks, options, serve, speak, transcribe};
use tokio::sync::mpsc;
use tokio_stream::wrappers::ReceiverStream;
use tonic::Code;
use vlnav_ingress::Options;
use vlnav_ingress::audio::{SampleEncoding, encode_wav};
use vlnav_proto::v1::{AudioChunk, AudioFormat, NormalizeTextRequest};

fn expect_status(result: Result<vlnav_proto::v1::Transcript, tonic::Status>, code: Code, needle: &str) {
    let status = result.expect_err("the call should fail");
    assert_eq!(status.code(), code, "{status:?}");
    assert!(status.message().contains(needle), "message {:?} should mention {needle:?}", status.message());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn malformed_audio_is_refused_with_the_reason() {
    let mut s = serve(options()).await;
    let c = &mut s.client;

    // No chunk at all, and a first chunk without data.
    expect_status(transcribe(c, vec![]).await, Code::InvalidArgument, "no AudioChunk");
    expect_status(transcribe(c, chunks(AudioFormat::Wav, 0, &[], 1)).await, Code::InvalidArgument, "empty");
    expect_status(transcribe(c, chunks(AudioFormat::Pcm16Mono, 16_000, &[], 1)).await, Code::InvalidArgument, "empty");

    // The format must be named, known and not change mid-stream.
    let wav = encode_wav(&[0.1; 1_600], 1, 16_000, SampleEncoding::I16);
    expect_status(
        transcribe(c, chunks(AudioFormat::Unspecified, 0, &wav, 1_024)).await,
        Code::InvalidArgument,
        "format",
    );
    let mut unknown = chunks(AudioFormat::Wav, 0, &wav, 1_024);
    unknown[0].format = 42;
    expect_status(transcribe(c, unknown).await, Code::InvalidArgument, "unknown audio format 42");
    let mut switched = chunks(AudioFormat::Wav, 0, &wav, 1_024);
    switched[2].format = AudioFormat::Pcm16Mono as i32;
    expect_status(transcribe(c, switched).await, Code::InvalidArgument, "chunk 2");

    // Unsupported formats: compressed files sent as WAV, a WAV codec we do not decode, a bad rate.
    let mp3 = b"ID3\x04\x00\x00\x00\x00\x00\x00\xff\xfb\x90\x64".to_vec();
    expect_status(transcribe(c, chunks(AudioFormat::Wav, 0, &mp3, 1_024)).await, Code::InvalidArgument, "MP3");
    let mut alaw = encode_wav(&[0.1; 800], 1, 8_000, SampleEncoding::U8);
    alaw[20..22].copy_from_slice(&6u16.to_le_bytes());
    expect_status(transcribe(c, chunks(AudioFormat::Wav, 0, &alaw, 1_024)).await, Code::InvalidArgument, "A-law");
    expect_status(
        transcribe(c, chunks(AudioFormat::Pcm16Mono, 0, &[0, 0, 1, 0], 1_024)).await,
        Code::InvalidArgument,
        "sample_rate",
    );
    expect_status(
        transcribe(c, chunks(AudioFormat::Pcm16Mono, 16_000, &[0, 0, 1], 1_024)).await,
        Code::InvalidArgument,
        "3 bytes",
    );

    // Silence only.
    let silence = encode_wav(&vec![0.0; 32_000], 1, 16_000, SampleEncoding::I16);
    expect_status(
        transcribe(c, chunks(AudioFormat::Wav, 0, &silence, 8_192)).await,
        Code::InvalidArgument,
        "no speech",
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn recordings_over_sixty_seconds_are_refused_early() {
    let mut s = serve(options()).await;
    let c = &mut s.client;
    // A WAV header declaring 61 s is refused on its header.
    let long = encode_wav(&vec![0.1; 16_000 * 61], 1, 16_000, SampleEncoding::I16);
    expect_status(transcribe(c, chunks(AudioFormat::Wav, 0, &long, 256 * 1024)).await, Code::InvalidArgument, "61.0 s");
    // Raw PCM has no header: refused once more than 60 s have arrived.
    let raw = vec![0u8; 2 * 16_000 * 61];
    expect_status(
        transcribe(c, chunks(AudioFormat::Pcm16Mono, 16_000, &raw, 256 * 1024)).await,
        Code::InvalidArgument,
        "at most 60 s",
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn streams_that_stop_mid_way_fail_cleanly_and_block_nothing() {
    let opts = Options { chunk_timeout_s: 1.0, ..options() };
    let mut s = serve(opts).await;
    let wav = speak("Bring a water bottle from the kitchen.");

    // The client closes the stream before the data the header declared.
    let half = &wav[..wav.len() / 2];
    expect_status(
        transcribe(&mut s.client, chunks(AudioFormat::Wav, 0, half, 4_096)).await,
        Code::InvalidArgument,
        "ended early",
    );

    // The client stops sending but keeps the stream open.
    let (tx, rx) = mpsc::channel::<AudioChunk>(4);
    tx.send(chunks(AudioFormat::Wav, 0, &wav[..4_096], 4_096).remove(0)).await.unwrap();
    let started = std::time::Instant::now();
    let stalled =
        tokio::time::timeout(CALL_TIMEOUT, s.client.transcribe(ReceiverStream::new(rx))).await.expect("answered");
    let status = stalled.expect_err("a stalled upload is refused");
    assert_eq!(status.code(), Code::DeadlineExceeded, "{status:?}");
    assert!(status.message().contains("stopped mid-way"), "{}", status.message());
    assert!(started.elapsed() < Duration::from_secs(30));
    drop(tx);

    // The client goes away mid-upload (the call is dropped, the HTTP/2 stream reset).
    let (tx, rx) = mpsc::channel::<AudioChunk>(4);
    tx.send(chunks(AudioFormat::Wav, 0, &wav[..8_192], 8_192).remove(0)).await.unwrap();
    let mut client = s.client.clone();
    let call = tokio::spawn(async move { client.transcribe(ReceiverStream::new(rx)).await });
    tokio::time::sleep(Duration::from_millis(200)).await;
    call.abort();
    let _ = call.await;
    drop(tx);

    // The service still answers a complete upload.
    let t = transcribe(&mut s.client, chunks(AudioFormat::Wav, 0, &wav, 8_192)).await.expect("service still works");
    assert!(t.text.to_lowercase().contains("water bottle"), "{}", t.text);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn typed_text_is_normalised_and_empty_text_refused() {
    let mut s = serve(options()).await;
    let ok = s
        .client
        .normalize_text(NormalizeTextRequest { text: "  Buddy take left turn ,move \u{FF14} m ahead\u{2026} ".into() })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(ok.text, "Buddy take left turn, move 4 m ahead.");
    let err = s.client.normalize_text(NormalizeTextRequest { text: " \n\t\u{200B} ".into() }).await.unwrap_err();
    assert_eq!(err.code(), Code::InvalidArgument);
    assert!(err.message().starts_with("text: "), "{}", err.message());
}

#[tokio::test]
async fn a_missing_model_stops_the_service_from_starting_and_names_the_setup_script() {
    let dir = tempfile::tempdir().unwrap();
    let opts = Options { models_dir: dir.path().to_path_buf(), ..Options::default() };
    let err = vlnav_ingress::services(&opts, &vlnav_runtime::ServerConfig::default()).await.err().expect("no model");
    let msg = format!("{err:#}");
    assert!(msg.contains("deploy/fetch-models.sh") && msg.contains("whisper"), "{msg}");
}

#[tokio::test]
async fn bad_decoding_options_stop_the_service_from_starting() {
    let cfg = vlnav_runtime::ServerConfig::default();
    for (opts, needle) in [
        (Options { beam_size: 0, ..options() }, "beam size"),
        (Options { window_margin_s: -1.0, ..options() }, "window margin"),
        (Options { window_margin_s: f64::NAN, ..options() }, "window margin"),
    ] {
        let err = vlnav_ingress::services(&opts, &cfg).await.err().expect("refused");
        assert!(format!("{err:#}").contains(needle), "{err:#}");
    }
}
