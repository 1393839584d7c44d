//! Path following (CMU's path follower): the look-ahead point is where the
//! chosen path crosses 0.5 m from the robot; `ω = 7.5·bearing`, clamped to
//! the yaw-rate limit, to what turns onto the bearing within one frame
//! period (at 5 fps the CMU gain alone would overshoot) and to what can
//! still stop on the bearing, `√(2·yaw_decel·|bearing|)`: a Husky needs
//! 0.26 s to stop from full yaw rate, and a command that only stops at the
//! bearing overshoots it and swings from side to side; speed ramps up by
//! `max_accel·dt` only while the bearing is below 0.2 rad (CMU's 0.1 is for
//! 100 Hz: at 5 fps a lagging turn swung the robot ±0.13 rad between two
//! near-equal paths and it never moved), otherwise down,
//! and slows within `slow_down_distance` of the goal, never below
//! `creep_speed` and never faster than covers the distance left to the
//! goal in one frame period, so it stops on the goal rather than past it.
//!
//! Each command then passes the footprint guard (`guard.rs`); a robot the
//! guard stops within the goal's position tolerance has reached it, one
//! stopped farther away creeps (`creep.rs`) or, wedged, backs out
//! (`backout.rs`), and a command that would close
//! on a walking person is cut to what keeps clear of them (`walkers.rs`).

use nalgebra::Vector2;

use super::rotate::clamp_turn;
use super::{FollowParams, RobotState, StepInput, StepOutput, StepStatus, polar};
use crate::planner::{Planner, Selection};

/// Where the selected path crosses `look_ahead_m` from the robot
/// (`base_link`), or its end if it stays nearer.
pub(super) fn look_point(sel: &Selection, p: &FollowParams) -> Vector2<f64> {
    sel.points
        .iter()
        .find(|q| q.norm() >= p.look_ahead_m)
        .or(sel.points.last())
        .copied()
        .unwrap_or_else(|| Vector2::new(1.0, 0.0))
}

impl RobotState {
    /// One frame toward a position goal the robot faces (`goal_base`: the
    /// goal, cleared of obstacles, in `base_link`): the chosen path's
    /// look-ahead point to (v, ω), guarded, then the progress watchdog.
    pub(super) fn follow(
        &mut self,
        planner: &Planner,
        p: &FollowParams,
        input: &StepInput<'_>,
        mut out: StepOutput,
        goal_base: &Vector2<f64>,
        dt: f64,
    ) -> StepOutput {
        let (distance, bearing) = polar(goal_base);
        let speed = if input.max_speed > 0.0 { input.max_speed.min(p.max_speed) } else { p.max_speed };
        // Near a walker, no faster than the robot stops from within the
        // reach it allows them (see `PeopleParams::near_walker_mps`).
        let speed = if self.people.walker_within(input.stamp, &input.pose, p.people.near_walker_m, &p.people) {
            speed.min(p.people.near_walker_mps)
        } else {
            speed
        };
        // Stuck once on this goal: through narrow passages, slowly
        // (`narrow.rs`); the paths still look as far as at the speed
        // otherwise allowed.
        let narrow = self.narrow(input, p);
        let (planner, cruise) =
            if narrow { (planner.narrow(), speed.min(super::narrow::NARROW_MPS)) } else { (planner, speed) };
        // The course held: where last frame's path crosses the look-ahead circle now.
        let course = self
            .last_path_odom
            .iter()
            .map(|q| input.pose.inverse_transform(q))
            .find(|q| q.norm() >= p.look_ahead_m && q.x > 0.0)
            .map_or(0.0, |q| q.y.atan2(q.x));
        let plan = self.plan_behind_walkers(planner, p, input, *goal_base, speed / p.max_speed, course);
        out.free_paths = plan.free_paths;
        out.path_scale = plan.scale;
        let Some(sel) = plan.selection else {
            self.log_blocked(input, 1.2, "no free path");
            self.last_selection = None;
            self.last_path_odom.clear();
            return self.stop(out, StepStatus::Blocked);
        };
        let look = look_point(&sel, p);
        let dir = look.y.atan2(look.x);
        let turn = clamp_turn(p.yaw_gain * dir, dir, p, dt);
        out.angular = self.rear_turn(turn, narrow, p);
        // The rear still alongside a jamb (`narrow.rs`): straight on, slowly, until it is past.
        let rear_held = out.angular == 0.0 && turn != 0.0;
        // Aim at the middle of the arrival band: one frame's travel never
        // carries the robot past the goal. (On a detour, with the goal well
        // off the heading, the distance to it is what is left.)
        let left = if bearing.abs() < std::f64::consts::FRAC_PI_4 { goal_base.x } else { distance };
        let ahead = (left - p.arrive_m / 2.0).max(0.0);
        let target = (cruise * (distance / p.slow_down_distance).min(1.0)).max(p.creep_speed).min(ahead / dt);
        let v = if rear_held {
            p.escape_speed.min(target)
        } else if dir.abs() < p.align_threshold {
            (self.last_speed + p.max_accel * dt).min(target)
        } else {
            (self.last_speed - p.max_accel * dt).max(0.0).min(target)
        };
        let (v, w) = self.guard(v, out.angular, dt, p, &|_, _| true);
        if v == 0.0 && w == 0.0 && distance <= input.goal.position_tolerance {
            // As close as the body fits.
            self.rotating = false;
            out.angular = 0.0;
            return self.stop(out, StepStatus::Reached);
        }
        let (v, w) = if v == 0.0 && w == 0.0 { self.creep(goal_base, dt, p) } else { (v, w) };
        let (v, w) = if v == 0.0 && w == 0.0 { self.back_out(input, goal_base, dt, p) } else { (v, w) };
        if v == 0.0 && w == 0.0 {
            self.log_blocked(input, 1.0, "the footprint guard stops every command");
        }
        let (v, w) = if self.people_closer(input, v, w, p) {
            // Yield to a walker: the parts of the command that keep clear of
            // them, or a stop; waiting for people is no lack of progress.
            self.progress = None;
            self.guard(v, w, dt, p, &|v, w| !self.people_closer(input, v, w, p))
        } else {
            (v, w)
        };
        out.linear = v;
        out.angular = w;
        self.last_path_odom = sel.points.iter().step_by(5).map(|q| input.pose.transform(q)).collect();
        out.selection = Some(sel.clone());
        self.last_selection = Some(sel);
        out.status = StepStatus::Moving;
        self.watch_progress(out, distance, input.stamp, v, p)
    }
}
