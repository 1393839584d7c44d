//! vlnav-detector: the DetectorService on its own port (default 50054).

use clap::Parser;

#[derive(Parser)]
#[command(name = "vlnav-detector", about = "COCO-80 object detection (NanoDet, YOLOv8, simulation) over gRPC")]
struct Cli {
    #[command(flatten)]
    detector: vlnav_detector::Options,
    #[command(flatten)]
    server: vlnav_runtime::ServerConfig,
}

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    let build = vlnav_detector::services(&cli.detector, &cli.server);
    vlnav_runtime::serve_main("vlnav-detector", vlnav_detector::DEFAULT_PORT, cli.server.clone(), build).await
}
