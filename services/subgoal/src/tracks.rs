//! Per-target state: each `track_key` owns a fixed-target fusion or a
//! moving-target filter, and each observation yields a goal computed from the
//! fused target and the robot's pose in the observing frame.

use std::collections::HashMap;

use nalgebra::{Vector2, Vector3};
use vlnav_geometry::{GoalSpec, Pose2};

use crate::fusion::{FixedParams, FixedTarget, Fused, MovingParams, MovingTarget};
use crate::geometry::{NoDepth, approach_goal, approach_heading};

/// Tunables of the visual-target goals and their fusion.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrackParams {
    pub fixed: FixedParams,
    pub moving: MovingParams,
    /// Stopping distance used when a request gives none (authors: 2.0 m).
    pub default_stop_distance_m: f64,
    /// The approach goal is reached within this distance, m.
    pub goal_tolerance_m: f64,
    /// Heading tolerance reported with the goal, rad.
    pub goal_yaw_tolerance: f64,
    /// Most tracks kept; the least recently used is forgotten beyond it.
    pub max_tracks: usize,
    /// A fixed target's goal faces along the line from where the robot first
    /// observed it; once the robot's own bearing to the target differs from
    /// that line's by more than this (a detour round something), the line is
    /// drawn again from where the robot is, rad.
    pub approach_line_max_rad: f64,
}

impl Default for TrackParams {
    fn default() -> Self {
        Self {
            fixed: FixedParams::default(),
            moving: MovingParams::default(),
            default_stop_distance_m: 2.0,
            goal_tolerance_m: 0.3,
            goal_yaw_tolerance: 0.2,
            max_tracks: 4096,
            approach_line_max_rad: 0.35,
        }
    }
}

/// One observation of a target, already converted to `odom`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Observation {
    pub stamp: f64,
    pub robot: Pose2,
    /// The target seen in this frame, or why there is none.
    pub target: Result<Vector3<f64>, NoDepth>,
    /// Stopping distance (≤ 0: the default).
    pub d_s: f64,
    pub moving: bool,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EstimateStatus {
    Ok,
    NoDepth,
    Outlier,
}

/// What one observation produced.
#[derive(Clone, Debug, PartialEq)]
pub struct TargetEstimate {
    pub status: EstimateStatus,
    pub detail: String,
    /// Absent only when there is no depth and no earlier observation.
    pub goal: Option<GoalSpec>,
    pub observed: Option<Vector3<f64>>,
    pub fused: Option<Vector3<f64>>,
    pub observations: u32,
    pub rejected: u32,
    pub spread_m: f64,
    pub range_m: f64,
    pub velocity: Vector2<f64>,
}

#[derive(Clone, Debug)]
enum Filter {
    Fixed(FixedTarget),
    Moving(MovingTarget),
}

#[derive(Clone, Debug)]
struct Track {
    filter: Filter,
    last_used: u64,
    /// Where the approach line to a fixed target starts (`odom`).
    approach_from: Option<Vector2<f64>>,
}

impl Track {
    /// The start of the approach line: where the robot first observed the
    /// target, or where it stands once its bearing to the target has turned
    /// more than `max_rad` away from the line (a detour).
    fn approach_line(&mut self, robot: &Pose2, target: &Vector2<f64>, max_rad: f64) -> Vector2<f64> {
        let here = robot.position();
        let from = *self.approach_from.get_or_insert(here);
        let (line, now) = (target - from, target - here);
        let apart = if line.norm() < 1e-9 || now.norm() < 1e-9 { 0.0 } else { line.angle(&now) };
        if apart > max_rad {
            self.approach_from = Some(here);
            return here;
        }
        from
    }
}

/// Every live track, keyed by `track_key`.
#[derive(Debug)]
pub struct Tracks {
    params: TrackParams,
    tracks: HashMap<String, Track>,
    clock: u64,
}

impl Tracks {
    pub fn new(params: TrackParams) -> Self {
        Self { params, tracks: HashMap::new(), clock: 0 }
    }

    pub fn len(&self) -> usize {
        self.tracks.len()
    }

    pub fn is_empty(&self) -> bool {
        self.tracks.is_empty()
    }

    /// Forgets a track; returns whether it existed.
    pub fn reset(&mut self, key: &str) -> bool {
        self.tracks.remove(key).is_some()
    }

    fn evict_if_full(&mut self) {
        if self.tracks.len() < self.params.max_tracks.max(1) {
            return;
        }
        if let Some(oldest) = self.tracks.iter().min_by_key(|(_, t)| t.last_used).map(|(k, _)| k.clone()) {
            self.tracks.remove(&oldest);
        }
    }

    /// Fuses one observation into `key`'s track and returns the goal.
    pub fn observe(&mut self, key: &str, obs: &Observation) -> TargetEstimate {
        self.clock += 1;
        let d_s = if obs.d_s > 0.0 { obs.d_s } else { self.params.default_stop_distance_m };
        let kind_matches =
            |t: &Track| matches!((&t.filter, obs.moving), (Filter::Fixed(_), false) | (Filter::Moving(_), true));
        // A track asked for with the other motion model starts over.
        if self.tracks.get(key).is_some_and(|t| !kind_matches(t)) {
            self.tracks.remove(key);
        }
        if !self.tracks.contains_key(key) {
            if let Err(e) = &obs.target {
                return TargetEstimate {
                    status: EstimateStatus::NoDepth,
                    detail: format!("{e}; no earlier observation of this target"),
                    goal: None,
                    observed: None,
                    fused: None,
                    observations: 0,
                    rejected: 0,
                    spread_m: 0.0,
                    range_m: 0.0,
                    velocity: Vector2::zeros(),
                };
            }
            self.evict_if_full();
            let filter = if obs.moving {
                Filter::Moving(MovingTarget::new(self.params.moving))
            } else {
                Filter::Fixed(FixedTarget::new(self.params.fixed))
            };
            self.tracks.insert(key.to_string(), Track { filter, last_used: 0, approach_from: None });
        }
        let track = self.tracks.get_mut(key).expect("inserted above");
        track.last_used = self.clock;
        let robot_xy = obs.robot.position();
        let (fused, status, detail) = match (&mut track.filter, obs.target) {
            (Filter::Fixed(f), Ok(p)) => {
                let r = f.add(p);
                (Some(r), if r.accepted { EstimateStatus::Ok } else { EstimateStatus::Outlier }, String::new())
            }
            (Filter::Moving(f), Ok(p)) => {
                let range = (p.xy() - robot_xy).norm();
                let r = f.add(p, obs.stamp, range);
                (Some(r), if r.accepted { EstimateStatus::Ok } else { EstimateStatus::Outlier }, String::new())
            }
            (Filter::Fixed(f), Err(e)) => {
                (f.current(), EstimateStatus::NoDepth, format!("{e}; goal from earlier observations"))
            }
            (Filter::Moving(f), Err(e)) => (
                f.current(obs.stamp),
                EstimateStatus::NoDepth,
                format!("{e}; goal predicted from earlier observations"),
            ),
        };
        let detail = match (status, &fused) {
            (EstimateStatus::Outlier, Some(r)) => format!(
                "observation rejected as an outlier ({} of {} rejected); goal from the fused target",
                r.rejected, r.observations
            ),
            _ => detail,
        };
        let observed = obs.target.ok();
        match fused {
            Some(Fused { target, observations, rejected, spread_m, velocity, .. }) => {
                let mut pose = approach_goal(&obs.robot, &target.xy(), d_s);
                if matches!(track.filter, Filter::Fixed(_)) {
                    // The course a relative step after this one turns from.
                    let from = track.approach_line(&obs.robot, &target.xy(), self.params.approach_line_max_rad);
                    pose.theta = approach_heading(&from, &target.xy(), pose.theta);
                }
                TargetEstimate {
                    status,
                    detail,
                    goal: Some(GoalSpec {
                        pose,
                        position_tolerance: self.params.goal_tolerance_m,
                        yaw_tolerance: self.params.goal_yaw_tolerance,
                        rotation_only: false,
                        // A person to follow walks on: only a fixed landmark's
                        // stopping distance holds from any bearing.
                        landmark: matches!(track.filter, Filter::Fixed(_)).then(|| target.xy()),
                    }),
                    observed,
                    fused: Some(target),
                    observations,
                    rejected,
                    spread_m,
                    range_m: (target.xy() - robot_xy).norm(),
                    velocity,
                }
            }
            None => TargetEstimate {
                status,
                detail,
                goal: None,
                observed,
                fused: None,
                observations: 0,
                rejected: 0,
                spread_m: 0.0,
                range_m: 0.0,
                velocity: Vector2::zeros(),
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn obs(target: Result<Vector3<f64>, NoDepth>, stamp: f64) -> Observation {
        Observation { stamp, robot: Pose2::new(0.0, 0.0, 0.0), target, d_s: 1.0, moving: false }
    }

    const NO_DEPTH: NoDepth = NoDepth { valid: 3, needed: 20, min_m: 0.5, max_m: 10.0 };

    #[test]
    fn no_depth_without_history_has_no_goal_and_no_nan() {
        let mut t = Tracks::new(TrackParams::default());
        let r = t.observe("m/1", &obs(Err(NO_DEPTH), 0.0));
        assert_eq!(r.status, EstimateStatus::NoDepth);
        assert!(r.goal.is_none());
        assert!(r.detail.contains("3 valid pixels"), "{}", r.detail);
        assert!(t.is_empty());
    }

    #[test]
    fn no_depth_with_history_keeps_the_fused_goal_from_the_current_pose() {
        let mut t = Tracks::new(TrackParams::default());
        t.observe("m/1", &obs(Ok(Vector3::new(5.0, 0.0, 0.3)), 0.0));
        let mut o = obs(Err(NO_DEPTH), 0.2);
        o.robot = Pose2::new(1.0, 0.0, 0.0);
        let r = t.observe("m/1", &o);
        assert_eq!(r.status, EstimateStatus::NoDepth);
        let g = r.goal.unwrap();
        assert!((g.pose.x - 4.0).abs() < 1e-9 && g.pose.y.abs() < 1e-9);
        assert!((r.range_m - 4.0).abs() < 1e-9);
        assert_eq!(r.observations, 1);
    }

    #[test]
    fn default_stop_distance_applies_when_none_given() {
        let mut t = Tracks::new(TrackParams::default());
        let mut o = obs(Ok(Vector3::new(5.0, 0.0, 0.0)), 0.0);
        o.d_s = 0.0;
        let g = t.observe("k", &o).goal.unwrap();
        assert!((g.pose.x - 3.0).abs() < 1e-9);
    }

    #[test]
    fn tracks_are_independent_reset_and_bounded() {
        let params = TrackParams { max_tracks: 2, ..TrackParams::default() };
        let mut t = Tracks::new(params);
        t.observe("a", &obs(Ok(Vector3::new(5.0, 0.0, 0.0)), 0.0));
        t.observe("b", &obs(Ok(Vector3::new(0.0, 5.0, 0.0)), 0.0));
        let r = t.observe("a", &obs(Ok(Vector3::new(5.0, 0.1, 0.0)), 0.1));
        assert_eq!(r.observations, 2);
        // A third key evicts the least recently used ("b").
        t.observe("c", &obs(Ok(Vector3::new(1.0, 1.0, 0.0)), 0.2));
        assert_eq!(t.len(), 2);
        assert!(!t.reset("b"));
        assert!(t.reset("a"));
        let r = t.observe("a", &obs(Ok(Vector3::new(2.0, 0.0, 0.0)), 0.3));
        assert_eq!(r.observations, 1);
    }

    #[test]
    fn the_goal_faces_along_the_line_from_first_sight_wherever_the_robot_weaved() {
        // First seen from the origin: the line runs along +x to the target at (6, 0).
        let mut t = Tracks::new(TrackParams::default());
        t.observe("f", &obs(Ok(Vector3::new(6.0, 0.0, 0.5)), 0.0));
        // Round a tree, 0.4 m to the left of the line, 2 m short of the target.
        let mut o = obs(Ok(Vector3::new(6.0, 0.0, 0.5)), 0.2);
        o.robot = Pose2::new(4.0, 0.4, 0.3);
        let g = t.observe("f", &o).goal.unwrap().pose;
        // The position is d_s short along the robot's own bearing (the paper's) …
        let bearing = (-0.4f64).atan2(2.0);
        let d = 0.4f64.hypot(2.0);
        assert!((g.x - (4.0 + (d - 1.0) * bearing.cos())).abs() < 1e-9, "{g:?}");
        assert!((g.y - (0.4 + (d - 1.0) * bearing.sin())).abs() < 1e-9, "{g:?}");
        // … and the course a following step turns from is the line's.
        assert!(g.theta.abs() < 1e-9, "{g:?}");
    }

    #[test]
    fn a_wide_detour_draws_the_approach_line_again_from_where_the_robot_is() {
        let mut t = Tracks::new(TrackParams::default());
        t.observe("f", &obs(Ok(Vector3::new(6.0, 0.0, 0.5)), 0.0));
        // Round a table: 2 m to the side, at 45° from the line (beyond 0.35 rad).
        let mut o = obs(Ok(Vector3::new(6.0, 0.0, 0.5)), 0.2);
        o.robot = Pose2::new(4.0, 2.0, 0.0);
        let g = t.observe("f", &o).goal.unwrap().pose;
        let redrawn = (-2.0f64).atan2(2.0);
        assert!((g.theta - redrawn).abs() < 1e-9, "{g:?}");
        // The new line holds from there on: a little off it, the heading stays.
        o.robot = Pose2::new(4.6, 1.2, 0.0);
        let again = t.observe("f", &o).goal.unwrap().pose;
        assert!((again.theta - redrawn).abs() < 1e-9, "{again:?}");
    }

    #[test]
    fn a_moving_target_is_faced_from_where_the_robot_is() {
        let mut t = Tracks::new(TrackParams::default());
        let mut m = obs(Ok(Vector3::new(6.0, 0.0, 0.5)), 0.0);
        m.moving = true;
        t.observe("p", &m);
        m.robot = Pose2::new(3.0, 1.0, 0.0);
        m.stamp = 0.2;
        let g = t.observe("p", &m).goal.unwrap().pose;
        let bearing = (-1.0f64).atan2(3.0);
        assert!((g.theta - bearing).abs() < 0.05, "{g:?}");
    }

    #[test]
    fn a_fixed_targets_goal_names_its_landmark_and_a_persons_does_not() {
        // The stopping distance from a fixed landmark holds from any bearing,
        // so the local planner may move a blocked goal round it; a person
        // walks on, and is faced from where the robot is.
        let mut t = Tracks::new(TrackParams::default());
        let fixed = t.observe("f", &obs(Ok(Vector3::new(6.0, 1.0, 0.5)), 0.0)).goal.unwrap();
        assert_eq!(fixed.landmark, Some(Vector2::new(6.0, 1.0)));
        let mut m = obs(Ok(Vector3::new(6.0, 0.0, 0.5)), 0.0);
        m.moving = true;
        assert_eq!(t.observe("p", &m).goal.unwrap().landmark, None);
    }

    #[test]
    fn switching_to_moving_starts_a_new_filter() {
        let mut t = Tracks::new(TrackParams::default());
        t.observe("f", &obs(Ok(Vector3::new(5.0, 0.0, 0.0)), 0.0));
        let mut o = obs(Ok(Vector3::new(5.0, 1.0, 0.0)), 0.2);
        o.moving = true;
        let r = t.observe("f", &o);
        assert_eq!(r.observations, 1);
        assert_eq!(r.status, EstimateStatus::Ok);
    }
}
