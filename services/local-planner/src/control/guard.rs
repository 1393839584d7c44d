//! Footprint guard: the paths keep a 0.45 m tube around the robot's centre
//! clear, but the Husky's corners reach 0.60 m, and a path that grazes an
//! obstacle diagonally ahead (or a goal beside a parked car) lets a corner
//! or the swinging rear touch it. Before a command goes out, the robot's
//! rectangle (`half_length_m` × `half_width_m`, plus `guard_margin_m`) is
//! moved along the commanded arc for one frame period plus the time
//! needed to stop (the longer of `v / 2·max_accel` and `ω / 2·yaw_decel`:
//! a spot turn beside a parked bicycle, checked over one frame only,
//! swung the rear corner into it while braking — evaluation, garage,
//! trial 3); if it would take in a blocking cell
//! (≥ 2 voxels) or a no-go cell (a marked zone, a cable: the paths keep
//! their 0.45 m tube off it, but a corner swinging round a cable's end
//! entered it — soft contact, docs/design.md §6), this frame's or
//! remembered, that it does not already cover, the command is reduced —
//! the turn alone, the straight part alone, or a stop. A robot stopped by
//! the guard within the goal's position tolerance has reached it (as
//! close as its body fits); farther away it creeps on toward the goal's
//! side at `escape_speed` where the guard lets it — forward on the
//! sharpest arc toward the goal that stays clear for `CREEP_HOLD_S`,
//! else straight (a path bending away from a zone beside the robot swings
//! the rear corner into it, and stopped there it would wait for ever:
//! `RobotState::creep`) — and the progress watchdog takes over where it
//! cannot.

use nalgebra::Vector2;

use super::{FollowParams, RobotState};
use crate::cloud::Cell;

impl RobotState {
    /// Whether the arc (v, ω) held for `horizon` s brings a cell the body
    /// must keep out of (an obstacle or a no-go region, [`Cell::keeps_out`])
    /// into the (margin-inflated) footprint that it does not cover now, or
    /// a cell already within the margin into the body itself (a box 3 cm
    /// ahead of the bumper is not to be driven into because it stands in
    /// the margin already; a cell inside the body — noise, or contact made —
    /// does not hold the robot).
    pub(super) fn footprint_hits(&self, v: f64, w: f64, horizon: f64, p: &FollowParams) -> bool {
        self.footprint_hits_from((0.0, 0.0, 0.0), v, w, horizon, p)
    }

    /// [`Self::footprint_hits`] for an arc that starts at `from` (x, y,
    /// heading in `base_link`) instead of where the robot stands.
    pub(super) fn footprint_hits_from(
        &self,
        from: (f64, f64, f64),
        v: f64,
        w: f64,
        horizon: f64,
        p: &FollowParams,
    ) -> bool {
        const SAMPLES: usize = 6;
        let (fs, fc) = (from.2.sin() as f32, from.2.cos() as f32);
        let (fx, fy) = (from.0 as f32, from.1 as f32);
        // A cell in the frame of the arc's start.
        let local = |c: &Cell| -> (f32, f32) {
            let (dx, dy) = (c.x - fx, c.y - fy);
            (fc * dx + fs * dy, -fs * dx + fc * dy)
        };
        let (hl, hw) = ((p.half_length_m + p.guard_margin_m) as f32, (p.half_width_m + p.guard_margin_m) as f32);
        let (bl, bw) = (p.half_length_m as f32, p.half_width_m as f32);
        let inside = |x: f32, y: f32| x.abs() <= hl && y.abs() <= hw;
        let poses: Vec<(f32, f32, f32, f32)> = (1..=SAMPLES)
            .map(|k| {
                let t = horizon * k as f64 / SAMPLES as f64;
                let (x, y, th) = arc_pose(v, w, t);
                (x as f32, y as f32, th.cos() as f32, th.sin() as f32)
            })
            .collect();
        let reach = (hl * hl + hw * hw).sqrt() + (v.abs() * horizon) as f32;
        self.cloud
            .cells
            .iter()
            .filter(|c| c.keeps_out())
            .map(local)
            .filter(|&(cx, cy)| cx * cx + cy * cy <= reach * reach && !(cx.abs() <= bl && cy.abs() <= bw))
            .any(|(cx, cy)| {
                // The rectangle the cell must stay out of: the body for a
                // cell already within the margin, else the inflated one.
                let (l, w) = if inside(cx, cy) { (bl, bw) } else { (hl, hw) };
                poses.iter().any(|&(x, y, cs, sn)| {
                    let (dx, dy) = (cx - x, cy - y);
                    (cs * dx + sn * dy).abs() <= l && (-sn * dx + cs * dy).abs() <= w
                })
            })
    }

    /// Whether the footprint centred at `centre` (`base_link`) facing
    /// `heading` (rad, `base_link`) holds no cell the body must keep out of.
    pub(super) fn footprint_clear_at(&self, centre: &Vector2<f64>, heading: f64, p: &FollowParams) -> bool {
        let (hl, hw) = (p.half_length_m + p.guard_margin_m, p.half_width_m + p.guard_margin_m);
        let (s, c) = heading.sin_cos();
        !self.cloud.cells.iter().filter(|cell| cell.keeps_out()).any(|cell| {
            let (dx, dy) = (f64::from(cell.x) - centre.x, f64::from(cell.y) - centre.y);
            (c * dx + s * dy).abs() <= hl && (-s * dx + c * dy).abs() <= hw
        })
    }

    /// Whether no cell the body must keep out of lies within `radius` of
    /// `centre` (`base_link`).
    pub(super) fn disc_clear_at(&self, centre: &Vector2<f64>, radius: f64) -> bool {
        !self
            .cloud
            .cells
            .iter()
            .filter(|cell| cell.keeps_out())
            .any(|cell| (f64::from(cell.x) - centre.x).hypot(f64::from(cell.y) - centre.y) <= radius)
    }

    /// The command itself if its arc keeps the footprint clear (and `ok`
    /// accepts it), else the first such of: the turn alone, the straight
    /// part alone, a stop.
    pub(super) fn guard(&self, v: f64, w: f64, dt: f64, p: &FollowParams, ok: &dyn Fn(f64, f64) -> bool) -> (f64, f64) {
        [(v, w), (0.0, w), (v, 0.0)]
            .into_iter()
            .find(|&(v, w)| {
                (v != 0.0 || w != 0.0) && !self.footprint_hits(v, w, stop_horizon(v, w, dt, p), p) && ok(v, w)
            })
            .unwrap_or((0.0, 0.0))
    }

    /// Whether the footprint stays clear on the arc (v, ω) held for `hold`
    /// s, or for a frame and its stop if that is longer.
    pub(super) fn clear_for(&self, (v, w): (f64, f64), hold: f64, dt: f64, p: &FollowParams) -> bool {
        !self.footprint_hits(v, w, hold.max(stop_horizon(v, w, dt, p)), p)
    }
}

/// Where the arc (v, ω) held for `t` s takes the robot, base link at its
/// start: x, y and heading.
pub(super) fn arc_pose(v: f64, w: f64, t: f64) -> (f64, f64, f64) {
    let th = w * t;
    if w.abs() < 1e-6 { (v * t, 0.0, th) } else { (v / w * th.sin(), v / w * (1.0 - th.cos()), th) }
}

/// How long the guard follows an arc: one frame, then as long as stopping
/// takes — the linear part at `max_accel`, the turn at `yaw_decel` (a spot
/// turn's rear corner swings on while it brakes), s.
pub(super) fn stop_horizon(v: f64, w: f64, dt: f64, p: &FollowParams) -> f64 {
    dt + (v.abs() / (2.0 * p.max_accel)).max(w.abs() / (2.0 * p.yaw_decel))
}

#[cfg(test)]
mod tests {
    use nalgebra::Vector2;

    use super::super::test_support::with_cells;
    use super::super::{FollowParams, RobotState};
    use crate::cloud::{Cell, ObstacleCloud};

    #[test]
    fn the_guard_keeps_the_footprint_off_obstacles_the_path_tube_misses() {
        let p = FollowParams::default();
        // A post diagonally ahead, 0.45 m to the left: clear of the straight
        // footprint (half-width 0.335 + 0.05), but driving a left arc swings
        // the front-left corner into it. Turning on the spot (one frame) is
        // clear, so the forward part waits.
        let post = with_cells(&[(0.6, 0.45)]);
        assert_eq!(post.guard(0.5, 1.0, 0.2, &p, &|_, _| true), (0.0, 1.0));
        // With the spot turn also blocked (a second post where the rear-right
        // corner swings), the
        // straight part alone is left.
        let posts = with_cells(&[(0.6, 0.45), (-0.45, -0.45)]);
        assert_eq!(posts.guard(0.5, 1.0, 0.2, &p, &|_, _| true), (0.5, 0.0));
        // Turning away from it is fine.
        assert_eq!(post.guard(0.5, -1.0, 0.2, &p, &|_, _| true), (0.5, -1.0));
        // A wall straight ahead within a frame and the stopping distance: stop.
        let wall = with_cells(&[(0.8, -0.1), (0.8, 0.0), (0.8, 0.1)]);
        assert_eq!(wall.guard(0.6, 0.0, 0.2, &p, &|_, _| true), (0.0, 0.0));
        // Far enough ahead to stop before it: go on.
        let far = with_cells(&[(1.6, 0.0)]);
        assert_eq!(far.guard(0.6, 0.0, 0.2, &p, &|_, _| true), (0.6, 0.0));
        // A cell the footprint already covers does not freeze the robot.
        let touching = with_cells(&[(0.3, 0.2)]);
        assert_eq!(touching.guard(-0.15, 0.0, 0.2, &p, &|_, _| true), (-0.15, 0.0));
        // One voxel is noise, not an obstacle.
        let ghost = RobotState {
            cloud: ObstacleCloud {
                cells: vec![Cell { x: 0.7, y: 0.0, blocking: 1, low: false, no_go: false, person: 0 }],
                ..ObstacleCloud::default()
            },
            ..RobotState::default()
        };
        assert_eq!(ghost.guard(0.5, 0.0, 0.2, &p, &|_, _| true), (0.5, 0.0));
    }

    #[test]
    fn the_guard_keeps_the_footprint_out_of_no_go_regions_too() {
        let p = FollowParams::default();
        // A cable's end diagonally ahead, 0.45 m to the left, on the floor:
        // no voxel above it, only the segmenter's no-go cell. A left arc
        // would swing the front-left corner over it, as it would into a post.
        let cable = |no_go| RobotState {
            cloud: ObstacleCloud {
                cells: vec![Cell { x: 0.6, y: 0.45, blocking: 0, low: false, no_go, person: 0 }],
                ..ObstacleCloud::default()
            },
            ..RobotState::default()
        };
        assert_eq!(cable(true).guard(0.5, 1.0, 0.2, &p, &|_, _| true), (0.0, 1.0));
        assert_eq!(
            cable(false).guard(0.5, 1.0, 0.2, &p, &|_, _| true),
            (0.5, 1.0),
            "a bare floor cell is no reason to stop"
        );
        // A goal whose footprint would lie on it is moved sideways off it.
        assert!(!cable(true).footprint_clear_at(&Vector2::new(0.6, 0.2), 0.0, &p));
        assert!(cable(true).footprint_clear_at(&Vector2::new(0.6, -0.0), 0.0, &p));
    }

    #[test]
    fn a_spot_turn_beside_a_parked_bicycle_counts_the_sweep_while_it_brakes() {
        let p = FollowParams::default();
        // The bicycle's side runs along the robot's right, 0.55 m from its
        // centre, from 1 m behind to beside the centre.
        let cells: Vec<Cell> = (0..21)
            .map(|i| Cell { x: -1.0 + 0.05 * i as f32, y: -0.55, blocking: 10, low: false, no_go: false, person: 0 })
            .collect();
        let state = RobotState { cloud: ObstacleCloud { cells, ..ObstacleCloud::default() }, ..RobotState::default() };
        // Turning left at 1.5 rad/s the rear-right corner swings toward it:
        // one frame (0.3 rad) keeps clear, but braking at 3 rad/s² takes
        // 0.375 rad more, and the inflated corner crosses the side at about
        // 0.42 rad: the robot stops (and creeps on, `creep`).
        assert_eq!(state.guard(0.0, 1.5, 0.2, &p, &|_, _| true), (0.0, 0.0));
        // Braking counted over one frame only, the turn went ahead.
        assert!(!state.footprint_hits(0.0, 1.5, 0.2, &p));
        // Turning right swings it away.
        assert_eq!(state.guard(0.0, -1.5, 0.2, &p, &|_, _| true), (0.0, -1.5));
    }

    #[test]
    fn a_cell_within_the_guard_margin_is_not_driven_into() {
        let p = FollowParams::default();
        // A box 0.03 m ahead of the bumper: inside the margin-inflated
        // footprint already, outside the body.
        let cell = Cell { x: 0.525, y: 0.0, blocking: 3, low: false, no_go: false, person: 0 };
        let state = RobotState {
            measured_cells: 1,
            cloud: ObstacleCloud { cells: vec![cell], ..ObstacleCloud::default() },
            ..RobotState::default()
        };
        assert!(state.footprint_hits(0.15, 0.0, 1.0, &p), "forward: into the body");
        assert!(state.footprint_hits(0.15, 0.3, 1.0, &p), "forward on an arc: into the body");
        assert!(!state.footprint_hits(-0.15, 0.0, 1.0, &p), "backing away");
        // Inside the body (noise, or contact made): it holds nothing.
        let touching = RobotState {
            cloud: ObstacleCloud { cells: vec![Cell { x: 0.45, ..cell }], ..ObstacleCloud::default() },
            ..RobotState::default()
        };
        assert!(!touching.footprint_hits(0.15, 0.0, 1.0, &p));
    }
}
