//! The creep: a robot the footprint guard stops short of its goal's
//! position tolerance creeps on toward the goal's side at `escape_speed`
//! where the guard lets it (see `guard.rs` for the guard itself).

use nalgebra::Vector2;

use super::{FollowParams, RobotState};

impl RobotState {
    /// What the robot does when the footprint guard stops every part of a
    /// path's command: a path that bends away from a zone the robot stands
    /// beside swings the rear corner into it, and stopped there it would
    /// wait for ever. It creeps on (`escape_speed`) toward the goal's side,
    /// where the guard lets it, until the turn is free: forward, on the
    /// sharpest of `CREEP_CURVATURES` that turns toward the goal and keeps
    /// the footprint clear, else straight; backward, straight. A driver
    /// pulls out of a tight spot that way: per radian of turn the rear
    /// corner swings out as far on an arc as on the spot, but on the arc the
    /// body moves forward meanwhile, so the corner follows something that
    /// runs alongside and outward (a cable along the rear-left) instead of
    /// sweeping over it, while straight on can only close in on what stands
    /// ahead (evaluation, lab: a robot that stopped before a chair with a
    /// cable along its rear-left crept straight into the chair and wedged
    /// itself there).
    pub(super) fn creep(&self, goal_base: &Vector2<f64>, dt: f64, p: &FollowParams) -> (f64, f64) {
        if goal_base.x < 0.0 {
            return self.guard(-p.escape_speed, 0.0, dt, p, &|_, _| true);
        }
        let side = if goal_base.y.atan2(goal_base.x).abs() < CREEP_STRAIGHT_RAD { 0.0 } else { goal_base.y.signum() };
        let v = p.escape_speed;
        let arcs: &[f64] = if side == 0.0 { &[] } else { &CREEP_CURVATURES };
        let moves: Vec<(f64, f64)> = arcs.iter().map(|k| (v, side * k * v)).chain([(v, 0.0)]).collect();
        // First a move that stays clear while held for `CREEP_HOLD_S` (a
        // sharp arc clear for one frame can swing the rear onto the cable
        // the next), then one clear for a frame and its stop.
        moves
            .iter()
            .find(|&&m| self.clear_for(m, CREEP_HOLD_S, dt, p))
            .or_else(|| moves.iter().find(|&&m| self.clear_for(m, 0.0, dt, p)))
            .copied()
            .unwrap_or((0.0, 0.0))
    }
}

/// The curvatures a creep tries toward the goal's side, sharpest first,
/// 1/m (radii 0.5, 1 and 2 m); the goal within `CREEP_STRAIGHT_RAD` of the
/// heading, it creeps straight.
pub(super) const CREEP_CURVATURES: [f64; 3] = [2.0, 1.0, 0.5];

pub(super) const CREEP_STRAIGHT_RAD: f64 = 0.1;

/// How long a creep's arc should stay clear if held, s (0.15 m of travel
/// at `escape_speed`).
pub(super) const CREEP_HOLD_S: f64 = 1.0;

#[cfg(test)]
mod tests {
    use nalgebra::Vector2;

    use super::super::guard::stop_horizon;
    use super::super::{FollowParams, RobotState};
    use crate::cloud::{Cell, ObstacleCloud};

    #[test]
    fn a_robot_beside_a_zone_creeps_on_when_the_turn_away_would_swing_its_rear_into_it() {
        let p = FollowParams::default();
        // A no-go rug along the left side, 0.40 m from the centre, from
        // beside the robot to 0.7 m ahead (remembered: it is out of view).
        let cells: Vec<Cell> = (0..9)
            .flat_map(|i| {
                (0..4).map(move |j| Cell {
                    x: -0.1 + 0.1 * i as f32,
                    y: 0.40 + 0.1 * j as f32,
                    blocking: 0,
                    low: false,
                    no_go: true,
                    person: 0,
                })
            })
            .collect();
        let state = RobotState { cloud: ObstacleCloud { cells, ..ObstacleCloud::default() }, ..RobotState::default() };
        // Turning right on the spot swings the rear-left corner into the rug.
        assert_eq!(state.guard(0.0, -1.57, 0.2, &p, &|_, _| true), (0.0, 0.0));
        // Straight on keeps its distance: the robot creeps toward the goal.
        assert_eq!(state.creep(&Vector2::new(3.4, 0.5), 0.2, &p), (p.escape_speed, 0.0));
        assert_eq!(state.creep(&Vector2::new(-2.0, 0.0), 0.2, &p), (-p.escape_speed, 0.0));
        // Not into something in the way.
        let mut walled = state.clone();
        walled.cloud.cells.push(Cell { x: 0.57, y: 0.0, blocking: 5, low: false, no_go: false, person: 0 });
        assert_eq!(walled.creep(&Vector2::new(3.4, 0.5), 0.2, &p), (0.0, 0.0));
    }

    #[test]
    fn a_robot_between_a_cable_and_a_chair_pulls_out_on_an_arc_toward_the_goal() {
        let p = FollowParams::default();
        // A floor cable along the rear-left (no-go), running farther out
        // ahead, and a chair's corner ahead-left, as a robot stands after
        // stopping before a chair beside a cable (evaluation, lab).
        let mut cells: Vec<Cell> = (0..9)
            .map(|i| {
                let x = -0.36 + 0.05 * i as f32;
                Cell { x, y: 0.45 + 0.5 * (x + 0.36), blocking: 0, low: false, no_go: true, person: 0 }
            })
            .collect();
        cells.extend([(0.47, 0.44), (0.51, 0.40), (0.55, 0.38)].map(|(x, y)| Cell {
            x,
            y,
            blocking: 13,
            low: false,
            no_go: false,
            person: 0,
        }));
        let state = RobotState { cloud: ObstacleCloud { cells, ..ObstacleCloud::default() }, ..RobotState::default() };
        let goal = Vector2::new(1.21, -0.62);
        // Turning right toward the goal swings the rear-left corner over the
        // cable, on the spot or on the path's tight arc.
        assert_eq!(state.guard(0.0, -1.0, 0.2, &p, &|_, _| true), (0.0, 0.0));
        assert_eq!(state.guard(0.1, -1.0, 0.2, &p, &|_, _| true), (0.0, 0.0));
        // It creeps on an arc toward the goal (radius 1 m), not straight at
        // the chair, and that arc keeps the footprint off both while held
        // for a second (5 frames).
        let (v, w) = state.creep(&goal, 0.2, &p);
        assert_eq!((v, w), (p.escape_speed, -p.escape_speed));
        assert!(!state.footprint_hits(v, w, 1.0, &p));
        assert!(state.footprint_hits(v, 0.0, stop_horizon(v, 0.0, 0.2, &p), &p));
        // The sharper 0.5 m arc is clear for a frame, but held it swings the
        // rear-left corner onto the cable.
        assert!(!state.footprint_hits(v, 2.0 * w, stop_horizon(v, 2.0 * w, 0.2, &p), &p));
        assert!(state.footprint_hits(v, 2.0 * w, 1.0, &p));
        // A goal dead ahead is crept to straight.
        let clear = RobotState::default();
        assert_eq!(clear.creep(&Vector2::new(2.0, 0.05), 0.2, &p), (p.escape_speed, 0.0));
    }
}
