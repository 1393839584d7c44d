//! Backing out of a wedge. A robot that drove along a wall and met
//! something ahead of its bumper can be stuck where the footprint guard
//! (`guard.rs`) stops every command: straight on closes on what is ahead,
//! and any turn swings the rear corner into the wall beside it (evaluation,
//! development set: a wall beside the robot and a marked zone's corner,
//! or a jog of the wall, just ahead of the bumper). The creep (`creep.rs`) only goes forward toward
//! a goal ahead, so the robot stood there until the executor asked.
//!
//! A driver backs up first. When the guard and the creep find nothing and
//! the goal lies ahead, the robot searches two-part manoeuvres: back along
//! a straight line or an arc (`CREEP_CURVATURES`, either side) for
//! `BACK_STEP_S`, 2·`BACK_STEP_S`, … s — never farther than the sweep's own
//! backing limit (`near_memory_m` less `sweep_radius_m`, 0.35 m), and only
//! where the robot's centre has been (its trail, as the give-way backs:
//! `giveway.rs`; behind, the camera sees nothing) — then on along a forward arc or
//! straight, driven for `ON_S`, which must keep the footprint clear for
//! twice that from where the backing ends (one clear only for the part
//! driven leads straight back into the wedge). It takes the way on that
//! stays clear longest (up to three times `ON_S`), after the shortest
//! backing, ending nearest the goal; it drives both parts,
//! each frame's command still passing the guard and never closing on a
//! walker, and then the paths take over again. Nothing is tried near a
//! person in the way: that is waited for (`walkers.rs`).

use nalgebra::Vector2;
use vlnav_geometry::Pose2;

use super::creep::CREEP_CURVATURES;
use super::guard::arc_pose;
use super::{FollowParams, RobotState, StepInput};

/// A manoeuvre out of a wedge: `back` (v, ω) for `back_s`, then `on` for
/// `ON_S`, from sensor time `since`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct BackOut {
    back: (f64, f64),
    back_s: f64,
    on: (f64, f64),
    since: f64,
}

/// The backing durations searched are multiples of this, s.
pub(super) const BACK_STEP_S: f64 = 0.4;

/// How long the way on is driven, and must at least stay clear from where
/// the backing ends, s (0.3 m at `escape_speed`).
pub(super) const ON_S: f64 = 2.0;

/// The way on must stay clear for at least `ON_CLEAR_MIN`·`ON_S` (one clear
/// only for the part driven leads straight back into the wedge), and one
/// clear for up to `ON_CLEAR_MAX`·`ON_S` is preferred.
const ON_CLEAR_MIN: u32 = 2;
const ON_CLEAR_MAX: u32 = 3;

impl RobotState {
    /// Plans a manoeuvre out of a wedge toward `goal_base` (`base_link`) and
    /// returns its first command, or a stop where none is clear.
    pub(super) fn back_out(
        &mut self,
        input: &StepInput<'_>,
        goal_base: &Vector2<f64>,
        dt: f64,
        p: &FollowParams,
    ) -> (f64, f64) {
        if goal_base.x <= 0.0 || self.person_in_the_way(input, p) {
            return (0.0, 0.0);
        }
        let e = p.escape_speed;
        let back_max = (p.near_memory_m - p.sweep_radius_m).max(0.0);
        let turns = || CREEP_CURVATURES.iter().flat_map(|&k| [k, -k]);
        let backs: Vec<(f64, f64)> = std::iter::once((-e, 0.0)).chain(turns().map(|k| (-e, k * e))).collect();
        let ons: Vec<(f64, f64)> = std::iter::once((e, 0.0)).chain(turns().map(|k| (e, k * e))).collect();
        let steps = (back_max / e / BACK_STEP_S + 1e-9).floor() as u32;
        let mut candidates = Vec::new();
        for i in 1..=steps {
            let back_s = f64::from(i) * BACK_STEP_S;
            for &back in &backs {
                // Behind, only over ground the robot's centre has been on.
                let known = self.on_trail_along(&input.pose, e * back_s, |k, n| {
                    let (x, y, _) = arc_pose(back.0, back.1, back_s * f64::from(k) / f64::from(n));
                    Vector2::new(x, y)
                });
                if !known || !self.clear_for(back, back_s, dt, p) || self.people_closer(input, back.0, back.1, p) {
                    continue;
                }
                let from = arc_pose(back.0, back.1, back_s);
                for &on in &ons {
                    // How many `ON_S` the way on stays clear, up to `ON_CLEAR_MAX`.
                    let clear = (1..=ON_CLEAR_MAX)
                        .take_while(|&k| !self.footprint_hits_from(from, on.0, on.1, f64::from(k) * ON_S, p))
                        .last();
                    if let Some(k) = clear.filter(|&k| k >= ON_CLEAR_MIN) {
                        let to_goal = way_on_end(from, on).metric_distance(goal_base);
                        candidates.push((std::cmp::Reverse(k), i, to_goal, back, on, back_s));
                    }
                }
            }
        }
        // The way on that stays clear longest, after the shortest backing,
        // ending nearest the goal.
        let best = candidates.into_iter().min_by(|a, b| (a.0, a.1).cmp(&(b.0, b.1)).then(a.2.total_cmp(&b.2)));
        if let Some((_, _, _, back, on, back_s)) = best {
            tracing::debug!(stamp = input.stamp, ?back, back_s, ?on, "backing out of a wedge");
            self.back_out = Some(BackOut { back, back_s, on, since: input.stamp });
            return back;
        }
        (0.0, 0.0)
    }

    /// This frame's command of a manoeuvre under way, if any: it ends when
    /// both parts are driven, or where its command would take in something
    /// (the guard, over a frame and its stop) or close on a walker.
    pub(super) fn backing_out(&mut self, input: &StepInput<'_>, dt: f64, p: &FollowParams) -> Option<(f64, f64)> {
        let b = self.back_out?;
        let t = input.stamp - b.since;
        let m = if t < b.back_s - 1e-6 {
            b.back
        } else if t < b.back_s + ON_S - 1e-6 {
            b.on
        } else {
            self.back_out = None;
            return None;
        };
        if !self.clear_for(m, 0.0, dt, p) || self.people_closer(input, m.0, m.1, p) {
            self.back_out = None;
            return None;
        }
        Some(m)
    }
}

/// Where the way on `on` (v, ω), held `ON_S` from `from` (x, y, heading,
/// `base_link`), ends.
fn way_on_end(from: (f64, f64, f64), on: (f64, f64)) -> Vector2<f64> {
    let (x, y, _) = arc_pose(on.0, on.1, ON_S);
    Pose2::new(from.0, from.1, from.2).transform(&Vector2::new(x, y))
}

#[cfg(test)]
mod tests {
    use nalgebra::Vector2;
    use vlnav_geometry::Pose2;

    use super::super::guard::arc_pose;
    use super::super::test_support::{drive_to, view_ahead, with_cells};
    use super::super::{FollowParams, RobotState};
    use super::{BACK_STEP_S, ON_S, way_on_end};
    use crate::cloud::{Cell, ObstacleCloud};

    /// A wedge as a robot saw it on the development set (office): the
    /// corner of a marked no-go zone just ahead-left of the bumper and the
    /// goal off to the right: straight on enters the zone, and a turn toward
    /// the goal, on the spot or on an arc, swings the front-left corner
    /// into it.
    fn wedged() -> RobotState {
        let mut state = RobotState::default();
        // It drove in along +x: the last 3 m behind it are its trail.
        for i in 0..=30 {
            state.give_way.record(Vector2::new(-3.0 + 0.1 * f64::from(i), 0.0));
        }
        for i in 0..8 {
            for j in 0..6 {
                let (x, y) = (0.56 + 0.05 * i as f32, 0.26 + 0.05 * j as f32);
                state.cloud.cells.push(Cell { x, y, blocking: 0, low: false, no_go: true, person: 0 });
            }
        }
        state
    }

    #[test]
    fn a_robot_wedged_at_a_zone_corner_backs_out_and_turns_away() {
        let p = FollowParams::default();
        let mut state = wedged();
        let goal = Vector2::new(4.0, -1.5);
        // Wedged: a path's turn toward the goal, its parts, and the creep
        // are stopped.
        assert_eq!(state.guard(0.3, -1.0, 0.2, &p, &|_, _| true), (0.0, 0.0));
        assert_eq!(state.creep(&goal, 0.2, &p), (0.0, 0.0));
        let empty = ObstacleCloud::default();
        let input = drive_to(10.0, Pose2::new(0.0, 0.0, 0.0), 6.0, &empty, view_ahead());
        let first = state.back_out(&input, &goal, 0.2, &p);
        assert!(first.0 < 0.0, "it backs: {first:?}");
        let b = state.back_out.expect("a manoeuvre is under way");
        // Both parts keep the footprint clear.
        assert!(!state.footprint_hits(b.back.0, b.back.1, b.back_s, &p));
        let from = arc_pose(b.back.0, b.back.1, b.back_s);
        assert!(!state.footprint_hits_from(from, b.on.0, b.on.1, ON_S, &p));
        let end = way_on_end(from, b.on);
        assert!(b.on.0 > 0.0 && end.x > 0.0, "{b:?} ends at {end:?}");
        // The next frames drive it (even where straight on is clear for a
        // frame again), then the paths take over.
        let at = |t: f64| drive_to(10.0 + t, Pose2::new(0.0, 0.0, 0.0), 6.0, &empty, view_ahead());
        assert_eq!(state.backing_out(&at(0.2), 0.2, &p), Some(b.back));
        // Backed: the cells as the robot now sees them.
        let (s, c) = (from.2.sin() as f32, from.2.cos() as f32);
        for cell in &mut state.cloud.cells {
            let (dx, dy) = (cell.x - from.0 as f32, cell.y - from.1 as f32);
            (cell.x, cell.y) = (c * dx + s * dy, -s * dx + c * dy);
        }
        assert_eq!(state.backing_out(&at(b.back_s), 0.2, &p), Some(b.on));
        assert_eq!(state.backing_out(&at(b.back_s + ON_S), 0.2, &p), None);
        assert_eq!(state.back_out, None);
    }

    #[test]
    fn a_robot_with_no_room_or_no_trail_behind_or_a_goal_behind_does_not_back_out() {
        let p = FollowParams::default();
        let empty = ObstacleCloud::default();
        let input = drive_to(10.0, Pose2::new(0.0, 0.0, 0.0), 6.0, &empty, view_ahead());
        // A wall right behind the rear bumper as well.
        let mut boxed = wedged();
        boxed
            .cloud
            .cells
            .extend(with_cells(&(0..20).map(|i| (-0.6, -0.5 + 0.05 * i as f32)).collect::<Vec<_>>()).cloud.cells);
        assert_eq!(boxed.back_out(&input, &Vector2::new(4.0, -1.5), 0.2, &p), (0.0, 0.0));
        assert_eq!(boxed.back_out, None);
        // Where it has not been, it does not back: behind, the camera sees nothing.
        let mut fresh = wedged();
        fresh.give_way.trail.clear();
        assert_eq!(fresh.back_out(&input, &Vector2::new(4.0, -1.5), 0.2, &p), (0.0, 0.0));
        // A goal behind is the creep's (it backs straight toward it).
        let mut state = wedged();
        assert_eq!(state.back_out(&input, &Vector2::new(-2.0, 0.0), 0.2, &p), (0.0, 0.0));
        // The backing stays within the sweep's limit of what memory knows behind.
        let mut state = wedged();
        state.back_out(&input, &Vector2::new(4.0, -1.5), 0.2, &p);
        let b = state.back_out.expect("room behind");
        assert!(b.back_s * p.escape_speed <= p.near_memory_m - p.sweep_radius_m + 1e-9);
        assert!(b.back_s >= BACK_STEP_S);
    }
}
