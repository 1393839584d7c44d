//! Local in-process LLM: Gemma 3 270M (GGUF, Q4_K_M) through candle's
//! `quantized_gemma3`, prompted few-shot and decoded greedily until a
//! complete JSON array. The tokenizer is read from the GGUF itself
//! (SentencePiece pieces and scores, byte fallback). The constant part of
//! the prompt (rules and examples) is run once and its key/value cache
//! reused for every request.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use candle_core::quantized::gguf_file;
use candle_core::{Device, Tensor};
use candle_transformers::models::quantized_gemma3::ModelWeights;
use serde_json::Value;

use crate::llm::{ChatModel, LlmError};
use crate::validate::extract_json;

/// The assembled weights under the models directory.
pub const GEMMA_FILE: &str = "gemma/gemma3-270m-q4_k_m.gguf";
/// Most tokens generated for one plan.
pub const MAX_NEW_TOKENS: usize = 120;
/// The start of every answer, given to the model rather than generated.
pub const ANSWER_OPENING: &str = " [{\"action\":\"";

/// SentencePiece tokenizer rebuilt from GGUF metadata.
pub struct SpmTokenizer {
    pieces: Vec<String>,
    ids: HashMap<String, (u32, f32)>,
    byte_ids: [Option<u32>; 256],
    pub bos: u32,
    pub eos: u32,
}

impl SpmTokenizer {
    pub fn from_gguf(ct: &gguf_file::Content) -> Result<SpmTokenizer, String> {
        let md = |k: &str| ct.metadata.get(k).ok_or(format!("GGUF metadata lacks {k}"));
        let tokens = match md("tokenizer.ggml.tokens")? {
            gguf_file::Value::Array(a) => {
                a.iter().map(|v| v.to_string().cloned().map_err(|e| e.to_string())).collect::<Result<Vec<_>, _>>()?
            }
            _ => return Err("tokenizer.ggml.tokens is not an array".into()),
        };
        let scores: Vec<f32> = match md("tokenizer.ggml.scores") {
            Ok(gguf_file::Value::Array(a)) => a.iter().map(|v| v.to_f32().unwrap_or(0.0)).collect(),
            _ => vec![0.0; tokens.len()],
        };
        let types: Vec<i32> = match md("tokenizer.ggml.token_type") {
            Ok(gguf_file::Value::Array(a)) => a.iter().map(|v| v.to_i32().unwrap_or(1)).collect(),
            _ => vec![1; tokens.len()],
        };
        let id_of = |k: &str, d: u32| md(k).ok().and_then(|v| v.to_u32().ok()).unwrap_or(d);
        let mut ids = HashMap::with_capacity(tokens.len());
        let mut byte_ids = [None; 256];
        for (i, t) in tokens.iter().enumerate() {
            let ty = types.get(i).copied().unwrap_or(1);
            if ty == 6 {
                if let Some(hex) = t.strip_prefix("<0x").and_then(|h| h.strip_suffix('>'))
                    && let Ok(b) = u8::from_str_radix(hex, 16)
                {
                    byte_ids[b as usize] = Some(i as u32);
                }
                continue;
            }
            // Control and unused tokens never come out of plain text.
            if matches!(ty, 3 | 5) {
                continue;
            }
            ids.entry(t.clone()).or_insert((i as u32, scores.get(i).copied().unwrap_or(0.0)));
        }
        Ok(SpmTokenizer {
            bos: id_of("tokenizer.ggml.bos_token_id", 2),
            eos: id_of("tokenizer.ggml.eos_token_id", 1),
            pieces: tokens,
            ids,
            byte_ids,
        })
    }

    /// Byte-pair merges by score within each whitespace-led word.
    pub fn encode(&self, text: &str) -> Vec<u32> {
        let text = text.replace(' ', "\u{2581}");
        let mut out = Vec::new();
        let mut word = String::new();
        for c in text.chars() {
            if (c == '\u{2581}' || c == '\n') && !word.is_empty() && !word.chars().all(|x| x == c) {
                self.encode_word(&word, &mut out);
                word.clear();
            }
            word.push(c);
        }
        if !word.is_empty() {
            self.encode_word(&word, &mut out);
        }
        out
    }

    fn encode_word(&self, word: &str, out: &mut Vec<u32>) {
        let mut syms: Vec<String> = word.chars().map(|c| c.to_string()).collect();
        loop {
            let mut best: Option<(usize, f32)> = None;
            for i in 0..syms.len().saturating_sub(1) {
                let joined = format!("{}{}", syms[i], syms[i + 1]);
                if let Some(&(_, score)) = self.ids.get(&joined)
                    && best.is_none_or(|(_, s)| score > s)
                {
                    best = Some((i, score));
                }
            }
            let Some((i, _)) = best else { break };
            let right = syms.remove(i + 1);
            syms[i].push_str(&right);
        }
        for s in syms {
            match self.ids.get(&s) {
                Some(&(id, _)) => out.push(id),
                None => out.extend(s.bytes().filter_map(|b| self.byte_ids[b as usize])),
            }
        }
    }

    pub fn decode(&self, ids: &[u32]) -> String {
        let mut bytes = Vec::new();
        for &id in ids {
            let Some(p) = self.pieces.get(id as usize) else { continue };
            if let Some(b) =
                p.strip_prefix("<0x").and_then(|h| h.strip_suffix('>')).and_then(|h| u8::from_str_radix(h, 16).ok())
            {
                bytes.push(b);
            } else if !(p.starts_with('<') && p.ends_with('>') && p.len() > 2) {
                bytes.extend_from_slice(p.replace('\u{2581}', " ").as_bytes());
            }
        }
        String::from_utf8_lossy(&bytes).into_owned()
    }
}

/// A prompt prefix already run through the model.
struct Cached {
    prefix: String,
    tokens: usize,
    state: ModelWeights,
}

pub struct GemmaChat {
    base: ModelWeights,
    tokenizer: SpmTokenizer,
    device: Device,
    cache: Option<Cached>,
    pub max_new_tokens: usize,
}

#[derive(Debug, thiserror::Error)]
pub enum GgufError {
    #[error("missing model file {0}: run deploy/fetch-models.sh (fragment 21-gemma) to fetch Gemma 3 270M")]
    Missing(PathBuf),
    #[error("cannot load {path}: {msg}")]
    Load { path: PathBuf, msg: String },
}

impl GemmaChat {
    pub fn path(models_dir: &Path) -> PathBuf {
        models_dir.join(GEMMA_FILE)
    }

    pub fn load(path: &Path) -> Result<GemmaChat, GgufError> {
        if !path.is_file() {
            return Err(GgufError::Missing(path.to_path_buf()));
        }
        let load = |msg: String| GgufError::Load { path: path.to_path_buf(), msg };
        let mut file = std::fs::File::open(path).map_err(|e| load(e.to_string()))?;
        let content = gguf_file::Content::read(&mut file).map_err(|e| load(e.to_string()))?;
        let tokenizer = SpmTokenizer::from_gguf(&content).map_err(load)?;
        let device = Device::Cpu;
        let base = ModelWeights::from_gguf(content, &mut file, &device).map_err(|e| load(e.to_string()))?;
        Ok(GemmaChat { base, tokenizer, device, cache: None, max_new_tokens: MAX_NEW_TOKENS })
    }

    pub fn tokenizer(&self) -> &SpmTokenizer {
        &self.tokenizer
    }

    fn logits(model: &mut ModelWeights, tokens: &[u32], pos: usize, device: &Device) -> candle_core::Result<Tensor> {
        let input = Tensor::new(tokens, device)?.unsqueeze(0)?;
        model.forward(&input, pos)?.squeeze(0)
    }

    /// Greedy continuation of `prompt`; the part up to the last
    /// "Instruction:" is cached across calls.
    pub fn generate(&mut self, prompt: &str) -> Result<String, LlmError> {
        let err = |e: candle_core::Error| LlmError::Local(e.to_string());
        let split = prompt.rfind("Instruction:").unwrap_or(0);
        let (prefix, rest) = prompt.split_at(split);
        if self.cache.as_ref().is_none_or(|c| c.prefix != prefix) {
            let mut tokens = vec![self.tokenizer.bos];
            tokens.extend(self.tokenizer.encode(prefix));
            let mut state = self.base.clone();
            Self::logits(&mut state, &tokens, 0, &self.device).map_err(err)?;
            self.cache = Some(Cached { prefix: prefix.to_string(), tokens: tokens.len(), state });
        }
        let cached = self.cache.as_ref().expect("cache filled above");
        let mut state = cached.state.clone();
        let mut pos = cached.tokens;
        // Feed one token at a time after the cached prefix: the model's
        // multi-token mask assumes an empty cache.
        let mut logits = None;
        for t in self.tokenizer.encode(rest) {
            logits = Some(Self::logits(&mut state, &[t], pos, &self.device).map_err(err)?);
            pos += 1;
        }
        let mut logits = logits.ok_or_else(|| LlmError::Local("empty prompt".into()))?;
        let mut out_ids = Vec::new();
        for _ in 0..self.max_new_tokens {
            let v: Vec<f32> = logits.to_vec1().map_err(err)?;
            let next = v
                .iter()
                .enumerate()
                .max_by(|a, b| a.1.total_cmp(b.1))
                .map(|(i, _)| i as u32)
                .unwrap_or(self.tokenizer.eos);
            if next == self.tokenizer.eos {
                break;
            }
            out_ids.push(next);
            let text = self.tokenizer.decode(&out_ids);
            // The answer ends where its JSON closes; a model that wanders on
            // into a blank line or the next example has stopped answering.
            if extract_json(&format!("{ANSWER_OPENING}{text}")).is_some()
                || text.contains("\n\n")
                || text.contains("Instruction:")
            {
                break;
            }
            logits = Self::logits(&mut state, &[next], pos, &self.device).map_err(err)?;
            pos += 1;
        }
        Ok(self.tokenizer.decode(&out_ids))
    }
}

impl ChatModel for GemmaChat {
    fn name(&self) -> &'static str {
        "gguf"
    }

    /// A base model has no chat template: the system text, then the user
    /// text, then the opening of the answer (`[{"action":"`), which the
    /// model continues; the closed action set is then one word away.
    /// The compact constraints replace the full system prompt: past the
    /// model's 512-token sliding window its answers degrade.
    fn complete(&mut self, _system: &str, user: &str, _schema: &Value) -> Result<String, LlmError> {
        let out = self.generate(&format!("{}\n\n{user}{ANSWER_OPENING}", crate::llm::compact_system_prompt()))?;
        Ok(format!("{}{out}", ANSWER_OPENING.trim_start()))
    }
}
