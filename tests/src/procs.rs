//! The deployment's binaries as separate processes on loopback: the seven
//! stage servers and the gateway, each on a free port, plaintext (loopback
//! needs no `--insecure`), with a supervisor that kills one with SIGKILL and
//! starts it again on the same port (the gateway with the same data
//! directory). Children are killed when the [`ProcStack`] is dropped, and
//! also (Linux) when the test process dies.

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::OnceLock;
use std::time::Duration;

use anyhow::Context;
use vlnav_proto::v1::{fleet_service_client::FleetServiceClient, mission_service_client::MissionServiceClient};
use vlnav_runtime::client::{TracedChannel, channel_with};
use vlnav_runtime::security::ClientSecurity;

use crate::proxy::Proxy;

/// The stage servers, in the order they start.
pub const STAGES: [&str; 7] = ["ingress", "planner", "detector", "reid", "segmenter", "subgoal", "local-planner"];

/// The gateway's name among the processes.
pub const GATEWAY: &str = "gateway";

/// The simulation perception backends, as `vlnav up --perception` sets them
/// (`vlnav::up::apply_perception`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Perception {
    /// Every visible instance, exact boxes, true identities, labelled no-go zones.
    Oracle,
    /// The error model measured on the shipped networks; colour segmentation.
    Realistic,
}

impl Perception {
    fn flags(self, stage: &str) -> Vec<String> {
        let f = |a: &[&str]| a.iter().map(|s| s.to_string()).collect();
        match (self, stage) {
            (Perception::Oracle, "detector") => f(&["--detector-backend", "sim", "--detector-sim-profile", "oracle"]),
            (Perception::Oracle, "reid") => f(&["--reid-backend", "sim", "--reid-sim-profile", "oracle"]),
            (Perception::Oracle, "segmenter") => f(&["--segmenter-backend", "sim"]),
            (Perception::Realistic, "detector") => {
                f(&["--detector-backend", "sim", "--detector-sim-profile", "nanodet"])
            }
            (Perception::Realistic, "reid") => f(&["--reid-backend", "sim", "--reid-sim-profile", "nanodet"]),
            (Perception::Realistic, "segmenter") => f(&["--segmenter-backend", "colour"]),
            _ => Vec::new(),
        }
    }
}

/// The executable of `name`'s server (`vlnav-<name>`).
pub fn binary_name(name: &str) -> String {
    format!("vlnav-{name}")
}

/// `target/<profile>/`, where cargo puts the workspace's binaries: the
/// parent of the test executable's `deps/` directory.
pub fn target_dir() -> PathBuf {
    let exe = std::env::current_exe().expect("the test executable's path");
    let deps = exe.parent().expect("the test executable sits in a directory");
    if deps.file_name().is_some_and(|n| n == "deps") { deps.parent().unwrap_or(deps) } else { deps }.to_path_buf()
}

/// Every binary a deployment runs, as (package, binary): the images hold
/// them all (`deploy/build-images.sh`). Built together, so the process and
/// container tiers share one build (cargo unifies features per build: the
/// servers alone would compile their dependencies a second time).
pub const DEPLOYED: [(&str, &str); 10] = [
    ("vlnav", "vlnav"),
    ("vlnav-gateway", "vlnav-gateway"),
    ("vlnav-ingress", "vlnav-ingress"),
    ("vlnav-planner", "vlnav-planner"),
    ("vlnav-detector", "vlnav-detector"),
    ("vlnav-reid", "vlnav-reid"),
    ("vlnav-segmenter", "vlnav-segmenter"),
    ("vlnav-subgoal", "vlnav-subgoal"),
    ("vlnav-local-planner", "vlnav-local-planner"),
    ("vlnav-edge-agent", "vlnav-edge"),
];

/// Builds the deployment's binaries ([`DEPLOYED`]) once per test process
/// (cargo does nothing when they are up to date) and returns the directory
/// they are in. Set `VLNAV_BIN_DIR` to use binaries built elsewhere instead.
pub fn binaries() -> anyhow::Result<PathBuf> {
    static BUILT: OnceLock<Result<PathBuf, String>> = OnceLock::new();
    BUILT
        .get_or_init(|| {
            if let Some(dir) = std::env::var_os("VLNAV_BIN_DIR") {
                return Ok(PathBuf::from(dir));
            }
            let dir = target_dir();
            let profile = dir.file_name().and_then(|n| n.to_str()).unwrap_or("debug").to_string();
            let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
            let mut cmd = Command::new(cargo);
            cmd.current_dir(crate::repo_root()).arg("build");
            match profile.as_str() {
                "debug" => {}
                "release" => {
                    cmd.arg("--release");
                }
                other => {
                    cmd.args(["--profile", other]);
                }
            }
            for (package, bin) in DEPLOYED {
                cmd.args(["-p", package, "--bin", bin]);
            }
            // The edge agent with its ROS 2 driver, as `make test` builds it (tests/tests/ros2_robot.rs).
            cmd.args(["--features", "vlnav-edge-agent/ros2"]);
            let out = cmd.output().map_err(|e| format!("cannot run cargo: {e}"))?;
            if !out.status.success() {
                return Err(format!("building the servers failed:\n{}", String::from_utf8_lossy(&out.stderr)));
            }
            Ok(dir)
        })
        .clone()
        .map_err(|e| anyhow::anyhow!(e))
}

/// A free loopback port for a server this process starts next.
///
/// A port from `bind(…:0)` is released before the server binds it, and the
/// kernel may hand it out again meanwhile: to another `bind(…:0)`, or as an
/// outgoing connection's source port, since both draw from the ephemeral
/// range. A server restarted on its port leaves the same gap while it is
/// down. So the ports come from below the ephemeral range, where the kernel
/// assigns none by itself, and this process never hands out one port twice.
pub fn free_port() -> u16 {
    use std::sync::Mutex;
    static NEXT: Mutex<Option<u32>> = Mutex::new(None);
    static EPHEMERAL_LOW: OnceLock<u32> = OnceLock::new();
    let ephemeral_low = *EPHEMERAL_LOW.get_or_init(|| {
        std::fs::read_to_string("/proc/sys/net/ipv4/ip_local_port_range")
            .ok()
            .and_then(|s| s.split_whitespace().next()?.parse::<u32>().ok())
            .unwrap_or(32768)
    });
    const LOW: u32 = 10_000;
    if ephemeral_low < LOW + 1_000 {
        // No room below the ephemeral range: the kernel's choice, as before.
        let l = std::net::TcpListener::bind("127.0.0.1:0").expect("bind 127.0.0.1:0");
        return l.local_addr().expect("a bound address").port();
    }
    let span = ephemeral_low - LOW;
    let mut next = NEXT.lock().unwrap_or_else(|e| e.into_inner());
    // Test processes running side by side start far apart.
    let mut candidate = next.unwrap_or_else(|| std::process::id().wrapping_mul(7919) % span);
    for _ in 0..span {
        let port = (LOW + candidate % span) as u16;
        candidate = (candidate + 1) % span;
        if std::net::TcpListener::bind(("127.0.0.1", port)).is_ok() {
            *next = Some(candidate);
            return port;
        }
    }
    panic!("no free loopback port in {LOW}..{ephemeral_low}");
}

/// The gRPC service a server of `name` must report SERVING before it counts
/// as started: a server of another kind on its port does not.
fn service_name(name: &str) -> &'static str {
    use vlnav_proto::v1 as pb;
    match name {
        "ingress" => pb::ingress_service_server::SERVICE_NAME,
        "planner" => pb::planner_service_server::SERVICE_NAME,
        "detector" => pb::detector_service_server::SERVICE_NAME,
        "reid" => pb::reid_service_server::SERVICE_NAME,
        "segmenter" => pb::segmenter_service_server::SERVICE_NAME,
        "subgoal" => pb::subgoal_service_server::SERVICE_NAME,
        "local-planner" => pb::local_planner_service_server::SERVICE_NAME,
        GATEWAY => pb::mission_service_server::SERVICE_NAME,
        _ => "",
    }
}

/// One server process: how to start it, and the running child.
pub struct Service {
    pub name: String,
    pub port: u16,
    program: PathBuf,
    args: Vec<String>,
    env: Vec<(String, String)>,
    log: PathBuf,
    child: Option<Child>,
    /// How many times it was started.
    pub starts: u32,
}

impl Service {
    pub fn addr(&self) -> SocketAddr {
        SocketAddr::from(([127, 0, 0, 1], self.port))
    }

    /// Its process id while running.
    pub fn pid(&self) -> Option<u32> {
        self.child.as_ref().map(|c| c.id())
    }

    fn spawn(&mut self) -> anyhow::Result<()> {
        anyhow::ensure!(self.child.is_none(), "{} is already running", self.name);
        let log = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&self.log)
            .with_context(|| format!("log file {}", self.log.display()))?;
        let mut cmd = Command::new(&self.program);
        cmd.args(&self.args)
            .envs(self.env.iter().map(|(k, v)| (k, v)))
            .stdin(Stdio::null())
            .stdout(log.try_clone()?)
            .stderr(log);
        #[cfg(target_os = "linux")]
        {
            use std::os::unix::process::CommandExt;
            // SAFETY: prctl is async-signal-safe; it only marks the child to
            // get SIGKILL when the thread that started it exits.
            unsafe {
                cmd.pre_exec(|| {
                    libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL);
                    Ok(())
                });
            }
        }
        let child = cmd.spawn().with_context(|| format!("starting {}", self.program.display()))?;
        self.child = Some(child);
        self.starts += 1;
        Ok(())
    }

    /// SIGKILL, then reap it.
    pub fn kill(&mut self) {
        if let Some(mut child) = self.child.take() {
            let _ = child.kill();
            let _ = child.wait();
        }
    }

    /// Whether it has exited on its own (and how).
    fn exited(&mut self) -> Option<std::process::ExitStatus> {
        self.child.as_mut().and_then(|c| c.try_wait().ok().flatten())
    }

    /// The last `lines` lines of its log.
    pub fn log_tail(&self, lines: usize) -> String {
        let text = std::fs::read_to_string(&self.log).unwrap_or_default();
        let all: Vec<&str> = text.lines().collect();
        all[all.len().saturating_sub(lines)..].join("\n")
    }

    /// Waits until it answers its gRPC health check for its own service, and
    /// is still running after: the answer came from this process.
    async fn ready(&mut self, within: Duration) -> anyhow::Result<()> {
        let deadline = tokio::time::Instant::now() + within;
        let uri = format!("http://{}", self.addr());
        loop {
            if let Some(status) = self.exited() {
                self.child = None;
                anyhow::bail!("{} exited ({status}) while starting:\n{}", self.name, self.log_tail(30));
            }
            if let Ok(ch) = channel_with(&uri, &ClientSecurity::none()) {
                let mut health = tonic_health::pb::health_client::HealthClient::new(ch);
                let req = tonic_health::pb::HealthCheckRequest { service: service_name(&self.name).into() };
                if let Ok(Ok(r)) = tokio::time::timeout(Duration::from_secs(2), health.check(req)).await
                    && r.into_inner().status == tonic_health::pb::health_check_response::ServingStatus::Serving as i32
                    && self.exited().is_none()
                {
                    return Ok(());
                }
            }
            if tokio::time::Instant::now() > deadline {
                anyhow::bail!("{} did not become ready within {within:?}:\n{}", self.name, self.log_tail(30));
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    }
}

impl Drop for Service {
    fn drop(&mut self) {
        self.kill();
    }
}

/// How to start a [`ProcStack`].
#[derive(Clone, Debug)]
pub struct StackOptions {
    pub perception: Perception,
    /// Stages the gateway reaches through a [`Proxy`] (see [`ProcStack::proxy`]).
    pub proxied: Vec<&'static str>,
    /// `RUST_LOG` of the servers.
    pub log: String,
    /// More arguments for the gateway (`--stage-timeout-s 2`, …).
    pub gateway_args: Vec<String>,
}

impl Default for StackOptions {
    fn default() -> Self {
        Self { perception: Perception::Oracle, proxied: Vec::new(), log: "warn".into(), gateway_args: Vec::new() }
    }
}

/// Every server of a deployment as its own process.
pub struct ProcStack {
    services: BTreeMap<String, Service>,
    proxies: BTreeMap<String, Proxy>,
    /// Data directories (the gateway's missions, the ReID gallery) and logs.
    pub dir: tempfile::TempDir,
}

impl ProcStack {
    /// Builds the binaries if needed, then starts the stages and the gateway
    /// and waits until each answers its health check.
    pub async fn start(opts: StackOptions) -> anyhow::Result<ProcStack> {
        crate::use_repo_models();
        let bin = binaries()?;
        let dir = tempfile::tempdir()?;
        let models = std::env::var("VLNAV_MODELS_DIR").context("VLNAV_MODELS_DIR")?;
        let mut stack = ProcStack { services: BTreeMap::new(), proxies: BTreeMap::new(), dir };
        let mut gateway_args = Vec::new();
        for name in STAGES {
            let port = free_port();
            let mut args = vec!["--listen".to_string(), format!("127.0.0.1:{port}")];
            args.extend(opts.perception.flags(name));
            if name == "reid" {
                args.extend(["--reid-data-dir".into(), stack.dir.path().join("reid").display().to_string()]);
            }
            let service = stack.service(&bin, name, port, args, &models, &opts.log);
            let upstream = service.addr();
            stack.services.insert(name.to_string(), service);
            let uri = if opts.proxied.contains(&name) {
                let proxy = Proxy::start(upstream).await?;
                let uri = proxy.uri();
                stack.proxies.insert(name.to_string(), proxy);
                uri
            } else {
                format!("http://{upstream}")
            };
            gateway_args.extend([format!("--{name}-uri"), uri]);
        }
        let port = free_port();
        gateway_args.extend([
            "--listen".to_string(),
            format!("127.0.0.1:{port}"),
            "--data-dir".into(),
            stack.dir.path().join("gateway").display().to_string(),
            "--live-view".into(),
            "off".into(),
            "--record".into(),
            "false".into(),
        ]);
        gateway_args.extend(opts.gateway_args.iter().cloned());
        let gateway = stack.service(&bin, GATEWAY, port, gateway_args, &models, &opts.log);
        stack.services.insert(GATEWAY.to_string(), gateway);
        // Start everything, then wait: the stages load their models side by side.
        for s in stack.services.values_mut() {
            s.spawn()?;
        }
        for s in stack.services.values_mut() {
            s.ready(Duration::from_secs(180)).await?;
        }
        Ok(stack)
    }

    fn service(&self, bin: &Path, name: &str, port: u16, args: Vec<String>, models: &str, log: &str) -> Service {
        Service {
            name: name.to_string(),
            port,
            program: bin.join(binary_name(name)),
            args,
            env: vec![
                ("VLNAV_MODELS_DIR".into(), models.to_string()),
                ("RUST_LOG".into(), log.to_string()),
                ("NO_COLOR".into(), "1".into()),
            ],
            log: self.dir.path().join(format!("{name}.log")),
            child: None,
            starts: 0,
        }
    }

    pub fn service_of(&self, name: &str) -> &Service {
        self.services.get(name).unwrap_or_else(|| panic!("no service named {name}"))
    }

    fn service_mut(&mut self, name: &str) -> &mut Service {
        self.services.get_mut(name).unwrap_or_else(|| panic!("no service named {name}"))
    }

    /// The gateway's address.
    pub fn gateway_addr(&self) -> SocketAddr {
        self.service_of(GATEWAY).addr()
    }

    pub fn gateway_uri(&self) -> String {
        format!("http://{}", self.gateway_addr())
    }

    /// The proxy between the gateway and `stage`, when it was asked for.
    pub fn proxy(&self, stage: &str) -> Option<&Proxy> {
        self.proxies.get(stage)
    }

    /// Kills `name` with SIGKILL (no shutdown of any kind) and reaps it.
    pub fn kill(&mut self, name: &str) {
        self.service_mut(name).kill();
    }

    /// Freezes `name` with SIGSTOP: its sockets stay open and the kernel
    /// still accepts bytes for it, but nothing answers, not even HTTP/2
    /// pings; [`ProcStack::thaw`] lets it go on where it stopped.
    pub fn freeze(&self, name: &str) -> anyhow::Result<()> {
        self.signal(name, libc::SIGSTOP)
    }

    /// Lets a frozen `name` run again (SIGCONT).
    pub fn thaw(&self, name: &str) -> anyhow::Result<()> {
        self.signal(name, libc::SIGCONT)
    }

    fn signal(&self, name: &str, signal: libc::c_int) -> anyhow::Result<()> {
        let pid = self.service_of(name).pid().with_context(|| format!("{name} is not running"))?;
        let pid = libc::pid_t::try_from(pid).context("process id")?;
        // SAFETY: kill(2) on a child this stack started and has not reaped.
        if unsafe { libc::kill(pid, signal) } != 0 {
            anyhow::bail!("signal {signal} to {name}: {}", std::io::Error::last_os_error());
        }
        Ok(())
    }

    /// Starts `name` again, same port and arguments, and waits until it is ready.
    pub async fn restart(&mut self, name: &str) -> anyhow::Result<()> {
        let s = self.service_mut(name);
        s.spawn()?;
        s.ready(Duration::from_secs(120)).await
    }

    /// The last lines of every server's log, for a failure message.
    pub fn logs(&self, lines: usize) -> String {
        self.services.values().map(|s| format!("--- {} ---\n{}\n", s.name, s.log_tail(lines))).collect()
    }

    pub fn missions(&self) -> MissionServiceClient<TracedChannel> {
        MissionServiceClient::new(
            channel_with(&self.gateway_uri(), &ClientSecurity::none()).expect("a valid gateway address"),
        )
    }

    pub fn fleet(&self) -> FleetServiceClient<TracedChannel> {
        FleetServiceClient::new(
            channel_with(&self.gateway_uri(), &ClientSecurity::none()).expect("a valid gateway address"),
        )
    }
}
