//! Network forward passes on this machine, candle against ONNX Runtime on the
//! same weights and the same number of threads:
//! - the trained YOLOv8s (deploy/fetch-models.sh) at 640×640, candle vs ONNX
//!   Runtime running the original ONNX export (tests/ort_reference.py);
//! - NanoDet-g at 416×416 in candle.
//!
//! `cargo bench -p vlnav-detector --bench forward` (threads: `RAYON_NUM_THREADS`,
//! default all cores; runs: `VLNAV_BENCH_RUNS`, default 10). Prints a
//! Markdown table of medians and ranges; the input is bus.jpg letterboxed.

use std::path::{Path, PathBuf};
use std::time::Instant;

use candle_core::{Device, Tensor};
use vlnav_detector::nanodet::{self, NanoDet, NanoDetFiles};
use vlnav_detector::preprocess::letterbox_chw;
use vlnav_detector::yolov8::{self, YoloV8};

fn models_dir() -> PathBuf {
    std::env::var_os("VLNAV_MODELS_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models"))
}

/// (median, min, max) in ms of `runs` calls after two warm-up calls.
fn time(runs: usize, mut f: impl FnMut()) -> (f64, f64, f64) {
    f();
    f();
    let mut ms: Vec<f64> = (0..runs)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    stats(&mut ms)
}

fn stats(ms: &mut [f64]) -> (f64, f64, f64) {
    ms.sort_by(f64::total_cmp);
    (ms[ms.len() / 2], ms[0], ms[ms.len() - 1])
}

/// ONNX Runtime's forward time on `input` (the session.run call alone, timed in Python).
fn onnx_runtime(model: &Path, input: &[f32], threads: usize, runs: usize) -> Option<(f64, f64, f64, String)> {
    let python = std::env::var_os("VLNAV_REFERENCE_PYTHON")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../../.venv/bin/python"));
    let dir = tempfile::tempdir().ok()?;
    let npy = dir.path().join("input.npy");
    write_npy(&npy, input);
    let status = std::process::Command::new(&python)
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/ort_reference.py"))
        .arg(model)
        .arg(dir.path().join("out"))
        .arg(&npy)
        .args(["--threads", &threads.to_string(), "--bench", &runs.to_string()])
        .status()
        .ok()?;
    if !status.success() {
        return None;
    }
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("out/bench.json")).ok()?).ok()?;
    let mut ms: Vec<f64> = v["ms"].as_array()?.iter().filter_map(|x| x.as_f64()).collect();
    let (med, lo, hi) = stats(&mut ms);
    Some((med, lo, hi, v["ort_version"].as_str().unwrap_or("?").to_string()))
}

fn write_npy(path: &Path, values: &[f32]) {
    let mut header = "{'descr': '<f4', 'fortran_order': False, 'shape': (1, 3, 640, 640), }".to_string();
    while !(10 + header.len() + 1).is_multiple_of(64) {
        header.push(' ');
    }
    header.push('\n');
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
    bytes.extend_from_slice(header.as_bytes());
    bytes.extend(values.iter().flat_map(|v| v.to_le_bytes()));
    std::fs::write(path, bytes).unwrap();
}

fn main() {
    // `cargo bench` passes --bench; `cargo test --benches` passes nothing: then just check it runs.
    let quick = !std::env::args().any(|a| a == "--bench");
    let runs: usize = std::env::var("VLNAV_BENCH_RUNS").ok().and_then(|v| v.parse().ok()).unwrap_or(10);
    let runs = if quick { 1 } else { runs };
    let threads = candle_core::utils::get_num_threads();
    let models = models_dir();
    let photo =
        image::open(models.join("photos/bus.jpg")).expect("photos/bus.jpg: run deploy/fetch-models.sh").into_rgb8();
    println!("threads {threads}, {runs} runs each, input bus.jpg letterboxed\n");
    println!("| network | input | runtime | median ms | min–max ms |");
    println!("|---|---|---|---|---|");

    let weights = models.join(format!("yolov8/{}.safetensors", vlnav_detector::TRAINED_YOLOV8));
    let yolo = YoloV8::load(&weights, None, &Device::Cpu).expect("the trained YOLOv8s: run deploy/fetch-models.sh");
    let (chw, _) = letterbox_chw(&photo, &yolov8::INPUT);
    let x = Tensor::from_vec(chw.clone(), (1, 3, 640, 640), &Device::Cpu).unwrap();
    let (med, lo, hi) = time(runs, || {
        yolo.forward(&x).unwrap();
    });
    println!("| YOLOv8s (fall, 2 classes) | 640×640 | candle 0.11 | {med:.0} | {lo:.0}–{hi:.0} |");
    let onnx = models.join(format!("yolov8/{}.onnx", vlnav_detector::TRAINED_YOLOV8));
    match onnx_runtime(&onnx, &chw, threads, runs) {
        Some((omed, olo, ohi, version)) => {
            println!(
                "| YOLOv8s (fall, 2 classes) | 640×640 | ONNX Runtime {version} | {omed:.0} | {olo:.0}–{ohi:.0} |"
            );
            println!("\ncandle / ONNX Runtime: {:.2}×\n", med / omed);
        }
        None => println!("\n(ONNX Runtime not run: deploy/setup-tools.sh installs it into ./.venv)\n"),
    }

    let nano = NanoDet::load(&NanoDetFiles::in_dir(&models.join("nanodet")), &Device::Cpu)
        .expect("NanoDet: run deploy/fetch-models.sh");
    let (chw, _) = letterbox_chw(&photo, &nanodet::INPUT);
    let (med, lo, hi) = time(runs, || {
        nano.forward(std::slice::from_ref(&chw)).unwrap();
    });
    println!("| NanoDet-g (COCO) | 416×416 | candle 0.11 | {med:.0} | {lo:.0}–{hi:.0} |");
}
