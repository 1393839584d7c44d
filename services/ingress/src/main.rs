use clap::Parser;

#[derive(Parser)]
#[command(
    name = "vlnav-ingress",
    about = "Speech and text ingress: Whisper tiny.en transcription and instruction normalisation"
)]
struct Cli {
    #[command(flatten)]
    server: vlnav_runtime::ServerConfig,
    #[command(flatten)]
    options: vlnav_ingress::Options,
}

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    let build = vlnav_ingress::services(&cli.options, &cli.server);
    vlnav_runtime::serve_main("vlnav-ingress", vlnav_ingress::DEFAULT_PORT, cli.server.clone(), build).await
}
