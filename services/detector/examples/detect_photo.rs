//! `vlnav detect` without building the gateway: prints a detector's boxes on image files.
//!
//! cargo run -p vlnav-detector --example detect_photo -- [--backend yolov8] [--min-score 0.3] models/photos/bike.jpg …

use clap::Parser;

#[derive(Parser)]
#[command(name = "detect_photo")]
struct Cli {
    #[command(flatten)]
    args: vlnav_detector::cli::DetectArgs,
}

fn main() -> anyhow::Result<()> {
    vlnav_detector::cli::run_detect(&Cli::parse().args, &mut std::io::stdout())?;
    Ok(())
}
