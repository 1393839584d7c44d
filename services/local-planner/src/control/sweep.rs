//! Rotating in place sweeps a disc: the Husky's corners reach
//! `sweep_radius_m` (its half-diagonal, √(0.495² + 0.335²) = 0.60 m, plus
//! 0.05 m; a remembered cell counts `memory_drift_m`, 0.05 m, farther
//! out, for the odometry's slip since it was seen). Before any turn in
//! place the disc must be free of obstacle cells (this frame's or
//! remembered); if it is not, the robot first
//! moves straight, at `escape_speed`, by the shorter of the forward and
//! the backward move that leaves the disc free (away from the nearest
//! cell when they are equal) with the body's lane free that far (backing,
//! where only memory knows the floor, within `near_memory_m` less the
//! disc's radius, 0.35 m). Where neither does within the disc's diameter,
//! it turns on the sharpest forward arc toward the turn's side that keeps
//! the footprint clear (`RobotState::arc_turn`); where no arc completes
//! the turn, it takes the move that frees the disc soonest and turns on
//! the spot from there (`RobotState::unwedge`); and it reports BLOCKED
//! where nothing frees the disc, rather than grinding a corner along a
//! parked car during a look-around.

use nalgebra::Vector2;

use super::creep::{CREEP_CURVATURES, CREEP_HOLD_S};
use super::guard::arc_pose;
use super::narrow::NARROW_SWEEP_M;
use super::{FollowParams, RobotState, StepInput};
use crate::cloud::Cell;

/// What a turn in place must do first when its sweep disc is not free.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Sweep {
    /// Move straight at this speed (m/s, negative: backwards) to clear it.
    Escape(f64),
    /// Neither straight move clears it: turn on this forward arc (v, ω)
    /// instead, which keeps the footprint clear where the spot turn's
    /// corners would sweep over something.
    Arc(f64, f64),
    /// The way out is taken too.
    Blocked,
}

impl RobotState {
    /// `None` when a turn in place (`turn`, rad, signed) is free to go;
    /// otherwise how to clear the disc first: the shorter straight move
    /// (forward or back) that clears it, or when neither does within
    /// `SWEEP_ESCAPE_MAX_M` (backing, within `near_memory_m − sweep_radius_m`)
    /// with the body's lane free, the turn made on a forward arc
    /// ([`RobotState::arc_turn`]; `goal`: the position the turn faces, base
    /// link), or BLOCKED when no arc keeps clear either.
    pub(super) fn sweep(
        &self,
        input: &StepInput<'_>,
        p: &FollowParams,
        turn: f64,
        goal: Option<&Vector2<f64>>,
        dt: f64,
    ) -> Option<Sweep> {
        // A remembered cell carries the odometry's drift since it was seen;
        // passing through a narrow passage, more (`narrow.rs`).
        let r_mem = p.sweep_radius_m + p.memory_drift_m + if self.narrow(input, p) { NARROW_SWEEP_M } else { 0.0 };
        // A person gets a wider berth than furniture: their place (the
        // tracker's) counts `PeopleParams::radius_m` nearer, since people
        // sway and step while the corners swing.
        let people: Vec<Cell> = self
            .people
            .people_at(input.stamp, &input.pose, &p.people)
            .into_iter()
            .filter(|q| q.norm() > 1e-6)
            .map(|q| {
                let near = q * ((q.norm() - p.people.radius_m).max(0.0) / q.norm());
                Cell { x: near.x as f32, y: near.y as f32, blocking: 2, low: false, no_go: false, person: 1 }
            })
            .collect();
        // Each cell with the radius it must keep outside of.
        let (r_now, r_mem) = (p.sweep_radius_m as f32, r_mem as f32);
        let cells: Vec<(f32, f32, f32)> = self
            .cloud
            .cells
            .iter()
            .enumerate()
            .map(|(i, c)| (c.x, c.y, if i < self.measured_cells { r_now } else { r_mem }))
            .chain(people.iter().map(|c| (c.x, c.y, r_now)))
            .collect();
        let nearest = cells
            .iter()
            .filter(|(x, y, r)| x * x + y * y < r * r)
            .min_by(|a, b| (a.0 * a.0 + a.1 * a.1).total_cmp(&(b.0 * b.0 + b.1 * b.1)))?;
        // Straight along the robot's axis, the shortest move either way that
        // leaves every cell outside the disc, if the body's lane is free
        // that far (its half-length plus the sweep's margin, at least 0.1 m,
        // beyond). Moving away from the nearest cell alone flipped between
        // two obstacles ahead and behind, 3 cm each way, for over a minute
        // (evaluation, garage, trial 3: a parked car ahead-left, the
        // bicycle behind-right); the shortest clearing move does not flip,
        // since moving along it shortens it.
        let reach = (p.half_length_m + (p.sweep_radius_m - p.half_length_m).max(0.1)) as f32;
        let lane = p.half_width_m as f32 + 0.05;
        // Behind the camera the disc is known only from memory, kept for
        // long only within `near_memory_m` of the robot: backing out, the
        // disc where the robot ends must lie within it (a robot that backed
        // 0.75 m along a corridor wall forgotten there turned its corner
        // into it: evaluation, corridor, visual trial 1).
        let back_max = (p.near_memory_m - p.sweep_radius_m).max(0.0) as f32;
        // Each cell the disc can take in along the axis: its x and the half
        // chord the disc's circle cuts at its y (the disc centred at c holds
        // it while |x − c| < h).
        let chords: Vec<(f32, f32)> =
            cells.iter().filter(|(_, y, r)| y.abs() < *r).map(|&(x, y, r)| (x, (r * r - y * y).sqrt())).collect();
        let clearing = |dir: f32| -> Option<f32> {
            let mut s = 0.0_f32;
            loop {
                let need = chords
                    .iter()
                    .filter(|&&(x, h)| (dir * x - s).abs() < h)
                    .map(|&(x, h)| dir * x + h)
                    .fold(s, f32::max);
                if need <= s {
                    break;
                }
                s = need + 1e-3;
                if s > SWEEP_ESCAPE_MAX_M {
                    return None;
                }
            }
            let taken = cells.iter().any(|&(x, y, _)| dir * x > 0.0 && dir * x < s + reach && y.abs() < lane);
            (!taken && (dir > 0.0 || s <= back_max)).then_some(s)
        };
        let away = if nearest.0 > 0.0 { -1.0_f32 } else { 1.0 };
        let dir = match (clearing(away), clearing(-away)) {
            (Some(a), Some(b)) if b + 0.01 < a => -away,
            (Some(_), _) => away,
            (None, Some(_)) => -away,
            (None, None) => {
                let arc = self.arc_turn(turn, goal, dt, p).or_else(|| self.unwedge(turn, &cells, back_max, dt, p));
                return Some(arc.map_or(Sweep::Blocked, |(v, w)| Sweep::Arc(v, w)));
            }
        };
        Some(Sweep::Escape(f64::from(dir) * p.escape_speed))
    }

    /// A turn in place toward `turn`'s side that its sweep forbids (the
    /// corners of a spot turn reach every point of the sweep disc's rim,
    /// but on an arc of radius R the rear corner swings out by about
    /// l² / 2 (R + w) only: l the half-length, w the half-width — 0.09 m at
    /// R = 1 m), made on the sharpest of `CREEP_CURVATURES` forward at
    /// `escape_speed` that keeps the footprint clear while held for
    /// `CREEP_HOLD_S`. Toward a goal position (`goal`, base link) only an arc
    /// whose circle leaves it outside: inside, the robot would circle it for
    /// ever. `None` when no arc is clear (evaluation, lab: a robot that ended
    /// a move beside a cable along its left, told to turn right, was BLOCKED
    /// and asked the user).
    pub(super) fn arc_turn(
        &self,
        turn: f64,
        goal: Option<&Vector2<f64>>,
        dt: f64,
        p: &FollowParams,
    ) -> Option<(f64, f64)> {
        let side = turn.signum();
        let v = p.escape_speed;
        CREEP_CURVATURES
            .iter()
            .filter(|&&k| goal.is_none_or(|g| (g - Vector2::new(0.0, side / k)).norm() > 1.0 / k))
            .map(|&k| (v, side * k * v))
            .find(|&m| self.clear_for(m, CREEP_HOLD_S, dt, p))
    }

    /// Where no arc completes the turn (each either hits something or
    /// circles the goal), the move that frees the sweep disc soonest, so
    /// that the turn can then be made on the spot: forward or backward (no
    /// farther than `back_max`, m) at `escape_speed` on one of
    /// `CREEP_CURVATURES` either way, held clear until, within
    /// `UNWEDGE_MAX_S`, the disc centred where the robot then stands holds
    /// none of `cells` (x, y, the radius each must keep outside of, base
    /// link); among equally soon, toward the turn's side and forward first.
    /// Taking it frame after frame shortens it, so the robot does not
    /// dither; a goal inside the arc's circle is no trap, since the arc is
    /// left once the disc is free (evaluation, lab: a robot stopped before
    /// a chair, with a cable along its left and the landmark to revisit on
    /// its right, inside every forward arc's circle, reported BLOCKED, its
    /// search legs ran into the chair, and it asked for a plant in view of
    /// where it stood).
    pub(super) fn unwedge(
        &self,
        turn: f64,
        cells: &[(f32, f32, f32)],
        back_max: f32,
        dt: f64,
        p: &FollowParams,
    ) -> Option<(f64, f64)> {
        const STEP_S: f64 = 0.5;
        let side = turn.signum();
        let v = p.escape_speed;
        let disc_free = |x: f64, y: f64| {
            cells.iter().all(|&(cx, cy, r)| {
                let (dx, dy) = (f64::from(cx) - x, f64::from(cy) - y);
                dx * dx + dy * dy >= f64::from(r * r)
            })
        };
        let moves = [v, -v].into_iter().flat_map(|v| {
            [side, -side].into_iter().flat_map(move |s| CREEP_CURVATURES.iter().map(move |k| (v, s * k * v.abs())))
        });
        let steps = (UNWEDGE_MAX_S / STEP_S).round() as u32;
        moves
            .filter_map(|(v, w)| {
                (1..=steps)
                    .map(|i| f64::from(i) * STEP_S)
                    .take_while(|&t| {
                        (v > 0.0 || v.abs() * t <= f64::from(back_max)) && self.clear_for((v, w), t, dt, p)
                    })
                    .find(|&t| {
                        let (x, y, _) = arc_pose(v, w, t);
                        disc_free(x, y)
                    })
                    .map(|t| (t, (v, w)))
            })
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .map(|(_, m)| m)
    }
}

/// The longest straight move that may clear the sweep disc before a turn
/// in place, m (its diameter): farther, the turn goes on an arc, if one is clear.
pub(super) const SWEEP_ESCAPE_MAX_M: f32 = 1.3;

/// The longest a move that frees the sweep disc may take before the turn,
/// s ([`RobotState::unwedge`]; 0.6 m at `escape_speed`).
pub(super) const UNWEDGE_MAX_S: f64 = 4.0;

#[cfg(test)]
mod tests {
    use nalgebra::Vector2;

    use super::super::test_support::turn_in_place_to;
    use super::super::{FollowParams, RobotState};
    use super::{Sweep, UNWEDGE_MAX_S};
    use crate::cloud::{Cell, ObstacleCloud};

    #[test]
    fn a_remembered_cell_counts_farther_out_for_a_turn_in_place() {
        let p = FollowParams::default();
        // 0.67 m behind-right: outside the 0.65 m disc, inside 0.70 m.
        let cell = Cell { x: -0.4, y: -0.5375, blocking: 10, low: false, no_go: false, person: 0 };
        let cloud = ObstacleCloud { cells: vec![cell], ..ObstacleCloud::default() };
        let mut state = RobotState { cloud, measured_cells: 1, ..RobotState::default() };
        let empty = ObstacleCloud::default();
        let input = turn_in_place_to(3.0, &empty);
        assert_eq!(
            state.sweep(&input, &p, input.goal.pose.theta, None, 0.2),
            None,
            "measured this frame: the turn may go"
        );
        state.measured_cells = 0;
        assert_eq!(
            state.sweep(&input, &p, input.goal.pose.theta, None, 0.2),
            Some(Sweep::Escape(p.escape_speed)),
            "remembered: move away first"
        );
        // A person standing 0.9 m to the left (their body's edge 0.6 m off,
        // the cells of this frame outside the disc): people get 0.3 m more.
        let seen = |at: Vector2<f64>, frames: u32| {
            let mut state = RobotState::default();
            for k in 0..frames {
                state.people.update(-0.2 * f64::from(frames - k), &[Some(at)], &p.people);
            }
            state
        };
        let beside = seen(Vector2::new(0.0, 0.9), 3);
        assert_eq!(
            beside.sweep(&input, &p, input.goal.pose.theta, None, 0.2),
            Some(Sweep::Escape(p.escape_speed)),
            "a person beside: move away first"
        );
        assert_eq!(
            seen(Vector2::new(0.0, 1.0), 3).sweep(&input, &p, input.goal.pose.theta, None, 0.2),
            None,
            "a person 1.0 m off: the turn may go"
        );
        assert_eq!(
            seen(Vector2::new(0.0, 0.9), 1).sweep(&input, &p, input.goal.pose.theta, None, 0.2),
            None,
            "one box (a false positive?) is no person yet"
        );
    }

    #[test]
    fn a_turn_wedged_between_two_obstacles_backs_out_one_way_not_both() {
        let p = FollowParams::default();
        let wall = |x0: f32, y: f32, n: usize| -> Vec<Cell> {
            (0..n)
                .map(|i| Cell { x: x0 + 0.05 * i as f32, y, blocking: 10, low: false, no_go: false, person: 0 })
                .collect()
        };
        // A parked car's corner ahead-left (0.632 m off), its side running
        // away from the robot's axis, and a bicycle's end behind-right
        // (0.638 m off): both in the 0.65 m disc.
        let mut cells: Vec<Cell> = (0..20)
            .map(|i| Cell {
                x: 0.25 + 0.0475 * i as f32,
                y: 0.58 + 0.0155 * i as f32,
                blocking: 10,
                low: false,
                no_go: false,
                person: 0,
            })
            .collect();
        cells.extend(wall(-0.48, -0.42, 1));
        let at = |dx: f32| {
            let cells = cells.iter().map(|c| Cell { x: c.x - dx, ..*c }).collect();
            RobotState {
                cloud: ObstacleCloud { cells, ..ObstacleCloud::default() },
                measured_cells: 21,
                ..RobotState::default()
            }
        };
        let empty = ObstacleCloud::default();
        let input = turn_in_place_to(-1.3, &empty);
        // The nearest cell is the car's corner, ahead: moving away from it
        // backs toward the bicycle, whose end is then the nearest, and the
        // robot went 3 cm each way for ever. Going on clears the disc past
        // the car's corner (about 0.5 m); backing out would take 1 m past
        // the bicycle. After a 3 cm step either way the answer is the same.
        for dx in [0.0, 0.03, 0.06, -0.03] {
            let state = at(dx);
            assert_eq!(
                state.sweep(&input, &p, input.goal.pose.theta, None, 0.2),
                Some(Sweep::Escape(p.escape_speed)),
                "moved {dx} m"
            );
        }
        // With the car's side running on close beside the lane and a crate
        // 1 m behind, neither way clears the disc. The car's side begins
        // beside the robot's middle, and the rear corner that swings out
        // passes behind its end: the turn goes on the sharpest arc, 0.5 m,
        // to the right.
        let mut boxed = wall(-0.2, 0.5, 40);
        boxed.extend(wall(-1.0, 0.0, 1));
        let state = |cells: Vec<Cell>| RobotState {
            measured_cells: cells.len(),
            cloud: ObstacleCloud { cells, ..ObstacleCloud::default() },
            ..RobotState::default()
        };
        let v = p.escape_speed;
        assert_eq!(state(boxed.clone()).sweep(&input, &p, -1.3, None, 0.2), Some(Sweep::Arc(v, -2.0 * v)));
        // A crate across the way ahead as well: BLOCKED.
        let mut shut = boxed;
        shut.extend((0..21).map(|i| Cell { y: -0.5 + 0.05 * i as f32, ..wall(0.62, 0.0, 1)[0] }));
        assert_eq!(state(shut).sweep(&input, &p, -1.3, None, 0.2), Some(Sweep::Blocked));
    }

    #[test]
    fn a_turn_whose_sweep_crosses_a_cable_alongside_is_made_on_an_arc() {
        let p = FollowParams::default();
        // A cable on the floor along the robot's left, 0.6 m from its
        // centre (inside the 0.65 m disc), from 1 m behind to 2 m ahead: a
        // move ended beside it (evaluation, lab), and the next step turns
        // right by 130°.
        let cable: Vec<Cell> = (0..61)
            .map(|i| Cell { x: -1.0 + 0.05 * i as f32, y: 0.6, blocking: 0, low: false, no_go: true, person: 0 })
            .collect();
        let state = RobotState {
            measured_cells: cable.len(),
            cloud: ObstacleCloud { cells: cable, ..ObstacleCloud::default() },
            ..RobotState::default()
        };
        let empty = ObstacleCloud::default();
        let input = turn_in_place_to(-2.26, &empty);
        // Turning on the spot, the rear-left corner sweeps over the cable;
        // no straight move clears the disc.
        assert!(state.footprint_hits(0.0, -1.0, 2.26, &p));
        let Some(Sweep::Arc(v, w)) = state.sweep(&input, &p, -2.26, None, 0.2) else {
            panic!("the turn is made on an arc")
        };
        assert!(v > 0.0 && w < 0.0, "forward, to the right: ({v}, {w})");
        // Held until the heading is reached (13 s at 0.15 m/s on the 0.5 m
        // arc), that arc never reaches the cable.
        assert!(!state.footprint_hits(v, w, 2.26 / w.abs(), &p));
        // Facing a goal inside every arc's circle (0.4 m to the right), the
        // robot would circle it on any of them: it takes the move that frees
        // the sweep disc soonest instead, held clear until the disc is free
        // (its centre 0.65 m from the cable), and turns on the spot from there.
        let Some(Sweep::Arc(v, w)) = state.sweep(&input, &p, -1.57, Some(&Vector2::new(0.0, -0.4)), 0.2) else {
            panic!("the disc is freed on an arc")
        };
        let freed = (1..=8).map(|i| f64::from(i) * 0.5).find(|&t| {
            let th = w * t;
            0.6 - v / w * (1.0 - th.cos()) >= p.sweep_radius_m && (v / w * th.sin()).abs() < 2.0
        });
        let t = freed.expect("the move frees the disc within UNWEDGE_MAX_S");
        assert!(t <= UNWEDGE_MAX_S);
        assert!(!state.footprint_hits(v, w, t, &p), "held clear until then");
        assert!(w < 0.0, "away from the cable: ({v}, {w})");
    }

    #[test]
    fn a_robot_boxed_in_on_every_side_is_blocked_not_unwedged() {
        let p = FollowParams::default();
        // A cable along the left and the right, 0.6 m from the centre, and
        // crates 0.15 m beyond the bumpers: no move frees the disc.
        let mut cells: Vec<Cell> = (0..61)
            .flat_map(|i| {
                let x = -1.0 + 0.05 * i as f32;
                [0.6_f32, -0.6].map(|y| Cell { x, y, blocking: 0, low: false, no_go: true, person: 0 })
            })
            .collect();
        cells.extend((0..13).flat_map(|i| {
            let y = -0.3 + 0.05 * i as f32;
            [0.65_f32, -0.65].map(|x| Cell { x, y, blocking: 3, low: false, no_go: false, person: 0 })
        }));
        let state = RobotState {
            measured_cells: cells.len(),
            cloud: ObstacleCloud { cells, ..ObstacleCloud::default() },
            ..RobotState::default()
        };
        let empty = ObstacleCloud::default();
        let input = turn_in_place_to(1.57, &empty);
        assert_eq!(state.sweep(&input, &p, 1.57, None, 0.2), Some(Sweep::Blocked));
    }
}
