//! Obstacle memory: the camera sees ±43°, so an obstacle leaves the view as
//! soon as the robot turns away from it, and a plan made without it would
//! turn straight back. Cells of recent frames, one per 5 cm `odom` voxel
//! (`memory_s`, 20 s of sensor time — the D455 sees nothing nearer than
//! its minimum range, so a sofa corner seen on the way in must still be
//! known when the robot turns beside it; `near_memory_s`, 120 s, for cells within `near_memory_m`, 1 m, of
//! the robot, which a turn in place must not forget: a robot that waits
//! beside a parked car while it searches must not forget the car) are kept in `odom` and
//! merged into the plan unless the current frame measured that place: a
//! remembered cell is forgotten only where it lies inside the view with
//! its top in the image (for a no-go marking on the floor: where the image
//! shows that floor, beyond `View::floor_from_m` — a cable just ahead lies
//! below the image while the depth along its bearing reaches past it; for
//! an obstacle lower than the camera: beyond `View::top_from` its height —
//! a water bottle 0.75 m ahead is below the image too) and the
//! frame's depth reached it along its bearing (`cloud::SeenRange`, within
//! `memory_seen_margin_m`), so an obstacle that moved away is forgotten
//! but one behind a stereo occlusion band — no depth left of a near edge,
//! docs/perception.md — is not. (Forgetting everything inside the view's
//! angle let the robot graze tunnel walls it had just seen.) When the
//! odometry jumps (re-anchored at a reached subgoal, where the robot
//! stands still) the memory moves with it: each cell keeps its place
//! relative to the robot. It is dropped when time runs backwards.
//!
//! Moving obstacles: a cell that appears where a frame `moving_lookback_s`
//! (0.25 s) earlier saw free space beyond it (by a voxel plus three
//! standard deviations of the depth error at that range, along every
//! bearing within one 1° bin plus what 5 cm subtend at its range of its
//! own: `cloud::SeenRange::free_beyond`, `moved_in_half_angle`) is
//! something that moved there — a person walking — and so is every
//! cell of the frame within `moving_cluster_m` (0.3 m) of it, and every
//! cell within that of a cell remembered as moving in the last
//! `moving_memory_s` (a person who pauses is still a person). A cell
//! remembered as standing never becomes moving. (With the cell's own bin
//! and one neighbour only, the outline of a standing person or statue
//! seen while the robot turned on the spot counted as moving in the demo
//! hall: it was forgotten once out of view and the robot, driving on
//! beside it, wedged itself against the person.) Out of view moving cells
//! are remembered for `moving_memory_s` (1.5 s) only: a person who walked
//! past the robot's side must not stay behind as a wall it can neither
//! see nor turn through. Moving cells ahead, in the view's angle but too
//! near for the camera to measure, stay until it sees their place.

use std::collections::BTreeSet;

use nalgebra::Vector2;
use vlnav_geometry::Pose2;

use super::{FollowParams, RobotState, StepInput};
use crate::cloud::{Cell, ObstacleCloud, SeenRange};

/// An obstacle cell remembered in `odom`.
#[derive(Clone, Copy, Debug)]
pub(super) struct Remembered {
    at: Vector2<f64>,
    cell: Cell,
    stamp: f64,
    /// Seen moving (see `FollowParams::moving_lookback_s`).
    moving: bool,
}

/// What one recent frame's depth saw, kept to tell moving cells from
/// standing ones.
#[derive(Clone, Debug, PartialEq)]
pub(super) struct RecentView {
    stamp: f64,
    /// `base_link` in `odom` at the frame.
    pose: Pose2,
    seen: SeenRange,
}

/// How far beyond a cell an earlier frame must have seen free space for the
/// cell to count as new there: a voxel and three standard deviations of the
/// D455's depth error, which grows with the square of range (≈ 2 % at 4 m,
/// `docs/perception.md`), m.
pub(super) fn moved_in_margin(range_m: f64) -> f64 {
    0.1 + 3.0 * vlnav_geometry::depth::d455_sigma_m(range_m)
}

/// How far to each side of a cell's bearing an earlier frame must have
/// seen free space for the cell to have moved in, rad: one 1° bin (an
/// outline falls anywhere inside the bin that holds it) plus the bearing
/// that the cell's own extent and odometry's jitter over the look-back
/// (`MOVED_IN_SLACK_M`) subtend at its range.
pub(super) fn moved_in_half_angle(range_m: f64) -> f64 {
    1f64.to_radians() + (MOVED_IN_SLACK_M / range_m.max(0.1)).atan()
}

/// A cell's half-diagonal (0.035 m of a 5 cm voxel) plus 1.5 cm of odometry
/// jitter over the look-back, m.
pub(super) const MOVED_IN_SLACK_M: f64 = 0.05;

/// Side of the `odom` grid the memory keeps one cell per, m (the cloud's voxel).
pub(super) const MEMORY_VOXEL: f64 = 0.05;

pub(super) fn memory_key(at: &Vector2<f64>) -> (i32, i32) {
    super::cell_of(at, MEMORY_VOXEL)
}

/// How tall a person is taken to be for whether the image shows them, m.
const PERSON_HEIGHT_M: f64 = 1.5;

impl RobotState {
    /// This frame's cells plus remembered cells outside the view; the
    /// memory becomes this frame's cells and the still-valid old ones.
    pub(super) fn merge_memory(
        &mut self,
        cloud: &ObstacleCloud,
        input: &StepInput<'_>,
        p: &FollowParams,
    ) -> ObstacleCloud {
        let mut cells = cloud.cells.clone();
        self.measured_cells = cells.len();
        let ats: Vec<Vector2<f64>> =
            cloud.cells.iter().map(|c| input.pose.transform(&Vector2::new(c.x as f64, c.y as f64))).collect();
        let people: Vec<Option<Vector2<f64>>> =
            cloud.people.iter().map(|at| at.map(|b| input.pose.transform(&b))).collect();
        self.people.update(input.stamp, &people, &p.people);
        // A person's recalled place the camera sees again, with depth
        // reaching a body's width past it and nobody detected there, is
        // empty now.
        let half = p.half_extents();
        self.people.forget_looked_at(input.stamp, &input.pose, &half, &p.people, |q| {
            let b = input.pose.inverse_transform(q);
            let beyond = b * (1.0 + 2.0 * p.people.radius_m / b.norm().max(1e-6));
            cloud.seen.as_ref().is_some_and(|s| s.reaches(&beyond, 0.0))
                && input.view.sees_top(&b, p.memory_near_m, PERSON_HEIGHT_M)
        });
        let moving = self.moving_cells(cloud, &ats, input.stamp, p);
        let mut moving_mask = moving.clone();
        let now: Vec<((i32, i32), Remembered)> = cloud
            .cells
            .iter()
            .zip(&ats)
            .zip(moving)
            .map(|((c, &at), moving)| (memory_key(&at), Remembered { at, cell: *c, stamp: input.stamp, moving }))
            .collect();
        let current: BTreeSet<(i32, i32)> = now.iter().map(|(k, _)| *k).collect();
        self.memory.retain(|k, m| {
            let b = input.pose.inverse_transform(&m.at);
            let age = input.stamp - m.stamp;
            // A moving cell ahead, too near for the camera to measure (below
            // its minimum range, or under the image), stays until the camera
            // sees its place: a person who stopped against the bumper is no
            // longer measured, and forgotten after `moving_memory_s` the
            // robot turned its corner into them (generated worlds,
            // development set, once a 160-pixel frame was sampled densely
            // enough to see people move: `cloud::CloudParams::stride_for`).
            let hidden_ahead =
                m.moving && input.view.in_angle(&b) && !input.view.sees_top(&b, p.memory_near_m, p.top_of(&m.cell));
            if current.contains(k)
                || (m.moving && age > p.moving_memory_s && !hidden_ahead)
                || (age > p.memory_s && !(age <= p.near_memory_s && b.norm() <= p.near_memory_m))
            {
                return false;
            }
            if b.norm() > p.memory_range_m || Self::seen_free(&m.cell, &b, cloud, input, p) {
                return false;
            }
            cells.push(Cell { x: b.x as f32, y: b.y as f32, ..m.cell });
            moving_mask.push(m.moving);
            true
        });
        self.memory.extend(now);
        self.moving_mask = moving_mask;
        if let Some(seen) = &cloud.seen {
            self.recent.push_back(RecentView { stamp: input.stamp, pose: input.pose, seen: seen.clone() });
            while self.recent.front().is_some_and(|v| input.stamp - v.stamp > 4.0 * p.moving_lookback_s) {
                self.recent.pop_front();
            }
        }
        ObstacleCloud { cells, raw_points: cloud.raw_points, seen: cloud.seen.clone(), people: cloud.people.clone() }
    }

    /// Whether this frame measured the place of a remembered `cell` at `b`
    /// (`base_link`) and found it free: the frame's depth reached it along
    /// its bearing, and the image shows it. A cell is looked at only where
    /// the image shows its top: depth along its bearing passes over
    /// something low whether or not the camera sees it. A marking on the
    /// floor (a no-go cell with nothing standing on it) needs the floor
    /// itself in the image — a cable the robot is about to cross lies below
    /// the bottom row — and a water bottle 0.75 m ahead of a D455 0.6 m up
    /// is below it too.
    pub(super) fn seen_free(
        cell: &Cell,
        b: &Vector2<f64>,
        cloud: &ObstacleCloud,
        input: &StepInput<'_>,
        p: &FollowParams,
    ) -> bool {
        let measured = cloud.seen.as_ref().is_none_or(|s| s.reaches(b, p.memory_seen_margin_m));
        let top = if cell.no_go && cell.blocking < 2 { 0.0 } else { p.top_of(cell) };
        measured && input.view.sees_top(b, p.memory_near_m, top)
    }

    /// Which of this frame's cells belong to something moving: a cell where
    /// the newest frame at least `moving_lookback_s` old saw free space
    /// beyond it, this frame's cells near such a cell (the same body), and
    /// cells near a cell remembered as moving within `moving_memory_s` (the
    /// same body a moment ago: a person who pauses is still a person). A
    /// cell remembered as standing (a wall seen before the person came
    /// beside it) never becomes moving. `ats`: the cells in `odom`.
    pub(super) fn moving_cells(
        &self,
        cloud: &ObstacleCloud,
        ats: &[Vector2<f64>],
        stamp: f64,
        p: &FollowParams,
    ) -> Vec<bool> {
        let mut moving = vec![false; cloud.cells.len()];
        let earlier = self.recent.iter().rev().find(|v| stamp - v.stamp >= p.moving_lookback_s);
        let r = p.moving_cluster_m;
        let recently_moving: Vec<Vector2<f64>> =
            self.memory.values().filter(|m| m.moving && stamp - m.stamp <= p.moving_memory_s).map(|m| m.at).collect();
        let mut seeds = Vec::new();
        let mut standing = vec![false; cloud.cells.len()];
        for (k, (c, at)) in cloud.cells.iter().zip(ats).enumerate() {
            if c.blocking == 0 {
                continue;
            }
            if self.memory.get(&memory_key(at)).is_some_and(|m| !m.moving && m.stamp < stamp) {
                standing[k] = true;
                continue;
            }
            let moved_in = earlier.is_some_and(|e| {
                let then = e.pose.inverse_transform(at);
                e.seen.free_beyond(&then, moved_in_margin(then.norm()), moved_in_half_angle(then.norm()))
            });
            if moved_in || recently_moving.iter().any(|q| (q - at).norm() <= r) {
                moving[k] = true;
                seeds.push((c.x, c.y));
            }
        }
        let r2 = (r * r) as f32;
        for (k, c) in cloud.cells.iter().enumerate() {
            if !moving[k]
                && !standing[k]
                && c.blocking > 0
                && seeds.iter().any(|&(x, y)| (c.x - x) * (c.x - x) + (c.y - y) * (c.y - y) <= r2)
            {
                moving[k] = true;
            }
        }
        moving
    }

    /// At debug level: why the robot is blocked — the remembered cells
    /// within `radius` m (base_link), their age, their blocking voxels and
    /// whether they move.
    pub(super) fn log_blocked(&self, input: &StepInput<'_>, radius: f64, why: &str) {
        if !tracing::enabled!(tracing::Level::DEBUG) {
            return;
        }
        let cells: Vec<String> = self
            .memory
            .values()
            .map(|m| (input.pose.inverse_transform(&m.at), m))
            .filter(|(b, _)| b.norm() < radius)
            .map(|(b, m)| {
                format!(
                    "({:.2}, {:.2}) {:.1} s, {} voxels{}",
                    b.x,
                    b.y,
                    input.stamp - m.stamp,
                    m.cell.blocking,
                    if m.moving { " moving" } else { "" }
                )
            })
            .collect();
        // This frame's cells the body keeps out of (fresh and remembered), in
        // `base_link`: what the guard and the paths actually see.
        let frame: Vec<String> = self
            .cloud
            .cells
            .iter()
            .filter(|c| c.keeps_out() && f64::from(c.x.hypot(c.y)) < radius)
            .map(|c| format!("({:.2}, {:.2}){}", c.x, c.y, if c.no_go { " no-go" } else { "" }))
            .collect();
        tracing::debug!(stamp = input.stamp, ?cells, ?frame, "{why}");
    }

    /// The remembered cells the body keeps out of that stand still and are
    /// no person: where each is (`odom`), the cell, and when it was seen.
    pub(super) fn standing_keep_out(&self) -> impl Iterator<Item = (Vector2<f64>, Cell, f64)> + '_ {
        self.memory
            .values()
            .filter(|m| !m.moving && m.cell.person == 0 && m.cell.keeps_out())
            .map(|m| (m.at, m.cell, m.stamp))
    }

    /// Time ran backwards (a replay restarted, a simulator reset): nothing
    /// remembered can be placed any more.
    pub(super) fn forget_all(&mut self) {
        self.grid.cells.clear();
        self.seen.clear();
        self.detour = None;
        self.memory.clear();
        self.recent.clear();
        self.people.clear();
    }

    /// Re-anchored odometry (`last` → `now` while the robot stood still):
    /// the memory and the people move with the frame, each keeping its
    /// place relative to the robot; the recent views, which only compare
    /// consecutive frames, are dropped.
    pub(super) fn reanchor(&mut self, last: Pose2, now: Pose2) {
        self.recent.clear();
        let old = std::mem::take(&mut self.memory);
        for (_, mut m) in old {
            m.at = now.transform(&last.inverse_transform(&m.at));
            self.memory.insert(memory_key(&m.at), m);
        }
        self.people.reanchor(|at| now.transform(&last.inverse_transform(at)));
        let grid = std::mem::take(&mut self.grid.cells);
        for (_, mut g) in grid {
            g.at = now.transform(&last.inverse_transform(&g.at));
            self.grid.cells.insert(super::detour::grid_key(&g.at), g);
        }
        self.seen.reanchor(last, now);
        self.detour = None;
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::Vector2;
    use vlnav_geometry::{GoalSpec, Pose2};

    use super::super::test_support::{drive_to, view_ahead};
    use super::super::{FollowParams, RobotState, StepInput, View};
    use crate::cloud::{Cell, ObstacleCloud, SeenRange};

    /// A frame whose depth reached `reach` m along every bearing except
    /// those within `hole` (rad, from the camera at the origin), with no
    /// obstacle cells.
    fn frame(reach: f64, hole: Option<(f64, f64)>) -> ObstacleCloud {
        let mut seen = SeenRange::new(Vector2::zeros());
        for k in 0..3600 {
            let a = -std::f64::consts::PI + k as f64 / 3600.0 * std::f64::consts::TAU;
            if hole.is_some_and(|(lo, hi)| a >= lo && a <= hi) {
                continue;
            }
            seen.record(reach * a.cos(), reach * a.sin());
        }
        ObstacleCloud { seen: Some(seen), ..ObstacleCloud::default() }
    }

    /// The cells planned with after merging `cloud` into the memory, seen with `view`.
    fn merged_in_view(state: &mut RobotState, cloud: &ObstacleCloud, stamp: f64, view: View) -> Vec<Cell> {
        let p = FollowParams::default();
        let input = drive_to(stamp, Pose2::new(0.0, 0.0, 0.0), 3.0, cloud, view);
        state.merge_memory(cloud, &input, &p).cells
    }

    fn remembered_after(state: &mut RobotState, cloud: &ObstacleCloud, stamp: f64) -> usize {
        merged_in_view(state, cloud, stamp, view_ahead()).len()
    }

    #[test]
    fn remembered_cells_are_forgotten_only_where_the_depth_reached_them() {
        let wall = Cell { x: 2.0, y: 0.5, blocking: 3, low: false, no_go: false, person: 0 };
        let bearing = 0.5_f64.atan2(2.0);
        let seen_wall = ObstacleCloud { cells: vec![wall], ..frame(2.0, None) };
        let mut state = RobotState::default();
        assert_eq!(remembered_after(&mut state, &seen_wall, 0.0), 1);
        // An occlusion band over the wall's bearing: nothing measured there,
        // so the wall stays although it is inside the view's angle.
        let hole = frame(4.0, Some((bearing - 0.05, bearing + 0.05)));
        assert_eq!(remembered_after(&mut state, &hole, 0.2), 1);
        // Depth that stops short of the wall (the floor seen to 1.5 m) did
        // not measure it either.
        assert_eq!(remembered_after(&mut state, &frame(1.5, None), 0.4), 1);
        // Depth that reached past it: the wall has gone.
        assert_eq!(remembered_after(&mut state, &frame(4.0, None), 0.6), 0);
        // Without coverage (clouds not built from depth) the view's angle
        // decides, as before.
        let mut state = RobotState::default();
        remembered_after(&mut state, &seen_wall, 0.0);
        assert_eq!(remembered_after(&mut state, &ObstacleCloud::default(), 0.2), 0);
    }

    #[test]
    fn a_floor_marking_below_the_image_is_remembered_until_the_image_shows_that_floor() {
        // A cable 0.9 m ahead: inside the view's angle, and the depth along
        // its bearing reaches 4 m (the floor and the walls beyond), but the
        // floor shows in the image only from 1.16 m on.
        let view = View { floor_from_m: 1.16, camera_x_m: 0.3, camera_z_m: 0.6, ..view_ahead() };
        let cable = Cell { x: 0.9, y: 0.1, blocking: 0, low: false, no_go: true, person: 0 };
        let remembered = |state: &mut RobotState, cloud: &ObstacleCloud, stamp: f64, view: View| {
            merged_in_view(state, cloud, stamp, view).len()
        };
        let mut state = RobotState::default();
        assert_eq!(remembered(&mut state, &ObstacleCloud { cells: vec![cable], ..frame(4.0, None) }, 0.0, view), 1);
        assert_eq!(remembered(&mut state, &frame(4.0, None), 0.2, view), 1, "below the image: remembered");
        // A camera that shows the floor there and no longer sees the cable: gone.
        let low = View { floor_from_m: 0.5, ..view };
        assert_eq!(remembered(&mut state, &frame(4.0, None), 0.4, low), 0);
        // An obstacle there is forgotten as before: the depth measured past it.
        let mut state = RobotState::default();
        let post = Cell { blocking: 3, no_go: false, ..cable };
        remembered(&mut state, &ObstacleCloud { cells: vec![post], ..frame(4.0, None) }, 0.0, view);
        assert_eq!(remembered(&mut state, &frame(4.0, None), 0.2, view), 0);
    }

    #[test]
    fn a_low_obstacle_below_the_image_is_remembered_until_the_image_shows_its_top() {
        // The simulated D455, 0.6 m up and 0.3 m ahead, shows the floor from
        // 1.16 m on: the top of a water bottle 0.3 m high (three voxels above
        // 0.15 m) from 0.73 m on. Nearer, the depth along its bearing passes
        // over it.
        let view = View { floor_from_m: 1.16, camera_x_m: 0.3, camera_z_m: 0.6, ..view_ahead() };
        assert!((view.top_from(0.30) - 0.73).abs() < 1e-9, "{}", view.top_from(0.30));
        assert_eq!(view.top_from(0.0), 1.16);
        assert_eq!(view.top_from(1.5), 0.3, "taller than the camera: in view from the camera on");
        let bottle = Cell { x: 0.7, y: -0.1, blocking: 3, low: false, no_go: false, person: 0 };
        let mut state = RobotState::default();
        let seen =
            |state: &mut RobotState, cloud: &ObstacleCloud, stamp: f64| merged_in_view(state, cloud, stamp, view);
        assert_eq!(seen(&mut state, &ObstacleCloud { cells: vec![bottle], ..frame(4.0, None) }, 0.0).len(), 1);
        assert_eq!(seen(&mut state, &frame(4.0, None), 0.2).len(), 1, "below the image: remembered");
        // A person there, taller than the camera, is in the image: gone
        // when the depth reaches past where they stood.
        let mut state = RobotState::default();
        let person = Cell { blocking: 30, ..bottle };
        seen(&mut state, &ObstacleCloud { cells: vec![person], ..frame(4.0, None) }, 0.0);
        assert!(seen(&mut state, &frame(4.0, None), 0.2).is_empty());
        // The bottle farther off, with its top in the image: forgotten too.
        let mut state = RobotState::default();
        let far = Cell { x: 0.9, ..bottle };
        seen(&mut state, &ObstacleCloud { cells: vec![far], ..frame(4.0, None) }, 0.0);
        assert!(seen(&mut state, &frame(4.0, None), 0.2).is_empty());
    }

    #[test]
    fn a_cell_that_appeared_in_free_space_is_moving_and_soon_forgotten_out_of_view() {
        // Beside the robot, outside the ±43° view: only the memory holds it.
        let person = Cell { x: 0.2, y: 1.0, blocking: 3, low: false, no_go: false, person: 0 };
        let sofa = Cell { x: -0.2, y: 1.0, blocking: 3, low: false, no_go: false, person: 0 };
        let mut state = RobotState::default();
        // The sofa was there from the first frame; the space where the person
        // now stands was seen free (depth reached 4 m all round).
        assert_eq!(remembered_after(&mut state, &ObstacleCloud { cells: vec![sofa], ..frame(4.0, None) }, 0.0), 1);
        let both = ObstacleCloud { cells: vec![sofa, person], ..frame(4.0, None) };
        assert_eq!(remembered_after(&mut state, &both, 0.3), 2);
        let moving: Vec<bool> = state.memory.values().map(|m| m.moving).collect();
        assert_eq!(moving.iter().filter(|m| **m).count(), 1, "the person moves, the sofa stands: {moving:?}");
        // Out of view, a moving cell is remembered for 1.5 s, a standing one for 20 s.
        assert_eq!(remembered_after(&mut state, &frame(4.0, None), 1.5), 2);
        assert_eq!(remembered_after(&mut state, &frame(4.0, None), 2.0), 1);
        assert_eq!(remembered_after(&mut state, &frame(4.0, None), 15.0), 1);
    }

    #[test]
    fn a_moving_cell_ahead_too_near_to_measure_stays_until_its_place_is_seen() {
        // A person who walked in and stopped 0.55 m ahead of the base, 0.05 m
        // from the bumper: nearer than the camera measures (`memory_near_m`,
        // 0.6 m), though inside the view's angle.
        let person = Cell { x: 0.55, y: 0.1, blocking: 30, low: false, no_go: false, person: 0 };
        let beside = Cell { x: 0.2, y: 1.0, ..person };
        let mut state = RobotState::default();
        assert_eq!(remembered_after(&mut state, &frame(4.0, None), 0.0), 0);
        let walked_in = ObstacleCloud { cells: vec![person, beside], ..frame(4.0, None) };
        assert_eq!(remembered_after(&mut state, &walked_in, 0.3), 2);
        assert!(state.memory.values().all(|m| m.moving), "both moved in");
        // Unmeasured for longer than `moving_memory_s`: the one beside the
        // robot, out of view, is forgotten; the one ahead is not.
        let kept = merged_in_view(&mut state, &frame(4.0, None), 2.5, view_ahead());
        assert_eq!(kept.len(), 1);
        assert_eq!((kept[0].x, kept[0].y), (0.55, 0.1));
        assert_eq!(remembered_after(&mut state, &frame(4.0, None), 15.0), 1, "still unmeasured");
        // Backed off 0.3 m, the camera sees the place, and depth reaches past it.
        let p = FollowParams::default();
        let empty = frame(4.0, None);
        let back = drive_to(15.2, Pose2::new(-0.3, 0.0, 0.0), 3.0, &empty, view_ahead());
        assert!(state.merge_memory(&empty, &back, &p).cells.is_empty(), "seen gone");
    }

    /// One frame of a robot at `pose` looking at a post of radius 0.25 m
    /// standing at `post` (odom) in an empty hall whose floor and walls the
    /// depth reached 10 m away: the post's visible outline as 5 cm cells
    /// (`base_link`) and the range seen along every bearing.
    fn post_frame(pose: Pose2, post: Vector2<f64>) -> ObstacleCloud {
        let c = pose.inverse_transform(&post);
        let (r, half_fov) = (0.25, 0.75);
        let mut seen = SeenRange::new(Vector2::zeros());
        let mut cells: Vec<Cell> = Vec::new();
        for k in 0..7200 {
            let a = -std::f64::consts::PI + k as f64 / 7200.0 * std::f64::consts::TAU;
            if a.abs() > half_fov {
                continue;
            }
            let dir = Vector2::new(a.cos(), a.sin());
            // Nearest intersection of the ray with the post's circle.
            let along = dir.dot(&c);
            let miss = (c - dir * along).norm();
            if along > 0.0 && miss < r {
                let hit = dir * (along - (r * r - miss * miss).sqrt());
                seen.record_obstacle(hit.x, hit.y);
                let (x, y) =
                    ((hit.x / 0.05).floor() as f32 * 0.05 + 0.025, (hit.y / 0.05).floor() as f32 * 0.05 + 0.025);
                if !cells.iter().any(|q| q.x == x && q.y == y) {
                    cells.push(Cell { x, y, blocking: 3, low: false, no_go: false, person: 0 });
                }
            } else {
                seen.record(10.0 * dir.x, 10.0 * dir.y);
            }
        }
        ObstacleCloud { cells, raw_points: 0, seen: Some(seen), people: vec![] }
    }

    #[test]
    fn a_standing_post_seen_while_turning_or_driving_never_counts_as_moving() {
        // The outline of a standing thing shifts between bins as the robot
        // turns or nears it, and odometry's heading is off by up to half a
        // degree from frame to frame; none of its cells moved in.
        let p = FollowParams::default();
        let post = Vector2::new(3.5, 0.4);
        let goal = GoalSpec {
            pose: Pose2::new(3.0, 0.0, 0.0),
            position_tolerance: 0.3,
            yaw_tolerance: 0.2,
            rotation_only: false,
            landmark: None,
        };
        for drive in [false, true] {
            let mut state = RobotState::default();
            for k in 0..60 {
                let t = k as f64 * 0.1;
                let pose = if drive {
                    Pose2::new(0.4 * t, -0.05 * t, 0.02 * t)
                } else {
                    Pose2::new(0.0, 0.0, -0.6 + 0.26 * t)
                };
                let cloud = post_frame(pose, post);
                let odom = Pose2::new(pose.x, pose.y, pose.theta + if k % 2 == 0 { 0.008 } else { -0.008 });
                let input = StepInput { stamp: t, pose: odom, goal, cloud: &cloud, max_speed: 0.0, view: view_ahead() };
                state.merge_memory(&cloud, &input, &p);
                let moving: Vec<Vector2<f64>> = state.memory.values().filter(|m| m.moving).map(|m| m.at).collect();
                assert!(
                    moving.is_empty(),
                    "driving {drive}, {t:.1} s: the post's cells at {moving:?} counted as moving"
                );
            }
        }
    }

    #[test]
    fn a_post_that_slides_across_the_view_counts_as_moving() {
        // The same post carried across at 0.6 m/s, 3 m ahead: a person walking.
        let p = FollowParams::default();
        let goal = GoalSpec {
            pose: Pose2::new(3.0, 0.0, 0.0),
            position_tolerance: 0.3,
            yaw_tolerance: 0.2,
            rotation_only: false,
            landmark: None,
        };
        let mut state = RobotState::default();
        let mut seen_moving = 0;
        for k in 0..20 {
            let t = k as f64 * 0.1;
            let cloud = post_frame(Pose2::new(0.0, 0.0, 0.0), Vector2::new(3.0, -0.6 + 0.6 * t));
            let input = StepInput {
                stamp: t,
                pose: Pose2::new(0.0, 0.0, 0.0),
                goal,
                cloud: &cloud,
                max_speed: 0.0,
                view: view_ahead(),
            };
            state.merge_memory(&cloud, &input, &p);
            seen_moving += usize::from(state.memory.values().any(|m| m.moving && m.stamp == t));
        }
        assert!(seen_moving >= 15, "moving in only {seen_moving} of 20 frames");
    }
}
