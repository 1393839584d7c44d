//! Harness of the end-to-end tests in `tests/tests/`: a whole vlnav stack on
//! ephemeral loopback ports, and the real command-line clients users run;
//! for the chaos tier, the deployment's binaries as separate processes
//! ([`procs`]), a breakable TCP link ([`proxy`]), a simulated robot driven by
//! the edge agent in this process ([`robot`]) and the measure of how fast it
//! is stopped ([`stops`]); a ROS 2 robot on rclpy in a network namespace of
//! the test's own ([`ros2`]).

pub mod procs;
pub mod proxy;
pub mod robot;
pub mod ros2;
pub mod stops;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use vlnav::up::{Stack, StackSecurity, UpArgs, up};
use vlnav_proto::v1::{
    GetMissionRequest, ListRobotsRequest, Mission, MissionEvent, WatchMissionRequest,
    fleet_service_client::FleetServiceClient, mission_service_client::MissionServiceClient,
};
use vlnav_runtime::client::{TracedChannel, channel_with};
use vlnav_runtime::security::ClientSecurity;

pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("tests/ sits in the repository").to_path_buf()
}

/// A command-line tool installed by `deploy/setup-tools.sh` into `.venv/bin`.
pub fn tool(name: &str) -> PathBuf {
    let path = repo_root().join(".venv/bin").join(name);
    assert!(path.exists(), "{} is missing: run deploy/setup-tools.sh (or `make test`) first", path.display());
    path
}

/// A reader's bash running `script` in `dir`, as someone following the
/// docs has it: the deployment's binaries (`bin`) and grpcurl first on
/// PATH, and none of this machine's `VLNAV_*` variables (the docs set what
/// they need). Used by the tests that run the docs' commands word for word.
pub fn reader_shell(script: &str, dir: &Path, bin: &Path) -> Command {
    let path = format!(
        "{}:{}:{}",
        bin.display(),
        tool("grpcurl").parent().expect(".venv/bin").display(),
        std::env::var("PATH").unwrap_or_default()
    );
    let mut cmd = Command::new("bash");
    for (name, _) in std::env::vars_os() {
        if name.to_string_lossy().starts_with("VLNAV_") {
            cmd.env_remove(name);
        }
    }
    cmd.arg("-c").arg(script).current_dir(dir).env("PATH", path);
    cmd
}

/// Points the services at the repository's models directory unless set.
pub fn use_repo_models() {
    if std::env::var_os("VLNAV_MODELS_DIR").is_none() {
        let dir = repo_root().join("models");
        assert!(
            dir.join("minilm").exists(),
            "models are missing in {}: run deploy/fetch-models.sh (or `make test`) first",
            dir.display()
        );
        // SAFETY: called at the start of a test, before the stack's threads read the environment.
        unsafe { std::env::set_var("VLNAV_MODELS_DIR", dir) };
    }
}

/// A stack on ephemeral ports with its own data directory.
pub struct TestStack {
    pub stack: Stack,
    pub data: tempfile::TempDir,
}

impl TestStack {
    pub async fn start(configure: impl FnOnce(&mut UpArgs)) -> Self {
        use_repo_models();
        let data = tempfile::tempdir().expect("temp dir");
        // Oracle perception unless a test asks for another: these tests check
        // the system's plumbing with a real-time robot, whose course must not
        // hang on whether a simulated detector happened to miss a target
        // (the evaluation tests set `realistic` and run in lockstep).
        let mut args = UpArgs {
            ephemeral_ports: true,
            data_dir: data.path().to_path_buf(),
            perception: vlnav_runtime::perception::PerceptionMode::Oracle,
            ..UpArgs::default()
        };
        configure(&mut args);
        let stack = up(&args).await.expect("the stack starts");
        let t = Self { stack, data };
        if !args.no_robot {
            t.wait_for_robot(&args.robot_id).await;
        }
        t
    }

    /// The gateway's address: https:// unless the stack runs `--insecure`.
    pub fn uri(&self) -> String {
        self.stack.gateway_uri()
    }

    pub fn addr(&self) -> String {
        self.stack.gateway_addr.to_string()
    }

    /// The stack's development credentials (docs/security.md).
    pub fn security(&self) -> &StackSecurity {
        self.stack.security.as_ref().expect("the stack runs with TLS and tokens")
    }

    /// What an operator's client brings (the CA, the operator token).
    pub fn operator(&self) -> ClientSecurity {
        self.stack.operator().expect("the operator's credentials load")
    }

    /// The CA and a bearer `token`.
    pub fn with_token(&self, token: &str) -> ClientSecurity {
        ClientSecurity::new(self.operator().tls, Some(token.to_string()))
    }

    pub async fn missions(&self) -> MissionServiceClient<TracedChannel> {
        self.missions_as(&self.operator())
    }

    pub fn missions_as(&self, security: &ClientSecurity) -> MissionServiceClient<TracedChannel> {
        MissionServiceClient::new(channel_with(&self.uri(), security).expect("a valid gateway address"))
    }

    /// A FleetService client with the operator's token (ListRobots).
    pub fn fleet(&self) -> FleetServiceClient<TracedChannel> {
        FleetServiceClient::new(channel_with(&self.uri(), &self.operator()).expect("a valid gateway address"))
    }

    /// A FleetService client presenting robot `robot_id`'s certificate (issued if new).
    pub fn fleet_as_robot(&self, robot_id: &str) -> FleetServiceClient<TracedChannel> {
        let tls = match &self.stack.security {
            Some(sec) => sec.robot(robot_id).and_then(|a| a.load()).expect("the robot's certificate"),
            None => None,
        };
        let security = ClientSecurity::new(tls, None);
        FleetServiceClient::new(channel_with(&self.uri(), &security).expect("a valid gateway address"))
            .max_encoding_message_size(64 << 20)
    }

    /// What `vlnav eval` needs to run its suite against this stack.
    pub fn eval_target(&self) -> vlnav_eval::Target {
        vlnav_eval::Target {
            gateway_uri: self.uri(),
            caller: self.operator(),
            pki: self.stack.security.as_ref().map(|s| s.pki.clone()),
        }
    }

    /// grpcurl flags that verify the gateway and send `token`.
    pub fn grpcurl_auth(&self, token: &str) -> Vec<String> {
        vec![
            "-cacert".into(),
            self.security().pki.ca().display().to_string(),
            "-H".into(),
            format!("authorization: Bearer {token}"),
        ]
    }

    pub async fn wait_for_robot(&self, robot_id: &str) {
        let mut client = self.fleet();
        for _ in 0..600 {
            let robots = client.list_robots(ListRobotsRequest {}).await.expect("ListRobots").into_inner().robots;
            if robots.iter().any(|r| r.robot_id == robot_id && r.connected && r.frames_received > 0) {
                return;
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        panic!("robot {robot_id} did not attach within 60 s");
    }

    /// Every event of a mission until it finishes (bounded by `limit`).
    pub async fn follow(&self, mission_id: &str, limit: Duration) -> (Vec<MissionEvent>, Mission) {
        let mut client = self.missions().await;
        let mut stream = client
            .watch_mission(WatchMissionRequest { mission_id: mission_id.into() })
            .await
            .expect("WatchMission")
            .into_inner();
        let mut events = Vec::new();
        let collect = async {
            while let Some(e) = stream.message().await.expect("event stream") {
                events.push(e);
            }
        };
        tokio::time::timeout(limit, collect)
            .await
            .unwrap_or_else(|_| panic!("mission {mission_id} did not finish within {limit:?}"));
        let mission = client
            .get_mission(GetMissionRequest { mission_id: mission_id.into() })
            .await
            .expect("GetMission")
            .into_inner();
        (events, mission)
    }
}

/// Runs the real grpcurl (1.8.6, reflection v1alpha) with `auth` flags
/// first, and returns stdout, or stderr as the error.
pub fn grpcurl_with(auth: &[String], args: &[&str]) -> Result<String, String> {
    let all: Vec<&str> = auth.iter().map(String::as_str).chain(args.iter().copied()).collect();
    grpcurl(&all)
}

/// Runs the real grpcurl (1.8.6, reflection v1alpha) and returns stdout, or
/// stderr as the error.
pub fn grpcurl(args: &[&str]) -> Result<String, String> {
    let out = Command::new(tool("grpcurl")).args(args).output().expect("grpcurl runs");
    if out.status.success() {
        Ok(String::from_utf8_lossy(&out.stdout).into_owned())
    } else {
        Err(String::from_utf8_lossy(&out.stderr).into_owned())
    }
}

/// grpcurl prints a stream as concatenated JSON objects.
pub fn json_objects(text: &str) -> Vec<serde_json::Value> {
    serde_json::Deserializer::from_str(text)
        .into_iter::<serde_json::Value>()
        .map(|v| v.expect("grpcurl prints JSON"))
        .collect()
}

/// The paper's Case 2 instruction (docs/design.md §2).
pub const CASE_2: &str = "Buddy take left turn, move 4 m ahead, then find the standing person to reach close to it, \
In your right you may see the visitor chair follow it. Finally go at spot where bicycle is standing.";
