//! OSNet (Zhou et al., "Omni-Scale Feature Learning for Person
//! Re-Identification", ICCV 2019) as torchreid builds it (`osnet_x1_0`,
//! `osnet_x0_25`), loading a torchreid state dict converted to safetensors
//! (names such as `conv2.0.conv2a.conv1.weight`, `fc.1.running_var`; a
//! `module.` prefix from DataParallel is stripped by the converter; the
//! identity `classifier.*` is ignored). The embedding is the output of the
//! `fc` block (Linear 512 + BatchNorm1d + ReLU) in eval mode, as torchreid's
//! `FeatureExtractor` returns it.

use candle_core::{Module, Result, Tensor};
use candle_nn::{Linear, VarBuilder};

use crate::nn::{Conv, Depthwise, conv, conv_bn, conv1x1_bias, depthwise_bn, global_avg_pool, linear_bn};

/// Embedding size of every torchreid OSNet (`feature_dim=512`).
pub const EMBEDDING_DIM: usize = 512;
/// torchreid's default input: 256 high × 128 wide.
pub const INPUT_HEIGHT: usize = 256;
pub const INPUT_WIDTH: usize = 128;

/// The width variants torchreid defines that this crate serves.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OsnetVariant {
    X1_0,
    X0_25,
}

impl OsnetVariant {
    /// Channels of conv1 and of the three OS stages (`channels` in torchreid).
    pub fn channels(self) -> [usize; 4] {
        match self {
            OsnetVariant::X1_0 => [64, 256, 384, 512],
            OsnetVariant::X0_25 => [16, 64, 96, 128],
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            OsnetVariant::X1_0 => "osnet_x1_0",
            OsnetVariant::X0_25 => "osnet_x0_25",
        }
    }
}

/// Conv + folded BN + ReLU (torchreid `ConvLayer`, `Conv1x1`; with `relu`
/// false, `Conv1x1Linear`). Weights under `conv`, `bn`.
struct ConvBn {
    conv: Conv,
    relu: bool,
}

impl ConvBn {
    fn load(cin: usize, cout: usize, k: usize, stride: usize, pad: usize, relu: bool, vb: VarBuilder) -> Result<Self> {
        Ok(Self { conv: conv_bn(cin, cout, k, stride, pad, 1, vb.pp("conv"), vb.pp("bn"))?, relu })
    }
}

impl Module for ConvBn {
    fn forward(&self, x: &Tensor) -> Result<Tensor> {
        let y = self.conv.forward(x)?;
        if self.relu { y.relu() } else { Ok(y) }
    }
}

/// torchreid `LightConv3x3`: 1×1 linear conv, depthwise 3×3, BN, ReLU.
struct LightConv3x3 {
    pointwise: Conv,
    depthwise_bn: Depthwise,
}

impl LightConv3x3 {
    fn load(c: usize, vb: VarBuilder) -> Result<Self> {
        Ok(Self {
            pointwise: conv(c, c, 1, 1, 0, 1, vb.pp("conv1"))?,
            depthwise_bn: depthwise_bn(c, 3, 1, 1, vb.pp("conv2"), vb.pp("bn"))?,
        })
    }
}

impl Module for LightConv3x3 {
    fn forward(&self, x: &Tensor) -> Result<Tensor> {
        self.depthwise_bn.forward(&self.pointwise.forward(x)?)?.relu()
    }
}

/// torchreid `ChannelGate` (sigmoid, reduction 16), shared by the four streams.
struct ChannelGate {
    fc1: Conv,
    fc2: Conv,
}

impl ChannelGate {
    fn load(c: usize, vb: VarBuilder) -> Result<Self> {
        let hidden = c / 16;
        Ok(Self { fc1: conv1x1_bias(c, hidden, vb.pp("fc1"))?, fc2: conv1x1_bias(hidden, c, vb.pp("fc2"))? })
    }
}

impl Module for ChannelGate {
    fn forward(&self, x: &Tensor) -> Result<Tensor> {
        let (n, c, _, _) = x.dims4()?;
        let g = global_avg_pool(x)?.reshape((n, c, 1, 1))?;
        let g = candle_nn::ops::sigmoid(&self.fc2.forward(&self.fc1.forward(&g)?.relu()?)?)?;
        x.broadcast_mul(&g)
    }
}

/// torchreid `OSBlock`: four streams of 1–4 lite 3×3 convs, unified
/// aggregation gate, 1×1 linear projection, residual.
struct OsBlock {
    conv1: ConvBn,
    streams: [Vec<LightConv3x3>; 4],
    gate: ChannelGate,
    conv3: ConvBn,
    downsample: Option<ConvBn>,
}

impl OsBlock {
    fn load(cin: usize, cout: usize, vb: VarBuilder) -> Result<Self> {
        let mid = cout / 4;
        let stream = |name: &str, depth: usize| -> Result<Vec<LightConv3x3>> {
            if depth == 1 {
                Ok(vec![LightConv3x3::load(mid, vb.pp(name))?])
            } else {
                (0..depth).map(|i| LightConv3x3::load(mid, vb.pp(name).pp(i))).collect()
            }
        };
        Ok(Self {
            conv1: ConvBn::load(cin, mid, 1, 1, 0, true, vb.pp("conv1"))?,
            streams: [stream("conv2a", 1)?, stream("conv2b", 2)?, stream("conv2c", 3)?, stream("conv2d", 4)?],
            gate: ChannelGate::load(mid, vb.pp("gate"))?,
            conv3: ConvBn::load(mid, cout, 1, 1, 0, false, vb.pp("conv3"))?,
            downsample: if cin != cout {
                Some(ConvBn::load(cin, cout, 1, 1, 0, false, vb.pp("downsample"))?)
            } else {
                None
            },
        })
    }
}

impl Module for OsBlock {
    fn forward(&self, x: &Tensor) -> Result<Tensor> {
        let x1 = self.conv1.forward(x)?;
        let mut sum: Option<Tensor> = None;
        for stream in &self.streams {
            let y = stream.iter().try_fold(x1.clone(), |y, l| l.forward(&y))?;
            let g = self.gate.forward(&y)?;
            sum = Some(match sum {
                None => g,
                Some(s) => (s + g)?,
            });
        }
        let x3 = self.conv3.forward(&sum.expect("four streams"))?;
        let identity = match &self.downsample {
            Some(d) => d.forward(x)?,
            None => x.clone(),
        };
        (x3 + identity)?.relu()
    }
}

/// One torchreid stage: two OS blocks, optionally a 1×1 conv + 2×2 average pool.
struct OsStage {
    blocks: Vec<OsBlock>,
    transition: Option<ConvBn>,
}

impl OsStage {
    fn load(cin: usize, cout: usize, reduce: bool, vb: VarBuilder) -> Result<Self> {
        let blocks = vec![OsBlock::load(cin, cout, vb.pp(0))?, OsBlock::load(cout, cout, vb.pp(1))?];
        let transition = if reduce { Some(ConvBn::load(cout, cout, 1, 1, 0, true, vb.pp("2.0"))?) } else { None };
        Ok(Self { blocks, transition })
    }
}

impl Module for OsStage {
    fn forward(&self, x: &Tensor) -> Result<Tensor> {
        let mut y = x.clone();
        for b in &self.blocks {
            y = b.forward(&y)?;
        }
        match &self.transition {
            Some(t) => t.forward(&y)?.avg_pool2d(2),
            None => Ok(y),
        }
    }
}

/// An OSNet feature extractor.
pub struct Osnet {
    variant: OsnetVariant,
    conv1: ConvBn,
    stages: [OsStage; 3],
    conv5: ConvBn,
    fc: Linear,
}

impl Osnet {
    pub fn load(variant: OsnetVariant, vb: VarBuilder) -> Result<Self> {
        let [c0, c1, c2, c3] = variant.channels();
        Ok(Self {
            variant,
            conv1: ConvBn::load(3, c0, 7, 2, 3, true, vb.pp("conv1"))?,
            stages: [
                OsStage::load(c0, c1, true, vb.pp("conv2"))?,
                OsStage::load(c1, c2, true, vb.pp("conv3"))?,
                OsStage::load(c2, c3, false, vb.pp("conv4"))?,
            ],
            conv5: ConvBn::load(c3, c3, 1, 1, 0, true, vb.pp("conv5"))?,
            fc: linear_bn(c3, EMBEDDING_DIM, vb.pp("fc.0"), vb.pp("fc.1"))?,
        })
    }

    pub fn variant(&self) -> OsnetVariant {
        self.variant
    }
}

impl Module for Osnet {
    /// (N, 3, 256, 128) normalised RGB → (N, 512) un-normalised features.
    fn forward(&self, x: &Tensor) -> Result<Tensor> {
        let x = self.conv1.forward(x)?;
        // 3×3/2 max pool with padding 1: after the ReLU every value is ≥ 0, so
        // zero padding gives the same maximum as PyTorch's −∞ padding.
        let x = x.pad_with_zeros(2, 1, 1)?.pad_with_zeros(3, 1, 1)?.max_pool2d_with_stride(3, 2)?;
        let x = self.stages.iter().try_fold(x, |x, s| s.forward(&x))?;
        let v = global_avg_pool(&self.conv5.forward(&x)?)?;
        self.fc.forward(&v)?.relu()
    }
}

/// Every tensor of a torchreid OSNet state dict with its shape, in the order
/// PyTorch's `state_dict()` lists them (classifier for `num_classes` identities
/// included). Used to write test weights and to check user checkpoints.
pub fn torchreid_state_dict_shapes(variant: OsnetVariant, num_classes: usize) -> Vec<(String, Vec<usize>)> {
    let mut out = Vec::new();
    let bn = |out: &mut Vec<(String, Vec<usize>)>, p: &str, c: usize| {
        for n in ["weight", "bias", "running_mean", "running_var"] {
            out.push((format!("{p}.{n}"), vec![c]));
        }
        out.push((format!("{p}.num_batches_tracked"), vec![]));
    };
    let conv_layer = |out: &mut Vec<(String, Vec<usize>)>, p: &str, cin: usize, cout: usize, k: usize| {
        out.push((format!("{p}.conv.weight"), vec![cout, cin, k, k]));
        bn(out, &format!("{p}.bn"), cout);
    };
    let light = |out: &mut Vec<(String, Vec<usize>)>, p: &str, c: usize| {
        out.push((format!("{p}.conv1.weight"), vec![c, c, 1, 1]));
        out.push((format!("{p}.conv2.weight"), vec![c, 1, 3, 3]));
        bn(out, &format!("{p}.bn"), c);
    };
    let block = |out: &mut Vec<(String, Vec<usize>)>, p: &str, cin: usize, cout: usize| {
        let mid = cout / 4;
        conv_layer(out, &format!("{p}.conv1"), cin, mid, 1);
        light(out, &format!("{p}.conv2a"), mid);
        for (name, depth) in [("conv2b", 2), ("conv2c", 3), ("conv2d", 4)] {
            for i in 0..depth {
                light(out, &format!("{p}.{name}.{i}"), mid);
            }
        }
        out.push((format!("{p}.gate.fc1.weight"), vec![mid / 16, mid, 1, 1]));
        out.push((format!("{p}.gate.fc1.bias"), vec![mid / 16]));
        out.push((format!("{p}.gate.fc2.weight"), vec![mid, mid / 16, 1, 1]));
        out.push((format!("{p}.gate.fc2.bias"), vec![mid]));
        conv_layer(out, &format!("{p}.conv3"), mid, cout, 1);
        if cin != cout {
            conv_layer(out, &format!("{p}.downsample"), cin, cout, 1);
        }
    };
    let [c0, c1, c2, c3] = variant.channels();
    conv_layer(&mut out, "conv1", 3, c0, 7);
    for (stage, cin, cout, reduce) in [("conv2", c0, c1, true), ("conv3", c1, c2, true), ("conv4", c2, c3, false)] {
        block(&mut out, &format!("{stage}.0"), cin, cout);
        block(&mut out, &format!("{stage}.1"), cout, cout);
        if reduce {
            conv_layer(&mut out, &format!("{stage}.2.0"), cout, cout, 1);
        }
    }
    conv_layer(&mut out, "conv5", c3, c3, 1);
    out.push(("fc.0.weight".into(), vec![EMBEDDING_DIM, c3]));
    out.push(("fc.0.bias".into(), vec![EMBEDDING_DIM]));
    bn(&mut out, "fc.1", EMBEDDING_DIM);
    out.push(("classifier.weight".into(), vec![num_classes, EMBEDDING_DIM]));
    out.push(("classifier.bias".into(), vec![num_classes]));
    out
}

/// A complete torchreid-format OSNet state dict filled with deterministic
/// pseudo-random values (He-scaled convolutions, batch norms near identity).
/// No trained OSNet weights ship in any package: this exercises the loading
/// path and the forward pass in tests and benchmarks, never serving.
pub fn random_state_dict(
    variant: OsnetVariant,
    num_classes: usize,
    seed: u64,
    device: &candle_core::Device,
) -> Result<std::collections::HashMap<String, Tensor>> {
    // splitmix64: small, dependency-free, reproducible.
    let mut state = seed;
    let mut next = move || {
        state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f32 / (1u64 << 53) as f32 * 2.0 - 1.0
    };
    let mut out = std::collections::HashMap::new();
    for (name, shape) in torchreid_state_dict_shapes(variant, num_classes) {
        let numel: usize = shape.iter().product();
        let t = if name.ends_with("num_batches_tracked") {
            Tensor::new(1000i64, device)?
        } else {
            let values: Vec<f32> = if name.ends_with("running_var") {
                (0..numel).map(|_| 1.0 + 0.2 * next()).collect()
            } else if name.ends_with("running_mean") || name.ends_with(".bias") {
                (0..numel).map(|_| 0.05 * next()).collect()
            } else if shape.len() == 1 {
                (0..numel).map(|_| 1.0 + 0.1 * next()).collect()
            } else {
                // Uniform with He variance 2/fan_in: U(−a, a), a = √(6/fan_in).
                let fan_in: usize = shape[1..].iter().product();
                let a = (6.0 / fan_in as f32).sqrt();
                (0..numel).map(|_| a * next()).collect()
            };
            Tensor::from_vec(values, shape.as_slice(), device)?
        };
        out.insert(name, t);
    }
    Ok(out)
}
