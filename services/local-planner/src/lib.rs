//! Motion-primitive local planner (`vlnav.v1.LocalPlannerService`), docs/design.md §4.
//!
//! - [`paths`]: the CMU path library (343 primitives), generated at start-up;
//! - [`lookup`]: the trapezoidal voxel → paths table, as bit sets;
//! - [`cloud`]: depth frame + no-go points → downsampled obstacle cells;
//! - [`planner`]: blocked paths through the table, cost J, rotations, scale
//!   and range shrinking, and the brute-force reference;
//! - [`control`]: per-robot step — reached, rotate in place, path following
//!   to (v, ω), blocked, no progress; [`actor`] owns the robots' state;
//! - [`grpc`]: validation and proto conversion.

pub mod actor;
pub mod cloud;
pub mod control;
pub mod grpc;
pub mod lookup;
pub mod paths;
pub mod people;
pub mod planner;

use std::sync::Arc;

use vlnav_geometry::convert::DepthDefaults;
use vlnav_proto::v1::local_planner_service_server::LocalPlannerServiceServer;

use crate::cloud::CloudParams;
use crate::control::FollowParams;
use crate::planner::{CostWeights, Planner, PlannerParams};

pub const DEFAULT_PORT: u16 = vlnav_runtime::ports::LOCAL_PLANNER;

/// Settings of the local planner (flags or `VLNAV_LOCAL_PLANNER_*`).
#[derive(clap::Args, Clone, Debug)]
pub struct Options {
    /// Metric clearance of the robot's centre line from obstacles, m (Husky half-width 0.335 + margin).
    #[arg(long = "local-planner-clearance", env = "VLNAV_LOCAL_PLANNER_CLEARANCE_M", default_value_t = 0.45)]
    pub clearance_m: f64,
    /// Cost J weights: w_g (per rad of heading error at the path end).
    #[arg(long = "local-planner-w-goal", env = "VLNAV_LOCAL_PLANNER_W_GOAL", default_value_t = 1.0)]
    pub w_goal: f64,
    /// w_o and α of w_o·exp(−α·d_obs).
    #[arg(long = "local-planner-w-obstacle", env = "VLNAV_LOCAL_PLANNER_W_OBSTACLE", default_value_t = 0.6)]
    pub w_obstacle: f64,
    #[arg(long = "local-planner-alpha", env = "VLNAV_LOCAL_PLANNER_ALPHA", default_value_t = 2.0)]
    pub alpha: f64,
    /// w_s and β of w_s·exp(−β·d_sem) (no-go zones).
    #[arg(long = "local-planner-w-semantic", env = "VLNAV_LOCAL_PLANNER_W_SEMANTIC", default_value_t = 1.2)]
    pub w_semantic: f64,
    #[arg(long = "local-planner-beta", env = "VLNAV_LOCAL_PLANNER_BETA", default_value_t = 1.5)]
    pub beta: f64,
    /// Penalty for passing a low (0.10–0.15 m) bump.
    #[arg(long = "local-planner-w-low", env = "VLNAV_LOCAL_PLANNER_W_LOW", default_value_t = 0.3)]
    pub w_low: f64,
    /// Per radian the robot must turn now (path bearing at the look-ahead).
    #[arg(long = "local-planner-w-turn", env = "VLNAV_LOCAL_PLANNER_W_TURN", default_value_t = 0.1)]
    pub w_turn: f64,
    /// Top speed, m/s, and yaw-rate limit, rad/s (Husky A200).
    #[arg(long = "local-planner-max-speed", env = "VLNAV_LOCAL_PLANNER_MAX_SPEED", default_value_t = 1.0)]
    pub max_speed: f64,
    #[arg(long = "local-planner-max-yaw-rate", env = "VLNAV_LOCAL_PLANNER_MAX_YAW_RATE", default_value_t = 1.57)]
    pub max_yaw_rate: f64,
    /// Speed ramp, m/s².
    #[arg(long = "local-planner-max-accel", env = "VLNAV_LOCAL_PLANNER_MAX_ACCEL", default_value_t = 1.0)]
    pub max_accel: f64,
    /// Yaw deceleration the turn command plans with, rad/s²: half the Husky's
    /// 6 rad/s², for the frame of delay before a command takes effect.
    #[arg(long = "local-planner-yaw-decel", env = "VLNAV_LOCAL_PLANNER_YAW_DECEL", default_value_t = 3.0)]
    pub yaw_decel: f64,
    /// Look-ahead distance and yaw-rate gain of the path follower.
    #[arg(long = "local-planner-look-ahead", env = "VLNAV_LOCAL_PLANNER_LOOK_AHEAD_M", default_value_t = 0.5)]
    pub look_ahead_m: f64,
    #[arg(long = "local-planner-yaw-gain", env = "VLNAV_LOCAL_PLANNER_YAW_GAIN", default_value_t = 7.5)]
    pub yaw_gain: f64,
    /// z of the floor in base_link, m (0 when base_link sits on the floor).
    #[arg(long = "local-planner-ground-z", env = "VLNAV_LOCAL_PLANNER_GROUND_Z_M", default_value_t = 0.0)]
    pub ground_z_m: f64,
    /// Points above this height are overhead and ignored, m.
    #[arg(long = "local-planner-max-height", env = "VLNAV_LOCAL_PLANNER_MAX_HEIGHT_M", default_value_t = 1.2)]
    pub max_height_m: f64,
    /// Use every n-th depth row and column of a 640-pixel-wide image; the
    /// same angular spacing at other widths (every column at 160 pixels).
    #[arg(long = "local-planner-depth-stride", env = "VLNAV_LOCAL_PLANNER_DEPTH_STRIDE", default_value_t = 4)]
    pub depth_stride: usize,
    /// Depth bounds used when a frame's CameraInfo leaves them at 0, m.
    #[arg(long = "local-planner-depth-min", env = "VLNAV_LOCAL_PLANNER_DEPTH_MIN_M", default_value_t = 0.3)]
    pub depth_min_m: f64,
    #[arg(long = "local-planner-depth-max", env = "VLNAV_LOCAL_PLANNER_DEPTH_MAX_M", default_value_t = 10.0)]
    pub depth_max_m: f64,
    /// NO_PROGRESS when the goal distance has not dropped by 0.1 m for this long (sensor time), s.
    #[arg(
        long = "local-planner-progress-window",
        env = "VLNAV_LOCAL_PLANNER_PROGRESS_WINDOW_S",
        default_value_t = 5.0
    )]
    pub progress_window_s: f64,
    /// Plan a detour on a rolling grid when the direct way makes no
    /// progress (docs/design.md §4, "Detours"). Off by default until it
    /// improves the generated development set beyond its interval.
    #[arg(long = "local-planner-detour", env = "VLNAV_LOCAL_PLANNER_DETOUR")]
    pub detour: bool,
    /// Keep what the depth has seen lately and report each frame the
    /// nearest edges of the space it has not seen; a FIND whose search legs
    /// are spent drives on toward one (docs/design.md §4, "Frontier"). Off
    /// by default until it improves the generated development set beyond
    /// its interval.
    #[arg(long = "local-planner-frontier", env = "VLNAV_LOCAL_PLANNER_FRONTIER")]
    pub frontier: bool,
    /// A step that is stuck with nobody near — BLOCKED, NO_PROGRESS, or
    /// 8 s without coming 0.3 m nearer — plans the next 2.5 m through
    /// narrow passages: doors down to about 0.85 m, slowly, with 10.5 MB
    /// more lookup tables (docs/design.md §4, "Narrow passages"). On by
    /// default; `--local-planner-narrow false` keeps every path 0.45 m
    /// from obstacles.
    #[arg(
        long = "local-planner-narrow",
        env = "VLNAV_LOCAL_PLANNER_NARROW",
        default_value_t = true,
        action = clap::ArgAction::Set
    )]
    pub narrow: bool,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            clearance_m: 0.45,
            w_goal: 1.0,
            w_obstacle: 0.6,
            alpha: 2.0,
            w_semantic: 1.2,
            beta: 1.5,
            w_low: 0.3,
            w_turn: 0.1,
            max_speed: 1.0,
            max_yaw_rate: 1.57,
            max_accel: 1.0,
            yaw_decel: 3.0,
            look_ahead_m: 0.5,
            yaw_gain: 7.5,
            ground_z_m: 0.0,
            max_height_m: 1.2,
            depth_stride: 4,
            depth_min_m: 0.3,
            depth_max_m: 10.0,
            progress_window_s: 5.0,
            detour: false,
            frontier: false,
            narrow: true,
        }
    }
}

impl Options {
    fn validate(&self) -> anyhow::Result<()> {
        let positive = [
            ("--local-planner-clearance", self.clearance_m),
            ("--local-planner-max-speed", self.max_speed),
            ("--local-planner-max-yaw-rate", self.max_yaw_rate),
            ("--local-planner-max-accel", self.max_accel),
            ("--local-planner-yaw-decel", self.yaw_decel),
            ("--local-planner-look-ahead", self.look_ahead_m),
            ("--local-planner-yaw-gain", self.yaw_gain),
            ("--local-planner-progress-window", self.progress_window_s),
            ("--local-planner-depth-max", self.depth_max_m),
        ];
        for (name, v) in positive {
            anyhow::ensure!(v.is_finite() && v > 0.0, "{name} must be positive, got {v}");
        }
        let non_negative = [
            ("--local-planner-w-goal", self.w_goal),
            ("--local-planner-w-obstacle", self.w_obstacle),
            ("--local-planner-alpha", self.alpha),
            ("--local-planner-w-semantic", self.w_semantic),
            ("--local-planner-beta", self.beta),
            ("--local-planner-w-low", self.w_low),
            ("--local-planner-w-turn", self.w_turn),
            ("--local-planner-depth-min", self.depth_min_m),
        ];
        for (name, v) in non_negative {
            anyhow::ensure!(v.is_finite() && v >= 0.0, "{name} must be ≥ 0, got {v}");
        }
        anyhow::ensure!(self.clearance_m < 1.5, "--local-planner-clearance above 1.5 m would block every path");
        anyhow::ensure!(self.depth_stride > 0, "--local-planner-depth-stride must be positive");
        anyhow::ensure!(
            self.max_height_m > 0.15,
            "--local-planner-max-height must be above the 0.15 m obstacle height"
        );
        Ok(())
    }

    pub fn planner_params(&self) -> PlannerParams {
        PlannerParams {
            clearance_m: self.clearance_m,
            weights: CostWeights {
                goal: self.w_goal,
                obstacle: self.w_obstacle,
                alpha: self.alpha,
                semantic: self.w_semantic,
                beta: self.beta,
                low: self.w_low,
                turn: self.w_turn,
            },
            look_ahead_m: self.look_ahead_m,
            narrow_clearance_m: if self.narrow { planner::NARROW_CLEARANCE_M } else { 0.0 },
            ..PlannerParams::default()
        }
    }

    pub fn follow_params(&self) -> FollowParams {
        FollowParams {
            look_ahead_m: self.look_ahead_m,
            yaw_gain: self.yaw_gain,
            max_speed: self.max_speed,
            max_yaw_rate: self.max_yaw_rate,
            max_accel: self.max_accel,
            yaw_decel: self.yaw_decel,
            progress_window_s: self.progress_window_s,
            detour: self.detour,
            frontier: self.frontier,
            narrow: self.narrow,
            ..FollowParams::default()
        }
    }

    pub fn cloud_params(&self) -> CloudParams {
        CloudParams {
            ground_z: self.ground_z_m,
            max_height: self.max_height_m,
            stride: self.depth_stride,
            ..CloudParams::default()
        }
    }
}

/// Generates the path library and lookup tables, spawns the actor and
/// returns the service, ready to serve.
pub async fn services(
    opts: &Options,
    server: &vlnav_runtime::ServerConfig,
) -> anyhow::Result<vlnav_runtime::ServiceSet> {
    opts.validate()?;
    let params = opts.planner_params();
    let planner = tokio::task::spawn_blocking(move || Planner::new(params)).await?;
    let svc = grpc::LocalPlanner {
        mailbox: actor::spawn(Arc::new(planner), opts.follow_params(), opts.cloud_params()),
        depth_defaults: DepthDefaults { min_m: opts.depth_min_m, max_m: opts.depth_max_m },
    };
    let server_svc = LocalPlannerServiceServer::new(svc)
        .max_decoding_message_size(server.max_message_bytes)
        .max_encoding_message_size(server.max_message_bytes);
    Ok(vlnav_runtime::ServiceSet::new().add("local-plan", server_svc).callers(vlnav_runtime::CallerPolicy::stages()))
}
