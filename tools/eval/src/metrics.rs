//! Per-trial metrics, as the paper defines them (docs/design.md §6), from plain values:
//! the mission's end state, the simulator's ground truth and the scenario's
//! expected destination.
//!
//! Definitions used throughout the harness:
//! - **Stopping error** of one trial: ‖G_d − R_d‖ − d, where G_d is the true
//!   destination (a landmark's centre, or a point), R_d the robot's true
//!   final position and d the distance from G_d the instruction asks the
//!   robot to stop at (the spoken distance from the landmark's surface plus
//!   its half depth; 0 for a point). Positive: it stopped farther than
//!   asked. No slack is added. A scenario's figure is the mean |error| ±
//!   the population standard deviation of |error| over the trials that
//!   completed every step (the paper's drift Ē ± σ).
//! - **Success**: the mission ended `SUCCEEDED` with every step of its plan
//!   completed, the robot never touched anything hard (a trial with a hard
//!   collision is not a success), *and* its true final position lies within
//!   the instruction's success radius of the true destination (‖G_d − R_d‖ ≤
//!   r, r = d + a slack the table states, 0.3–0.75 m). Success at 0.25 m
//!   holds the same trial to |stopping error| ≤ 0.25 m.
//! - **Collisions**: the share of trials with at least one soft event (the
//!   footprint entered a semantic no-go region) / hard event (it touched
//!   structure, an object or a person) is the primary figure. The share of
//!   mission time in contact is reported beside it, labelled as such.
//! - **Path length**: the true distance driven (simulation ground truth),
//!   averaged over all trials of the scenario.
//! - **Mission time**: sensor seconds from the first executed frame to the end
//!   (frame stamps, never the wall clock).

use nalgebra::Vector2;
use serde::{Deserialize, Serialize};

/// How an instruction guides the robot (Table IV's three columns).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    /// Only dead-reckoned MOVE steps, computed from the nominal start pose.
    Geometric,
    /// Only FIND steps: the robot is guided by what it sees.
    Visual,
    /// The instruction as a person would give it: MOVE and FIND mixed.
    Hybrid,
}

impl Mode {
    pub const ALL: [Mode; 3] = [Mode::Geometric, Mode::Visual, Mode::Hybrid];

    pub fn as_str(self) -> &'static str {
        match self {
            Mode::Geometric => "geometric",
            Mode::Visual => "visual",
            Mode::Hybrid => "hybrid",
        }
    }
}

impl std::fmt::Display for Mode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl std::str::FromStr for Mode {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "geometric" => Ok(Mode::Geometric),
            "visual" => Ok(Mode::Visual),
            "hybrid" => Ok(Mode::Hybrid),
            other => Err(format!("unknown mode {other:?}: expected geometric, visual or hybrid")),
        }
    }
}

/// A point in the world (ground-truth) frame, metres.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Point2 {
    pub x: f64,
    pub y: f64,
}

impl Point2 {
    pub const fn new(x: f64, y: f64) -> Self {
        Self { x, y }
    }

    pub fn distance(self, other: Point2) -> f64 {
        (self.x - other.x).hypot(self.y - other.y)
    }
}

/// A planar pose, metres and radians: the shared one.
pub use vlnav_geometry::{Pose2 as Pose, wrap_angle};

impl From<Vector2<f64>> for Point2 {
    fn from(v: Vector2<f64>) -> Self {
        Point2::new(v.x, v.y)
    }
}

impl From<Point2> for Vector2<f64> {
    fn from(p: Point2) -> Self {
        Vector2::new(p.x, p.y)
    }
}

/// How a mission ended, as the harness saw it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Outcome {
    /// The executor reported `MISSION_STATE_SUCCEEDED`.
    Succeeded,
    /// The executor reported `MISSION_STATE_FAILED`.
    Failed,
    /// Cancelled (by the harness when the sensor-time budget ran out).
    TimedOut,
    /// The planner or executor asked a question; the harness does not answer.
    Clarification,
    /// The mission could not be run (submission rejected, stream broken).
    Error,
}

impl Outcome {
    pub fn as_str(self) -> &'static str {
        match self {
            Outcome::Succeeded => "succeeded",
            Outcome::Failed => "failed",
            Outcome::TimedOut => "timed_out",
            Outcome::Clarification => "clarification",
            Outcome::Error => "error",
        }
    }
}

/// Ground truth at one simulated frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TruthSample {
    /// Sensor time, seconds.
    pub stamp: f64,
    /// True pose of base_link in the world.
    pub pose: Pose,
    /// What odometry believed at the same instant (odom frame).
    pub odom: Pose,
    /// Origin of the odom frame in the world at this instant.
    pub odom_origin: Pose,
    /// The footprint touches structure or an object.
    pub hard_contact: bool,
    /// The footprint is inside a restricted (no-go) region.
    pub soft_contact: bool,
}

impl TruthSample {
    /// Where odometry believed the robot was, drawn in the world frame.
    pub fn odom_in_world(&self) -> Pose {
        self.odom_origin.compose(&self.odom)
    }
}

/// Collision figures of one trial, from its ground-truth track.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ContactAccount {
    /// Number of times contact began (rising edges).
    pub hard_events: u32,
    pub soft_events: u32,
    /// Sensor seconds spent in contact.
    pub hard_s: f64,
    pub soft_s: f64,
    /// Hard events the robot's own motion made; the others are people
    /// walking into it (`docs/simulation.md`, "Contact and its cause").
    #[serde(default)]
    pub hard_by_robot: u32,
    /// Hard events with a pedestrian, and those of them the robot made.
    #[serde(default)]
    pub pedestrian_events: u32,
    #[serde(default)]
    pub pedestrian_by_robot: u32,
}

impl ContactAccount {
    /// Counts events and contact time over a track ordered by stamp. The
    /// interval between two samples counts as in contact when its closing
    /// sample is (the state the simulator integrated into).
    pub fn from_track(track: &[TruthSample]) -> Self {
        let mut acc = ContactAccount::default();
        let mut prev: Option<&TruthSample> = None;
        for s in track {
            let (was_hard, was_soft, dt) = match prev {
                Some(p) => (p.hard_contact, p.soft_contact, (s.stamp - p.stamp).max(0.0)),
                None => (false, false, 0.0),
            };
            if s.hard_contact {
                acc.hard_s += dt;
                if !was_hard {
                    acc.hard_events += 1;
                }
            }
            if s.soft_contact {
                acc.soft_s += dt;
                if !was_soft {
                    acc.soft_events += 1;
                }
            }
            prev = Some(s);
        }
        acc
    }
}

/// Length of a polyline through the track's true positions.
pub fn path_length(track: &[TruthSample]) -> f64 {
    track.windows(2).map(|w| w[0].pose.distance(&w[1].pose)).sum()
}

/// Everything measured about one trial.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrialRecord {
    pub scenario: String,
    pub mode: Mode,
    /// Id of the instruction (within the scenario) this trial ran.
    pub instruction: String,
    pub trial: u32,
    pub seed: u64,
    pub outcome: Outcome,
    /// Why it failed, as reported (empty on success).
    pub reason: String,
    pub steps_completed: u32,
    pub steps_total: u32,
    /// True destination G_d (world) and success radius r (d + slack).
    pub destination: Point2,
    pub success_radius_m: f64,
    /// Distance d from G_d the instruction asks the robot to stop at, metres.
    pub stop_distance_m: f64,
    /// True final position R_d (world).
    pub final_position: Point2,
    /// True distance driven, metres.
    pub path_length_m: f64,
    /// Distance driven according to odometry, metres.
    pub odom_path_length_m: f64,
    /// Sensor seconds from the first executed frame to the end.
    pub duration_s: f64,
    pub frames: u32,
    pub replans: u32,
    pub contact: ContactAccount,
}

impl TrialRecord {
    /// ‖G_d − R_d‖.
    pub fn final_error_m(&self) -> f64 {
        self.destination.distance(self.final_position)
    }

    /// Stopping error ‖G_d − R_d‖ − d, signed (positive: farther than asked).
    pub fn stop_error_m(&self) -> f64 {
        self.final_error_m() - self.stop_distance_m
    }

    /// The slack the success radius allows beyond the asked distance, metres.
    pub fn slack_m(&self) -> f64 {
        self.success_radius_m - self.stop_distance_m
    }

    /// The executor finished every step of a non-empty plan.
    pub fn completed(&self) -> bool {
        self.outcome == Outcome::Succeeded && self.steps_total > 0 && self.steps_completed == self.steps_total
    }

    /// Completed, no hard contact the robot made, and the true final
    /// position within the success radius. (A person walking into the
    /// stopped robot is counted, but is not the robot's failure.)
    pub fn success(&self) -> bool {
        self.completed() && self.contact.hard_by_robot == 0 && self.final_error_m() <= self.success_radius_m
    }

    /// Completed, no hard contact the robot made, and |stopping error| ≤ `slack`.
    pub fn success_within(&self, slack: f64) -> bool {
        self.completed() && self.contact.hard_by_robot == 0 && self.stop_error_m().abs() <= slack
    }

    /// Share of the mission's sensor time in hard contact, 0–1.
    pub fn hard_time_share(&self) -> f64 {
        share(self.contact.hard_s, self.duration_s)
    }

    /// Share of the mission's sensor time inside a no-go region, 0–1.
    pub fn soft_time_share(&self) -> f64 {
        share(self.contact.soft_s, self.duration_s)
    }
}

fn share(part: f64, whole: f64) -> f64 {
    if whole > 0.0 { (part / whole).clamp(0.0, 1.0) } else { 0.0 }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    pub(crate) fn record(trial: u32, outcome: Outcome, final_xy: (f64, f64)) -> TrialRecord {
        TrialRecord {
            scenario: "indoor".into(),
            mode: Mode::Hybrid,
            instruction: "a".into(),
            trial,
            seed: u64::from(trial),
            outcome,
            reason: String::new(),
            steps_completed: 3,
            steps_total: 3,
            destination: Point2::new(10.0, 0.0),
            success_radius_m: 1.0,
            stop_distance_m: 0.5,
            final_position: Point2::new(final_xy.0, final_xy.1),
            path_length_m: 12.0,
            odom_path_length_m: 12.1,
            duration_s: 40.0,
            frames: 200,
            replans: 0,
            contact: ContactAccount::default(),
        }
    }

    #[test]
    fn success_needs_the_true_position_inside_the_radius() {
        assert!(record(0, Outcome::Succeeded, (9.2, 0.0)).success());
        assert!(record(0, Outcome::Succeeded, (11.0, 0.0)).success(), "exactly on the radius counts");
        assert!(!record(0, Outcome::Succeeded, (8.5, 0.0)).success(), "executor says done, truth disagrees");
        assert!(!record(0, Outcome::Failed, (10.0, 0.0)).success(), "ending nearby is not completing");
    }

    #[test]
    fn success_needs_every_step() {
        let mut r = record(0, Outcome::Succeeded, (10.0, 0.0));
        r.steps_completed = 2;
        assert!(!r.success());
        r.steps_completed = 0;
        r.steps_total = 0;
        assert!(!r.success(), "an empty plan is not a mission");
    }

    #[test]
    fn the_stopping_error_is_measured_against_the_asked_distance_without_slack() {
        // ‖G − R‖ = 1.5, asked 0.5 → 1.0 too far.
        let r = record(0, Outcome::Succeeded, (10.0, 1.5));
        assert!((r.final_error_m() - 1.5).abs() < 1e-12);
        assert!((r.stop_error_m() - 1.0).abs() < 1e-12);
        // Closer than asked is negative.
        assert!((record(0, Outcome::Succeeded, (10.0, 0.2)).stop_error_m() + 0.3).abs() < 1e-12);
        assert!((r.slack_m() - 0.5).abs() < 1e-12);
    }

    #[test]
    fn a_hard_collision_is_not_a_success_and_the_tight_slack_is_stricter() {
        let mut r = record(0, Outcome::Succeeded, (10.0, 0.9));
        assert!(r.success(), "0.9 m from G_d, radius 1 m");
        assert!(!r.success_within(0.25), "0.4 m farther than the asked 0.5 m");
        assert!(record(0, Outcome::Succeeded, (10.0, 0.7)).success_within(0.25));
        r.contact.hard_events = 1;
        assert!(r.success(), "a person walked into the stopped robot: counted, not the robot's failure");
        r.contact.hard_by_robot = 1;
        assert!(!r.success() && !r.success_within(1.0), "a trial with hard contact the robot made is not a success");
        r.contact.hard_events = 0;
        r.contact.hard_by_robot = 0;
        r.contact.soft_events = 3;
        assert!(r.success(), "soft events do not fail a trial");
    }

    fn sample(stamp: f64, hard: bool, soft: bool) -> TruthSample {
        TruthSample { stamp, hard_contact: hard, soft_contact: soft, ..Default::default() }
    }

    #[test]
    fn contact_time_and_events_come_from_the_track() {
        let track = [
            sample(0.0, false, false),
            sample(0.2, false, true),
            sample(0.4, false, true),
            sample(0.6, true, false),
            sample(0.8, false, false),
            sample(1.0, false, true),
        ];
        let acc = ContactAccount::from_track(&track);
        assert_eq!(acc.soft_events, 2);
        assert_eq!(acc.hard_events, 1);
        assert!((acc.soft_s - 0.6).abs() < 1e-12);
        assert!((acc.hard_s - 0.2).abs() < 1e-12);
    }

    #[test]
    fn contact_in_the_first_sample_is_an_event_without_time() {
        let acc = ContactAccount::from_track(&[sample(5.0, true, false)]);
        assert_eq!(acc.hard_events, 1);
        assert_eq!(acc.hard_s, 0.0);
        assert_eq!(ContactAccount::from_track(&[]), ContactAccount::default());
    }

    #[test]
    fn time_shares_are_bounded_and_safe_on_empty_missions() {
        let mut r = record(0, Outcome::Succeeded, (10.0, 0.0));
        r.contact.soft_s = 4.0;
        assert!((r.soft_time_share() - 0.1).abs() < 1e-12);
        r.duration_s = 0.0;
        assert_eq!(r.soft_time_share(), 0.0);
    }

    #[test]
    fn path_length_sums_true_positions() {
        let mut a = sample(0.0, false, false);
        let mut b = sample(1.0, false, false);
        let mut c = sample(2.0, false, false);
        a.pose = Pose::new(0.0, 0.0, 0.0);
        b.pose = Pose::new(3.0, 4.0, 0.0);
        c.pose = Pose::new(3.0, 5.0, 0.0);
        assert!((path_length(&[a, b, c]) - 6.0).abs() < 1e-12);
    }

    #[test]
    fn modes_parse_and_print() {
        for m in Mode::ALL {
            assert_eq!(m.as_str().parse::<Mode>().unwrap(), m);
        }
        assert!("fancy".parse::<Mode>().unwrap_err().contains("geometric"));
    }
}
