//! Where a forward pass spends its time, layer by layer: every fused
//! convolution's patch layout, matrix product and activation, and the rest of
//! the network (concatenations, splits, residual adds, upsampling, pooling,
//! the head's reshapes and sigmoid) as the forward pass's time minus the
//! convolutions'.
//!
//! ```text
//! RAYON_NUM_THREADS=2 cargo run --release -p vlnav-detector --example profile_forward -- [yolov8|nanodet] [RUNS] [--quiet]
//! ```
//!
//! Prints medians over RUNS (default 10) after two warm-up passes; the input is
//! bus.jpg letterboxed. `--quiet` runs RUNS passes without warm-up or recording,
//! for `valgrind --tool=callgrind --collect-atstart=no --toggle-collect='*YoloV8*forward*'`
//! (with `RAYON_NUM_THREADS=1`: callgrind counts only the calling thread's
//! instructions under the toggled function) or `perf record`.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use candle_core::{Device, Tensor};
use vlnav_detector::conv::profile::{self, ConvTiming};
use vlnav_detector::nanodet::{self, NanoDet, NanoDetFiles};
use vlnav_detector::preprocess::letterbox_chw;
use vlnav_detector::yolov8::{self, YoloV8};

fn models_dir() -> PathBuf {
    std::env::var_os("VLNAV_MODELS_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models"))
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// This process's CPU time (all threads, user + system), from /proc/self/stat.
fn cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    let fields: Vec<&str> = stat.rsplit_once(')')?.1.split_whitespace().collect();
    let ticks: f64 = fields.get(11)?.parse::<f64>().ok()? + fields.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let quiet = args.iter().any(|a| a == "--quiet");
    let network = args.iter().find(|a| !a.starts_with("--") && a.parse::<usize>().is_err()).map_or("yolov8", |s| s);
    let runs: usize = args.iter().find_map(|a| a.parse().ok()).unwrap_or(10).max(1);
    let models = models_dir();
    let photo = image::open(models.join("photos/bus.jpg"))?.into_rgb8();

    let forward: Box<dyn Fn()> = match network {
        "yolov8" => {
            let weights = models.join(format!("yolov8/{}.safetensors", vlnav_detector::TRAINED_YOLOV8));
            let yolo = YoloV8::load(&weights, None, &Device::Cpu)?;
            let (chw, _) = letterbox_chw(&photo, &yolov8::INPUT);
            let x = Tensor::from_vec(chw, (1, 3, 640, 640), &Device::Cpu)?;
            Box::new(move || {
                yolo.forward(&x).unwrap();
            })
        }
        "nanodet" => {
            let nano = NanoDet::load(&NanoDetFiles::in_dir(&models.join("nanodet")), &Device::Cpu)?;
            let (chw, _) = letterbox_chw(&photo, &nanodet::INPUT);
            Box::new(move || {
                nano.forward(std::slice::from_ref(&chw)).unwrap();
            })
        }
        other => anyhow::bail!("unknown network {other} (yolov8 or nanodet)"),
    };
    if quiet {
        for _ in 0..runs {
            forward();
        }
        return Ok(());
    }
    forward();
    forward();

    let mut passes: Vec<(f64, Vec<ConvTiming>)> = Vec::new();
    let cpu_start = cpu_seconds();
    for _ in 0..runs {
        profile::enable(true);
        let t = Instant::now();
        forward();
        let total = ms(t.elapsed());
        passes.push((total, profile::take()));
    }
    profile::enable(false);
    let cpu = cpu_start.zip(cpu_seconds()).map(|(a, b)| (b - a) / runs as f64 * 1e3);

    let layers = passes[0].1.len();
    let per_layer =
        |i: usize, f: &dyn Fn(&ConvTiming) -> Duration| median(passes.iter().map(|p| ms(f(&p.1[i]))).collect());
    println!("{network}, {} threads, {runs} runs, medians in ms\n", candle_core::utils::get_num_threads());
    println!("| # | convolution | out | MFLOP | patches | matmul | activation | total | GFLOP/s |");
    println!("|---|---|---|---|---|---|---|---|---|");
    let mut sums = [0f64; 4];
    let mut flops = 0f64;
    let mut by_kind: std::collections::BTreeMap<String, (f64, f64)> = Default::default();
    for i in 0..layers {
        let c = &passes[0].1[i];
        let row = [
            per_layer(i, &|t| t.patches),
            per_layer(i, &|t| t.matmul),
            per_layer(i, &|t| t.activation),
            per_layer(i, &|t| t.total),
        ];
        for (s, v) in sums.iter_mut().zip(row) {
            *s += v;
        }
        flops += c.flops();
        let kind = by_kind.entry(format!("{}×{} stride {}", c.k, c.k, c.stride)).or_default();
        kind.0 += row[3];
        kind.1 += c.flops();
        println!(
            "| {i} | {}→{} {}×{}/{} on {}×{} | {}×{} | {:.0} | {:.2} | {:.2} | {:.2} | {:.2} | {:.0} |",
            c.c_in,
            c.c_out,
            c.k,
            c.k,
            c.stride,
            c.h,
            c.w,
            c.out_h,
            c.out_w,
            c.flops() / 1e6,
            row[0],
            row[1],
            row[2],
            row[3],
            c.flops() / row[3] / 1e6
        );
    }
    let fwd = median(passes.iter().map(|p| p.0).collect());
    let fastest = passes.iter().map(|p| p.0).fold(f64::INFINITY, f64::min);
    println!(
        "\nforward pass: {fwd:.1} ms (fastest {fastest:.1}; CPU time {}); {layers} convolutions, {:.2} GFLOP",
        cpu.map_or("n/a".to_string(), |c| format!("{c:.0} ms")),
        flops / 1e9
    );
    println!(
        "convolutions {:.1} ms ({:.0} GFLOP/s): patches {:.1}, matmul (with bias fill) {:.1}, activation {:.1}",
        sums[3],
        flops / sums[3] / 1e6,
        sums[0],
        sums[1],
        sums[2]
    );
    for (kind, (t, f)) in &by_kind {
        println!("  {kind}: {t:.1} ms, {:.2} GFLOP, {:.0} GFLOP/s", f / 1e9, f / t / 1e6);
    }
    println!("everything else (concat, split, add, upsample, pool, head): {:.1} ms", fwd - sums[3]);
    Ok(())
}
