//! all-MiniLM-L6-v2 sentence embeddings with candle's BERT: mean pooling
//! over the attention mask, then L2 normalisation (what sentence-transformers
//! does for this model), so a dot product is the cosine similarity.

use std::path::{Path, PathBuf};

use candle_core::{DType, Device, Tensor};
use candle_nn::VarBuilder;
use candle_transformers::models::bert::{BertModel, Config};
use tokenizers::Tokenizer;

/// Files of the model under `<models>/minilm/`.
pub const MINILM_DIR: &str = "minilm";
pub const MINILM_FILES: [&str; 3] = ["model.safetensors", "tokenizer.json", "config.json"];

/// Longest phrase embedded, tokens (targets are short noun phrases).
const MAX_TOKENS: usize = 64;

#[derive(Debug, thiserror::Error)]
pub enum EmbedError {
    #[error("missing model file {0}: run deploy/fetch-models.sh (fragment 20-minilm) to fetch all-MiniLM-L6-v2")]
    Missing(PathBuf),
    #[error("cannot load all-MiniLM-L6-v2 from {path}: {msg}")]
    Load { path: PathBuf, msg: String },
    #[error("embedding failed: {0}")]
    Run(String),
}

pub struct MiniLm {
    model: BertModel,
    tokenizer: Tokenizer,
    device: Device,
}

impl MiniLm {
    /// Loads `<models_dir>/minilm/{model.safetensors, tokenizer.json, config.json}`.
    pub fn load(models_dir: &Path) -> Result<MiniLm, EmbedError> {
        let dir = models_dir.join(MINILM_DIR);
        for f in MINILM_FILES {
            let p = dir.join(f);
            if !p.is_file() {
                return Err(EmbedError::Missing(p));
            }
        }
        let load = |msg: String| EmbedError::Load { path: dir.clone(), msg };
        let config: Config =
            serde_json::from_slice(&std::fs::read(dir.join("config.json")).map_err(|e| load(e.to_string()))?)
                .map_err(|e| load(format!("config.json: {e}")))?;
        let mut tokenizer =
            Tokenizer::from_file(dir.join("tokenizer.json")).map_err(|e| load(format!("tokenizer.json: {e}")))?;
        tokenizer
            .with_truncation(Some(tokenizers::TruncationParams { max_length: MAX_TOKENS, ..Default::default() }))
            .map_err(|e| load(format!("tokenizer truncation: {e}")))?;
        tokenizer.with_padding(None);
        let device = Device::Cpu;
        // SAFETY: the weights file is memory-mapped read-only and not modified while mapped.
        let vb = unsafe { VarBuilder::from_mmaped_safetensors(&[dir.join("model.safetensors")], DType::F32, &device) }
            .map_err(|e| load(format!("model.safetensors: {e}")))?;
        let model = BertModel::load(vb, &config).map_err(|e| load(format!("BERT weights: {e}")))?;
        Ok(MiniLm { model, tokenizer, device })
    }

    /// The unit-length 384-d embedding of `text`.
    pub fn embed(&self, text: &str) -> Result<Vec<f32>, EmbedError> {
        let run = |e: &dyn std::fmt::Display| EmbedError::Run(e.to_string());
        let enc = self.tokenizer.encode(text, true).map_err(|e| run(&e))?;
        let ids = enc.get_ids();
        let n = ids.len();
        let input = Tensor::new(ids, &self.device).and_then(|t| t.reshape((1, n))).map_err(|e| run(&e))?;
        let types = input.zeros_like().map_err(|e| run(&e))?;
        let mask = input.ones_like().map_err(|e| run(&e))?;
        let hidden = self.model.forward(&input, &types, Some(&mask)).map_err(|e| run(&e))?;
        // Mean over tokens (one unpadded sequence: every token counts).
        let pooled = hidden.mean(1).and_then(|t| t.squeeze(0)).and_then(|t| t.to_vec1::<f32>()).map_err(|e| run(&e))?;
        Ok(normalise(pooled))
    }
}

fn normalise(mut v: Vec<f32>) -> Vec<f32> {
    let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
    if n > 0.0 {
        v.iter_mut().for_each(|x| *x /= n);
    }
    v
}

/// Cosine similarity of two unit vectors.
pub fn cosine(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}
