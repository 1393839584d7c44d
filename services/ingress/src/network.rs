//! Whisper's transformer on candle, reading the tensor names of
//! `candle_transformers::models::whisper` (what `vlnav-convert-whisper`
//! writes), with what decoding needs to be fast on a CPU: the
//! decoder keeps the keys and values of its self-attention between steps,
//! so each new token costs one position instead of the whole prefix, and the
//! cross-attention keys and values of the audio are computed once per window.

use candle_core::{D, DType, Device, IndexOp, Module, Result, Tensor};
use candle_nn::{Conv1d, Conv1dConfig, LayerNorm, Linear, VarBuilder};

use crate::convert::WhisperConfig;

fn layer_norm(size: usize, vb: VarBuilder) -> Result<LayerNorm> {
    Ok(LayerNorm::new(vb.get(size, "weight")?, vb.get(size, "bias")?, 1e-5))
}

fn linear(in_dim: usize, out_dim: usize, vb: VarBuilder) -> Result<Linear> {
    Ok(Linear::new(vb.get((out_dim, in_dim), "weight")?, Some(vb.get(out_dim, "bias")?)))
}

fn linear_no_bias(in_dim: usize, out_dim: usize, vb: VarBuilder) -> Result<Linear> {
    Ok(Linear::new(vb.get((out_dim, in_dim), "weight")?, None))
}

/// [batch, time, d] → [batch, heads, time, d / heads].
fn split_heads(x: &Tensor, heads: usize) -> Result<Tensor> {
    let (b, t, d) = x.dims3()?;
    x.reshape((b, t, heads, d / heads))?.transpose(1, 2)?.contiguous()
}

/// Scaled dot-product attention over head-split q, k, v; returns [batch, time, d].
fn attend(q: &Tensor, k: &Tensor, v: &Tensor, mask: Option<&Tensor>) -> Result<Tensor> {
    let head_dim = q.dim(D::Minus1)?;
    let scores = (q.matmul(&k.t()?)? * (head_dim as f64).powf(-0.5))?;
    let scores = match mask {
        Some(m) => scores.broadcast_add(m)?,
        None => scores,
    };
    let weights = candle_nn::ops::softmax_last_dim(&scores)?;
    weights.matmul(v)?.transpose(1, 2)?.flatten_from(2)
}

struct Attention {
    query: Linear,
    key: Linear,
    value: Linear,
    out: Linear,
    heads: usize,
}

impl Attention {
    fn load(d: usize, heads: usize, vb: VarBuilder) -> Result<Self> {
        Ok(Self {
            query: linear(d, d, vb.pp("q_proj"))?,
            key: linear_no_bias(d, d, vb.pp("k_proj"))?,
            value: linear(d, d, vb.pp("v_proj"))?,
            out: linear(d, d, vb.pp("out_proj"))?,
            heads,
        })
    }

    fn keys_values(&self, x: &Tensor) -> Result<(Tensor, Tensor)> {
        Ok((split_heads(&self.key.forward(x)?, self.heads)?, split_heads(&self.value.forward(x)?, self.heads)?))
    }

    /// Self-attention of `x`; with a cache, `x` holds only the new positions
    /// and their keys/values are appended to it.
    fn self_attend(
        &self,
        x: &Tensor,
        cache: Option<&mut Option<(Tensor, Tensor)>>,
        mask: Option<&Tensor>,
    ) -> Result<Tensor> {
        let q = split_heads(&self.query.forward(x)?, self.heads)?;
        let (mut k, mut v) = self.keys_values(x)?;
        if let Some(cache) = cache {
            if let Some((past_k, past_v)) = cache.as_ref() {
                k = Tensor::cat(&[past_k, &k], 2)?;
                v = Tensor::cat(&[past_v, &v], 2)?;
            }
            *cache = Some((k.clone(), v.clone()));
        }
        self.out.forward(&attend(&q, &k, &v, mask)?)
    }

    fn cross_attend(&self, x: &Tensor, kv: &(Tensor, Tensor)) -> Result<Tensor> {
        let q = split_heads(&self.query.forward(x)?, self.heads)?;
        self.out.forward(&attend(&q, &kv.0, &kv.1, None)?)
    }
}

struct Block {
    attn: Attention,
    attn_ln: LayerNorm,
    cross: Option<(Attention, LayerNorm)>,
    fc1: Linear,
    fc2: Linear,
    mlp_ln: LayerNorm,
}

impl Block {
    fn load(d: usize, heads: usize, cross: bool, vb: VarBuilder) -> Result<Self> {
        let cross = if cross {
            Some((Attention::load(d, heads, vb.pp("encoder_attn"))?, layer_norm(d, vb.pp("encoder_attn_layer_norm"))?))
        } else {
            None
        };
        Ok(Self {
            attn: Attention::load(d, heads, vb.pp("self_attn"))?,
            attn_ln: layer_norm(d, vb.pp("self_attn_layer_norm"))?,
            cross,
            fc1: linear(d, 4 * d, vb.pp("fc1"))?,
            fc2: linear(4 * d, d, vb.pp("fc2"))?,
            mlp_ln: layer_norm(d, vb.pp("final_layer_norm"))?,
        })
    }

    fn mlp(&self, x: &Tensor) -> Result<Tensor> {
        x + self.fc2.forward(&self.fc1.forward(&self.mlp_ln.forward(x)?)?.gelu_erf()?)?
    }
}

/// Sinusoidal position table of the audio encoder ([length, channels]).
fn sinusoids(length: usize, channels: usize, device: &Device) -> Result<Tensor> {
    let half = channels / 2;
    let increment = (10_000f64).ln() / (half as f64 - 1.0);
    let inv: Vec<f32> = (0..half).map(|i| (-(increment * i as f64)).exp() as f32).collect();
    let inv = Tensor::from_vec(inv, (1, half), device)?;
    let t = Tensor::arange(0u32, length as u32, device)?.to_dtype(DType::F32)?.reshape((length, 1))?;
    let scaled = t.broadcast_mul(&inv)?;
    Tensor::cat(&[scaled.sin()?, scaled.cos()?], 1)
}

/// The audio encoder: two convolutions, positions, transformer blocks.
pub struct Encoder {
    conv1: Conv1d,
    conv2: Conv1d,
    positions: Tensor,
    blocks: Vec<Block>,
    ln_post: LayerNorm,
}

impl Encoder {
    fn load(cfg: &WhisperConfig, vb: VarBuilder) -> Result<Self> {
        let d = cfg.d_model;
        let conv = |cin: usize, stride: usize, vb: VarBuilder| -> Result<Conv1d> {
            let config = Conv1dConfig { padding: 1, stride, groups: 1, dilation: 1, cudnn_fwd_algo: None };
            Ok(Conv1d::new(vb.get((d, cin, 3), "weight")?, Some(vb.get(d, "bias")?), config))
        };
        Ok(Self {
            conv1: conv(cfg.num_mel_bins, 1, vb.pp("conv1"))?,
            conv2: conv(d, 2, vb.pp("conv2"))?,
            positions: sinusoids(cfg.max_source_positions, d, vb.device())?.to_dtype(vb.dtype())?,
            blocks: (0..cfg.encoder_layers)
                .map(|i| Block::load(d, cfg.encoder_attention_heads, false, vb.pp(format!("layers.{i}"))))
                .collect::<Result<_>>()?,
            ln_post: layer_norm(d, vb.pp("layer_norm"))?,
        })
    }

    /// Log-mel features [1, n_mels, frames] → audio states [1, frames / 2, d].
    pub fn forward(&self, mel: &Tensor) -> Result<Tensor> {
        let x = self.conv1.forward(mel)?.gelu_erf()?;
        let x = self.conv2.forward(&x)?.gelu_erf()?.transpose(1, 2)?;
        let frames = x.dim(1)?;
        let mut x = x.broadcast_add(&self.positions.narrow(0, 0, frames)?)?;
        for block in &self.blocks {
            x = (&x + block.attn.self_attend(&block.attn_ln.forward(&x)?, None, None)?)?;
            x = block.mlp(&x)?;
        }
        self.ln_post.forward(&x)
    }
}

/// Decoding state of one audio window: per-layer self-attention cache and
/// the cross-attention keys/values of the audio.
#[derive(Clone)]
pub struct DecoderState {
    self_kv: Vec<Option<(Tensor, Tensor)>>,
    cross_kv: Vec<(Tensor, Tensor)>,
    /// Tokens already fed.
    pub position: usize,
}

/// The text decoder.
pub struct Decoder {
    embedding: Tensor,
    positions: Tensor,
    blocks: Vec<Block>,
    ln: LayerNorm,
    max_positions: usize,
}

impl Decoder {
    fn load(cfg: &WhisperConfig, vb: VarBuilder) -> Result<Self> {
        let d = cfg.d_model;
        Ok(Self {
            embedding: vb.get((cfg.vocab_size, d), "embed_tokens.weight")?,
            positions: vb.get((cfg.max_target_positions, d), "embed_positions.weight")?,
            blocks: (0..cfg.decoder_layers)
                .map(|i| Block::load(d, cfg.decoder_attention_heads, true, vb.pp(format!("layers.{i}"))))
                .collect::<Result<_>>()?,
            ln: layer_norm(d, vb.pp("layer_norm"))?,
            max_positions: cfg.max_target_positions,
        })
    }

    /// A fresh state for decoding against `audio` (the encoder's output).
    pub fn start(&self, audio: &Tensor) -> Result<DecoderState> {
        let cross_kv = self
            .blocks
            .iter()
            .map(|b| b.cross.as_ref().expect("decoder blocks have cross-attention").0.keys_values(audio))
            .collect::<Result<_>>()?;
        Ok(DecoderState { self_kv: vec![None; self.blocks.len()], cross_kv, position: 0 })
    }

    /// Feeds `tokens` after those already in `state`; returns their hidden
    /// states [1, tokens, d].
    pub fn forward(&self, tokens: &[u32], state: &mut DecoderState) -> Result<Tensor> {
        let n = tokens.len();
        let past = state.position;
        if past + n > self.max_positions {
            candle_core::bail!("the decoder holds at most {} tokens", self.max_positions);
        }
        let device = self.embedding.device();
        let ids = Tensor::new(tokens, device)?;
        let mut x =
            self.embedding.index_select(&ids, 0)?.broadcast_add(&self.positions.narrow(0, past, n)?)?.unsqueeze(0)?;
        // New position i may see cached positions and new ones up to itself.
        let mask = if n > 1 {
            let m: Vec<f32> = (0..n)
                .flat_map(|i| (0..past + n).map(move |j| if j > past + i { f32::NEG_INFINITY } else { 0.0 }))
                .collect();
            Some(Tensor::from_vec(m, (n, past + n), device)?.to_dtype(x.dtype())?)
        } else {
            None
        };
        for (i, block) in self.blocks.iter().enumerate() {
            let attn =
                block.attn.self_attend(&block.attn_ln.forward(&x)?, Some(&mut state.self_kv[i]), mask.as_ref())?;
            x = (&x + attn)?;
            let (cross, cross_ln) = block.cross.as_ref().expect("decoder blocks have cross-attention");
            x = (&x + cross.cross_attend(&cross_ln.forward(&x)?, &state.cross_kv[i])?)?;
            x = block.mlp(&x)?;
        }
        state.position += n;
        self.ln.forward(&x)
    }

    /// Vocabulary logits of hidden state `index` of `hidden` ([1, t, d]), as f32.
    pub fn logits(&self, hidden: &Tensor, index: usize) -> Result<Tensor> {
        hidden.i((0, index..index + 1))?.matmul(&self.embedding.t()?)?.i(0)?.to_dtype(DType::F32)
    }
}

/// Encoder and decoder of one Whisper model.
pub struct Network {
    pub encoder: Encoder,
    pub decoder: Decoder,
}

impl Network {
    /// Loads from candle's Whisper names (`model.encoder.*`, `model.decoder.*`).
    pub fn load(cfg: &WhisperConfig, vb: VarBuilder) -> Result<Self> {
        Ok(Self {
            encoder: Encoder::load(cfg, vb.pp("model.encoder"))?,
            decoder: Decoder::load(cfg, vb.pp("model.decoder"))?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tiny() -> (WhisperConfig, Network) {
        let cfg = WhisperConfig {
            num_mel_bins: 4,
            max_source_positions: 8,
            d_model: 8,
            encoder_attention_heads: 2,
            encoder_layers: 1,
            vocab_size: 11,
            max_target_positions: 6,
            decoder_attention_heads: 2,
            decoder_layers: 2,
            suppress_tokens: vec![],
            begin_suppress_tokens: vec![],
        };
        // Create every variable, give each random values, then load again.
        let vm = candle_nn::VarMap::new();
        Network::load(&cfg, VarBuilder::from_varmap(&vm, DType::F32, &Device::Cpu)).unwrap();
        for var in vm.data().lock().unwrap().values() {
            var.set(&Tensor::randn(0f32, 0.5, var.shape(), &Device::Cpu).unwrap()).unwrap();
        }
        let net = Network::load(&cfg, VarBuilder::from_varmap(&vm, DType::F32, &Device::Cpu)).unwrap();
        (cfg, net)
    }

    #[test]
    fn cached_decoding_equals_decoding_the_whole_prefix() {
        let (cfg, net) = tiny();
        let mel = Tensor::randn(0f32, 1.0, (1, cfg.num_mel_bins, 16), &Device::Cpu).unwrap();
        let audio = net.encoder.forward(&mel).unwrap();
        assert_eq!(audio.dims(), &[1, 8, 8]);
        let tokens = [3u32, 7, 1, 9];

        let mut whole = net.decoder.start(&audio).unwrap();
        let all = net.decoder.forward(&tokens, &mut whole).unwrap();

        let mut stepwise = net.decoder.start(&audio).unwrap();
        let first = net.decoder.forward(&tokens[..2], &mut stepwise).unwrap();
        let mut rows = vec![first.i((0, 0)).unwrap(), first.i((0, 1)).unwrap()];
        for t in &tokens[2..] {
            rows.push(net.decoder.forward(&[*t], &mut stepwise).unwrap().i((0, 0)).unwrap());
        }
        let stepped = Tensor::stack(&rows, 0).unwrap();
        let diff = (all.i(0).unwrap() - stepped).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap();
        assert!(diff < 1e-4, "cached and full decoding differ by {diff}");
        assert_eq!(net.decoder.logits(&all, 3).unwrap().dims(), &[cfg.vocab_size]);
        assert!(net.decoder.forward(&[1, 2, 3], &mut stepwise).is_err(), "past the context length");
    }
}
