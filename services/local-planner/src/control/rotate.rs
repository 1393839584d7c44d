//! Rotate in place (the authors' rule) while the goal is more than
//! `rotate_threshold` (1.0 rad) off the heading, `ω = 0.8·error`, until it is
//! within `rotate_exit` (0.3 rad, hysteresis so the paths take over inside
//! the camera's view). Once aligned with a goal, the robot rotates in place
//! again only if the goal falls behind it (`rerotate_threshold`, 1.9 rad):
//! a detour around an obstacle between robot and goal points the heading
//! well away from the goal, and turning back to the goal there would
//! undo the detour and oscillate.
//!
//! A rotation goal (`GoalSpec::rotation_only`) is turned to the same way,
//! until the yaw error is below `goal.yaw_tolerance`. Either turn goes on
//! the spot only where its sweep disc is free (`sweep.rs`), and never
//! toward a walking person (`walkers.rs`).

use nalgebra::Vector2;
use vlnav_geometry::wrap_angle;

use super::sweep::Sweep;
use super::{FollowParams, RobotState, StepInput, StepOutput, StepStatus};

impl RobotState {
    /// A rotation goal: turn until the yaw error is within its tolerance.
    pub(super) fn turn_to_yaw(
        &mut self,
        input: &StepInput<'_>,
        p: &FollowParams,
        mut out: StepOutput,
        dt: f64,
    ) -> StepOutput {
        let yaw_error = wrap_angle(input.goal.pose.theta - input.pose.theta);
        out.heading_error = yaw_error;
        if yaw_error.abs() < input.goal.yaw_tolerance {
            return self.stop(out, StepStatus::Reached);
        }
        self.turn_in_place(input, p, out, yaw_error, None, dt)
    }

    /// Whether a position goal `bearing` rad off the heading is turned to
    /// on the spot this frame: beyond `rotate_threshold` before the robot
    /// first faced the goal, beyond `rerotate_threshold` after, and, once
    /// turning, until within `rotate_exit` (hysteresis).
    pub(super) fn needs_rotation(&mut self, bearing: f64, p: &FollowParams) -> bool {
        let exit = match (self.rotating, self.aligned) {
            (true, _) => p.rotate_exit,
            (false, false) => p.rotate_threshold,
            (false, true) => p.rerotate_threshold,
        };
        self.rotating = bearing.abs() > exit;
        self.aligned |= !self.rotating;
        self.rotating
    }

    /// One frame of a turn in place by `turn` rad (signed): on the spot
    /// where the sweep disc is free, else the way `sweep` finds to free it
    /// (`goal`: the position the turn faces, `base_link`), BLOCKED where
    /// nothing does; a stop where the command would close on a walker.
    pub(super) fn turn_in_place(
        &mut self,
        input: &StepInput<'_>,
        p: &FollowParams,
        mut out: StepOutput,
        turn: f64,
        goal: Option<&Vector2<f64>>,
        dt: f64,
    ) -> StepOutput {
        match self.sweep(input, p, turn, goal, dt) {
            Some(Sweep::Blocked) => {
                self.log_blocked(input, p.sweep_radius_m, "a turn in place is blocked");
                return self.stop(out, StepStatus::Blocked);
            }
            Some(Sweep::Escape(v)) => out.linear = v,
            Some(Sweep::Arc(v, w)) => (out.linear, out.angular) = (v, w),
            None => out.angular = clamp_turn(p.rotate_gain * turn, turn, p, dt),
        }
        if self.people_closer(input, out.linear, out.angular, p) {
            (out.linear, out.angular) = (0.0, 0.0);
        }
        self.stop(out, StepStatus::Rotating)
    }
}

/// A turn rate toward a bearing `error` rad away, capped so that it never
/// turns past the bearing within one frame period (`dt`) nor faster than
/// still stops on it at `yaw_decel`.
pub(super) fn clamp_turn(rate: f64, error: f64, p: &FollowParams, dt: f64) -> f64 {
    // Never turn past the target bearing within one frame period, nor faster
    // than lets the robot still stop on it.
    let cap = p.max_yaw_rate.min(error.abs() / dt.max(1e-3)).min((2.0 * p.yaw_decel * error.abs()).sqrt());
    rate.clamp(-cap, cap)
}

#[cfg(test)]
mod tests {
    use super::super::FollowParams;
    use super::clamp_turn;

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
}
