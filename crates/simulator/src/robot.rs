//! Clearpath Husky A200: skid-steer kinematics with the platform controller's
//! velocity and acceleration limits, and wheel slip that makes odometry drift.
//!
//! The wheels track the commanded body velocity under the acceleration
//! limits; odometry integrates what the wheels report. The ground truth moves
//! less than the wheels claim, by a slip that grows with yaw rate and speed
//! (skid-steer turns by scrubbing the tyres sideways), plus a lateral skid
//! proportional to v·ω — so odometry drifts non-linearly, mostly in turns.

use rand::Rng;
use rand_distr::{Distribution, Normal};
use serde::Deserialize;

use crate::geometry::{Pose2, Vec2, wrap_angle};
pub use vlnav_geometry::Twist;

/// The platform's geometry and limits (Husky A200 defaults: `husky_control`
/// limits 1.0 m/s, 2.0 rad/s, 3.0 m/s², 6.0 rad/s²; footprint 0.988 × 0.670 m).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HuskyParams {
    pub max_linear: f64,
    pub max_angular: f64,
    pub max_linear_accel: f64,
    pub max_angular_accel: f64,
    pub length: f64,
    pub width: f64,
}

impl Default for HuskyParams {
    fn default() -> Self {
        Self {
            max_linear: 1.0,
            max_angular: 2.0,
            max_linear_accel: 3.0,
            max_angular_accel: 6.0,
            length: 0.988,
            width: 0.670,
        }
    }
}

/// Wheel-slip coefficients (scenario `[robot.slip]`).
///
/// Yaw slip s_ω = yaw_base + yaw_per_rate·|ω| + yaw_per_speed·|v| + N(0, yaw_noise);
/// longitudinal slip s_v = long_base + long_per_rate·|ω| + N(0, long_noise);
/// truth moves with v·(1 − s_v) forward, ω·(1 − s_ω) in yaw, and skids
/// sideways at lateral_gain·v·ω (outward of the turn).
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SlipModel {
    pub yaw_base: f64,
    pub yaw_per_rate: f64,
    pub yaw_per_speed: f64,
    pub yaw_noise: f64,
    pub long_base: f64,
    pub long_per_rate: f64,
    pub long_noise: f64,
    pub lateral_gain: f64,
}

impl Default for SlipModel {
    fn default() -> Self {
        Self {
            yaw_base: 0.005,
            yaw_per_rate: 0.015,
            yaw_per_speed: 0.005,
            yaw_noise: 0.005,
            long_base: 0.005,
            long_per_rate: 0.01,
            long_noise: 0.003,
            lateral_gain: 0.01,
        }
    }
}

impl SlipModel {
    /// No slip at all: truth equals odometry.
    pub fn none() -> Self {
        Self {
            yaw_base: 0.0,
            yaw_per_rate: 0.0,
            yaw_per_speed: 0.0,
            yaw_noise: 0.0,
            long_base: 0.0,
            long_per_rate: 0.0,
            long_noise: 0.0,
            lateral_gain: 0.0,
        }
    }

    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        for (k, v) in [
            ("yaw_base", self.yaw_base),
            ("yaw_per_rate", self.yaw_per_rate),
            ("yaw_per_speed", self.yaw_per_speed),
            ("yaw_noise", self.yaw_noise),
            ("long_base", self.long_base),
            ("long_per_rate", self.long_per_rate),
            ("long_noise", self.long_noise),
            ("lateral_gain", self.lateral_gain),
        ] {
            if !v.is_finite() || !(0.0..=0.5).contains(&v) {
                return Err((k, format!("{v} must be within [0, 0.5]")));
            }
        }
        Ok(())
    }
}

/// The robot's state: truth, odometry, and what the wheels do.
#[derive(Clone, Debug, PartialEq)]
pub struct RobotState {
    /// Ground-truth pose in the world.
    pub truth: Pose2,
    /// Ground-truth body velocity (after slip).
    pub truth_twist: Twist,
    /// Pose in the odom frame (integrated wheel motion).
    pub odom: Pose2,
    /// Body velocity the wheels report (what odometry sees).
    pub wheel_twist: Twist,
    /// World pose of the odom frame's origin (where odometry last read zero).
    pub odom_origin: Pose2,
}

impl RobotState {
    pub fn at(start: Pose2) -> Self {
        Self {
            truth: start,
            truth_twist: Twist::ZERO,
            odom: Pose2::default(),
            wheel_twist: Twist::ZERO,
            odom_origin: start,
        }
    }

    /// Re-anchors odometry at the current pose.
    pub fn reset_odometry(&mut self) {
        self.odom = Pose2::default();
        self.odom_origin = self.truth;
    }
}

/// Clamps a command to the velocity limits.
pub fn clamp_velocity(cmd: Twist, p: &HuskyParams) -> Twist {
    let sane = |v: f64| if v.is_finite() { v } else { 0.0 };
    Twist::new(
        sane(cmd.linear).clamp(-p.max_linear, p.max_linear),
        sane(cmd.angular).clamp(-p.max_angular, p.max_angular),
    )
}

/// Moves `current` towards `target` by at most the acceleration limits over `dt`.
pub fn ramp(current: Twist, target: Twist, p: &HuskyParams, dt: f64) -> Twist {
    let step = |c: f64, t: f64, a: f64| c + (t - c).clamp(-a * dt, a * dt);
    Twist::new(
        step(current.linear, target.linear, p.max_linear_accel),
        step(current.angular, target.angular, p.max_angular_accel),
    )
}

/// One integration substep's motion: the new wheel twist, the truth twist
/// (with slip) and the candidate truth and odometry poses. The caller decides
/// whether the truth may move there (collisions).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Motion {
    pub wheel_twist: Twist,
    pub truth_twist: Twist,
    pub lateral: f64,
    pub truth: Pose2,
    pub odom: Pose2,
}

/// Integrates one substep of `dt` seconds (exact arc integration).
pub fn integrate<R: Rng>(
    state: &RobotState,
    cmd: Twist,
    p: &HuskyParams,
    slip: &SlipModel,
    dt: f64,
    rng: &mut R,
) -> Motion {
    let wheel = ramp(state.wheel_twist, clamp_velocity(cmd, p), p, dt);
    let (v, w) = (wheel.linear, wheel.angular);
    let moving = v != 0.0 || w != 0.0;
    let gauss = |sigma: f64, rng: &mut R| -> f64 {
        if sigma > 0.0 { Normal::new(0.0, sigma).map(|n| n.sample(rng)).unwrap_or(0.0) } else { 0.0 }
    };
    // Draw noise only while moving, so a robot at rest consumes no randomness
    // and stays exactly where it is.
    let (n_yaw, n_long) = if moving { (gauss(slip.yaw_noise, rng), gauss(slip.long_noise, rng)) } else { (0.0, 0.0) };
    let s_yaw = (slip.yaw_base + slip.yaw_per_rate * w.abs() + slip.yaw_per_speed * v.abs() + n_yaw).clamp(0.0, 0.9);
    let s_long = (slip.long_base + slip.long_per_rate * w.abs() + n_long).clamp(0.0, 0.9);
    let truth_twist = if moving { Twist::new(v * (1.0 - s_long), w * (1.0 - s_yaw)) } else { Twist::ZERO };
    // Outward skid: to the right (−y) in a left turn while driving forward.
    let lateral = -slip.lateral_gain * v * w;
    let truth = advance(state.truth, truth_twist, lateral, dt);
    let odom = advance(state.odom, wheel, 0.0, dt);
    Motion { wheel_twist: wheel, truth_twist, lateral, truth, odom }
}

/// Pose after moving with a constant body twist (plus lateral velocity) for `dt`.
pub fn advance(pose: Pose2, twist: Twist, lateral: f64, dt: f64) -> Pose2 {
    let dth = twist.angular * dt;
    // Body-frame displacement of a constant-twist arc.
    let (fx, fy) =
        if dth.abs() < 1e-9 { (1.0 - dth * dth / 6.0, dth / 2.0) } else { (dth.sin() / dth, (1.0 - dth.cos()) / dth) };
    let vx = twist.linear * dt;
    let vy = lateral * dt;
    let d = Vec2::new(fx * vx - fy * vy, fy * vx + fx * vy);
    let w = pose.transform(&d.into());
    Pose2::new(w.x, w.y, wrap_angle(pose.theta + dth))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn commands_are_clamped_and_ramped_at_the_limits() {
        let p = HuskyParams::default();
        assert_eq!(clamp_velocity(Twist::new(3.0, -9.0), &p), Twist::new(1.0, -2.0));
        assert_eq!(clamp_velocity(Twist::new(f64::NAN, 0.5), &p), Twist::new(0.0, 0.5));
        let r = ramp(Twist::ZERO, Twist::new(1.0, 2.0), &p, 0.1);
        assert!((r.linear - 0.3).abs() < 1e-12 && (r.angular - 0.6).abs() < 1e-12);
    }

    #[test]
    fn arc_integration_turns_a_quarter_circle() {
        // 1 m/s at π/2 rad/s for 1 s: a quarter circle of radius 2/π.
        let p = advance(Pose2::default(), Twist::new(1.0, std::f64::consts::FRAC_PI_2), 0.0, 1.0);
        let r = 2.0 / std::f64::consts::PI;
        assert!(
            (p.x - r).abs() < 1e-12 && (p.y - r).abs() < 1e-12 && (p.theta - std::f64::consts::FRAC_PI_2).abs() < 1e-12
        );
    }

    #[test]
    fn slip_makes_truth_lag_odometry_more_in_turns_than_straight() {
        let p = HuskyParams::default();
        let slip = SlipModel::default();
        let run = |cmd: Twist| {
            let mut rng = ChaCha8Rng::seed_from_u64(7);
            let mut s = RobotState::at(Pose2::default());
            for _ in 0..300 {
                let m = integrate(&s, cmd, &p, &slip, 0.01, &mut rng);
                s.wheel_twist = m.wheel_twist;
                s.truth_twist = m.truth_twist;
                s.truth = m.truth;
                s.odom = m.odom;
            }
            s.truth.distance(&s.odom) + (s.truth.theta - s.odom.theta).abs()
        };
        let straight = run(Twist::new(1.0, 0.0));
        let turning = run(Twist::new(1.0, 1.0));
        assert!(straight > 0.0, "slip must make odometry drift");
        assert!(turning > 2.0 * straight, "turning drift {turning} vs straight {straight}");
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let none =
            integrate(&RobotState::at(Pose2::default()), Twist::new(1.0, 1.0), &p, &SlipModel::none(), 0.01, &mut rng);
        assert_eq!(none.truth, none.odom);
    }
}
