//! YOLOv8 (n/s/m/l/x) detection in candle, loading safetensors in the widely
//! used candle naming: `net.*` (backbone), `fpn.*` (neck), `head.*` (decoupled
//! head with `cv2.*` box branches, `cv3.*` class branches and `dfl.conv`).
//! Each conv block is `<name>.conv.weight` + `<name>.bn.{weight,bias,
//! running_mean,running_var}` (batch norm folded into the conv at load) or,
//! for already-folded exports (every ONNX export), `<name>.conv.weight` +
//! `<name>.conv.bias`. The scale is read from the stem's width and the number
//! of classes from the class branch ([`inspect`]); the classes' names and their
//! COCO ids come from a class-names file ([`crate::classes`]).
//!
//! Input: RGB / 255 letterboxed into 640×640 on a grey (114) canvas. The head
//! is decoded outside the network ([`crate::detection::decode_dense`]): class
//! sigmoid, four 16-bin distance distributions per point, × stride. Every
//! convolution runs with its bias and SiLU fused ([`crate::conv`]).
//!
//! Converting an ultralytics model: `tools/onnx_yolov8_to_safetensors.py` for
//! an ONNX export; for a `.pt` checkpoint the candle names map one to one onto
//! ultralytics' `model.N.*` modules (`model.0` → `net.b1.0`, `model.1` →
//! `net.b1.1`, `model.2` → `net.b2.0`, `model.3` → `net.b2.1`, `model.4` →
//! `net.b2.2`, `model.5` → `net.b3.0`, `model.6` → `net.b3.1`, `model.7` →
//! `net.b4.0`, `model.8` → `net.b4.1`, `model.9` → `net.b5.0`, `model.12` →
//! `fpn.n1`, `model.15` → `fpn.n2`, `model.16` → `fpn.n3`, `model.18` →
//! `fpn.n4`, `model.19` → `fpn.n5`, `model.21` → `fpn.n6`, `model.22` →
//! `head`; inside C2f blocks `m.K` → `bottleneck.K`); see the README of this
//! crate for both.

use std::mem::MaybeUninit;
use std::path::Path;

use candle_core::{CpuStorage, CustomOp1, CustomOp2, DType, Device, Layout, Module, Shape, Tensor};
use candle_nn::{Conv2dConfig, VarBuilder};
use image::RgbImage;
use rayon::prelude::*;

use crate::conv::{Activation, FusedConv, cpu_input, written};
use crate::detection::{DetectFilter, Detection, HeadLevel, HeadSpec, Letterbox, decode_dense, nms};
use crate::nanodet::ModelError;
use crate::preprocess::{InputSpec, letterbox_chw};

pub const INPUT_SIZE: u32 = 640;
pub const STRIDES: [u32; 3] = [8, 16, 32];
pub const REG_BINS: usize = 16;
pub const INPUT: InputSpec = InputSpec { size: INPUT_SIZE, pad: 114, bgr: false, mean: [0.0; 3], std: [255.0; 3] };

/// Model scale.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Size {
    N,
    S,
    M,
    L,
    X,
}

impl Size {
    /// (depth, width, ratio) multiples as ultralytics defines them.
    fn multiples(self) -> (f64, f64, f64) {
        match self {
            Size::N => (0.33, 0.25, 2.0),
            Size::S => (0.33, 0.50, 2.0),
            Size::M => (0.67, 0.75, 1.5),
            Size::L => (1.00, 1.00, 1.0),
            Size::X => (1.00, 1.25, 1.0),
        }
    }

    /// The scale whose stem convolution has `channels` outputs (16, 32, 48, 64, 80).
    pub fn from_stem_channels(channels: usize) -> Option<Self> {
        [Size::N, Size::S, Size::M, Size::L, Size::X].into_iter().find(|s| ch(64.0 * s.multiples().1) == channels)
    }

    pub fn name(self) -> &'static str {
        match self {
            Size::N => "yolov8n",
            Size::S => "yolov8s",
            Size::M => "yolov8m",
            Size::L => "yolov8l",
            Size::X => "yolov8x",
        }
    }
}

/// Whether conv blocks carry an unfolded batch norm.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Norm {
    /// Look at the weights: `bn.running_mean` present → fold it, else expect `conv.bias`.
    Detect,
    /// Always create `bn.*` (used when generating weights).
    Unfolded,
}

struct ConvBlock {
    conv: FusedConv,
}

impl ConvBlock {
    fn load(vb: VarBuilder, norm: Norm, c1: usize, c2: usize, k: usize, stride: usize) -> candle_core::Result<Self> {
        let cfg = Conv2dConfig { padding: k / 2, stride, groups: 1, dilation: 1, cudnn_fwd_algo: None };
        let conv = if norm == Norm::Unfolded || vb.contains_tensor("bn.running_mean") {
            let bn = candle_nn::batch_norm(c2, 1e-3, vb.pp("bn"))?;
            candle_nn::conv2d_no_bias(c1, c2, k, cfg, vb.pp("conv"))?.absorb_bn(&bn)?
        } else {
            candle_nn::conv2d(c1, c2, k, cfg, vb.pp("conv"))?
        };
        Ok(Self { conv: FusedConv::new(conv.weight(), conv.bias(), stride, k / 2, Activation::Silu)? })
    }

    fn forward(&self, xs: &Tensor) -> candle_core::Result<Tensor> {
        self.conv.forward(xs)
    }
}

struct Bottleneck {
    cv1: ConvBlock,
    cv2: ConvBlock,
    residual: bool,
}

impl Bottleneck {
    fn load(vb: VarBuilder, norm: Norm, c: usize, shortcut: bool) -> candle_core::Result<Self> {
        Ok(Self {
            cv1: ConvBlock::load(vb.pp("cv1"), norm, c, c, 3, 1)?,
            cv2: ConvBlock::load(vb.pp("cv2"), norm, c, c, 3, 1)?,
            residual: shortcut,
        })
    }

    fn forward(&self, xs: &Tensor) -> candle_core::Result<Tensor> {
        let ys = self.cv2.forward(&self.cv1.forward(xs)?)?;
        if self.residual { xs + ys } else { Ok(ys) }
    }
}

/// CSP bottleneck with two convolutions ("C2f").
struct C2f {
    cv1: ConvBlock,
    cv2: ConvBlock,
    bottlenecks: Vec<Bottleneck>,
}

impl C2f {
    fn load(vb: VarBuilder, norm: Norm, c1: usize, c2: usize, n: usize, shortcut: bool) -> candle_core::Result<Self> {
        let c = c2 / 2;
        let bottlenecks = (0..n)
            .map(|i| Bottleneck::load(vb.pp(format!("bottleneck.{i}")), norm, c, shortcut))
            .collect::<candle_core::Result<_>>()?;
        Ok(Self {
            cv1: ConvBlock::load(vb.pp("cv1"), norm, c1, 2 * c, 1, 1)?,
            cv2: ConvBlock::load(vb.pp("cv2"), norm, (2 + n) * c, c2, 1, 1)?,
            bottlenecks,
        })
    }

    fn forward(&self, xs: &Tensor) -> candle_core::Result<Tensor> {
        if xs.device().is_cpu() {
            return xs.apply_op1_no_bwd(self);
        }
        let mut ys = self.cv1.forward(xs)?.chunk(2, 1)?;
        for b in &self.bottlenecks {
            let next = b.forward(ys.last().expect("two chunks"))?;
            ys.push(next);
        }
        self.cv2.forward(&Tensor::cat(&ys, 1)?)
    }
}

/// The whole block as one CPU operation, without a split, a concatenation or
/// a separate residual add: per image, `cv1` writes both halves into the
/// concatenation buffer, each bottleneck reads the last chunk there and writes
/// the next one (its residual added in `cv2`'s epilogue), and `cv2` reads the
/// buffer as it is.
impl CustomOp1 for C2f {
    fn name(&self) -> &'static str {
        "yolov8-c2f"
    }

    fn cpu_fwd(&self, storage: &CpuStorage, layout: &Layout) -> candle_core::Result<(CpuStorage, Shape)> {
        let (b, c1, h, w) = layout.shape().dims4()?;
        let x = cpu_input(storage, layout)?;
        let hw = h * w;
        let c = self.cv1.conv.out_channels() / 2;
        let c2 = self.cv2.conv.out_channels();
        // No buffer is zeroed: the kernels write every value before it is read.
        let mut cat = Vec::with_capacity((2 + self.bottlenecks.len()) * c * hw);
        let cat = &mut cat.spare_capacity_mut()[..(2 + self.bottlenecks.len()) * c * hw];
        let mut tmp = Vec::with_capacity(c * hw);
        let tmp = &mut tmp.spare_capacity_mut()[..c * hw];
        let len = b * c2 * hw;
        let mut out = Vec::with_capacity(len);
        for (img, dst) in out.spare_capacity_mut()[..len].chunks_mut(c2 * hw).enumerate() {
            self.cv1.conv.forward_image(&x[img * c1 * hw..(img + 1) * c1 * hw], h, w, &mut cat[..2 * c * hw], None)?;
            for (i, bottleneck) in self.bottlenecks.iter().enumerate() {
                let (done, next) = cat.split_at_mut((2 + i) * c * hw);
                // SAFETY: chunks 0..2 + i are written (by cv1 and the bottlenecks before).
                let input = unsafe { written(&done[(1 + i) * c * hw..]) };
                bottleneck.cv1.conv.forward_image(input, h, w, tmp, None)?;
                // SAFETY: written just above.
                let mid = unsafe { written(tmp) };
                let residual = bottleneck.residual.then_some(input);
                bottleneck.cv2.conv.forward_image(mid, h, w, &mut next[..c * hw], residual)?;
            }
            // SAFETY: every chunk is written.
            self.cv2.conv.forward_image(unsafe { written(cat) }, h, w, dst, None)?;
        }
        // SAFETY: cv2 wrote every value of every image.
        unsafe { out.set_len(len) };
        Ok((CpuStorage::F32(out), Shape::from((b, c2, h, w))))
    }
}

/// Spatial pyramid pooling, fast: three chained 5×5 max pools.
struct Sppf {
    cv1: ConvBlock,
    cv2: ConvBlock,
}

impl Sppf {
    fn load(vb: VarBuilder, norm: Norm, c1: usize, c2: usize) -> candle_core::Result<Self> {
        let c = c1 / 2;
        Ok(Self {
            cv1: ConvBlock::load(vb.pp("cv1"), norm, c1, c, 1, 1)?,
            cv2: ConvBlock::load(vb.pp("cv2"), norm, 4 * c, c2, 1, 1)?,
        })
    }

    fn forward(&self, xs: &Tensor) -> candle_core::Result<Tensor> {
        // 5×5 max pool, stride 1, padded with −∞ as PyTorch pads max pooling.
        let pool = |t: &Tensor| -> candle_core::Result<Tensor> {
            let pad = |t: &Tensor, dim: usize| -> candle_core::Result<Tensor> {
                let mut shape = t.dims().to_vec();
                shape[dim] = 2;
                let fill = Tensor::full(f32::NEG_INFINITY, shape, t.device())?.to_dtype(t.dtype())?;
                Tensor::cat(&[&fill, t, &fill], dim)
            };
            pad(&pad(t, 2)?, 3)?.max_pool2d_with_stride(5, 1)
        };
        if xs.device().is_cpu() {
            return xs.apply_op1_no_bwd(self);
        }
        let x = self.cv1.forward(xs)?;
        let y1 = pool(&x)?;
        let y2 = pool(&y1)?;
        let y3 = pool(&y2)?;
        self.cv2.forward(&Tensor::cat(&[&x, &y1, &y2, &y3], 1)?)
    }
}

/// The block as one CPU operation: `cv1` and the three pools write into the
/// concatenation buffer that `cv2` reads.
impl CustomOp1 for Sppf {
    fn name(&self) -> &'static str {
        "yolov8-sppf"
    }

    fn cpu_fwd(&self, storage: &CpuStorage, layout: &Layout) -> candle_core::Result<(CpuStorage, Shape)> {
        let (b, c1, h, w) = layout.shape().dims4()?;
        let x = cpu_input(storage, layout)?;
        let hw = h * w;
        let c = self.cv1.conv.out_channels();
        let c2 = self.cv2.conv.out_channels();
        let mut cat = Vec::with_capacity(4 * c * hw);
        let cat = &mut cat.spare_capacity_mut()[..4 * c * hw];
        let len = b * c2 * hw;
        let mut out = Vec::with_capacity(len);
        for (img, dst) in out.spare_capacity_mut()[..len].chunks_mut(c2 * hw).enumerate() {
            self.cv1.conv.forward_image(&x[img * c1 * hw..(img + 1) * c1 * hw], h, w, &mut cat[..c * hw], None)?;
            for i in 0..3 {
                let (done, next) = cat.split_at_mut((i + 1) * c * hw);
                // SAFETY: chunk i is written (by cv1 or the pool before).
                max_pool5(unsafe { written(&done[i * c * hw..]) }, h, w, &mut next[..c * hw]);
            }
            // SAFETY: cv1 and the three pools wrote every chunk.
            self.cv2.conv.forward_image(unsafe { written(cat) }, h, w, dst, None)?;
        }
        // SAFETY: cv2 wrote every value of every image.
        unsafe { out.set_len(len) };
        Ok((CpuStorage::F32(out), Shape::from((b, c2, h, w))))
    }
}

/// 5×5 max pooling with stride 1 over `[c][h][w]` planes, the border padded
/// with −∞ (PyTorch's `MaxPool2d(5, 1, 2)`): row maxima, then column maxima.
fn max_pool5(x: &[f32], h: usize, w: usize, out: &mut [MaybeUninit<f32>]) {
    x.par_chunks(h * w).zip(out.par_chunks_mut(h * w)).for_each(|(src, dst)| {
        let mut rows = vec![f32::NEG_INFINITY; h * w];
        for y in 0..h {
            for x0 in 0..w {
                let window = &src[y * w + x0.saturating_sub(2)..y * w + (x0 + 3).min(w)];
                rows[y * w + x0] = window.iter().fold(f32::NEG_INFINITY, |m, v| m.max(*v));
            }
        }
        for y in 0..h {
            for x0 in 0..w {
                dst[y * w + x0].write(
                    (y.saturating_sub(2)..(y + 3).min(h)).fold(f32::NEG_INFINITY, |m, yy| m.max(rows[yy * w + x0])),
                );
            }
        }
    });
}

struct Backbone {
    b1_0: ConvBlock,
    b1_1: ConvBlock,
    b2_0: C2f,
    b2_1: ConvBlock,
    b2_2: C2f,
    b3_0: ConvBlock,
    b3_1: C2f,
    b4_0: ConvBlock,
    b4_1: C2f,
    b5: Sppf,
}

fn ch(x: f64) -> usize {
    x as usize
}

impl Backbone {
    fn load(vb: VarBuilder, norm: Norm, size: Size) -> candle_core::Result<Self> {
        let (d, w, r) = size.multiples();
        let n3 = (3.0 * d).round() as usize;
        let n6 = (6.0 * d).round() as usize;
        Ok(Self {
            b1_0: ConvBlock::load(vb.pp("b1.0"), norm, 3, ch(64.0 * w), 3, 2)?,
            b1_1: ConvBlock::load(vb.pp("b1.1"), norm, ch(64.0 * w), ch(128.0 * w), 3, 2)?,
            b2_0: C2f::load(vb.pp("b2.0"), norm, ch(128.0 * w), ch(128.0 * w), n3, true)?,
            b2_1: ConvBlock::load(vb.pp("b2.1"), norm, ch(128.0 * w), ch(256.0 * w), 3, 2)?,
            b2_2: C2f::load(vb.pp("b2.2"), norm, ch(256.0 * w), ch(256.0 * w), n6, true)?,
            b3_0: ConvBlock::load(vb.pp("b3.0"), norm, ch(256.0 * w), ch(512.0 * w), 3, 2)?,
            b3_1: C2f::load(vb.pp("b3.1"), norm, ch(512.0 * w), ch(512.0 * w), n6, true)?,
            b4_0: ConvBlock::load(vb.pp("b4.0"), norm, ch(512.0 * w), ch(512.0 * w * r), 3, 2)?,
            b4_1: C2f::load(vb.pp("b4.1"), norm, ch(512.0 * w * r), ch(512.0 * w * r), n3, true)?,
            b5: Sppf::load(vb.pp("b5.0"), norm, ch(512.0 * w * r), ch(512.0 * w * r))?,
        })
    }

    /// Features at strides 8, 16 and 32.
    fn forward(&self, xs: &Tensor) -> candle_core::Result<(Tensor, Tensor, Tensor)> {
        let x = self.b1_1.forward(&self.b1_0.forward(xs)?)?;
        let p3 = self.b2_2.forward(&self.b2_1.forward(&self.b2_0.forward(&x)?)?)?;
        let p4 = self.b3_1.forward(&self.b3_0.forward(&p3)?)?;
        let p5 = self.b5.forward(&self.b4_1.forward(&self.b4_0.forward(&p4)?)?)?;
        Ok((p3, p4, p5))
    }
}

struct Neck {
    n1: C2f,
    n2: C2f,
    n3: ConvBlock,
    n4: C2f,
    n5: ConvBlock,
    n6: C2f,
}

/// `cat([upsample×2(small), large], 1)`, nearest-neighbour upsampling.
fn upsample_cat(small: &Tensor, large: &Tensor) -> candle_core::Result<Tensor> {
    if small.device().is_cpu() {
        return small.apply_op2_no_bwd(large, &UpsampleCat);
    }
    let (_, _, h, w) = small.dims4()?;
    Tensor::cat(&[&small.upsample_nearest2d(2 * h, 2 * w)?, large], 1)
}

/// [`upsample_cat`] as one CPU pass over the output, without the upsampled
/// intermediate.
struct UpsampleCat;

impl CustomOp2 for UpsampleCat {
    fn name(&self) -> &'static str {
        "yolov8-upsample-cat"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let (b, ca, h, w) = l1.shape().dims4()?;
        let (b2, cb, h2, w2) = l2.shape().dims4()?;
        if (b2, h2, w2) != (b, 2 * h, 2 * w) {
            candle_core::bail!("upsample-cat: {:?} upsampled does not match {:?}", l1.dims(), l2.dims());
        }
        let (small, large) = (cpu_input(s1, l1)?, cpu_input(s2, l2)?);
        let plane = h2 * w2;
        let len = b * (ca + cb) * plane;
        let mut out = Vec::with_capacity(len);
        out.spare_capacity_mut()[..len].par_chunks_mut(plane).enumerate().for_each(|(i, dst)| {
            let (img, ch) = (i / (ca + cb), i % (ca + cb));
            if ch < ca {
                let src = &small[(img * ca + ch) * h * w..][..h * w];
                for (y, row) in dst.chunks_mut(w2).enumerate() {
                    let src_row = &src[y / 2 * w..][..w];
                    for (x, d) in row.iter_mut().enumerate() {
                        d.write(src_row[x / 2]);
                    }
                }
            } else {
                let src = &large[(img * cb + ch - ca) * plane..][..plane];
                for (d, s) in dst.iter_mut().zip(src) {
                    d.write(*s);
                }
            }
        });
        // SAFETY: every plane of every image was written above.
        unsafe { out.set_len(len) };
        Ok((CpuStorage::F32(out), Shape::from((b, ca + cb, h2, w2))))
    }
}

impl Neck {
    fn load(vb: VarBuilder, norm: Norm, size: Size) -> candle_core::Result<Self> {
        let (d, w, r) = size.multiples();
        let n = (3.0 * d).round() as usize;
        Ok(Self {
            n1: C2f::load(vb.pp("n1"), norm, ch(512.0 * w * (1.0 + r)), ch(512.0 * w), n, false)?,
            n2: C2f::load(vb.pp("n2"), norm, ch(768.0 * w), ch(256.0 * w), n, false)?,
            n3: ConvBlock::load(vb.pp("n3"), norm, ch(256.0 * w), ch(256.0 * w), 3, 2)?,
            n4: C2f::load(vb.pp("n4"), norm, ch(768.0 * w), ch(512.0 * w), n, false)?,
            n5: ConvBlock::load(vb.pp("n5"), norm, ch(512.0 * w), ch(512.0 * w), 3, 2)?,
            n6: C2f::load(vb.pp("n6"), norm, ch(512.0 * w * (1.0 + r)), ch(512.0 * w * r), n, false)?,
        })
    }

    fn forward(&self, p3: &Tensor, p4: &Tensor, p5: &Tensor) -> candle_core::Result<[Tensor; 3]> {
        let x = self.n1.forward(&upsample_cat(p5, p4)?)?;
        let h1 = self.n2.forward(&upsample_cat(&x, p3)?)?;
        let h2 = self.n4.forward(&Tensor::cat(&[&self.n3.forward(&h1)?, &x], 1)?)?;
        let h3 = self.n6.forward(&Tensor::cat(&[&self.n5.forward(&h2)?, p5], 1)?)?;
        Ok([h1, h2, h3])
    }
}

/// A head branch after its first convolution (which [`Head`] runs for both
/// branches of a level at once).
struct Branch {
    b1: ConvBlock,
    out: FusedConv,
}

impl Branch {
    /// The branch and its first convolution.
    fn load(
        vb: VarBuilder,
        norm: Norm,
        c_in: usize,
        c_mid: usize,
        c_out: usize,
    ) -> candle_core::Result<(FusedConv, Self)> {
        let b0 = ConvBlock::load(vb.pp("0"), norm, c_in, c_mid, 3, 1)?.conv;
        let branch = Self {
            b1: ConvBlock::load(vb.pp("1"), norm, c_mid, c_mid, 3, 1)?,
            out: {
                let conv = candle_nn::conv2d(c_mid, c_out, 1, Default::default(), vb.pp("2"))?;
                FusedConv::new(conv.weight(), conv.bias(), 1, 0, Activation::Identity)?
            },
        };
        Ok((b0, branch))
    }

    fn forward(&self, xs: &Tensor) -> candle_core::Result<Tensor> {
        self.out.forward(&self.b1.forward(xs)?)
    }
}

struct Head {
    /// Per level, the first convolutions of the box and the class branch as
    /// one (they read the same features): `c_box` box channels, then the class
    /// branch's.
    first: [FusedConv; 3],
    c_box: usize,
    boxes: [Branch; 3],
    classes: [Branch; 3],
}

impl Head {
    fn load(vb: VarBuilder, norm: Norm, size: Size, nc: usize) -> candle_core::Result<Self> {
        let (_, w, r) = size.multiples();
        let filters = [ch(256.0 * w), ch(512.0 * w), ch(512.0 * w * r)];
        let c_cls = filters[0].max(nc);
        let c_box = (filters[0] / 4).max(4 * REG_BINS);
        // The DFL projection is the fixed arange(16) and is applied in decoding; it must still be there.
        candle_nn::conv2d_no_bias(REG_BINS, 1, 1, Default::default(), vb.pp("dfl.conv"))?;
        let level = |i: usize| -> candle_core::Result<(FusedConv, Branch, Branch)> {
            let (box0, boxes) = Branch::load(vb.pp(format!("cv2.{i}")), norm, filters[i], c_box, 4 * REG_BINS)?;
            let (cls0, classes) = Branch::load(vb.pp(format!("cv3.{i}")), norm, filters[i], c_cls, nc)?;
            Ok((FusedConv::stacked(&[&box0, &cls0])?, boxes, classes))
        };
        let [(f0, b0, c0), (f1, b1, c1), (f2, b2, c2)] = [level(0)?, level(1)?, level(2)?];
        Ok(Self { first: [f0, f1, f2], c_box, boxes: [b0, b1, b2], classes: [c0, c1, c2] })
    }

    /// Level `i`'s box logits and class logits, `[b, 64, h, w]` and `[b, classes, h, w]`.
    fn forward(&self, i: usize, xs: &Tensor) -> candle_core::Result<(Tensor, Tensor)> {
        let both = self.first[i].forward(xs)?;
        let c = both.dim(1)?;
        let boxes = self.boxes[i].forward(&both.narrow(1, 0, self.c_box)?.contiguous()?)?;
        let classes = self.classes[i].forward(&both.narrow(1, self.c_box, c - self.c_box)?.contiguous()?)?;
        Ok((boxes, classes))
    }
}

/// Raw head output of one level, point-major.
#[derive(Clone, Debug)]
pub struct LevelOutput {
    pub stride: u32,
    pub width: usize,
    pub height: usize,
    /// `[batch][points][classes]` probabilities (sigmoid applied).
    pub scores: Tensor,
    /// `[batch][points][4·16]` side-distribution logits.
    pub box_logits: Tensor,
}

/// What a weights file says about its model.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct WeightsInfo {
    pub size: Size,
    pub num_classes: usize,
}

/// Reads the scale (stem width) and the number of classes (the class branch's
/// output channels) from the safetensors header of `weights`.
pub fn inspect(weights: &Path) -> Result<WeightsInfo, ModelError> {
    use std::io::Read;
    let invalid = |msg: String| ModelError::Invalid { path: weights.to_path_buf(), msg };
    if !weights.is_file() {
        return Err(ModelError::Missing(weights.to_path_buf()));
    }
    let mut f = std::fs::File::open(weights).map_err(|e| invalid(e.to_string()))?;
    let mut len = [0u8; 8];
    f.read_exact(&mut len).map_err(|e| invalid(format!("not a safetensors file ({e})")))?;
    let len = u64::from_le_bytes(len);
    if len > 100 << 20 {
        return Err(invalid(format!("not a safetensors file (header length {len})")));
    }
    let mut header = vec![0u8; len as usize];
    f.read_exact(&mut header).map_err(|e| invalid(format!("not a safetensors file ({e})")))?;
    let header: serde_json::Value =
        serde_json::from_slice(&header).map_err(|e| invalid(format!("not a safetensors file ({e})")))?;
    let shape = |name: &str| -> Result<Vec<usize>, ModelError> {
        header[name]["shape"]
            .as_array()
            .and_then(|a| a.iter().map(|v| v.as_u64().map(|v| v as usize)).collect::<Option<Vec<_>>>())
            .ok_or_else(|| {
                invalid(format!(
                    "no tensor {name}: not YOLOv8 weights in candle naming (see services/detector/README.md)"
                ))
            })
    };
    let stem = shape("net.b1.0.conv.weight")?;
    let size = Size::from_stem_channels(stem[0]).ok_or_else(|| {
        invalid(format!("a {}-channel stem is no YOLOv8 scale (n 16, s 32, m 48, l 64, x 80)", stem[0]))
    })?;
    let num_classes = shape("head.cv3.0.2.weight")?[0];
    Ok(WeightsInfo { size, num_classes })
}

pub struct YoloV8 {
    net: Backbone,
    fpn: Neck,
    head: Head,
    size: Size,
    num_classes: usize,
    device: Device,
}

impl YoloV8 {
    /// Loads `<weights>` (safetensors, candle naming). The scale and the number
    /// of classes are read from the weights; a given `size` must match them.
    pub fn load(weights: &Path, size: Option<Size>, device: &Device) -> Result<Self, ModelError> {
        let found = inspect(weights)?;
        let size = match size {
            Some(s) if s != found.size => {
                return Err(ModelError::Invalid {
                    path: weights.to_path_buf(),
                    msg: format!("not {} weights: the stem has the width of {}", s.name(), found.size.name()),
                });
            }
            _ => found.size,
        };
        if device.is_cpu() {
            crate::conv::keep_freed_memory();
        }
        // SAFETY: the file is memory-mapped read-only and not modified while the model lives.
        let vb = unsafe { VarBuilder::from_mmaped_safetensors(&[weights], DType::F32, device) }
            .map_err(|e| ModelError::Invalid { path: weights.to_path_buf(), msg: e.to_string() })?;
        Self::from_var_builder(vb, Norm::Detect, size, found.num_classes, device).map_err(|e| ModelError::Invalid {
            path: weights.to_path_buf(),
            msg: format!("not {} weights: {e}", size.name()),
        })
    }

    fn from_var_builder(
        vb: VarBuilder,
        norm: Norm,
        size: Size,
        nc: usize,
        device: &Device,
    ) -> candle_core::Result<Self> {
        Ok(Self {
            net: Backbone::load(vb.pp("net"), norm, size)?,
            fpn: Neck::load(vb.pp("fpn"), norm, size)?,
            head: Head::load(vb.pp("head"), norm, size, nc)?,
            size,
            num_classes: nc,
            device: device.clone(),
        })
    }

    /// Writes randomly initialised weights with every tensor name and shape of
    /// a `size` model (batch norm unfolded, as exported checkpoints have it):
    /// what the tests and benchmarks load when no trained checkpoint is present.
    pub fn write_random_weights(path: &Path, size: Size, num_classes: usize) -> candle_core::Result<()> {
        let varmap = candle_nn::VarMap::new();
        let vb = VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
        Self::from_var_builder(vb, Norm::Unfolded, size, num_classes, &Device::Cpu)?;
        varmap.save(path)
    }

    pub fn size(&self) -> Size {
        self.size
    }

    pub fn num_classes(&self) -> usize {
        self.num_classes
    }

    /// Runs the network on a `[batch, 3, 640, 640]` input.
    pub fn forward(&self, xs: &Tensor) -> candle_core::Result<Vec<LevelOutput>> {
        let (p3, p4, p5) = self.net.forward(xs)?;
        let feats = self.fpn.forward(&p3, &p4, &p5)?;
        let mut out = Vec::with_capacity(3);
        for (i, f) in feats.iter().enumerate() {
            let (b, _, h, w) = f.dims4()?;
            let (boxes, cls) = self.head.forward(i, f)?;
            let boxes = boxes.reshape((b, 4 * REG_BINS, h * w))?.transpose(1, 2)?.contiguous()?;
            let cls = cls.reshape((b, self.num_classes, h * w))?.transpose(1, 2)?;
            let scores = candle_nn::ops::sigmoid(&cls.contiguous()?)?;
            out.push(LevelOutput { stride: STRIDES[i], width: w, height: h, scores, box_logits: boxes });
        }
        Ok(out)
    }

    /// The head's predictions in the layout of ultralytics' ONNX export
    /// (`output0`): per image, `[4 + classes][points]` channel-major, rows
    /// centre x, centre y, width, height (network-input pixels), then the class
    /// probabilities; points level by level (strides 8, 16, 32), row-major.
    pub fn predictions(&self, levels: &[LevelOutput]) -> candle_core::Result<Vec<Vec<f32>>> {
        let nc = self.num_classes;
        let total: usize = levels.iter().map(|l| l.width * l.height).sum();
        let batch = levels.first().map_or(Ok(0), |l| l.scores.dim(0))?;
        let mut out = vec![vec![0f32; (4 + nc) * total]; batch];
        let mut offset = 0;
        for l in levels {
            let points = l.width * l.height;
            let scores = l.scores.to_device(&Device::Cpu)?.to_vec3::<f32>()?;
            let logits = l.box_logits.to_device(&Device::Cpu)?.to_vec3::<f32>()?;
            for (b, img) in out.iter_mut().enumerate() {
                for p in 0..points {
                    let side =
                        |k: usize| crate::detection::expected_bin(&logits[b][p][k * REG_BINS..(k + 1) * REG_BINS]);
                    let (cx, cy) = ((p % l.width) as f32 + 0.5, (p / l.width) as f32 + 0.5);
                    let (x0, y0, x1, y1) = (cx - side(0), cy - side(1), cx + side(2), cy + side(3));
                    let s = l.stride as f32;
                    let col = offset + p;
                    img[col] = (x0 + x1) / 2.0 * s;
                    img[total + col] = (y0 + y1) / 2.0 * s;
                    img[2 * total + col] = (x1 - x0) * s;
                    img[3 * total + col] = (y1 - y0) * s;
                    for c in 0..nc {
                        img[(4 + c) * total + col] = scores[b][p][c];
                    }
                }
            }
            offset += points;
        }
        Ok(out)
    }

    /// Detects objects in each image; `filters[i]` applies to `images[i]`;
    /// class ids are the model's class indices (see [`crate::classes`]).
    pub fn detect(
        &self,
        images: &[&RgbImage],
        filters: &[DetectFilter],
        iou_threshold: f32,
    ) -> Result<Vec<Vec<Detection>>, ModelError> {
        let (inputs, boxes): (Vec<Vec<f32>>, Vec<Letterbox>) =
            images.iter().map(|img| letterbox_chw(img, &INPUT)).unzip();
        let n = inputs.len();
        let s = INPUT_SIZE as usize;
        let flat: Vec<f32> = inputs.into_iter().flatten().collect();
        let x = Tensor::from_vec(flat, (n, 3, s, s), &Device::Cpu)?.to_device(&self.device)?;
        let levels = self.forward(&x)?;
        let host: Vec<(Vec<f32>, Vec<f32>)> = levels
            .iter()
            .map(|l| {
                Ok((
                    l.scores.to_device(&Device::Cpu)?.flatten_all()?.to_vec1::<f32>()?,
                    l.box_logits.to_device(&Device::Cpu)?.flatten_all()?.to_vec1::<f32>()?,
                ))
            })
            .collect::<candle_core::Result<_>>()?;
        let spec = HeadSpec { num_classes: self.num_classes, bins: REG_BINS };
        (0..n)
            .map(|i| {
                let per: Vec<HeadLevel<'_>> = levels
                    .iter()
                    .zip(&host)
                    .map(|(l, (sc, bx))| {
                        let (ps, pb) = (sc.len() / n, bx.len() / n);
                        HeadLevel {
                            stride: l.stride as f32,
                            width: l.width,
                            height: l.height,
                            scores: &sc[i * ps..(i + 1) * ps],
                            box_logits: &bx[i * pb..(i + 1) * pb],
                        }
                    })
                    .collect();
                let dets = decode_dense(&per, spec, &filters[i]).map_err(|e| ModelError::Inference(e.to_string()))?;
                Ok(nms(dets, iou_threshold, crate::MAX_DETECTIONS).into_iter().map(|d| boxes[i].to_source(d)).collect())
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shapes(path: &Path) -> std::collections::HashMap<String, Vec<usize>> {
        candle_core::safetensors::load(path, &Device::Cpu)
            .unwrap()
            .into_iter()
            .map(|(k, v)| (k, v.dims().to_vec()))
            .collect()
    }

    /// Generated weights carry ultralytics' tensor layout under the candle names
    /// (yolov8n: 16-channel stem, 64-channel box branches, 80-channel class branches),
    /// load back, and the network produces the three 640-input levels.
    #[test]
    fn yolov8n_weights_names_shapes_and_forward() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("yolov8n.safetensors");
        YoloV8::write_random_weights(&path, Size::N, 80).unwrap();
        let s = shapes(&path);
        let expect = [
            ("net.b1.0.conv.weight", vec![16, 3, 3, 3]),
            ("net.b1.0.bn.running_var", vec![16]),
            ("net.b2.0.cv1.conv.weight", vec![32, 32, 1, 1]),
            ("net.b2.0.bottleneck.0.cv1.conv.weight", vec![16, 16, 3, 3]),
            ("net.b5.0.cv1.conv.weight", vec![128, 256, 1, 1]),
            ("net.b5.0.cv2.conv.weight", vec![256, 512, 1, 1]),
            ("fpn.n1.cv1.conv.weight", vec![128, 384, 1, 1]),
            ("fpn.n6.cv2.conv.weight", vec![256, 384, 1, 1]),
            ("head.cv2.0.0.conv.weight", vec![64, 64, 3, 3]),
            ("head.cv2.2.2.weight", vec![64, 64, 1, 1]),
            ("head.cv3.1.0.conv.weight", vec![80, 128, 3, 3]),
            ("head.cv3.0.2.bias", vec![80]),
            ("head.dfl.conv.weight", vec![1, 16, 1, 1]),
        ];
        for (name, shape) in expect {
            assert_eq!(s.get(name), Some(&shape), "{name}");
        }
        // ultralytics reports 3,157,200 parameters for yolov8n; batch-norm running statistics are buffers.
        let stats: usize = s.iter().filter(|(k, _)| k.contains(".bn.running_")).map(|(_, v)| v[0]).sum();
        let numel: usize = s.values().map(|v| v.iter().product::<usize>()).sum();
        assert_eq!(numel - stats, 3_157_200);

        let model = YoloV8::load(&path, None, &Device::Cpu).unwrap();
        assert_eq!((model.size(), model.num_classes()), (Size::N, 80));
        let x = Tensor::zeros((1, 3, 640, 640), DType::F32, &Device::Cpu).unwrap();
        let levels = model.forward(&x).unwrap();
        let dims: Vec<(usize, Vec<usize>, Vec<usize>)> =
            levels.iter().map(|l| (l.width, l.scores.dims().to_vec(), l.box_logits.dims().to_vec())).collect();
        assert_eq!(
            dims,
            vec![
                (80, vec![1, 6400, 80], vec![1, 6400, 64]),
                (40, vec![1, 1600, 80], vec![1, 1600, 64]),
                (20, vec![1, 400, 80], vec![1, 400, 64]),
            ]
        );
        // Loading with the wrong scale fails, naming it.
        let e = YoloV8::load(&path, Some(Size::S), &Device::Cpu).err().unwrap().to_string();
        assert!(e.contains("not yolov8s weights"), "{e}");
    }

    #[test]
    fn yolov8s_and_m_weights_load_with_folded_or_unfolded_norms() {
        let dir = tempfile::tempdir().unwrap();
        for (size, stem, params) in [(Size::S, 32, 11_166_560usize), (Size::M, 48, 25_902_640)] {
            let path = dir.path().join(format!("{}.safetensors", size.name()));
            YoloV8::write_random_weights(&path, size, 80).unwrap();
            let s = shapes(&path);
            assert_eq!(s["net.b1.0.conv.weight"], vec![stem, 3, 3, 3]);
            let bn: usize = s.iter().filter(|(k, _)| k.contains(".bn.running_")).map(|(_, v)| v[0]).sum();
            let numel: usize = s.values().map(|v| v.iter().product::<usize>()).sum();
            assert_eq!(numel - bn, params, "{}", size.name());
            assert_eq!(inspect(&path).unwrap(), WeightsInfo { size, num_classes: 80 });
            YoloV8::load(&path, Some(size), &Device::Cpu).unwrap();
        }
        // An export with batch norm already folded (conv.bias instead of bn.*) loads too.
        let path = dir.path().join("yolov8s.safetensors");
        let tensors = candle_core::safetensors::load(&path, &Device::Cpu).unwrap();
        let mut folded: std::collections::HashMap<String, Tensor> = std::collections::HashMap::new();
        for (k, v) in &tensors {
            if let Some(prefix) = k.strip_suffix(".bn.bias") {
                folded.insert(format!("{prefix}.conv.bias"), v.clone());
            } else if !k.contains(".bn.") {
                folded.insert(k.clone(), v.clone());
            }
        }
        let folded_path = dir.path().join("folded.safetensors");
        candle_core::safetensors::save(&folded, &folded_path).unwrap();
        YoloV8::load(&folded_path, None, &Device::Cpu).unwrap();
    }
}
