//! CTranslate2 Whisper (`WhisperSpec`) → the tensor names and layout of
//! `candle_transformers::models::whisper` (the Hugging Face names under
//! `model.encoder.*` / `model.decoder.*`).
//!
//! CTranslate2 fuses projections that candle keeps apart:
//! - self-attention `linear_0` is [q; k; v] stacked on the output axis
//!   ([3·d, d] weight, [3·d] bias) → `q_proj`, `k_proj`, `v_proj`;
//! - the decoder's cross-attention `linear_1` is [k; v] ([2·d, d]) →
//!   `k_proj`, `v_proj`, while `linear_0` is the query and `linear_2` the output.
//!
//! Whisper's key projections have no bias. CTranslate2 stores zeros there
//! when fusing; a key bias would not change attention anyway (it adds the
//! same q·b to every score of a query, which softmax cancels), so it is dropped.
//! Layer norms' `gamma`/`beta` become `weight`/`bias`. The encoder's
//! sinusoidal position table is not stored: candle computes the same table.

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::ct2::{self, DType};

/// One output tensor: a name in candle's layout and little-endian bytes.
#[derive(Clone, Debug, PartialEq)]
pub struct NamedTensor<'a> {
    pub name: String,
    pub shape: Vec<usize>,
    pub dtype: DType,
    pub data: &'a [u8],
}

/// `config.json` next to the weights: candle's `whisper::Config` fields plus
/// the decoding constants CTranslate2 keeps in its own config.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct WhisperConfig {
    pub num_mel_bins: usize,
    pub max_source_positions: usize,
    pub d_model: usize,
    pub encoder_attention_heads: usize,
    pub encoder_layers: usize,
    pub vocab_size: usize,
    pub max_target_positions: usize,
    pub decoder_attention_heads: usize,
    pub decoder_layers: usize,
    /// Never generated (non-speech symbols, task tokens).
    #[serde(default)]
    pub suppress_tokens: Vec<u32>,
    /// Not allowed as the first generated token (a lone space, end of text).
    #[serde(default)]
    pub begin_suppress_tokens: Vec<u32>,
}

impl WhisperConfig {
    pub fn to_candle(&self) -> candle_transformers::models::whisper::Config {
        candle_transformers::models::whisper::Config {
            num_mel_bins: self.num_mel_bins,
            max_source_positions: self.max_source_positions,
            d_model: self.d_model,
            encoder_attention_heads: self.encoder_attention_heads,
            encoder_layers: self.encoder_layers,
            vocab_size: self.vocab_size,
            max_target_positions: self.max_target_positions,
            decoder_attention_heads: self.decoder_attention_heads,
            decoder_layers: self.decoder_layers,
            suppress_tokens: self.suppress_tokens.clone(),
        }
    }
}

/// The decoding constants in CTranslate2's `config.json`.
#[derive(Clone, Debug, Default, Deserialize)]
pub struct Ct2Config {
    #[serde(default)]
    pub suppress_ids: Vec<u32>,
    #[serde(default)]
    pub suppress_ids_begin: Vec<u32>,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ConvertError {
    #[error("the model is a {0}, not a WhisperSpec")]
    NotWhisper(String),
    #[error("variable {0} is missing")]
    Missing(String),
    #[error("variable {name} has shape {shape:?}, expected {expected}")]
    Shape { name: String, shape: Vec<usize>, expected: String },
    #[error("variable {name} is {dtype:?}; weights must be f32, f16 or bf16")]
    DType { name: String, dtype: DType },
    #[error("option {0} is not an integer scalar")]
    Option(String),
}

struct Converter<'m, 'a> {
    model: &'m ct2::Model<'a>,
    out: Vec<NamedTensor<'a>>,
}

impl<'a> Converter<'_, 'a> {
    fn var(&self, name: &str) -> Result<&ct2::Variable<'a>, ConvertError> {
        let v = self.model.get(name).ok_or_else(|| ConvertError::Missing(name.to_string()))?;
        if !matches!(v.dtype, DType::F32 | DType::F16 | DType::BF16) {
            return Err(ConvertError::DType { name: name.to_string(), dtype: v.dtype });
        }
        Ok(v)
    }

    fn expect_shape(&self, name: &str, shape: &[usize]) -> Result<&ct2::Variable<'a>, ConvertError> {
        let v = self.var(name)?;
        if v.shape != shape {
            return Err(ConvertError::Shape {
                name: name.into(),
                shape: v.shape.clone(),
                expected: format!("{shape:?}"),
            });
        }
        Ok(v)
    }

    fn push(&mut self, name: String, v: &ct2::Variable<'a>) {
        self.out.push(NamedTensor { name, shape: v.shape.clone(), dtype: v.dtype, data: v.data });
    }

    fn copy(&mut self, from: &str, to: String) -> Result<(), ConvertError> {
        let v = self.var(from)?.clone();
        self.push(to, &v);
        Ok(())
    }

    fn layer_norm(&mut self, from: &str, to: &str, d: usize) -> Result<(), ConvertError> {
        let g = self.expect_shape(&format!("{from}/gamma"), &[d])?.clone();
        let b = self.expect_shape(&format!("{from}/beta"), &[d])?.clone();
        self.push(format!("{to}.weight"), &g);
        self.push(format!("{to}.bias"), &b);
        Ok(())
    }

    fn linear(&mut self, from: &str, to: &str, out_dim: usize, in_dim: usize) -> Result<(), ConvertError> {
        let w = self.expect_shape(&format!("{from}/weight"), &[out_dim, in_dim])?.clone();
        let b = self.expect_shape(&format!("{from}/bias"), &[out_dim])?.clone();
        self.push(format!("{to}.weight"), &w);
        self.push(format!("{to}.bias"), &b);
        Ok(())
    }

    /// Splits a fused projection into `parts` equal row blocks named
    /// `{to}.{part}_proj`; the `k` part keeps no bias.
    fn split_linear(&mut self, from: &str, to: &str, parts: &[&str], d: usize) -> Result<(), ConvertError> {
        let n = parts.len();
        let w = self.expect_shape(&format!("{from}/weight"), &[n * d, d])?.clone();
        let b = self.expect_shape(&format!("{from}/bias"), &[n * d])?.clone();
        let w_block = d * d * w.dtype.size();
        let b_block = d * b.dtype.size();
        for (i, part) in parts.iter().enumerate() {
            self.out.push(NamedTensor {
                name: format!("{to}.{part}_proj.weight"),
                shape: vec![d, d],
                dtype: w.dtype,
                data: &w.data[i * w_block..(i + 1) * w_block],
            });
            if *part != "k" {
                self.out.push(NamedTensor {
                    name: format!("{to}.{part}_proj.bias"),
                    shape: vec![d],
                    dtype: b.dtype,
                    data: &b.data[i * b_block..(i + 1) * b_block],
                });
            }
        }
        Ok(())
    }

    fn int_option(&self, name: &str) -> Result<usize, ConvertError> {
        self.model
            .get(name)
            .and_then(|v| v.as_int())
            .filter(|&v| v > 0)
            .map(|v| v as usize)
            .ok_or_else(|| ConvertError::Option(name.to_string()))
    }

    fn count_layers(&self, prefix: &str) -> usize {
        (0..)
            .take_while(|i| self.model.variables.keys().any(|k| k.starts_with(&format!("{prefix}/layer_{i}/"))))
            .count()
    }
}

/// Maps every weight of a CTranslate2 Whisper model to candle's names.
pub fn convert<'a>(
    model: &ct2::Model<'a>,
    ct2_config: &Ct2Config,
) -> Result<(Vec<NamedTensor<'a>>, WhisperConfig), ConvertError> {
    if model.spec != "WhisperSpec" {
        return Err(ConvertError::NotWhisper(model.spec.clone()));
    }
    let mut c = Converter { model, out: Vec::new() };
    let conv1 = c.var("encoder/conv1/weight")?;
    let [d, n_mels, 3] = conv1.shape[..] else {
        return Err(ConvertError::Shape {
            name: "encoder/conv1/weight".into(),
            shape: conv1.shape.clone(),
            expected: "[d_model, n_mels, 3]".into(),
        });
    };
    let embeddings = c.var("decoder/embeddings/weight")?;
    let vocab = embeddings.shape[0];
    c.expect_shape("decoder/embeddings/weight", &[vocab, d])?;
    let n_audio_ctx = c.var("encoder/position_encodings/encodings")?.shape[0];
    c.expect_shape("encoder/position_encodings/encodings", &[n_audio_ctx, d])?;
    let n_text_ctx = c.var("decoder/position_encodings/encodings")?.shape[0];
    c.expect_shape("decoder/position_encodings/encodings", &[n_text_ctx, d])?;
    let n_mlp = c.var("encoder/layer_0/ffn/linear_0/weight")?.shape[0];

    c.copy("encoder/conv1/weight", "model.encoder.conv1.weight".into())?;
    c.copy("encoder/conv1/bias", "model.encoder.conv1.bias".into())?;
    c.expect_shape("encoder/conv2/weight", &[d, d, 3])?;
    c.copy("encoder/conv2/weight", "model.encoder.conv2.weight".into())?;
    c.copy("encoder/conv2/bias", "model.encoder.conv2.bias".into())?;

    let encoder_layers = c.count_layers("encoder");
    for i in 0..encoder_layers {
        let (f, t) = (format!("encoder/layer_{i}"), format!("model.encoder.layers.{i}"));
        c.layer_norm(&format!("{f}/self_attention/layer_norm"), &format!("{t}.self_attn_layer_norm"), d)?;
        c.split_linear(&format!("{f}/self_attention/linear_0"), &format!("{t}.self_attn"), &["q", "k", "v"], d)?;
        c.linear(&format!("{f}/self_attention/linear_1"), &format!("{t}.self_attn.out_proj"), d, d)?;
        c.layer_norm(&format!("{f}/ffn/layer_norm"), &format!("{t}.final_layer_norm"), d)?;
        c.linear(&format!("{f}/ffn/linear_0"), &format!("{t}.fc1"), n_mlp, d)?;
        c.linear(&format!("{f}/ffn/linear_1"), &format!("{t}.fc2"), d, n_mlp)?;
    }
    c.layer_norm("encoder/layer_norm", "model.encoder.layer_norm", d)?;

    c.copy("decoder/embeddings/weight", "model.decoder.embed_tokens.weight".into())?;
    c.copy("decoder/position_encodings/encodings", "model.decoder.embed_positions.weight".into())?;
    let decoder_layers = c.count_layers("decoder");
    for i in 0..decoder_layers {
        let (f, t) = (format!("decoder/layer_{i}"), format!("model.decoder.layers.{i}"));
        c.layer_norm(&format!("{f}/self_attention/layer_norm"), &format!("{t}.self_attn_layer_norm"), d)?;
        c.split_linear(&format!("{f}/self_attention/linear_0"), &format!("{t}.self_attn"), &["q", "k", "v"], d)?;
        c.linear(&format!("{f}/self_attention/linear_1"), &format!("{t}.self_attn.out_proj"), d, d)?;
        c.layer_norm(&format!("{f}/attention/layer_norm"), &format!("{t}.encoder_attn_layer_norm"), d)?;
        c.linear(&format!("{f}/attention/linear_0"), &format!("{t}.encoder_attn.q_proj"), d, d)?;
        c.split_linear(&format!("{f}/attention/linear_1"), &format!("{t}.encoder_attn"), &["k", "v"], d)?;
        c.linear(&format!("{f}/attention/linear_2"), &format!("{t}.encoder_attn.out_proj"), d, d)?;
        c.layer_norm(&format!("{f}/ffn/layer_norm"), &format!("{t}.final_layer_norm"), d)?;
        c.linear(&format!("{f}/ffn/linear_0"), &format!("{t}.fc1"), n_mlp, d)?;
        c.linear(&format!("{f}/ffn/linear_1"), &format!("{t}.fc2"), d, n_mlp)?;
    }
    c.layer_norm("decoder/layer_norm", "model.decoder.layer_norm", d)?;

    let config = WhisperConfig {
        num_mel_bins: n_mels,
        max_source_positions: n_audio_ctx,
        d_model: d,
        encoder_attention_heads: c.int_option("encoder/num_heads")?,
        encoder_layers,
        vocab_size: vocab,
        max_target_positions: n_text_ctx,
        decoder_attention_heads: c.int_option("decoder/num_heads")?,
        decoder_layers,
        suppress_tokens: ct2_config.suppress_ids.clone(),
        begin_suppress_tokens: ct2_config.suppress_ids_begin.clone(),
    };
    Ok((c.out, config))
}

/// Reads `model.bin` and `config.json` of a CTranslate2 Whisper model and
/// writes `model.safetensors` and `config.json` into `out_dir`. Returns the
/// number of tensors written.
pub fn convert_files(
    model_bin: &Path,
    ct2_config_json: &Path,
    out_dir: &Path,
) -> anyhow::Result<(usize, WhisperConfig)> {
    use anyhow::Context;
    let bytes = std::fs::read(model_bin).with_context(|| format!("reading {}", model_bin.display()))?;
    let model = ct2::parse(&bytes).with_context(|| format!("parsing {}", model_bin.display()))?;
    let ct2_config: Ct2Config = serde_json::from_slice(
        &std::fs::read(ct2_config_json).with_context(|| format!("reading {}", ct2_config_json.display()))?,
    )
    .with_context(|| format!("parsing {}", ct2_config_json.display()))?;
    let (tensors, config) = convert(&model, &ct2_config)?;
    std::fs::create_dir_all(out_dir).with_context(|| format!("creating {}", out_dir.display()))?;
    let views = tensors
        .iter()
        .map(|t| {
            let dtype = match t.dtype {
                DType::F32 => safetensors::Dtype::F32,
                DType::F16 => safetensors::Dtype::F16,
                DType::BF16 => safetensors::Dtype::BF16,
                other => anyhow::bail!("{}: unexpected dtype {other:?}", t.name),
            };
            Ok((t.name.clone(), safetensors::tensor::TensorView::new(dtype, t.shape.clone(), t.data)?))
        })
        .collect::<anyhow::Result<BTreeMap<_, _>>>()?;
    let metadata = Some(
        [("source".to_string(), "CTranslate2 WhisperSpec model.bin, converted by vlnav-convert-whisper".to_string())]
            .into_iter()
            .collect(),
    );
    // Write to temporary names and rename, so a partial file is never taken for a model.
    let weights = out_dir.join("model.safetensors");
    let tmp = out_dir.join("model.safetensors.part");
    safetensors::serialize_to_file(views, &metadata, &tmp)?;
    std::fs::rename(&tmp, &weights)?;
    let cfg_tmp = out_dir.join("config.json.part");
    std::fs::write(&cfg_tmp, serde_json::to_vec_pretty(&config)?)?;
    std::fs::rename(&cfg_tmp, out_dir.join("config.json"))?;
    Ok((tensors.len(), config))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ct2::write;

    /// A two-layer model with d = 2: every value encodes its origin so the
    /// split can be checked element by element.
    fn tiny_model() -> Vec<u8> {
        let d = 2;
        let f32s = |vals: Vec<f32>| vals.into_iter().flat_map(|v| v.to_le_bytes()).collect::<Vec<u8>>();
        let seq = |n: usize, base: f32| f32s((0..n).map(|i| base + i as f32).collect());
        let mut vars: Vec<(String, Vec<usize>, DType, Vec<u8>)> = vec![
            ("encoder/conv1/weight".into(), vec![d, 3, 3], DType::F32, seq(d * 9, 0.0)),
            ("encoder/conv1/bias".into(), vec![d], DType::F32, seq(d, 0.0)),
            ("encoder/conv2/weight".into(), vec![d, d, 3], DType::F32, seq(d * d * 3, 0.0)),
            ("encoder/conv2/bias".into(), vec![d], DType::F32, seq(d, 0.0)),
            ("encoder/position_encodings/encodings".into(), vec![5, d], DType::F32, seq(10, 0.0)),
            ("encoder/layer_norm/gamma".into(), vec![d], DType::F32, seq(d, 1.0)),
            ("encoder/layer_norm/beta".into(), vec![d], DType::F32, seq(d, 0.0)),
            ("encoder/num_heads".into(), vec![], DType::I16, 1i16.to_le_bytes().to_vec()),
            ("decoder/num_heads".into(), vec![], DType::I16, 1i16.to_le_bytes().to_vec()),
            ("decoder/embeddings/weight".into(), vec![7, d], DType::F32, seq(14, 0.0)),
            ("decoder/position_encodings/encodings".into(), vec![4, d], DType::F32, seq(8, 0.0)),
            ("decoder/layer_norm/gamma".into(), vec![d], DType::F32, seq(d, 1.0)),
            ("decoder/layer_norm/beta".into(), vec![d], DType::F32, seq(d, 0.0)),
        ];
        let mut block = |p: &str, cross: bool| {
            for ln in ["self_attention/layer_norm", "ffn/layer_norm"] {
                vars.push((format!("{p}/{ln}/gamma"), vec![d], DType::F32, seq(d, 1.0)));
                vars.push((format!("{p}/{ln}/beta"), vec![d], DType::F32, seq(d, 0.0)));
            }
            // Fused qkv: rows 0-1 q (values 100+), rows 2-3 k (200+), rows 4-5 v (300+).
            let mut w = Vec::new();
            let mut b = Vec::new();
            for (k, base) in [100.0, 200.0, 300.0].into_iter().enumerate() {
                w.extend((0..d * d).map(|i| base + i as f32));
                b.extend((0..d).map(|i| if k == 1 { 0.0 } else { base + 50.0 + i as f32 }));
            }
            vars.push((format!("{p}/self_attention/linear_0/weight"), vec![3 * d, d], DType::F32, f32s(w)));
            vars.push((format!("{p}/self_attention/linear_0/bias"), vec![3 * d], DType::F32, f32s(b)));
            vars.push((format!("{p}/self_attention/linear_1/weight"), vec![d, d], DType::F32, seq(d * d, 0.0)));
            vars.push((format!("{p}/self_attention/linear_1/bias"), vec![d], DType::F32, seq(d, 0.0)));
            vars.push((format!("{p}/ffn/linear_0/weight"), vec![8, d], DType::F32, seq(8 * d, 0.0)));
            vars.push((format!("{p}/ffn/linear_0/bias"), vec![8], DType::F32, seq(8, 0.0)));
            vars.push((format!("{p}/ffn/linear_1/weight"), vec![d, 8], DType::F32, seq(8 * d, 0.0)));
            vars.push((format!("{p}/ffn/linear_1/bias"), vec![d], DType::F32, seq(d, 0.0)));
            if cross {
                vars.push((format!("{p}/attention/layer_norm/gamma"), vec![d], DType::F32, seq(d, 1.0)));
                vars.push((format!("{p}/attention/layer_norm/beta"), vec![d], DType::F32, seq(d, 0.0)));
                for (l, rows) in [("linear_0", d), ("linear_2", d)] {
                    vars.push((format!("{p}/attention/{l}/weight"), vec![rows, d], DType::F32, seq(rows * d, 0.0)));
                    vars.push((format!("{p}/attention/{l}/bias"), vec![rows], DType::F32, seq(rows, 0.0)));
                }
                // Fused kv: k rows 500+, v rows 600+.
                let w: Vec<f32> =
                    (0..d * d).map(|i| 500.0 + i as f32).chain((0..d * d).map(|i| 600.0 + i as f32)).collect();
                let b: Vec<f32> = vec![0.0; d].into_iter().chain((0..d).map(|i| 650.0 + i as f32)).collect();
                vars.push((format!("{p}/attention/linear_1/weight"), vec![2 * d, d], DType::F32, f32s(w)));
                vars.push((format!("{p}/attention/linear_1/bias"), vec![2 * d], DType::F32, f32s(b)));
            }
        };
        for i in 0..2 {
            block(&format!("encoder/layer_{i}"), false);
            block(&format!("decoder/layer_{i}"), true);
        }
        let refs: Vec<(&str, Vec<usize>, DType, Vec<u8>)> =
            vars.iter().map(|(n, s, t, b)| (n.as_str(), s.clone(), *t, b.clone())).collect();
        write("WhisperSpec", 3, &refs, &[("decoder/projection/weight", "decoder/embeddings/weight")])
    }

    fn values(t: &NamedTensor) -> Vec<f32> {
        t.data.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect()
    }

    #[test]
    fn fused_projections_are_split_in_q_k_v_order() {
        let bytes = tiny_model();
        let model = ct2::parse(&bytes).unwrap();
        let cfg = Ct2Config { suppress_ids: vec![1, 2], suppress_ids_begin: vec![220] };
        let (tensors, config) = convert(&model, &cfg).unwrap();
        let by_name: BTreeMap<_, _> = tensors.iter().map(|t| (t.name.as_str(), t)).collect();
        let get = |n: &str| values(by_name.get(n).unwrap_or_else(|| panic!("{n} missing")));

        assert_eq!(get("model.encoder.layers.1.self_attn.q_proj.weight"), vec![100.0, 101.0, 102.0, 103.0]);
        assert_eq!(get("model.encoder.layers.1.self_attn.k_proj.weight"), vec![200.0, 201.0, 202.0, 203.0]);
        assert_eq!(get("model.encoder.layers.1.self_attn.v_proj.weight"), vec![300.0, 301.0, 302.0, 303.0]);
        assert_eq!(get("model.encoder.layers.1.self_attn.q_proj.bias"), vec![150.0, 151.0]);
        assert_eq!(get("model.encoder.layers.1.self_attn.v_proj.bias"), vec![350.0, 351.0]);
        assert!(!by_name.contains_key("model.encoder.layers.1.self_attn.k_proj.bias"));
        assert_eq!(get("model.decoder.layers.0.encoder_attn.k_proj.weight"), vec![500.0, 501.0, 502.0, 503.0]);
        assert_eq!(get("model.decoder.layers.0.encoder_attn.v_proj.weight"), vec![600.0, 601.0, 602.0, 603.0]);
        assert_eq!(get("model.decoder.layers.0.encoder_attn.v_proj.bias"), vec![650.0, 651.0]);
        assert_eq!(get("model.decoder.layers.1.encoder_attn_layer_norm.weight"), vec![1.0, 2.0]);
        assert_eq!(by_name["model.decoder.embed_tokens.weight"].shape, vec![7, 2]);

        assert_eq!(
            config,
            WhisperConfig {
                num_mel_bins: 3,
                max_source_positions: 5,
                d_model: 2,
                encoder_attention_heads: 1,
                encoder_layers: 2,
                vocab_size: 7,
                max_target_positions: 4,
                decoder_attention_heads: 1,
                decoder_layers: 2,
                suppress_tokens: vec![1, 2],
                begin_suppress_tokens: vec![220],
            }
        );
        // Encoder layer: 2 norms (4), q/k/v weights + q/v biases (5), out (2), fc1 + fc2 (4);
        // a decoder layer adds the cross-attention norm (2), q (2), k/v (3) and out (2).
        let per_encoder_layer = 4 + 5 + 2 + 4;
        let per_decoder_layer = per_encoder_layer + 2 + 2 + 3 + 2;
        assert_eq!(tensors.len(), 4 + 2 + 2 * per_encoder_layer + 2 + 2 + 2 * per_decoder_layer);
    }

    #[test]
    fn a_model_of_another_kind_or_missing_pieces_is_refused() {
        let other = write("TransformerSpec", 1, &[], &[]);
        let m = ct2::parse(&other).unwrap();
        assert_eq!(convert(&m, &Ct2Config::default()).unwrap_err(), ConvertError::NotWhisper("TransformerSpec".into()));
        let empty = write("WhisperSpec", 3, &[], &[]);
        let m = ct2::parse(&empty).unwrap();
        assert_eq!(
            convert(&m, &Ct2Config::default()).unwrap_err(),
            ConvertError::Missing("encoder/conv1/weight".into())
        );
    }

    #[test]
    fn files_are_written_where_candle_reads_them() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("model.bin"), tiny_model()).unwrap();
        std::fs::write(dir.path().join("ct2.json"), r#"{"suppress_ids":[5],"suppress_ids_begin":[6]}"#).unwrap();
        let out = dir.path().join("out");
        let (n, _) = convert_files(&dir.path().join("model.bin"), &dir.path().join("ct2.json"), &out).unwrap();
        let bytes = std::fs::read(out.join("model.safetensors")).unwrap();
        let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
        assert_eq!(st.len(), n);
        let k = st.tensor("model.decoder.layers.1.encoder_attn.k_proj.weight").unwrap();
        assert_eq!(k.shape(), &[2, 2]);
        let cfg: WhisperConfig = serde_json::from_slice(&std::fs::read(out.join("config.json")).unwrap()).unwrap();
        assert_eq!((cfg.suppress_tokens, cfg.begin_suppress_tokens), (vec![5], vec![6]));
        // candle's own Config reads the same file.
        let candle_cfg: candle_transformers::models::whisper::Config =
            serde_json::from_slice(&std::fs::read(out.join("config.json")).unwrap()).unwrap();
        assert_eq!(candle_cfg.decoder_layers, 2);
    }
}
