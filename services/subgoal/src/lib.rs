//! Subgoal estimator (`vlnav.v1.SubgoalService`): egocentric MOVE steps and
//! detected boxes in RGB-D frames become goals in the odometry frame (docs/design.md §3).
//!
//! - [`geometry`]: the formulas — MOVE, box median depth, back-projection,
//!   camera mount, base → odom, the approach goal `d_s` short of the target;
//! - [`fusion`]: robust fusion of a fixed target's scattered estimates and a
//!   constant-velocity Kalman filter for a moving one (FOLLOW);
//! - [`tracks`]: per-`track_key` state; [`actor`] owns it;
//! - [`grpc`]: validation and proto conversion.
//!
//! The camera model, poses and the frame conversions are `vlnav_geometry`'s.

pub mod actor;
pub mod fusion;
pub mod geometry;
pub mod grpc;
pub mod tracks;

use vlnav_geometry::convert::DepthDefaults;
use vlnav_proto::v1::subgoal_service_server::SubgoalServiceServer;

use crate::fusion::{FixedParams, MovingParams};
use crate::geometry::{BoxDepthParams, MoveParams};
use crate::grpc::Subgoal;
use crate::tracks::TrackParams;

pub const DEFAULT_PORT: u16 = vlnav_runtime::ports::SUBGOAL;

/// Settings of the subgoal estimator (flags or `VLNAV_SUBGOAL_*`).
#[derive(clap::Args, Clone, Debug)]
pub struct Options {
    /// Stopping distance d_s for visual targets when a request gives 0, m.
    #[arg(
        long = "subgoal-default-stop-distance",
        env = "VLNAV_SUBGOAL_DEFAULT_STOP_DISTANCE_M",
        default_value_t = 2.0
    )]
    pub default_stop_distance_m: f64,
    /// Smallest position tolerance of a MOVE goal (raised to the step's d_s), m.
    #[arg(long = "subgoal-move-tolerance", env = "VLNAV_SUBGOAL_MOVE_TOLERANCE_M", default_value_t = 0.25)]
    pub move_tolerance_m: f64,
    /// Heading tolerance of a pure rotation (|f_dist| < 0.1 m), rad.
    #[arg(long = "subgoal-yaw-tolerance", env = "VLNAV_SUBGOAL_YAW_TOLERANCE", default_value_t = 0.2)]
    pub yaw_tolerance: f64,
    /// Position tolerance of a visual target's approach goal, m.
    #[arg(long = "subgoal-target-tolerance", env = "VLNAV_SUBGOAL_TARGET_TOLERANCE_M", default_value_t = 0.3)]
    pub target_tolerance_m: f64,
    /// Fewer valid depth pixels in a box than this is "no depth".
    #[arg(long = "subgoal-min-valid-pixels", env = "VLNAV_SUBGOAL_MIN_VALID_PIXELS", default_value_t = 20)]
    pub min_valid_pixels: usize,
    /// Central fraction of the box (width and height) whose depth is used first.
    #[arg(long = "subgoal-central-fraction", env = "VLNAV_SUBGOAL_CENTRAL_FRACTION", default_value_t = 0.5)]
    pub central_fraction: f64,
    /// Depth bounds used when a frame's CameraInfo leaves them at 0, m.
    #[arg(long = "subgoal-depth-min", env = "VLNAV_SUBGOAL_DEPTH_MIN_M", default_value_t = 0.5)]
    pub depth_min_m: f64,
    #[arg(long = "subgoal-depth-max", env = "VLNAV_SUBGOAL_DEPTH_MAX_M", default_value_t = 10.0)]
    pub depth_max_m: f64,
    /// Observations kept per fixed target.
    #[arg(long = "subgoal-window", env = "VLNAV_SUBGOAL_WINDOW", default_value_t = 30)]
    pub window: usize,
    /// Outlier gate in robust standard deviations (1.4826·MAD), floored at --subgoal-gate-floor.
    #[arg(long = "subgoal-gate-k", env = "VLNAV_SUBGOAL_GATE_K", default_value_t = 3.0)]
    pub gate_k: f64,
    #[arg(long = "subgoal-gate-floor", env = "VLNAV_SUBGOAL_GATE_FLOOR_M", default_value_t = 0.3)]
    pub gate_floor_m: f64,
    /// Moving targets: standard deviation of the target's acceleration, m/s².
    #[arg(long = "subgoal-accel-sigma", env = "VLNAV_SUBGOAL_ACCEL_SIGMA", default_value_t = 1.0)]
    pub accel_sigma: f64,
    /// Most tracks kept at once (least recently used forgotten first).
    #[arg(long = "subgoal-max-tracks", env = "VLNAV_SUBGOAL_MAX_TRACKS", default_value_t = 4096)]
    pub max_tracks: usize,
    /// A fixed target's goal faces along the line from where the robot first
    /// saw it until the robot's bearing to the target turns this far from it, rad.
    #[arg(long = "subgoal-approach-line-max", env = "VLNAV_SUBGOAL_APPROACH_LINE_MAX", default_value_t = 0.35)]
    pub approach_line_max_rad: f64,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            default_stop_distance_m: 2.0,
            move_tolerance_m: 0.25,
            yaw_tolerance: 0.2,
            target_tolerance_m: 0.3,
            min_valid_pixels: 20,
            central_fraction: 0.5,
            depth_min_m: 0.5,
            depth_max_m: 10.0,
            window: 30,
            gate_k: 3.0,
            gate_floor_m: 0.3,
            accel_sigma: 1.0,
            max_tracks: 4096,
            approach_line_max_rad: 0.35,
        }
    }
}

impl Options {
    fn validate(&self) -> anyhow::Result<()> {
        let positive = [
            ("--subgoal-move-tolerance", self.move_tolerance_m),
            ("--subgoal-yaw-tolerance", self.yaw_tolerance),
            ("--subgoal-target-tolerance", self.target_tolerance_m),
            ("--subgoal-gate-k", self.gate_k),
            ("--subgoal-accel-sigma", self.accel_sigma),
            ("--subgoal-depth-max", self.depth_max_m),
            ("--subgoal-approach-line-max", self.approach_line_max_rad),
        ];
        for (name, v) in positive {
            anyhow::ensure!(v.is_finite() && v > 0.0, "{name} must be positive, got {v}");
        }
        anyhow::ensure!(
            self.default_stop_distance_m.is_finite() && self.default_stop_distance_m >= 0.0,
            "--subgoal-default-stop-distance must be ≥ 0"
        );
        anyhow::ensure!(self.gate_floor_m.is_finite() && self.gate_floor_m >= 0.0, "--subgoal-gate-floor must be ≥ 0");
        anyhow::ensure!(
            self.central_fraction > 0.0 && self.central_fraction <= 1.0,
            "--subgoal-central-fraction must be in (0, 1], got {}",
            self.central_fraction
        );
        anyhow::ensure!(
            self.depth_min_m >= 0.0 && self.depth_min_m < self.depth_max_m,
            "--subgoal-depth-min must be ≥ 0 and below --subgoal-depth-max"
        );
        anyhow::ensure!(
            self.window > 0 && self.max_tracks > 0,
            "--subgoal-window and --subgoal-max-tracks must be positive"
        );
        Ok(())
    }

    pub fn track_params(&self) -> TrackParams {
        TrackParams {
            fixed: FixedParams {
                window: self.window,
                gate_k: self.gate_k,
                gate_floor_m: self.gate_floor_m,
                ..FixedParams::default()
            },
            moving: MovingParams { accel_sigma: self.accel_sigma, ..MovingParams::default() },
            default_stop_distance_m: self.default_stop_distance_m,
            goal_tolerance_m: self.target_tolerance_m,
            goal_yaw_tolerance: self.yaw_tolerance,
            max_tracks: self.max_tracks,
            approach_line_max_rad: self.approach_line_max_rad,
        }
    }
}

/// Spawns the track actor and returns the service, ready to serve.
pub async fn services(
    opts: &Options,
    server: &vlnav_runtime::ServerConfig,
) -> anyhow::Result<vlnav_runtime::ServiceSet> {
    opts.validate()?;
    let svc = Subgoal {
        mailbox: actor::spawn(opts.track_params()),
        move_params: MoveParams {
            yaw_tolerance: opts.yaw_tolerance,
            min_position_tolerance: opts.move_tolerance_m,
            ..MoveParams::default()
        },
        box_params: BoxDepthParams { min_valid_pixels: opts.min_valid_pixels, central_fraction: opts.central_fraction },
        depth_defaults: DepthDefaults { min_m: opts.depth_min_m, max_m: opts.depth_max_m },
    };
    let server_svc = SubgoalServiceServer::new(svc)
        .max_decoding_message_size(server.max_message_bytes)
        .max_encoding_message_size(server.max_message_bytes);
    Ok(vlnav_runtime::ServiceSet::new().add("subgoal", server_svc).callers(vlnav_runtime::CallerPolicy::stages()))
}
