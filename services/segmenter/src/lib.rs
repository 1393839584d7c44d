//! vlnav-segmenter: semantic hazards on the floor — restricted zones marked
//! in red, hazard tape, cables — as a per-pixel mask and as virtual obstacle
//! points in base_link, stacked from the floor to 0.5 m, for the local planner.
//!
//! Backends implement [`segment::SegmentBackend`]: `colour` thresholds HSV per
//! class (configurable table, [`colour::default_classes`]) and keeps only
//! pixels whose depth puts them on the floor plane; `sim` reads the
//! simulator's label image. An RGB-D network (ESANet-style) is one more
//! implementation of the same trait.
//!
//! Layout: [`colour`], [`segment`] are the pure domain (the pinhole and
//! mount model is `vlnav_geometry::camera`, shared with the subgoal estimator
//! and the local planner); [`actor`] owns the backend; [`grpc`] is the tonic
//! layer.

pub mod actor;
pub mod colour;
pub mod grpc;
pub mod segment;

use std::path::PathBuf;

use anyhow::Context;
use vlnav_proto::v1::segmenter_service_server::SegmenterServiceServer;

use crate::actor::SegmenterActor;
use crate::colour::ColourClass;
use crate::segment::{ColourBackend, PointSettings, SegmentBackend, SimBackend};

pub const DEFAULT_PORT: u16 = vlnav_runtime::ports::SEGMENTER;

/// Segmenter settings (flags or `VLNAV_SEGMENTER_*` environment variables).
#[derive(clap::Args, Clone, Debug)]
pub struct Options {
    /// `colour` (HSV thresholds + depth floor check) or `sim` (simulator labels).
    #[arg(long = "segmenter-backend", env = "VLNAV_SEGMENTER_BACKEND", default_value = "colour")]
    pub backend: String,
    /// JSON class table for the colour backend:
    /// `[{"name": "restricted_zone", "ranges": [{"h": [0, 10], "s": [120, 255], "v": [70, 255]}], "floor_only": true}]`
    /// (H on OpenCV's 0–180 scale). Default: restricted_zone (red), hazard (yellow tape), cable (dark).
    #[arg(long = "segmenter-classes", env = "VLNAV_SEGMENTER_CLASSES")]
    pub classes_file: Option<PathBuf>,
    /// Height of the floor in base_link, metres.
    #[arg(long = "segmenter-floor-z-m", env = "VLNAV_SEGMENTER_FLOOR_Z_M", default_value_t = 0.0)]
    pub floor_z_m: f64,
    /// Floor-only pixels must lie within this of the floor plane, metres.
    #[arg(long = "segmenter-floor-tolerance-m", env = "VLNAV_SEGMENTER_FLOOR_TOLERANCE_M", default_value_t = 0.10)]
    pub floor_tolerance_m: f64,
    /// Heights above the floor of the stacked virtual points, metres.
    #[arg(
        long = "segmenter-layers-m",
        env = "VLNAV_SEGMENTER_LAYERS_M",
        value_delimiter = ',',
        default_value = "0,0.25,0.5"
    )]
    pub layers_m: Vec<f64>,
    /// Keep every n-th pixel (in x and in y) of a 640-wide frame when making
    /// points, scaled to the frame's width (`actor::scaled_stride`), unless
    /// the request says otherwise.
    #[arg(long = "segmenter-point-stride", env = "VLNAV_SEGMENTER_POINT_STRIDE", default_value_t = 4)]
    pub point_stride: usize,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            backend: "colour".into(),
            classes_file: None,
            floor_z_m: 0.0,
            floor_tolerance_m: 0.10,
            layers_m: vec![0.0, 0.25, 0.5],
            point_stride: 4,
        }
    }
}

/// Reads a colour class table (JSON) and checks it.
pub fn load_classes(path: &std::path::Path) -> anyhow::Result<Vec<ColourClass>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read the class table {}", path.display()))?;
    let classes: Vec<ColourClass> =
        serde_json::from_str(&text).with_context(|| format!("{}: not a valid class table", path.display()))?;
    anyhow::ensure!(!classes.is_empty() && classes.len() < 255, "{}: 1–254 classes expected", path.display());
    for c in &classes {
        anyhow::ensure!(
            !c.name.is_empty() && !c.ranges.is_empty(),
            "{}: every class needs a name and ranges",
            path.display()
        );
        for r in &c.ranges {
            anyhow::ensure!(
                r.h[0] <= r.h[1] && r.h[1] <= 180 && r.s[0] <= r.s[1] && r.v[0] <= r.v[1],
                "{}: class {}: ranges are [low, high] with H ≤ 180",
                path.display(),
                c.name
            );
        }
    }
    Ok(classes)
}

/// Builds the backend, spawns the actor, returns the service.
pub async fn services(
    opts: &Options,
    server: &vlnav_runtime::ServerConfig,
) -> anyhow::Result<vlnav_runtime::ServiceSet> {
    let backend: Box<dyn SegmentBackend> = match opts.backend.as_str() {
        "colour" | "color" => Box::new(ColourBackend::new(match &opts.classes_file {
            Some(p) => load_classes(p)?,
            None => colour::default_classes(),
        })),
        "sim" => Box::new(SimBackend),
        other => anyhow::bail!("unknown segmenter backend {other:?}: use colour or sim"),
    };
    anyhow::ensure!(
        opts.floor_tolerance_m.is_finite() && opts.floor_tolerance_m > 0.0,
        "--segmenter-floor-tolerance-m must be positive"
    );
    anyhow::ensure!(
        !opts.layers_m.is_empty() && opts.layers_m.iter().all(|z| z.is_finite()),
        "--segmenter-layers-m needs at least one finite height"
    );
    anyhow::ensure!(opts.point_stride >= 1, "--segmenter-point-stride must be at least 1");
    let name = backend.name();
    let info = grpc::BackendInfo { name, classes: backend.classes(), reads: backend.reads() };
    tracing::info!(backend = name, classes = ?backend.classes(), "segmenter ready");
    let settings = PointSettings {
        floor_z_m: opts.floor_z_m,
        floor_tolerance_m: opts.floor_tolerance_m,
        layers_m: opts.layers_m.clone(),
    };
    let actor = SegmenterActor::new(backend, settings, opts.point_stride).spawn();
    let svc = SegmenterServiceServer::new(grpc::SegmenterGrpc::new(actor, info))
        .max_decoding_message_size(server.max_message_bytes)
        .max_encoding_message_size(server.max_message_bytes);
    Ok(vlnav_runtime::ServiceSet::new().add("segment", svc).callers(vlnav_runtime::CallerPolicy::stages()))
}
