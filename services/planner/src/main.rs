//! vlnav-planner: the PlannerService on its own port (default 50053).

use clap::Parser;

#[derive(Parser)]
#[command(
    name = "vlnav-planner",
    about = "Instruction to a validated action plan (rules, OpenAI-compatible, GGUF) over gRPC"
)]
struct Cli {
    #[command(flatten)]
    planner: vlnav_planner::Options,
    #[command(flatten)]
    server: vlnav_runtime::ServerConfig,
}

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    let build = vlnav_planner::services(&cli.planner, &cli.server);
    vlnav_runtime::serve_main("vlnav-planner", vlnav_planner::DEFAULT_PORT, cli.server.clone(), build).await
}
