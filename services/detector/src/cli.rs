//! `vlnav detect IMAGE…`: runs a detector on photos, prints one line per box
//! (or JSON) and writes annotated copies. The same backends and code path as
//! the service ([`crate::actor::Backend`]), without the network.

use std::io::Write;
use std::path::{Path, PathBuf};

use image::RgbImage;

use crate::actor::{Backend, Input, Job};
use crate::classes::Labeled;
use crate::detection::DetectFilter;
use crate::{BackendKind, DeviceKind, Options};

/// The neural backends (the simulation backend reads label images, not photos).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum PhotoBackend {
    Nanodet,
    Yolov8,
}

#[derive(clap::Args, Clone, Debug)]
pub struct DetectArgs {
    /// Photos (PNG or JPEG).
    #[arg(required = true, value_name = "IMAGE")]
    pub images: Vec<PathBuf>,
    /// nanodet (COCO-80) or yolov8 (default weights: the trained YOLOv8s from deploy/fetch-models.sh).
    #[arg(long, value_enum, default_value_t = PhotoBackend::Nanodet)]
    pub backend: PhotoBackend,
    /// Weights: NanoDet `<x>.safetensors` (with `<x>.graph.json` beside it) or YOLOv8 safetensors in candle naming.
    #[arg(long, value_name = "FILE")]
    pub weights: Option<PathBuf>,
    /// A YOLOv8 model's class names (YAML or JSON; default `<weights stem>.names.yaml`).
    #[arg(long, value_name = "FILE")]
    pub names: Option<PathBuf>,
    /// Lowest score shown.
    #[arg(long, value_name = "S", default_value_t = 0.4)]
    pub min_score: f32,
    /// Non-maximum suppression IoU threshold (per class).
    #[arg(long, default_value_t = 0.45)]
    pub nms_iou: f32,
    /// Print one JSON document instead of one line per box.
    #[arg(long)]
    pub json: bool,
    /// Write each photo with its boxes drawn into DIR (same file name).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Model directory.
    #[arg(long, env = "VLNAV_MODELS_DIR", default_value = "models")]
    pub models_dir: PathBuf,
    #[arg(long, value_enum, default_value_t = DeviceKind::Cpu)]
    pub device: DeviceKind,
}

impl DetectArgs {
    /// Arguments with defaults for `images`.
    pub fn new(images: Vec<PathBuf>) -> Self {
        Self {
            images,
            backend: PhotoBackend::Nanodet,
            weights: None,
            names: None,
            min_score: 0.4,
            nms_iou: 0.45,
            json: false,
            out: None,
            models_dir: std::env::var_os("VLNAV_MODELS_DIR").map(PathBuf::from).unwrap_or_else(|| "models".into()),
            device: DeviceKind::Cpu,
        }
    }

    /// The detector options these arguments select.
    pub fn options(&self) -> anyhow::Result<Options> {
        anyhow::ensure!((0.0..=1.0).contains(&self.min_score), "--min-score must be in [0, 1], got {}", self.min_score);
        anyhow::ensure!((0.0..=1.0).contains(&self.nms_iou), "--nms-iou must be in [0, 1], got {}", self.nms_iou);
        let mut o = Options {
            models_dir: self.models_dir.clone(),
            min_score: self.min_score,
            nms_iou: self.nms_iou,
            device: self.device,
            ..Options::default()
        };
        match self.backend {
            PhotoBackend::Nanodet => {
                anyhow::ensure!(
                    self.names.is_none(),
                    "--names is for --backend yolov8 (NanoDet's classes are COCO-80)"
                );
                o.backend = BackendKind::Nanodet;
                o.nanodet_weights = self.weights.clone();
            }
            PhotoBackend::Yolov8 => {
                o.backend = BackendKind::Yolov8;
                o.yolo_weights = self.weights.clone();
                o.yolo_names = self.names.clone();
            }
        }
        if let Some(w) = &self.weights {
            anyhow::ensure!(w.is_file(), "--weights {}: no such file", w.display());
        }
        if let Some(n) = &self.names {
            anyhow::ensure!(n.is_file(), "--names {}: no such file", n.display());
        }
        Ok(o)
    }
}

/// One photo's result.
#[derive(Clone, Debug, PartialEq)]
pub struct PhotoResult {
    pub path: PathBuf,
    pub width: u32,
    pub height: u32,
    pub detections: Vec<Labeled>,
    /// Where the annotated copy went (with `--out`).
    pub annotated: Option<PathBuf>,
}

fn read_photo(path: &Path) -> anyhow::Result<RgbImage> {
    let reader =
        image::ImageReader::open(path).map_err(|e| anyhow::anyhow!("cannot read image {}: {e}", path.display()))?;
    let reader =
        reader.with_guessed_format().map_err(|e| anyhow::anyhow!("cannot read image {}: {e}", path.display()))?;
    let img = reader
        .decode()
        .map_err(|e| anyhow::anyhow!("cannot read image {}: {e} (PNG and JPEG are supported)", path.display()))?;
    Ok(img.into_rgb8())
}

/// One line per box: `<image>: <label>[ → <COCO class>] <score> (x_min, y_min)–(x_max, y_max)`.
pub fn describe(path: &Path, l: &Labeled) -> String {
    let d = &l.detection;
    let coco = vlnav_proto::coco::name(d.class_id);
    let class = match coco {
        Some(c) if c == l.label => l.label.clone(),
        Some(c) => format!("{} → {c}", l.label),
        None => format!("{} (no COCO class)", l.label),
    };
    format!(
        "{}: {class} {:.2} ({:.0}, {:.0})–({:.0}, {:.0})",
        path.display(),
        d.score,
        d.x_min,
        d.y_min,
        d.x_max,
        d.y_max
    )
}

fn to_json(r: &PhotoResult, backend: &str, model: &str) -> serde_json::Value {
    let dets: Vec<serde_json::Value> = r
        .detections
        .iter()
        .map(|l| {
            let d = &l.detection;
            serde_json::json!({
                "label": l.label,
                "class_id": d.class_id,
                "coco_class": vlnav_proto::coco::name(d.class_id),
                "score": d.score,
                "box": {"x_min": d.x_min, "y_min": d.y_min, "x_max": d.x_max, "y_max": d.y_max},
            })
        })
        .collect();
    serde_json::json!({
        "image": r.path.display().to_string(),
        "width": r.width,
        "height": r.height,
        "backend": backend,
        "model": model,
        "detections": dets,
        "annotated": r.annotated.as_ref().map(|p| p.display().to_string()),
    })
}

/// Runs `args`: reads every photo first (an unreadable one stops the run,
/// named), loads the backend (a missing or mismatched model file stops it,
/// named), detects, prints to `out`, writes annotated copies.
pub fn run_detect(args: &DetectArgs, out: &mut impl Write) -> anyhow::Result<Vec<PhotoResult>> {
    let opts = args.options()?;
    let photos: Vec<RgbImage> = args.images.iter().map(|p| read_photo(p)).collect::<anyhow::Result<_>>()?;
    if let Some(dir) = &args.out {
        std::fs::create_dir_all(dir).map_err(|e| anyhow::anyhow!("--out {}: {e}", dir.display()))?;
    }
    let backend = Backend::load(&opts)?;
    let info = backend.info();
    let filter = DetectFilter { class_ids: vec![], min_score: args.min_score };
    let mut results = Vec::with_capacity(photos.len());
    for (path, img) in args.images.iter().zip(photos) {
        let (width, height) = img.dimensions();
        let job = Job { input: Input::Rgb(img), filter: filter.clone() };
        let detections = backend.run(std::slice::from_ref(&job)).remove(0)?;
        let annotated = match &args.out {
            Some(dir) => Some(write_annotated(path, dir, job.input, &detections)?),
            None => None,
        };
        let r = PhotoResult { path: path.clone(), width, height, detections, annotated };
        if !args.json {
            if r.detections.is_empty() {
                writeln!(out, "{}: nothing at score ≥ {:.2}", path.display(), args.min_score)?;
            }
            for l in &r.detections {
                writeln!(out, "{}", describe(path, l))?;
            }
        }
        results.push(r);
    }
    if args.json {
        let doc: Vec<serde_json::Value> = results.iter().map(|r| to_json(r, info.backend, &info.model)).collect();
        writeln!(out, "{}", serde_json::to_string_pretty(&doc)?)?;
    }
    Ok(results)
}

fn write_annotated(src: &Path, dir: &Path, input: Input, detections: &[Labeled]) -> anyhow::Result<PathBuf> {
    let Input::Rgb(mut img) = input else { unreachable!("photos are RGB inputs") };
    let name = src.file_name().ok_or_else(|| anyhow::anyhow!("{}: not a file name", src.display()))?;
    let dest = dir.join(name);
    if let (Ok(a), Ok(b)) = (dest.canonicalize(), src.canonicalize()) {
        anyhow::ensure!(a != b, "--out {}: would overwrite the photo {} itself", dir.display(), src.display());
    }
    crate::annotate::draw(&mut img, detections);
    img.save(&dest).map_err(|e| anyhow::anyhow!("cannot write {}: {e}", dest.display()))?;
    Ok(dest)
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::{Args, FromArgMatches};

    fn parse(args: &[&str]) -> Result<DetectArgs, clap::Error> {
        let cmd = DetectArgs::augment_args(clap::Command::new("detect"));
        cmd.clone().debug_assert();
        DetectArgs::from_arg_matches(&cmd.try_get_matches_from(args)?)
    }

    #[test]
    fn flags_and_their_errors() {
        let a = parse(&["detect", "a.jpg", "b.png", "--backend", "yolov8", "--min-score", "0.3", "--json"]).unwrap();
        assert_eq!((a.images.len(), a.backend, a.min_score, a.json), (2, PhotoBackend::Yolov8, 0.3, true));
        let e = parse(&["detect", "a.jpg", "--backend", "yolo9"]).unwrap_err().to_string();
        assert!(e.contains("yolo9") && e.contains("nanodet") && e.contains("yolov8"), "{e}");
        assert!(parse(&["detect"]).is_err(), "an image is required");
        let e = run_detect(&DetectArgs { min_score: 2.0, ..DetectArgs::new(vec!["a.jpg".into()]) }, &mut Vec::new());
        assert!(e.unwrap_err().to_string().contains("--min-score"));
    }

    #[test]
    fn unreadable_images_and_missing_weights_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let text = dir.path().join("notes.jpg");
        std::fs::write(&text, "not a picture").unwrap();
        let e = run_detect(&DetectArgs::new(vec![text.clone()]), &mut Vec::new()).unwrap_err().to_string();
        assert!(e.contains("cannot read image") && e.contains("notes.jpg"), "{e}");
        let missing = dir.path().join("gone.png");
        let e = run_detect(&DetectArgs::new(vec![missing]), &mut Vec::new()).unwrap_err().to_string();
        assert!(e.contains("gone.png"), "{e}");

        let img = dir.path().join("grey.png");
        RgbImage::from_pixel(8, 8, image::Rgb([128, 128, 128])).save(&img).unwrap();
        let weights = dir.path().join("mine.safetensors");
        let args =
            DetectArgs { backend: PhotoBackend::Yolov8, weights: Some(weights), ..DetectArgs::new(vec![img.clone()]) };
        let e = run_detect(&args, &mut Vec::new()).unwrap_err().to_string();
        assert!(e.contains("mine.safetensors"), "{e}");
        let args = DetectArgs { models_dir: dir.path().into(), ..DetectArgs::new(vec![img.clone()]) };
        let e = run_detect(&args, &mut Vec::new()).unwrap_err().to_string();
        assert!(e.contains("nanodet") && e.contains("deploy/fetch-models.sh"), "{e}");
        let args = DetectArgs { names: Some(dir.path().join("n.yaml")), ..DetectArgs::new(vec![img]) };
        assert!(run_detect(&args, &mut Vec::new()).unwrap_err().to_string().contains("--names"));
    }
}
