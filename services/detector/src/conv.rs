//! Convolution + bias + activation as one CPU operation, for the detectors'
//! networks (YOLOv8's conv blocks with SiLU, NanoDet's with LeakyReLU).
//!
//! Per image: the input patches are laid out once as a `[c_in·k·k, out_h·out_w]`
//! matrix (rows copied as contiguous runs, zero padding included, so padding
//! costs nothing extra; a 1×1 stride-1 convolution reads its input as it is),
//! the output is initialised with the bias, one `gemm` call accumulates
//! `weights [c_out, c_in·k·k] × patches` into it in NCHW order, and the
//! activation is applied in place. The weights are flattened once, at load.
//! Against candle's generic path (re-flattening the filter and an NHWC copy of
//! the input on every call, 512-pixel tiles scattered into the output, then
//! separate passes for the bias and the activation) this removes every layout
//! copy around the matrix product.
//!
//! Other devices (CUDA) use candle's convolution, bias and activation ops: same
//! results, the kernels candle has for them.

use candle_core::{CpuStorage, CustomOp1, DType, Layout, Module, Shape, Tensor};
use rayon::prelude::*;

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Activation {
    Identity,
    /// max(x, αx)
    Leaky(f32),
    /// x·σ(x)
    Silu,
}

impl Activation {
    #[inline]
    fn apply(self, v: &mut [f32]) {
        match self {
            Activation::Identity => {}
            Activation::Leaky(a) => v.iter_mut().for_each(|x| *x = if *x < 0.0 { *x * a } else { *x }),
            Activation::Silu => v.iter_mut().for_each(|x| *x /= 1.0 + (-*x).exp()),
        }
    }

    fn apply_tensor(self, x: &Tensor) -> candle_core::Result<Tensor> {
        match self {
            Activation::Identity => Ok(x.clone()),
            Activation::Leaky(a) => x.maximum(&(x * a as f64)?),
            Activation::Silu => candle_nn::ops::silu(x),
        }
    }
}

/// A 2-D convolution (square kernel, one group) with bias and activation.
#[derive(Clone, Debug)]
pub struct FusedConv {
    /// `[c_out, c_in·k·k]`, row-major.
    weight: Vec<f32>,
    bias: Vec<f32>,
    c_in: usize,
    c_out: usize,
    k: usize,
    stride: usize,
    pad: usize,
    act: Activation,
    /// For non-CPU devices: the filter `[c_out, c_in, k, k]` and bias `[1, c_out, 1, 1]` there.
    device_weights: Option<(Tensor, Tensor)>,
}

impl FusedConv {
    /// `weight` `[c_out, c_in, k, k]`, `bias` `[c_out]` (none: zero).
    pub fn new(
        weight: &Tensor,
        bias: Option<&Tensor>,
        stride: usize,
        pad: usize,
        act: Activation,
    ) -> candle_core::Result<Self> {
        let (c_out, c_in, kh, kw) = weight.dims4()?;
        if kh != kw || stride == 0 {
            candle_core::bail!("fused conv: {kh}×{kw} kernel with stride {stride} is not supported");
        }
        let bias_t = match bias {
            Some(b) => b.to_dtype(DType::F32)?.reshape(c_out)?,
            None => Tensor::zeros(c_out, DType::F32, weight.device())?,
        };
        let weight_t = weight.to_dtype(DType::F32)?.contiguous()?;
        let device_weights =
            if weight.device().is_cpu() { None } else { Some((weight_t.clone(), bias_t.reshape((1, c_out, 1, 1))?)) };
        Ok(Self {
            weight: weight_t.flatten_all()?.to_device(&candle_core::Device::Cpu)?.to_vec1()?,
            bias: bias_t.to_device(&candle_core::Device::Cpu)?.to_vec1()?,
            c_in,
            c_out,
            k: kh,
            stride,
            pad,
            act,
            device_weights,
        })
    }

    pub fn out_channels(&self) -> usize {
        self.c_out
    }

    /// The same layer with another activation.
    pub fn with_activation(mut self, act: Activation) -> Self {
        self.act = act;
        self
    }

    pub fn activation(&self) -> Activation {
        self.act
    }

    /// Adds `pad` more zeros on every side of the input (an explicit Pad before it, folded in).
    pub fn with_extra_padding(mut self, pad: usize) -> Self {
        self.pad += pad;
        self
    }
}

impl Module for FusedConv {
    fn forward(&self, xs: &Tensor) -> candle_core::Result<Tensor> {
        match &self.device_weights {
            None => xs.apply_op1_no_bwd(self),
            Some((w, b)) => {
                let y = xs.conv2d(w, self.pad, self.stride, 1, 1)?.broadcast_add(b)?;
                self.act.apply_tensor(&y)
            }
        }
    }
}

/// Fills `col` (`[c_in·k·k][oh·ow]`) with the input patches of one image;
/// `x` is `[c_in][h][w]` contiguous.
#[allow(clippy::too_many_arguments)]
fn im2col(x: &[f32], c_in: usize, h: usize, w: usize, k: usize, stride: usize, pad: usize, col: &mut [f32]) {
    let oh = (h + 2 * pad - k) / stride + 1;
    let ow = (w + 2 * pad - k) / stride + 1;
    let n = oh * ow;
    debug_assert_eq!(col.len(), c_in * k * k * n);
    col.par_chunks_mut(k * k * n).enumerate().for_each(|(c, rows)| {
        let plane = &x[c * h * w..(c + 1) * h * w];
        for ky in 0..k {
            for kx in 0..k {
                let row = &mut rows[(ky * k + kx) * n..(ky * k + kx + 1) * n];
                // Output columns whose input x is inside the image: ox in [x_lo, x_hi).
                let x_lo = pad.saturating_sub(kx).div_ceil(stride).min(ow);
                let x_hi = if w + pad > kx { ((w + pad - kx - 1) / stride + 1).min(ow) } else { 0 }.max(x_lo);
                for oy in 0..oh {
                    let dst = &mut row[oy * ow..(oy + 1) * ow];
                    let iy = (oy * stride + ky) as isize - pad as isize;
                    if iy < 0 || iy >= h as isize {
                        dst.fill(0.0);
                        continue;
                    }
                    let src = &plane[iy as usize * w..(iy as usize + 1) * w];
                    dst[..x_lo].fill(0.0);
                    dst[x_hi..].fill(0.0);
                    if x_hi == x_lo {
                        continue;
                    }
                    let ix0 = x_lo * stride + kx - pad;
                    if stride == 1 {
                        dst[x_lo..x_hi].copy_from_slice(&src[ix0..ix0 + (x_hi - x_lo)]);
                    } else {
                        for (d, s) in dst[x_lo..x_hi].iter_mut().zip(src[ix0..].iter().step_by(stride)) {
                            *d = *s;
                        }
                    }
                }
            }
        }
    });
}

impl CustomOp1 for FusedConv {
    fn name(&self) -> &'static str {
        "fused-conv2d"
    }

    fn cpu_fwd(&self, storage: &CpuStorage, layout: &Layout) -> candle_core::Result<(CpuStorage, Shape)> {
        let CpuStorage::F32(data) = storage else { candle_core::bail!("fused conv: the input must be f32") };
        let (b, c, h, w) = layout.shape().dims4()?;
        if c != self.c_in {
            candle_core::bail!("fused conv: input has {c} channels, the filter expects {}", self.c_in);
        }
        if h + 2 * self.pad < self.k || w + 2 * self.pad < self.k {
            candle_core::bail!("fused conv: {h}×{w} input is smaller than the {}×{} kernel", self.k, self.k);
        }
        // A contiguous NCHW view of the input (a copy only when it is strided).
        let owned;
        let x: &[f32] = match layout.contiguous_offsets() {
            Some((start, end)) => &data[start..end],
            None => {
                owned = strided_copy(data, layout);
                &owned
            }
        };
        let (k, s, p) = (self.k, self.stride, self.pad);
        let oh = (h + 2 * p - k) / s + 1;
        let ow = (w + 2 * p - k) / s + 1;
        let n = oh * ow;
        let kk = self.c_in * k * k;
        let direct = k == 1 && s == 1 && p == 0;
        let mut col = if direct { Vec::new() } else { vec![0f32; kk * n] };
        let mut out = vec![0f32; b * self.c_out * n];
        let threads = candle_core::utils::get_num_threads();
        for (img, dst) in out.chunks_mut(self.c_out * n).enumerate() {
            let src = &x[img * c * h * w..(img + 1) * c * h * w];
            let rhs: &[f32] = if direct {
                src
            } else {
                im2col(src, c, h, w, k, s, p, &mut col);
                &col
            };
            dst.par_chunks_mut(n).zip(&self.bias).for_each(|(row, &bias)| row.fill(bias));
            // SAFETY: dst is [c_out][n], weight [c_out][kk], rhs [kk][n], all row-major and in bounds.
            unsafe {
                gemm::gemm(
                    self.c_out,
                    n,
                    kk,
                    dst.as_mut_ptr(),
                    1,
                    n as isize,
                    true,
                    self.weight.as_ptr(),
                    1,
                    kk as isize,
                    rhs.as_ptr(),
                    1,
                    n as isize,
                    1.0,
                    1.0,
                    false,
                    false,
                    false,
                    if threads > 1 { gemm::Parallelism::Rayon(threads) } else { gemm::Parallelism::None },
                );
            }
            if self.act != Activation::Identity {
                dst.par_chunks_mut(n.clamp(1, 16384)).for_each(|v| self.act.apply(v));
            }
        }
        Ok((CpuStorage::F32(out), Shape::from((b, self.c_out, oh, ow))))
    }
}

/// The elements of a strided 4-D layout, in row-major order.
fn strided_copy(data: &[f32], layout: &Layout) -> Vec<f32> {
    let dims = layout.dims();
    let st = layout.stride();
    let start = layout.start_offset();
    let mut out = Vec::with_capacity(layout.shape().elem_count());
    for i0 in 0..dims[0] {
        for i1 in 0..dims[1] {
            for i2 in 0..dims[2] {
                let base = start + i0 * st[0] + i1 * st[1] + i2 * st[2];
                if st[3] == 1 {
                    out.extend_from_slice(&data[base..base + dims[3]]);
                } else {
                    out.extend((0..dims[3]).map(|i3| data[base + i3 * st[3]]));
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;

    /// candle's convolution, bias and activation: the reference.
    fn reference(x: &Tensor, w: &Tensor, b: &Tensor, stride: usize, pad: usize, act: Activation) -> Tensor {
        let c = w.dim(0).unwrap();
        let y = x.conv2d(w, pad, stride, 1, 1).unwrap().broadcast_add(&b.reshape((1, c, 1, 1)).unwrap()).unwrap();
        act.apply_tensor(&y).unwrap()
    }

    #[test]
    fn equals_candle_convolution_for_every_shape_the_networks_use() {
        let dev = Device::Cpu;
        let cases = [
            // (c_in, c_out, k, stride, pad, h, w, act)
            (3, 8, 3, 2, 1, 17, 20, Activation::Silu),
            (8, 16, 3, 1, 1, 9, 7, Activation::Leaky(0.1)),
            (16, 4, 1, 1, 0, 6, 5, Activation::Identity),
            (6, 5, 1, 2, 0, 7, 9, Activation::Silu),
            (4, 4, 3, 2, 0, 10, 11, Activation::Leaky(0.1)),
            (5, 7, 5, 1, 2, 8, 8, Activation::Identity),
            (2, 3, 3, 1, 3, 4, 4, Activation::Silu),
        ];
        for (c_in, c_out, k, stride, pad, h, w, act) in cases {
            let x = Tensor::randn(0f32, 1.0, (2, c_in, h, w), &dev).unwrap();
            let wt = Tensor::randn(0f32, 0.5, (c_out, c_in, k, k), &dev).unwrap();
            let b = Tensor::randn(0f32, 0.5, c_out, &dev).unwrap();
            let want = reference(&x, &wt, &b, stride, pad, act);
            let conv = FusedConv::new(&wt, Some(&b), stride, pad, act).unwrap();
            let got = conv.forward(&x).unwrap();
            assert_eq!(got.dims(), want.dims(), "{c_in}→{c_out} k{k} s{stride} p{pad}");
            let diff: f32 = (got - &want).unwrap().abs().unwrap().max_all().unwrap().to_scalar().unwrap();
            assert!(diff < 1e-4, "{c_in}→{c_out} k{k} s{stride} p{pad} {h}×{w}: max |Δ| {diff}");
            // A strided (permuted) input gives the same result.
            let nhwc = x.permute((0, 2, 3, 1)).unwrap().contiguous().unwrap();
            let strided = conv.forward(&nhwc.permute((0, 3, 1, 2)).unwrap()).unwrap();
            let diff: f32 = (strided - &want).unwrap().abs().unwrap().max_all().unwrap().to_scalar().unwrap();
            assert!(diff < 1e-4);
        }
        // Wrong channel count: an error, not a panic.
        let conv =
            FusedConv::new(&Tensor::zeros((2, 3, 3, 3), DType::F32, &dev).unwrap(), None, 1, 1, Activation::Silu)
                .unwrap();
        assert!(conv.forward(&Tensor::zeros((1, 4, 5, 5), DType::F32, &dev).unwrap()).is_err());
    }
}
