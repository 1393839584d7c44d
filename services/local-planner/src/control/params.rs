//! The local planner's path-following, guard and watchdog settings
//! ([`FollowParams`]): the Husky A200's limits and the tuned values each
//! behaviour module of `control` reads.

use nalgebra::Vector2;

use crate::cloud::{Cell, CloudParams};
use crate::people::PeopleParams;

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
    /// Plan detours on the rolling grid when the direct way makes no
    /// progress (`detour.rs`).
    pub detour: bool,
    /// Keep what the depth has seen and report the frontier of what it has
    /// not (`frontier.rs`), for the executor's search for a target.
    pub frontier: bool,
    /// A stuck step plans through narrow passages with the planner's
    /// narrow tables (`narrow.rs`; the planner needs them:
    /// `PlannerParams::narrow_clearance_m`). Off here, so that each
    /// behaviour's tests see the usual paths; the service turns it on
    /// (`Options::narrow`, `--local-planner-narrow`).
    pub narrow: bool,
}

impl FollowParams {
    /// How high a cell stands at least, above the floor, m: its voxels
    /// above `obstacle_height_m` counted (`Cell::blocking`).
    pub(super) fn top_of(&self, cell: &Cell) -> f64 {
        self.obstacle_height_m + f64::from(cell.blocking) * self.voxel_m
    }

    /// Half the robot's length and width, m, as one vector (`base_link`'s x
    /// and y): what the people tracker measures a course's gap to the body
    /// with (`people.rs`).
    pub fn half_extents(&self) -> Vector2<f64> {
        Vector2::new(self.half_length_m, self.half_width_m)
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
            detour: false,
            frontier: false,
            narrow: false,
        }
    }
}
