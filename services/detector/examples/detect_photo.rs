//! Prints NanoDet's detections on image files.
//!
//! cargo run -p vlnav-detector --example detect_photo -- [--min-score 0.3] models/photos/bike.jpg …

use vlnav_detector::detection::DetectFilter;
use vlnav_detector::nanodet::{NanoDet, NanoDetFiles};

fn main() -> anyhow::Result<()> {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let mut min_score = 0.3f32;
    if let Some(i) = args.iter().position(|a| a == "--min-score") {
        min_score = args.get(i + 1).ok_or_else(|| anyhow::anyhow!("--min-score needs a value"))?.parse()?;
        args.drain(i..i + 2);
    }
    let models = std::env::var_os("VLNAV_MODELS_DIR").map(std::path::PathBuf::from).unwrap_or_else(|| "models".into());
    let model = NanoDet::load(&NanoDetFiles::in_dir(&models.join("nanodet")), &candle_core::Device::Cpu)?;
    for path in &args {
        let img = image::open(path)?.into_rgb8();
        let filter = DetectFilter { class_ids: vec![], min_score };
        let dets = model.detect(&[&img], &[filter], 0.45)?.remove(0);
        println!("{path} ({}×{}): {} detections", img.width(), img.height(), dets.len());
        for d in dets {
            println!(
                "  {:<12} {:.2}  [{:.0}, {:.0}, {:.0}, {:.0}]",
                vlnav_proto::coco::name(d.class_id).unwrap_or("?"),
                d.score,
                d.x_min,
                d.y_min,
                d.x_max,
                d.y_max
            );
        }
    }
    Ok(())
}
