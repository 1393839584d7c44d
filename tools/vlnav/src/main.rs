//! `vlnav`: the all-in-one runner, the client commands and the evaluation.

use std::net::SocketAddr;

use clap::{Parser, Subcommand};
use tokio::net::TcpListener;
use vlnav::mission::{MissionArgs, run_mission};
use vlnav::up::{UpArgs, up};
use vlnav_runtime::{CancellationToken, ports, telemetry};

use vlnav::CASE_2;

#[derive(Subcommand)]
enum CredentialsCmd {
    /// Certificates (one CA, one per component, one per robot) and tokens
    /// for k8s/base, as Secrets in a kustomization (docs/security.md).
    K8s(vlnav::credentials::K8sCredentialsArgs),
    /// One robot's certificate and key from an existing CA (`vlnav up`'s or
    /// `vlnav credentials k8s`'), and the `vlnav-edge` flags that use them.
    Robot(vlnav::credentials::RobotCredentialsArgs),
    /// Revoke a robot, a component or one certificate: writes
    /// <dir>/revoked.toml, which servers read again within a second
    /// (docs/security.md).
    Revoke(vlnav::credentials::RevokeArgs),
}

#[derive(Subcommand)]
enum WorldsCmd {
    /// Write seeded worlds of a family (or the fixed test set) and a suite
    /// manifest for `vlnav eval --suite DIR/suite.toml`; instructions the
    /// Husky could not carry out on the true map are dropped and counted.
    Generate(vlnav_eval::worlds::GenerateArgs),
}

/// `vlnav eval`: the harness's settings, and the mission executor's of the
/// stack the trials run on (its defaults unless given: an executor setting
/// is measured on the development set this way, docs/evaluation.md).
#[derive(clap::Args)]
struct EvalCmd {
    #[command(flatten)]
    eval: vlnav_eval::EvalArgs,
    #[command(flatten, next_help_heading = "Mission executor")]
    executor: vlnav_gateway::config::ExecutorParams,
}

#[derive(Parser)]
#[command(name = "vlnav", version, about = "Language-driven, map-free navigation for service robots")]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Run every service, the gateway and a simulated Husky in one process (loopback gRPC).
    Up(UpArgs),
    /// Submit an instruction to a running gateway and follow the mission.
    Mission(MissionArgs),
    /// `up`, then the paper's example instruction, then a summary and a latency profile.
    Demo {
        /// What to tell the robot.
        #[arg(long, default_value = CASE_2)]
        instruction: String,
        #[command(flatten)]
        up: UpArgs,
    },
    /// Run the evaluation suite in lockstep simulation through the real services.
    Eval(EvalCmd),
    /// Generated worlds: `vlnav worlds generate --family hall --count 20 --seed 0 --out DIR`.
    #[command(subcommand)]
    Worlds(WorldsCmd),
    /// Issue and revoke credentials: `vlnav credentials k8s` writes the
    /// Secrets of a Kubernetes deployment (certificates for every component,
    /// tokens); `vlnav credentials robot` issues one robot's certificate;
    /// `vlnav credentials revoke` refuses a robot or component.
    #[command(subcommand)]
    Credentials(CredentialsCmd),
    /// Feed a mission recording's frames through a fresh gateway and stages
    /// and report where the commands differ from the recorded ones.
    Replay(vlnav::replay::ReplayArgs),
    /// Per-stage latency of a mission from its distributed trace.
    Profile(vlnav_traces::ProfileArgs),
    /// Benchmarks: `vlnav bench fleet` (robots per gateway), `vlnav bench plot`,
    /// `vlnav bench jpeg` (what JPEG colour costs the perception).
    #[command(subcommand)]
    Bench(vlnav::bench::BenchCmd),
    /// Run a detector on photos: one line per box (or JSON), annotated copies with --out.
    Detect(vlnav_detector::cli::DetectArgs),
    /// Measure the perception error model on the real NanoDet and MobileNetV2
    /// (real photos, scaled, cut and pasted) and write the profile.
    CalibratePerception(vlnav_eval::calibrate::CalibrateArgs),
}

/// Starts the built-in OTLP trace receiver (unless an endpoint is configured)
/// and points this process's exporter at it: over mutual TLS with the
/// stack's development PKI unless `insecure` (docs/security.md).
async fn trace_receiver(args: &UpArgs, token: &CancellationToken) -> anyhow::Result<()> {
    let (data_dir, ephemeral) = (&args.data_dir, args.ephemeral_ports);
    if telemetry::otlp_endpoint().is_some() {
        return Ok(());
    }
    let addr = SocketAddr::from(([127, 0, 0, 1], if ephemeral { 0 } else { ports::TRACE_RECEIVER }));
    let listener = match TcpListener::bind(addr).await {
        Ok(l) => l,
        Err(_) => TcpListener::bind(SocketAddr::from(([127, 0, 0, 1], 0))).await?,
    };
    let (endpoint, tls) = if args.insecure {
        (format!("http://{}", listener.local_addr()?), None)
    } else {
        let names = vlnav::up::server_names(args)?;
        let pki = vlnav_runtime::security::DevPki::ensure_named(&data_dir.join("security"), &[], &names)?;
        let vars = [
            ("OTEL_EXPORTER_OTLP_CERTIFICATE", pki.ca()),
            ("OTEL_EXPORTER_OTLP_CLIENT_CERTIFICATE", pki.gateway_cert()),
            ("OTEL_EXPORTER_OTLP_CLIENT_KEY", pki.gateway_key()),
        ];
        for (k, v) in vars {
            // SAFETY: set before any other thread reads the environment (telemetry is not yet initialised).
            unsafe { std::env::set_var(k, v) };
        }
        (format!("https://{}", listener.local_addr()?), pki.server_args().load(false)?)
    };
    serve_spans(listener, &endpoint, &data_dir.join("traces"), tls, token)
}

/// Serves OTLP on `listener` into a span store at `dir` until `token` is
/// cancelled, and points this process's exporter at `endpoint`, the
/// listener's address. Call before telemetry is initialised.
fn serve_spans(
    listener: TcpListener,
    endpoint: &str,
    dir: &std::path::Path,
    tls: Option<vlnav_runtime::tls::ServerTls>,
    token: &CancellationToken,
) -> anyhow::Result<()> {
    // SAFETY: set before any other thread reads the environment (telemetry is not yet initialised).
    unsafe { std::env::set_var("OTEL_EXPORTER_OTLP_ENDPOINT", endpoint) };
    let store = std::sync::Arc::new(vlnav_traces::SpanStore::open(dir)?);
    let token = token.clone();
    tokio::spawn(async move {
        if let Err(e) = vlnav_traces::serve_receiver_with(listener, store, tls, token).await {
            tracing::error!("trace receiver stopped: {e}");
        }
    });
    Ok(())
}

/// The trace receiver of `vlnav bench fleet --traces DIR`: plaintext on
/// loopback, in this process, writing to `dir`; this process's exporter
/// points at it.
async fn bench_trace_receiver(dir: &std::path::Path, token: &CancellationToken) -> anyhow::Result<()> {
    if let Some(endpoint) = telemetry::otlp_endpoint() {
        anyhow::bail!(
            "--traces runs its own trace receiver, but OTEL_EXPORTER_OTLP_ENDPOINT is set ({endpoint}): unset it, or drop --traces and profile with your collector"
        );
    }
    let listener = TcpListener::bind(SocketAddr::from(([127, 0, 0, 1], 0))).await?;
    let endpoint = format!("http://{}", listener.local_addr()?);
    serve_spans(listener, &endpoint, dir, None, token)
}

#[tokio::main]
async fn main() {
    if let Err(e) = run(Cli::parse()).await {
        eprintln!("vlnav: {e:#}");
        std::process::exit(1);
    }
}

async fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.cmd {
        Cmd::Up(args) => {
            let receiver = CancellationToken::new();
            trace_receiver(&args, &receiver).await?;
            let telemetry = telemetry::init("vlnav")?;
            let stack = up(&args).await?;
            if stack.dial_addr() == stack.gateway_addr {
                eprintln!("vlnav is up: gateway on {} (Ctrl-C to stop)", stack.gateway_uri());
            } else {
                eprintln!(
                    "vlnav is up: gateway listening on {} (every interface); here dial {}, from another computer \
                     a name in its certificate (Ctrl-C to stop)",
                    stack.gateway_addr,
                    stack.gateway_uri()
                );
            }
            if let Some(addr) = stack.live_view_addr() {
                eprintln!("{}", live_view_hint(addr));
            }
            match &stack.security {
                Some(sec) => eprintln!(
                    "TLS and tokens on every link; credentials in {}\n  vlnav mission \"move 2 m ahead\"    (picks them up)\n  {}\n  \
                     the gateway's certificate names {} (more: --gateway-name); a robot's files: \
                     vlnav credentials robot --id ID --out DIR",
                    sec.pki.dir.display(),
                    sec.grpcurl_hint(stack.dial_addr()),
                    sec.pki.server_names().join(", ")
                ),
                None => eprintln!(
                    "INSECURE: plaintext and no tokens (--insecure); anyone who reaches {} can drive the robot",
                    stack.gateway_addr
                ),
            }
            let token = stack.token();
            tokio::spawn(async move {
                vlnav_runtime::shutdown_signal().await;
                token.cancel();
            });
            let result = stack.wait().await;
            drop(telemetry);
            receiver.cancel();
            result
        }
        Cmd::Mission(args) => {
            let mission = run_mission(&args, &mut std::io::stdout()).await?;
            let ok = matches!(mission.state, 4 | 7);
            if !ok {
                std::process::exit(2);
            }
            Ok(())
        }
        Cmd::Demo { instruction, up: args } => {
            let receiver = CancellationToken::new();
            trace_receiver(&args, &receiver).await?;
            let telemetry = telemetry::init("vlnav")?;
            let stack = up(&args).await?;
            if let Some(addr) = stack.live_view_addr() {
                eprintln!("{}", live_view_hint(addr));
            }
            let mission_args = MissionArgs {
                text: Some(instruction),
                audio: None,
                robot: args.robot_id.clone(),
                gateway: stack.gateway_uri(),
                caller: vlnav_runtime::security::CallerArgs {
                    credentials_dir: args.data_dir.join("security"),
                    ..Default::default()
                },
                dry_run: false,
                // Nobody answers a demo's questions.
                stop_on_question: true,
            };
            wait_for_robot(&stack.gateway_uri(), &stack.operator()?, &args.robot_id).await?;
            let mission = run_mission(&mission_args, &mut std::io::stdout()).await;
            telemetry.flush();
            // Give the batch exporter a moment to deliver the last spans.
            tokio::time::sleep(std::time::Duration::from_millis(600)).await;
            if let Ok(m) = &mission {
                let source = vlnav_traces::SpanSource::Dir(args.data_dir.join("traces"));
                match vlnav_traces::cli::profile_trace(&source, &m.trace_id, vlnav_traces::CONTROL_CYCLE).await {
                    Ok(report) => println!("\n{report}"),
                    Err(e) => eprintln!("(no latency profile: {e})"),
                }
            }
            stack.shutdown().await?;
            // Exporters flush on drop: before their receiver goes away.
            drop(telemetry);
            receiver.cancel();
            let mission = mission?;
            if mission.state != vlnav_proto::v1::MissionState::Succeeded as i32 {
                anyhow::bail!("the demo mission did not succeed: {}", mission.reason);
            }
            Ok(())
        }
        Cmd::Eval(EvalCmd { eval: mut args, executor }) => {
            args.executor_flags = executor.changed_flags();
            let _telemetry = telemetry::init("vlnav")?;
            let data = args.out.join("gateway");
            let up_args = UpArgs {
                no_robot: true,
                ephemeral_ports: true,
                data_dir: data,
                perception: args.perception,
                executor,
                ..UpArgs::default()
            };
            let stack = up(&up_args).await?;
            let target = vlnav_eval::Target {
                gateway_uri: stack.gateway_uri(),
                caller: stack.operator()?,
                pki: stack.security.as_ref().map(|s| s.pki.clone()),
            };
            let report = vlnav_eval::run_eval(args, target).await;
            stack.shutdown().await?;
            report.map(|_| ())
        }
        Cmd::Worlds(WorldsCmd::Generate(args)) => {
            print!("{}", vlnav_eval::worlds::run_generate(&args)?);
            Ok(())
        }
        Cmd::Credentials(CredentialsCmd::K8s(args)) => {
            let dir = vlnav::credentials::write_k8s(&args)?;
            eprintln!("{}", vlnav::credentials::next_steps(&args, &dir));
            Ok(())
        }
        Cmd::Credentials(CredentialsCmd::Robot(args)) => {
            let (_, report) = vlnav::credentials::issue_robot(&args)?;
            println!("{report}");
            Ok(())
        }
        Cmd::Credentials(CredentialsCmd::Revoke(args)) => {
            eprintln!("{}", vlnav::credentials::revoke(&args)?);
            Ok(())
        }
        Cmd::Replay(args) => {
            let report = vlnav::replay::replay(&args).await?;
            if args.json {
                println!("{}", serde_json::to_string(&report)?);
            } else {
                println!("{report}");
            }
            if !report.identical() {
                std::process::exit(3);
            }
            Ok(())
        }
        Cmd::Profile(args) => {
            println!("{}", vlnav_traces::run_profile(args).await?);
            Ok(())
        }
        Cmd::Bench(vlnav::bench::BenchCmd::Fleet(args)) => {
            let receiver = CancellationToken::new();
            if let Some(dir) = &args.traces {
                bench_trace_receiver(dir, &receiver).await?;
            }
            let telemetry = telemetry::init("vlnav")?;
            let result = vlnav::bench::fleet(&args, &mut std::io::stdout()).await.map(|_| ());
            // Exporters flush on drop: before their receiver goes away.
            drop(telemetry);
            receiver.cancel();
            result
        }
        Cmd::Bench(vlnav::bench::BenchCmd::Plot(args)) => vlnav::bench::plot(&args),
        Cmd::Bench(vlnav::bench::BenchCmd::Jpeg(args)) => {
            tokio::task::spawn_blocking(move || vlnav_eval::jpeg_cost::run(&args, &mut std::io::stdout())).await??;
            Ok(())
        }
        Cmd::Bench(vlnav::bench::BenchCmd::Robots(args)) => {
            // Each real robot has its own computer. Here they share two cores,
            // so many worker threads let the OS preempt a robot's rendering
            // when another robot's command arrives, instead of the command
            // waiting for a worker (which the benchmark would count as latency).
            tokio::task::spawn_blocking(move || {
                let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(16).enable_all().build()?;
                rt.block_on(vlnav::bench::robots(&args))
            })
            .await?
        }
        Cmd::Detect(args) => {
            tokio::task::spawn_blocking(move || vlnav_detector::cli::run_detect(&args, &mut std::io::stdout()))
                .await??;
            Ok(())
        }
        Cmd::CalibratePerception(args) => {
            let summary = tokio::task::spawn_blocking(move || vlnav_eval::calibrate::run(&args)).await??;
            print!("{summary}");
            Ok(())
        }
    }
}

/// How to open the live view.
fn live_view_hint(addr: std::net::SocketAddr) -> String {
    format!(
        "live view: ws://{addr} — in Foxglove or Lichtblick, Open connection → Foxglove WebSocket → ws://{addr}, \
         then import the layout deploy/foxglove/vlnav-layout.json (docs/observability.md)"
    )
}

/// Waits (up to 30 s) until the robot has attached to the gateway.
async fn wait_for_robot(
    gateway: &str,
    security: &vlnav_runtime::security::ClientSecurity,
    robot_id: &str,
) -> anyhow::Result<()> {
    use vlnav_proto::v1::{ListRobotsRequest, fleet_service_client::FleetServiceClient};
    let mut client = FleetServiceClient::new(vlnav_runtime::client::channel_with(gateway, security)?);
    for _ in 0..300 {
        let robots = client.list_robots(ListRobotsRequest {}).await?.into_inner().robots;
        if robots.iter().any(|r| r.robot_id == robot_id && r.connected && r.frames_received > 0) {
            return Ok(());
        }
        tokio::time::sleep(std::time::Duration::from_millis(100)).await;
    }
    anyhow::bail!("robot {robot_id} did not attach within 30 s")
}
