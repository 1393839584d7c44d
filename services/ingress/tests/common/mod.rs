//! Shared by the ingress service tests: model location, speech synthesis
//! with espeak-ng, and a real server on a loopback port.

#![allow(dead_code)]

use std::path::PathBuf;
use std::process::Command;
use std::time::Duration;

use tonic::transport::Channel;
use vlnav_ingress::Options;
use vlnav_proto::v1::ingress_service_client::IngressServiceClient;
use vlnav_proto::v1::{AudioChunk, AudioFormat};
use vlnav_runtime::ServerConfig;
use vlnav_runtime::testing::{self, Connected};

/// The instructions spoken in the tests: the paper's two worked examples
/// (Case 1 and Case 2) and the other instruction kinds it names.
pub const INSTRUCTIONS: [&str; 6] = [
    "Buddy take left turn, move 4 m ahead, then find the standing person to reach close to it, In your right you may see the visitor chair follow it. Finally go at spot where bicycle is standing.",
    "Buddy go to the statue, take a right turn and move a little ahead, then find the visitor chair to reach close to it, and on the right you may see a bicycle.",
    "Move five meters forward, take a right turn, and stop near the elephant statue.",
    "Bring a water bottle from the kitchen.",
    "Go ahead ten meters, turn right at the lotus statue, and proceed to the pharmacy.",
    "Hi Buddy, please deliver this file to Mister David and report back to me.",
];

pub fn models_dir() -> PathBuf {
    std::env::var_os("VLNAV_MODELS_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../models"))
}

/// Options pointing at the fetched Whisper model; fails the test, naming
/// the set-up script, when a model file is missing.
pub fn options() -> Options {
    let opts = Options { models_dir: models_dir(), ..Options::default() };
    let files = vlnav_ingress::ModelFiles::in_dir(&opts.whisper_dir());
    if let Some(missing) = files.missing() {
        panic!("Whisper model file {} is missing: run deploy/fetch-models.sh first", missing.display());
    }
    opts
}

/// `text` spoken by espeak-ng (American English voice) as a WAV file
/// (22.05 kHz, 16-bit mono).
pub fn speak(text: &str) -> Vec<u8> {
    let dir = tempfile::tempdir().expect("temporary directory");
    let path = dir.path().join("speech.wav");
    let status = Command::new("espeak-ng")
        .args(["-v", "en-us", "-s", "150", "-w"])
        .arg(&path)
        .arg(text)
        .status()
        .unwrap_or_else(|e| {
            panic!("cannot run espeak-ng ({e}): install the Debian package espeak-ng (listed in .ci/apt/ingress.txt)")
        });
    assert!(status.success(), "espeak-ng failed with {status}");
    std::fs::read(&path).expect("espeak-ng wrote no WAV")
}

/// A running ingress server and a client connected to it.
pub type Served = Connected<IngressServiceClient<Channel>>;

pub async fn serve(opts: Options) -> Served {
    // The tests check what is heard, not how fast: 35 s of speech in a debug
    // build on a loaded 2-core machine can take longer than the server's
    // default 30 s request timeout. CALL_TIMEOUT still bounds every call.
    let cfg = ServerConfig { request_timeout_s: CALL_TIMEOUT.as_secs_f64(), ..ServerConfig::default() };
    let services = vlnav_ingress::services(&opts, &cfg).await.expect("ingress services start");
    testing::start_client(&cfg, services, IngressServiceClient::new)
        .await
        .expect("ingress server starts and accepts a client")
}

/// `data` as a stream of chunks of at most `chunk` bytes; the first names the format.
pub fn chunks(format: AudioFormat, sample_rate: u32, data: &[u8], chunk: usize) -> Vec<AudioChunk> {
    let mut out: Vec<AudioChunk> =
        data.chunks(chunk.max(1)).map(|d| AudioChunk { format: 0, sample_rate: 0, data: d.to_vec().into() }).collect();
    if out.is_empty() {
        out.push(AudioChunk::default());
    }
    out[0].format = format as i32;
    out[0].sample_rate = sample_rate;
    out
}

/// Every call in the tests is bounded: a hang fails the test instead of blocking it.
pub const CALL_TIMEOUT: Duration = Duration::from_secs(120);

pub async fn transcribe(
    client: &mut IngressServiceClient<Channel>,
    chunks: Vec<AudioChunk>,
) -> Result<vlnav_proto::v1::Transcript, tonic::Status> {
    tokio::time::timeout(CALL_TIMEOUT, client.transcribe(tokio_stream::iter(chunks)))
        .await
        .expect("Transcribe did not answer in time")
        .map(|r| r.into_inner())
}
