//! The detector actor: a dedicated thread owns the loaded backend and drains
//! the mailbox. Whatever requests queued up while a forward pass ran are taken
//! together (up to `max_batch`) and go through the network as one batch.

use image::RgbImage;
use tokio::sync::{mpsc, oneshot};
use vlnav_runtime::actor::Mailbox;

use crate::classes::{ClassMap, Labeled};
use crate::detection::{DetectFilter, Detection};
use crate::nanodet::{self, ModelError, NanoDet};
use crate::sim::{self, LabeledFrame, SimConfig};
use crate::yolov8::{self, YoloV8};
use crate::{BackendKind, Options};

/// What a backend reads from a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum InputKind {
    Rgb,
    /// The label image, and depth when `depth` (the oracle backend ranges
    /// its boxes; the realistic one draws from its model without depth).
    Labels {
        depth: bool,
    },
}

/// Static description of the loaded backend.
#[derive(Clone, Debug, PartialEq)]
pub struct BackendInfo {
    pub backend: &'static str,
    pub model: String,
    pub input_width: u32,
    pub input_height: u32,
    pub device: String,
    pub input: InputKind,
    /// The model's class names, by its class index.
    pub classes: Vec<String>,
}

/// One frame's input.
#[derive(Clone, Debug)]
pub enum Input {
    Rgb(RgbImage),
    Labels(LabeledFrame),
}

#[derive(Clone, Debug)]
pub struct Job {
    pub input: Input,
    pub filter: DetectFilter,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum DetectError {
    #[error("{0}")]
    InvalidArgument(String),
    #[error("detection failed: {0}")]
    Internal(String),
}

pub enum Backend {
    NanoDet { model: Box<NanoDet>, nms_iou: f32, device: String },
    YoloV8 { model: Box<YoloV8>, classes: ClassMap, nms_iou: f32, device: String },
    Sim(SimConfig),
}

fn device_name(d: &candle_core::Device) -> String {
    match d {
        candle_core::Device::Cpu => "cpu".into(),
        candle_core::Device::Cuda(_) => "cuda:0".into(),
        candle_core::Device::Metal(_) => "metal".into(),
    }
}

impl Backend {
    /// Loads the backend `opts` selects; a missing model names its file and deploy/fetch-models.sh.
    pub fn load(opts: &Options) -> anyhow::Result<Self> {
        Ok(match opts.backend {
            BackendKind::Nanodet => {
                let dev = crate::device(opts.device)?;
                let model = NanoDet::load(&opts.nanodet_files(), &dev)?;
                Backend::NanoDet { model: Box::new(model), nms_iou: opts.nms_iou, device: device_name(&dev) }
            }
            BackendKind::Yolov8 => {
                let dev = crate::device(opts.device)?;
                let path = opts.yolo_weights_path();
                let model = YoloV8::load(&path, opts.yolo_size, &dev).map_err(|e| match e {
                    ModelError::Missing(p) => anyhow::anyhow!(
                        "{} is missing: run deploy/fetch-models.sh for the trained YOLOv8s ({}), or convert your \
                         ultralytics model to candle naming (see services/detector/README.md) and pass --detector-yolo-weights",
                        p.display(),
                        crate::TRAINED_YOLOV8
                    ),
                    other => other.into(),
                })?;
                let classes = yolo_classes(opts, &path, model.num_classes())?;
                Backend::YoloV8 { model: Box::new(model), classes, nms_iou: opts.nms_iou, device: device_name(&dev) }
            }
            BackendKind::Sim => Backend::Sim(opts.sim_config()?),
        })
    }

    pub fn info(&self) -> BackendInfo {
        match self {
            Backend::NanoDet { device, .. } => BackendInfo {
                backend: "nanodet",
                model: nanodet::MODEL_NAME.into(),
                input_width: nanodet::INPUT_SIZE,
                input_height: nanodet::INPUT_SIZE,
                device: device.clone(),
                input: InputKind::Rgb,
                classes: coco_names(),
            },
            Backend::YoloV8 { model, classes, device, .. } => BackendInfo {
                backend: "yolov8",
                model: model.size().name().into(),
                input_width: yolov8::INPUT_SIZE,
                input_height: yolov8::INPUT_SIZE,
                device: device.clone(),
                input: InputKind::Rgb,
                classes: classes.names().to_vec(),
            },
            Backend::Sim(cfg) => BackendInfo {
                backend: "sim",
                model: "label-image simulation".into(),
                input_width: 0,
                input_height: 0,
                device: "cpu".into(),
                input: InputKind::Labels { depth: cfg.model.is_none() },
                classes: coco_names(),
            },
        }
    }

    /// Runs a batch; one result per job, in order.
    pub fn run(&self, jobs: &[Job]) -> Vec<Result<Vec<Labeled>, DetectError>> {
        let coco = |r: Result<Vec<Detection>, DetectError>| r.map(|ds| ds.into_iter().map(Labeled::coco).collect());
        match self {
            Backend::Sim(cfg) => jobs
                .iter()
                .map(|j| match &j.input {
                    Input::Labels(f) => Ok(sim::detect(f, cfg, &j.filter)),
                    Input::Rgb(_) => {
                        Err(DetectError::InvalidArgument("the simulation backend needs frame.labels".into()))
                    }
                })
                .map(coco)
                .collect(),
            Backend::NanoDet { model, nms_iou, .. } => {
                run_images(jobs, |f| f.clone(), |imgs, filters| model.detect(imgs, filters, *nms_iou))
                    .into_iter()
                    .map(coco)
                    .collect()
            }
            Backend::YoloV8 { model, classes, nms_iou, .. } => {
                // Detection, NMS and class filtering in the model's classes; then reported as COCO.
                let filter = |f: &DetectFilter| classes.model_filter(f);
                run_images(jobs, filter, |imgs, filters| model.detect(imgs, filters, *nms_iou))
                    .into_iter()
                    .map(|r| r.map(|ds| ds.into_iter().map(|d| classes.report(d)).collect()))
                    .collect()
            }
        }
    }
}

fn coco_names() -> Vec<String> {
    vlnav_proto::coco::CLASSES.iter().map(|c| c.to_string()).collect()
}

/// The YOLOv8 model's classes: its names file, or COCO-80 for an 80-class model
/// without one; a names file that does not match the head is a start-up error.
fn yolo_classes(opts: &Options, weights: &std::path::Path, num_classes: usize) -> anyhow::Result<ClassMap> {
    let Some(path) = opts.yolo_names_path() else {
        anyhow::ensure!(
            num_classes == 80,
            "{}: the model has {num_classes} classes, and there is no class-names file: pass --detector-yolo-names \
             (YAML or JSON as ultralytics writes them, e.g. `names: {{0: Normal, 1: Fall}}`; see services/detector/README.md)",
            weights.display()
        );
        return Ok(ClassMap::coco80());
    };
    let classes = ClassMap::load(&path)?;
    anyhow::ensure!(
        classes.len() == num_classes,
        "{} names {} classes, but the model's head ({}) has {num_classes}",
        path.display(),
        classes.len(),
        weights.display()
    );
    Ok(classes)
}

/// Runs the image jobs through `detect` as one batch, each with `filter_of` its
/// request's filter; other jobs get an error.
fn run_images<G, F>(jobs: &[Job], filter_of: G, detect: F) -> Vec<Result<Vec<Detection>, DetectError>>
where
    G: Fn(&DetectFilter) -> DetectFilter,
    F: Fn(&[&RgbImage], &[DetectFilter]) -> Result<Vec<Vec<Detection>>, ModelError>,
{
    let mut results: Vec<Result<Vec<Detection>, DetectError>> = Vec::with_capacity(jobs.len());
    let mut images = Vec::new();
    let mut filters = Vec::new();
    let mut slots = Vec::new();
    for (i, j) in jobs.iter().enumerate() {
        match &j.input {
            Input::Rgb(img) => {
                images.push(img);
                filters.push(filter_of(&j.filter));
                slots.push(i);
                results.push(Ok(Vec::new()));
            }
            Input::Labels(_) => results.push(Err(DetectError::InvalidArgument("this backend reads frame.rgb".into()))),
        }
    }
    if images.is_empty() {
        return results;
    }
    match detect(&images, &filters) {
        Ok(per_image) => {
            for (slot, dets) in slots.into_iter().zip(per_image) {
                results[slot] = Ok(dets);
            }
        }
        Err(e) => {
            for slot in slots {
                results[slot] = Err(DetectError::Internal(e.to_string()));
            }
        }
    }
    results
}

pub enum Msg {
    Detect { job: Job, reply: oneshot::Sender<Result<Vec<Labeled>, DetectError>> },
}

/// Starts the actor thread; it ends when every mailbox handle is dropped.
pub fn spawn(backend: Backend, max_batch: usize) -> Mailbox<Msg> {
    let (mailbox, rx) = Mailbox::channel("detector", 64);
    std::thread::Builder::new()
        .name("detector-actor".into())
        .spawn(move || run_loop(backend, rx, max_batch.max(1)))
        .expect("spawning the detector thread");
    mailbox
}

fn run_loop(backend: Backend, mut rx: mpsc::Receiver<Msg>, max_batch: usize) {
    while let Some(first) = rx.blocking_recv() {
        let mut batch = vec![first];
        while batch.len() < max_batch {
            match rx.try_recv() {
                Ok(m) => batch.push(m),
                Err(_) => break,
            }
        }
        let (jobs, replies): (Vec<Job>, Vec<_>) = batch
            .into_iter()
            .map(|m| match m {
                Msg::Detect { job, reply } => (job, reply),
            })
            .unzip();
        tracing::debug!(batch = jobs.len(), "detector batch");
        for (reply, result) in replies.into_iter().zip(backend.run(&jobs)) {
            // The caller may have given up (deadline); nothing to do then.
            let _ = reply.send(result);
        }
    }
}
