//! vlnav-gateway: MissionService and FleetService on their own port (default
//! 50051), with the stage services elsewhere.

use clap::Parser;
use vlnav_gateway::{GatewayOptions, api::Gateway};
use vlnav_runtime::{ServerConfig, ports};

#[derive(Parser)]
#[command(
    name = "vlnav-gateway",
    version,
    about = "Mission and fleet gateway: plans instructions and runs them on attached robots through the stage services"
)]
struct Cli {
    #[command(flatten)]
    gateway: GatewayOptions,
    #[command(flatten)]
    server: ServerConfig,
}

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    let addr = cli.server.listen_addr(ports::GATEWAY);
    if cli.gateway.tokens_file.is_none() && !addr.ip().is_loopback() {
        if !cli.server.insecure {
            anyhow::bail!(
                "refusing to serve {addr} without bearer tokens: give --tokens-file (VLNAV_TOKENS_FILE; \
                 docs/security.md), listen on a loopback address, or pass --insecure to let anyone who reaches \
                 {addr} submit missions"
            );
        }
        eprintln!("vlnav-gateway: INSECURE: no bearer tokens on {addr}; anyone who reaches it can submit missions");
    }
    let server = Gateway::server_config(&cli.server);
    // Kept to close it after serving: its recordings are finished on shutdown.
    let kept = std::sync::Arc::new(std::sync::Mutex::new(None));
    let keep = kept.clone();
    let build = async move {
        let gateway = Gateway::new(&cli.gateway)?;
        let services = gateway.services(&ServerConfig::default());
        *keep.lock().unwrap_or_else(|p| p.into_inner()) = Some(gateway);
        Ok(services)
    };
    let result = vlnav_runtime::serve_main("vlnav-gateway", ports::GATEWAY, server, build).await;
    let gateway = kept.lock().unwrap_or_else(|p| p.into_inner()).take();
    if let Some(gateway) = gateway {
        gateway.close().await;
    }
    result
}
