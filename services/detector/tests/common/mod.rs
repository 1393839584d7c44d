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
    v1::Image { width, height, encoding: encoding as i32, data: data.into() }
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

/// Reads a little-endian float32 C-order array from a `.npy` file's bytes.
pub fn parse_npy_f32(bytes: &[u8]) -> (Vec<usize>, Vec<f32>) {
    assert_eq!(&bytes[..6], b"\x93NUMPY", "not a .npy file");
    let (header_len, start) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        _ => (u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize, 12),
    };
    let header = std::str::from_utf8(&bytes[start..start + header_len]).unwrap();
    assert!(header.contains("'descr': '<f4'") && header.contains("'fortran_order': False"), "{header}");
    let shape_txt = header.split("'shape': (").nth(1).unwrap().split(')').next().unwrap();
    let shape: Vec<usize> = shape_txt.split(',').filter_map(|s| s.trim().parse().ok()).collect();
    let data = &bytes[start + header_len..];
    let values: Vec<f32> = data.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
    assert_eq!(values.len(), shape.iter().product::<usize>());
    (shape, values)
}

/// Writes a float32 C-order array as a `.npy` file (format 1.0).
pub fn write_npy_f32(path: &Path, shape: &[usize], values: &[f32]) {
    assert_eq!(values.len(), shape.iter().product::<usize>());
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let shape_txt = if dims.len() == 1 { format!("{},", dims[0]) } else { dims.join(", ") };
    let mut header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': ({shape_txt}), }}");
    while !(10 + header.len() + 1).is_multiple_of(64) {
        header.push(' ');
    }
    header.push('\n');
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
    bytes.extend_from_slice(header.as_bytes());
    for v in values {
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    std::fs::write(path, bytes).unwrap();
}

/// The Python with ONNX Runtime the reference tests run: `$VLNAV_REFERENCE_PYTHON`,
/// else the workspace's `.venv/bin/python` (deploy/setup-tools.sh installs onnxruntime there).
pub fn reference_python() -> PathBuf {
    let p = std::env::var_os("VLNAV_REFERENCE_PYTHON")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../../.venv/bin/python"));
    let ok =
        std::process::Command::new(&p).args(["-c", "import onnxruntime, numpy"]).status().is_ok_and(|s| s.success());
    assert!(ok, "{} cannot import onnxruntime and numpy: run deploy/setup-tools.sh", p.display());
    p
}

/// The trained YOLOv8s options (deploy/fetch-models.sh, fragment 32-yolov8-fall).
pub fn trained_yolo_options() -> vlnav_detector::Options {
    require("yolov8/fall-yolov8s.safetensors");
    require("yolov8/fall-yolov8s.names.yaml");
    vlnav_detector::Options {
        backend: vlnav_detector::BackendKind::Yolov8,
        models_dir: models_dir(),
        ..Default::default()
    }
}
