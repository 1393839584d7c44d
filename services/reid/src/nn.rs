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
) -> Result<Conv2d> {
    let w = conv.get((out_channels, in_channels / groups, kernel, kernel), "weight")?;
    let (scale, shift) = bn_scale_shift(out_channels, &bn)?;
    let w = w.broadcast_mul(&scale.reshape((out_channels, 1, 1, 1))?)?;
    let cfg = Conv2dConfig { padding, stride, dilation: 1, groups, cudnn_fwd_algo: None };
    Ok(Conv2d::new(w, Some(shift), cfg))
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
) -> Result<Conv2d> {
    let w = vb.get((out_channels, in_channels / groups, kernel, kernel), "weight")?;
    let cfg = Conv2dConfig { padding, stride, dilation: 1, groups, cudnn_fwd_algo: None };
    Ok(Conv2d::new(w, None, cfg))
}

/// A 1×1 convolution with bias (squeeze-excitation style gates).
pub fn conv1x1_bias(in_channels: usize, out_channels: usize, vb: VarBuilder) -> Result<Conv2d> {
    let w = vb.get((out_channels, in_channels, 1, 1), "weight")?;
    let b = vb.get(out_channels, "bias")?;
    Ok(Conv2d::new(w, Some(b), Conv2dConfig::default()))
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
    fn l2_normalize_gives_unit_rows() -> Result<()> {
        let x = Tensor::new(&[[3f32, 4.0], [0.0, -2.0]], &Device::Cpu)?;
        assert_eq!(l2_normalize(&x)?.to_vec2::<f32>()?, vec![vec![0.6, 0.8], vec![0.0, -1.0]]);
        Ok(())
    }
}
