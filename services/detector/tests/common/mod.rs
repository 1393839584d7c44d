//! Shared helpers of the detector's service tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use vlnav_proto::v1::{self, detector_service_client::DetectorServiceClient};
use vlnav_runtime::ServerConfig;
use vlnav_runtime::testing::{self, Connected};

/// `$VLNAV_MODELS_DIR`, else the workspace's `models/`.
pub fn models_dir() -> PathBuf {
    std::env::var_os("VLNAV_MODELS_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models"))
}

/// A model or asset file that must exist; fails the test saying how to get it.
pub fn require(relative: &str) -> PathBuf {
    let p = models_dir().join(relative);
    assert!(p.is_file(), "{} is missing: run deploy/fetch-models.sh first", p.display());
    p
}

pub type Running = Connected<DetectorServiceClient<tonic::transport::Channel>>;

/// Starts the detector on 127.0.0.1:0 and connects a client.
pub async fn start(opts: vlnav_detector::Options) -> Running {
    let cfg = ServerConfig::default();
    let set = vlnav_detector::services(&opts, &cfg).await.expect("detector services");
    let make =
        |ch| DetectorServiceClient::new(ch).max_decoding_message_size(64 << 20).max_encoding_message_size(64 << 20);
    testing::start_client(&cfg, set, make).await.unwrap()
}

pub fn nanodet_options() -> vlnav_detector::Options {
    require("nanodet/nanodet.safetensors");
    require("nanodet/nanodet.graph.json");
    vlnav_detector::Options { models_dir: models_dir(), ..Default::default() }
}

pub fn image(encoding: v1::ImageEncoding, width: u32, height: u32, data: Vec<u8>) -> v1::Image {
    v1::Image { width, height, encoding: encoding as i32, data }
}

pub fn rgb_frame(img: v1::Image) -> v1::RgbdFrame {
    v1::RgbdFrame { robot_id: "test".into(), seq: 1, stamp: 0.0, rgb: Some(img), ..Default::default() }
}

/// The photo's bytes, sent as PNG or JPEG by extension.
pub fn photo_frame(name: &str) -> v1::RgbdFrame {
    let path = require(&format!("photos/{name}"));
    let data = std::fs::read(&path).unwrap();
    let enc = if name.ends_with(".png") { v1::ImageEncoding::Png } else { v1::ImageEncoding::Jpeg };
    rgb_frame(image(enc, 0, 0, data))
}

pub fn request(frame: v1::RgbdFrame, class_ids: Vec<i32>, min_score: f32) -> v1::DetectRequest {
    v1::DetectRequest { frame: Some(frame), class_ids, min_score }
}
