//! Keeping behind people who walk: the paths are chosen over the whole
//! cloud, walkers' cells included, so a person walking ahead of the robot in
//! a corridor, or crossing its way, blocks every path toward the goal and
//! the cheapest free one swerves far off it — through the first open door
//! beside the robot, into a side room it then cannot turn out of
//! (generated worlds, development set: most of the corridor family's
//! failures). A walker is gone from where they stand a moment later;
//! going round them is what a person does for someone standing, not for
//! someone walking the same way.
//!
//! So where people are near, the paths are chosen a second time over the
//! cloud without their cells (cells seen moving, `memory.rs`; cells within
//! a walker's radius plus `WALKER_CELL_MARGIN_M` of where the tracker
//! expects them, `people.rs`; cells inside a person box, `cloud.rs`, but
//! for a person seen standing still for a second, who is gone round: with
//! every person box's cells taken out, the paths led straight at a statue
//! the detector calls a person, the touch rule stopped the robot there,
//! and it gave way and came back for minutes — the demo hall, Case 2).
//! Where the two choices set off more than
//! `PeopleParams::swerve_max_rad` apart — people alone turn the robot
//! away — it takes the second: it drives on toward the goal behind them,
//! at the speed the guards near people allow (`walkers.rs`), and stops
//! for them (WAITING) where they are in the way. Within that angle it
//! goes round them as round anything else. Where no path is free at all
//! the robot stops as before, WAITING for the people in its way, rather
//! than closing on them (docs/design.md §4, "People in the way").

use nalgebra::Vector2;
use vlnav_geometry::wrap_angle;

use super::follow::look_point;
use super::{FollowParams, RobotState, StepInput};
use crate::cloud::ObstacleCloud;
use crate::planner::{Plan, Planner, Selection};

/// A cell within a walker's radius plus this of their expected centre is
/// theirs, m: the centroid of the body's cells wanders by a few cm between
/// frames, and the body is seen from one side.
const WALKER_CELL_MARGIN_M: f64 = 0.2;

impl RobotState {
    /// The paths' choice toward `goal_base` (`base_link`): over the whole
    /// cloud, unless walkers alone swing it more than
    /// `PeopleParams::swerve_max_rad` from the choice without them (see
    /// the module docs).
    pub(super) fn plan_behind_walkers(
        &mut self,
        planner: &Planner,
        p: &FollowParams,
        input: &StepInput<'_>,
        goal_base: Vector2<f64>,
        speed_fraction: f64,
        course: f64,
    ) -> Plan {
        let plan = planner.plan(&self.cloud, goal_base, speed_fraction, course, &mut self.scratch);
        let Some(bare) = self.without_walkers(input, p) else {
            return plan;
        };
        let behind = planner.plan(&bare, goal_base, speed_fraction, course, &mut self.scratch);
        let Some(b) = &behind.selection else {
            return plan;
        };
        // No free path at all: the robot stops, and waits where people are
        // in the way (`walkers.rs`), rather than closing on them.
        let Some(a) = &plan.selection else {
            return plan;
        };
        let swerve = wrap_angle(look_bearing(a, p) - look_bearing(b, p)).abs();
        if swerve <= p.people.swerve_max_rad {
            return plan;
        }
        tracing::debug!(stamp = input.stamp, swerve, "keeping behind a walking person");
        behind
    }

    /// The cloud without the walkers' cells, or `None` where no cell is
    /// theirs.
    fn without_walkers(&self, input: &StepInput<'_>, p: &FollowParams) -> Option<ObstacleCloud> {
        let walkers: Vec<Vector2<f64>> =
            self.people.walkers_ahead(input.stamp, 0.0, &input.pose, &p.people).into_iter().map(|(q, _)| q).collect();
        let standing = self.people.standing_at(input.stamp, &input.pose, &p.people);
        let reach = p.people.radius_m + WALKER_CELL_MARGIN_M;
        let theirs: Vec<bool> = self
            .cloud
            .cells
            .iter()
            .enumerate()
            .map(|(i, c)| {
                let at = Vector2::new(c.x as f64, c.y as f64);
                let near = |qs: &[Vector2<f64>]| qs.iter().any(|q| (q - at).norm() <= reach);
                self.moving_mask.get(i).copied().unwrap_or(false)
                    || near(&walkers)
                    || (c.person > 0 && !near(&standing))
            })
            .collect();
        if !theirs.contains(&true) {
            return None;
        }
        let cells = self.cloud.cells.iter().zip(&theirs).filter(|(_, t)| !**t).map(|(c, _)| *c).collect();
        Some(ObstacleCloud {
            cells,
            raw_points: self.cloud.raw_points,
            seen: self.cloud.seen.clone(),
            people: self.cloud.people.clone(),
        })
    }
}

/// The bearing a selection sets off on: its look-ahead point's
/// (`follow::look_point`), rad.
pub(super) fn look_bearing(sel: &Selection, p: &FollowParams) -> f64 {
    let look = look_point(sel, p);
    look.y.atan2(look.x)
}

#[cfg(test)]
mod tests {
    use nalgebra::Vector2;
    use vlnav_geometry::Pose2;

    use super::super::test_support::{drive_to, planner, view_ahead};
    use super::super::{FollowParams, RobotState};
    use super::look_bearing;
    use crate::cloud::{Cell, ObstacleCloud};

    /// A robot at the origin whose cloud is a row of cells across its way
    /// `x` m ahead, from `y0` to `y1`, each marked as the `person`-th
    /// person box's (0: no person's).
    fn row(x: f32, y0: f32, y1: f32, person: u8) -> RobotState {
        let n = ((y1 - y0) / 0.05).round() as usize;
        let cells = (0..=n)
            .map(|k| Cell { x, y: y0 + 0.05 * k as f32, blocking: 3, low: false, no_go: false, person })
            .collect();
        RobotState { cloud: ObstacleCloud { cells, ..ObstacleCloud::default() }, ..RobotState::default() }
    }

    /// The bearing the robot sets off on toward a goal 8 m ahead, and the
    /// bearing over the whole cloud (`None`: no free path).
    fn set_off(state: &mut RobotState) -> (Option<f64>, Option<f64>) {
        let p = FollowParams::default();
        let empty = ObstacleCloud::default();
        let input = drive_to(0.0, Pose2::new(0.0, 0.0, 0.0), 8.0, &empty, view_ahead());
        let goal = Vector2::new(8.0, 0.0);
        let whole = planner().plan(&state.cloud, goal, 1.0, 0.0, &mut state.scratch);
        let chosen = state.plan_behind_walkers(planner(), &p, &input, goal, 1.0, 0.0);
        (chosen.selection.map(|s| look_bearing(&s, &p)), whole.selection.map(|s| look_bearing(&s, &p)))
    }

    #[test]
    fn people_walking_across_the_way_are_followed_people_seen_standing_there_are_gone_round() {
        let p = FollowParams::default();
        // People side by side 1.2 m ahead, 2.4 m of them, walking: going
        // round takes a swerve of more than 30°; the robot keeps on toward
        // the goal.
        let mut walking = row(1.2, -1.2, 1.2, 1);
        walking.moving_mask = vec![true; walking.cloud.cells.len()];
        let (chosen, whole) = set_off(&mut walking);
        let whole = whole.expect("a way round the row");
        assert!(whole.abs() > p.people.swerve_max_rad, "round the row: {whole}");
        let chosen = chosen.expect("a way behind them");
        assert!(chosen.abs() < 0.1, "behind the people: {chosen}");
        // Person boxes not yet seen to walk: followed, as walkers.
        let (chosen, _) = set_off(&mut row(1.2, -1.2, 1.2, 1));
        assert!(chosen.is_some_and(|b| b.abs() < 0.1), "{chosen:?}");
        // The same people seen standing still for over a second, and a
        // bench there: gone round.
        let mut standing = row(1.2, -1.2, 1.2, 1);
        for k in 0..8 {
            let at: Vec<Option<Vector2<f64>>> = (-2..=2).map(|j| Some(Vector2::new(1.3, 0.5 * f64::from(j)))).collect();
            standing.people.update(-1.4 + 0.2 * f64::from(k), &at, &p.people);
        }
        for mut state in [standing, row(1.2, -1.2, 1.2, 0)] {
            let (chosen, whole) = set_off(&mut state);
            assert_eq!(chosen, whole);
            assert!(chosen.is_some_and(|b| b.abs() > p.people.swerve_max_rad));
        }
    }

    #[test]
    fn one_person_well_ahead_is_gone_round_as_anything_else() {
        // Half a metre of person 3.5 m ahead: going round sets off within
        // 30° of the straight way, so the whole cloud's choice stands.
        let mut one = row(3.5, -0.25, 0.25, 1);
        one.moving_mask = vec![true; one.cloud.cells.len()];
        let (chosen, whole) = set_off(&mut one);
        assert_eq!(chosen, whole);
        assert!(chosen.is_some());
    }

    #[test]
    fn cells_seen_moving_count_as_walkers_without_a_person_box() {
        let mut state = row(1.2, -1.2, 1.2, 0);
        state.moving_mask = vec![true; state.cloud.cells.len()];
        let (chosen, whole) = set_off(&mut state);
        assert!(whole.is_some_and(|b| b.abs() > 0.5));
        assert!(chosen.is_some_and(|b| b.abs() < 0.1), "{chosen:?}");
    }
}
