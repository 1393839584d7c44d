use clap::Parser;

/// vlnav segmenter service: floor hazards as a mask and virtual obstacle points.
#[derive(Parser)]
#[command(name = "vlnav-segmenter", version)]
struct Cli {
    #[command(flatten)]
    opts: vlnav_segmenter::Options,
    #[command(flatten)]
    server: vlnav_runtime::ServerConfig,
}

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    vlnav_runtime::serve_main(
        "vlnav-segmenter",
        vlnav_segmenter::DEFAULT_PORT,
        cli.server.clone(),
        vlnav_segmenter::services(&cli.opts, &cli.server),
    )
    .await
}
