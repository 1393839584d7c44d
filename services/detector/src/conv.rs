//! Convolution + bias + activation as one CPU operation, for the detectors'
//! networks (YOLOv8's conv blocks with SiLU, NanoDet's with LeakyReLU).
//!
//! Per image the output `[c_out][out_h·out_w]` (NCHW) is cut into tasks that
//! rayon's threads take as they become free: column tiles (runs of 64 or more
//! output positions whose patches fit in 256 KiB) and, when there are too few
//! tiles to keep every thread busy, blocks of output channels too. A task lays
//! out its tile's input patches (`[c_in·k·k][tile]`, zero padding included; a
//! 1×1 stride-1 convolution reads its input as it is), multiplies
//! `weights [c_out, c_in·k·k] × patches` with a single-threaded `gemm` call
//! straight into the output, and applies bias and activation to the block
//! while it is still in cache: SiLU with a polynomial `exp` the compiler
//! vectorises (AVX-512 or AVX2 picked at run time), an optional residual
//! added after it. Nothing is zeroed first and no whole-image patch matrix is
//! written to memory (except for small outputs, laid out once and shared).
//! The weights are flattened once, at load.
//!
//! [`FusedConv::forward_image`] writes into a caller's buffer, so that blocks
//! (YOLOv8's C2f and SPPF) can place their convolutions' outputs straight into
//! a concatenation. [`profile`] records per-call timings for
//! `examples/profile_forward.rs`.
//!
//! Other devices (CUDA) use candle's convolution, bias and activation ops: same
//! results, the kernels candle has for them.

use std::borrow::Cow;
use std::mem::MaybeUninit;
use std::time::Instant;

use candle_core::{CpuStorage, CustomOp1, DType, Layout, Module, Shape, Tensor};
use rayon::prelude::*;

/// Where the convolutions of a forward pass spend their time: off unless
/// switched on (`examples/profile_forward.rs`); one record per CPU call.
pub mod profile {
    use std::sync::Mutex;
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::time::Duration;

    static ON: AtomicBool = AtomicBool::new(false);
    static LOG: Mutex<Vec<ConvTiming>> = Mutex::new(Vec::new());

    /// One convolution call: its shape and wall-clock times.
    #[derive(Clone, Debug, Default)]
    pub struct ConvTiming {
        pub batch: usize,
        pub c_in: usize,
        pub c_out: usize,
        pub k: usize,
        pub stride: usize,
        pub h: usize,
        pub w: usize,
        pub out_h: usize,
        pub out_w: usize,
        /// Laying out the patches (im2col).
        pub patches: Duration,
        /// The bias fill and the matrix product.
        pub matmul: Duration,
        /// The activation.
        pub activation: Duration,
        /// The whole call.
        pub total: Duration,
    }

    impl ConvTiming {
        pub fn flops(&self) -> f64 {
            2.0 * (self.batch * self.c_out * self.out_h * self.out_w * self.c_in * self.k * self.k) as f64
        }
    }

    /// Starts (or stops) recording; clears what was recorded.
    pub fn enable(on: bool) {
        LOG.lock().unwrap_or_else(|e| e.into_inner()).clear();
        ON.store(on, Ordering::Relaxed);
    }

    /// The records since the last call, in call order.
    pub fn take() -> Vec<ConvTiming> {
        std::mem::take(&mut *LOG.lock().unwrap_or_else(|e| e.into_inner()))
    }

    pub(super) fn on() -> bool {
        ON.load(Ordering::Relaxed)
    }

    pub(super) fn record(t: ConvTiming) {
        LOG.lock().unwrap_or_else(|e| e.into_inner()).push(t);
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Activation {
    Identity,
    /// max(x, αx)
    Leaky(f32),
    /// x·σ(x)
    Silu,
}

impl Activation {
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

    /// One convolution computing `convs`' outputs stacked along the channels
    /// (same input, kernel, stride, padding and activation): their input's
    /// patches are laid out once.
    pub fn stacked(convs: &[&FusedConv]) -> candle_core::Result<Self> {
        let Some(first) = convs.first() else { candle_core::bail!("fused conv: nothing to stack") };
        if convs
            .iter()
            .any(|c| (c.c_in, c.k, c.stride, c.pad, c.act) != (first.c_in, first.k, first.stride, first.pad, first.act))
        {
            candle_core::bail!("fused conv: only convolutions of the same input and geometry can be stacked");
        }
        let device_weights = match &first.device_weights {
            None => None,
            Some(_) => {
                let (w, b): (Vec<&Tensor>, Vec<&Tensor>) =
                    convs.iter().filter_map(|c| c.device_weights.as_ref().map(|(w, b)| (w, b))).unzip();
                Some((Tensor::cat(&w, 0)?, Tensor::cat(&b, 1)?))
            }
        };
        Ok(Self {
            weight: convs.iter().flat_map(|c| c.weight.iter().copied()).collect(),
            bias: convs.iter().flat_map(|c| c.bias.iter().copied()).collect(),
            c_out: convs.iter().map(|c| c.c_out).sum(),
            device_weights,
            ..(*first).clone()
        })
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
                    copy_strided(&mut dst[x_lo..x_hi], &src[x_lo * stride + kx - pad..], stride);
                }
            }
        }
    });
}

/// `dst[i] = src[i·stride]`; stride 2 (the downsampling convolutions) as a
/// deinterleave the compiler vectorises.
#[inline]
fn copy_strided(dst: &mut [f32], src: &[f32], stride: usize) {
    let n = dst.len();
    match stride {
        1 => dst.copy_from_slice(&src[..n]),
        2 if n > 0 => {
            for (d, pair) in dst[..n - 1].iter_mut().zip(src.chunks_exact(2)) {
                *d = pair[0];
            }
            dst[n - 1] = src[2 * (n - 1)];
        }
        _ => dst.iter_mut().zip(src.iter().step_by(stride)).for_each(|(d, s)| *d = *s),
    }
}

/// Elementwise kernels, compiled for AVX-512 and for AVX2 + FMA besides the
/// baseline and picked at run time. They use IEEE additions, multiplications,
/// divisions, minima/maxima and integer operations only (no fused
/// multiply-adds), so every path gives the same bits.
mod simd {
    use super::Activation;

    /// e^x: Cephes' `expf` (x = n·ln 2 + r, |r| ≤ ln 2 / 2, a degree-7 polynomial
    /// for e^r, 2^n from the exponent bits), without branches so that loops over
    /// it vectorise. Relative error < 1e-7 on [-87, 88]; the input is clamped
    /// to that range (e^-87 ≈ 1.6e-38, e^88 ≈ 1.7e38).
    #[inline(always)]
    pub(super) fn exp(x: f32) -> f32 {
        const LOG2E: f32 = std::f32::consts::LOG2_E;
        // 1.5·2^23: adding it rounds to an integer held in the low mantissa bits.
        const ROUND: f32 = 12_582_912.0;
        const LN2_HI: f32 = 0.693_359_4;
        const LN2_LO: f32 = -2.121_944_4e-4;
        let x = x.clamp(-87.0, 88.0);
        let z = x * LOG2E + ROUND;
        let n = z - ROUND;
        let r = x - n * LN2_HI - n * LN2_LO;
        let p = ((((1.987_569_1e-4 * r + 1.398_199_9e-3) * r + 8.333_452e-3) * r + 4.166_579_6e-2) * r + 0.166_666_65)
            * r
            + 0.5;
        let p = p * (r * r) + r + 1.0;
        // 2^n: n (in −126..=127) from z's low bits, shifted into the exponent.
        p * f32::from_bits((z.to_bits() << 23).wrapping_add(127 << 23))
    }

    /// x·σ(x) = x / (1 + e^−x).
    #[inline(always)]
    pub(super) fn silu(x: f32) -> f32 {
        x / (1.0 + exp(-x))
    }

    /// `v[i] = act(v[i] + bias) (+ residual[i])`.
    #[inline(always)]
    fn epilogue_body(act: Activation, bias: f32, v: &mut [f32], residual: Option<&[f32]>) {
        match (act, residual) {
            (Activation::Silu, None) => v.iter_mut().for_each(|x| *x = silu(*x + bias)),
            (Activation::Silu, Some(r)) => v.iter_mut().zip(r).for_each(|(x, r)| *x = silu(*x + bias) + r),
            (Activation::Leaky(a), None) => v.iter_mut().for_each(|x| {
                let y = *x + bias;
                *x = if y < 0.0 { y * a } else { y }
            }),
            (Activation::Leaky(a), Some(r)) => v.iter_mut().zip(r).for_each(|(x, r)| {
                let y = *x + bias;
                *x = (if y < 0.0 { y * a } else { y }) + r
            }),
            (Activation::Identity, None) => v.iter_mut().for_each(|x| *x += bias),
            (Activation::Identity, Some(r)) => v.iter_mut().zip(r).for_each(|(x, r)| *x = *x + bias + r),
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    unsafe fn epilogue_avx512(act: Activation, bias: f32, v: &mut [f32], residual: Option<&[f32]>) {
        epilogue_body(act, bias, v, residual)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn epilogue_avx2(act: Activation, bias: f32, v: &mut [f32], residual: Option<&[f32]>) {
        epilogue_body(act, bias, v, residual)
    }

    /// `v[i] = act(v[i] + bias) (+ residual[i])`, vectorised for this CPU.
    pub(super) fn epilogue(act: Activation, bias: f32, v: &mut [f32], residual: Option<&[f32]>) {
        debug_assert!(residual.is_none_or(|r| r.len() == v.len()));
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f") {
                // SAFETY: the CPU has AVX-512F.
                return unsafe { epilogue_avx512(act, bias, v, residual) };
            }
            if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
                // SAFETY: the CPU has AVX2 and FMA.
                return unsafe { epilogue_avx2(act, bias, v, residual) };
            }
        }
        epilogue_body(act, bias, v, residual)
    }
}

/// Fills `col` (`[c_in·k·k][tw]`) with the patches of output positions
/// `c0..c0 + tw` (row-major over the `ow`-wide output) of one image.
#[allow(clippy::too_many_arguments)]
fn im2col_tile(
    x: &[f32],
    (c_in, h, w): (usize, usize, usize),
    (k, stride, pad): (usize, usize, usize),
    ow: usize,
    c0: usize,
    tw: usize,
    col: &mut [f32],
) {
    debug_assert_eq!(col.len(), c_in * k * k * tw);
    for c in 0..c_in {
        let plane = &x[c * h * w..(c + 1) * h * w];
        for ky in 0..k {
            for kx in 0..k {
                let row = &mut col[((c * k + ky) * k + kx) * tw..][..tw];
                // Output columns whose input x is inside the image: ox in [x_lo, x_hi).
                let x_lo = pad.saturating_sub(kx).div_ceil(stride).min(ow);
                let x_hi = if w + pad > kx { ((w + pad - kx - 1) / stride + 1).min(ow) } else { 0 }.max(x_lo);
                let mut pos = c0;
                while pos < c0 + tw {
                    let (oy, ox0) = (pos / ow, pos % ow);
                    let ox1 = ow.min(ox0 + (c0 + tw - pos));
                    let dst = &mut row[pos - c0..pos - c0 + (ox1 - ox0)];
                    pos += ox1 - ox0;
                    let iy = (oy * stride + ky) as isize - pad as isize;
                    if iy < 0 || iy >= h as isize {
                        dst.fill(0.0);
                        continue;
                    }
                    let src = &plane[iy as usize * w..(iy as usize + 1) * w];
                    let lo = x_lo.clamp(ox0, ox1);
                    let hi = x_hi.clamp(lo, ox1);
                    dst[..lo - ox0].fill(0.0);
                    dst[hi - ox0..].fill(0.0);
                    if hi == lo {
                        continue;
                    }
                    copy_strided(&mut dst[lo - ox0..hi - ox0], &src[lo * stride + kx - pad..], stride);
                }
            }
        }
    }
}

/// The output buffer, shared by tasks that write disjoint blocks of it.
#[derive(Clone, Copy)]
struct OutPtr(*mut f32);
// SAFETY: tasks write disjoint (row block × column tile) regions only.
unsafe impl Send for OutPtr {}
unsafe impl Sync for OutPtr {}

impl OutPtr {
    /// The address `offset` values in (a method, so that closures capture the
    /// whole `Send` wrapper rather than its raw pointer).
    fn at(self, offset: usize) -> *mut f32 {
        self.0.wrapping_add(offset)
    }
}

thread_local! {
    /// A task's patch tile, kept between calls.
    static PATCHES: std::cell::RefCell<Vec<f32>> = const { std::cell::RefCell::new(Vec::new()) };
    /// An image's patches when all tasks share them, kept between calls.
    static SHARED_PATCHES: std::cell::RefCell<Vec<f32>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Values in one task's patch tile: 256 KiB, which stays in L2 while gemm
/// packs it (on the 1 MiB-L2 AMD EPYC of the README's figures, tiles of
/// 64 KiB, 1 MiB and 4 MiB took 3 %, 2 % and 35 % more CPU time per YOLOv8s
/// pass, one comparison on a loaded machine).
const TILE_FLOATS: usize = 256 * 1024 / 4;

impl FusedConv {
    /// One image on the CPU: `x` `[c_in][h][w]` → `out` `[c_out][oh][ow]`,
    /// `out = act(weights ⊛ x + bias) (+ residual)`.
    ///
    /// The output is cut into column tiles (runs of output positions) and, when
    /// there are few of them, row blocks (output channels); rayon's threads take
    /// (tile, block) tasks, and each task lays out its tile's patches (unless a
    /// 1×1 convolution reads its input as it is), multiplies on one thread and
    /// applies bias and activation while the block is still in cache.
    pub fn forward_image(
        &self,
        x: &[f32],
        h: usize,
        w: usize,
        out: &mut [MaybeUninit<f32>],
        residual: Option<&[f32]>,
    ) -> candle_core::Result<()> {
        use std::sync::atomic::{AtomicU64, Ordering};
        let (k, s, p) = (self.k, self.stride, self.pad);
        if h + 2 * p < k || w + 2 * p < k {
            candle_core::bail!("fused conv: {h}×{w} input is smaller than the {k}×{k} kernel");
        }
        let (oh, ow) = self.out_size(h, w);
        let n = oh * ow;
        let kk = self.c_in * k * k;
        if x.len() != self.c_in * h * w || out.len() != self.c_out * n || residual.is_some_and(|r| r.len() != out.len())
        {
            candle_core::bail!(
                "fused conv: buffers of {} / {} / {:?} values for {}×{h}×{w} → {}×{oh}×{ow}",
                x.len(),
                out.len(),
                residual.map(<[f32]>::len),
                self.c_in,
                self.c_out
            );
        }
        let t0 = Instant::now();
        let direct = k == 1 && s == 1 && p == 0;
        let threads = rayon::current_num_threads().max(1);
        // Column tiles: a tile's patches fit the budget (in L2).
        let tw = (TILE_FLOATS / kk / 64 * 64).clamp(64, 4096).min(n);
        let tiles = n.div_ceil(tw);
        // Enough tasks to keep every thread busy: patches per task when there
        // are many tiles, else laid out once and output channels split too.
        let per_task_patches = !direct && tiles >= 8 * threads;
        let mut row_blocks = 1;
        if !per_task_patches {
            while tiles * row_blocks < 8 * threads && self.c_out / (2 * row_blocks) >= 16 {
                row_blocks *= 2;
            }
        }
        let profiling = profile::on();
        let t = Instant::now();
        // Shared patches go to this thread's buffer, kept between calls (taken
        // out while in use: a call nested in this one allocates its own).
        let mut shared = Vec::new();
        if !direct && !per_task_patches {
            shared = SHARED_PATCHES.with_borrow_mut(std::mem::take);
            if shared.len() < kk * n {
                shared.resize(kk * n, 0.0);
            }
            im2col(x, self.c_in, h, w, k, s, p, &mut shared[..kk * n]);
        }
        let shared_patches = t.elapsed();
        let stage_ns = [AtomicU64::new(0), AtomicU64::new(0), AtomicU64::new(0)];
        // gemm writes every value of the output without reading it (read_dst
        // false), so it needs no zeroing first.
        let out_ptr = OutPtr(out.as_mut_ptr().cast::<f32>());
        (0..tiles * row_blocks).into_par_iter().for_each(|task| {
            let (tile, block) = (task / row_blocks, task % row_blocks);
            let c0 = tile * tw;
            let cols = tw.min(n - c0);
            let r0 = block * self.c_out / row_blocks;
            let rows = (block + 1) * self.c_out / row_blocks - r0;
            let mut clock = profiling.then(Instant::now);
            let mut lap = |stage: usize| {
                if let Some(c) = clock.as_mut() {
                    stage_ns[stage].fetch_add(c.elapsed().as_nanos() as u64, Ordering::Relaxed);
                    *c = Instant::now();
                }
            };
            PATCHES.with_borrow_mut(|buf| {
                let (rhs, rhs_rs): (*const f32, usize) = if direct {
                    (x[c0..].as_ptr(), n)
                } else if per_task_patches {
                    if buf.len() < kk * cols {
                        buf.resize(kk * cols, 0.0);
                    }
                    im2col_tile(x, (self.c_in, h, w), (k, s, p), ow, c0, cols, &mut buf[..kk * cols]);
                    (buf.as_ptr(), cols)
                } else {
                    (shared[c0..].as_ptr(), n)
                };
                lap(0);
                // SAFETY: dst is rows × cols of the [c_out][n] output at (r0, c0),
                // this task's block alone; weight rows r0.. of [c_out][kk]; rhs is
                // kk × cols with row stride rhs_rs; all in bounds.
                unsafe {
                    gemm::gemm(
                        rows,
                        cols,
                        kk,
                        out_ptr.at(r0 * n + c0),
                        1,
                        n as isize,
                        false,
                        self.weight[r0 * kk..].as_ptr(),
                        1,
                        kk as isize,
                        rhs,
                        1,
                        rhs_rs as isize,
                        0.0,
                        1.0,
                        false,
                        false,
                        false,
                        gemm::Parallelism::None,
                    );
                }
            });
            lap(1);
            for r in r0..r0 + rows {
                // SAFETY: row r, columns c0..c0 + cols: inside this task's block.
                let v = unsafe { std::slice::from_raw_parts_mut(out_ptr.at(r * n + c0), cols) };
                simd::epilogue(self.act, self.bias[r], v, residual.map(|res| &res[r * n + c0..r * n + c0 + cols]));
            }
            lap(2);
        });
        if shared.capacity() > 0 {
            SHARED_PATCHES.with_borrow_mut(|buf| {
                if buf.capacity() < shared.capacity() {
                    *buf = shared;
                }
            });
        }
        if profiling {
            let ns = |i: usize| std::time::Duration::from_nanos(stage_ns[i].load(Ordering::Relaxed));
            profile::record(profile::ConvTiming {
                batch: 1,
                c_in: self.c_in,
                c_out: self.c_out,
                k,
                stride: s,
                h,
                w,
                out_h: oh,
                out_w: ow,
                patches: shared_patches + ns(0),
                matmul: ns(1),
                activation: ns(2),
                total: t0.elapsed(),
            });
        }
        Ok(())
    }

    /// The output's height and width for an `h`×`w` input.
    pub fn out_size(&self, h: usize, w: usize) -> (usize, usize) {
        ((h + 2 * self.pad - self.k) / self.stride + 1, (w + 2 * self.pad - self.k) / self.stride + 1)
    }
}

impl CustomOp1 for FusedConv {
    fn name(&self) -> &'static str {
        "fused-conv2d"
    }

    fn cpu_fwd(&self, storage: &CpuStorage, layout: &Layout) -> candle_core::Result<(CpuStorage, Shape)> {
        let (b, c, h, w) = layout.shape().dims4()?;
        if c != self.c_in {
            candle_core::bail!("fused conv: input has {c} channels, the filter expects {}", self.c_in);
        }
        let x = cpu_input(storage, layout)?;
        let (oh, ow) = self.out_size(h, w);
        let len = b * self.c_out * oh * ow;
        let mut out = Vec::with_capacity(len);
        for (img, dst) in out.spare_capacity_mut()[..len].chunks_mut(self.c_out * oh * ow).enumerate() {
            self.forward_image(&x[img * c * h * w..(img + 1) * c * h * w], h, w, dst, None)?;
        }
        // SAFETY: forward_image wrote every value.
        unsafe { out.set_len(len) };
        Ok((CpuStorage::F32(out), Shape::from((b, self.c_out, oh, ow))))
    }
}

/// Keeps freed memory in the process for the next forward pass instead of
/// returning it to the kernel (Linux with glibc; elsewhere nothing).
///
/// Every candle op allocates its output afresh. glibc serves blocks above its
/// mmap threshold (128 KiB until a large block is freed) with a fresh mapping
/// and trims the heap once 2× that much is free at its top, so each pass
/// faulted in and zeroed its tensors' pages again: NanoDet-g 4,100 page
/// faults a pass, ≈ 15 ms of system time on one thread. With the thresholds
/// at 32 MiB (glibc's own ceiling for the dynamic one) and 64 MiB, about 150.
/// Called when a CPU model is loaded; process-wide, set once.
pub fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        static ONCE: std::sync::Once = std::sync::Once::new();
        ONCE.call_once(|| {
            // SAFETY: mallopt only changes glibc's allocation parameters.
            unsafe {
                libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
                libc::mallopt(libc::M_TRIM_THRESHOLD, 64 << 20);
            }
        });
    }
}

/// Values a kernel has written, as `f32`s.
///
/// # Safety
/// Every element of `v` has been written.
pub(crate) unsafe fn written(v: &[MaybeUninit<f32>]) -> &[f32] {
    // SAFETY: MaybeUninit<f32> has f32's layout, and the caller says the values are initialised.
    unsafe { &*(v as *const [MaybeUninit<f32>] as *const [f32]) }
}

/// A CPU op's f32 input as contiguous row-major values (a copy only when the layout is strided).
pub(crate) fn cpu_input<'a>(storage: &'a CpuStorage, layout: &Layout) -> candle_core::Result<Cow<'a, [f32]>> {
    let CpuStorage::F32(data) = storage else { candle_core::bail!("the input must be f32") };
    Ok(match layout.contiguous_offsets() {
        Some((start, end)) => Cow::Borrowed(&data[start..end]),
        None => Cow::Owned(strided_copy(data, layout)),
    })
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
        // Sizes where every task lays out its own patch tile (many column
        // tiles), and where the patches are shared and the output channels split.
        for (c_in, c_out, k, stride, pad, h, w) in [
            (16, 24, 3, 1, 1, 96, 96),
            (8, 40, 3, 2, 1, 190, 170),
            (64, 96, 1, 1, 0, 70, 60),
            (96, 200, 3, 1, 1, 9, 11),
        ] {
            let x = Tensor::randn(0f32, 1.0, (1, c_in, h, w), &dev).unwrap();
            let wt = Tensor::randn(0f32, 0.2, (c_out, c_in, k, k), &dev).unwrap();
            let b = Tensor::randn(0f32, 0.5, c_out, &dev).unwrap();
            let want = reference(&x, &wt, &b, stride, pad, Activation::Silu);
            let got = FusedConv::new(&wt, Some(&b), stride, pad, Activation::Silu).unwrap().forward(&x).unwrap();
            let diff: f32 = (got - &want).unwrap().abs().unwrap().max_all().unwrap().to_scalar().unwrap();
            assert!(diff < 1e-4, "{c_in}→{c_out} k{k} s{stride} p{pad} {h}×{w}: max |Δ| {diff}");
        }
        // Wrong channel count: an error, not a panic.
        let conv =
            FusedConv::new(&Tensor::zeros((2, 3, 3, 3), DType::F32, &dev).unwrap(), None, 1, 1, Activation::Silu)
                .unwrap();
        assert!(conv.forward(&Tensor::zeros((1, 4, 5, 5), DType::F32, &dev).unwrap()).is_err());
    }

    #[test]
    fn vectorised_exp_and_silu_match_f64_to_float_precision() {
        let mut worst = (0f64, 0f64);
        let mut x = -100f32;
        while x < 100.0 {
            let (e, t) = ((x as f64).exp(), x as f64 / (1.0 + (-(x as f64)).exp()));
            if x.abs() < 87.0 {
                worst.0 = worst.0.max((simd::exp(x) as f64 - e).abs() / e);
            }
            // Relative where the value is a normal float, else absolute.
            let err = (simd::silu(x) as f64 - t).abs();
            if t.abs() > 1e-30 {
                worst.1 = worst.1.max(err / t.abs());
            } else {
                assert!(err < 1e-35, "silu({x}): {} vs {t:e}", simd::silu(x));
            }
            x += 3e-4;
        }
        assert!(worst.0 < 2e-7 && worst.1 < 4e-7, "relative error: exp {:e}, silu {:e}", worst.0, worst.1);
        assert!(simd::silu(-200.0).abs() < 1e-35);
        assert_eq!(simd::silu(200.0), 200.0);
        // The vectorised epilogue gives the bits of the scalar function, with and without a residual.
        let v: Vec<f32> = (0..1000).map(|i| (i as f32 - 500.0) * 0.037).collect();
        let res: Vec<f32> = (0..1000).map(|i| i as f32 * 0.01).collect();
        let mut got = v.clone();
        simd::epilogue(Activation::Silu, 0.25, &mut got, None);
        assert!(got.iter().zip(&v).all(|(g, x)| *g == simd::silu(x + 0.25)));
        let mut got = v.clone();
        simd::epilogue(Activation::Silu, 0.25, &mut got, Some(&res));
        assert!(got.iter().zip(&v).zip(&res).all(|((g, x), r)| *g == simd::silu(x + 0.25) + r));
        let mut got = v.clone();
        simd::epilogue(Activation::Leaky(0.1), -0.5, &mut got, None);
        assert!(got.iter().zip(&v).all(|(g, x)| *g == if x - 0.5 < 0.0 { (x - 0.5) * 0.1 } else { x - 0.5 }));
    }
}
