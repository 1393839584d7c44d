use clap::Parser;

#[derive(Parser)]
#[command(name = "vlnav-local-planner", about = "Motion-primitive local planner: one (v, ω) per RGB-D frame")]
struct Cli {
    #[command(flatten)]
    options: vlnav_local_planner::Options,
    #[command(flatten)]
    server: vlnav_runtime::ServerConfig,
}

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    let build = vlnav_local_planner::services(&cli.options, &cli.server);
    vlnav_runtime::serve_main("vlnav-local-planner", vlnav_local_planner::DEFAULT_PORT, cli.server.clone(), build).await
}
