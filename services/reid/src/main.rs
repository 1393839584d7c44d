use clap::Parser;

/// vlnav ReID service: a gallery of named people matched by appearance.
#[derive(Parser)]
#[command(name = "vlnav-reid", version)]
struct Cli {
    #[command(flatten)]
    opts: vlnav_reid::Options,
    #[command(flatten)]
    server: vlnav_runtime::ServerConfig,
}

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    vlnav_runtime::serve_main(
        "vlnav-reid",
        vlnav_reid::DEFAULT_PORT,
        cli.server.clone(),
        vlnav_reid::services(&cli.opts, &cli.server),
    )
    .await
}
