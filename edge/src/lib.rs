//! The fleet edge agent: the program beside each robot. It attaches to the
//! gateway's `FleetService`, streams the robot's RGB-D frames and odometry
//! up, and applies the velocity commands that come down — behind a local
//! safety governor (deadman in sensor time, velocity/acceleration limits,
//! e-stop) that no remote service can override.
//!
//! Drivers: `sim` (the [`vlnav_sim`] simulator, real time or lockstep),
//! `ros1` (a ROS 1 node: `/cmd_vel` out; odometry and RealSense topics in)
//! and `ros2` (a ROS 2 node on DDS, cargo feature `ros2`: `<ns>/cmd_vel` out;
//! odometry, RealSense, e-stop and battery topics in). For load generators,
//! [`replay::run_replay`] drives a robot that sends recorded frames again.
//!
//! For evaluation, [`run_with`] takes [`Hooks`]: an observer channel that
//! receives one [`StepRecord`] per frame (with the simulator's ground truth),
//! an [`EstopSwitch`], and an [`IdleGate`] that holds a lockstep robot
//! between two frames while a mission is submitted; [`run_episode`] collects
//! the records of a run.

pub mod convert;
pub mod link;
pub mod replay;
pub mod ros1;
#[cfg(feature = "ros2")]
pub mod ros2;
pub mod ros_common;
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
    /// A ROS 2 robot (Husky A300 on Jazzy, A200 on Humble or Jazzy) over DDS
    /// (`ROS_DOMAIN_ID`); needs a build with the cargo feature `ros2`.
    Ros2,
}

impl DriverKind {
    pub fn as_str(self) -> &'static str {
        match self {
            DriverKind::Sim => "sim",
            DriverKind::Ros1 => "ros1",
            DriverKind::Ros2 => "ros2",
        }
    }
}

/// The ROS 2 distribution the robot runs: it decides the type of `cmd_vel`.
#[derive(clap::ValueEnum, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum RosDistro {
    /// `geometry_msgs/msg/TwistStamped` on `cmd_vel` (Clearpath's Jazzy platforms).
    #[default]
    Jazzy,
    /// `geometry_msgs/msg/Twist` on `cmd_vel`.
    Humble,
}

/// The topics a ROS driver uses, with the driver's defaults filled in.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RosTopics {
    pub cmd_vel: String,
    pub odom: String,
    pub color: String,
    pub depth: String,
    pub camera_info: String,
    /// ROS 2 only.
    pub estop: String,
    /// ROS 2 only.
    pub battery: String,
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
    /// Disparity quantised with --disparity-step, then compressed: a bounded
    /// error (half a step of disparity, about step/2·z² of depth) for a
    /// fraction of RVL's bytes (`vlnav_geometry::disparity`;
    /// docs/architecture.md, "Frames").
    Disparity,
}

/// How colour travels to the gateway (docs/architecture.md, "Frames").
#[derive(clap::ValueEnum, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ColourCodec {
    /// 8-bit RGB as the camera gives it: 921,600 bytes a 640×480 frame.
    #[default]
    Raw,
    /// JPEG at --jpeg-quality, encoded on the robot: lossy, under a tenth of
    /// the bytes, for an uplink whose bandwidth is the limit.
    Jpeg,
}

impl ColourCodec {
    pub fn as_str(self) -> &'static str {
        match self {
            ColourCodec::Raw => "raw",
            ColourCodec::Jpeg => "jpeg",
        }
    }
}

impl DepthCodec {
    pub fn as_str(self) -> &'static str {
        match self {
            DepthCodec::Raw => "raw",
            DepthCodec::Rvl => "rvl",
            DepthCodec::Disparity => "disparity",
        }
    }
}

/// The disparity step of `--depth-codec disparity` unless told otherwise,
/// 1/m: the D455's own depth noise.
pub const DEFAULT_DISPARITY_STEP: f32 = vlnav_geometry::disparity::D455_STEP_PER_M;

/// The JPEG quality of `--colour-codec jpeg` unless told otherwise.
pub const DEFAULT_JPEG_QUALITY: u8 = 85;

/// How a frame's images are sent up: `--colour-codec` at `--jpeg-quality`,
/// and `--depth-codec` at `--disparity-step`. Also the link flags of the
/// tools that drive simulated robots through this crate (`vlnav bench
/// fleet`, `vlnav eval`): the edge agent's own flags ([`EdgeOptions`])
/// without its `VLNAV_EDGE_*` variables, which configure an agent, not a
/// benchmark.
#[derive(clap::Args, Clone, Copy, Debug, PartialEq)]
pub struct Codecs {
    /// How the robots send colour (the edge agent's --colour-codec).
    #[arg(long = "colour-codec", alias = "color-codec", value_name = "COLOUR_CODEC", value_enum, default_value_t = ColourCodec::Raw)]
    pub colour: ColourCodec,
    /// JPEG quality of --colour-codec jpeg, 1–100 (the edge agent's --jpeg-quality).
    #[arg(long = "jpeg-quality", default_value_t = DEFAULT_JPEG_QUALITY,
          value_parser = clap::value_parser!(u8).range(1..=100))]
    pub jpeg_quality: u8,
    /// How the robots send depth (the edge agent's --depth-codec).
    #[arg(long = "depth-codec", value_name = "DEPTH_CODEC", value_enum, default_value_t = DepthCodec::Raw)]
    pub depth: DepthCodec,
    /// Disparity step of --depth-codec disparity, 1/m (the edge agent's --disparity-step).
    #[arg(long = "disparity-step", default_value_t = DEFAULT_DISPARITY_STEP)]
    pub disparity_step: f32,
}

impl Codecs {
    /// The colour codec as reports name it: `raw`, `jpeg q85`.
    pub fn colour_name(&self) -> String {
        match self.colour {
            ColourCodec::Raw => "raw".into(),
            ColourCodec::Jpeg => format!("jpeg q{}", self.jpeg_quality),
        }
    }

    /// The depth codec as reports name it: `raw`, `rvl`, `disparity 0.005/m`.
    pub fn depth_name(&self) -> String {
        match self.depth {
            DepthCodec::Disparity => format!("disparity {}/m", self.disparity_step),
            other => other.as_str().into(),
        }
    }

    /// The flags that give these codecs to the edge agent, or to a tool that
    /// takes them (`vlnav bench robots`).
    pub fn to_flags(&self) -> Vec<String> {
        vec![
            "--colour-codec".into(),
            self.colour.as_str().into(),
            "--jpeg-quality".into(),
            self.jpeg_quality.to_string(),
            "--depth-codec".into(),
            self.depth.as_str().into(),
            "--disparity-step".into(),
            self.disparity_step.to_string(),
        ]
    }
}

impl Default for Codecs {
    fn default() -> Self {
        Self {
            colour: ColourCodec::Raw,
            jpeg_quality: DEFAULT_JPEG_QUALITY,
            depth: DepthCodec::Raw,
            disparity_step: DEFAULT_DISPARITY_STEP,
        }
    }
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
    /// sim: advance one frame period per answered frame (deterministic, faster than real time); the world stands still while no mission drives the robot.
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
    /// How depth is sent: `raw`; `rvl` (lossless, a third to a half of the
    /// bytes); or `disparity` (within half of --disparity-step of each
    /// pixel's disparity, about a tenth of the bytes), for a link whose
    /// bandwidth is the limit (docs/architecture.md, "Frames").
    #[arg(long, env = "VLNAV_EDGE_DEPTH_CODEC", value_enum, default_value_t = DepthCodec::Raw)]
    pub depth_codec: DepthCodec,
    /// Disparity step of --depth-codec disparity, 1/m, 0.0001–0.03. The
    /// default, 0.005, is the D455's own depth noise (σ = 0.005·z²), so each
    /// pixel stays within half of it: 10 mm at 2 m, 40 mm at 4 m.
    #[arg(long, env = "VLNAV_EDGE_DISPARITY_STEP", default_value_t = DEFAULT_DISPARITY_STEP)]
    pub disparity_step: f32,
    /// How colour is sent: `raw` RGB8, or `jpeg` (lossy, encoded here at
    /// --jpeg-quality in 3–5 ms a 640×480 frame: under a tenth of the bytes
    /// at 85, for a link whose bandwidth is the limit; it costs the detector
    /// marginal boxes and the segmenter thin cables, docs/architecture.md,
    /// "Frames").
    #[arg(long, alias = "color-codec", env = "VLNAV_EDGE_COLOUR_CODEC", value_enum, default_value_t = ColourCodec::Raw)]
    pub colour_codec: ColourCodec,
    /// JPEG quality of --colour-codec jpeg, 1 (smallest) to 100 (finest).
    #[arg(long, env = "VLNAV_EDGE_JPEG_QUALITY", default_value_t = DEFAULT_JPEG_QUALITY,
          value_parser = clap::value_parser!(u8).range(1..=100))]
    pub jpeg_quality: u8,
    /// Largest gRPC message sent or accepted, bytes.
    #[arg(long, env = "VLNAV_EDGE_MAX_MESSAGE_BYTES", default_value_t = 16 * 1024 * 1024)]
    pub max_message_bytes: usize,
    /// ros1, ros2: node name.
    #[arg(long, env = "VLNAV_EDGE_ROS_NODE", default_value = "vlnav_edge")]
    pub ros_node: String,
    /// ros2: the robot's namespace (Clearpath: the serial number, e.g.
    /// `a300_0001`); relative topic names resolve under it.
    #[arg(long, env = "VLNAV_EDGE_ROS_NAMESPACE", default_value = "")]
    pub ros_namespace: String,
    /// ros2: the robot's ROS 2 distribution: `jazzy` publishes TwistStamped on
    /// cmd_vel, `humble` Twist.
    #[arg(long, env = "VLNAV_EDGE_ROS_DISTRO", value_enum, default_value_t = RosDistro::Jazzy)]
    pub ros_distro: RosDistro,
    /// ros2: take "now" from `/clock` (the `use_sim_time` parameter of ROS 2
    /// nodes) instead of the newest stamp plus the wall time since it arrived.
    #[arg(long, env = "VLNAV_EDGE_USE_SIM_TIME", default_value_t = false)]
    pub use_sim_time: bool,
    /// Velocity command topic. ros1: `/cmd_vel` (geometry_msgs/Twist); ros2:
    /// `cmd_vel` (TwistStamped on jazzy, Twist on humble).
    #[arg(long, env = "VLNAV_EDGE_CMD_VEL_TOPIC")]
    pub cmd_vel_topic: Option<String>,
    /// Odometry topic (nav_msgs/Odometry). ros1: `/odometry/filtered`; ros2:
    /// `platform/odom/filtered`.
    #[arg(long, env = "VLNAV_EDGE_ODOM_TOPIC")]
    pub odom_topic: Option<String>,
    /// Colour image topic (sensor_msgs/Image, rgb8/bgr8/rgba8/bgra8/mono8).
    /// ros1: `/camera/color/image_raw`; ros2: `/camera/camera/color/image_raw`.
    #[arg(long, env = "VLNAV_EDGE_COLOR_TOPIC")]
    pub color_topic: Option<String>,
    /// Depth aligned to colour (sensor_msgs/Image, 16UC1 mm or 32FC1 m). ros1:
    /// `/camera/aligned_depth_to_color/image_raw`; ros2:
    /// `/camera/camera/aligned_depth_to_color/image_raw`.
    #[arg(long, env = "VLNAV_EDGE_DEPTH_TOPIC")]
    pub depth_topic: Option<String>,
    /// Colour camera intrinsics (sensor_msgs/CameraInfo). ros1:
    /// `/camera/color/camera_info`; ros2: `/camera/camera/color/camera_info`.
    #[arg(long, env = "VLNAV_EDGE_CAMERA_INFO_TOPIC")]
    pub camera_info_topic: Option<String>,
    /// ros2: the robot's emergency stop (std_msgs/Bool, true = engaged).
    #[arg(long, env = "VLNAV_EDGE_ESTOP_TOPIC", default_value = "platform/emergency_stop")]
    pub estop_topic: String,
    /// ros2: the robot's battery (sensor_msgs/BatteryState).
    #[arg(long, env = "VLNAV_EDGE_BATTERY_TOPIC", default_value = "platform/bms/state")]
    pub battery_topic: String,
    /// Charge (0 to 1) below which the battery is reported low.
    #[arg(long, env = "VLNAV_EDGE_BATTERY_LOW", default_value_t = 0.2)]
    pub battery_low: f64,
    /// ros1, ros2: camera body pose in base_link: x,y,z (m),yaw (rad).
    #[arg(long, env = "VLNAV_EDGE_CAMERA_MOUNT", value_delimiter = ',', num_args = 4, default_values_t = [0.30, 0.0, 0.60, 0.0])]
    pub camera_mount: Vec<f64>,
    /// ros1, ros2: cmd_vel publish rate, Hz (the deadman is checked at this rate).
    #[arg(long, env = "VLNAV_EDGE_CONTROL_RATE_HZ", default_value_t = 20.0)]
    pub control_rate_hz: f64,
    /// ros1, ros2: the platform's limits (Husky A200 defaults).
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
            disparity_step: DEFAULT_DISPARITY_STEP,
            colour_codec: ColourCodec::Raw,
            jpeg_quality: DEFAULT_JPEG_QUALITY,
            max_message_bytes: 16 * 1024 * 1024,
            ros_node: "vlnav_edge".into(),
            ros_namespace: String::new(),
            ros_distro: RosDistro::Jazzy,
            use_sim_time: false,
            cmd_vel_topic: None,
            odom_topic: None,
            color_topic: None,
            depth_topic: None,
            camera_info_topic: None,
            estop_topic: "platform/emergency_stop".into(),
            battery_topic: "platform/bms/state".into(),
            battery_low: 0.2,
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
        if !(0.0..=1.0).contains(&self.battery_low) {
            anyhow::bail!("--battery-low is a charge from 0 to 1, got {}", self.battery_low);
        }
        if let Err(e) = vlnav_geometry::disparity::check_step(self.disparity_step) {
            anyhow::bail!("--disparity-step: {e}");
        }
        if !(1..=100).contains(&self.jpeg_quality) {
            anyhow::bail!("--jpeg-quality is from 1 (smallest) to 100 (finest), got {}", self.jpeg_quality);
        }
        if self.lockstep && self.driver != DriverKind::Sim {
            anyhow::bail!("--lockstep needs --driver sim (a real robot cannot wait for the gateway)");
        }
        Ok(())
    }
}

impl EdgeOptions {
    /// How this agent sends a frame's images.
    pub fn codecs(&self) -> Codecs {
        Codecs {
            colour: self.colour_codec,
            jpeg_quality: self.jpeg_quality,
            depth: self.depth_codec,
            disparity_step: self.disparity_step,
        }
    }

    /// Sends a frame's images with `codecs` (a tool's [`Codecs`] flags).
    pub fn with_codecs(self, codecs: Codecs) -> Self {
        Self {
            colour_codec: codecs.colour,
            jpeg_quality: codecs.jpeg_quality,
            depth_codec: codecs.depth,
            disparity_step: codecs.disparity_step,
            ..self
        }
    }

    /// The topics of the ROS driver, each flag left out taking the driver's default.
    pub fn ros_topics(&self) -> RosTopics {
        let ros2 = self.driver == DriverKind::Ros2;
        let pick = |flag: &Option<String>, ros1: &str, ros2_default: &str| {
            flag.clone().unwrap_or_else(|| if ros2 { ros2_default } else { ros1 }.to_string())
        };
        RosTopics {
            cmd_vel: pick(&self.cmd_vel_topic, "/cmd_vel", "cmd_vel"),
            odom: pick(&self.odom_topic, "/odometry/filtered", "platform/odom/filtered"),
            color: pick(&self.color_topic, "/camera/color/image_raw", "/camera/camera/color/image_raw"),
            depth: pick(
                &self.depth_topic,
                "/camera/aligned_depth_to_color/image_raw",
                "/camera/camera/aligned_depth_to_color/image_raw",
            ),
            camera_info: pick(&self.camera_info_topic, "/camera/color/camera_info", "/camera/camera/color/camera_info"),
            estop: self.estop_topic.clone(),
            battery: self.battery_topic.clone(),
        }
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
    /// dropped because the link's queue was full. `bytes`: its message as
    /// encoded for the link (everything but gRPC's 5-byte prefix, HTTP/2
    /// framing and TLS); `image_bytes`: its colour and depth data alone, what
    /// a real robot's frame carries (the simulator adds a label image).
    Frame { stamp: f64, queued: bool, at: std::time::Instant, bytes: usize, image_bytes: usize },
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
        #[cfg(feature = "ros2")]
        DriverKind::Ros2 => ros2::run_ros2(&opts, shutdown, hooks).await,
        #[cfg(not(feature = "ros2"))]
        DriverKind::Ros2 => anyhow::bail!(
            "this vlnav-edge was built without the ROS 2 driver: cargo build --release -p vlnav-edge-agent --features ros2"
        ),
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

#[cfg(test)]
mod tests {
    use clap::Parser;

    use super::*;

    #[derive(Parser, Debug)]
    struct Cli {
        #[command(flatten)]
        edge: EdgeOptions,
    }

    fn parse(args: &[&str]) -> Result<EdgeOptions, String> {
        Cli::try_parse_from(std::iter::once("vlnav-edge").chain(args.iter().copied()))
            .map(|c| c.edge)
            .map_err(|e| e.to_string())
    }

    #[test]
    fn the_colour_codec_and_its_quality_are_flags_with_raw_the_default() {
        let default = parse(&[]).unwrap();
        assert_eq!(default.codecs(), Codecs::default());
        assert_eq!(default.codecs().colour, ColourCodec::Raw);
        let jpeg = parse(&["--colour-codec", "jpeg", "--jpeg-quality", "70", "--depth-codec", "rvl"]).unwrap();
        assert_eq!(
            jpeg.codecs(),
            Codecs { colour: ColourCodec::Jpeg, jpeg_quality: 70, depth: DepthCodec::Rvl, ..Codecs::default() }
        );
        let disparity = parse(&["--depth-codec", "disparity", "--disparity-step", "0.01"]).unwrap();
        assert_eq!((disparity.codecs().depth, disparity.codecs().disparity_step), (DepthCodec::Disparity, 0.01));
        assert!(disparity.validate().is_ok());
        assert_eq!(parse(&["--color-codec", "jpeg"]).unwrap().colour_codec, ColourCodec::Jpeg);
        assert!(jpeg.validate().is_ok());
    }

    #[derive(Parser, Debug)]
    struct LinkCli {
        #[command(flatten)]
        link: Codecs,
    }

    #[test]
    fn a_tools_link_flags_are_the_agents_and_go_back_to_flags_and_names() {
        let parse_link = |args: &[&str]| {
            LinkCli::try_parse_from(std::iter::once("tool").chain(args.iter().copied())).map(|c| c.link)
        };
        assert_eq!(parse_link(&[]).unwrap(), Codecs::default());
        let args =
            ["--color-codec", "jpeg", "--jpeg-quality", "70", "--depth-codec", "disparity", "--disparity-step", "0.01"];
        let link = parse_link(&args).unwrap();
        assert_eq!(link, parse(&args).unwrap().codecs(), "the same flags as the edge agent's");
        let flags = link.to_flags();
        let round: Vec<&str> = flags.iter().map(String::as_str).collect();
        assert_eq!(parse_link(&round).unwrap(), link, "{flags:?}");
        assert_eq!(parse(&round).unwrap().codecs(), link, "an edge agent takes them too");
        assert_eq!((link.colour_name(), link.depth_name()), ("jpeg q70".to_string(), "disparity 0.01/m".to_string()));
        assert_eq!((Codecs::default().colour_name(), Codecs::default().depth_name()), ("raw".into(), "raw".into()));
        assert_eq!(EdgeOptions::default().with_codecs(link).codecs(), link);
        assert!(parse_link(&["--jpeg-quality", "0"]).is_err());
    }

    #[test]
    fn a_bad_jpeg_quality_or_codec_is_refused_with_the_valid_values() {
        for (q, why) in [("0", "0 is not in 1..=100"), ("101", "101 is not in 1..=100"), ("high", "invalid digit")] {
            let e = parse(&["--colour-codec", "jpeg", "--jpeg-quality", q]).unwrap_err();
            assert!(e.contains("--jpeg-quality") && e.contains(why), "{e}");
        }
        let e = parse(&["--colour-codec", "png"]).unwrap_err();
        assert!(e.contains("possible values: raw, jpeg"), "{e}");
        // Settings built in code are checked as the flags are.
        let e = EdgeOptions { jpeg_quality: 0, ..EdgeOptions::default() }.validate().unwrap_err().to_string();
        assert!(e.contains("--jpeg-quality is from 1 (smallest) to 100 (finest), got 0"), "{e}");
        let e = parse(&["--depth-codec", "disparity", "--disparity-step", "0.5"]).unwrap().validate().unwrap_err();
        assert!(e.to_string().contains("--disparity-step: the disparity step 0.5"), "{e}");
    }
}
