//! `vlnav-edge`: one robot's edge agent (sim or ROS 1 driver).

use clap::Parser;

#[derive(Parser, Debug)]
#[command(
    name = "vlnav-edge",
    about = "Fleet edge agent: streams a robot's sensors to the vlnav gateway and applies its velocity commands behind a local deadman"
)]
struct Cli {
    #[command(flatten)]
    edge: vlnav_edge_agent::EdgeOptions,
}

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    let telemetry = vlnav_runtime::telemetry::init("vlnav-edge")?;
    let shutdown = vlnav_runtime::CancellationToken::new();
    let trigger = shutdown.clone();
    tokio::spawn(async move {
        vlnav_runtime::shutdown_signal().await;
        trigger.cancel();
    });
    let hooks = vlnav_edge_agent::Hooks::default();
    vlnav_edge_agent::spawn_estop_signals(hooks.estop.clone(), shutdown.clone());
    let result = vlnav_edge_agent::run_with(cli.edge, shutdown, hooks).await;
    telemetry.flush();
    result
}
