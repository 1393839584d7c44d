//! The mission state machine: pure and synchronous, over domain types
//! (`executor/model.rs`). It never calls a service. Each sensor frame it asks
//! for what it needs from the stages, one [`Request`] at a time, and the
//! adapter (`executor/grpc.rs`) answers each with a [`Reply`] — or with a
//! [`StageFailure`] — until the machine is [`Next::Done`] with the frame's one
//! velocity command. Every decision reads sensor time (`Frame::stamp`), so a
//! test scripts a whole mission — confirmation, association, exploration,
//! settling, asking, replanning — without any server, and a lockstep
//! simulation replays exactly.
//!
//! - MOVE: goal relative to the anchor (the odometry pose re-anchored at the
//!   last reached subgoal) → local planner until reached. After a reached MOVE
//!   or FIND the anchor keeps that step's heading (the MOVE's course; facing
//!   the FIND's target), not the heading the robot arrived with: "move 10 m,
//!   then turn left 30°" turns from the direction of the first leg, and a
//!   swerve or a settle at the end of a step would otherwise rotate everything
//!   after it.
//! - FIND: detector (+ ReID for a named person) → subgoal estimator (fused
//!   target) → confirmed after `confirm_frames` sightings within the last
//!   `confirm_window` frames (a real detector misses a small or distant
//!   object in many frames; demanding an unbroken streak would leave it
//!   unconfirmed — docs/perception.md) → local planner until within d_s.
//!   A drive that stops converging settles where it stands once it is
//!   within `SETTLE_M` beyond its goal's tolerance, or — toward a confirmed
//!   fixed target — no farther from the target than the goal is (plus
//!   `PROGRESS_M`): the stopping distance holds there, whatever the
//!   bearing, and a goal on a cable cannot be reached.
//!   The detector is asked for every class, and a candidate is confirmed
//!   only once its sightings are at least twice the frames in which a box of
//!   another class stands where the candidate projects, counted over every
//!   frame it has been watched and after a full window of `confirm_window`
//!   frames from its first sighting; sightings more than `CONSISTENT_M` from
//!   it do not count for it: a detector that takes a
//!   bicycle for a motorcycle in one frame of five does not send the robot
//!   to the bicycle. A candidate that the other class outvotes (twice its
//!   sightings, and `REJECT_NET` more) is dropped,
//!   its place remembered and ignored for the rest of the step, and a new
//!   track started. Once a fixed target is confirmed, each frame's
//!   box is the one where the fused target projects (camera model, odometry
//!   pose), not the one nearest last frame's box: a turning robot shifts the
//!   image by tens of pixels a frame, and a second chair swinging into view
//!   must not take the first one's place. Unseen for `unseen_frames` → bounded
//!   exploration (scan: turn 30°, look; then search legs, toward the last
//!   unconfirmed sighting if there was one) → a question
//!   to the user → the user's answer → the planner revises the remaining plan.
//!   A target described by another object ("the chair next to the table",
//!   the step's `reference`): while it is unconfirmed, the instance whose
//!   footprint stands nearest where a reference box has stood this step is
//!   the candidate (docs/perception.md, "Relations").
//!   Objects of every class seen during the mission's FIND steps are
//!   remembered where they stood (odom footprints, [`Landmark`]): a FIND
//!   whose target is not in view, and whose class an earlier step saw,
//!   first drives toward that place to look again (the landmark passed on
//!   the way, now hidden behind the one just reached) before it looks around
//!   (docs/perception.md, "Objects seen on the way").
//! - FOLLOW: FIND with a moving-target track, kept for a while.
//! - RETURN: back to the odometry pose where the mission started.
//! - A stage that fails holds the robot and backs off in sensor time; one that
//!   stays down for `STAGE_OUTAGE_S` fails the mission with the stage's name.

use nalgebra::{Vector2, Vector3};
use vlnav_geometry::camera::Projector;
use vlnav_geometry::wrap_angle as wrap;

use super::model::*;
use crate::config::ExecutorParams;

/// Sensor seconds a stage may stay unreachable before the mission fails.
pub const STAGE_OUTAGE_S: f64 = 10.0;
/// The first retry after a stage failed waits this long, sensor seconds; each
/// further failure doubles the wait, up to `STAGE_RETRY_MAX_S`.
const STAGE_RETRY_S: f64 = 0.1;
const STAGE_RETRY_MAX_S: f64 = 1.0;
/// A step makes progress when it gets this much closer to its goal, m …
const PROGRESS_M: f64 = 0.1;
/// … or, turning in place, this much closer to its heading, rad.
const PROGRESS_RAD: f64 = 0.05;
/// A drive that stops converging within this distance beyond its goal's
/// tolerance has arrived: it settles instead of asking, m.
const SETTLE_M: f64 = 0.25;
/// A sighting of an unconfirmed candidate counts for it only if it puts
/// the target within this of the candidate's fused position, m (the D455's
/// single-frame error is 0.5 m at 10 m; docs/perception.md).
const CONSISTENT_M: f64 = 1.0;
/// A search leg toward a lead closer than this (beyond the stopping
/// distance) goes straight ahead instead, m.
const LEAD_MIN_M: f64 = 0.5;
/// The class vote on an unnamed fixed candidate, counted over every frame
/// it has been watched: it is confirmed once its sightings are at least this
/// many times the frames another class's box stood where it projects, and
/// dropped once those frames (at least `confirm_frames`) are this many times
/// its sightings; in between it is watched on. The shipped detector calls a
/// bicycle a motorcycle, and a suitcase a backpack, in one frame of five
/// (deploy/perception/nanodet-realistic.toml): a bare majority over one
/// window of 8 frames goes the wrong way in about one window of 18, and a
/// robot watching an object for a few seconds sees many windows.
const VOTE_MARGIN: u32 = 2;
/// A candidate is dropped only once the other class's frames also outnumber
/// its sightings by this many. With a confusion rate c each label moves the
/// odds by (1 − c)/c, 4 at the shipped detector's 0.2; three net labels put
/// them at 64 : 1 against the candidate. A margin of two (16 : 1) dropped a
/// real chair labelled "couch" in three of its first four sightings, and
/// its place is ignored for the rest of the step (evaluation, indoor,
/// trial 18; campus, trial 47, a bench labelled "chair").
const REJECT_NET: u32 = 3;
/// A target with a reference: another instance takes the candidate's place
/// only when its footprint stands this much nearer a reference's (metres on
/// the ground), so two about equally near do not take turns.
const REFERENCE_MARGIN_M: f64 = 0.5;
/// Reference footprints this close (metres) are one object seen again: the
/// newer replaces the older. At most `REFERENCE_PLACES` are kept, the oldest
/// forgotten first.
const REFERENCE_SAME_M: f64 = 0.75;
const REFERENCE_PLACES: usize = 16;
/// Places of objects seen during the mission's FIND steps kept at most;
/// the least seen is forgotten first.
const LANDMARK_PLACES: usize = 64;

/// Sensor seconds one scan turn of exploration may take before looking anyway.
const SCAN_TURN_LIMIT_S: f64 = 4.0;
/// A search leg slower than this on average ends early, m/s.
const SEARCH_MIN_SPEED: f64 = 0.2;

/// A goal relative to `anchor`: turn by `yaw`, then drive `f_dist` metres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MoveQuery {
    pub anchor: Pose2,
    pub f_dist: f64,
    pub yaw: f64,
    pub d_s: f64,
}

/// What the machine needs from the stages, about the current frame.
#[derive(Clone, Debug, PartialEq)]
pub enum Request {
    /// A step begins: for a MOVE, turn `move_goal` into an odometry goal.
    /// With `forget` (the mission's first step) the local planner first
    /// forgets this robot's state. Later steps keep it: odometry runs on
    /// through a mission (a step's goals are relative to its anchor pose;
    /// the robot's `odom` frame is never reset), and what stood behind the
    /// robot when one step ended still stands there when the next begins —
    /// the turn in place that opens a step must know it
    /// (services/local-planner/README.md, obstacle memory).
    StartStep { index: u32, action: Action, desc: String, move_goal: Option<MoveQuery>, forget: bool },
    /// Segment the frame into no-go points and detect: for a FIND every
    /// class at `min_score` (the step's `class_id` is the target; the others
    /// vote against it), otherwise people only; all at once. The adapter
    /// keeps the no-go points and person boxes for this frame's `Drive`.
    Perceive { detect: Option<(i32, f32)> },
    /// Which of `boxes` is the person `name`.
    Identify { boxes: Vec<Detection>, name: String },
    /// The target in `detection`, fused with the track's earlier sightings,
    /// and the goal `d_s` short of it.
    Locate { track_key: String, detection: Detection, d_s: f64, moving: bool },
    /// An odometry goal for an exploration turn or search leg.
    MoveGoal(MoveQuery),
    /// One local-planner step toward `goal` on this frame's depth and no-go points.
    Drive { goal: Goal },
}

/// The stages' answer to a [`Request`].
#[derive(Clone, Debug, PartialEq)]
pub enum Reply {
    StepStarted { goal: Option<Goal> },
    Perceived { boxes: Vec<Detection> },
    Identified(Vec<Identity>),
    Located(Estimate),
    Goal(Goal),
    Driven(DriveAnswer),
}

/// A stage service failed for this frame.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("the {stage} service failed: {message}")]
pub struct StageFailure {
    pub stage: &'static str,
    pub message: String,
}

/// The frame's answer to the robot.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Command {
    pub twist: Twist,
    /// False while the robot may idle (waiting for the user or for a stage).
    pub active: bool,
    /// Set when the mission reached a terminal state on this frame.
    pub finished: Option<Outcome>,
}

#[derive(Clone, Debug, PartialEq)]
pub enum Next {
    Call(Request),
    Done(Command),
}

/// What the planner is asked after the user answered a question.
#[derive(Clone, Debug, PartialEq)]
pub enum PlannerQuery {
    /// The question came before anything ran: the answer is the instruction now.
    Plan { instruction: String },
    /// Revise the plan from the step that failed.
    Replan { instruction: String, plan: Vec<PlanStep>, failed_step: u32, failure: String, answer: String },
}

#[derive(Clone, Debug, PartialEq)]
pub enum PlannerReply {
    Plan { steps: Vec<PlanStep>, plan_json: String },
    Question(Question),
}

#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("mission {0} is not waiting for an answer")]
pub struct NotAwaiting(pub String);

/// The next phase of a fruitless search, given where the last one ended.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ExplorePlan {
    /// Turn once more (the scan turn number, 0-based) within the current look-around.
    Turn(u32),
    /// Drive one search leg (1-based leg number).
    Search(u32),
    /// Exploration is exhausted: ask the user.
    Ask,
}

/// Where an object stood when a FIND step saw it: the footprints of a
/// class's boxes within `REFERENCE_SAME_M` of each other are one object,
/// at their running mean.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Landmark {
    pub class_id: i32,
    /// Odom, on the floor.
    pub at: Vector2<f64>,
    /// Frames a box of the class stood there.
    pub sightings: u32,
    /// The plan step that saw it last.
    pub step: usize,
}

/// Adds this frame's footprints (`class`, odom) seen by step `step` to `landmarks`.
fn remember_landmarks(landmarks: &mut Vec<Landmark>, seen: impl IntoIterator<Item = (i32, Vector2<f64>)>, step: usize) {
    for (class_id, at) in seen {
        let same = landmarks
            .iter_mut()
            .filter(|l| l.class_id == class_id && (l.at - at).norm() <= REFERENCE_SAME_M)
            .min_by(|a, b| (a.at - at).norm().total_cmp(&(b.at - at).norm()));
        match same {
            Some(l) => {
                l.sightings = l.sightings.saturating_add(1);
                l.at += (at - l.at) / f64::from(l.sightings);
                l.step = step;
            }
            None => {
                if landmarks.len() == LANDMARK_PLACES
                    && let Some(i) = (0..landmarks.len()).min_by_key(|&i| (landmarks[i].sightings, landmarks[i].step))
                {
                    landmarks.swap_remove(i);
                }
                landmarks.push(Landmark { class_id, at, sightings: 1, step });
            }
        }
    }
}

/// The place to look for a `class_id` target first when step `step` does
/// not see it: the nearest to `pose` of the objects of that class an
/// earlier step saw in at least `min_sightings` frames (one stray box — a
/// false positive — is not a place).
pub fn remembered(
    landmarks: &[Landmark],
    class_id: i32,
    step: usize,
    min_sightings: u32,
    pose: Pose2,
) -> Option<Vector2<f64>> {
    let here = Vector2::new(pose.x, pose.y);
    landmarks
        .iter()
        .filter(|l| l.class_id == class_id && l.step < step && l.sightings >= min_sightings)
        .map(|l| l.at)
        .min_by(|a, b| (a - here).norm().total_cmp(&(b - here).norm()))
}

/// One search leg from `pose`: toward `lead` — where a sighting not yet
/// confirmed put the target — to look again from closer (a detector finds a
/// small, distant object in only a few frames; docs/perception.md), else
/// straight ahead. Toward a lead it goes half the way to the stopping
/// distance, at least `search_leg_m`, never past that distance; a lead
/// already within reach is not worth another look from the same place.
pub fn search_leg(pose: Pose2, lead: Option<&Vector3<f64>>, d_s: f64, p: &ExecutorParams) -> MoveQuery {
    let ahead = MoveQuery { anchor: pose, f_dist: p.search_leg_m, yaw: 0.0, d_s: 0.0 };
    let Some(t) = lead else { return ahead };
    let room = (t.x - pose.x).hypot(t.y - pose.y) - d_s;
    if room < LEAD_MIN_M {
        return ahead;
    }
    let f_dist = (room / 2.0).max(p.search_leg_m).min(room);
    MoveQuery { anchor: pose, f_dist, yaw: wrap(bearing(pose, t) - pose.theta), d_s: 0.0 }
}

/// Bounded exploration schedule: `scan_turns` turns per look-around, then a
/// search leg, up to `search_legs` legs, each followed by a new look-around.
pub fn after_look(turn: u32, leg: u32, p: &ExecutorParams) -> ExplorePlan {
    if turn + 1 < p.scan_turns {
        ExplorePlan::Turn(turn + 1)
    } else if leg < p.search_legs {
        ExplorePlan::Search(leg + 1)
    } else {
        ExplorePlan::Ask
    }
}

#[derive(Clone, Copy, Debug)]
enum Explore {
    Idle,
    /// `since`: the stamp the turn or leg began.
    /// `origin`: the pose the look-around began at; its turns are counted
    /// from it, so each turn's tolerance does not shrink the look-around.
    Turn {
        goal: Goal,
        turn: u32,
        leg: u32,
        since: f64,
        origin: Pose2,
    },
    Look {
        frames_left: u32,
        turn: u32,
        leg: u32,
        origin: Pose2,
    },
    Search {
        goal: Goal,
        leg: u32,
        since: f64,
    },
}

#[derive(Debug)]
struct FindRun {
    track_key: String,
    class_id: i32,
    person: String,
    target: String,
    /// The class of the object the target was described by, if any, and
    /// where (odom, on the floor) boxes of that class have stood this step.
    reference: Option<i32>,
    reference_at: Vec<Vector2<f64>>,
    d_s: f64,
    moving: bool,
    /// FOLLOW: how long to follow once the target is confirmed, s (the
    /// plan's duration, or the configured default when it gives none).
    follow_s: f64,
    /// Sightings of the last frames, newest in bit 0.
    recent: u64,
    /// The class vote on the current candidate, over every frame it has
    /// been watched: its accepted sightings, and the frames in which
    /// another class's box (and none of the target's) stood where it projects.
    votes_for: u32,
    votes_against: u32,
    /// Frames the current candidate has been watched for (the vote needs a
    /// full window before it may confirm).
    watched: u32,
    /// Places (odom) of candidates another class outvoted.
    rejected: Vec<Vector2<f64>>,
    /// Where an earlier step saw an object of this class ([`remembered`]),
    /// until the exploration has driven toward it.
    revisit: Option<Vector2<f64>>,
    /// Tracks started for this step (a new one after each rejection).
    tracks: u32,
    confirmed: bool,
    goal: Option<Goal>,
    /// The fused target (odom) of the latest accepted observation.
    fused: Option<Vector3<f64>>,
    last_center: Option<(f32, f32)>,
    unseen: u32,
    last_seen: Option<f64>,
    /// FOLLOW: the target's walking velocity (odom, m/s), from its fused
    /// positions, and the fused position and stamp it was last measured from.
    velocity: Option<Vector2<f64>>,
    velocity_from: Option<(f64, Vector3<f64>)>,
    follow_until: Option<f64>,
    explore: Explore,
}

impl FindRun {
    /// An unnamed fixed target: put to the class vote and checked for
    /// consistent sightings before it is confirmed.
    fn put_to_vote(&self) -> bool {
        self.person.is_empty() && !self.moving
    }

    /// A candidate is under the vote: sighted, not yet confirmed.
    fn under_vote(&self) -> bool {
        self.put_to_vote() && !self.confirmed && self.votes_for > 0
    }

    /// Drops the current candidate: its votes and the subgoal estimator's
    /// track (the next sighting starts a new one).
    fn new_track(&mut self) {
        self.tracks += 1;
        self.track_key = format!("{}#{}", self.track_key.split('#').next().unwrap_or_default(), self.tracks);
        (self.recent, self.votes_for, self.votes_against, self.watched, self.last_center, self.goal) =
            (0, 0, 0, 0, None, None);
    }

    /// Where the target is now by its last sighting: the fused position, a
    /// moving target carried on along its velocity for the time unseen
    /// (at most `FOLLOW_PREDICT_S`).
    fn predicted(&self, stamp: f64) -> Option<Vector3<f64>> {
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
    fn track(&mut self, stamp: f64, fused: Vector3<f64>) {
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

#[derive(Debug)]
enum StepRun {
    Drive { goal: Goal },
    Find(Box<FindRun>),
}

#[derive(Debug)]
struct Active {
    started: f64,
    /// The best distance (rotation goals: yaw error) so far and when it was reached.
    progress: Option<(f64, f64)>,
    /// Since when the local planner has said Blocked or NoProgress without a break.
    stuck_since: Option<f64>,
    run: StepRun,
}

/// Where the current frame's work stands while a request is out.
#[derive(Debug)]
enum Pending {
    Start {
        step: PlanStep,
        anchor: Pose2,
        d_s: f64,
    },
    DrivePerceived {
        goal: Goal,
    },
    DrivePlanned {
        goal: Goal,
    },
    FindPerceived,
    FindIdentified {
        boxes: Vec<Detection>,
    },
    FindLocated {
        detection: Detection,
        identity: String,
        similarity: f32,
    },
    FindPlanned {
        goal: Goal,
    },
    FollowPlanned,
    /// An exploration goal is being computed; what it is for.
    ExploreGoal(ExploreGoalFor),
    /// An exploration turn or search leg is being driven.
    ExploreDriven(Explore),
}

#[derive(Clone, Copy, Debug)]
enum ExploreGoalFor {
    /// The first turn of a look-around from `origin` after `leg` search legs;
    /// `announce`: report the exploration's start when the goal is known.
    Scan { leg: u32, origin: Pose2, announce: bool },
    /// Turn `turn` of the look-around that began at `origin`.
    NextTurn { turn: u32, leg: u32, origin: Pose2 },
    /// Search leg number `leg`.
    SearchLeg { leg: u32 },
    /// The leg toward where an earlier step saw the target's class.
    Revisit,
}

/// A stage outage: since when, how many failures, the latest one, and when to try again.
#[derive(Debug)]
struct Outage {
    since: f64,
    failures: u32,
    last: StageFailure,
    retry_at: f64,
}

#[derive(Default, Debug)]
struct MetricsAcc {
    first_stamp: Option<f64>,
    last_stamp: f64,
    last_pose: Option<Pose2>,
    odom_path: f64,
    frames: u32,
    truth_start: Option<Truth>,
    truth_last: Option<Truth>,
}

impl MetricsAcc {
    fn observe(&mut self, stamp: f64, pose: &Pose2, truth: Option<&Truth>) {
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

/// Where a MOVE starts from: the robot's position, facing the course of the
/// MOVE or FIND reached just before (if any), else its own heading.
fn move_anchor(pose: &Pose2, course: Option<f64>) -> Pose2 {
    Pose2 { theta: course.unwrap_or(pose.theta), ..*pose }
}

/// Where a target fixed in `odom` appears in this frame.
#[derive(Clone, Copy, Debug, PartialEq)]
enum TargetView {
    /// At this pixel.
    At(f32, f32),
    /// Behind the camera or outside the image: any box seen is something else.
    OutOfView,
}

/// `None` when the frame has no camera model to predict with.
fn target_view(frame: &Frame, target: &Vector3<f64>) -> Option<TargetView> {
    let camera = frame.camera.as_ref()?;
    let (w, h) = (camera.width as f64, camera.height as f64);
    let base = frame.pose.inverse_transform(&Vector2::new(target.x, target.y));
    let pixel = Projector::new(camera).pixel_of(Vector3::new(base.x, base.y, target.z));
    Some(match pixel {
        Some((u, v, _)) if (0.0..w).contains(&u) && (0.0..h).contains(&v) => TargetView::At(u as f32, v as f32),
        _ => TargetView::OutOfView,
    })
}

/// The box showing the target predicted at `(u, v)`: the nearest whose
/// extent, grown by half its size on every side, holds the prediction.
fn box_at(boxes: &[Detection], u: f32, v: f32) -> Option<&Detection> {
    boxes
        .iter()
        .filter(|b| {
            let (mx, my) = ((b.x_max - b.x_min) / 2.0, (b.y_max - b.y_min) / 2.0);
            (b.x_min - mx..=b.x_max + mx).contains(&u) && (b.y_min - my..=b.y_max + my).contains(&v)
        })
        .min_by(|a, b| {
            let d = |x: &Detection| (x.center().0 - u).hypot(x.center().1 - v);
            d(a).total_cmp(&d(b))
        })
}

/// `(u, v)` lies in the middle of `b` (its central half in each direction):
/// the box shows what stands there, not a neighbour beside it.
fn centred_on(b: &Detection, u: f32, v: f32) -> bool {
    let (qx, qy) = ((b.x_max - b.x_min) / 4.0, (b.y_max - b.y_min) / 4.0);
    (b.x_min + qx..=b.x_max - qx).contains(&u) && (b.y_min + qy..=b.y_max - qy).contains(&v)
}

/// Where an object stands on the floor (`odom`, metres): the ground under
/// the middle of its box's bottom edge, seen from this frame's pose.
fn footprint(frame: &Frame, projector: &Projector, b: &Detection) -> Option<Vector2<f64>> {
    let u = (b.x_min + b.x_max) as f64 / 2.0;
    projector.ground_point(u, b.y_max as f64).map(|g| frame.pose.transform(&g.xy()))
}

/// Where this frame's boxes stand, with their class (odom footprints; none
/// without a camera model, or for a box whose bottom is not below the horizon).
fn places_of(frame: &Frame, boxes: &[Detection]) -> Vec<(i32, Vector2<f64>)> {
    let Some(camera) = frame.camera.as_ref() else { return Vec::new() };
    let projector = Projector::new(camera);
    boxes.iter().filter_map(|b| footprint(frame, &projector, b).map(|at| (b.class_id, at))).collect()
}

/// The index of the box whose centre is nearest `(cx, cy)`, the instance
/// tracked so far.
fn nearest_to(boxes: &[Detection], (cx, cy): (f32, f32)) -> Option<usize> {
    let d = |b: &Detection| (b.center().0 - cx).hypot(b.center().1 - cy);
    (0..boxes.len()).min_by(|&i, &j| d(&boxes[i]).total_cmp(&d(&boxes[j])))
}

/// Remembers where reference boxes stood.
fn remember_reference(f: &mut FindRun, places: Vec<Vector2<f64>>) {
    for at in places {
        f.reference_at.retain(|p| (p - at).norm() > REFERENCE_SAME_M);
        if f.reference_at.len() == REFERENCE_PLACES {
            f.reference_at.remove(0);
        }
        f.reference_at.push(at);
    }
}

/// An unconfirmed target with a reference seen this step (in this frame or
/// an earlier one): the instance in this frame whose footprint stands
/// nearest a reference's, and whether it replaces the candidate tracked so
/// far. The candidate is kept unless another instance is
/// `REFERENCE_MARGIN_M` nearer. `None` when the rule does not apply (no
/// reference seen yet, no camera model, a box whose bottom is at or above
/// the horizon): the usual choice then stands.
fn by_reference<'a>(f: &FindRun, frame: &Frame, boxes: &'a [Detection]) -> Option<(&'a Detection, bool)> {
    if f.confirmed || f.reference_at.is_empty() {
        return None;
    }
    let projector = Projector::new(frame.camera.as_ref()?);
    let gaps = boxes
        .iter()
        .map(|b| {
            let at = footprint(frame, &projector, b)?;
            f.reference_at.iter().map(|a| (a - at).norm()).min_by(f64::total_cmp)
        })
        .collect::<Option<Vec<f64>>>()?;
    let best = (0..boxes.len()).min_by(|&i, &j| gaps[i].total_cmp(&gaps[j]))?;
    let Some(last) = f.last_center else { return Some((&boxes[best], false)) };
    let current = nearest_to(boxes, last)?;
    if current == best || gaps[current] - gaps[best] <= REFERENCE_MARGIN_M {
        Some((&boxes[current], false))
    } else {
        Some((&boxes[best], true))
    }
}

/// The box of an unnamed target in this frame: where a confirmed fixed
/// target projects; else the instance tracked so far; else the most confident.
fn choose_box<'a>(f: &FindRun, frame: &Frame, boxes: &'a [Detection]) -> Option<&'a Detection> {
    if f.confirmed && !f.moving {
        match f.fused.as_ref().and_then(|t| target_view(frame, t)) {
            Some(TargetView::At(u, v)) => return box_at(boxes, u, v),
            Some(TargetView::OutOfView) => return None,
            None => {}
        }
    }
    match f.last_center {
        Some(last) => nearest_to(boxes, last).map(|i| &boxes[i]),
        None => boxes.iter().max_by(|a, b| a.score.total_cmp(&b.score)),
    }
}

fn capitalise(s: &str) -> String {
    let mut c = s.chars();
    c.next().map(|f| f.to_uppercase().collect::<String>() + c.as_str()).unwrap_or_default()
}

/// One mission on one robot.
#[derive(Debug)]
pub struct Mission {
    mission_id: String,
    instruction: String,
    plan: Vec<PlanStep>,
    index: usize,
    step: Option<Active>,
    start_pose: Option<Pose2>,
    last_goal: Option<Pose2>,
    /// The heading (odom) of the last reached MOVE's or FIND's goal: the
    /// course the next MOVE turns from.
    course: Option<f64>,
    metrics: MetricsAcc,
    replans: u32,
    /// Objects seen during this mission's FIND steps.
    landmarks: Vec<Landmark>,
    /// The question waiting for an answer, and the failure that caused it.
    awaiting: Option<(Question, String)>,
    outage: Option<Outage>,
    /// A step has been started (the local planner holds this mission's state).
    started: bool,
    /// The frame being handled and where its work stands.
    frame: Frame,
    pending: Option<Pending>,
    events: Vec<Stamped>,
}

impl Mission {
    /// A mission running `plan`; `question` holds one asked before execution.
    pub fn new(mission_id: String, instruction: String, plan: Vec<PlanStep>, question: Option<Question>) -> Self {
        Self {
            mission_id,
            instruction,
            plan,
            index: 0,
            step: None,
            start_pose: None,
            last_goal: None,
            course: None,
            metrics: MetricsAcc::default(),
            replans: 0,
            landmarks: Vec::new(),
            awaiting: question.map(|q| {
                let reason = q.reason.clone();
                (q, reason)
            }),
            outage: None,
            started: false,
            frame: Frame::default(),
            pending: None,
            events: Vec::new(),
        }
    }

    pub fn is_awaiting(&self) -> bool {
        self.awaiting.is_some()
    }

    /// Whether a step is under way (its trace span is the parent of this frame's work).
    pub fn has_step(&self) -> bool {
        self.step.is_some()
    }

    pub fn plan(&self) -> &[PlanStep] {
        &self.plan
    }

    /// The events since the last call, in order.
    pub fn take_events(&mut self) -> Vec<Stamped> {
        std::mem::take(&mut self.events)
    }

    fn emit(&mut self, event: Event) {
        self.events.push(Stamped { stamp: self.frame.stamp, event });
    }

    fn metrics(&self) -> Metrics {
        self.metrics.metrics(self.index as u32, self.plan.len() as u32, self.replans, self.last_goal.as_ref())
    }

    /// Ends the mission with `outcome`, stamped with the last frame's time.
    pub fn finish(&mut self, outcome: Outcome, reason: String) {
        let stamp = self.metrics.last_stamp;
        let metrics = self.metrics();
        let current_step = self.index as u32;
        self.events.push(Stamped { stamp, event: Event::Finished { outcome, reason, metrics, current_step } });
        self.step = None;
        self.pending = None;
    }

    pub fn cancel(&mut self) {
        self.finish(Outcome::Cancelled, "cancelled by the user; the robot was stopped".into());
    }

    fn done(&mut self, twist: Twist, finished: Option<Outcome>) -> Next {
        self.pending = None;
        self.outage = None;
        Next::Done(Command { twist, active: finished.is_none() && self.awaiting.is_none(), finished })
    }

    fn hold(&mut self) -> Next {
        self.done(Twist::ZERO, None)
    }

    fn call(&mut self, pending: Pending, request: Request) -> Next {
        self.pending = Some(pending);
        Next::Call(request)
    }

    /// A new sensor frame: the start of one control cycle.
    pub fn on_frame(&mut self, p: &ExecutorParams, frame: Frame) -> Next {
        self.pending = None;
        if self.awaiting.is_some() {
            return Next::Done(Command { twist: Twist::ZERO, active: false, finished: None });
        }
        self.metrics.observe(frame.stamp, &frame.pose, frame.truth.as_ref());
        self.start_pose.get_or_insert(frame.pose);
        self.frame = frame;
        if let Some(o) = &self.outage {
            let stamp = self.frame.stamp;
            if stamp - o.since >= STAGE_OUTAGE_S {
                return self.fail_outage();
            }
            if stamp < o.retry_at {
                // Backing off: the robot holds still and may idle meanwhile.
                return Next::Done(Command { twist: Twist::ZERO, active: false, finished: None });
            }
        }
        if self.step.is_none() {
            if self.index >= self.plan.len() {
                self.finish(Outcome::Succeeded, "every step completed".into());
                return self.done(Twist::ZERO, Some(Outcome::Succeeded));
            }
            return self.start_step(p);
        }
        self.continue_step(p)
    }

    /// A stage failed: hold the robot, try again later in sensor time, and
    /// fail the mission when the outage outlasts `STAGE_OUTAGE_S`.
    pub fn on_stage_error(&mut self, failure: StageFailure) -> Next {
        self.pending = None;
        let stamp = self.frame.stamp;
        let o = self.outage.get_or_insert(Outage { since: stamp, failures: 0, last: failure.clone(), retry_at: stamp });
        o.failures += 1;
        o.last = failure;
        let wait = (STAGE_RETRY_S * 2f64.powi(o.failures.min(16) as i32 - 1)).min(STAGE_RETRY_MAX_S);
        o.retry_at = stamp + wait;
        if stamp - o.since >= STAGE_OUTAGE_S {
            return self.fail_outage();
        }
        Next::Done(Command { twist: Twist::ZERO, active: false, finished: None })
    }

    fn fail_outage(&mut self) -> Next {
        let Some(o) = self.outage.take() else { return self.hold() };
        let reason = format!("{} for {:.0} s of robot time; the robot was stopped", o.last, self.frame.stamp - o.since);
        self.finish(Outcome::Failed, reason);
        self.done(Twist::ZERO, Some(Outcome::Failed))
    }

    fn start_step(&mut self, p: &ExecutorParams) -> Next {
        let step = self.plan[self.index].clone();
        let pose = self.frame.pose;
        let d_s = if step.d_s > 0.0 { step.d_s } else { p.default_d_s };
        let anchor = match step.action {
            Action::Move => move_anchor(&pose, self.course),
            _ => pose,
        };
        if step.action == Action::Unspecified {
            self.finish(Outcome::Failed, format!("step {} has no action; the plan is invalid", self.index + 1));
            return self.done(Twist::ZERO, Some(Outcome::Failed));
        }
        let move_goal = (step.action == Action::Move).then_some(MoveQuery {
            anchor,
            f_dist: step.f_dist,
            yaw: step.yaw,
            d_s: step.d_s,
        });
        let forget = !std::mem::replace(&mut self.started, true);
        let request = Request::StartStep {
            index: self.index as u32,
            action: step.action,
            desc: step.desc.clone(),
            move_goal,
            forget,
        };
        self.call(Pending::Start { step, anchor, d_s }, request)
    }

    fn step_started(
        &mut self,
        p: &ExecutorParams,
        step: PlanStep,
        anchor: Pose2,
        d_s: f64,
        goal: Option<Goal>,
    ) -> Next {
        let run = match step.action {
            Action::Move => match goal {
                Some(goal) => StepRun::Drive { goal },
                None => {
                    return self
                        .on_stage_error(StageFailure { stage: "subgoal", message: "no goal for a MOVE step".into() });
                }
            },
            Action::Return => StepRun::Drive {
                goal: Goal {
                    pose: self.start_pose.unwrap_or(self.frame.pose),
                    position_tolerance: 0.5_f64.max(step.d_s),
                    yaw_tolerance: std::f64::consts::PI,
                    rotation_only: false,
                    landmark: None,
                },
            },
            Action::Find | Action::Follow | Action::Unspecified => StepRun::Find(Box::new(FindRun {
                track_key: format!("{}/{}/{}", self.mission_id, self.replans, self.index),
                class_id: step.class_id,
                person: step.person.clone(),
                target: if step.target.is_empty() {
                    vlnav_proto::coco::name(step.class_id).unwrap_or("target").to_string()
                } else {
                    step.target.clone()
                },
                reference: step.reference.as_ref().map(|r| r.class_id),
                reference_at: Vec::new(),
                d_s,
                moving: step.action == Action::Follow,
                follow_s: if step.duration_s > 0.0 { step.duration_s } else { p.follow_default_s },
                recent: 0,
                votes_for: 0,
                votes_against: 0,
                watched: 0,
                rejected: Vec::new(),
                // An unnamed fixed target only: people walk away.
                revisit: (step.action == Action::Find && step.person.is_empty())
                    .then(|| remembered(&self.landmarks, step.class_id, self.index, p.confirm_frames, self.frame.pose))
                    .flatten(),
                tracks: 0,
                confirmed: false,
                goal: None,
                fused: None,
                last_center: None,
                unseen: 0,
                last_seen: None,
                velocity: None,
                velocity_from: None,
                follow_until: None,
                explore: Explore::Idle,
            })),
        };
        let index = self.index as u32;
        if let StepRun::Find(f) = &run {
            tracing::debug!(mission = %self.mission_id, step = index, revisit = ?f.revisit, landmarks = ?self.landmarks, "find starts");
        }
        self.emit(Event::StepStarted { index, step, anchor });
        self.step = Some(Active { started: self.frame.stamp, progress: None, stuck_since: None, run });
        self.continue_step(p)
    }

    /// The step under way, this frame: its time limit, then perception.
    fn continue_step(&mut self, p: &ExecutorParams) -> Next {
        let stamp = self.frame.stamp;
        let Some(active) = self.step.as_ref() else { return self.hold() };
        if stamp - active.started > p.step_timeout_s {
            let what = self.plan[self.index].desc.clone();
            self.ask(
                format!("step {} ({what}) did not finish within {:.0} s", self.index + 1, p.step_timeout_s),
                "This is taking much longer than expected. Should I keep going, skip this step, or stop?".into(),
            );
            return self.hold();
        }
        match &active.run {
            StepRun::Drive { goal } => {
                let goal = *goal;
                self.call(Pending::DrivePerceived { goal }, Request::Perceive { detect: None })
            }
            StepRun::Find(f) => {
                let detect = Some((f.class_id, p.min_score));
                self.call(Pending::FindPerceived, Request::Perceive { detect })
            }
        }
    }

    fn find(&self) -> Option<&FindRun> {
        match self.step.as_ref().map(|s| &s.run) {
            Some(StepRun::Find(f)) => Some(f),
            _ => None,
        }
    }

    fn find_mut(&mut self) -> Option<&mut FindRun> {
        match self.step.as_mut().map(|s| &mut s.run) {
            Some(StepRun::Find(f)) => Some(f),
            _ => None,
        }
    }

    /// The stages' answer to the last request.
    pub fn on_reply(&mut self, p: &ExecutorParams, reply: Reply) -> Next {
        let Some(pending) = self.pending.take() else { return self.hold() };
        match (pending, reply) {
            (Pending::Start { step, anchor, d_s }, Reply::StepStarted { goal }) => {
                self.step_started(p, step, anchor, d_s, goal)
            }
            (Pending::DrivePerceived { goal }, Reply::Perceived { .. }) => {
                self.call(Pending::DrivePlanned { goal }, Request::Drive { goal })
            }
            (Pending::DrivePlanned { goal } | Pending::FindPlanned { goal }, Reply::Driven(answer)) => {
                self.drive_outcome(p, &goal, answer)
            }
            (Pending::FindPerceived, Reply::Perceived { boxes }) => self.find_box(p, boxes),
            (Pending::FindIdentified { boxes }, Reply::Identified(identities)) => {
                let Some(f) = self.find() else { return self.hold() };
                let best = identities
                    .iter()
                    .filter(|i| i.matched && i.name.eq_ignore_ascii_case(&f.person))
                    .max_by(|a, b| a.similarity.total_cmp(&b.similarity));
                match best.and_then(|i| boxes.get(i.box_index as usize).map(|b| (b.clone(), i))) {
                    Some((b, i)) => {
                        let (name, similarity) = (i.name.clone(), i.similarity);
                        self.locate(b, name, similarity)
                    }
                    None => self.observed(p, None),
                }
            }
            (Pending::FindLocated { detection, identity, similarity }, Reply::Located(est)) => {
                let usable = matches!(est.status, EstimateStatus::Ok | EstimateStatus::Outlier) && est.goal.is_some();
                self.observed(p, usable.then_some((detection, identity, similarity, est)))
            }
            (Pending::FollowPlanned, Reply::Driven(answer)) => {
                // Following: being within d_s is where we want to stay, not the end.
                let twist = if answer.status == DriveStatus::Reached { Twist::ZERO } else { answer.cmd };
                self.done(twist, None)
            }
            (Pending::ExploreGoal(what), Reply::Goal(goal)) => self.explore_goal(what, goal),
            (Pending::ExploreDriven(state), Reply::Driven(answer)) => self.explore_driven(p, state, answer),
            (pending, reply) => {
                tracing::error!(mission = %self.mission_id, ?pending, ?reply, "a stage reply that answers nothing asked");
                self.on_stage_error(StageFailure { stage: "gateway", message: "an answer out of order".into() })
            }
        }
    }

    /// This frame's boxes of the target's class: which one is the target.
    fn find_box(&mut self, p: &ExecutorParams, all: Vec<Detection>) -> Next {
        let places = places_of(&self.frame, &all);
        remember_landmarks(&mut self.landmarks, places.iter().copied(), self.index);
        let Some(f) = self.find() else { return self.hold() };
        let (boxes, others): (Vec<Detection>, Vec<Detection>) = all.into_iter().partition(|b| b.class_id == f.class_id);
        let reference_places: Vec<Vector2<f64>> = match f.reference {
            Some(class) if class != f.class_id => {
                places.iter().filter(|(c, _)| *c == class).map(|(_, at)| *at).collect()
            }
            _ => Vec::new(),
        };
        // The class vote: does another class's box (and none of the
        // target's) stand where the unconfirmed candidate projects?
        let rival = f.under_vote()
            && matches!(f.fused.as_ref().and_then(|t| target_view(&self.frame, t)),
                Some(TargetView::At(u, v)) if others.iter().any(|b| centred_on(b, u, v)) && box_at(&boxes, u, v).is_none());
        let Some(f) = self.find_mut() else { return self.hold() };
        f.votes_against += u32::from(rival);
        if f.votes_against >= p.confirm_frames
            && f.votes_against >= VOTE_MARGIN * f.votes_for
            && f.votes_against >= f.votes_for + REJECT_NET
        {
            if let Some(t) = f.fused.take() {
                tracing::debug!(x = t.x, y = t.y, f.votes_for, f.votes_against, "candidate outvoted by another class");
                f.rejected.push(Vector2::new(t.x, t.y));
            }
            f.new_track();
        }
        // Where the object the target is described by stands, for
        // `by_reference` now and in later frames.
        remember_reference(f, reference_places);
        let Some(f) = self.find() else { return self.hold() };
        if boxes.is_empty() {
            return self.observed(p, None);
        }
        if !f.person.is_empty() {
            let name = f.person.clone();
            return self.call(Pending::FindIdentified { boxes: boxes.clone() }, Request::Identify { boxes, name });
        }
        if let Some((b, switch)) = by_reference(f, &self.frame, &boxes) {
            let b = b.clone();
            if switch {
                let Some(f) = self.find_mut() else { return self.hold() };
                tracing::debug!(target = %f.target, "another instance stands nearer the reference: new candidate");
                f.new_track();
            }
            return self.locate(b, String::new(), 0.0);
        }
        match choose_box(f, &self.frame, &boxes) {
            Some(b) => {
                let b = b.clone();
                self.locate(b, String::new(), 0.0)
            }
            None => self.observed(p, None),
        }
    }

    fn locate(&mut self, detection: Detection, identity: String, similarity: f32) -> Next {
        let Some(f) = self.find() else { return self.hold() };
        let request = Request::Locate {
            track_key: f.track_key.clone(),
            detection: detection.clone(),
            d_s: f.d_s,
            moving: f.moving,
        };
        self.call(Pending::FindLocated { detection, identity, similarity }, request)
    }

    /// This frame's sighting (or none) updates the search, then drives,
    /// waits or explores.
    fn observed(&mut self, p: &ExecutorParams, observation: Option<(Detection, String, f32, Estimate)>) -> Next {
        let stamp = self.frame.stamp;
        let index = self.index as u32;
        let Some(f) = self.find_mut() else { return self.hold() };
        // A sighting where an outvoted candidate stood is that object again.
        let observation = observation.filter(|(_, _, _, est)| {
            est.fused_target
                .is_none_or(|t| !f.rejected.iter().any(|r| (r - Vector2::new(t.x, t.y)).norm() < REJECTED_M))
        });
        // A sighting far from the candidate being voted on is another object
        // or a false positive: it does not count for this one. (False
        // positives come at random places; counted together over a long
        // look, a few of them would confirm a target where there is none.)
        let candidate = f.under_vote().then_some(f.fused).flatten();
        let observation = observation.filter(|(_, _, _, est)| match (candidate, est.fused_target) {
            (Some(c), Some(t)) => (c.xy() - t.xy()).norm() <= CONSISTENT_M,
            _ => true,
        });
        let mut seen = None;
        if f.votes_for > 0 || observation.is_some() {
            f.watched = f.watched.saturating_add(1);
        }
        match observation {
            Some((b, identity, similarity, est)) => {
                if f.votes_for == 0 && !f.confirmed {
                    tracing::debug!(at = ?est.fused_target, class = b.class_id, score = b.score, "new candidate");
                }
                f.unseen = 0;
                f.recent = (f.recent << 1 | 1) & window_mask(p.confirm_window);
                f.votes_for += 1;
                f.last_seen = Some(stamp);
                f.goal = est.goal;
                f.fused = est.fused_target.or(f.fused);
                if let Some(t) = est.fused_target {
                    f.track(stamp, t);
                }
                f.last_center = Some(b.center());
                // A fixed, unnamed target is put to the class vote over a full
                // window first; a named person (ReID decides) or a moving
                // target is confirmed by its sightings alone.
                let voted = !f.put_to_vote() || f.watched >= p.confirm_window;
                if !f.confirmed
                    && voted
                    && f.recent.count_ones() >= p.confirm_frames
                    && f.votes_for >= VOTE_MARGIN * f.votes_against
                {
                    tracing::debug!(target = ?f.fused, votes_for = f.votes_for, votes_against = f.votes_against, "target confirmed");
                    f.confirmed = true;
                    f.explore = Explore::Idle;
                    seen = Some(Event::TargetSeen {
                        index,
                        detection: b,
                        target: est.fused_target,
                        goal: est.goal.map(|g| g.pose),
                        range_m: est.range_m,
                        identity,
                        identity_similarity: similarity,
                    });
                }
            }
            None => {
                f.recent = (f.recent << 1) & window_mask(p.confirm_window);
                f.unseen += 1;
                if f.under_vote() && f.recent == 0 {
                    // Not seen again for a whole window: forget the
                    // candidate, keeping where it was (`fused`) as a lead
                    // for the search.
                    tracing::debug!(lead = ?f.fused, votes_for = f.votes_for, votes_against = f.votes_against, "candidate not seen again: forgotten, kept as a lead");
                    f.new_track();
                }
                if f.moving && f.confirmed && f.last_seen.is_some_and(|t| stamp - t > p.follow_lost_s) {
                    f.confirmed = false;
                }
            }
        }
        let (confirmed, goal, moving, waiting) =
            (f.confirmed, f.goal, f.moving, f.recent != 0 || f.unseen < p.unseen_frames);
        if let Some(event) = seen {
            self.emit(event);
        }
        if confirmed {
            let Some(goal) = goal else { return self.hold() };
            if moving {
                let Some(f) = self.find_mut() else { return self.hold() };
                let until = *f.follow_until.get_or_insert(stamp + f.follow_s);
                if stamp >= until {
                    self.complete_step(&goal);
                    return self.hold();
                }
                let stale = f.last_seen.is_some_and(|t| stamp - t > FOLLOW_STALE_S);
                if let (true, Some(t)) = (stale, f.predicted(stamp)) {
                    let face = self.facing(&t, &goal);
                    return self.call(Pending::FollowPlanned, Request::Drive { goal: face });
                }
                return self.call(Pending::FollowPlanned, Request::Drive { goal });
            }
            return self.call(Pending::FindPlanned { goal }, Request::Drive { goal });
        }
        if waiting {
            // A candidate to confirm, or still looking from here: hold still.
            return self.hold();
        }
        self.explore(p)
    }

    /// Applies a local-planner answer for a drive toward the step's goal.
    fn drive_outcome(&mut self, p: &ExecutorParams, goal: &Goal, plan: DriveAnswer) -> Next {
        let (stamp, pose) = (self.frame.stamp, self.frame.pose);
        tracing::debug!(
            mission = %self.mission_id, step = self.index, stamp, status = ?plan.status, distance = plan.distance_to_goal,
            heading_error = plan.heading_error, free_paths = plan.free_paths, x = pose.x, y = pose.y, theta = pose.theta,
            v = plan.cmd.linear, w = plan.cmd.angular, path = plan.path_id,
            "drive"
        );
        if plan.status == DriveStatus::Reached {
            self.complete_step(goal);
            return self.hold();
        }
        // Progress is measured here, over the whole step, in sensor time: the
        // local planner's own watchdog fires once per window and then moves
        // again, so a robot circling its goal would never count as stuck.
        let (measure, step_m) = if goal.rotation_only {
            (plan.heading_error.abs(), PROGRESS_RAD)
        } else {
            (plan.distance_to_goal, PROGRESS_M)
        };
        let Some(step) = self.step.as_mut() else { return self.hold() };
        let since = match &mut step.progress {
            Some(best) => {
                if measure < best.0 - step_m {
                    *best = (measure, stamp);
                }
                best.1
            }
            None => {
                step.progress = Some((measure, stamp));
                stamp
            }
        };
        let stuck_since = if matches!(plan.status, DriveStatus::Blocked | DriveStatus::NoProgress) {
            *step.stuck_since.get_or_insert(stamp)
        } else {
            step.stuck_since = None;
            stamp
        };
        // At the stopping distance from a confirmed fixed target, or nearer,
        // though not on the goal: "stop 1 m before the chair" holds from
        // anywhere at that range, and a goal placed on a cable, or beyond
        // one the robot went round, cannot be reached — turning back to it
        // only wedges the robot between the cable and the landmark
        // (evaluation, lab: the robot stood 0.08 m farther from the chair
        // than its goal, which lay 0.64 m behind it across a cable, and it
        // asked the user the way).
        let at_range = || {
            self.find().is_some_and(|f| {
                f.put_to_vote()
                    && f.confirmed
                    && f.fused.is_some_and(|t| {
                        let t = Vector2::new(t.x, t.y);
                        (pose.position() - t).norm() <= (goal.pose.position() - t).norm() + PROGRESS_M
                    })
            })
        };
        if !goal.rotation_only
            && stamp - since >= p.settle_after_s
            && (plan.distance_to_goal <= goal.position_tolerance + SETTLE_M || at_range())
        {
            // Close to the goal (or at its range) and no longer converging: settle where we are.
            self.complete_step(goal);
            return self.hold();
        }
        if stamp - stuck_since < p.stuck_timeout_s && stamp - since < p.progress_timeout_s {
            return self.done(plan.cmd, None);
        }
        let why = if plan.status == DriveStatus::Blocked { "my way is blocked" } else { "I am not getting closer" };
        self.ask(
            format!("step {}: {why} ({:.1} m from the goal)", self.index + 1, plan.distance_to_goal),
            format!("{} — should I try another way, skip this step, or stop?", capitalise(why)),
        );
        self.hold()
    }

    fn complete_step(&mut self, goal: &Goal) {
        let (g, pose) = (goal.pose, self.frame.pose);
        let error_m = (pose.x - g.x).hypot(pose.y - g.y);
        self.last_goal = Some(g);
        // A MOVE's goal heads along its course, a FIND's faces its target; a
        // FOLLOW ends wherever the person led, a RETURN at the start pose.
        let sets_course = self.plan.get(self.index).is_some_and(|s| matches!(s.action, Action::Move | Action::Find));
        self.course = sets_course.then_some(g.theta);
        let index = self.index as u32;
        self.emit(Event::SubgoalReached { index, pose, goal: g, error_m });
        // Re-anchor: the next step is relative to where this one ended.
        self.index += 1;
        self.step = None;
    }

    fn ask(&mut self, reason: String, question: String) {
        let index = self.index as u32;
        let question = Question {
            question,
            reason: reason.clone(),
            options: vec!["skip this step".into(), "try again".into(), "cancel the mission".into()],
        };
        // Whatever the answer, the robot goes on from where it stands.
        self.course = None;
        self.emit(Event::StepFailed { index, reason: reason.clone() });
        self.emit(Event::ClarificationNeeded { index, question: question.clone() });
        self.awaiting = Some((question, reason));
        self.step = None;
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

    /// Scan turn `turn` (0-based) of the look-around that began at `origin`.
    fn turn_query(p: &ExecutorParams, origin: Pose2, turn: u32) -> MoveQuery {
        MoveQuery { anchor: origin, f_dist: 0.0, yaw: wrap(p.scan_turn_rad * f64::from(turn + 1)), d_s: 0.0 }
    }

    /// The target is not in view and nothing is to be confirmed: the next
    /// move of the bounded exploration.
    fn explore(&mut self, p: &ExecutorParams) -> Next {
        let (pose, stamp) = (self.frame.pose, self.frame.stamp);
        let index = self.index as u32;
        let course = self.course;
        let Some(f) = self.find_mut() else { return self.hold() };
        let state = std::mem::replace(&mut f.explore, Explore::Idle);
        match state {
            Explore::Idle if f.revisit.is_some() => {
                // An earlier step saw one where it is not seen from here (the
                // landmark just reached may hide it): look again from closer
                // before looking around. A place already within reach is
                // looked for by the look-around instead.
                let lead = f.revisit.take().map(|at| Vector3::new(at.x, at.y, 0.0));
                let room = lead.as_ref().map_or(0.0, |t| (t.x - pose.x).hypot(t.y - pose.y) - f.d_s);
                f.explore = Explore::Idle;
                if room < LEAD_MIN_M {
                    return self.explore(p);
                }
                let query = search_leg(pose, lead.as_ref(), f.d_s, p);
                tracing::debug!(
                    ?lead,
                    f_dist = query.f_dist,
                    yaw = query.yaw,
                    "revisit leg toward a landmark an earlier step saw"
                );
                self.call(Pending::ExploreGoal(ExploreGoalFor::Revisit), Request::MoveGoal(query))
            }
            Explore::Idle => {
                // Look first where the target was last seen (a person who
                // walked out of view went that way); else, where the robot
                // faces more than a scan turn off the route's course, along
                // the course (a MOVE that went round a cable's end ended
                // facing 73° off it, and the look-around, turning on from
                // there, came to the chair off the route before the one on
                // it: evaluation, lab); then on round from there.
                let origin = match (f.predicted(stamp), course) {
                    (Some(t), _) => Pose2::new(pose.x, pose.y, wrap(bearing(pose, &t) - p.scan_turn_rad)),
                    (None, Some(c)) if wrap(c - pose.theta).abs() > p.scan_turn_rad => {
                        Pose2::new(pose.x, pose.y, wrap(c - p.scan_turn_rad))
                    }
                    (None, _) => pose,
                };
                let what = ExploreGoalFor::Scan { leg: 0, origin, announce: true };
                self.call(Pending::ExploreGoal(what), Request::MoveGoal(Self::turn_query(p, origin, 0)))
            }
            Explore::Turn { goal, .. } | Explore::Search { goal, .. } => {
                self.call(Pending::ExploreDriven(state), Request::Drive { goal })
            }
            Explore::Look { frames_left, turn, leg, origin } if frames_left > 1 => {
                f.explore = Explore::Look { frames_left: frames_left - 1, turn, leg, origin };
                self.hold()
            }
            Explore::Look { turn, leg, origin, .. } => match after_look(turn, leg, p) {
                ExplorePlan::Turn(t) => {
                    let what = ExploreGoalFor::NextTurn { turn: t, leg, origin };
                    self.call(Pending::ExploreGoal(what), Request::MoveGoal(Self::turn_query(p, origin, t)))
                }
                ExplorePlan::Search(l) => {
                    let query = search_leg(pose, f.fused.as_ref(), f.d_s, p);
                    tracing::debug!(leg = l, lead = ?f.fused, f_dist = query.f_dist, yaw = query.yaw, "search leg");
                    self.call(Pending::ExploreGoal(ExploreGoalFor::SearchLeg { leg: l }), Request::MoveGoal(query))
                }
                ExplorePlan::Ask => {
                    let who = if f.person.is_empty() {
                        format!("the {}", f.target)
                    } else {
                        format!("{} ({})", f.person, f.target)
                    };
                    self.ask(
                        format!(
                            "step {}: {who} not found after looking all around and {} search leg(s)",
                            index + 1,
                            p.search_legs
                        ),
                        format!("I could not find {who}. Where should I look, or should I skip it?"),
                    );
                    self.hold()
                }
            },
        }
    }

    fn explore_goal(&mut self, what: ExploreGoalFor, goal: Goal) -> Next {
        let stamp = self.frame.stamp;
        let index = self.index as u32;
        let next = match what {
            ExploreGoalFor::Scan { leg, origin, announce } => {
                if announce {
                    self.emit(Event::Exploring { index, phase: ExplorePhase::Scan, attempt: 1 });
                }
                Explore::Turn { goal, turn: 0, leg, since: stamp, origin }
            }
            ExploreGoalFor::NextTurn { turn, leg, origin } => Explore::Turn { goal, turn, leg, since: stamp, origin },
            ExploreGoalFor::SearchLeg { leg } => {
                self.emit(Event::Exploring { index, phase: ExplorePhase::Search, attempt: leg });
                Explore::Search { goal, leg, since: stamp }
            }
            // Counted as leg 0: the look-around and the search legs follow as usual.
            ExploreGoalFor::Revisit => {
                self.emit(Event::Exploring { index, phase: ExplorePhase::Revisit, attempt: 1 });
                Explore::Search { goal, leg: 0, since: stamp }
            }
        };
        if let Some(f) = self.find_mut() {
            f.explore = next;
        }
        self.hold()
    }

    fn explore_driven(&mut self, p: &ExecutorParams, state: Explore, answer: DriveAnswer) -> Next {
        let (stamp, pose) = (self.frame.stamp, self.frame.pose);
        let index = self.index as u32;
        let (next, twist) = match state {
            Explore::Turn { goal, turn, leg, since, origin } => {
                // A scan turn that does not finish in time (a wheel stalled
                // short of the heading), or that the local planner reports
                // BLOCKED (no room to turn), looks from where it got to: a
                // robot wedged beside a cable waited out every turn of two
                // look-arounds and the mission ran out of time unasked.
                let done = matches!(answer.status, DriveStatus::Reached | DriveStatus::Blocked);
                if done || stamp - since >= SCAN_TURN_LIMIT_S {
                    (Explore::Look { frames_left: p.look_frames, turn, leg, origin }, Twist::ZERO)
                } else {
                    (Explore::Turn { goal, turn, leg, since, origin }, answer.cmd)
                }
            }
            Explore::Search { goal, leg, since } => {
                let overdue = stamp - since >= p.search_leg_m / SEARCH_MIN_SPEED + SCAN_TURN_LIMIT_S;
                let ended =
                    matches!(answer.status, DriveStatus::Reached | DriveStatus::Blocked | DriveStatus::NoProgress);
                if overdue || ended {
                    self.emit(Event::Exploring { index, phase: ExplorePhase::Scan, attempt: leg + 1 });
                    let what = ExploreGoalFor::Scan { leg, origin: pose, announce: false };
                    return self.call(Pending::ExploreGoal(what), Request::MoveGoal(Self::turn_query(p, pose, 0)));
                }
                (Explore::Search { goal, leg, since }, answer.cmd)
            }
            other => (other, Twist::ZERO),
        };
        if let Some(f) = self.find_mut() {
            f.explore = next;
        }
        self.done(twist, None)
    }

    /// What to ask the planner with the user's answer.
    pub fn planner_query(&self, answer: &str) -> Result<PlannerQuery, NotAwaiting> {
        let Some((_, failure)) = self.awaiting.as_ref() else { return Err(NotAwaiting(self.mission_id.clone())) };
        Ok(if self.plan.is_empty() {
            PlannerQuery::Plan { instruction: answer.to_string() }
        } else {
            PlannerQuery::Replan {
                instruction: self.instruction.clone(),
                plan: self.plan.clone(),
                failed_step: self.index as u32,
                failure: failure.clone(),
                answer: answer.to_string(),
            }
        })
    }

    /// The planner's answer to [`Mission::planner_query`]: the revised full
    /// plan (the mission resumes at the step that failed), or a further question.
    pub fn on_planner_reply(&mut self, answer: &str, reply: PlannerReply) -> Result<Vec<PlanStep>, Question> {
        let stamp = self.metrics.last_stamp;
        match reply {
            PlannerReply::Plan { steps, plan_json } => {
                let mut plan = self.plan[..self.index.min(self.plan.len())].to_vec();
                plan.extend(steps);
                self.plan = plan.clone();
                self.replans += 1;
                self.awaiting = None;
                let event = Event::Replanned {
                    plan: plan.clone(),
                    plan_json,
                    answer: answer.to_string(),
                    resume_index: self.index as u32,
                };
                self.events.push(Stamped { stamp, event });
                Ok(plan)
            }
            PlannerReply::Question(q) => {
                let index = self.index as u32;
                self.events.push(Stamped { stamp, event: Event::ClarificationNeeded { index, question: q.clone() } });
                if let Some(a) = self.awaiting.as_mut() {
                    a.0 = q.clone();
                }
                Err(q)
            }
        }
    }
}

#[cfg(test)]
#[path = "machine_tests.rs"]
mod tests;

/// The bits of the last `window` frames (1 to 64).
fn window_mask(window: u32) -> u64 {
    match window.clamp(1, 64) {
        64 => u64::MAX,
        w => (1u64 << w) - 1,
    }
}

/// The direction from `pose` to `target` (odom), rad.
fn bearing(pose: Pose2, target: &Vector3<f64>) -> f64 {
    (target.y - pose.y).atan2(target.x - pose.x)
}

/// A sighting this close to an outvoted candidate's place is that object, m.
const REJECTED_M: f64 = 0.75;
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
