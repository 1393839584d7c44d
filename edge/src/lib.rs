//! The fleet edge agent: the program beside each robot. It attaches to the
//! gateway's `FleetService`, streams the robot's RGB-D frames and odometry
//! up, and applies the velocity commands that come down — behind a local
//! safety governor (deadman in sensor time, velocity/acceleration limits,
//! e-stop) that no remote service can override.
//!
//! Drivers: `sim` (the [`vlnav_sim`] simulator, real time or lockstep) and
//! `ros1` (a ROS 1 node: `/cmd_vel` out; odometry and RealSense topics in).
//!
//! For evaluation, [`run_with`] takes [`Hooks`]: an observer channel that
//! receives one [`StepRecord`] per frame (with the simulator's ground truth),
//! an [`EstopSwitch`], and an [`IdleGate`] that holds a lockstep robot
//! between two frames while a mission is submitted; [`run_episode`] collects
//! the records of a run.

pub mod convert;
pub mod link;
pub mod ros1;
pub mod safety;
pub mod sim;

/// The paths the link and the `sim` driver had before they were split into
/// [`link`] and [`sim`]; kept so that callers of those paths keep building.
pub mod agent {
    pub use crate::link::{Link, SessionEnd, StatusReporter};
    pub use crate::sim::run_sim;
    pub use crate::spawn_estop_signals;
}

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use tokio::sync::{mpsc, watch};
use vlnav_runtime::CancellationToken;

pub use safety::Verdict;
pub use vlnav_sim::Twist;

/// Which robot the agent drives.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum DriverKind {
    /// The built-in simulator (`--scenario`, `--seed`, `--lockstep`).
    Sim,
    /// A ROS 1 robot (Husky): `ROS_MASTER_URI` names the master.
    Ros1,
}

impl DriverKind {
    pub fn as_str(self) -> &'static str {
        match self {
            DriverKind::Sim => "sim",
            DriverKind::Ros1 => "ros1",
        }
    }
}

/// How depth travels to the gateway (docs/architecture.md, "Frames").
#[derive(clap::ValueEnum, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum DepthCodec {
    /// Little-endian u16 millimetres as the camera gives them.
    #[default]
    Raw,
    /// Lossless RVL: a third to a half of the bytes, for about 1 ms a frame at
    /// each end (`cargo bench -p vlnav-sim --bench depth_codec`). For an
    /// uplink whose bandwidth is the limit (docs/architecture.md, "Frames").
    Rvl,
}

/// Settings of one edge agent (flags or `VLNAV_EDGE_*` environment variables).
#[derive(clap::Args, Clone, Debug)]
pub struct EdgeOptions {
    /// The gateway's FleetService.
    #[arg(long, env = "VLNAV_EDGE_GATEWAY", default_value = "http://127.0.0.1:50051")]
    pub gateway: String,
    /// The CA the gateway's certificate is verified against (then --gateway
    /// must be https://) and this robot's certificate, which must name it
    /// (`spiffe://vlnav/robot/<robot_id>`; docs/security.md).
    #[command(flatten)]
    pub tls: vlnav_runtime::security::ClientTlsArgs,
    /// This robot's id in the fleet.
    #[arg(long, env = "VLNAV_EDGE_ROBOT_ID", default_value = "husky-1")]
    pub robot_id: String,
    #[arg(long, env = "VLNAV_EDGE_DRIVER", value_enum, default_value = "sim")]
    pub driver: DriverKind,
    /// sim: a shipped scenario (`demo`, `lab`) or a scenario file path.
    #[arg(long, env = "VLNAV_EDGE_SCENARIO", default_value = "demo")]
    pub scenario: String,
    /// sim: seed of the wheel-slip and depth-noise generators.
    #[arg(long, env = "VLNAV_EDGE_SEED", default_value_t = 0)]
    pub seed: u64,
    /// sim: advance one frame period per answered frame (deterministic, faster than real time).
    #[arg(long, env = "VLNAV_EDGE_LOCKSTEP", default_value_t = false)]
    pub lockstep: bool,
    /// Stop unless the newest command is at most this old in sensor time, seconds.
    #[arg(long, env = "VLNAV_EDGE_DEADMAN_TIMEOUT_S", default_value_t = 0.3)]
    pub deadman_timeout_s: f64,
    /// Camera frames sent per second of sensor time.
    #[arg(long, env = "VLNAV_EDGE_FRAME_RATE", default_value_t = 10.0)]
    pub frame_rate: f64,
    /// sim: image width (intrinsics scale with it); default the scenario's (640).
    #[arg(long, env = "VLNAV_EDGE_WIDTH")]
    pub width: Option<u32>,
    /// sim: image height; default the scenario's (480).
    #[arg(long, env = "VLNAV_EDGE_HEIGHT")]
    pub height: Option<u32>,
    /// Wall-clock seconds without any message from the gateway before the link
    /// is declared dead (robot held stopped, reconnect with backoff).
    #[arg(long, env = "VLNAV_EDGE_LIVENESS_TIMEOUT_S", default_value_t = 5.0)]
    pub liveness_timeout_s: f64,
    /// First reconnect delay, seconds (doubles up to --reconnect-max-s).
    #[arg(long, env = "VLNAV_EDGE_RECONNECT_INITIAL_S", default_value_t = 0.2)]
    pub reconnect_initial_s: f64,
    #[arg(long, env = "VLNAV_EDGE_RECONNECT_MAX_S", default_value_t = 5.0)]
    pub reconnect_max_s: f64,
    /// Start with the e-stop engaged (SIGUSR1 engages, SIGUSR2 releases).
    #[arg(long, env = "VLNAV_EDGE_ESTOP", default_value_t = false)]
    pub estop: bool,
    /// sim: end the run once simulation time reaches this many seconds.
    #[arg(long, env = "VLNAV_EDGE_MAX_SIM_TIME_S")]
    pub max_sim_time_s: Option<f64>,
    /// How depth is sent: `raw`, or `rvl` (lossless, a third to a half of the
    /// bytes, for a link whose bandwidth is the limit).
    #[arg(long, env = "VLNAV_EDGE_DEPTH_CODEC", value_enum, default_value_t = DepthCodec::Raw)]
    pub depth_codec: DepthCodec,
    /// Largest gRPC message sent or accepted, bytes.
    #[arg(long, env = "VLNAV_EDGE_MAX_MESSAGE_BYTES", default_value_t = 16 * 1024 * 1024)]
    pub max_message_bytes: usize,
    /// ros1: node name.
    #[arg(long, env = "VLNAV_EDGE_ROS_NODE", default_value = "vlnav_edge")]
    pub ros_node: String,
    /// ros1: velocity command topic (geometry_msgs/Twist).
    #[arg(long, env = "VLNAV_EDGE_CMD_VEL_TOPIC", default_value = "/cmd_vel")]
    pub cmd_vel_topic: String,
    /// ros1: odometry topic (nav_msgs/Odometry).
    #[arg(long, env = "VLNAV_EDGE_ODOM_TOPIC", default_value = "/odometry/filtered")]
    pub odom_topic: String,
    /// ros1: colour image topic (sensor_msgs/Image, rgb8/bgr8/rgba8/bgra8).
    #[arg(long, env = "VLNAV_EDGE_COLOR_TOPIC", default_value = "/camera/color/image_raw")]
    pub color_topic: String,
    /// ros1: depth aligned to colour (sensor_msgs/Image, 16UC1 mm or 32FC1 m).
    #[arg(long, env = "VLNAV_EDGE_DEPTH_TOPIC", default_value = "/camera/aligned_depth_to_color/image_raw")]
    pub depth_topic: String,
    /// ros1: colour camera intrinsics (sensor_msgs/CameraInfo).
    #[arg(long, env = "VLNAV_EDGE_CAMERA_INFO_TOPIC", default_value = "/camera/color/camera_info")]
    pub camera_info_topic: String,
    /// ros1: camera body pose in base_link: x,y,z (m),yaw (rad).
    #[arg(long, env = "VLNAV_EDGE_CAMERA_MOUNT", value_delimiter = ',', num_args = 4, default_values_t = [0.30, 0.0, 0.60, 0.0])]
    pub camera_mount: Vec<f64>,
    /// ros1: /cmd_vel publish rate, Hz (the deadman is checked at this rate).
    #[arg(long, env = "VLNAV_EDGE_CONTROL_RATE_HZ", default_value_t = 20.0)]
    pub control_rate_hz: f64,
    /// ros1: the platform's limits (Husky A200 defaults).
    #[arg(long, env = "VLNAV_EDGE_MAX_LINEAR", default_value_t = 1.0)]
    pub max_linear: f64,
    #[arg(long, env = "VLNAV_EDGE_MAX_ANGULAR", default_value_t = 2.0)]
    pub max_angular: f64,
    #[arg(long, env = "VLNAV_EDGE_MAX_LINEAR_ACCEL", default_value_t = 3.0)]
    pub max_linear_accel: f64,
    #[arg(long, env = "VLNAV_EDGE_MAX_ANGULAR_ACCEL", default_value_t = 6.0)]
    pub max_angular_accel: f64,
}

impl Default for EdgeOptions {
    fn default() -> Self {
        Self {
            gateway: "http://127.0.0.1:50051".into(),
            tls: Default::default(),
            robot_id: "husky-1".into(),
            driver: DriverKind::Sim,
            scenario: "demo".into(),
            seed: 0,
            lockstep: false,
            deadman_timeout_s: 0.3,
            frame_rate: 10.0,
            width: None,
            height: None,
            liveness_timeout_s: 5.0,
            reconnect_initial_s: 0.2,
            reconnect_max_s: 5.0,
            estop: false,
            max_sim_time_s: None,
            depth_codec: DepthCodec::Raw,
            max_message_bytes: 16 * 1024 * 1024,
            ros_node: "vlnav_edge".into(),
            cmd_vel_topic: "/cmd_vel".into(),
            odom_topic: "/odometry/filtered".into(),
            color_topic: "/camera/color/image_raw".into(),
            depth_topic: "/camera/aligned_depth_to_color/image_raw".into(),
            camera_info_topic: "/camera/color/camera_info".into(),
            camera_mount: vec![0.30, 0.0, 0.60, 0.0],
            control_rate_hz: 20.0,
            max_linear: 1.0,
            max_angular: 2.0,
            max_linear_accel: 3.0,
            max_angular_accel: 6.0,
        }
    }
}

impl EdgeOptions {
    /// Checks the settings; the error names the flag.
    pub fn validate(&self) -> anyhow::Result<()> {
        let positive = |name: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(anyhow::anyhow!("--{name} must be a positive number, got {v}"))
            }
        };
        positive("deadman-timeout-s", self.deadman_timeout_s)?;
        positive("frame-rate", self.frame_rate)?;
        positive("liveness-timeout-s", self.liveness_timeout_s)?;
        positive("reconnect-initial-s", self.reconnect_initial_s)?;
        positive("reconnect-max-s", self.reconnect_max_s)?;
        positive("control-rate-hz", self.control_rate_hz)?;
        positive("max-linear", self.max_linear)?;
        positive("max-angular", self.max_angular)?;
        positive("max-linear-accel", self.max_linear_accel)?;
        positive("max-angular-accel", self.max_angular_accel)?;
        if self.robot_id.trim().is_empty() {
            anyhow::bail!("--robot-id must not be empty");
        }
        if self.camera_mount.len() != 4 || !self.camera_mount.iter().all(|v| v.is_finite()) {
            anyhow::bail!("--camera-mount takes x,y,z,yaw (four numbers), got {:?}", self.camera_mount);
        }
        if self.lockstep && self.driver != DriverKind::Sim {
            anyhow::bail!("--lockstep needs --driver sim (a real robot cannot wait for the gateway)");
        }
        Ok(())
    }
}

/// A latching emergency stop shared between the agent and whoever may press it.
#[derive(Clone, Debug, Default)]
pub struct EstopSwitch(Arc<AtomicBool>);

impl EstopSwitch {
    pub fn engage(&self) {
        self.0.store(true, Ordering::SeqCst);
    }
    pub fn release(&self) {
        self.0.store(false, Ordering::SeqCst);
    }
    pub fn is_engaged(&self) -> bool {
        self.0.load(Ordering::SeqCst)
    }
}

/// Installs SIGUSR1 (engage) / SIGUSR2 (release) as e-stop buttons.
pub fn spawn_estop_signals(estop: crate::EstopSwitch, shutdown: CancellationToken) {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{SignalKind, signal};
        let (Ok(mut engage), Ok(mut release)) =
            (signal(SignalKind::user_defined1()), signal(SignalKind::user_defined2()))
        else {
            tracing::warn!("cannot install SIGUSR1/SIGUSR2 e-stop handlers");
            return;
        };
        tokio::spawn(async move {
            loop {
                tokio::select! {
                    _ = shutdown.cancelled() => return,
                    Some(()) = engage.recv() => { tracing::warn!("e-stop engaged (SIGUSR1)"); estop.engage(); }
                    Some(()) = release.recv() => { tracing::warn!("e-stop released (SIGUSR2)"); estop.release(); }
                }
            }
        });
    }
}

/// What happened at one frame: sent up at `stamp`, answered (or not), applied.
#[derive(Clone, Debug, PartialEq)]
pub struct StepRecord {
    pub seq: u64,
    /// Sensor time of the frame, seconds.
    pub stamp: f64,
    /// Odometry pose (odom frame) at the frame.
    pub odom: vlnav_sim::Pose2,
    /// Simulator ground truth at the frame (sim driver only).
    pub truth: Option<vlnav_sim::Truth>,
    /// The newest command received when the output was computed: its stamp and twist.
    pub command: Option<(f64, Twist)>,
    /// What the governor let through, applied until the next step.
    pub applied: Twist,
    pub verdict: Verdict,
    /// The gateway said no mission is running.
    pub idle: bool,
    pub mission_id: String,
}

/// Optional attachments of a run: an observer of every step, an e-stop and
/// an idle gate.
#[derive(Clone, Debug, Default)]
pub struct Hooks {
    pub observer: Option<mpsc::UnboundedSender<StepRecord>>,
    pub estop: EstopSwitch,
    /// Lockstep only: after a frame the gateway answered as idle, the next
    /// frame waits until the gate is open (instead of one frame period of
    /// wall time). A harness closes it, submits a mission, and opens it, so
    /// the mission starts on the same frame in every run of the same seed.
    pub idle_gate: Option<IdleGate>,
    /// Wall-clock moments of the link, for measuring the control cycle
    /// (`vlnav bench fleet`): each frame offered and each command received.
    pub timing: Option<mpsc::UnboundedSender<LinkEvent>>,
}

/// A moment on the link to the gateway, on the wall clock (the only place
/// the agent reports it: a benchmark measures frame in → command out).
#[derive(Clone, Copy, Debug)]
pub enum LinkEvent {
    /// The frame stamped `stamp` was handed to the link (`queued`), or
    /// dropped because the link's queue was full.
    Frame { stamp: f64, queued: bool, at: std::time::Instant },
    /// A velocity command answering the frame stamped `stamp` arrived.
    Command { stamp: f64, idle: bool, at: std::time::Instant },
}

/// A gate a lockstep robot waits at between an idle frame and the next one.
#[derive(Clone, Debug)]
pub struct IdleGate(Arc<watch::Sender<bool>>);

impl IdleGate {
    /// A gate that starts closed.
    pub fn closed() -> Self {
        Self(Arc::new(watch::channel(false).0))
    }
    pub fn open(&self) {
        self.0.send_replace(true);
    }
    pub fn is_open(&self) -> bool {
        *self.0.borrow()
    }
    /// Returns once the gate is open.
    pub async fn opened(&self) {
        let mut rx = self.0.subscribe();
        // The sender lives in `self`, so the channel cannot close while we wait.
        let _ = rx.wait_for(|open| *open).await;
    }
}

/// Runs the agent until `shutdown` is cancelled (or, sim, `--max-sim-time-s` is reached).
pub async fn run(opts: EdgeOptions, shutdown: CancellationToken) -> anyhow::Result<()> {
    run_with(opts, shutdown, Hooks::default()).await
}

/// [`run`] with an observer and an e-stop switch.
pub async fn run_with(opts: EdgeOptions, shutdown: CancellationToken, hooks: Hooks) -> anyhow::Result<()> {
    opts.validate()?;
    if opts.estop {
        hooks.estop.engage();
    }
    match opts.driver {
        DriverKind::Sim => sim::run_sim(&opts, shutdown, hooks).await,
        DriverKind::Ros1 => ros1::run_ros1(&opts, shutdown, hooks).await,
    }
}

/// Runs one episode and returns every step's record (the ground-truth
/// trajectory for the sim driver) once the run ends — when `shutdown` is
/// cancelled or `max_sim_time_s` is reached.
pub async fn run_episode(opts: EdgeOptions, shutdown: CancellationToken) -> anyhow::Result<Vec<StepRecord>> {
    let (tx, mut rx) = mpsc::unbounded_channel();
    let hooks = Hooks { observer: Some(tx), ..Hooks::default() };
    let result = run_with(opts, shutdown, hooks).await;
    let mut records = Vec::new();
    while let Ok(r) = rx.try_recv() {
        records.push(r);
    }
    result.map(|_| records)
}
