//! No progress: while moving, if the distance to the goal has not dropped
//! by `progress_distance` (0.1 m) within `progress_window_s` (5 s of sensor
//! time), the step reports NO_PROGRESS once with a stop and the window
//! restarts, so the mission executor can recover instead of hanging.
//! Waiting for a walking person is no lack of progress: the window
//! restarts while the robot yields (`follow.rs`).

use super::{FollowParams, RobotState, StepOutput, StepStatus};

impl RobotState {
    /// The watchdog over a moving command `out` (linear part `v`) at
    /// `distance` m from the goal, sensor time `stamp`: the command itself,
    /// or a stop reported NO_PROGRESS once the window ran out without the
    /// distance dropping by `progress_distance`.
    pub(super) fn watch_progress(
        &mut self,
        mut out: StepOutput,
        distance: f64,
        stamp: f64,
        v: f64,
        p: &FollowParams,
    ) -> StepOutput {
        if window_ran_out(&mut self.progress, distance, stamp, p.progress_distance, p.progress_window_s) {
            self.last_speed = 0.0;
            out.linear = 0.0;
            out.angular = 0.0;
            out.status = StepStatus::NoProgress;
            return out;
        }
        self.last_speed = v;
        out
    }
}

/// A window over the distance to a goal, `(best, since)`: whether `distance`
/// m at sensor time `stamp` ends a window of `window_s` in which the
/// distance never dropped by `drop_m` below the window's start. A drop, or
/// a window that ran out, starts the next window here. The watchdog above
/// and the narrow passage's circling (`narrow.rs`) each keep one.
pub(super) fn window_ran_out(
    window: &mut Option<(f64, f64)>,
    distance: f64,
    stamp: f64,
    drop_m: f64,
    window_s: f64,
) -> bool {
    let ran_out = match *window {
        Some((best, since)) if distance > best - drop_m => {
            if stamp - since < window_s {
                return false;
            }
            true
        }
        _ => false,
    };
    *window = Some((distance, stamp));
    ran_out
}

#[cfg(test)]
mod tests {
    use super::super::{FollowParams, RobotState, StepOutput, StepStatus};

    fn moving(v: f64) -> StepOutput {
        StepOutput {
            linear: v,
            angular: 0.1,
            status: StepStatus::Moving,
            selection: None,
            path_scale: 1.0,
            distance_to_goal: 0.0,
            heading_error: 0.0,
            free_paths: 1,
            frontier: Vec::new(),
        }
    }

    #[test]
    fn a_robot_that_closes_in_is_never_stopped() {
        let p = FollowParams::default();
        let mut state = RobotState::default();
        // 0.1 m closer every 4 s: each window sees the drop it asks for.
        for k in 0..20 {
            let out = state.watch_progress(moving(0.5), 5.0 - 0.1 * f64::from(k), 4.0 * f64::from(k), 0.5, &p);
            assert_eq!(out.status, StepStatus::Moving, "frame {k}");
            assert_eq!(out.linear, 0.5);
        }
    }

    #[test]
    fn a_robot_stuck_for_the_window_is_stopped_once_then_watched_again() {
        let p = FollowParams::default();
        let mut state = RobotState::default();
        let mut reports = Vec::new();
        for k in 0..=60 {
            // 0.2 s frames, 0.05 m closer in all: never the 0.1 m asked.
            let stamp = 0.2 * f64::from(k);
            let out = state.watch_progress(moving(0.3), 3.0 - 0.05 * stamp / 12.0, stamp, 0.3, &p);
            if out.status == StepStatus::NoProgress {
                assert_eq!((out.linear, out.angular), (0.0, 0.0));
                assert_eq!(state.last_speed, 0.0);
                reports.push(stamp);
            }
        }
        // Sensor time, not frames: at 5 s, then 5 s after that restart.
        assert_eq!(reports.len(), 2, "{reports:?}");
        assert!((reports[0] - p.progress_window_s).abs() < 1e-9, "{reports:?}");
        assert!((reports[1] - 2.0 * p.progress_window_s).abs() < 1e-9, "{reports:?}");
    }
}
