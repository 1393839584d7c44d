//! Service-level latency of each backend on this machine: one Detect call
//! over a real loopback gRPC connection (decode, preprocess, forward, decode,
//! NMS), plus the pure decoding + NMS step.
//!
//! NanoDet and the trained YOLOv8s need deploy/fetch-models.sh; YOLOv8n runs
//! on generated weights (the speed of a network does not depend on its weight
//! values).

use std::path::{Path, PathBuf};

use criterion::{Criterion, criterion_group, criterion_main};
use vlnav_detector::{BackendKind, Options};
use vlnav_proto::v1::{self, detector_service_client::DetectorServiceClient};
use vlnav_runtime::ServerConfig;
use vlnav_runtime::testing::{Connected, start_client};

fn models_dir() -> PathBuf {
    std::env::var_os("VLNAV_MODELS_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models"))
}

/// The detector served on a loopback port, with a client (dropping it stops the server).
async fn start(opts: Options) -> Connected<DetectorServiceClient<tonic::transport::Channel>> {
    let cfg = ServerConfig::default();
    let set = vlnav_detector::services(&opts, &cfg).await.expect("detector services (run deploy/fetch-models.sh)");
    start_client(&cfg, set, |ch| DetectorServiceClient::new(ch).max_decoding_message_size(64 << 20)).await.unwrap()
}

/// A 640×480 camera frame (the D455's colour resolution) as raw RGB8, cut from bike.jpg.
fn camera_frame() -> v1::RgbdFrame {
    let photo = image::open(models_dir().join("photos/bike.jpg"))
        .expect("photos/bike.jpg: run deploy/fetch-models.sh")
        .into_rgb8();
    let frame = image::imageops::crop_imm(&photo, 80, 38, 640, 480).to_image();
    v1::RgbdFrame {
        seq: 1,
        rgb: Some(v1::Image {
            width: 640,
            height: 480,
            encoding: v1::ImageEncoding::Rgb8 as i32,
            data: frame.into_raw().into(),
        }),
        ..Default::default()
    }
}

/// A 640×480 label frame with 12 instances and depth.
fn label_frame() -> v1::RgbdFrame {
    let (w, h) = (640u32, 480u32);
    let mut ids = Vec::with_capacity((w * h * 2) as usize);
    let mut depth = Vec::with_capacity((w * h * 2) as usize);
    for y in 0..h {
        for x in 0..w {
            let id: u16 = if y > 120 { (x / 54 + 1) as u16 } else { 0 };
            ids.extend_from_slice(&id.to_le_bytes());
            depth.extend_from_slice(&(1000 + (x as u16) * 5).to_le_bytes());
        }
    }
    let instances = (1..=12)
        .map(|i| v1::LabelInstance { instance_id: i, class_id: (i % 3) as i32, ..Default::default() })
        .collect();
    v1::RgbdFrame {
        seq: 1,
        depth: Some(v1::DepthImage { width: w, height: h, data_mm: depth.into(), encoding: 0, disparity_step: 0.0 }),
        labels: Some(v1::LabelImage { width: w, height: h, instance_ids: ids.into(), instances }),
        ..Default::default()
    }
}

fn service_latency(c: &mut Criterion) {
    let rt = tokio::runtime::Runtime::new().unwrap();
    let mut group = c.benchmark_group("detect_service");
    group.sample_size(20);

    let yolo_dir = tempfile::tempdir().unwrap();
    let yolo = yolo_dir.path().join("yolov8n.safetensors");
    vlnav_detector::yolov8::YoloV8::write_random_weights(&yolo, vlnav_detector::yolov8::Size::N, 80).unwrap();
    let cases = [
        ("nanodet_416", Options { models_dir: models_dir(), ..Default::default() }, camera_frame()),
        (
            "yolov8n_640",
            Options { backend: BackendKind::Yolov8, yolo_weights: Some(yolo), ..Default::default() },
            camera_frame(),
        ),
        (
            "yolov8s_640_trained",
            Options { backend: BackendKind::Yolov8, models_dir: models_dir(), ..Default::default() },
            camera_frame(),
        ),
        ("sim_640x480", Options { backend: BackendKind::Sim, ..Default::default() }, label_frame()),
    ];
    for (name, opts, frame) in cases {
        let served = rt.block_on(start(opts));
        let client = served.client.clone();
        let req = v1::DetectRequest { frame: Some(frame), class_ids: vec![], min_score: 0.0 };
        group.bench_function(name, |b| {
            b.to_async(&rt).iter(|| {
                let mut client = client.clone();
                let req = req.clone();
                async move { client.detect(req).await.unwrap() }
            })
        });
        drop(served);
    }
    group.finish();
}

fn decode_and_nms(c: &mut Criterion) {
    use vlnav_detector::detection::{DetectFilter, HeadLevel, HeadSpec, decode_dense, nms};
    // A NanoDet-sized head with pseudo-random scores: ~2 % of points above 0.4.
    let mut state = 12345u32;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 17;
        state ^= state << 5;
        state as f32 / u32::MAX as f32
    };
    let levels: Vec<(usize, f32, Vec<f32>, Vec<f32>)> = [(52usize, 8.0f32), (26, 16.0), (13, 32.0)]
        .into_iter()
        .map(|(side, stride)| {
            let p = side * side;
            let scores = (0..p * 80).map(|_| next().powi(200) * 0.9 + next() * 0.05).collect();
            let logits = (0..p * 44).map(|_| next() * 4.0).collect();
            (side, stride, scores, logits)
        })
        .collect();
    let heads: Vec<HeadLevel<'_>> = levels
        .iter()
        .map(|(side, stride, s, l)| HeadLevel {
            stride: *stride,
            width: *side,
            height: *side,
            scores: s,
            box_logits: l,
        })
        .collect();
    let spec = HeadSpec { num_classes: 80, bins: 11 };
    let filter = DetectFilter { class_ids: vec![], min_score: 0.4 };
    c.bench_function("decode_nms_nanodet_head", |b| {
        b.iter(|| nms(decode_dense(&heads, spec, &filter).unwrap(), 0.45, 100))
    });
}

criterion_group!(benches, service_latency, decode_and_nms);
criterion_main!(benches);
