//! The DetectorService over a real socket: the simulation backend, YOLOv8 on
//! generated weights, start-up failures, and bad input.

mod common;

use common::*;
use tonic::Code;
use vlnav_detector::{BackendKind, Options};
use vlnav_proto::v1;

/// The oracle simulation backend: exact boxes (the realistic model is tested in `sim.rs`).
fn sim_options() -> Options {
    Options { backend: BackendKind::Sim, sim_min_pixels: 4, sim_profile: "oracle".into(), ..Default::default() }
}

/// A 16×8 label frame: a person (instance 7) at x 2..5, y 1..7, 2 m away; a
/// wall (instance 9, class −1) on the right; a chair (instance 8) at 11 m.
fn labelled_frame(seq: u64) -> v1::RgbdFrame {
    let (w, h) = (16u32, 8u32);
    let mut ids = Vec::new();
    let mut depth = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let (id, mm): (u16, u16) = match (x, y) {
                (2..=5, 1..=6) => (7, 2000),
                (14..=15, _) => (9, 1000),
                (8..=10, 0..=3) => (8, 11000),
                _ => (0, 0),
            };
            ids.extend_from_slice(&id.to_le_bytes());
            depth.extend_from_slice(&mm.to_le_bytes());
        }
    }
    let inst = |instance_id: u32, class_id: i32, semantic: &str| v1::LabelInstance {
        instance_id,
        class_id,
        identity: String::new(),
        semantic: semantic.into(),
        ..Default::default()
    };
    v1::RgbdFrame {
        robot_id: "husky-1".into(),
        seq,
        stamp: seq as f64 * 0.2,
        depth: Some(v1::DepthImage { width: w, height: h, data_mm: depth.into(), encoding: 0, disparity_step: 0.0 }),
        labels: Some(v1::LabelImage {
            width: w,
            height: h,
            instance_ids: ids.into(),
            instances: vec![inst(7, 0, "object"), inst(8, 56, "object"), inst(9, -1, "wall")],
        }),
        ..Default::default()
    }
}

#[tokio::test]
async fn simulation_backend_reads_label_images() {
    let mut svc = start(sim_options()).await;
    let info = svc.client.get_model_info(v1::GetModelInfoRequest {}).await.unwrap().into_inner();
    assert_eq!(info.backend, "sim");
    // The oracle ranges its boxes by depth; the realistic model reads labels alone.
    assert_eq!(info.inputs, Some(v1::FrameInputs { rgb: false, depth: true, labels: true }));
    let resp = svc.client.detect(request(labelled_frame(1), vec![], 0.0)).await.unwrap().into_inner();
    assert_eq!(resp.backend, "sim");
    assert_eq!(resp.boxes.len(), 1, "{:?}", resp.boxes);
    let b = &resp.boxes[0];
    assert_eq!((b.class_id, b.label.as_str()), (0, "person"));
    assert_eq!((b.x_min, b.y_min, b.x_max, b.y_max), (2.0, 1.0, 6.0, 7.0));
    // Filtered out by class.
    let none = svc.client.detect(request(labelled_frame(1), vec![56], 0.0)).await.unwrap().into_inner();
    assert!(none.boxes.is_empty());

    // Without labels, or with a label image of the wrong size: INVALID_ARGUMENT naming the field.
    let mut frame = labelled_frame(2);
    frame.labels = None;
    let e = svc.client.detect(request(frame, vec![], 0.0)).await.unwrap_err();
    assert_eq!(e.code(), Code::InvalidArgument);
    assert!(e.message().contains("frame.labels"), "{}", e.message());
    let mut frame = labelled_frame(2);
    let ids = &mut frame.labels.as_mut().unwrap().instance_ids;
    ids.truncate(ids.len() - 1);
    let e = svc.client.detect(request(frame, vec![], 0.0)).await.unwrap_err();
    assert_eq!(e.code(), Code::InvalidArgument);
    assert!(e.message().contains("frame.labels") && e.message().contains("expected 256"), "{}", e.message());
    let mut frame = labelled_frame(2);
    frame.depth.as_mut().unwrap().width = 8;
    let e = svc.client.detect(request(frame, vec![], 0.0)).await.unwrap_err();
    assert!(e.code() == Code::InvalidArgument && e.message().contains("frame.depth"), "{}", e.message());
    svc.stop().await.unwrap();
}

#[tokio::test]
async fn the_realistic_simulation_reads_the_label_image_alone_and_answers_a_frame_cut_to_it() {
    let mut svc = start(Options { backend: BackendKind::Sim, sim_profile: "nanodet".into(), ..sim_options() }).await;
    let info = svc.client.get_model_info(v1::GetModelInfoRequest {}).await.unwrap().into_inner();
    assert_eq!(info.inputs, Some(v1::FrameInputs { rgb: false, depth: false, labels: true }));
    for seq in 0..20 {
        let whole = svc.client.detect(request(labelled_frame(seq), vec![], 0.0)).await.unwrap().into_inner();
        let cut = v1::RgbdFrame { depth: None, ..labelled_frame(seq) };
        let answer = svc.client.detect(request(cut, vec![], 0.0)).await.unwrap().into_inner();
        assert_eq!(answer.boxes, whole.boxes, "seq {seq}");
    }
    svc.stop().await.unwrap();
}

#[tokio::test]
async fn simulated_misses_and_jitter_reproduce() {
    let opts = Options { sim_miss_rate: 0.3, sim_jitter_px: 1.5, sim_seed: 42, ..sim_options() };
    let mut a = start(opts.clone()).await;
    let mut b = start(opts).await;
    let mut seen = 0;
    for seq in 0..40 {
        let ra = a.client.detect(request(labelled_frame(seq), vec![], 0.0)).await.unwrap().into_inner().boxes;
        let rb = b.client.detect(request(labelled_frame(seq), vec![], 0.0)).await.unwrap().into_inner().boxes;
        assert_eq!(ra, rb, "seq {seq}");
        seen += ra.len();
    }
    assert!((15..40).contains(&seen), "{seen} of 40 seen at a 30 % miss rate");
    a.stop().await.unwrap();
    b.stop().await.unwrap();
}

#[tokio::test]
async fn missing_models_fail_at_start_with_the_fix() {
    let empty = tempfile::tempdir().unwrap();
    let opts = Options { models_dir: empty.path().to_path_buf(), ..Default::default() };
    let err = vlnav_detector::services(&opts, &Default::default()).await.err().expect("must fail").to_string();
    assert!(err.contains("nanodet.graph.json") && err.contains("deploy/fetch-models.sh"), "{err}");
    let opts = Options { backend: BackendKind::Yolov8, models_dir: empty.path().to_path_buf(), ..Default::default() };
    let err = vlnav_detector::services(&opts, &Default::default()).await.err().expect("must fail").to_string();
    assert!(
        err.contains("fall-yolov8s.safetensors")
            && err.contains("deploy/fetch-models.sh")
            && err.contains("--detector-yolo-weights"),
        "{err}"
    );
    // Weights of the wrong model scale are rejected, naming the file.
    let small = empty.path().join("yolov8n.safetensors");
    vlnav_detector::yolov8::YoloV8::write_random_weights(&small, vlnav_detector::yolov8::Size::N, 80).unwrap();
    let opts = Options {
        backend: BackendKind::Yolov8,
        yolo_weights: Some(small.clone()),
        yolo_size: Some(vlnav_detector::yolov8::Size::S),
        ..Default::default()
    };
    let err = vlnav_detector::services(&opts, &Default::default()).await.err().expect("must fail").to_string();
    assert!(err.contains("yolov8n.safetensors") && err.contains("not yolov8s weights"), "{err}");
}

#[tokio::test]
async fn yolov8_serves_generated_weights() {
    let dir = tempfile::tempdir().unwrap();
    let weights = dir.path().join("yolov8n.safetensors");
    vlnav_detector::yolov8::YoloV8::write_random_weights(&weights, vlnav_detector::yolov8::Size::N, 80).unwrap();
    let mut svc =
        start(Options { backend: BackendKind::Yolov8, yolo_weights: Some(weights), ..Default::default() }).await;
    let info = svc.client.get_model_info(v1::GetModelInfoRequest {}).await.unwrap().into_inner();
    assert_eq!((info.backend.as_str(), info.model.as_str(), info.input_width), ("yolov8", "yolov8n", 640));
    assert_eq!(info.inputs, Some(v1::FrameInputs { rgb: true, depth: false, labels: false }));
    // Random weights detect nonsense, but every box is well formed, filtered and inside the image.
    let img = vec![128u8; 64 * 48 * 3];
    let frame = rgb_frame(image(v1::ImageEncoding::Rgb8, 64, 48, img));
    let resp = svc.client.detect(request(frame, vec![0, 2], 0.01)).await.unwrap().into_inner();
    assert_eq!(resp.backend, "yolov8");
    assert!(resp.boxes.len() <= vlnav_detector::MAX_DETECTIONS);
    for b in &resp.boxes {
        assert!([0, 2].contains(&b.class_id) && b.score >= 0.01);
        assert!(b.x_min >= 0.0 && b.x_max <= 64.0 && b.y_min >= 0.0 && b.y_max <= 48.0, "{b:?}");
    }
    svc.stop().await.unwrap();
}

#[tokio::test]
async fn bad_images_get_invalid_argument_with_a_clear_message() {
    let mut svc = start(nanodet_options()).await;
    let mut expect = async |req: v1::DetectRequest, needle: &str| {
        let e = svc.client.detect(req).await.unwrap_err();
        assert_eq!(e.code(), Code::InvalidArgument, "{}", e.message());
        assert!(e.message().contains(needle), "{:?} should mention {needle:?}", e.message());
    };
    let jpeg = std::fs::read(require("photos/bike.jpg")).unwrap();
    // Truncated JPEG.
    let truncated = image(v1::ImageEncoding::Jpeg, 0, 0, jpeg[..jpeg.len() / 3].to_vec());
    expect(request(rgb_frame(truncated), vec![], 0.0), "cannot decode the JPEG").await;
    // Declared size differs from the decoded one.
    let odd = image(v1::ImageEncoding::Jpeg, 801, 556, jpeg.clone());
    expect(request(rgb_frame(odd), vec![], 0.0), "decodes to 800×556").await;
    // Raw RGB8 of the wrong length; RGBA sent as RGB8.
    let short = image(v1::ImageEncoding::Rgb8, 10, 10, vec![0; 299]);
    expect(request(rgb_frame(short), vec![], 0.0), "299 bytes, but 10×10×3 = 300").await;
    let rgba = image(v1::ImageEncoding::Rgb8, 10, 10, vec![0; 400]);
    expect(request(rgb_frame(rgba), vec![], 0.0), "4-channel").await;
    let no_width = image(v1::ImageEncoding::Rgb8, 0, 10, vec![0; 30]);
    expect(request(rgb_frame(no_width), vec![], 0.0), "width and height").await;
    let unspecified = image(v1::ImageEncoding::Unspecified, 1, 1, vec![0; 3]);
    expect(request(rgb_frame(unspecified), vec![], 0.0), "encoding").await;
    // Missing frame or image, bad class id, bad score.
    expect(v1::DetectRequest { frame: None, class_ids: vec![], min_score: 0.0 }, "frame").await;
    expect(request(v1::RgbdFrame::default(), vec![], 0.0), "frame.rgb").await;
    let ok = || rgb_frame(image(v1::ImageEncoding::Rgb8, 2, 2, vec![0; 12]));
    expect(request(ok(), vec![0, 80], 0.0), "class_ids[1] = 80").await;
    expect(request(ok(), vec![], 1.5), "min_score").await;
    expect(request(ok(), vec![], f32::NAN), "min_score").await;
    // A tiny valid image is fine.
    let resp = svc.client.detect(request(ok(), vec![], 0.0)).await.unwrap().into_inner();
    assert_eq!(resp.backend, "nanodet");
    svc.stop().await.unwrap();
}
