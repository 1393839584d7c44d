//! One robot's planning step: goal checks, rotate-in-place, path selection,
//! path following to (v, ω) and the progress watchdog. Time comes only from
//! frame stamps.
//!
//! [`RobotState::step`] takes a frame through the behaviours in order, one
//! module each, each with its own tests:
//!
//! | module | behaviour |
//! |---|---|
//! | `memory.rs` | obstacle memory in `odom`, moving cells, re-anchoring |
//! | `goal.rs` | a goal whose footprint holds an obstacle is moved off it |
//! | `rotate.rs` | rotate in place toward a goal far off the heading, or to a yaw |
//! | `sweep.rs` | a turn in place clears its sweep disc first (escape, arc, unwedge) |
//! | `follow.rs` | path following: the chosen path's look-ahead point to (v, ω) |
//! | `guard.rs` | the footprint guard every command passes |
//! | `creep.rs` | a robot the guard stops creeps on toward the goal's side |
//! | `backout.rs` | a robot the guard and the creep leave wedged backs out, then goes on |
//! | `behind.rs` | walkers who alone turn the paths far off are followed, not gone round |
//! | `walkers.rs` | no command closes on a walking person; a way blocked near a person is WAITING |
//! | `giveway.rs` | a robot that waited for a person backs away along its own trail |
//! | `narrow.rs` | a stuck step plans through narrow passages, slowly (`--local-planner-narrow`, on by default) |
//! | `detour.rs` | a way beyond the paths' reach, searched on a rolling grid when stuck |
//! | `frontier.rs` | what the depth has seen lately, and the nearest edge of what it has not (`--local-planner-frontier`, off by default) |
//! | `progress.rs` | the no-progress watchdog |
//! | `params.rs`, `view.rs` | the settings and the camera's view |
//!
//! Reached: the goal is no longer ahead — its distance along the heading is
//! below `arrive_m` (0.03 m) — while it lies within
//! `goal.position_tolerance`; or the robot is within `arrive_m` of it; or,
//! for a pure rotation, the yaw error is below `goal.yaw_tolerance`. The
//! tolerance is the sideways slack a goal allows, not where the robot may
//! stop short: stopping at the tolerance circle left every approach about
//! 0.26 m short of the asked distance (docs/design.md §6).

mod backout;
mod behind;
mod creep;
mod detour;
mod follow;
mod frontier;
mod giveway;
mod goal;
mod guard;
mod memory;
mod narrow;
mod params;
mod progress;
mod rotate;
mod sweep;
#[cfg(test)]
mod test_support;
mod view;
mod walkers;

use std::collections::{BTreeMap, VecDeque};

use nalgebra::Vector2;
use vlnav_geometry::{GoalSpec, Pose2};

pub use params::FollowParams;
pub use view::View;

use crate::cloud::ObstacleCloud;
use crate::people::Tracker;
use crate::planner::{Planner, Scratch, Selection};
use backout::BackOut;
use detour::{Detour, DetourGrid};
use frontier::SeenGrid;
use giveway::GiveWay;
use goal::GoalMove;
use memory::{RecentView, Remembered};

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StepStatus {
    Moving,
    Rotating,
    Reached,
    Blocked,
    NoProgress,
    /// Stopped for a person: BLOCKED or NO_PROGRESS while someone tracked
    /// is within `PeopleParams::yield_m` (`walkers.rs`).
    Waiting,
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
    /// The nearest edges of the space the depth has not seen, `odom`,
    /// nearest first (`frontier.rs`; empty: none, or
    /// `FollowParams::frontier` is off).
    pub frontier: Vec<Vector2<f64>>,
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
    /// Which of `cloud`'s cells were seen moving (`memory.rs`).
    moving_mask: Vec<bool>,
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
    /// The detour layer's rolling grid of keep-out cells, `odom`.
    grid: DetourGrid,
    /// The detour being driven, if any.
    detour: Option<Detour>,
    /// The robot's trail and how it gave way to people.
    give_way: GiveWay,
    /// A manoeuvre out of a wedge under way (`backout.rs`).
    back_out: Option<BackOut>,
    /// Where (`odom`) this goal began planning through a narrow passage
    /// (`narrow.rs`).
    narrow_from: Option<Vector2<f64>>,
    /// Best distance to this goal, turns in place included, and when it
    /// was reached (`narrow.rs`, `RobotState::circling`).
    circling: Option<(f64, f64)>,
    /// What the depth has seen lately, for the frontier (`frontier.rs`).
    seen: SeenGrid,
}

impl RobotState {
    /// Obstacle cells currently remembered (this frame's included).
    pub fn remembered_cells(&self) -> usize {
        self.memory.len()
    }

    /// Plans one step. `cloud` replaces the stored cloud.
    pub fn step(&mut self, planner: &Planner, p: &FollowParams, input: StepInput<'_>) -> StepOutput {
        let dt = self.begin_frame(&input, p);
        let mut out = self.plan_step(planner, p, &input, dt);
        if p.frontier {
            if let Some(seen) = &input.cloud.seen {
                self.seen.observe(&input.pose, seen, input.stamp);
            }
            out.frontier = self.seen.frontier_at(&input.pose.position(), input.stamp).to_vec();
        }
        let near = self.slow_near_people(&input, out.linear, out.angular, p);
        let blocked = matches!(out.status, StepStatus::Blocked | StepStatus::NoProgress);
        if near.touches || (blocked && self.person_in_the_way(&input, p)) {
            // Stopped for a person: WAITING, and after a while giving way.
            out = self.stop(out, StepStatus::Waiting);
            let (v, w) = self.yield_to_person(&input, p, dt);
            let near = self.slow_near_people(&input, v, w, p);
            (out.linear, out.angular) = if near.touches { (0.0, 0.0) } else { (near.v, near.w) };
        } else {
            self.not_waiting(input.stamp);
            if (near.v, near.w) != (out.linear, out.angular) {
                (out.linear, out.angular) = (near.v, near.w);
                self.last_speed = self.last_speed.min(near.v.abs());
            }
        }
        out
    }

    /// One step's command before it is slowed, or stopped, for people.
    fn plan_step(&mut self, planner: &Planner, p: &FollowParams, input: &StepInput<'_>, dt: f64) -> StepOutput {
        let input = input.clone();
        self.cloud = self.merge_memory(input.cloud, &input, p);
        if p.detour {
            self.update_grid(&input, p);
        }
        let goal = input.goal;
        let goal_at = if goal.rotation_only { goal.pose.position() } else { self.clear_goal(&input, p) };
        let goal_base = input.pose.inverse_transform(&goal_at);
        let (distance, bearing) = polar(&goal_base);
        let out = StepOutput {
            linear: 0.0,
            angular: 0.0,
            status: StepStatus::Reached,
            selection: None,
            path_scale: 0.0,
            distance_to_goal: distance,
            heading_error: bearing,
            free_paths: 0,
            frontier: Vec::new(),
        };
        if goal.rotation_only {
            return self.turn_to_yaw(&input, p, out, dt);
        }
        if distance <= p.arrive_m || (distance <= goal.position_tolerance && goal_base.x <= p.arrive_m) {
            self.rotating = false;
            return self.stop(out, StepStatus::Reached);
        }
        if let Some((v, w)) = self.backing_out(&input, dt, p) {
            // Out of a wedge first; the paths take over when it is done.
            let mut out = self.stop(out, StepStatus::Moving);
            (out.linear, out.angular) = (v, w);
            return out;
        }
        // On a detour, toward its waypoint, and the distance left is the way's.
        let detouring = self.detour_target(&input, &goal_at, p);
        let (aim, along) = match detouring {
            Some((waypoint, left)) => (input.pose.inverse_transform(&waypoint), Some(left)),
            None => (goal_base, None),
        };
        let (_, aim_bearing) = polar(&aim);
        let mut out = if self.needs_rotation(aim_bearing, p) {
            self.turn_in_place(&input, p, out, aim_bearing, Some(&aim), dt)
        } else {
            self.follow(planner, p, &input, out, &aim, dt)
        };
        if let Some(left) = along {
            (out.distance_to_goal, out.heading_error) = (left, aim_bearing);
        }
        let stuck = matches!(out.status, StepStatus::Blocked | StepStatus::NoProgress);
        let circling = self.circling(&input, out.distance_to_goal, p);
        if stuck || circling {
            self.stuck_at(&input, p);
        }
        // A waypoint reached (as close as the body fits) is no goal reached.
        let waypoint_reached = along.is_some() && out.status == StepStatus::Reached;
        if (stuck || waypoint_reached) && self.plan_detour(&input, &goal_at, p) && (along.is_none() || !stuck) {
            // A way round: this frame stands, the next drives it. Stuck on
            // a detour already, the step says so: the executor decides.
            out = self.stop(out, StepStatus::Moving);
            (out.linear, out.angular) = (0.0, 0.0);
            if let Some((_, left)) = self.detour_target(&input, &goal_at, p) {
                out.distance_to_goal = left;
            }
        }
        out
    }

    /// The frame's period (`nominal_period_s` until two stamps are known,
    /// or after a gap), and what a new frame resets: everything remembered
    /// when time ran backwards, the memory's anchor when the odometry
    /// jumped (re-anchored at a reached subgoal), the rotation and the
    /// progress window when the goal changed.
    fn begin_frame(&mut self, input: &StepInput<'_>, p: &FollowParams) -> f64 {
        let dt = match self.last_stamp {
            Some(t) if input.stamp > t && input.stamp - t < 2.0 => input.stamp - t,
            _ => p.nominal_period_s,
        };
        let time_went_back = self.last_stamp.is_some_and(|t| input.stamp < t);
        let jumped = self
            .last_pose
            .is_some_and(|q| (q.position() - input.pose.position()).norm() > 0.5 + 2.0 * p.max_speed * dt);
        if time_went_back {
            self.forget_all();
            self.last_path_odom.clear();
            self.give_way = GiveWay::default();
        } else if let (true, Some(last)) = (jumped, self.last_pose) {
            // Re-anchored odometry: the robot has not moved, its frame has.
            self.reanchor(last, input.pose);
            self.give_way.reanchor(last, input.pose);
            self.last_path_odom.clear();
        }
        self.give_way.record(input.pose.position());
        self.last_pose = Some(input.pose);
        self.last_stamp = Some(input.stamp);
        if self.last_goal != Some(input.goal) {
            // A goal refined by a new estimate of the same target keeps the
            // wait; another goal starts afresh.
            if self.last_goal.is_none_or(|g| (g.pose.position() - input.goal.pose.position()).norm() > 1.0) {
                self.give_way.reset();
            }
            self.last_goal = Some(input.goal);
            self.detour = None;
            self.back_out = None;
            self.narrow_from = None;
            self.circling = None;
            self.progress = None;
            self.rotating = false;
            self.aligned = false;
        }
        dt
    }

    /// A frame's answer that leaves the robot standing (or turning on the
    /// spot): no speed carried into the next frame, no course held, the
    /// progress window restarted.
    fn stop(&mut self, mut out: StepOutput, status: StepStatus) -> StepOutput {
        self.last_speed = 0.0;
        self.last_path_odom.clear();
        self.progress = None;
        out.status = status;
        out
    }
}

/// The cell of side `side` m holding `at` (`odom`), as the memory and the
/// rolling grids key their cells.
fn cell_of(at: &Vector2<f64>, side: f64) -> (i32, i32) {
    ((at.x / side).floor() as i32, (at.y / side).floor() as i32)
}

/// A point's distance and bearing from the robot (`base_link`), m and rad.
fn polar(at: &Vector2<f64>) -> (f64, f64) {
    let distance = at.norm();
    (distance, if distance > 1e-9 { at.y.atan2(at.x) } else { 0.0 })
}
