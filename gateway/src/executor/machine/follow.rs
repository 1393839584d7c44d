//! FOLLOW: a FIND whose target moves — its walking velocity, where it is
//! now when unseen, and staying with it for the step's time.

use nalgebra::{Vector2, Vector3};

use super::find::FindRun;
use super::{Mission, Next, Pending, bearing};
use crate::executor::model::*;

/// A followed target unseen this long is not driven after: its goal is
/// stale (a person who walked past the robot is behind it, not where the
/// goal was set); the robot turns to where it was last seen instead, s.
const FOLLOW_STALE_S: f64 = 1.0;
/// How far a lost moving target is carried on along its velocity, s.
const FOLLOW_PREDICT_S: f64 = 4.0;
/// Shortest interval a walking velocity is measured over, s.
const VELOCITY_BASELINE_S: f64 = 0.5;
/// Facing a lost target this closely is facing it, rad (10°).
const FACING_TOLERANCE_RAD: f64 = 0.17;

impl FindRun {
    /// Where the target is now by its last sighting: the fused position, a
    /// moving target carried on along its velocity for the time unseen
    /// (at most `FOLLOW_PREDICT_S`).
    pub(super) fn predicted(&self, stamp: f64) -> Option<Vector3<f64>> {
        let t = self.fused?;
        match (self.moving, self.velocity, self.last_seen) {
            (true, Some(v), Some(seen)) => {
                let dt = (stamp - seen).clamp(0.0, FOLLOW_PREDICT_S);
                Some(Vector3::new(t.x + v.x * dt, t.y + v.y * dt, t.z))
            }
            _ => Some(t),
        }
    }

    /// Updates the velocity from a new fused position (moving targets only).
    pub(super) fn track(&mut self, stamp: f64, fused: Vector3<f64>) {
        if !self.moving {
            return;
        }
        match self.velocity_from {
            Some((t0, p0)) if stamp - t0 >= VELOCITY_BASELINE_S => {
                let v = Vector2::new(fused.x - p0.x, fused.y - p0.y) / (stamp - t0);
                // People walk at up to about 2 m/s; faster is a bad estimate.
                if v.norm() <= 2.0 {
                    self.velocity = Some(self.velocity.map_or(v, |old| old * 0.5 + v * 0.5));
                }
                self.velocity_from = Some((stamp, fused));
            }
            Some(_) => {}
            None => self.velocity_from = Some((stamp, fused)),
        }
    }
}

impl Mission {
    /// A confirmed moving target, this frame: followed until the step's time
    /// is up; once its goal is stale, the robot turns to where it should be.
    pub(super) fn follow(&mut self, stamp: f64, goal: Goal) -> Next {
        let Some(f) = self.find_mut() else { return self.hold() };
        let until = *f.follow_until.get_or_insert(stamp + f.follow_s);
        if stamp >= until {
            self.complete_step(&goal);
            return self.hold();
        }
        let stale = f.last_seen.is_some_and(|t| stamp - t > FOLLOW_STALE_S);
        if let (true, Some(t)) = (stale, f.predicted(stamp)) {
            let face = self.facing(&t, &goal);
            return self.call(Pending::FollowPlanned, self.drive(face));
        }
        self.call(Pending::FollowPlanned, self.drive(goal))
    }

    /// A turn in place, where the robot stands, to face `target` (odom).
    fn facing(&self, target: &Vector3<f64>, like: &Goal) -> Goal {
        let pose = self.frame.pose;
        Goal {
            pose: Pose2::new(pose.x, pose.y, bearing(pose, target)),
            yaw_tolerance: FACING_TOLERANCE_RAD,
            rotation_only: true,
            ..*like
        }
    }
}

#[cfg(test)]
#[path = "follow_tests.rs"]
mod tests;
