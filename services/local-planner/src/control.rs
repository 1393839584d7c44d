//! One robot's planning step: goal checks, rotate-in-place, path selection,
//! path following to (v, ω) and the progress watchdog. Time comes only from
//! frame stamps.
//!
//! - Reached: the goal is no longer ahead — its distance along the heading is
//!   below `arrive_m` (0.03 m) — while it lies within
//!   `goal.position_tolerance`; or the robot is within `arrive_m` of it; or,
//!   for a pure rotation, the yaw error is below `goal.yaw_tolerance`. The
//!   tolerance is the sideways slack a goal allows, not where the robot may
//!   stop short: stopping at the tolerance circle left every approach about
//!   0.26 m short of the asked distance (docs/design.md §6).
//! - Rotate in place (the authors' rule) while the goal is more than
//!   `rotate_threshold` (1.0 rad) off the heading, `ω = 0.8·error`, until it is
//!   within `rotate_exit` (0.3 rad, hysteresis so the paths take over inside
//!   the camera's view). Once aligned with a goal, the robot rotates in place
//!   again only if the goal falls behind it (`rerotate_threshold`, 1.9 rad):
//!   a detour around an obstacle between robot and goal points the heading
//!   well away from the goal, and turning back to the goal there would
//!   undo the detour and oscillate.
//! - Path following (CMU's path follower): the look-ahead point is where the
//!   chosen path crosses 0.5 m from the robot; `ω = 7.5·bearing`, clamped to
//!   the yaw-rate limit, to what turns onto the bearing within one frame
//!   period (at 5 fps the CMU gain alone would overshoot) and to what can
//!   still stop on the bearing, `√(2·yaw_decel·|bearing|)`: a Husky needs
//!   0.26 s to stop from full yaw rate, and a command that only stops at the
//!   bearing overshoots it and swings from side to side; speed ramps up by
//!   `max_accel·dt` only while the bearing is below 0.2 rad (CMU's 0.1 is for
//!   100 Hz: at 5 fps a lagging turn swung the robot ±0.13 rad between two
//!   near-equal paths and it never moved), otherwise down,
//!   and slows within `slow_down_distance` of the goal, never below
//!   `creep_speed` and never faster than covers the distance left to the
//!   goal in one frame period, so it stops on the goal rather than past it.
//! - Rotating in place sweeps a disc: the Husky's corners reach
//!   `sweep_radius_m` (its half-diagonal, √(0.495² + 0.335²) = 0.60 m, plus
//!   0.05 m; a remembered cell counts `memory_drift_m`, 0.05 m, farther
//!   out, for the odometry's slip since it was seen). Before any turn in
//!   place the disc must be free of obstacle cells (this frame's or
//!   remembered); if it is not, the robot first
//!   moves straight, at `escape_speed`, by the shorter of the forward and
//!   the backward move that leaves the disc free (away from the nearest
//!   cell when they are equal) with the body's lane free that far (backing,
//!   where only memory knows the floor, within `near_memory_m` less the
//!   disc's radius, 0.35 m). Where neither does within the disc's diameter,
//!   it turns on the sharpest forward arc toward the turn's side that keeps
//!   the footprint clear (`RobotState::arc_turn`); where no arc completes
//!   the turn, it takes the move that frees the disc soonest and turns on
//!   the spot from there (`RobotState::unwedge`); and it reports BLOCKED
//!   where nothing frees the disc, rather than grinding a corner along a
//!   parked car during a look-around.
//! - Footprint guard: the paths keep a 0.45 m tube around the robot's centre
//!   clear, but the Husky's corners reach 0.60 m, and a path that grazes an
//!   obstacle diagonally ahead (or a goal beside a parked car) lets a corner
//!   or the swinging rear touch it. Before a command goes out, the robot's
//!   rectangle (`half_length_m` × `half_width_m`, plus `guard_margin_m`) is
//!   moved along the commanded arc for one frame period plus the time
//!   needed to stop (the longer of `v / 2·max_accel` and `ω / 2·yaw_decel`:
//!   a spot turn beside a parked bicycle, checked over one frame only,
//!   swung the rear corner into it while braking — evaluation, garage,
//!   trial 3); if it would take in a blocking cell
//!   (≥ 2 voxels) or a no-go cell (a marked zone, a cable: the paths keep
//!   their 0.45 m tube off it, but a corner swinging round a cable's end
//!   entered it — soft contact, docs/design.md §6), this frame's or
//!   remembered, that it does not already cover, the command is reduced —
//!   the turn alone, the straight part alone, or a stop. A robot stopped by
//!   the guard within the goal's position tolerance has reached it (as
//!   close as its body fits); farther away it creeps on toward the goal's
//!   side at `escape_speed` where the guard lets it — forward on the
//!   sharpest arc toward the goal that stays clear for `CREEP_HOLD_S`,
//!   else straight (a path bending away from a zone beside the robot swings
//!   the rear corner into it, and stopped there it would wait for ever:
//!   `RobotState::creep`) — and the progress watchdog takes over where it
//!   cannot.
//! - Goals beside obstacles: a goal whose footprint (the rectangle at the
//!   goal, facing the goal's heading, plus `guard_margin_m`) would hold a
//!   blocking or no-go cell — an approach goal on the line to a hydrant that stands
//!   0.15 m from a wall, a MOVE that ends beside a parked car — is moved
//!   sideways, across its heading, by the smallest multiple of 0.05 m up to
//!   `goal_shift_max_m` (0.4 m) that clears it. Across the heading, the
//!   distance to what the robot faces changes by only δ²/2d (3 cm for 0.3 m
//!   at 1.5 m). Where no shift clears it and the goal lies at a fixed
//!   landmark's stopping distance (`GoalSpec::landmark`), it is moved round
//!   the landmark, heading and all, by the smallest multiple of 5° up to
//!   `goal_orbit_max_rad` (90°) that clears its footprint and the sweep
//!   disc, so the robot can turn on the spot there (docs/design.md §4). The
//!   move is kept while it stays clear, so it does not jitter from frame to
//!   frame.
//! - Obstacle memory: the camera sees ±43°, so an obstacle leaves the view as
//!   soon as the robot turns away from it, and a plan made without it would
//!   turn straight back. Cells of recent frames, one per 5 cm `odom` voxel
//!   (`memory_s`, 20 s of sensor time — the D455 sees nothing nearer than
//!   its minimum range, so a sofa corner seen on the way in must still be
//!   known when the robot turns beside it; `near_memory_s`, 120 s, for cells within `near_memory_m`, 1 m, of
//!   the robot, which a turn in place must not forget: a robot that waits
//!   beside a parked car while it searches must not forget the car) are kept in `odom` and
//!   merged into the plan unless the current frame measured that place: a
//!   remembered cell is forgotten only where it lies inside the view with
//!   its top in the image (for a no-go marking on the floor: where the image
//!   shows that floor, beyond `View::floor_from_m` — a cable just ahead lies
//!   below the image while the depth along its bearing reaches past it; for
//!   an obstacle lower than the camera: beyond `View::top_from` its height —
//!   a water bottle 0.75 m ahead is below the image too) and the
//!   frame's depth reached it along its bearing (`cloud::SeenRange`, within
//!   `memory_seen_margin_m`), so an obstacle that moved away is forgotten
//!   but one behind a stereo occlusion band — no depth left of a near edge,
//!   docs/perception.md — is not. (Forgetting everything inside the view's
//!   angle let the robot graze tunnel walls it had just seen.) When the
//!   odometry jumps (re-anchored at a reached subgoal, where the robot
//!   stands still) the memory moves with it: each cell keeps its place
//!   relative to the robot. It is dropped when time runs backwards.
//! - Moving obstacles: a cell that appears where a frame `moving_lookback_s`
//!   (0.25 s) earlier saw free space beyond it (by a voxel plus three
//!   standard deviations of the depth error at that range, along every
//!   bearing within one 1° bin plus what 5 cm subtend at its range of its
//!   own: `cloud::SeenRange::free_beyond`, `moved_in_half_angle`) is
//!   something that moved there — a person walking — and so is every
//!   cell of the frame within `moving_cluster_m` (0.3 m) of it, and every
//!   cell within that of a cell remembered as moving in the last
//!   `moving_memory_s` (a person who pauses is still a person). A cell
//!   remembered as standing never becomes moving. (With the cell's own bin
//!   and one neighbour only, the outline of a standing person or statue
//!   seen while the robot turned on the spot counted as moving in the demo
//!   hall: it was forgotten once out of view and the robot, driving on
//!   beside it, wedged itself against the person.) Out of view moving cells
//!   are remembered for `moving_memory_s` (1.5 s) only: a person who walked
//!   past the robot's side must not stay behind as a wall it can neither
//!   see nor turn through.
//! - People: the detector's person boxes give where each person stands
//!   (`cloud.rs`); `people::Tracker` links those places over frames and
//!   tells walkers (faster than `PeopleParams::walking_mps` within the last
//!   `keep_s`). No command — a turn in place, a way out of the sweep disc, a
//!   path's (v, ω) — may bring the footprint within a walker's reach (their
//!   radius plus how far they may have strayed), both carried on for
//!   `PeopleParams::horizon_s`, nearer than standing still would: the
//!   guard's fallbacks are tried, else the robot waits, stopped, and the
//!   progress window restarts. The camera looks only ahead, and a person
//!   who crossed in front of a turning robot walks on past its side, where
//!   its corners swing (evaluation, hall with people crossing). In the
//!   sweep disc everyone tracked counts `PeopleParams::radius_m` nearer
//!   than where they stand: people sway and step while the corners swing.
//!   Within `PeopleParams::near_walker_m` of a walker the speed is capped
//!   at `PeopleParams::near_walker_mps`, from which the robot stops within
//!   the straying the reach test allows them.
//!   A walker's cells stay ordinary cells in the memory: forgetting them
//!   out of view once they walked (they had gone on) raised the crossing
//!   hall's success but let the robot turn into people who had stopped
//!   beside it.
//! - No progress: while moving, if the distance to the goal has not dropped
//!   by `progress_distance` (0.1 m) within `progress_window_s` (5 s of sensor
//!   time), the step reports NO_PROGRESS once with a stop and the window
//!   restarts, so the mission executor can recover instead of hanging.

use std::collections::{BTreeMap, BTreeSet, VecDeque};

use nalgebra::{Rotation2, Vector2};
use vlnav_geometry::{GoalSpec, Pose2, wrap_angle};

use crate::cloud::{Cell, CloudParams, ObstacleCloud, SeenRange};
use crate::people::{PeopleParams, Tracker};
use crate::planner::{Planner, Scratch, Selection};

/// Path-following and watchdog settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FollowParams {
    pub look_ahead_m: f64,
    pub yaw_gain: f64,
    /// Husky A200 limits.
    pub max_speed: f64,
    pub max_yaw_rate: f64,
    pub max_accel: f64,
    /// Yaw deceleration turn commands plan with, rad/s².
    pub yaw_decel: f64,
    /// Speed ramps up only while the look-ahead bearing is below this, rad.
    pub align_threshold: f64,
    pub rotate_threshold: f64,
    /// Goal bearing beyond which an aligned robot rotates in place again, rad.
    pub rerotate_threshold: f64,
    pub rotate_exit: f64,
    pub rotate_gain: f64,
    pub slow_down_distance: f64,
    /// The goal counts as reached once it is less than this far ahead, m.
    pub arrive_m: f64,
    /// Slowest approach speed while the goal is still ahead, m/s.
    pub creep_speed: f64,
    pub progress_distance: f64,
    pub progress_window_s: f64,
    /// Frame period assumed before two stamps are known, s (the authors' 5 fps).
    pub nominal_period_s: f64,
    /// How long obstacle cells outside the view are remembered, s.
    pub memory_s: f64,
    /// Closer than this the camera does not see the floor-level space, so
    /// remembered cells are kept even inside the view's angle, m.
    pub memory_near_m: f64,
    /// Remembered cells farther than this are dropped, m.
    pub memory_range_m: f64,
    /// A remembered cell counts as measured again when the frame's depth
    /// reached to within this of it along its bearing, m (one voxel).
    pub memory_seen_margin_m: f64,
    /// Cells this close to the robot are remembered for `near_memory_s`, m.
    pub near_memory_m: f64,
    pub near_memory_s: f64,
    /// A cell that appeared where an earlier frame (at least
    /// `moving_lookback_s` before) saw free space is something moving — a
    /// person walking — and so is every cell of this frame within
    /// `moving_cluster_m` of it; out of view, moving cells are remembered
    /// for `moving_memory_s` only, so a person who walked past does not
    /// stay behind as a wall.
    pub moving_lookback_s: f64,
    pub moving_cluster_m: f64,
    pub moving_memory_s: f64,
    /// People tracked from the detector's boxes (see `people.rs`).
    pub people: PeopleParams,
    /// The obstacle cloud's `obstacle_height` and `voxel` (`CloudParams`;
    /// `actor::spawn` copies them): a cell's height above the floor is at
    /// least `obstacle_height_m + blocking · voxel_m`, m.
    pub obstacle_height_m: f64,
    pub voxel_m: f64,
    /// Radius of the disc a turn in place sweeps (half-diagonal + margin), m.
    pub sweep_radius_m: f64,
    /// Added to the sweep disc for remembered cells: where the odometry
    /// puts a cell seen seconds ago may be off by the slip since (a turn in
    /// place went ahead 5 cm clear of a plant remembered 16 s before, and
    /// its corner met the plant: evaluation, complex mission), m.
    pub memory_drift_m: f64,
    /// Half the robot's length and width, m (Husky A200: 0.99 m × 0.67 m).
    pub half_length_m: f64,
    pub half_width_m: f64,
    /// Speed of the straight move that clears the sweep disc, m/s.
    pub escape_speed: f64,
    /// Margin around the footprint the guard keeps free, m (one voxel).
    pub guard_margin_m: f64,
    /// Largest sideways move of a goal whose footprint holds an obstacle, m.
    pub goal_shift_max_m: f64,
    /// Largest turn of a landmark's goal round the landmark where no
    /// sideways move clears its footprint, rad.
    pub goal_orbit_max_rad: f64,
}

impl FollowParams {
    /// How high a cell stands at least, above the floor, m: its voxels
    /// above `obstacle_height_m` counted (`Cell::blocking`).
    fn top_of(&self, cell: &Cell) -> f64 {
        self.obstacle_height_m + f64::from(cell.blocking) * self.voxel_m
    }
}

impl Default for FollowParams {
    fn default() -> Self {
        let cloud = CloudParams::default();
        Self {
            look_ahead_m: 0.5,
            yaw_gain: 7.5,
            max_speed: 1.0,
            max_yaw_rate: 1.57,
            max_accel: 1.0,
            yaw_decel: 3.0,
            align_threshold: 0.2,
            rotate_threshold: 1.0,
            rerotate_threshold: 1.9,
            rotate_exit: 0.3,
            rotate_gain: 0.8,
            slow_down_distance: 1.0,
            arrive_m: 0.03,
            creep_speed: 0.08,
            progress_distance: 0.1,
            progress_window_s: 5.0,
            nominal_period_s: 0.2,
            memory_s: 20.0,
            memory_near_m: 0.6,
            memory_range_m: 4.25,
            memory_seen_margin_m: 0.05,
            near_memory_m: 1.0,
            near_memory_s: 120.0,
            moving_lookback_s: 0.25,
            moving_cluster_m: 0.3,
            moving_memory_s: 1.5,
            people: PeopleParams::default(),
            obstacle_height_m: cloud.obstacle_height,
            voxel_m: cloud.voxel,
            sweep_radius_m: 0.65,
            memory_drift_m: 0.05,
            half_length_m: 0.495,
            half_width_m: 0.335,
            escape_speed: 0.15,
            guard_margin_m: 0.05,
            goal_shift_max_m: 0.4,
            goal_orbit_max_rad: std::f64::consts::FRAC_PI_2,
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StepStatus {
    Moving,
    Rotating,
    Reached,
    Blocked,
    NoProgress,
}

/// What one frame asks of the planner.
#[derive(Clone, Debug)]
pub struct StepInput<'a> {
    pub stamp: f64,
    pub pose: Pose2,
    pub goal: GoalSpec,
    pub cloud: &'a ObstacleCloud,
    /// Cruise speed (≤ 0: the top speed), m/s.
    pub max_speed: f64,
    /// What the camera sees of the plane around the robot.
    pub view: View,
}

/// The camera's view in `base_link`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct View {
    /// Direction of the optical axis, rad (the mount's yaw).
    pub yaw: f64,
    /// Half the horizontal field of view, rad (D455: about 43°).
    pub half_fov: f64,
    /// Where the floor comes into view ahead, m along `base_link`'s x: the
    /// ground under the image's bottom row (a D455 0.6 m up, level: 1.16 m
    /// ahead of the base). Nearer floor is below the image. 0: everywhere.
    pub floor_from_m: f64,
    /// The camera's position in `base_link`: ahead of the base and above
    /// the floor, m. The bottom row's ray falls from there to the floor at
    /// `floor_from_m`, so an obstacle lower than the camera is in the image
    /// only beyond where that ray passes below its top ([`View::top_from`]).
    pub camera_x_m: f64,
    pub camera_z_m: f64,
}

impl View {
    /// The view of a pinhole camera `width` pixels wide with focal length
    /// `fx`, seeing the floor everywhere in its angle.
    pub fn pinhole(width: u32, fx: f64, yaw: f64) -> Self {
        Self { yaw, half_fov: (width as f64 / 2.0 / fx).atan(), floor_from_m: 0.0, camera_x_m: 0.0, camera_z_m: 0.0 }
    }

    /// The view of `camera`, with where its image's bottom row meets the
    /// floor (infinitely far when it never looks down to the floor).
    pub fn of_camera(camera: &vlnav_geometry::camera::Camera) -> Self {
        let projector = vlnav_geometry::camera::Projector::new(camera);
        let bottom = f64::from(camera.height) - 0.5;
        let floor_from_m = projector.ground_point(camera.intrinsics.cx, bottom).map_or(f64::INFINITY, |g| g.x.max(0.0));
        Self {
            floor_from_m,
            camera_x_m: camera.mount.translation.x,
            camera_z_m: camera.mount.translation.z,
            ..Self::pinhole(camera.width, camera.intrinsics.fx, camera.mount.yaw)
        }
    }

    fn sees(&self, p: &Vector2<f64>, near: f64) -> bool {
        p.norm() >= near && wrap_angle(p.y.atan2(p.x) - self.yaw).abs() < self.half_fov
    }

    /// Where something `top_m` high (above the floor) comes into the image
    /// ahead, m along x: where the bottom row's ray passes below its top.
    /// The floor itself (0 m): `floor_from_m`; as high as the camera or
    /// higher: the camera's own x. 0 when the image shows the floor everywhere.
    pub fn top_from(&self, top_m: f64) -> f64 {
        if self.floor_from_m <= 0.0 {
            0.0
        } else if top_m >= self.camera_z_m {
            self.camera_x_m.min(self.floor_from_m)
        } else {
            self.camera_x_m + (self.floor_from_m - self.camera_x_m) * (1.0 - top_m.max(0.0) / self.camera_z_m)
        }
    }

    /// Whether something `top_m` high at `p` is in the image: in the view's
    /// angle, and not so near that its top lies below the bottom row.
    fn sees_top(&self, p: &Vector2<f64>, near: f64, top_m: f64) -> bool {
        self.sees(p, near) && p.x >= self.top_from(top_m)
    }
}

/// An obstacle cell remembered in `odom`.
#[derive(Clone, Copy, Debug)]
struct Remembered {
    at: Vector2<f64>,
    cell: Cell,
    stamp: f64,
    /// Seen moving (see `FollowParams::moving_lookback_s`).
    moving: bool,
}

/// What one recent frame's depth saw, kept to tell moving cells from
/// standing ones.
#[derive(Clone, Debug, PartialEq)]
struct RecentView {
    stamp: f64,
    /// `base_link` in `odom` at the frame.
    pose: Pose2,
    seen: SeenRange,
}

/// How far beyond a cell an earlier frame must have seen free space for the
/// cell to count as new there: a voxel and three standard deviations of the
/// D455's depth error, which grows with the square of range (≈ 2 % at 4 m,
/// `docs/perception.md`), m.
fn moved_in_margin(range_m: f64) -> f64 {
    0.1 + 3.0 * vlnav_geometry::depth::d455_sigma_m(range_m)
}

/// How far to each side of a cell's bearing an earlier frame must have
/// seen free space for the cell to have moved in, rad: one 1° bin (an
/// outline falls anywhere inside the bin that holds it) plus the bearing
/// that the cell's own extent and odometry's jitter over the look-back
/// (`MOVED_IN_SLACK_M`) subtend at its range.
fn moved_in_half_angle(range_m: f64) -> f64 {
    1f64.to_radians() + (MOVED_IN_SLACK_M / range_m.max(0.1)).atan()
}

/// A cell's half-diagonal (0.035 m of a 5 cm voxel) plus 1.5 cm of odometry
/// jitter over the look-back, m.
const MOVED_IN_SLACK_M: f64 = 0.05;

/// The command and what led to it.
#[derive(Clone, Debug, PartialEq)]
pub struct StepOutput {
    pub linear: f64,
    pub angular: f64,
    pub status: StepStatus,
    pub selection: Option<Selection>,
    pub path_scale: f64,
    pub distance_to_goal: f64,
    /// Bearing of the goal from the heading (rotation goals: the yaw error), rad.
    pub heading_error: f64,
    pub free_paths: usize,
}

/// The state a robot keeps between frames.
#[derive(Clone, Debug, Default)]
pub struct RobotState {
    last_stamp: Option<f64>,
    last_speed: f64,
    rotating: bool,
    /// The robot has faced this goal once (rotate-in-place is done).
    aligned: bool,
    /// Best distance of the current window and the stamp it was reached.
    progress: Option<(f64, f64)>,
    last_goal: Option<GoalSpec>,
    /// The latest obstacle cloud (this frame's cells, then remembered
    /// ones) and chosen path.
    pub cloud: ObstacleCloud,
    /// How many of `cloud`'s cells this frame measured (the rest are remembered).
    measured_cells: usize,
    pub last_selection: Option<Selection>,
    /// The chosen path in odom, for the course it set.
    last_path_odom: Vec<Vector2<f64>>,
    /// One remembered cell per `odom` voxel, the newest (ordered, so that
    /// runs are reproducible).
    memory: BTreeMap<(i32, i32), Remembered>,
    /// The last second of frames' depth coverage, oldest first.
    recent: VecDeque<RecentView>,
    last_pose: Option<Pose2>,
    /// The goal (odom position) a move off its blocked footprint was chosen
    /// for, and the move.
    goal_shift: Option<(Vector2<f64>, GoalMove)>,
    /// The people seen lately, `odom`.
    people: Tracker,
    scratch: Scratch,
}

/// How a goal whose footprint holds an obstacle is moved off it.
#[derive(Clone, Copy, Debug, PartialEq)]
enum GoalMove {
    /// Sideways, across the goal's heading (left positive), m.
    Across(f64),
    /// Round the goal's landmark (counter-clockwise positive), its heading
    /// turned with it, rad.
    Round(f64),
}

impl GoalMove {
    /// The moved goal's position and heading (`odom`).
    fn apply(self, goal: &GoalSpec) -> (Vector2<f64>, f64) {
        let g = goal.pose;
        match (self, goal.landmark) {
            (GoalMove::Across(d), _) => (g.position() + Vector2::new(-g.theta.sin(), g.theta.cos()) * d, g.theta),
            (GoalMove::Round(a), Some(l)) => (l + Rotation2::new(a) * (g.position() - l), g.theta + a),
            (GoalMove::Round(_), None) => (g.position(), g.theta),
        }
    }
}

/// The step of a landmark goal's turn round its landmark, rad (5°).
const ORBIT_STEP_RAD: f64 = 5.0 * std::f64::consts::PI / 180.0;

/// What a turn in place must do first when its sweep disc is not free.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Sweep {
    /// Move straight at this speed (m/s, negative: backwards) to clear it.
    Escape(f64),
    /// Neither straight move clears it: turn on this forward arc (v, ω)
    /// instead, which keeps the footprint clear where the spot turn's
    /// corners would sweep over something.
    Arc(f64, f64),
    /// The way out is taken too.
    Blocked,
}

impl RobotState {
    /// `None` when a turn in place (`turn`, rad, signed) is free to go;
    /// otherwise how to clear the disc first: the shorter straight move
    /// (forward or back) that clears it, or when neither does within
    /// `SWEEP_ESCAPE_MAX_M` (backing, within `near_memory_m − sweep_radius_m`)
    /// with the body's lane free, the turn made on a forward arc
    /// ([`RobotState::arc_turn`]; `goal`: the position the turn faces, base
    /// link), or BLOCKED when no arc keeps clear either.
    fn sweep(
        &self,
        input: &StepInput<'_>,
        p: &FollowParams,
        turn: f64,
        goal: Option<&Vector2<f64>>,
        dt: f64,
    ) -> Option<Sweep> {
        // A remembered cell carries the odometry's drift since it was seen.
        let r_mem = p.sweep_radius_m + p.memory_drift_m;
        // A person gets a wider berth than furniture: their place (the
        // tracker's) counts `PeopleParams::radius_m` nearer, since people
        // sway and step while the corners swing.
        let people: Vec<Cell> = self
            .people
            .people_at(input.stamp, &input.pose, &p.people)
            .into_iter()
            .filter(|q| q.norm() > 1e-6)
            .map(|q| {
                let near = q * ((q.norm() - p.people.radius_m).max(0.0) / q.norm());
                Cell { x: near.x as f32, y: near.y as f32, blocking: 2, low: false, no_go: false, person: 1 }
            })
            .collect();
        // Each cell with the radius it must keep outside of.
        let (r_now, r_mem) = (p.sweep_radius_m as f32, r_mem as f32);
        let cells: Vec<(f32, f32, f32)> = self
            .cloud
            .cells
            .iter()
            .enumerate()
            .map(|(i, c)| (c.x, c.y, if i < self.measured_cells { r_now } else { r_mem }))
            .chain(people.iter().map(|c| (c.x, c.y, r_now)))
            .collect();
        let nearest = cells
            .iter()
            .filter(|(x, y, r)| x * x + y * y < r * r)
            .min_by(|a, b| (a.0 * a.0 + a.1 * a.1).total_cmp(&(b.0 * b.0 + b.1 * b.1)))?;
        // Straight along the robot's axis, the shortest move either way that
        // leaves every cell outside the disc, if the body's lane is free
        // that far (its half-length plus the sweep's margin, at least 0.1 m,
        // beyond). Moving away from the nearest cell alone flipped between
        // two obstacles ahead and behind, 3 cm each way, for over a minute
        // (evaluation, garage, trial 3: a parked car ahead-left, the
        // bicycle behind-right); the shortest clearing move does not flip,
        // since moving along it shortens it.
        let reach = (p.half_length_m + (p.sweep_radius_m - p.half_length_m).max(0.1)) as f32;
        let lane = p.half_width_m as f32 + 0.05;
        // Behind the camera the disc is known only from memory, kept for
        // long only within `near_memory_m` of the robot: backing out, the
        // disc where the robot ends must lie within it (a robot that backed
        // 0.75 m along a corridor wall forgotten there turned its corner
        // into it: evaluation, corridor, visual trial 1).
        let back_max = (p.near_memory_m - p.sweep_radius_m).max(0.0) as f32;
        // Each cell the disc can take in along the axis: its x and the half
        // chord the disc's circle cuts at its y (the disc centred at c holds
        // it while |x − c| < h).
        let chords: Vec<(f32, f32)> =
            cells.iter().filter(|(_, y, r)| y.abs() < *r).map(|&(x, y, r)| (x, (r * r - y * y).sqrt())).collect();
        let clearing = |dir: f32| -> Option<f32> {
            let mut s = 0.0_f32;
            loop {
                let need = chords
                    .iter()
                    .filter(|&&(x, h)| (dir * x - s).abs() < h)
                    .map(|&(x, h)| dir * x + h)
                    .fold(s, f32::max);
                if need <= s {
                    break;
                }
                s = need + 1e-3;
                if s > SWEEP_ESCAPE_MAX_M {
                    return None;
                }
            }
            let taken = cells.iter().any(|&(x, y, _)| dir * x > 0.0 && dir * x < s + reach && y.abs() < lane);
            (!taken && (dir > 0.0 || s <= back_max)).then_some(s)
        };
        let away = if nearest.0 > 0.0 { -1.0_f32 } else { 1.0 };
        let dir = match (clearing(away), clearing(-away)) {
            (Some(a), Some(b)) if b + 0.01 < a => -away,
            (Some(_), _) => away,
            (None, Some(_)) => -away,
            (None, None) => {
                let arc = self.arc_turn(turn, goal, dt, p).or_else(|| self.unwedge(turn, &cells, back_max, dt, p));
                return Some(arc.map_or(Sweep::Blocked, |(v, w)| Sweep::Arc(v, w)));
            }
        };
        Some(Sweep::Escape(f64::from(dir) * p.escape_speed))
    }
}

impl RobotState {
    /// Whether the arc (v, ω) held for `horizon` s brings a cell the body
    /// must keep out of (an obstacle or a no-go region, [`Cell::keeps_out`])
    /// into the (margin-inflated) footprint that it does not cover now, or
    /// a cell already within the margin into the body itself (a box 3 cm
    /// ahead of the bumper is not to be driven into because it stands in
    /// the margin already; a cell inside the body — noise, or contact made —
    /// does not hold the robot).
    fn footprint_hits(&self, v: f64, w: f64, horizon: f64, p: &FollowParams) -> bool {
        const SAMPLES: usize = 6;
        let (hl, hw) = ((p.half_length_m + p.guard_margin_m) as f32, (p.half_width_m + p.guard_margin_m) as f32);
        let (bl, bw) = (p.half_length_m as f32, p.half_width_m as f32);
        let inside = |x: f32, y: f32| x.abs() <= hl && y.abs() <= hw;
        let poses: Vec<(f32, f32, f32, f32)> = (1..=SAMPLES)
            .map(|k| {
                let t = horizon * k as f64 / SAMPLES as f64;
                let (x, y, th) = arc_pose(v, w, t);
                (x as f32, y as f32, th.cos() as f32, th.sin() as f32)
            })
            .collect();
        let reach = (hl * hl + hw * hw).sqrt() + (v.abs() * horizon) as f32;
        self.cloud
            .cells
            .iter()
            .filter(|c| {
                c.keeps_out() && c.x * c.x + c.y * c.y <= reach * reach && !(c.x.abs() <= bl && c.y.abs() <= bw)
            })
            .any(|c| {
                // The rectangle the cell must stay out of: the body for a
                // cell already within the margin, else the inflated one.
                let (l, w) = if inside(c.x, c.y) { (bl, bw) } else { (hl, hw) };
                poses.iter().any(|&(x, y, cs, sn)| {
                    let (dx, dy) = (c.x - x, c.y - y);
                    (cs * dx + sn * dy).abs() <= l && (-sn * dx + cs * dy).abs() <= w
                })
            })
    }

    /// Whether the footprint centred at `centre` (`base_link`) facing
    /// `heading` (rad, `base_link`) holds no cell the body must keep out of.
    fn footprint_clear_at(&self, centre: &Vector2<f64>, heading: f64, p: &FollowParams) -> bool {
        let (hl, hw) = (p.half_length_m + p.guard_margin_m, p.half_width_m + p.guard_margin_m);
        let (s, c) = heading.sin_cos();
        !self.cloud.cells.iter().filter(|cell| cell.keeps_out()).any(|cell| {
            let (dx, dy) = (f64::from(cell.x) - centre.x, f64::from(cell.y) - centre.y);
            (c * dx + s * dy).abs() <= hl && (-s * dx + c * dy).abs() <= hw
        })
    }

    /// Whether no cell the body must keep out of lies within `radius` of
    /// `centre` (`base_link`).
    fn disc_clear_at(&self, centre: &Vector2<f64>, radius: f64) -> bool {
        !self
            .cloud
            .cells
            .iter()
            .filter(|cell| cell.keeps_out())
            .any(|cell| (f64::from(cell.x) - centre.x).hypot(f64::from(cell.y) - centre.y) <= radius)
    }

    /// The goal's position (odom), moved off a footprint that holds an
    /// obstacle (docs above): sideways across its heading by the smallest
    /// shift up to `goal_shift_max_m` that clears it, else — for a goal at a
    /// landmark's stopping distance — round the landmark by the smallest
    /// turn up to `goal_orbit_max_rad` that clears it; unmoved when it is
    /// clear or nothing clears it.
    fn clear_goal(&mut self, input: &StepInput<'_>, p: &FollowParams) -> Vector2<f64> {
        let g = input.goal.pose;
        // A goal moved round its landmark must also leave the robot room to
        // turn on the spot there, as the step after a landmark mostly does:
        // its sweep disc free.
        let clear = |s: &Self, m: GoalMove| {
            let (at, heading) = m.apply(&input.goal);
            let centre = input.pose.inverse_transform(&at);
            s.footprint_clear_at(&centre, wrap_angle(heading - input.pose.theta), p)
                && (matches!(m, GoalMove::Across(_)) || s.disc_clear_at(&centre, p.sweep_radius_m))
        };
        let kept = self.goal_shift.filter(|(at, _)| (at - g.position()).norm() < 0.5).map(|(_, m)| m);
        let shifts = (p.goal_shift_max_m / 0.05).round() as i32;
        let across = (0..=shifts).flat_map(|k| [f64::from(k) * 0.05, -f64::from(k) * 0.05]).map(GoalMove::Across);
        // Round the landmark both ways, each turn's nearer side first.
        let turns =
            if input.goal.landmark.is_some() { (p.goal_orbit_max_rad / ORBIT_STEP_RAD).round() as i32 } else { 0 };
        let here = input.pose.position();
        let round = (1..=turns).flat_map(|k| {
            let mut both =
                [GoalMove::Round(f64::from(k) * ORBIT_STEP_RAD), GoalMove::Round(-f64::from(k) * ORBIT_STEP_RAD)];
            let away = |m: &GoalMove| (m.apply(&input.goal).0 - here).norm();
            both.sort_by(|a, b| away(a).total_cmp(&away(b)));
            both
        });
        let chosen =
            kept.into_iter().chain(across).chain(round).find(|&m| clear(self, m)).unwrap_or(GoalMove::Across(0.0));
        self.goal_shift = Some((g.position(), chosen));
        chosen.apply(&input.goal).0
    }

    /// The command itself if its arc keeps the footprint clear (and `ok`
    /// accepts it), else the first such of: the turn alone, the straight
    /// part alone, a stop.
    fn guard(&self, v: f64, w: f64, dt: f64, p: &FollowParams, ok: &dyn Fn(f64, f64) -> bool) -> (f64, f64) {
        [(v, w), (0.0, w), (v, 0.0)]
            .into_iter()
            .find(|&(v, w)| {
                (v != 0.0 || w != 0.0) && !self.footprint_hits(v, w, stop_horizon(v, w, dt, p), p) && ok(v, w)
            })
            .unwrap_or((0.0, 0.0))
    }

    /// What the robot does when the footprint guard stops every part of a
    /// path's command: a path that bends away from a zone the robot stands
    /// beside swings the rear corner into it, and stopped there it would
    /// wait for ever. It creeps on (`escape_speed`) toward the goal's side,
    /// where the guard lets it, until the turn is free: forward, on the
    /// sharpest of `CREEP_CURVATURES` that turns toward the goal and keeps
    /// the footprint clear, else straight; backward, straight. A driver
    /// pulls out of a tight spot that way: per radian of turn the rear
    /// corner swings out as far on an arc as on the spot, but on the arc the
    /// body moves forward meanwhile, so the corner follows something that
    /// runs alongside and outward (a cable along the rear-left) instead of
    /// sweeping over it, while straight on can only close in on what stands
    /// ahead (evaluation, lab: a robot that stopped before a chair with a
    /// cable along its rear-left crept straight into the chair and wedged
    /// itself there).
    fn creep(&self, goal_base: &Vector2<f64>, dt: f64, p: &FollowParams) -> (f64, f64) {
        if goal_base.x < 0.0 {
            return self.guard(-p.escape_speed, 0.0, dt, p, &|_, _| true);
        }
        let side = if goal_base.y.atan2(goal_base.x).abs() < CREEP_STRAIGHT_RAD { 0.0 } else { goal_base.y.signum() };
        let v = p.escape_speed;
        let arcs: &[f64] = if side == 0.0 { &[] } else { &CREEP_CURVATURES };
        let moves: Vec<(f64, f64)> = arcs.iter().map(|k| (v, side * k * v)).chain([(v, 0.0)]).collect();
        // First a move that stays clear while held for `CREEP_HOLD_S` (a
        // sharp arc clear for one frame can swing the rear onto the cable
        // the next), then one clear for a frame and its stop.
        moves
            .iter()
            .find(|&&m| self.clear_for(m, CREEP_HOLD_S, dt, p))
            .or_else(|| moves.iter().find(|&&m| self.clear_for(m, 0.0, dt, p)))
            .copied()
            .unwrap_or((0.0, 0.0))
    }

    /// A turn in place toward `turn`'s side that its sweep forbids (the
    /// corners of a spot turn reach every point of the sweep disc's rim,
    /// but on an arc of radius R the rear corner swings out by about
    /// l² / 2 (R + w) only: l the half-length, w the half-width — 0.09 m at
    /// R = 1 m), made on the sharpest of `CREEP_CURVATURES` forward at
    /// `escape_speed` that keeps the footprint clear while held for
    /// `CREEP_HOLD_S`. Toward a goal position (`goal`, base link) only an arc
    /// whose circle leaves it outside: inside, the robot would circle it for
    /// ever. `None` when no arc is clear (evaluation, lab: a robot that ended
    /// a move beside a cable along its left, told to turn right, was BLOCKED
    /// and asked the user).
    fn arc_turn(&self, turn: f64, goal: Option<&Vector2<f64>>, dt: f64, p: &FollowParams) -> Option<(f64, f64)> {
        let side = turn.signum();
        let v = p.escape_speed;
        CREEP_CURVATURES
            .iter()
            .filter(|&&k| goal.is_none_or(|g| (g - Vector2::new(0.0, side / k)).norm() > 1.0 / k))
            .map(|&k| (v, side * k * v))
            .find(|&m| self.clear_for(m, CREEP_HOLD_S, dt, p))
    }

    /// Where no arc completes the turn (each either hits something or
    /// circles the goal), the move that frees the sweep disc soonest, so
    /// that the turn can then be made on the spot: forward or backward (no
    /// farther than `back_max`, m) at `escape_speed` on one of
    /// `CREEP_CURVATURES` either way, held clear until, within
    /// `UNWEDGE_MAX_S`, the disc centred where the robot then stands holds
    /// none of `cells` (x, y, the radius each must keep outside of, base
    /// link); among equally soon, toward the turn's side and forward first.
    /// Taking it frame after frame shortens it, so the robot does not
    /// dither; a goal inside the arc's circle is no trap, since the arc is
    /// left once the disc is free (evaluation, lab: a robot stopped before
    /// a chair, with a cable along its left and the landmark to revisit on
    /// its right, inside every forward arc's circle, reported BLOCKED, its
    /// search legs ran into the chair, and it asked for a plant in view of
    /// where it stood).
    fn unwedge(
        &self,
        turn: f64,
        cells: &[(f32, f32, f32)],
        back_max: f32,
        dt: f64,
        p: &FollowParams,
    ) -> Option<(f64, f64)> {
        const STEP_S: f64 = 0.5;
        let side = turn.signum();
        let v = p.escape_speed;
        let disc_free = |x: f64, y: f64| {
            cells.iter().all(|&(cx, cy, r)| {
                let (dx, dy) = (f64::from(cx) - x, f64::from(cy) - y);
                dx * dx + dy * dy >= f64::from(r * r)
            })
        };
        let moves = [v, -v].into_iter().flat_map(|v| {
            [side, -side].into_iter().flat_map(move |s| CREEP_CURVATURES.iter().map(move |k| (v, s * k * v.abs())))
        });
        let steps = (UNWEDGE_MAX_S / STEP_S).round() as u32;
        moves
            .filter_map(|(v, w)| {
                (1..=steps)
                    .map(|i| f64::from(i) * STEP_S)
                    .take_while(|&t| {
                        (v > 0.0 || v.abs() * t <= f64::from(back_max)) && self.clear_for((v, w), t, dt, p)
                    })
                    .find(|&t| {
                        let (x, y, _) = arc_pose(v, w, t);
                        disc_free(x, y)
                    })
                    .map(|t| (t, (v, w)))
            })
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .map(|(_, m)| m)
    }

    /// Whether the footprint stays clear on the arc (v, ω) held for `hold`
    /// s, or for a frame and its stop if that is longer.
    fn clear_for(&self, (v, w): (f64, f64), hold: f64, dt: f64, p: &FollowParams) -> bool {
        !self.footprint_hits(v, w, hold.max(stop_horizon(v, w, dt, p)), p)
    }
}

/// Where the arc (v, ω) held for `t` s takes the robot, base link at its
/// start: x, y and heading.
fn arc_pose(v: f64, w: f64, t: f64) -> (f64, f64, f64) {
    let th = w * t;
    if w.abs() < 1e-6 { (v * t, 0.0, th) } else { (v / w * th.sin(), v / w * (1.0 - th.cos()), th) }
}

/// How long the guard follows an arc: one frame, then as long as stopping
/// takes — the linear part at `max_accel`, the turn at `yaw_decel` (a spot
/// turn's rear corner swings on while it brakes), s.
fn stop_horizon(v: f64, w: f64, dt: f64, p: &FollowParams) -> f64 {
    dt + (v.abs() / (2.0 * p.max_accel)).max(w.abs() / (2.0 * p.yaw_decel))
}

/// The curvatures a creep tries toward the goal's side, sharpest first,
/// 1/m (radii 0.5, 1 and 2 m); the goal within `CREEP_STRAIGHT_RAD` of the
/// heading, it creeps straight.
const CREEP_CURVATURES: [f64; 3] = [2.0, 1.0, 0.5];
const CREEP_STRAIGHT_RAD: f64 = 0.1;
/// How long a creep's arc should stay clear if held, s (0.15 m of travel
/// at `escape_speed`).
const CREEP_HOLD_S: f64 = 1.0;

/// The longest straight move that may clear the sweep disc before a turn
/// in place, m (its diameter): farther, the turn goes on an arc, if one is clear.
const SWEEP_ESCAPE_MAX_M: f32 = 1.3;

/// The longest a move that frees the sweep disc may take before the turn,
/// s ([`RobotState::unwedge`]; 0.6 m at `escape_speed`).
const UNWEDGE_MAX_S: f64 = 4.0;

/// Side of the `odom` grid the memory keeps one cell per, m (the cloud's voxel).
const MEMORY_VOXEL: f64 = 0.05;

fn memory_key(at: &Vector2<f64>) -> (i32, i32) {
    ((at.x / MEMORY_VOXEL).floor() as i32, (at.y / MEMORY_VOXEL).floor() as i32)
}

fn clamp_turn(rate: f64, error: f64, p: &FollowParams, dt: f64) -> f64 {
    // Never turn past the target bearing within one frame period, nor faster
    // than lets the robot still stop on it.
    let cap = p.max_yaw_rate.min(error.abs() / dt.max(1e-3)).min((2.0 * p.yaw_decel * error.abs()).sqrt());
    rate.clamp(-cap, cap)
}

impl RobotState {
    /// This frame's cells plus remembered cells outside the view; the
    /// memory becomes this frame's cells and the still-valid old ones.
    fn merge_memory(&mut self, cloud: &ObstacleCloud, input: &StepInput<'_>, p: &FollowParams) -> ObstacleCloud {
        let mut cells = cloud.cells.clone();
        self.measured_cells = cells.len();
        let ats: Vec<Vector2<f64>> =
            cloud.cells.iter().map(|c| input.pose.transform(&Vector2::new(c.x as f64, c.y as f64))).collect();
        let people: Vec<Option<Vector2<f64>>> =
            cloud.people.iter().map(|at| at.map(|b| input.pose.transform(&b))).collect();
        self.people.update(input.stamp, &people, &p.people);
        let moving = self.moving_cells(cloud, &ats, input.stamp, p);
        let now: Vec<((i32, i32), Remembered)> = cloud
            .cells
            .iter()
            .zip(&ats)
            .zip(moving)
            .map(|((c, &at), moving)| (memory_key(&at), Remembered { at, cell: *c, stamp: input.stamp, moving }))
            .collect();
        let current: BTreeSet<(i32, i32)> = now.iter().map(|(k, _)| *k).collect();
        self.memory.retain(|k, m| {
            let b = input.pose.inverse_transform(&m.at);
            let age = input.stamp - m.stamp;
            if current.contains(k)
                || (m.moving && age > p.moving_memory_s)
                || (age > p.memory_s && !(age <= p.near_memory_s && b.norm() <= p.near_memory_m))
            {
                return false;
            }
            let measured = cloud.seen.as_ref().is_none_or(|s| s.reaches(&b, p.memory_seen_margin_m));
            // A cell is looked at only where the image shows its top: depth
            // along its bearing passes over something low whether or not
            // the camera sees it. A marking on the floor (a no-go cell with
            // nothing standing on it) needs the floor itself in the image —
            // a cable the robot is about to cross lies below the bottom row
            // — and a water bottle 0.75 m ahead of a D455 0.6 m up is below
            // it too.
            let top = if m.cell.no_go && m.cell.blocking < 2 { 0.0 } else { p.top_of(&m.cell) };
            let looked_at = input.view.sees_top(&b, p.memory_near_m, top);
            if b.norm() > p.memory_range_m || (measured && looked_at) {
                return false;
            }
            cells.push(Cell { x: b.x as f32, y: b.y as f32, ..m.cell });
            true
        });
        self.memory.extend(now);
        if let Some(seen) = &cloud.seen {
            self.recent.push_back(RecentView { stamp: input.stamp, pose: input.pose, seen: seen.clone() });
            while self.recent.front().is_some_and(|v| input.stamp - v.stamp > 4.0 * p.moving_lookback_s) {
                self.recent.pop_front();
            }
        }
        ObstacleCloud { cells, raw_points: cloud.raw_points, seen: cloud.seen.clone(), people: cloud.people.clone() }
    }

    /// Which of this frame's cells belong to something moving: a cell where
    /// the newest frame at least `moving_lookback_s` old saw free space
    /// beyond it, this frame's cells near such a cell (the same body), and
    /// cells near a cell remembered as moving within `moving_memory_s` (the
    /// same body a moment ago: a person who pauses is still a person). A
    /// cell remembered as standing (a wall seen before the person came
    /// beside it) never becomes moving. `ats`: the cells in `odom`.
    fn moving_cells(&self, cloud: &ObstacleCloud, ats: &[Vector2<f64>], stamp: f64, p: &FollowParams) -> Vec<bool> {
        let mut moving = vec![false; cloud.cells.len()];
        let earlier = self.recent.iter().rev().find(|v| stamp - v.stamp >= p.moving_lookback_s);
        let r = p.moving_cluster_m;
        let recently_moving: Vec<Vector2<f64>> =
            self.memory.values().filter(|m| m.moving && stamp - m.stamp <= p.moving_memory_s).map(|m| m.at).collect();
        let mut seeds = Vec::new();
        let mut standing = vec![false; cloud.cells.len()];
        for (k, (c, at)) in cloud.cells.iter().zip(ats).enumerate() {
            if c.blocking == 0 {
                continue;
            }
            if self.memory.get(&memory_key(at)).is_some_and(|m| !m.moving && m.stamp < stamp) {
                standing[k] = true;
                continue;
            }
            let moved_in = earlier.is_some_and(|e| {
                let then = e.pose.inverse_transform(at);
                e.seen.free_beyond(&then, moved_in_margin(then.norm()), moved_in_half_angle(then.norm()))
            });
            if moved_in || recently_moving.iter().any(|q| (q - at).norm() <= r) {
                moving[k] = true;
                seeds.push((c.x, c.y));
            }
        }
        let r2 = (r * r) as f32;
        for (k, c) in cloud.cells.iter().enumerate() {
            if !moving[k]
                && !standing[k]
                && c.blocking > 0
                && seeds.iter().any(|&(x, y)| (c.x - x) * (c.x - x) + (c.y - y) * (c.y - y) <= r2)
            {
                moving[k] = true;
            }
        }
        moving
    }

    /// At debug level: why the robot is blocked — the remembered cells
    /// within `radius` m (base_link), their age, their blocking voxels and
    /// whether they move.
    fn log_blocked(&self, input: &StepInput<'_>, radius: f64, why: &str) {
        if !tracing::enabled!(tracing::Level::DEBUG) {
            return;
        }
        let cells: Vec<String> = self
            .memory
            .values()
            .map(|m| (input.pose.inverse_transform(&m.at), m))
            .filter(|(b, _)| b.norm() < radius)
            .map(|(b, m)| {
                format!(
                    "({:.2}, {:.2}) {:.1} s, {} voxels{}",
                    b.x,
                    b.y,
                    input.stamp - m.stamp,
                    m.cell.blocking,
                    if m.moving { " moving" } else { "" }
                )
            })
            .collect();
        tracing::debug!(stamp = input.stamp, ?cells, "{why}");
    }

    /// Whether the command (v, ω), held for `PeopleParams::horizon_s`,
    /// brings the robot's body nearer a walker than their reach and nearer
    /// than standing still would (see the module docs). Logged at debug level.
    fn people_closer(&self, input: &StepInput<'_>, v: f64, w: f64, p: &FollowParams) -> bool {
        const SAMPLES: usize = 10;
        let pp = &p.people;
        if v == 0.0 && w == 0.0 {
            return false;
        }
        let walkers = self.people.walkers_ahead(input.stamp, 0.0, &input.pose, pp).len();
        if walkers == 0 {
            return false;
        }
        // Distance from the footprint at (x, y, θ) to the point q.
        let gap = |q: &Vector2<f64>, x: f64, y: f64, th: f64| {
            let (s, c) = th.sin_cos();
            let (dx, dy) = (q.x - x, q.y - y);
            let (bx, by) = (c * dx + s * dy, -s * dx + c * dy);
            Vector2::new((bx.abs() - p.half_length_m).max(0.0), (by.abs() - p.half_width_m).max(0.0)).norm()
        };
        let mut moving = vec![f64::INFINITY; walkers];
        let mut still = vec![f64::INFINITY; walkers];
        for k in 0..=SAMPLES {
            let t = pp.horizon_s * k as f64 / SAMPLES as f64;
            let (x, y, th) = arc_pose(v, w, t);
            for (i, (q, reach)) in self.people.walkers_ahead(input.stamp, t, &input.pose, pp).iter().enumerate() {
                moving[i] = moving[i].min(gap(q, x, y, th) - reach);
                still[i] = still[i].min(gap(q, 0.0, 0.0, 0.0) - reach);
            }
        }
        let closer = moving.iter().zip(&still).any(|(m, s)| *m < 0.0 && *m < *s - 0.01);
        if closer {
            tracing::debug!(stamp = input.stamp, v, w, "waiting for a walking person");
        }
        closer
    }

    /// Obstacle cells currently remembered (this frame's included).
    pub fn remembered_cells(&self) -> usize {
        self.memory.len()
    }

    /// Plans one step. `cloud` replaces the stored cloud.
    pub fn step(&mut self, planner: &Planner, p: &FollowParams, input: StepInput<'_>) -> StepOutput {
        let dt = match self.last_stamp {
            Some(t) if input.stamp > t && input.stamp - t < 2.0 => input.stamp - t,
            _ => p.nominal_period_s,
        };
        let time_went_back = self.last_stamp.is_some_and(|t| input.stamp < t);
        let jumped = self
            .last_pose
            .is_some_and(|q| (q.position() - input.pose.position()).norm() > 0.5 + 2.0 * p.max_speed * dt);
        if time_went_back {
            self.memory.clear();
            self.recent.clear();
            self.people.clear();
            self.last_path_odom.clear();
        } else if let (true, Some(last)) = (jumped, self.last_pose) {
            self.recent.clear();
            // Re-anchored odometry: the robot has not moved, its frame has.
            let old = std::mem::take(&mut self.memory);
            for (_, mut m) in old {
                m.at = input.pose.transform(&last.inverse_transform(&m.at));
                self.memory.insert(memory_key(&m.at), m);
            }
            self.people.reanchor(|at| input.pose.transform(&last.inverse_transform(at)));
            self.last_path_odom.clear();
        }
        self.last_pose = Some(input.pose);
        self.last_stamp = Some(input.stamp);
        if self.last_goal != Some(input.goal) {
            self.last_goal = Some(input.goal);
            self.progress = None;
            self.rotating = false;
            self.aligned = false;
        }
        self.cloud = self.merge_memory(input.cloud, &input, p);
        let goal = input.goal;
        let goal_at = if goal.rotation_only { goal.pose.position() } else { self.clear_goal(&input, p) };
        let goal_base = input.pose.inverse_transform(&goal_at);
        let distance = goal_base.norm();
        let bearing = if distance > 1e-9 { goal_base.y.atan2(goal_base.x) } else { 0.0 };
        let mut out = StepOutput {
            linear: 0.0,
            angular: 0.0,
            status: StepStatus::Reached,
            selection: None,
            path_scale: 0.0,
            distance_to_goal: distance,
            heading_error: bearing,
            free_paths: 0,
        };
        let stop = |s: &mut Self, mut out: StepOutput, status: StepStatus| {
            s.last_speed = 0.0;
            s.last_path_odom.clear();
            s.progress = None;
            out.status = status;
            out
        };
        if goal.rotation_only {
            let yaw_error = wrap_angle(goal.pose.theta - input.pose.theta);
            out.heading_error = yaw_error;
            if yaw_error.abs() < goal.yaw_tolerance {
                return stop(self, out, StepStatus::Reached);
            }
            match self.sweep(&input, p, yaw_error, None, dt) {
                Some(Sweep::Blocked) => return stop(self, out, StepStatus::Blocked),
                Some(Sweep::Escape(v)) => out.linear = v,
                Some(Sweep::Arc(v, w)) => (out.linear, out.angular) = (v, w),
                None => out.angular = clamp_turn(p.rotate_gain * yaw_error, yaw_error, p, dt),
            }
            if self.people_closer(&input, out.linear, out.angular, p) {
                (out.linear, out.angular) = (0.0, 0.0);
            }
            return stop(self, out, StepStatus::Rotating);
        }
        if distance <= p.arrive_m || (distance <= goal.position_tolerance && goal_base.x <= p.arrive_m) {
            self.rotating = false;
            return stop(self, out, StepStatus::Reached);
        }
        let exit = match (self.rotating, self.aligned) {
            (true, _) => p.rotate_exit,
            (false, false) => p.rotate_threshold,
            (false, true) => p.rerotate_threshold,
        };
        self.rotating = bearing.abs() > exit;
        self.aligned |= !self.rotating;
        if self.rotating {
            match self.sweep(&input, p, bearing, Some(&goal_base), dt) {
                Some(Sweep::Blocked) => {
                    self.log_blocked(&input, p.sweep_radius_m, "a turn in place is blocked");
                    return stop(self, out, StepStatus::Blocked);
                }
                Some(Sweep::Escape(v)) => out.linear = v,
                Some(Sweep::Arc(v, w)) => (out.linear, out.angular) = (v, w),
                None => out.angular = clamp_turn(p.rotate_gain * bearing, bearing, p, dt),
            }
            if self.people_closer(&input, out.linear, out.angular, p) {
                (out.linear, out.angular) = (0.0, 0.0);
            }
            return stop(self, out, StepStatus::Rotating);
        }

        let speed = if input.max_speed > 0.0 { input.max_speed.min(p.max_speed) } else { p.max_speed };
        // Near a walker, no faster than the robot stops from within the
        // reach it allows them (see `PeopleParams::near_walker_mps`).
        let speed = if self.people.walker_within(input.stamp, &input.pose, p.people.near_walker_m, &p.people) {
            speed.min(p.people.near_walker_mps)
        } else {
            speed
        };
        // The course held: where last frame's path crosses the look-ahead circle now.
        let course = self
            .last_path_odom
            .iter()
            .map(|q| input.pose.inverse_transform(q))
            .find(|q| q.norm() >= p.look_ahead_m && q.x > 0.0)
            .map_or(0.0, |q| q.y.atan2(q.x));
        let plan = planner.plan(&self.cloud, goal_base, speed / p.max_speed, course, &mut self.scratch);
        out.free_paths = plan.free_paths;
        out.path_scale = plan.scale;
        let Some(sel) = plan.selection else {
            self.log_blocked(&input, 1.2, "no free path");
            self.last_selection = None;
            self.last_path_odom.clear();
            return stop(self, out, StepStatus::Blocked);
        };
        let look = sel
            .points
            .iter()
            .find(|q| q.norm() >= p.look_ahead_m)
            .or(sel.points.last())
            .copied()
            .unwrap_or_else(|| Vector2::new(1.0, 0.0));
        let dir = look.y.atan2(look.x);
        out.angular = clamp_turn(p.yaw_gain * dir, dir, p, dt);
        // Aim at the middle of the arrival band: one frame's travel never
        // carries the robot past the goal. (On a detour, with the goal well
        // off the heading, the distance to it is what is left.)
        let left = if bearing.abs() < std::f64::consts::FRAC_PI_4 { goal_base.x } else { distance };
        let ahead = (left - p.arrive_m / 2.0).max(0.0);
        let target = (speed * (distance / p.slow_down_distance).min(1.0)).max(p.creep_speed).min(ahead / dt);
        let v = if dir.abs() < p.align_threshold {
            (self.last_speed + p.max_accel * dt).min(target)
        } else {
            (self.last_speed - p.max_accel * dt).max(0.0).min(target)
        };
        let (v, w) = self.guard(v, out.angular, dt, p, &|_, _| true);
        if v == 0.0 && w == 0.0 && distance <= goal.position_tolerance {
            // As close as the body fits.
            self.rotating = false;
            out.angular = 0.0;
            return stop(self, out, StepStatus::Reached);
        }
        let (v, w) = if v == 0.0 && w == 0.0 { self.creep(&goal_base, dt, p) } else { (v, w) };
        if v == 0.0 && w == 0.0 {
            self.log_blocked(&input, p.sweep_radius_m, "the footprint guard stops every command");
        }
        let (v, w) = if self.people_closer(&input, v, w, p) {
            // Yield to a walker: the parts of the command that keep clear of
            // them, or a stop; waiting for people is no lack of progress.
            self.progress = None;
            self.guard(v, w, dt, p, &|v, w| !self.people_closer(&input, v, w, p))
        } else {
            (v, w)
        };
        out.linear = v;
        out.angular = w;
        self.last_path_odom = sel.points.iter().step_by(5).map(|q| input.pose.transform(q)).collect();
        out.selection = Some(sel.clone());
        self.last_selection = Some(sel);
        out.status = StepStatus::Moving;

        // Progress watchdog, sensor time.
        match self.progress {
            None => self.progress = Some((distance, input.stamp)),
            Some((best, _)) if distance <= best - p.progress_distance => self.progress = Some((distance, input.stamp)),
            Some((_, since)) if input.stamp - since >= p.progress_window_s => {
                self.progress = Some((distance, input.stamp));
                self.last_speed = 0.0;
                out.linear = 0.0;
                out.angular = 0.0;
                out.status = StepStatus::NoProgress;
                return out;
            }
            Some(_) => {}
        }
        self.last_speed = v;
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cloud::SeenRange;

    /// Turns a Husky-like yaw axis (6 rad/s² acceleration limit; each
    /// frame's command held over the next frame period, as the edge agent
    /// does) onto a bearing `target` rad away; returns the largest overshoot
    /// past it, rad.
    fn overshoot(p: &FollowParams, target: f64, dt: f64) -> f64 {
        let (mut heading, mut rate, mut worst) = (0.0_f64, 0.0_f64, 0.0_f64);
        for _ in 0..(5.0 / dt) as usize {
            let command = clamp_turn(p.yaw_gain * (target - heading), target - heading, p, dt);
            for _ in 0..10 {
                let step = 6.0 * dt / 10.0;
                rate += (command - rate).clamp(-step, step);
                heading += rate * dt / 10.0;
            }
            worst = worst.max(heading - target);
        }
        worst
    }

    /// A frame whose depth reached `reach` m along every bearing except
    /// those within `hole` (rad, from the camera at the origin), with no
    /// obstacle cells.
    fn frame(reach: f64, hole: Option<(f64, f64)>) -> ObstacleCloud {
        let mut seen = SeenRange::new(Vector2::zeros());
        for k in 0..3600 {
            let a = -std::f64::consts::PI + k as f64 / 3600.0 * std::f64::consts::TAU;
            if hole.is_some_and(|(lo, hi)| a >= lo && a <= hi) {
                continue;
            }
            seen.record(reach * a.cos(), reach * a.sin());
        }
        ObstacleCloud { seen: Some(seen), ..ObstacleCloud::default() }
    }

    /// The cells planned with after merging `cloud` into the memory, seen with `view`.
    /// A level view ±0.75 rad wide that shows the floor everywhere.
    fn view_ahead() -> View {
        View { yaw: 0.0, half_fov: 0.75, floor_from_m: 0.0, camera_x_m: 0.0, camera_z_m: 0.0 }
    }

    fn merged_in_view(state: &mut RobotState, cloud: &ObstacleCloud, stamp: f64, view: View) -> Vec<Cell> {
        let p = FollowParams::default();
        let input = StepInput {
            stamp,
            pose: Pose2::new(0.0, 0.0, 0.0),
            goal: GoalSpec {
                pose: Pose2::new(3.0, 0.0, 0.0),
                position_tolerance: 0.3,
                yaw_tolerance: 0.2,
                rotation_only: false,
                landmark: None,
            },
            cloud,
            max_speed: 0.0,
            view,
        };
        state.merge_memory(cloud, &input, &p).cells
    }

    fn remembered_after(state: &mut RobotState, cloud: &ObstacleCloud, stamp: f64) -> usize {
        merged_in_view(state, cloud, stamp, view_ahead()).len()
    }

    #[test]
    fn remembered_cells_are_forgotten_only_where_the_depth_reached_them() {
        let wall = Cell { x: 2.0, y: 0.5, blocking: 3, low: false, no_go: false, person: 0 };
        let bearing = 0.5_f64.atan2(2.0);
        let seen_wall = ObstacleCloud { cells: vec![wall], ..frame(2.0, None) };
        let mut state = RobotState::default();
        assert_eq!(remembered_after(&mut state, &seen_wall, 0.0), 1);
        // An occlusion band over the wall's bearing: nothing measured there,
        // so the wall stays although it is inside the view's angle.
        let hole = frame(4.0, Some((bearing - 0.05, bearing + 0.05)));
        assert_eq!(remembered_after(&mut state, &hole, 0.2), 1);
        // Depth that stops short of the wall (the floor seen to 1.5 m) did
        // not measure it either.
        assert_eq!(remembered_after(&mut state, &frame(1.5, None), 0.4), 1);
        // Depth that reached past it: the wall has gone.
        assert_eq!(remembered_after(&mut state, &frame(4.0, None), 0.6), 0);
        // Without coverage (clouds not built from depth) the view's angle
        // decides, as before.
        let mut state = RobotState::default();
        remembered_after(&mut state, &seen_wall, 0.0);
        assert_eq!(remembered_after(&mut state, &ObstacleCloud::default(), 0.2), 0);
    }

    #[test]
    fn a_floor_marking_below_the_image_is_remembered_until_the_image_shows_that_floor() {
        // A cable 0.9 m ahead: inside the view's angle, and the depth along
        // its bearing reaches 4 m (the floor and the walls beyond), but the
        // floor shows in the image only from 1.16 m on.
        let view = View { floor_from_m: 1.16, camera_x_m: 0.3, camera_z_m: 0.6, ..view_ahead() };
        let cable = Cell { x: 0.9, y: 0.1, blocking: 0, low: false, no_go: true, person: 0 };
        let remembered = |state: &mut RobotState, cloud: &ObstacleCloud, stamp: f64, view: View| {
            merged_in_view(state, cloud, stamp, view).len()
        };
        let mut state = RobotState::default();
        assert_eq!(remembered(&mut state, &ObstacleCloud { cells: vec![cable], ..frame(4.0, None) }, 0.0, view), 1);
        assert_eq!(remembered(&mut state, &frame(4.0, None), 0.2, view), 1, "below the image: remembered");
        // A camera that shows the floor there and no longer sees the cable: gone.
        let low = View { floor_from_m: 0.5, ..view };
        assert_eq!(remembered(&mut state, &frame(4.0, None), 0.4, low), 0);
        // An obstacle there is forgotten as before: the depth measured past it.
        let mut state = RobotState::default();
        let post = Cell { blocking: 3, no_go: false, ..cable };
        remembered(&mut state, &ObstacleCloud { cells: vec![post], ..frame(4.0, None) }, 0.0, view);
        assert_eq!(remembered(&mut state, &frame(4.0, None), 0.2, view), 0);
    }

    #[test]
    fn a_low_obstacle_below_the_image_is_remembered_until_the_image_shows_its_top() {
        // The simulated D455, 0.6 m up and 0.3 m ahead, shows the floor from
        // 1.16 m on: the top of a water bottle 0.3 m high (three voxels above
        // 0.15 m) from 0.73 m on. Nearer, the depth along its bearing passes
        // over it.
        let view = View { floor_from_m: 1.16, camera_x_m: 0.3, camera_z_m: 0.6, ..view_ahead() };
        assert!((view.top_from(0.30) - 0.73).abs() < 1e-9, "{}", view.top_from(0.30));
        assert_eq!(view.top_from(0.0), 1.16);
        assert_eq!(view.top_from(1.5), 0.3, "taller than the camera: in view from the camera on");
        let bottle = Cell { x: 0.7, y: -0.1, blocking: 3, low: false, no_go: false, person: 0 };
        let mut state = RobotState::default();
        let seen =
            |state: &mut RobotState, cloud: &ObstacleCloud, stamp: f64| merged_in_view(state, cloud, stamp, view);
        assert_eq!(seen(&mut state, &ObstacleCloud { cells: vec![bottle], ..frame(4.0, None) }, 0.0).len(), 1);
        assert_eq!(seen(&mut state, &frame(4.0, None), 0.2).len(), 1, "below the image: remembered");
        // A person there, taller than the camera, is in the image: gone
        // when the depth reaches past where they stood.
        let mut state = RobotState::default();
        let person = Cell { blocking: 30, ..bottle };
        seen(&mut state, &ObstacleCloud { cells: vec![person], ..frame(4.0, None) }, 0.0);
        assert!(seen(&mut state, &frame(4.0, None), 0.2).is_empty());
        // The bottle farther off, with its top in the image: forgotten too.
        let mut state = RobotState::default();
        let far = Cell { x: 0.9, ..bottle };
        seen(&mut state, &ObstacleCloud { cells: vec![far], ..frame(4.0, None) }, 0.0);
        assert!(seen(&mut state, &frame(4.0, None), 0.2).is_empty());
    }

    #[test]
    fn the_floor_comes_into_view_where_the_bottom_row_meets_it() {
        use vlnav_geometry::camera::{Camera, Intrinsics, Mount};
        // The simulated D455: 0.6 m up, 0.3 m ahead, level; 480 rows, fy 343.
        let camera = Camera {
            width: 640,
            height: 480,
            intrinsics: Intrinsics { fx: 343.159, fy: 343.159, cx: 320.5, cy: 240.5 },
            mount: Mount { translation: nalgebra::Vector3::new(0.3, 0.0, 0.6), ..Mount::default() },
            depth_min_m: 0.0,
            depth_max_m: 10.0,
        };
        let view = View::of_camera(&camera);
        let expected = 0.3 + 0.6 * 343.159 / (479.5 - 240.5);
        assert!((view.floor_from_m - expected).abs() < 1e-6, "{view:?} vs {expected}");
        assert!((view.half_fov - (320.0f64 / 343.159).atan()).abs() < 1e-12);
    }

    #[test]
    fn a_cell_that_appeared_in_free_space_is_moving_and_soon_forgotten_out_of_view() {
        // Beside the robot, outside the ±43° view: only the memory holds it.
        let person = Cell { x: 0.2, y: 1.0, blocking: 3, low: false, no_go: false, person: 0 };
        let sofa = Cell { x: -0.2, y: 1.0, blocking: 3, low: false, no_go: false, person: 0 };
        let mut state = RobotState::default();
        // The sofa was there from the first frame; the space where the person
        // now stands was seen free (depth reached 4 m all round).
        assert_eq!(remembered_after(&mut state, &ObstacleCloud { cells: vec![sofa], ..frame(4.0, None) }, 0.0), 1);
        let both = ObstacleCloud { cells: vec![sofa, person], ..frame(4.0, None) };
        assert_eq!(remembered_after(&mut state, &both, 0.3), 2);
        let moving: Vec<bool> = state.memory.values().map(|m| m.moving).collect();
        assert_eq!(moving.iter().filter(|m| **m).count(), 1, "the person moves, the sofa stands: {moving:?}");
        // Out of view, a moving cell is remembered for 1.5 s, a standing one for 20 s.
        assert_eq!(remembered_after(&mut state, &frame(4.0, None), 1.5), 2);
        assert_eq!(remembered_after(&mut state, &frame(4.0, None), 2.0), 1);
        assert_eq!(remembered_after(&mut state, &frame(4.0, None), 15.0), 1);
    }

    /// One frame of a robot at `pose` looking at a post of radius 0.25 m
    /// standing at `post` (odom) in an empty hall whose floor and walls the
    /// depth reached 10 m away: the post's visible outline as 5 cm cells
    /// (`base_link`) and the range seen along every bearing.
    fn post_frame(pose: Pose2, post: Vector2<f64>) -> ObstacleCloud {
        let c = pose.inverse_transform(&post);
        let (r, half_fov) = (0.25, 0.75);
        let mut seen = SeenRange::new(Vector2::zeros());
        let mut cells: Vec<Cell> = Vec::new();
        for k in 0..7200 {
            let a = -std::f64::consts::PI + k as f64 / 7200.0 * std::f64::consts::TAU;
            if a.abs() > half_fov {
                continue;
            }
            let dir = Vector2::new(a.cos(), a.sin());
            // Nearest intersection of the ray with the post's circle.
            let along = dir.dot(&c);
            let miss = (c - dir * along).norm();
            if along > 0.0 && miss < r {
                let hit = dir * (along - (r * r - miss * miss).sqrt());
                seen.record_obstacle(hit.x, hit.y);
                let (x, y) =
                    ((hit.x / 0.05).floor() as f32 * 0.05 + 0.025, (hit.y / 0.05).floor() as f32 * 0.05 + 0.025);
                if !cells.iter().any(|q| q.x == x && q.y == y) {
                    cells.push(Cell { x, y, blocking: 3, low: false, no_go: false, person: 0 });
                }
            } else {
                seen.record(10.0 * dir.x, 10.0 * dir.y);
            }
        }
        ObstacleCloud { cells, raw_points: 0, seen: Some(seen), people: vec![] }
    }

    #[test]
    fn a_standing_post_seen_while_turning_or_driving_never_counts_as_moving() {
        // The outline of a standing thing shifts between bins as the robot
        // turns or nears it, and odometry's heading is off by up to half a
        // degree from frame to frame; none of its cells moved in.
        let p = FollowParams::default();
        let post = Vector2::new(3.5, 0.4);
        let goal = GoalSpec {
            pose: Pose2::new(3.0, 0.0, 0.0),
            position_tolerance: 0.3,
            yaw_tolerance: 0.2,
            rotation_only: false,
            landmark: None,
        };
        for drive in [false, true] {
            let mut state = RobotState::default();
            for k in 0..60 {
                let t = k as f64 * 0.1;
                let pose = if drive {
                    Pose2::new(0.4 * t, -0.05 * t, 0.02 * t)
                } else {
                    Pose2::new(0.0, 0.0, -0.6 + 0.26 * t)
                };
                let cloud = post_frame(pose, post);
                let odom = Pose2::new(pose.x, pose.y, pose.theta + if k % 2 == 0 { 0.008 } else { -0.008 });
                let input = StepInput { stamp: t, pose: odom, goal, cloud: &cloud, max_speed: 0.0, view: view_ahead() };
                state.merge_memory(&cloud, &input, &p);
                let moving: Vec<Vector2<f64>> = state.memory.values().filter(|m| m.moving).map(|m| m.at).collect();
                assert!(
                    moving.is_empty(),
                    "driving {drive}, {t:.1} s: the post's cells at {moving:?} counted as moving"
                );
            }
        }
    }

    #[test]
    fn a_post_that_slides_across_the_view_counts_as_moving() {
        // The same post carried across at 0.6 m/s, 3 m ahead: a person walking.
        let p = FollowParams::default();
        let goal = GoalSpec {
            pose: Pose2::new(3.0, 0.0, 0.0),
            position_tolerance: 0.3,
            yaw_tolerance: 0.2,
            rotation_only: false,
            landmark: None,
        };
        let mut state = RobotState::default();
        let mut seen_moving = 0;
        for k in 0..20 {
            let t = k as f64 * 0.1;
            let cloud = post_frame(Pose2::new(0.0, 0.0, 0.0), Vector2::new(3.0, -0.6 + 0.6 * t));
            let input = StepInput {
                stamp: t,
                pose: Pose2::new(0.0, 0.0, 0.0),
                goal,
                cloud: &cloud,
                max_speed: 0.0,
                view: view_ahead(),
            };
            state.merge_memory(&cloud, &input, &p);
            seen_moving += usize::from(state.memory.values().any(|m| m.moving && m.stamp == t));
        }
        assert!(seen_moving >= 15, "moving in only {seen_moving} of 20 frames");
    }

    fn with_cells(cells: &[(f32, f32)]) -> RobotState {
        let cells =
            cells.iter().map(|&(x, y)| Cell { x, y, blocking: 3, low: false, no_go: false, person: 0 }).collect();
        RobotState { cloud: ObstacleCloud { cells, ..ObstacleCloud::default() }, ..RobotState::default() }
    }

    #[test]
    fn the_guard_keeps_the_footprint_off_obstacles_the_path_tube_misses() {
        let p = FollowParams::default();
        // A post diagonally ahead, 0.45 m to the left: clear of the straight
        // footprint (half-width 0.335 + 0.05), but driving a left arc swings
        // the front-left corner into it. Turning on the spot (one frame) is
        // clear, so the forward part waits.
        let post = with_cells(&[(0.6, 0.45)]);
        assert_eq!(post.guard(0.5, 1.0, 0.2, &p, &|_, _| true), (0.0, 1.0));
        // With the spot turn also blocked (a second post where the rear-right
        // corner swings), the
        // straight part alone is left.
        let posts = with_cells(&[(0.6, 0.45), (-0.45, -0.45)]);
        assert_eq!(posts.guard(0.5, 1.0, 0.2, &p, &|_, _| true), (0.5, 0.0));
        // Turning away from it is fine.
        assert_eq!(post.guard(0.5, -1.0, 0.2, &p, &|_, _| true), (0.5, -1.0));
        // A wall straight ahead within a frame and the stopping distance: stop.
        let wall = with_cells(&[(0.8, -0.1), (0.8, 0.0), (0.8, 0.1)]);
        assert_eq!(wall.guard(0.6, 0.0, 0.2, &p, &|_, _| true), (0.0, 0.0));
        // Far enough ahead to stop before it: go on.
        let far = with_cells(&[(1.6, 0.0)]);
        assert_eq!(far.guard(0.6, 0.0, 0.2, &p, &|_, _| true), (0.6, 0.0));
        // A cell the footprint already covers does not freeze the robot.
        let touching = with_cells(&[(0.3, 0.2)]);
        assert_eq!(touching.guard(-0.15, 0.0, 0.2, &p, &|_, _| true), (-0.15, 0.0));
        // One voxel is noise, not an obstacle.
        let ghost = RobotState {
            cloud: ObstacleCloud {
                cells: vec![Cell { x: 0.7, y: 0.0, blocking: 1, low: false, no_go: false, person: 0 }],
                ..ObstacleCloud::default()
            },
            ..RobotState::default()
        };
        assert_eq!(ghost.guard(0.5, 0.0, 0.2, &p, &|_, _| true), (0.5, 0.0));
    }

    #[test]
    fn the_guard_keeps_the_footprint_out_of_no_go_regions_too() {
        let p = FollowParams::default();
        // A cable's end diagonally ahead, 0.45 m to the left, on the floor:
        // no voxel above it, only the segmenter's no-go cell. A left arc
        // would swing the front-left corner over it, as it would into a post.
        let cable = |no_go| RobotState {
            cloud: ObstacleCloud {
                cells: vec![Cell { x: 0.6, y: 0.45, blocking: 0, low: false, no_go, person: 0 }],
                ..ObstacleCloud::default()
            },
            ..RobotState::default()
        };
        assert_eq!(cable(true).guard(0.5, 1.0, 0.2, &p, &|_, _| true), (0.0, 1.0));
        assert_eq!(
            cable(false).guard(0.5, 1.0, 0.2, &p, &|_, _| true),
            (0.5, 1.0),
            "a bare floor cell is no reason to stop"
        );
        // A goal whose footprint would lie on it is moved sideways off it.
        assert!(!cable(true).footprint_clear_at(&Vector2::new(0.6, 0.2), 0.0, &p));
        assert!(cable(true).footprint_clear_at(&Vector2::new(0.6, -0.0), 0.0, &p));
    }

    #[test]
    fn a_robot_beside_a_zone_creeps_on_when_the_turn_away_would_swing_its_rear_into_it() {
        let p = FollowParams::default();
        // A no-go rug along the left side, 0.40 m from the centre, from
        // beside the robot to 0.7 m ahead (remembered: it is out of view).
        let cells: Vec<Cell> = (0..9)
            .flat_map(|i| {
                (0..4).map(move |j| Cell {
                    x: -0.1 + 0.1 * i as f32,
                    y: 0.40 + 0.1 * j as f32,
                    blocking: 0,
                    low: false,
                    no_go: true,
                    person: 0,
                })
            })
            .collect();
        let state = RobotState { cloud: ObstacleCloud { cells, ..ObstacleCloud::default() }, ..RobotState::default() };
        // Turning right on the spot swings the rear-left corner into the rug.
        assert_eq!(state.guard(0.0, -1.57, 0.2, &p, &|_, _| true), (0.0, 0.0));
        // Straight on keeps its distance: the robot creeps toward the goal.
        assert_eq!(state.creep(&Vector2::new(3.4, 0.5), 0.2, &p), (p.escape_speed, 0.0));
        assert_eq!(state.creep(&Vector2::new(-2.0, 0.0), 0.2, &p), (-p.escape_speed, 0.0));
        // Not into something in the way.
        let mut walled = state.clone();
        walled.cloud.cells.push(Cell { x: 0.57, y: 0.0, blocking: 5, low: false, no_go: false, person: 0 });
        assert_eq!(walled.creep(&Vector2::new(3.4, 0.5), 0.2, &p), (0.0, 0.0));
    }

    #[test]
    fn a_robot_between_a_cable_and_a_chair_pulls_out_on_an_arc_toward_the_goal() {
        let p = FollowParams::default();
        // A floor cable along the rear-left (no-go), running farther out
        // ahead, and a chair's corner ahead-left, as a robot stands after
        // stopping before a chair beside a cable (evaluation, lab).
        let mut cells: Vec<Cell> = (0..9)
            .map(|i| {
                let x = -0.36 + 0.05 * i as f32;
                Cell { x, y: 0.45 + 0.5 * (x + 0.36), blocking: 0, low: false, no_go: true, person: 0 }
            })
            .collect();
        cells.extend([(0.47, 0.44), (0.51, 0.40), (0.55, 0.38)].map(|(x, y)| Cell {
            x,
            y,
            blocking: 13,
            low: false,
            no_go: false,
            person: 0,
        }));
        let state = RobotState { cloud: ObstacleCloud { cells, ..ObstacleCloud::default() }, ..RobotState::default() };
        let goal = Vector2::new(1.21, -0.62);
        // Turning right toward the goal swings the rear-left corner over the
        // cable, on the spot or on the path's tight arc.
        assert_eq!(state.guard(0.0, -1.0, 0.2, &p, &|_, _| true), (0.0, 0.0));
        assert_eq!(state.guard(0.1, -1.0, 0.2, &p, &|_, _| true), (0.0, 0.0));
        // It creeps on an arc toward the goal (radius 1 m), not straight at
        // the chair, and that arc keeps the footprint off both while held
        // for a second (5 frames).
        let (v, w) = state.creep(&goal, 0.2, &p);
        assert_eq!((v, w), (p.escape_speed, -p.escape_speed));
        assert!(!state.footprint_hits(v, w, 1.0, &p));
        assert!(state.footprint_hits(v, 0.0, stop_horizon(v, 0.0, 0.2, &p), &p));
        // The sharper 0.5 m arc is clear for a frame, but held it swings the
        // rear-left corner onto the cable.
        assert!(!state.footprint_hits(v, 2.0 * w, stop_horizon(v, 2.0 * w, 0.2, &p), &p));
        assert!(state.footprint_hits(v, 2.0 * w, 1.0, &p));
        // A goal dead ahead is crept to straight.
        let clear = RobotState::default();
        assert_eq!(clear.creep(&Vector2::new(2.0, 0.05), 0.2, &p), (p.escape_speed, 0.0));
    }

    #[test]
    fn a_spot_turn_beside_a_parked_bicycle_counts_the_sweep_while_it_brakes() {
        let p = FollowParams::default();
        // The bicycle's side runs along the robot's right, 0.55 m from its
        // centre, from 1 m behind to beside the centre.
        let cells: Vec<Cell> = (0..21)
            .map(|i| Cell { x: -1.0 + 0.05 * i as f32, y: -0.55, blocking: 10, low: false, no_go: false, person: 0 })
            .collect();
        let state = RobotState { cloud: ObstacleCloud { cells, ..ObstacleCloud::default() }, ..RobotState::default() };
        // Turning left at 1.5 rad/s the rear-right corner swings toward it:
        // one frame (0.3 rad) keeps clear, but braking at 3 rad/s² takes
        // 0.375 rad more, and the inflated corner crosses the side at about
        // 0.42 rad: the robot stops (and creeps on, `creep`).
        assert_eq!(state.guard(0.0, 1.5, 0.2, &p, &|_, _| true), (0.0, 0.0));
        // Braking counted over one frame only, the turn went ahead.
        assert!(!state.footprint_hits(0.0, 1.5, 0.2, &p));
        // Turning right swings it away.
        assert_eq!(state.guard(0.0, -1.5, 0.2, &p, &|_, _| true), (0.0, -1.5));
    }

    /// A turn in place at the origin to `yaw`, with no cells measured this frame.
    fn turn_in_place_to(yaw: f64, empty: &ObstacleCloud) -> StepInput<'_> {
        StepInput {
            stamp: 0.0,
            pose: Pose2::new(0.0, 0.0, 0.0),
            goal: GoalSpec {
                pose: Pose2::new(0.0, 0.0, yaw),
                position_tolerance: 0.3,
                yaw_tolerance: 0.2,
                rotation_only: true,
                landmark: None,
            },
            cloud: empty,
            max_speed: 0.0,
            view: view_ahead(),
        }
    }

    #[test]
    fn a_remembered_cell_counts_farther_out_for_a_turn_in_place() {
        let p = FollowParams::default();
        // 0.67 m behind-right: outside the 0.65 m disc, inside 0.70 m.
        let cell = Cell { x: -0.4, y: -0.5375, blocking: 10, low: false, no_go: false, person: 0 };
        let cloud = ObstacleCloud { cells: vec![cell], ..ObstacleCloud::default() };
        let mut state = RobotState { cloud, measured_cells: 1, ..RobotState::default() };
        let empty = ObstacleCloud::default();
        let input = turn_in_place_to(3.0, &empty);
        assert_eq!(
            state.sweep(&input, &p, input.goal.pose.theta, None, 0.2),
            None,
            "measured this frame: the turn may go"
        );
        state.measured_cells = 0;
        assert_eq!(
            state.sweep(&input, &p, input.goal.pose.theta, None, 0.2),
            Some(Sweep::Escape(p.escape_speed)),
            "remembered: move away first"
        );
        // A person standing 0.9 m to the left (their body's edge 0.6 m off,
        // the cells of this frame outside the disc): people get 0.3 m more.
        let seen = |at: Vector2<f64>, frames: u32| {
            let mut state = RobotState::default();
            for k in 0..frames {
                state.people.update(-0.2 * f64::from(frames - k), &[Some(at)], &p.people);
            }
            state
        };
        let beside = seen(Vector2::new(0.0, 0.9), 3);
        assert_eq!(
            beside.sweep(&input, &p, input.goal.pose.theta, None, 0.2),
            Some(Sweep::Escape(p.escape_speed)),
            "a person beside: move away first"
        );
        assert_eq!(
            seen(Vector2::new(0.0, 1.0), 3).sweep(&input, &p, input.goal.pose.theta, None, 0.2),
            None,
            "a person 1.0 m off: the turn may go"
        );
        assert_eq!(
            seen(Vector2::new(0.0, 0.9), 1).sweep(&input, &p, input.goal.pose.theta, None, 0.2),
            None,
            "one box (a false positive?) is no person yet"
        );
    }

    #[test]
    fn a_turn_wedged_between_two_obstacles_backs_out_one_way_not_both() {
        let p = FollowParams::default();
        let wall = |x0: f32, y: f32, n: usize| -> Vec<Cell> {
            (0..n)
                .map(|i| Cell { x: x0 + 0.05 * i as f32, y, blocking: 10, low: false, no_go: false, person: 0 })
                .collect()
        };
        // A parked car's corner ahead-left (0.632 m off), its side running
        // away from the robot's axis, and a bicycle's end behind-right
        // (0.638 m off): both in the 0.65 m disc.
        let mut cells: Vec<Cell> = (0..20)
            .map(|i| Cell {
                x: 0.25 + 0.0475 * i as f32,
                y: 0.58 + 0.0155 * i as f32,
                blocking: 10,
                low: false,
                no_go: false,
                person: 0,
            })
            .collect();
        cells.extend(wall(-0.48, -0.42, 1));
        let at = |dx: f32| {
            let cells = cells.iter().map(|c| Cell { x: c.x - dx, ..*c }).collect();
            RobotState {
                cloud: ObstacleCloud { cells, ..ObstacleCloud::default() },
                measured_cells: 21,
                ..RobotState::default()
            }
        };
        let empty = ObstacleCloud::default();
        let input = turn_in_place_to(-1.3, &empty);
        // The nearest cell is the car's corner, ahead: moving away from it
        // backs toward the bicycle, whose end is then the nearest, and the
        // robot went 3 cm each way for ever. Going on clears the disc past
        // the car's corner (about 0.5 m); backing out would take 1 m past
        // the bicycle. After a 3 cm step either way the answer is the same.
        for dx in [0.0, 0.03, 0.06, -0.03] {
            let state = at(dx);
            assert_eq!(
                state.sweep(&input, &p, input.goal.pose.theta, None, 0.2),
                Some(Sweep::Escape(p.escape_speed)),
                "moved {dx} m"
            );
        }
        // With the car's side running on close beside the lane and a crate
        // 1 m behind, neither way clears the disc. The car's side begins
        // beside the robot's middle, and the rear corner that swings out
        // passes behind its end: the turn goes on the sharpest arc, 0.5 m,
        // to the right.
        let mut boxed = wall(-0.2, 0.5, 40);
        boxed.extend(wall(-1.0, 0.0, 1));
        let state = |cells: Vec<Cell>| RobotState {
            measured_cells: cells.len(),
            cloud: ObstacleCloud { cells, ..ObstacleCloud::default() },
            ..RobotState::default()
        };
        let v = p.escape_speed;
        assert_eq!(state(boxed.clone()).sweep(&input, &p, -1.3, None, 0.2), Some(Sweep::Arc(v, -2.0 * v)));
        // A crate across the way ahead as well: BLOCKED.
        let mut shut = boxed;
        shut.extend((0..21).map(|i| Cell { y: -0.5 + 0.05 * i as f32, ..wall(0.62, 0.0, 1)[0] }));
        assert_eq!(state(shut).sweep(&input, &p, -1.3, None, 0.2), Some(Sweep::Blocked));
    }

    #[test]
    fn a_cell_within_the_guard_margin_is_not_driven_into() {
        let p = FollowParams::default();
        // A box 0.03 m ahead of the bumper: inside the margin-inflated
        // footprint already, outside the body.
        let cell = Cell { x: 0.525, y: 0.0, blocking: 3, low: false, no_go: false, person: 0 };
        let state = RobotState {
            measured_cells: 1,
            cloud: ObstacleCloud { cells: vec![cell], ..ObstacleCloud::default() },
            ..RobotState::default()
        };
        assert!(state.footprint_hits(0.15, 0.0, 1.0, &p), "forward: into the body");
        assert!(state.footprint_hits(0.15, 0.3, 1.0, &p), "forward on an arc: into the body");
        assert!(!state.footprint_hits(-0.15, 0.0, 1.0, &p), "backing away");
        // Inside the body (noise, or contact made): it holds nothing.
        let touching = RobotState {
            cloud: ObstacleCloud { cells: vec![Cell { x: 0.45, ..cell }], ..ObstacleCloud::default() },
            ..RobotState::default()
        };
        assert!(!touching.footprint_hits(0.15, 0.0, 1.0, &p));
    }

    #[test]
    fn a_turn_whose_sweep_crosses_a_cable_alongside_is_made_on_an_arc() {
        let p = FollowParams::default();
        // A cable on the floor along the robot's left, 0.6 m from its
        // centre (inside the 0.65 m disc), from 1 m behind to 2 m ahead: a
        // move ended beside it (evaluation, lab), and the next step turns
        // right by 130°.
        let cable: Vec<Cell> = (0..61)
            .map(|i| Cell { x: -1.0 + 0.05 * i as f32, y: 0.6, blocking: 0, low: false, no_go: true, person: 0 })
            .collect();
        let state = RobotState {
            measured_cells: cable.len(),
            cloud: ObstacleCloud { cells: cable, ..ObstacleCloud::default() },
            ..RobotState::default()
        };
        let empty = ObstacleCloud::default();
        let input = turn_in_place_to(-2.26, &empty);
        // Turning on the spot, the rear-left corner sweeps over the cable;
        // no straight move clears the disc.
        assert!(state.footprint_hits(0.0, -1.0, 2.26, &p));
        let Some(Sweep::Arc(v, w)) = state.sweep(&input, &p, -2.26, None, 0.2) else {
            panic!("the turn is made on an arc")
        };
        assert!(v > 0.0 && w < 0.0, "forward, to the right: ({v}, {w})");
        // Held until the heading is reached (13 s at 0.15 m/s on the 0.5 m
        // arc), that arc never reaches the cable.
        assert!(!state.footprint_hits(v, w, 2.26 / w.abs(), &p));
        // Facing a goal inside every arc's circle (0.4 m to the right), the
        // robot would circle it on any of them: it takes the move that frees
        // the sweep disc soonest instead, held clear until the disc is free
        // (its centre 0.65 m from the cable), and turns on the spot from there.
        let Some(Sweep::Arc(v, w)) = state.sweep(&input, &p, -1.57, Some(&Vector2::new(0.0, -0.4)), 0.2) else {
            panic!("the disc is freed on an arc")
        };
        let freed = (1..=8).map(|i| f64::from(i) * 0.5).find(|&t| {
            let th = w * t;
            0.6 - v / w * (1.0 - th.cos()) >= p.sweep_radius_m && (v / w * th.sin()).abs() < 2.0
        });
        let t = freed.expect("the move frees the disc within UNWEDGE_MAX_S");
        assert!(t <= UNWEDGE_MAX_S);
        assert!(!state.footprint_hits(v, w, t, &p), "held clear until then");
        assert!(w < 0.0, "away from the cable: ({v}, {w})");
    }

    #[test]
    fn a_robot_boxed_in_on_every_side_is_blocked_not_unwedged() {
        let p = FollowParams::default();
        // A cable along the left and the right, 0.6 m from the centre, and
        // crates 0.15 m beyond the bumpers: no move frees the disc.
        let mut cells: Vec<Cell> = (0..61)
            .flat_map(|i| {
                let x = -1.0 + 0.05 * i as f32;
                [0.6_f32, -0.6].map(|y| Cell { x, y, blocking: 0, low: false, no_go: true, person: 0 })
            })
            .collect();
        cells.extend((0..13).flat_map(|i| {
            let y = -0.3 + 0.05 * i as f32;
            [0.65_f32, -0.65].map(|x| Cell { x, y, blocking: 3, low: false, no_go: false, person: 0 })
        }));
        let state = RobotState {
            measured_cells: cells.len(),
            cloud: ObstacleCloud { cells, ..ObstacleCloud::default() },
            ..RobotState::default()
        };
        let empty = ObstacleCloud::default();
        let input = turn_in_place_to(1.57, &empty);
        assert_eq!(state.sweep(&input, &p, 1.57, None, 0.2), Some(Sweep::Blocked));
    }

    #[test]
    fn turn_commands_leave_room_to_stop_on_the_bearing() {
        let p = FollowParams::default();
        // Full yaw rate only while the bearing leaves room to brake at yaw_decel.
        assert_eq!(clamp_turn(10.0, 1.0, &p, 0.1), p.max_yaw_rate);
        assert!((clamp_turn(10.0, 0.1, &p, 0.1) - (2.0 * p.yaw_decel * 0.1_f64).sqrt()).abs() < 1e-12);
        assert_eq!(clamp_turn(-10.0, -0.1, &p, 0.1), -(2.0 * p.yaw_decel * 0.1_f64).sqrt());
        // Closed loop at the demo's 10 fps: without the braking cap the robot
        // swings well past the bearing; with it, it settles onto it.
        let unbraked = FollowParams { yaw_decel: f64::INFINITY, ..p };
        for target in [0.3, 0.6, 1.0] {
            let (with, without) = (overshoot(&p, target, 0.1), overshoot(&unbraked, target, 0.1));
            assert!(without > 0.08, "target {target}: the unbraked turn overshoots ({without:.3} rad)");
            assert!(with < 0.4 * without, "target {target}: braked {with:.3} rad vs unbraked {without:.3} rad");
        }
    }

    #[test]
    fn a_landmark_goal_on_a_cable_is_moved_round_the_landmark_where_no_sideways_shift_clears_it() {
        let p = FollowParams::default();
        // A chair 2.25 m ahead, its goal 1.25 m before it, and a floor cable
        // across the approach 1.5 m ahead, under the goal's front, from
        // 0.6 m right to 1.5 m left: along it no sideways shift clears the
        // goal (evaluation, lab: robots that stopped short of the cable
        // stood where the chair hid the plant of the next step).
        let cells: Vec<Cell> = (0..43)
            .map(|i| Cell { x: 1.5, y: -0.6 + 0.05 * i as f32, blocking: 0, low: false, no_go: true, person: 0 })
            .collect();
        let cloud = ObstacleCloud { cells: cells.clone(), ..ObstacleCloud::default() };
        let chair = Vector2::new(2.25, 0.0);
        let goal = GoalSpec {
            pose: Pose2::new(1.0, 0.0, 0.0),
            position_tolerance: 0.25,
            yaw_tolerance: 0.2,
            rotation_only: false,
            landmark: Some(chair),
        };
        let input = StepInput {
            stamp: 0.0,
            pose: Pose2::new(0.0, 0.0, 0.0),
            goal,
            cloud: &cloud,
            max_speed: 0.0,
            view: view_ahead(),
        };
        let mut state = RobotState { cloud: cloud.clone(), ..RobotState::default() };
        for k in -8..=8 {
            let (at, heading) = GoalMove::Across(0.05 * f64::from(k)).apply(&goal);
            assert!(!state.footprint_clear_at(&at, heading, &p), "a shift of {:.2} m clears it", 0.05 * f64::from(k));
        }
        // Round the chair, past the cable's end (the right), at the same
        // distance from the chair, with room to turn on the spot there.
        let at = state.clear_goal(&input, &p);
        assert!(((at - chair).norm() - 1.25).abs() < 1e-9, "{at:?}");
        assert!(at.y < -0.6, "{at:?}");
        let Some((_, GoalMove::Round(turn))) = state.goal_shift else { panic!("{:?}", state.goal_shift) };
        assert!(turn > 0.0 && turn <= p.goal_orbit_max_rad, "{turn}");
        assert!(state.footprint_clear_at(&at, turn, &p));
        assert!(state.disc_clear_at(&at, p.sweep_radius_m));
        // The smallest such turn: one step less is blocked.
        let (before, heading) = GoalMove::Round(turn - ORBIT_STEP_RAD).apply(&goal);
        assert!(
            !state.footprint_clear_at(&before, heading, &p) || !state.disc_clear_at(&before, p.sweep_radius_m),
            "{turn}"
        );
        // Kept on the next frame, while it stays clear.
        assert_eq!(state.clear_goal(&input, &p), at);
        // A goal at no landmark (a MOVE's end) is left where it is.
        let mut plain = RobotState { cloud: cloud.clone(), ..RobotState::default() };
        let no_landmark = StepInput { goal: GoalSpec { landmark: None, ..goal }, ..input.clone() };
        assert_eq!(plain.clear_goal(&no_landmark, &p), goal.pose.position());
    }
}
