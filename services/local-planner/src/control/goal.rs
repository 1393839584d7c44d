//! Goals beside obstacles: a goal whose footprint (the rectangle at the
//! goal, facing the goal's heading, plus `guard_margin_m`) would hold a
//! blocking or no-go cell — an approach goal on the line to a hydrant that stands
//! 0.15 m from a wall, a MOVE that ends beside a parked car — is moved
//! sideways, across its heading, by the smallest multiple of 0.05 m up to
//! `goal_shift_max_m` (0.4 m) that clears it. Across the heading, the
//! distance to what the robot faces changes by only δ²/2d (3 cm for 0.3 m
//! at 1.5 m). Where no shift clears it and the goal lies at a fixed
//! landmark's stopping distance (`GoalSpec::landmark`), it is moved round
//! the landmark, heading and all, by the smallest multiple of 5° up to
//! `goal_orbit_max_rad` (90°) that clears its footprint and the sweep
//! disc, so the robot can turn on the spot there (docs/design.md §4). The
//! move is kept while it stays clear, so it does not jitter from frame to
//! frame.

use nalgebra::{Rotation2, Vector2};
use vlnav_geometry::{GoalSpec, wrap_angle};

use super::{FollowParams, RobotState, StepInput};

/// How a goal whose footprint holds an obstacle is moved off it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum GoalMove {
    /// Sideways, across the goal's heading (left positive), m.
    Across(f64),
    /// Round the goal's landmark (counter-clockwise positive), its heading
    /// turned with it, rad.
    Round(f64),
}

impl GoalMove {
    /// The moved goal's position and heading (`odom`).
    pub(super) fn apply(self, goal: &GoalSpec) -> (Vector2<f64>, f64) {
        let g = goal.pose;
        match (self, goal.landmark) {
            (GoalMove::Across(d), _) => (g.position() + Vector2::new(-g.theta.sin(), g.theta.cos()) * d, g.theta),
            (GoalMove::Round(a), Some(l)) => (l + Rotation2::new(a) * (g.position() - l), g.theta + a),
            (GoalMove::Round(_), None) => (g.position(), g.theta),
        }
    }
}

/// The step of a landmark goal's turn round its landmark, rad (5°).
pub(super) const ORBIT_STEP_RAD: f64 = 5.0 * std::f64::consts::PI / 180.0;

impl RobotState {
    /// The goal's position (odom), moved off a footprint that holds an
    /// obstacle (docs above): sideways across its heading by the smallest
    /// shift up to `goal_shift_max_m` that clears it, else — for a goal at a
    /// landmark's stopping distance — round the landmark by the smallest
    /// turn up to `goal_orbit_max_rad` that clears it; unmoved when it is
    /// clear or nothing clears it.
    pub(super) fn clear_goal(&mut self, input: &StepInput<'_>, p: &FollowParams) -> Vector2<f64> {
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
}

#[cfg(test)]
mod tests {
    use nalgebra::Vector2;
    use vlnav_geometry::{GoalSpec, Pose2};

    use super::super::test_support::view_ahead;
    use super::super::{FollowParams, RobotState, StepInput};
    use super::{GoalMove, ORBIT_STEP_RAD};
    use crate::cloud::{Cell, ObstacleCloud};

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
