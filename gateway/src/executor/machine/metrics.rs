//! A mission's metrics: duration and path length in sensor time and
//! odometry, and from the simulator's ground truth when frames carry it.

use super::Mission;
use crate::executor::model::*;

#[derive(Default, Debug)]
pub(super) struct MetricsAcc {
    first_stamp: Option<f64>,
    pub(super) last_stamp: f64,
    last_pose: Option<Pose2>,
    odom_path: f64,
    frames: u32,
    truth_start: Option<Truth>,
    truth_last: Option<Truth>,
}

impl MetricsAcc {
    pub(super) fn observe(&mut self, stamp: f64, pose: &Pose2, truth: Option<&Truth>) {
        self.first_stamp.get_or_insert(stamp);
        self.last_stamp = stamp;
        if let Some(p) = &self.last_pose {
            self.odom_path += (pose.x - p.x).hypot(pose.y - p.y);
        }
        self.last_pose = Some(*pose);
        self.frames += 1;
        if let Some(t) = truth {
            if self.truth_start.is_none() {
                self.truth_start = Some(*t);
            }
            self.truth_last = Some(*t);
        }
    }

    fn metrics(&self, steps_completed: u32, steps_total: u32, replans: u32, last_goal: Option<&Pose2>) -> Metrics {
        let mut m = Metrics {
            duration_s: self.first_stamp.map_or(0.0, |f| self.last_stamp - f),
            odom_path_length_m: self.odom_path,
            steps_completed,
            steps_total,
            frames: self.frames,
            replans,
            ..Default::default()
        };
        if let (Some(a), Some(b)) = (&self.truth_start, &self.truth_last) {
            m.has_ground_truth = true;
            m.true_path_length_m = b.path_length_m - a.path_length_m;
            m.hard_collisions = b.hard_collisions.saturating_sub(a.hard_collisions);
            m.soft_collisions = b.soft_collisions.saturating_sub(a.soft_collisions);
            if let (Some(goal), Some(origin), Some(truth)) = (last_goal, b.odom_origin.as_ref(), b.pose.as_ref()) {
                let world_goal = origin.compose(goal);
                m.final_error_m = (truth.x - world_goal.x).hypot(truth.y - world_goal.y);
            }
        }
        m
    }
}

impl Mission {
    pub(super) fn metrics(&self) -> Metrics {
        self.metrics.metrics(self.index as u32, self.plan.len() as u32, self.replans, self.last_goal.as_ref())
    }
}

#[cfg(test)]
#[path = "metrics_tests.rs"]
mod tests;
