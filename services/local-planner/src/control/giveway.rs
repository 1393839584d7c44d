//! Giving way to a person: a robot that has waited `GIVE_WAY_AFTER_S` for
//! someone in its way (`walkers.rs`, WAITING) backs away along its own
//! trail, slowly, by up to `GIVE_WAY_MAX_M`, then waits there.
//!
//! Waiting alone deadlocks wherever the person waits for the robot too: a
//! person who wants through the doorway the robot stands before, one
//! crossing a corridor into the side room whose door the robot blocks, one
//! coming along a corridor too narrow for both. People give a machine more
//! room than it needs (docs/simulation.md, "People"), so neither moves, and
//! the robot asked the user (generated worlds, development set: with a
//! bound on waiting alone, success did not change and the asks became
//! time-outs). Backing off opens the gap the person waits for; once they
//! are past, the way is free and the robot drives on.
//!
//! Behind the robot the camera sees nothing, so it backs only over ground
//! it knows: where its own centre passed (the trail, the last
//! `TRAIL_KEEP_M` of it, kept in `odom` and moved with the odometry when
//! that is re-anchored), with no remembered cell in the body's lane and no
//! one tracked behind it (docs/design.md §4, "People in the way").

use std::collections::VecDeque;

use nalgebra::Vector2;
use vlnav_geometry::Pose2;

use super::{FollowParams, RobotState, StepInput};

/// How long a robot waits for a person before it backs away, s of sensor time.
pub(super) const GIVE_WAY_AFTER_S: f64 = 3.0;
/// The most it backs away for one goal before it only waits, m.
pub(super) const GIVE_WAY_MAX_M: f64 = 1.5;
/// Its speed backing away, m/s.
pub(super) const GIVE_WAY_SPEED: f64 = 0.25;
/// The trail keeps one point per this much travel, m …
const TRAIL_STEP_M: f64 = 0.1;
/// … over this much of the latest travel, m.
pub(super) const TRAIL_KEEP_M: f64 = 3.0;
/// A place the robot backs over is known when its centre passed within
/// this distance of it, m.
const ON_TRAIL_M: f64 = 0.15;
/// A way over the trail is checked at places this far apart, m.
const TRAIL_CHECK_M: f64 = 0.05;
/// Room kept beyond the body's sides and rear from remembered cells and
/// from people tracked behind, m.
const LANE_MARGIN_M: f64 = 0.1;
const PERSON_MARGIN_M: f64 = 0.5;
/// Give-way state is forgotten once the robot has not waited for this
/// long, s.
const FORGET_S: f64 = 5.0;

/// Where the robot's centre has been lately, and how it gave way.
#[derive(Clone, Debug, Default)]
pub(super) struct GiveWay {
    /// `odom` positions, oldest first, `TRAIL_STEP_M` apart.
    pub(super) trail: VecDeque<Vector2<f64>>,
    /// Since when the steps have been WAITING without a break.
    pub(super) waiting_since: Option<f64>,
    /// The last stamp that was WAITING.
    pub(super) last_waiting: Option<f64>,
    /// How far the robot has backed away for the current goal, m.
    pub(super) backed_m: f64,
}

impl GiveWay {
    /// Adds the robot's position to the trail when it has moved
    /// `TRAIL_STEP_M` from the last point, dropping what lies more than
    /// `TRAIL_KEEP_M` of travel back.
    pub(super) fn record(&mut self, at: Vector2<f64>) {
        if self.trail.back().is_none_or(|q| (q - at).norm() >= TRAIL_STEP_M) {
            self.trail.push_back(at);
        }
        let keep = (TRAIL_KEEP_M / TRAIL_STEP_M).ceil() as usize + 1;
        while self.trail.len() > keep {
            self.trail.pop_front();
        }
    }

    /// The odometry was re-anchored (`last` → `now`, the robot standing
    /// still): the trail keeps its place relative to the robot.
    pub(super) fn reanchor(&mut self, last: Pose2, now: Pose2) {
        for q in &mut self.trail {
            *q = now.transform(&last.inverse_transform(q));
        }
    }

    /// A new goal, or time that ran backwards: nothing waited for yet.
    pub(super) fn reset(&mut self) {
        self.waiting_since = None;
        self.last_waiting = None;
        self.backed_m = 0.0;
    }
}

impl RobotState {
    /// The command of a WAITING step at `stamp`: standing still, or, once
    /// it has waited `GIVE_WAY_AFTER_S`, backing straight away along the
    /// trail while that much of it is known free (see the module docs).
    pub(super) fn yield_to_person(&mut self, input: &StepInput<'_>, p: &FollowParams, dt: f64) -> (f64, f64) {
        let stamp = input.stamp;
        let since = *self.give_way.waiting_since.get_or_insert(stamp);
        self.give_way.last_waiting = Some(stamp);
        if stamp - since < GIVE_WAY_AFTER_S || self.give_way.backed_m >= GIVE_WAY_MAX_M {
            return (0.0, 0.0);
        }
        let step = GIVE_WAY_SPEED * dt;
        let free = self.free_behind(input, p, step + GIVE_WAY_SPEED * GIVE_WAY_SPEED / (2.0 * p.max_accel));
        if !free {
            return (0.0, 0.0);
        }
        self.give_way.backed_m += step;
        tracing::debug!(stamp, backed_m = self.give_way.backed_m, "giving way to a person");
        (-GIVE_WAY_SPEED, 0.0)
    }

    /// A step that is not WAITING: the wait is over, and the give-way
    /// state goes once it has been over for `FORGET_S`.
    pub(super) fn not_waiting(&mut self, stamp: f64) {
        self.give_way.waiting_since = None;
        if self.give_way.last_waiting.is_some_and(|t| stamp - t > FORGET_S) {
            self.give_way.reset();
        }
    }

    /// Whether `at` (`base_link` of `pose`) is within `ON_TRAIL_M` of where
    /// the robot's centre has been.
    pub(super) fn on_trail(&self, pose: &Pose2, at: &Vector2<f64>) -> bool {
        let q = pose.transform(at);
        self.give_way.trail.iter().any(|t| (t - q).norm() <= ON_TRAIL_M)
    }

    /// Whether a way of `length` m from `pose` keeps the centre within
    /// `ON_TRAIL_M` of the trail, checked every `TRAIL_CHECK_M`: `at(k, n)`
    /// is the place (`base_link` of `pose`) k n-ths of the way along.
    pub(super) fn on_trail_along(&self, pose: &Pose2, length: f64, at: impl Fn(u32, u32) -> Vector2<f64>) -> bool {
        let n = (length / TRAIL_CHECK_M).ceil().max(1.0) as u32;
        (1..=n).all(|k| self.on_trail(pose, &at(k, n)))
    }

    /// Whether backing straight `back` m is over known, free ground: each
    /// place of the centre on the way within `ON_TRAIL_M` of the trail, no
    /// remembered cell in the body's lane that far back, and no one tracked
    /// behind the robot within `PERSON_MARGIN_M` of that lane.
    fn free_behind(&self, input: &StepInput<'_>, p: &FollowParams, back: f64) -> bool {
        let pose = input.pose;
        let on_trail = self.on_trail_along(&pose, back, |k, n| Vector2::new(-back * f64::from(k) / f64::from(n), 0.0));
        if !on_trail {
            return false;
        }
        let (rear, side) = (-(p.half_length_m + back + LANE_MARGIN_M), p.half_width_m + LANE_MARGIN_M);
        let in_lane = |x: f64, y: f64, margin: f64| x < 0.0 && x > rear - margin && y.abs() < side + margin;
        let cells_clear = self.cloud.cells.iter().all(|c| !in_lane(f64::from(c.x), f64::from(c.y), 0.0));
        let people_clear =
            self.people.people_at(input.stamp, &pose, &p.people).iter().all(|q| !in_lane(q.x, q.y, PERSON_MARGIN_M));
        cells_clear && people_clear
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::Vector2;
    use vlnav_geometry::Pose2;

    use super::super::test_support::{drive_to, view_ahead};
    use super::super::{FollowParams, RobotState, StepInput};
    use super::{GIVE_WAY_AFTER_S, GIVE_WAY_MAX_M, GIVE_WAY_SPEED, GiveWay, TRAIL_KEEP_M};
    use crate::cloud::{Cell, ObstacleCloud};

    fn input(stamp: f64, x: f64, cloud: &ObstacleCloud) -> StepInput<'_> {
        drive_to(stamp, Pose2::new(x, 0.0, 0.0), 5.0, cloud, view_ahead())
    }

    /// A robot that drove from x = 0 to x = 2 along the x axis.
    fn after_a_drive() -> RobotState {
        let mut state = RobotState::default();
        for k in 0..=40 {
            state.give_way.record(Vector2::new(0.05 * f64::from(k), 0.0));
        }
        state
    }

    #[test]
    fn the_trail_keeps_its_last_metres_only() {
        let mut g = GiveWay::default();
        for k in 0..1000 {
            g.record(Vector2::new(0.01 * f64::from(k), 0.0));
        }
        let first = g.trail.front().unwrap().x;
        let last = g.trail.back().unwrap().x;
        // One point per 0.1 m of travel or a little more (frames do not fall
        // on the spacing): at least the kept length, not much over.
        assert!(last - first >= TRAIL_KEEP_M - 1e-9 && last - first < 1.1 * TRAIL_KEEP_M + 0.1, "{first}..{last}");
    }

    #[test]
    fn it_waits_first_then_backs_along_its_trail_no_farther_than_the_bound() {
        let p = FollowParams::default();
        let mut state = after_a_drive();
        let empty = ObstacleCloud::default();
        let (mut x, mut t, dt) = (2.0, 0.0, 0.2);
        let mut backing_from = None;
        while t < 30.0 {
            let (v, w) = state.yield_to_person(&input(t, x, &empty), &p, dt);
            assert_eq!(w, 0.0);
            if t < GIVE_WAY_AFTER_S - 1e-9 {
                assert_eq!(v, 0.0, "waits first, at {t}");
            }
            if v < 0.0 {
                assert_eq!(v, -GIVE_WAY_SPEED);
                backing_from.get_or_insert(t);
            }
            x += v * dt;
            t += dt;
        }
        assert!((backing_from.unwrap() - GIVE_WAY_AFTER_S).abs() < 0.2 + 1e-9);
        assert!(2.0 - x <= GIVE_WAY_MAX_M + 1e-9 && 2.0 - x > GIVE_WAY_MAX_M - 0.1, "backed {:.2} m", 2.0 - x);
    }

    #[test]
    fn it_backs_only_over_known_free_ground() {
        let p = FollowParams::default();
        let empty = ObstacleCloud::default();
        // No trail: the ground behind is unknown.
        let mut state = RobotState::default();
        assert_eq!(state.yield_to_person(&input(0.0, 2.0, &empty), &p, 0.2), (0.0, 0.0));
        assert_eq!(state.yield_to_person(&input(5.0, 2.0, &empty), &p, 0.2), (0.0, 0.0));
        // A remembered cell just behind the rear bumper.
        let mut state = after_a_drive();
        state.cloud.cells.push(Cell { x: -0.6, y: 0.1, blocking: 2, low: false, no_go: false, person: 0 });
        state.yield_to_person(&input(0.0, 2.0, &empty), &p, 0.2);
        assert_eq!(state.yield_to_person(&input(5.0, 2.0, &empty), &p, 0.2), (0.0, 0.0));
        // The same trail, nothing behind: it backs.
        let mut state = after_a_drive();
        state.yield_to_person(&input(0.0, 2.0, &empty), &p, 0.2);
        assert_eq!(state.yield_to_person(&input(5.0, 2.0, &empty), &p, 0.2), (-GIVE_WAY_SPEED, 0.0));
    }
}
