//! Inputs the behaviour modules' tests share.

use std::sync::OnceLock;

use vlnav_geometry::{GoalSpec, Pose2};

use super::{RobotState, StepInput, View};
use crate::cloud::{Cell, ObstacleCloud};
use crate::planner::{Planner, PlannerParams};

/// A level view ±0.75 rad wide that shows the floor everywhere.
pub(super) fn view_ahead() -> View {
    View { yaw: 0.0, half_fov: 0.75, floor_from_m: 0.0, camera_x_m: 0.0, camera_z_m: 0.0 }
}

/// A robot whose cloud holds a 3-voxel obstacle cell at each (x, y), `base_link`.
pub(super) fn with_cells(cells: &[(f32, f32)]) -> RobotState {
    let cells = cells.iter().map(|&(x, y)| Cell { x, y, blocking: 3, low: false, no_go: false, person: 0 }).collect();
    RobotState { cloud: ObstacleCloud { cells, ..ObstacleCloud::default() }, ..RobotState::default() }
}

/// A turn in place at the origin to `yaw`, with no cells measured this frame.
pub(super) fn turn_in_place_to(yaw: f64, empty: &ObstacleCloud) -> StepInput<'_> {
    StepInput {
        stamp: 0.0,
        pose: Pose2::new(0.0, 0.0, 0.0),
        goal: GoalSpec {
            pose: Pose2::new(0.0, 0.0, yaw),
            position_tolerance: 0.3,
            yaw_tolerance: 0.2,
            rotation_only: true,
            landmark: None,
        },
        cloud: empty,
        max_speed: 0.0,
        view: view_ahead(),
    }
}

/// A drive at `stamp` from `pose` toward a position goal at (`goal_x`, 0),
/// seen with `view`.
pub(super) fn drive_to(stamp: f64, pose: Pose2, goal_x: f64, cloud: &ObstacleCloud, view: View) -> StepInput<'_> {
    StepInput {
        stamp,
        pose,
        goal: GoalSpec {
            pose: Pose2::new(goal_x, 0.0, 0.0),
            position_tolerance: 0.3,
            yaw_tolerance: 0.2,
            rotation_only: false,
            landmark: None,
        },
        cloud,
        max_speed: 0.0,
        view,
    }
}

/// The planner of the default parameters, built once for all tests.
pub(super) fn planner() -> &'static Planner {
    static P: OnceLock<Planner> = OnceLock::new();
    P.get_or_init(|| Planner::new(PlannerParams::default()))
}

/// The default planner with the narrow-passage tables (`narrow.rs`).
pub(super) fn narrow_planner() -> &'static Planner {
    static P: OnceLock<Planner> = OnceLock::new();
    P.get_or_init(|| {
        Planner::new(PlannerParams {
            narrow_clearance_m: crate::planner::NARROW_CLEARANCE_M,
            ..PlannerParams::default()
        })
    })
}
