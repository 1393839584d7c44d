use clap::Parser;

#[derive(Parser)]
#[command(name = "vlnav-subgoal", about = "Subgoal estimator: moves and detected boxes to goals in the odometry frame")]
struct Cli {
    #[command(flatten)]
    options: vlnav_subgoal::Options,
    #[command(flatten)]
    server: vlnav_runtime::ServerConfig,
}

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    let build = vlnav_subgoal::services(&cli.options, &cli.server);
    vlnav_runtime::serve_main("vlnav-subgoal", vlnav_subgoal::DEFAULT_PORT, cli.server.clone(), build).await
}
