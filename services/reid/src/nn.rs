//! Layers shared by the ReID networks: convolutions with their batch norm
//! folded in at load time (inference only, so `y = γ(x−μ)/σ + β` becomes a
//! per-channel scale of the weights and a bias), and linear + BatchNorm1d.

use candle_core::{D, Module, Result, Tensor};
use candle_nn::{Conv2d, Conv2dConfig, Linear, VarBuilder};

/// PyTorch's BatchNorm default epsilon (both torchreid and DeepSORT use it).
pub const BN_EPS: f64 = 1e-5;

/// Per-channel (scale, shift) of an inference-mode batch norm stored under
/// `vb` as `weight`, `bias`, `running_mean`, `running_var`.
fn bn_scale_shift(channels: usize, vb: &VarBuilder) -> Result<(Tensor, Tensor)> {
    let gamma = vb.get(channels, "weight")?;
    let beta = vb.get(channels, "bias")?;
    let mean = vb.get(channels, "running_mean")?;
    let var = vb.get(channels, "running_var")?;
    let scale = gamma.broadcast_div(&(var + BN_EPS)?.sqrt()?)?;
    let shift = (beta - mean.mul(&scale)?)?;
    Ok((scale, shift))
}

/// A convolution as the networks use it: 1×1 stride-1 convolutions run as
/// one matrix product over all pixels (no im2col copies), others through candle.
pub enum Conv {
    Pointwise { weight: Tensor, bias: Option<Tensor> },
    General(Conv2d),
}

impl Conv {
    fn new(weight: Tensor, bias: Option<Tensor>, cfg: Conv2dConfig) -> Result<Self> {
        let (cout, cin, kh, kw) = weight.dims4()?;
        if kh == 1 && kw == 1 && cfg.stride == 1 && cfg.padding == 0 && cfg.groups == 1 {
            let bias = bias.map(|b| b.reshape((1, cout, 1))).transpose()?;
            Ok(Conv::Pointwise { weight: weight.reshape((cout, cin))?.contiguous()?, bias })
        } else {
            Ok(Conv::General(Conv2d::new(weight, bias, cfg)))
        }
    }

    /// Weight in Conv2d layout (C_out, C_in/groups, k, k) and bias.
    fn parts(&self) -> Result<(Tensor, Option<Tensor>)> {
        match self {
            Conv::Pointwise { weight, bias } => {
                let (cout, cin) = weight.dims2()?;
                Ok((weight.reshape((cout, cin, 1, 1))?, bias.as_ref().map(|b| b.flatten_all()).transpose()?))
            }
            Conv::General(c) => Ok((c.weight().clone(), c.bias().cloned())),
        }
    }
}

impl Module for Conv {
    fn forward(&self, x: &Tensor) -> Result<Tensor> {
        match self {
            Conv::Pointwise { weight, bias } => {
                let (n, c, h, w) = x.dims4()?;
                let y = weight.broadcast_matmul(&x.reshape((n, c, h * w))?)?;
                let y = match bias {
                    Some(b) => y.broadcast_add(b)?,
                    None => y,
                };
                y.reshape((n, weight.dim(0)?, h, w))
            }
            Conv::General(c) => c.forward(x),
        }
    }
}

/// A bias-free `nn.Conv2d` (weights under `conv`) followed by `nn.BatchNorm2d`
/// (under `bn`), folded into one convolution with bias.
#[allow(clippy::too_many_arguments)]
pub fn conv_bn(
    in_channels: usize,
    out_channels: usize,
    kernel: usize,
    stride: usize,
    padding: usize,
    groups: usize,
    conv: VarBuilder,
    bn: VarBuilder,
) -> Result<Conv> {
    let w = conv.get((out_channels, in_channels / groups, kernel, kernel), "weight")?;
    let (scale, shift) = bn_scale_shift(out_channels, &bn)?;
    let w = w.broadcast_mul(&scale.reshape((out_channels, 1, 1, 1))?)?;
    let cfg = Conv2dConfig { padding, stride, dilation: 1, groups, cudnn_fwd_algo: None };
    Conv::new(w, Some(shift), cfg)
}

/// A depthwise convolution (one k×k filter per channel) with bias. candle
/// runs a grouped convolution as one small convolution per group, which makes
/// depthwise layers (groups = channels) the bulk of MobileNetV2's and OSNet's
/// CPU time; on the CPU this runs a direct kernel instead, elsewhere candle's.
pub struct Depthwise {
    weight: Tensor,
    bias: Tensor,
    stride: usize,
    padding: usize,
    kernel: usize,
}

impl Depthwise {
    /// From a grouped Conv2d whose groups equal its channels.
    pub fn new(weight: Tensor, bias: Tensor, stride: usize, padding: usize) -> Result<Self> {
        let (_, one, k, k2) = weight.dims4()?;
        if one != 1 || k != k2 {
            candle_core::bail!("depthwise weights must be (C, 1, k, k), got {:?}", weight.dims());
        }
        Ok(Self { weight: weight.contiguous()?, bias: bias.contiguous()?, stride, padding, kernel: k })
    }
}

impl Module for Depthwise {
    fn forward(&self, x: &Tensor) -> Result<Tensor> {
        if x.device().is_cpu() && x.dtype() == candle_core::DType::F32 {
            let op = DepthwiseCpu { stride: self.stride, padding: self.padding, kernel: self.kernel };
            x.contiguous()?.apply_op3_no_bwd(&self.weight, &self.bias, &op)
        } else {
            let channels = self.weight.dim(0)?;
            let cfg = Conv2dConfig {
                padding: self.padding,
                stride: self.stride,
                dilation: 1,
                groups: channels,
                cudnn_fwd_algo: None,
            };
            Conv2d::new(self.weight.clone(), Some(self.bias.clone()), cfg).forward(x)
        }
    }
}

struct DepthwiseCpu {
    stride: usize,
    padding: usize,
    kernel: usize,
}

fn f32_slice<'a>(s: &'a candle_core::CpuStorage, l: &candle_core::Layout, what: &str) -> Result<&'a [f32]> {
    let candle_core::CpuStorage::F32(v) = s else { candle_core::bail!("depthwise {what}: f32 expected") };
    let Some((start, end)) = l.contiguous_offsets() else {
        candle_core::bail!("depthwise {what}: contiguous expected")
    };
    Ok(&v[start..end])
}

impl candle_core::CustomOp3 for DepthwiseCpu {
    fn name(&self) -> &'static str {
        "depthwise-conv2d"
    }

    fn cpu_fwd(
        &self,
        s1: &candle_core::CpuStorage,
        l1: &candle_core::Layout,
        s2: &candle_core::CpuStorage,
        l2: &candle_core::Layout,
        s3: &candle_core::CpuStorage,
        l3: &candle_core::Layout,
    ) -> Result<(candle_core::CpuStorage, candle_core::Shape)> {
        let (x, w, b) = (f32_slice(s1, l1, "input")?, f32_slice(s2, l2, "weight")?, f32_slice(s3, l3, "bias")?);
        let (n, c, h, wd) = l1.shape().dims4()?;
        let (k, s, p) = (self.kernel, self.stride, self.padding);
        if w.len() != c * k * k || b.len() != c {
            candle_core::bail!("depthwise: {c} channels but {} weights and {} biases", w.len(), b.len());
        }
        if h + 2 * p < k || wd + 2 * p < k {
            candle_core::bail!("depthwise: {h}×{wd} input is smaller than the {k}×{k} kernel");
        }
        let (ho, wo) = ((h + 2 * p - k) / s + 1, (wd + 2 * p - k) / s + 1);
        let mut out = vec![0f32; n * c * ho * wo];
        // Output columns ox whose input column ox·s + kx − p lies inside the row.
        let col_range = |kx: usize| {
            let lo = p.saturating_sub(kx).div_ceil(s);
            let hi = if wd + p > kx { ((wd + p - kx - 1) / s + 1).min(wo) } else { 0 };
            (lo, hi.max(lo))
        };
        let cols: Vec<(usize, usize)> = (0..k).map(col_range).collect();
        for (plane, o) in out.chunks_exact_mut(ho * wo).enumerate() {
            let ch = plane % c;
            let input = &x[plane * h * wd..(plane + 1) * h * wd];
            let filt = &w[ch * k * k..(ch + 1) * k * k];
            o.fill(b[ch]);
            for oy in 0..ho {
                let orow = &mut o[oy * wo..(oy + 1) * wo];
                for ky in 0..k {
                    let iy = (oy * s + ky) as isize - p as isize;
                    if iy < 0 || iy >= h as isize {
                        continue;
                    }
                    let irow = &input[iy as usize * wd..(iy as usize + 1) * wd];
                    for (kx, &(lo, hi)) in cols.iter().enumerate() {
                        let wv = filt[ky * k + kx];
                        let first = lo * s + kx - p;
                        if s == 1 {
                            for (ov, iv) in orow[lo..hi].iter_mut().zip(&irow[first..first + (hi - lo)]) {
                                *ov += wv * iv;
                            }
                        } else {
                            for (j, ov) in orow[lo..hi].iter_mut().enumerate() {
                                *ov += wv * irow[first + j * s];
                            }
                        }
                    }
                }
            }
        }
        Ok((candle_core::CpuStorage::F32(out), candle_core::Shape::from((n, c, ho, wo))))
    }
}

/// `conv_bn` for a depthwise convolution, run by [`Depthwise`].
pub fn depthwise_bn(
    channels: usize,
    kernel: usize,
    stride: usize,
    padding: usize,
    conv: VarBuilder,
    bn: VarBuilder,
) -> Result<Depthwise> {
    let (weight, bias) = conv_bn(channels, channels, kernel, stride, padding, channels, conv, bn)?.parts()?;
    Depthwise::new(weight, bias.expect("folded convolutions have a bias"), stride, padding)
}

/// A plain bias-free convolution (no batch norm after it).
pub fn conv(
    in_channels: usize,
    out_channels: usize,
    kernel: usize,
    stride: usize,
    padding: usize,
    groups: usize,
    vb: VarBuilder,
) -> Result<Conv> {
    let w = vb.get((out_channels, in_channels / groups, kernel, kernel), "weight")?;
    let cfg = Conv2dConfig { padding, stride, dilation: 1, groups, cudnn_fwd_algo: None };
    Conv::new(w, None, cfg)
}

/// A 1×1 convolution with bias (squeeze-excitation style gates).
pub fn conv1x1_bias(in_channels: usize, out_channels: usize, vb: VarBuilder) -> Result<Conv> {
    let w = vb.get((out_channels, in_channels, 1, 1), "weight")?;
    let b = vb.get(out_channels, "bias")?;
    Conv::new(w, Some(b), Conv2dConfig::default())
}

/// `nn.Linear` (under `linear`) followed by `nn.BatchNorm1d` (under `bn`), folded.
pub fn linear_bn(in_dim: usize, out_dim: usize, linear: VarBuilder, bn: VarBuilder) -> Result<Linear> {
    let w = linear.get((out_dim, in_dim), "weight")?;
    let b = linear.get(out_dim, "bias")?;
    let (scale, shift) = bn_scale_shift(out_dim, &bn)?;
    let w = w.broadcast_mul(&scale.reshape((out_dim, 1))?)?;
    let b = (b.mul(&scale)? + shift)?;
    Ok(Linear::new(w, Some(b)))
}

/// Global average pooling: (N, C, H, W) → (N, C).
pub fn global_avg_pool(x: &Tensor) -> Result<Tensor> {
    x.mean(D::Minus1)?.mean(D::Minus1)
}

/// Row-wise L2 normalisation of (N, D) embeddings.
pub fn l2_normalize(x: &Tensor) -> Result<Tensor> {
    let norm = x.sqr()?.sum_keepdim(D::Minus1)?.sqrt()?.clamp(1e-12f32, f32::MAX)?;
    x.broadcast_div(&norm)
}

/// Applies a list of layers in order.
pub fn sequential<M: Module>(layers: &[M], x: &Tensor) -> Result<Tensor> {
    layers.iter().try_fold(x.clone(), |x, l| l.forward(&x))
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{DType, Device};
    use candle_nn::{BatchNorm, ModuleT};
    use std::collections::HashMap;

    #[test]
    fn folded_conv_bn_equals_conv_then_batch_norm() -> Result<()> {
        let dev = Device::Cpu;
        let mut t = HashMap::new();
        t.insert("conv.weight".to_string(), Tensor::randn(0f32, 1.0, (4, 3, 3, 3), &dev)?);
        t.insert("bn.weight".to_string(), Tensor::new(&[1.5f32, 0.5, -1.0, 2.0], &dev)?);
        t.insert("bn.bias".to_string(), Tensor::new(&[0.1f32, -0.2, 0.3, 0.0], &dev)?);
        t.insert("bn.running_mean".to_string(), Tensor::new(&[0.5f32, -1.0, 0.0, 2.0], &dev)?);
        t.insert("bn.running_var".to_string(), Tensor::new(&[0.25f32, 4.0, 1.0, 0.5], &dev)?);
        let vb = VarBuilder::from_tensors(t.clone(), DType::F32, &dev);
        let folded = conv_bn(3, 4, 3, 2, 1, 1, vb.pp("conv"), vb.pp("bn"))?;
        let x = Tensor::randn(0f32, 1.0, (2, 3, 9, 7), &dev)?;
        let plain = Conv2d::new(
            t["conv.weight"].clone(),
            None,
            Conv2dConfig { padding: 1, stride: 2, dilation: 1, groups: 1, cudnn_fwd_algo: None },
        );
        let bn = BatchNorm::new(
            4,
            t["bn.running_mean"].clone(),
            t["bn.running_var"].clone(),
            t["bn.weight"].clone(),
            t["bn.bias"].clone(),
            BN_EPS,
        )?;
        let want = bn.forward_t(&plain.forward(&x)?, false)?;
        let got = folded.forward(&x)?;
        let err = (want - got)?.abs()?.flatten_all()?.max(0)?.to_scalar::<f32>()?;
        assert!(err < 1e-4, "max abs error {err}");
        Ok(())
    }

    #[test]
    fn the_depthwise_kernel_matches_candles_grouped_convolution() -> Result<()> {
        let dev = Device::Cpu;
        for (k, stride, padding, h, w) in
            [(3, 1, 1, 9, 7), (3, 2, 1, 9, 7), (3, 2, 1, 8, 8), (5, 2, 2, 11, 6), (3, 1, 0, 4, 5)]
        {
            let c = 6;
            let weight = Tensor::randn(0f32, 1.0, (c, 1, k, k), &dev)?;
            let bias = Tensor::randn(0f32, 1.0, c, &dev)?;
            let x = Tensor::randn(0f32, 1.0, (2, c, h, w), &dev)?;
            let cfg = Conv2dConfig { padding, stride, dilation: 1, groups: c, cudnn_fwd_algo: None };
            let want = Conv2d::new(weight.clone(), Some(bias.clone()), cfg).forward(&x)?;
            let got = Depthwise::new(weight, bias, stride, padding)?.forward(&x)?;
            assert_eq!(want.dims(), got.dims(), "k{k} s{stride} p{padding} {h}×{w}");
            let err = (want - got)?.abs()?.flatten_all()?.max(0)?.to_scalar::<f32>()?;
            assert!(err < 1e-4, "k{k} s{stride} p{padding} {h}×{w}: max abs error {err}");
        }
        Ok(())
    }

    #[test]
    fn pointwise_matrix_product_matches_candles_convolution() -> Result<()> {
        let dev = Device::Cpu;
        let weight = Tensor::randn(0f32, 1.0, (5, 3, 1, 1), &dev)?;
        let bias = Tensor::randn(0f32, 1.0, 5, &dev)?;
        let x = Tensor::randn(0f32, 1.0, (2, 3, 4, 6), &dev)?;
        let want = Conv2d::new(weight.clone(), Some(bias.clone()), Conv2dConfig::default()).forward(&x)?;
        let conv = Conv::new(weight, Some(bias), Conv2dConfig::default())?;
        assert!(matches!(conv, Conv::Pointwise { .. }));
        let err = (want - conv.forward(&x)?)?.abs()?.flatten_all()?.max(0)?.to_scalar::<f32>()?;
        assert!(err < 1e-5, "max abs error {err}");
        Ok(())
    }

    #[test]
    fn l2_normalize_gives_unit_rows() -> Result<()> {
        let x = Tensor::new(&[[3f32, 4.0], [0.0, -2.0]], &Device::Cpu)?;
        assert_eq!(l2_normalize(&x)?.to_vec2::<f32>()?, vec![vec![0.6, 0.8], vec![0.0, -1.0]]);
        Ok(())
    }
}
