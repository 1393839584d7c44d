//! `vlnav up`: every stage service and the gateway in one process, each on
//! its own loopback port and talking real gRPC to the others, plus a
//! simulated Husky attached through the edge agent.

use std::net::SocketAddr;
use std::path::PathBuf;

use tokio::net::TcpListener;
use tokio::task::JoinSet;
use vlnav_runtime::perception::PerceptionMode;
use vlnav_runtime::security::{ClientSecurity, ClientTlsArgs, DevPki, read_token};
use vlnav_runtime::{CancellationToken, ServerConfig, ServiceSet, ports};

use vlnav_gateway::api::Gateway;
use vlnav_gateway::config::{GatewayOptions, StagePorts};

#[derive(clap::Args, Clone, Debug)]
pub struct UpArgs {
    /// Where the gateway listens.
    #[arg(long, default_value = "127.0.0.1:50051")]
    pub listen: SocketAddr,
    /// A DNS name or IP address robots and clients on the network dial the
    /// gateway by, put in the development server certificate besides
    /// localhost, 127.0.0.1 and ::1 (an existing certificate lacking one is
    /// issued again from the same CA); repeatable. A --listen address that is
    /// neither loopback nor 0.0.0.0 is added by itself.
    #[arg(long = "gateway-name", value_name = "NAME")]
    pub gateway_names: Vec<String>,
    /// Put every server on a free port chosen by the OS (for tests and side-by-side stacks).
    #[arg(long)]
    pub ephemeral_ports: bool,
    /// Do not attach the simulated robot.
    #[arg(long)]
    pub no_robot: bool,
    #[arg(long, default_value = "husky-1")]
    pub robot_id: String,
    /// Scenario of the simulated robot: a shipped name (demo, lab) or a TOML path.
    #[arg(long, default_value = "demo")]
    pub scenario: String,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Run the simulated robot on the wall clock instead of in lockstep (in
    /// lockstep its world stands still while no mission drives it).
    #[arg(long)]
    pub realtime: bool,
    /// Perception of the simulated robot's frames: `realistic` (the detector
    /// and ReID error model measured on the real networks, the real colour +
    /// depth segmenter), `oracle` (ground truth from the label images, an
    /// upper bound) or `neural` (the real NanoDet, MobileNetV2 and segmenter).
    #[arg(long, env = "VLNAV_PERCEPTION", value_enum, default_value_t = PerceptionMode::Realistic)]
    pub perception: PerceptionMode,
    /// Where missions (and the built-in trace receiver's spans) persist.
    /// The development CA, certificates and tokens live in its `security/`.
    #[arg(long, env = "VLNAV_DATA_DIR", default_value = ".vlnav")]
    pub data_dir: PathBuf,
    /// Plaintext gRPC and no tokens on every link (docs/security.md). Anyone
    /// who reaches the gateway can then drive the robot.
    #[arg(long, env = "VLNAV_INSECURE")]
    pub insecure: bool,
    /// Where the live view (Foxglove WebSocket protocol; open it in Foxglove
    /// or Lichtblick with deploy/foxglove/vlnav-layout.json) listens, or `off`.
    /// Loopback only (docs/observability.md).
    #[arg(long, env = "VLNAV_LIVE_VIEW", default_value = "127.0.0.1:8765")]
    pub live_view: String,
    /// Record every mission to MCAP in `<data-dir>/recordings`.
    #[arg(long, env = "VLNAV_RECORD", default_value_t = true, action = clap::ArgAction::Set)]
    pub record: bool,
    /// Missions one caller may submit a minute, after a burst of 20
    /// (docs/architecture.md, "Overload"); 0: no limit.
    #[arg(long, env = "VLNAV_SUBMIT_PER_MINUTE", default_value_t = 60)]
    pub submit_per_minute: u32,
    #[command(flatten)]
    pub executor: vlnav_gateway::config::ExecutorParams,
}

impl Default for UpArgs {
    fn default() -> Self {
        Self {
            listen: SocketAddr::from(([127, 0, 0, 1], ports::GATEWAY)),
            gateway_names: Vec::new(),
            ephemeral_ports: false,
            no_robot: false,
            robot_id: "husky-1".into(),
            scenario: "demo".into(),
            seed: 1,
            realtime: false,
            perception: PerceptionMode::Realistic,
            data_dir: PathBuf::from(".vlnav"),
            insecure: false,
            // Tests and the evaluation opt in; the command line's defaults serve and record.
            live_view: "off".into(),
            record: false,
            // The evaluation and the tests submit as fast as missions end.
            submit_per_minute: 0,
            executor: Default::default(),
        }
    }
}

type BuildFuture = futures::future::BoxFuture<'static, anyhow::Result<ServiceSet>>;
type Builder = Box<dyn Fn() -> BuildFuture + Send + Sync>;

/// One stage server of the stack, restartable on its port.
struct StageServer {
    addr: SocketAddr,
    build: Builder,
    token: CancellationToken,
}

/// The development credentials of a stack (docs/security.md): a CA, the
/// servers' and the gateway's certificates, one per robot, and tokens.
#[derive(Clone, Debug)]
pub struct StackSecurity {
    pub pki: DevPki,
    pub tokens_file: PathBuf,
    pub operator_token: String,
    pub viewer_token: String,
}

impl StackSecurity {
    /// Opens (first time: creates) the credentials in `dir`.
    pub fn ensure(dir: &std::path::Path, robots: &[&str]) -> anyhow::Result<Self> {
        Self::ensure_named(dir, robots, &[])
    }

    /// As [`StackSecurity::ensure`], the server certificate also naming
    /// `server_names` (issued again when it lacks one).
    pub fn ensure_named(dir: &std::path::Path, robots: &[&str], server_names: &[String]) -> anyhow::Result<Self> {
        let pki = DevPki::ensure_named(dir, robots, server_names)?;
        let tokens_file = vlnav_gateway::auth::ensure_dev_tokens(dir)?;
        Ok(Self {
            operator_token: read_token(&dir.join("operator.token"))?,
            viewer_token: read_token(&dir.join("viewer.token"))?,
            pki,
            tokens_file,
        })
    }

    /// What an operator's client brings: the CA and the operator token.
    pub fn operator(&self) -> anyhow::Result<ClientSecurity> {
        Ok(ClientSecurity::new(self.pki.client_args(None).load()?, Some(self.operator_token.clone())))
    }

    /// Edge-agent TLS of robot `robot_id` (its certificate issued if new).
    pub fn robot(&self, robot_id: &str) -> anyhow::Result<ClientTlsArgs> {
        self.pki.ensure_robot(robot_id)?;
        Ok(self.pki.client_args(Some((self.pki.robot_cert(robot_id), self.pki.robot_key(robot_id)))))
    }

    /// How to call the gateway at `addr` with grpcurl.
    pub fn grpcurl_hint(&self, addr: SocketAddr) -> String {
        format!(
            "grpcurl -cacert {} -H \"authorization: Bearer $(cat {})\" {addr} list vlnav.v1.MissionService",
            self.pki.ca().display(),
            self.pki.dir.join("operator.token").display()
        )
    }
}

/// `addr` with the unspecified IP (`0.0.0.0`, `::`) replaced by loopback of
/// the same family: an address a client on this computer can dial and a
/// development certificate names.
pub fn dialable(addr: SocketAddr) -> SocketAddr {
    let ip = match addr.ip() {
        std::net::IpAddr::V4(ip) if ip.is_unspecified() => std::net::IpAddr::V4(std::net::Ipv4Addr::LOCALHOST),
        std::net::IpAddr::V6(ip) if ip.is_unspecified() => std::net::IpAddr::V6(std::net::Ipv6Addr::LOCALHOST),
        ip => ip,
    };
    SocketAddr::new(ip, addr.port())
}

/// A running stack. Dropping it does not stop it; call [`Stack::shutdown`].
pub struct Stack {
    pub gateway_addr: SocketAddr,
    /// `None` when started with `--insecure`.
    pub security: Option<StackSecurity>,
    pub ports: StagePorts,
    pub gateway: Gateway,
    token: CancellationToken,
    tasks: JoinSet<anyhow::Result<()>>,
    stages: std::collections::HashMap<&'static str, StageServer>,
    cfg: ServerConfig,
}

impl Stack {
    /// Where the live view listens (`None`: off).
    pub fn live_view_addr(&self) -> Option<SocketAddr> {
        self.gateway.live_view_addr()
    }

    /// Where a client on this computer dials the gateway: its address, or
    /// loopback where it listens on every interface (`--listen 0.0.0.0:…`),
    /// since no certificate names the unspecified address.
    pub fn dial_addr(&self) -> SocketAddr {
        dialable(self.gateway_addr)
    }

    pub fn gateway_uri(&self) -> String {
        let scheme = if self.security.is_some() { "https" } else { "http" };
        format!("{scheme}://{}", self.dial_addr())
    }

    /// What an operator's client brings to this stack (nothing when insecure).
    pub fn operator(&self) -> anyhow::Result<ClientSecurity> {
        match &self.security {
            Some(s) => s.operator(),
            None => Ok(ClientSecurity::none()),
        }
    }

    pub fn token(&self) -> CancellationToken {
        self.token.clone()
    }

    /// Stops one stage server ("planner", "detector", "local-planner", …),
    /// as if its process died: in-flight calls drain, new ones are refused.
    pub fn stop_stage(&mut self, name: &str) -> anyhow::Result<()> {
        let stage = self.stages.get_mut(name).ok_or_else(|| anyhow::anyhow!("no stage named {name}"))?;
        stage.token.cancel();
        Ok(())
    }

    /// Starts a stopped stage server again on its old port.
    pub async fn restart_stage(&mut self, name: &str) -> anyhow::Result<()> {
        let stage = self.stages.get_mut(name).ok_or_else(|| anyhow::anyhow!("no stage named {name}"))?;
        let set = (stage.build)().await?;
        let mut listener = None;
        for _ in 0..50 {
            match TcpListener::bind(stage.addr).await {
                Ok(l) => {
                    listener = Some(l);
                    break;
                }
                Err(_) => tokio::time::sleep(std::time::Duration::from_millis(100)).await,
            }
        }
        let listener = listener.ok_or_else(|| anyhow::anyhow!("cannot listen on {} again", stage.addr))?;
        stage.token = self.token.child_token();
        spawn_server(&mut self.tasks, &self.cfg, listener, set, &stage.token);
        Ok(())
    }

    /// Stops every server (draining in-flight calls) and the robot.
    pub async fn shutdown(mut self) -> anyhow::Result<()> {
        self.token.cancel();
        while let Some(r) = self.tasks.join_next().await {
            r??;
        }
        self.gateway.close().await;
        Ok(())
    }

    /// Waits until a server fails or the token is cancelled.
    /// The gateway is closed either way (its recordings finished).
    pub async fn wait(mut self) -> anyhow::Result<()> {
        let mut result = Ok(());
        while let Some(r) = self.tasks.join_next().await {
            match r {
                Ok(Ok(())) => {}
                Ok(Err(e)) => {
                    result = Err(e);
                    break;
                }
                Err(e) => {
                    result = Err(e.into());
                    break;
                }
            }
        }
        self.token.cancel();
        self.gateway.close().await;
        result
    }
}

/// Defaults of a service's options, with its environment variables applied.
pub fn options_from_env<T: clap::Args + clap::FromArgMatches>() -> anyhow::Result<T> {
    let cmd = T::augment_args(clap::Command::new("vlnav").no_binary_name(true));
    let matches = cmd.try_get_matches_from(std::iter::empty::<String>())?;
    Ok(T::from_arg_matches(&matches)?)
}

async fn bind(ephemeral: bool, port: u16) -> anyhow::Result<TcpListener> {
    let addr = SocketAddr::from(([127, 0, 0, 1], if ephemeral { 0 } else { port }));
    TcpListener::bind(addr)
        .await
        .map_err(|e| anyhow::anyhow!("cannot listen on {addr}: {e} (is another `vlnav up` running?)"))
}

fn spawn_server(
    tasks: &mut JoinSet<anyhow::Result<()>>,
    cfg: &ServerConfig,
    listener: TcpListener,
    set: ServiceSet,
    token: &CancellationToken,
) {
    let cfg = cfg.clone();
    let token = token.clone();
    tasks.spawn(async move { vlnav_runtime::serve(&cfg, listener, set, token).await });
}

/// Wraps a service's `services(&Options, &ServerConfig)` as a rebuildable stage.
macro_rules! stage {
    ($krate:ident, $opts:expr, $cfg:expr) => {{
        let opts = std::sync::Arc::new($opts);
        let cfg = $cfg.clone();
        Box::new(move || {
            let opts = opts.clone();
            let cfg = cfg.clone();
            Box::pin(async move { $krate::services(&opts, &cfg).await }) as BuildFuture
        }) as Builder
    }};
}

/// Sets the perception stages' backends for `mode`. Realistic keeps a sim
/// profile given in the environment (`VLNAV_DETECTOR_SIM_PROFILE`,
/// `VLNAV_REID_SIM_PROFILE`) unless it says `oracle`.
pub fn apply_perception(
    mode: PerceptionMode,
    detector: &mut vlnav_detector::Options,
    reid: &mut vlnav_reid::Options,
    segmenter: &mut vlnav_segmenter::Options,
) {
    match mode {
        PerceptionMode::Oracle => {
            detector.backend = vlnav_detector::BackendKind::Sim;
            detector.sim_profile = "oracle".into();
            reid.backend = "sim".into();
            reid.sim_profile = "oracle".into();
            segmenter.backend = "sim".into();
        }
        PerceptionMode::Realistic => {
            detector.backend = vlnav_detector::BackendKind::Sim;
            if detector.sim_profile == "oracle" {
                detector.sim_profile = "nanodet".into();
            }
            reid.backend = "sim".into();
            if reid.sim_profile == "oracle" {
                reid.sim_profile = "nanodet".into();
            }
            segmenter.backend = "colour".into();
        }
        PerceptionMode::Neural => {
            detector.backend = vlnav_detector::BackendKind::Nanodet;
            if reid.backend == "sim" {
                reid.backend = "mobilenetv2".into();
            }
            segmenter.backend = "colour".into();
        }
    }
}

/// The names besides loopback the development server certificate must
/// carry: every `--gateway-name`, and the `--listen` address when it is a
/// specific address of the network. Refused with `--insecure` (no
/// certificate) and when a name cannot be one.
pub fn server_names(args: &UpArgs) -> anyhow::Result<Vec<String>> {
    if args.insecure && !args.gateway_names.is_empty() {
        anyhow::bail!(
            "--gateway-name puts a name in the gateway's TLS certificate, and --insecure serves no TLS: drop one of the two"
        );
    }
    let mut names = Vec::new();
    for name in &args.gateway_names {
        vlnav_runtime::security::check_server_name(name).map_err(|e| anyhow::anyhow!("--gateway-name {e}"))?;
        names.push(name.clone());
    }
    let ip = args.listen.ip();
    if !ip.is_loopback() && !ip.is_unspecified() {
        names.push(ip.to_string());
    }
    Ok(names)
}

/// Starts the stack. Telemetry must already be initialised.
pub async fn up(args: &UpArgs) -> anyhow::Result<Stack> {
    let token = CancellationToken::new();
    let mut tasks = JoinSet::new();
    let names = server_names(args)?;
    let security = if args.insecure {
        if !args.listen.ip().is_loopback() {
            tracing::warn!(listen = %args.listen, "--insecure on a non-loopback address: anyone who reaches it can drive the robot");
        }
        None
    } else {
        Some(StackSecurity::ensure_named(&args.data_dir.join("security"), &[&args.robot_id], &names)?)
    };
    let mut cfg = ServerConfig { insecure: args.insecure, ..ServerConfig::default() };
    if let Some(sec) = &security {
        cfg.tls = sec.pki.server_args();
    }
    let eph = args.ephemeral_ports;
    let mut detector: vlnav_detector::Options = options_from_env()?;
    let mut reid: vlnav_reid::Options = options_from_env()?;
    let mut segmenter: vlnav_segmenter::Options = options_from_env()?;
    apply_perception(args.perception, &mut detector, &mut reid, &mut segmenter);
    reid.data_dir = args.data_dir.join("reid");
    let builders: Vec<(&'static str, u16, Builder)> = vec![
        ("ingress", ports::INGRESS, stage!(vlnav_ingress, options_from_env::<vlnav_ingress::Options>()?, cfg)),
        ("planner", ports::PLANNER, stage!(vlnav_planner, options_from_env::<vlnav_planner::Options>()?, cfg)),
        ("detector", ports::DETECTOR, stage!(vlnav_detector, detector, cfg)),
        ("reid", ports::REID, stage!(vlnav_reid, reid, cfg)),
        ("segmenter", ports::SEGMENTER, stage!(vlnav_segmenter, segmenter, cfg)),
        ("subgoal", ports::SUBGOAL, stage!(vlnav_subgoal, options_from_env::<vlnav_subgoal::Options>()?, cfg)),
        (
            "local-planner",
            ports::LOCAL_PLANNER,
            stage!(vlnav_local_planner, options_from_env::<vlnav_local_planner::Options>()?, cfg),
        ),
    ];
    let mut stages = std::collections::HashMap::new();
    let mut port_of = std::collections::HashMap::new();
    for (name, port, build) in builders {
        let listener = bind(eph, port).await?;
        let addr = listener.local_addr()?;
        let set = build().await.map_err(|e| anyhow::anyhow!("{name}: {e:#}"))?;
        let stage_token = token.child_token();
        spawn_server(&mut tasks, &cfg, listener, set, &stage_token);
        port_of.insert(name, addr.port());
        stages.insert(name, StageServer { addr, build, token: stage_token });
    }
    let stage_ports = StagePorts {
        ingress: port_of["ingress"],
        planner: port_of["planner"],
        detector: port_of["detector"],
        reid: port_of["reid"],
        segmenter: port_of["segmenter"],
        subgoal: port_of["subgoal"],
        local_planner: port_of["local-planner"],
    };

    let mut opts = GatewayOptions::loopback(&stage_ports, args.data_dir.clone());
    opts.view.live_view = args.live_view.clone();
    opts.view.record = args.record;
    opts.view.metadata = vec![
        ("perception".into(), args.perception.as_str().into()),
        ("scenario".into(), args.scenario.clone()),
        ("seed".into(), args.seed.to_string()),
    ];
    opts.executor = args.executor.clone();
    opts.submit_per_minute = args.submit_per_minute;
    let gateway_cfg = Gateway::server_config(&cfg);
    if let Some(sec) = &security {
        opts = opts.over_tls(sec.pki.client_args(Some((sec.pki.gateway_cert(), sec.pki.gateway_key()))));
        opts.tokens_file = Some(sec.tokens_file.clone());
    }
    let gateway = Gateway::new(&opts)?;
    let l_gateway = if eph {
        bind(true, 0).await?
    } else {
        TcpListener::bind(args.listen).await.map_err(|e| anyhow::anyhow!("cannot listen on {}: {e}", args.listen))?
    };
    let gateway_addr = l_gateway.local_addr()?;
    spawn_server(&mut tasks, &gateway_cfg, l_gateway, gateway.services(&gateway_cfg), &token);

    if !args.no_robot {
        let scheme = if security.is_some() { "https" } else { "http" };
        let mut edge = robot_options(args, &format!("{scheme}://{}", dialable(gateway_addr)))?;
        if let Some(sec) = &security {
            edge.tls = sec.robot(&args.robot_id)?;
        }
        let t = token.clone();
        tasks.spawn(async move { vlnav_edge_agent::run(edge, t).await });
    }
    tracing::info!(gateway = %gateway_addr, ?stage_ports, robot = !args.no_robot, "vlnav is up");
    Ok(Stack { gateway_addr, security, ports: stage_ports, gateway, token, tasks, stages, cfg })
}

/// The edge agent settings of the simulated robot.
pub fn robot_options(args: &UpArgs, gateway_uri: &str) -> anyhow::Result<vlnav_edge_agent::EdgeOptions> {
    let mut edge: vlnav_edge_agent::EdgeOptions = options_from_env()?;
    edge.gateway = gateway_uri.to_string();
    edge.robot_id = args.robot_id.clone();
    edge.scenario = args.scenario.clone();
    edge.seed = args.seed;
    edge.lockstep = !args.realtime;
    Ok(edge)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_gateway_on_every_interface_is_dialled_on_loopback() {
        let d = |a: &str| dialable(a.parse().unwrap()).to_string();
        assert_eq!(d("0.0.0.0:50051"), "127.0.0.1:50051");
        assert_eq!(d("[::]:50051"), "[::1]:50051");
        assert_eq!(d("192.168.1.20:50051"), "192.168.1.20:50051");
        assert_eq!(d("127.0.0.2:7"), "127.0.0.2:7");
    }

    #[test]
    fn gateway_names_are_checked_and_a_network_listen_address_is_named_too() {
        let args = |f: &dyn Fn(&mut UpArgs)| {
            let mut a = UpArgs::default();
            f(&mut a);
            a
        };
        assert!(server_names(&args(&|_| {})).unwrap().is_empty());
        let names = server_names(&args(&|a| {
            a.gateway_names = vec!["gw.lab.example".into(), "fd00::7".into()];
            a.listen = "192.168.1.20:50051".parse().unwrap();
        }))
        .unwrap();
        assert_eq!(names, ["gw.lab.example", "fd00::7", "192.168.1.20"]);
        let names = server_names(&args(&|a| a.listen = "0.0.0.0:50051".parse().unwrap())).unwrap();
        assert!(names.is_empty(), "0.0.0.0 is no name: {names:?}");
        let names = server_names(&args(&|a| a.listen = "127.0.0.2:50051".parse().unwrap())).unwrap();
        assert!(names.is_empty(), "loopback is named already: {names:?}");
        let e = server_names(&args(&|a| a.gateway_names = vec!["https://gw:50051".into()])).unwrap_err().to_string();
        assert!(e.starts_with("--gateway-name \"https://gw:50051\"") && e.contains("without a scheme"), "{e}");
        let e = server_names(&args(&|a| {
            a.insecure = true;
            a.gateway_names = vec!["gw".into()];
        }))
        .unwrap_err()
        .to_string();
        assert!(e.contains("--insecure serves no TLS"), "{e}");
    }

    #[tokio::test]
    async fn a_bad_gateway_name_stops_the_start_before_anything_is_written() {
        let data = tempfile::tempdir().unwrap();
        let pki = DevPki::ensure(&data.path().join("security"), &["husky-1"]).unwrap();
        let server = std::fs::read(pki.server_cert()).unwrap();
        let e = up(&UpArgs {
            data_dir: data.path().to_path_buf(),
            gateway_names: vec!["0.0.0.0".into()],
            ..UpArgs::default()
        })
        .await
        .err()
        .expect("0.0.0.0 is refused");
        assert!(e.to_string().contains("--gateway-name \"0.0.0.0\""), "{e}");
        assert_eq!(std::fs::read(pki.server_cert()).unwrap(), server, "the certificate is untouched");
    }
}
