//! Narrow passages: the paths keep the robot's centre line
//! `PlannerParams::clearance_m` (0.45 m) from every obstacle cell, so a
//! doorway less than about 0.95 m wide is threaded only by a path that
//! happens to run within a few centimetres of its middle — with nine
//! library rotations 10° apart, seldom. The footprint itself, with the
//! guard's 0.05 m margin (`guard.rs`), fits through 0.77 m. Home doors are
//! 0.8–1.4 m wide: on the development set the homes whose narrowest door
//! was under 1.08 m between wall centres (0.98 m clear) failed in most
//! trials, nearly all asking "I am not getting closer" before the door,
//! those with wider doors hardly ever (generated worlds, `home-5`,
//! `home-6`, `home-46`, `home-59`).
//!
//! So once a step is stuck (BLOCKED or NO_PROGRESS) with nobody near, the
//! robot plans with the narrow tables (`Planner::narrow`, centre line
//! 0.42 m from obstacles: the half width, the guard's margin and 35 mm
//! for where a jamb seen from afar is remembered — a few hundredths of a
//! radian of the odometry's slip in turns, times its range, and half a
//! 5 cm voxel; with 5 mm instead, robots touched jambs beside them) at
//! no more than `NARROW_MPS`, for the next `NARROW_SPAN_M` of travel, except while
//! someone is near (`PeopleParams::yield_m`): a robot held up by people
//! is not in a narrow passage, and passing closer to things near people
//! is passing closer to people. The guard, the people rules and the
//! watchdog are unchanged.
//!
//! Before a doorway too narrow for the usual paths the step is seldom
//! reported stuck: the follower takes the free paths off to the side and
//! turns toward them on the spot until the goal is `rerotate_threshold`
//! off the heading, the turn in place (`rotate.rs`) turns back, and every
//! turn restarts the watchdog's window (`progress.rs`), so neither BLOCKED
//! nor NO_PROGRESS comes and the executor asks "I am not getting closer"
//! after its own timeout (development set, `home-25`, `home-5`: 15–40 s
//! of turning back and forth 1.5 m before the door). So a goal that came
//! no nearer by `CIRCLING_M` within `CIRCLING_S`, counting every frame,
//! turns in place included, is stuck here too
//! (`RobotState::circling`).
//!
//! Passing so close, the remembered cells' own error — the odometry's slip
//! since they were seen, half a voxel — is most of the margin left, and
//! where the robot then turns, it turned its rear into the jambs it had
//! just passed (development set, home-59: the rear still between them;
//! corridor-45: a spot turn with the rear at the wall's line). So within
//! the passage a turn never swings the rear toward a cell beside it
//! (`REAR_BAND_M` of the body's side, from the rear bumper to the middle;
//! `RobotState::rear_turn`) — the robot drives straight on until its rear
//! is past — and a turn on the spot keeps remembered cells
//! `NARROW_SWEEP_M` farther out of its sweep disc (`sweep.rs`).

use super::progress::window_ran_out;
use super::{FollowParams, RobotState, StepInput};

/// The top speed while planning with the narrow clearance, m/s: slow
/// enough that a frame's travel (0.06 m at 5 fps) stays near the guard's
/// margin.
pub(super) const NARROW_MPS: f64 = 0.3;

/// How far the robot plans with the narrow clearance once it began, m: a
/// doorway is passed within its own length and a little (the Husky is
/// 0.99 m long); beyond, the usual clearance again, until the step is
/// stuck once more. Held for the rest of the goal, the robot wove along
/// walls at 9–13 cm where nothing was narrow, against cells remembered
/// through many turns (development set, home-26).
pub(super) const NARROW_SPAN_M: f64 = 2.5;

/// A cell this close beside the body's rear half (from its side, m) is a
/// jamb or wall the rear is still alongside: no turn swings the rear toward
/// it.
pub(super) const REAR_BAND_M: f64 = 0.2;

/// What a spot turn's sweep disc adds for a remembered cell in a narrow
/// passage, m, on top of `FollowParams::memory_drift_m`.
pub(super) const NARROW_SWEEP_M: f64 = 0.05;

/// How long a goal may come no nearer by `CIRCLING_M`, every frame counted,
/// before it counts as stuck for the narrow passage, s: longer than the
/// watchdog's window (5 s) and than a half turn with its sweep checks.
pub(super) const CIRCLING_S: f64 = 8.0;

/// How much nearer the goal must come within `CIRCLING_S`, m.
pub(super) const CIRCLING_M: f64 = 0.3;

impl RobotState {
    /// Whether this goal, `distance` m away now, came no nearer by
    /// `CIRCLING_M` within `CIRCLING_S` of sensor time, turns in place
    /// included (see the module docs); the window then restarts. Only with
    /// `FollowParams::narrow`, which it serves.
    pub(super) fn circling(&mut self, input: &StepInput<'_>, distance: f64, p: &FollowParams) -> bool {
        if !p.narrow {
            return false;
        }
        window_ran_out(&mut self.circling, distance, input.stamp, CIRCLING_M, CIRCLING_S)
    }

    /// `w` (rad/s), or 0 where it would swing the rear toward a cell beside
    /// it: a turn to the right (ω < 0) swings the rear to the left. Only in
    /// a narrow passage (`narrow`: `RobotState::narrow` this frame).
    pub(super) fn rear_turn(&self, w: f64, narrow: bool, p: &FollowParams) -> f64 {
        if w == 0.0 || !narrow {
            return w;
        }
        let (hw, back) = (p.half_width_m as f32, -(p.half_length_m + p.guard_margin_m) as f32);
        let band = hw + REAR_BAND_M as f32;
        let toward = |c: &&crate::cloud::Cell| c.x <= 0.0 && c.x >= back && c.y.abs() >= hw && c.y.abs() <= band;
        // The rear swings to the side opposite the turn.
        let swung = |c: &crate::cloud::Cell| if w < 0.0 { c.y > 0.0 } else { c.y < 0.0 };
        if self.cloud.cells.iter().filter(|c| c.keeps_out()).filter(toward).any(swung) { 0.0 } else { w }
    }

    /// Whether this goal plans through narrow passages now: it has been
    /// stuck once since it was set with nobody near, and nobody is near
    /// now (`PeopleParams::yield_m`).
    pub(super) fn narrow(&self, input: &StepInput<'_>, p: &FollowParams) -> bool {
        self.in_passage(input) && !self.people.person_near(input.stamp, &input.pose, p.people.yield_m, &p.people)
    }

    /// Whether the robot is within `NARROW_SPAN_M` of where this goal began
    /// planning through a narrow passage.
    fn in_passage(&self, input: &StepInput<'_>) -> bool {
        self.narrow_from.is_some_and(|from| (input.pose.position() - from).norm() <= NARROW_SPAN_M)
    }

    /// A stuck step (BLOCKED or NO_PROGRESS) with nobody near switches its
    /// goal to the narrow-passage paths (see the module docs). Near people
    /// the people rules decide (`walkers.rs`, `giveway.rs`): a robot
    /// waiting for someone is not stuck in a doorway.
    pub(super) fn stuck_at(&mut self, input: &StepInput<'_>, p: &FollowParams) {
        if p.narrow
            && !self.in_passage(input)
            && !self.people.person_near(input.stamp, &input.pose, p.people.yield_m, &p.people)
        {
            tracing::debug!(stamp = input.stamp, "stuck: planning through narrow passages");
            self.narrow_from = Some(input.pose.position());
        }
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::Vector2;
    use vlnav_geometry::Pose2;

    use super::super::sweep::Sweep;
    use super::super::test_support::{drive_to, narrow_planner, planner, turn_in_place_to, view_ahead, with_cells};
    use super::super::{FollowParams, RobotState, StepStatus};
    use super::{CIRCLING_M, CIRCLING_S};
    use crate::cloud::{Cell, ObstacleCloud};

    /// A wall across the way 1.5 m ahead, of cells 0.05 m apart, with no
    /// cell within `width / 2` of a line 0.1 m left of the robot's.
    fn door(width: f32) -> ObstacleCloud {
        let mut cells = Vec::new();
        for k in 0..=120 {
            let y = -3.0 + 0.05 * k as f32;
            if (y - 0.1).abs() > width / 2.0 {
                for x in [1.5_f32, 1.55] {
                    cells.push(Cell { x, y, blocking: 5, low: false, no_go: false, person: 0 });
                }
            }
        }
        ObstacleCloud { cells, ..ObstacleCloud::default() }
    }

    #[test]
    fn a_door_the_paths_do_not_thread_is_driven_through_once_the_step_is_stuck() {
        let p = FollowParams { narrow: true, ..FollowParams::default() };
        let cloud = door(0.8);
        let goal = Vector2::new(4.0, 0.1);
        // Cells 0.9 m apart across the door: the usual paths (checked to
        // 4.25 m) swerve away along the wall; the narrow ones go through.
        let through = |pl: &crate::planner::Planner| {
            pl.plan(&cloud, goal, 1.0, 0.0, &mut Default::default())
                .selection
                .is_some_and(|s| s.points.iter().any(|q| q.x > 1.7))
        };
        assert!(!through(planner()), "the usual clearance threads the door");
        assert!(std::ptr::eq(planner().narrow(), planner()), "no narrow tables unless asked for");
        assert!(through(narrow_planner().narrow()), "the narrow clearance does not thread the door");
        // A stuck step switches to them, for the next NARROW_SPAN_M.
        let mut state = RobotState::default();
        let input = drive_to(0.0, Pose2::new(0.0, 0.0, 0.0), 4.0, &cloud, view_ahead());
        assert!(!state.narrow(&input, &p));
        // Off where the settings turn it off (`--local-planner-narrow false`).
        state.stuck_at(&input, &FollowParams::default());
        assert!(!state.narrow(&input, &p));
        state.stuck_at(&input, &p);
        assert!(state.narrow(&input, &p));
        let out = state.step(narrow_planner(), &p, input.clone());
        assert_ne!(out.status, StepStatus::Blocked, "{out:?}");
        // Past the passage (NARROW_SPAN_M on), the usual paths again, until
        // the step is stuck once more.
        let beyond = drive_to(0.4, Pose2::new(2.6, 0.1, 0.0), 4.0, &cloud, view_ahead());
        assert!(!state.narrow(&beyond, &p), "the passage is left behind");
        state.stuck_at(&beyond, &p);
        assert!(state.narrow(&beyond, &p), "stuck again: a new narrow passage");
        let mut next = drive_to(0.2, Pose2::new(0.0, 0.0, 0.0), 6.0, &cloud, view_ahead());
        next.goal.pose = Pose2::new(6.0, 0.1, 0.0);
        state.step(narrow_planner(), &p, next.clone());
        assert!(!state.narrow(&next, &p), "a new goal plans with the usual clearance");
        // Stuck with someone near: the people rules decide, not the narrow paths.
        let mut crowded = RobotState::default();
        for k in 0..5 {
            crowded.people.update(-0.2 * f64::from(4 - k), &[Some(Vector2::new(1.2, 0.5))], &p.people);
        }
        crowded.stuck_at(&input, &p);
        assert!(!crowded.narrow(&input, &p));
        // Narrow already, then someone comes near: the usual paths while they are.
        state.stuck_at(&next, &p);
        assert!(state.narrow(&next, &p));
        for k in 0..5 {
            state.people.update(-0.2 * f64::from(4 - k), &[Some(Vector2::new(1.2, 0.5))], &p.people);
        }
        assert!(!state.narrow(&next, &p));
    }

    #[test]
    fn a_goal_that_comes_no_nearer_while_the_robot_turns_back_and_forth_is_stuck() {
        let p = FollowParams { narrow: true, ..FollowParams::default() };
        let cloud = door(0.8);
        // Turning back and forth 2 m before the door, 0.2 s frames: the
        // distance never drops by CIRCLING_M, so every CIRCLING_S of
        // sensor time counts once as stuck, then the window restarts.
        let mut state = RobotState::default();
        let mut stuck = Vec::new();
        for k in 0..=100 {
            let stamp = 0.2 * f64::from(k);
            let input = drive_to(stamp, Pose2::new(0.0, 0.0, 0.3 * (0.5 * stamp).sin()), 4.0, &cloud, view_ahead());
            if state.circling(&input, 4.0 - 0.01 * stamp, &p) {
                stuck.push(stamp);
            }
        }
        assert_eq!(stuck.len(), 2, "{stuck:?}");
        assert!((stuck[0] - CIRCLING_S).abs() < 1e-9 && (stuck[1] - 2.0 * CIRCLING_S).abs() < 1e-9, "{stuck:?}");
        // Closing in by CIRCLING_M within each window, however slowly: never.
        let mut closing = RobotState::default();
        for k in 0..=100 {
            let stamp = 0.2 * f64::from(k);
            let input = drive_to(stamp, Pose2::new(0.0, 0.0, 0.0), 4.0, &cloud, view_ahead());
            let distance = 4.0 - 1.01 * CIRCLING_M * stamp / CIRCLING_S;
            assert!(!closing.circling(&input, distance, &p), "at {stamp} s");
        }
        // Without narrow passages (the default) nothing is watched.
        let mut off = RobotState::default();
        for k in 0..=100 {
            let input = drive_to(0.2 * f64::from(k), Pose2::new(0.0, 0.0, 0.0), 4.0, &cloud, view_ahead());
            assert!(!off.circling(&input, 4.0, &FollowParams::default()));
        }
        assert_eq!(off.circling, None);
        // Stuck this way with nobody near, the goal plans through narrow passages.
        let input = drive_to(20.2, Pose2::new(0.0, 0.0, 0.0), 4.0, &cloud, view_ahead());
        assert!(!state.narrow(&input, &p));
        state.stuck_at(&input, &p);
        assert!(state.narrow(&input, &p));
    }

    #[test]
    fn in_a_narrow_passage_the_rear_does_not_swing_into_what_it_is_still_beside() {
        let p = FollowParams { narrow: true, ..FollowParams::default() };
        let empty = ObstacleCloud::default();
        // A jamb beside the rear's left, 0.1 m off the body's side (half
        // width 0.335 m), remembered.
        let state = with_cells(&[(-0.3, 0.435), (-0.35, 0.435)]);
        assert_eq!(state.rear_turn(-0.5, false, &p), -0.5, "outside a narrow passage: unchanged");
        assert_eq!(state.rear_turn(-0.5, true, &p), 0.0, "turning right swings the rear left, into it");
        assert_eq!(state.rear_turn(0.5, true, &p), 0.5, "turning left swings it away");
        // Past the rear bumper, or more than REAR_BAND_M off: no jamb beside it.
        for cell in [(-0.7, 0.435), (-0.3, 0.56)] {
            assert_eq!(with_cells(&[cell]).rear_turn(-0.5, true, &p), -0.5, "{cell:?}");
        }
        // Jambs both sides: straight on.
        let both = with_cells(&[(-0.3, 0.435), (-0.3, -0.435)]);
        assert_eq!(both.rear_turn(0.5, true, &p), 0.0);
        // A spot turn keeps a remembered cell NARROW_SWEEP_M farther out:
        // 0.72 m off is outside the usual 0.70 m, inside 0.75 m.
        let turn = turn_in_place_to(1.5, &empty);
        let mut spot = with_cells(&[(0.0, -0.72)]);
        assert_eq!(spot.sweep(&turn, &p, 1.5, None, 0.2), None);
        spot.narrow_from = Some(turn.pose.position());
        assert!(matches!(spot.sweep(&turn, &p, 1.5, None, 0.2), Some(Sweep::Escape(_))));
    }
}
