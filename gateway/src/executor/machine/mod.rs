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
//!   exploration (scan: turn 30°, look, all around; then search legs, toward the last
//!   unconfirmed sighting if there was one, each followed by a fan of looks
//!   about the way ahead; docs/perception.md) → a question
//!   to the user → the user's answer → the planner revises the remaining plan.
//!   A target described by another object ("the chair next to the table",
//!   the step's `reference`): while it is unconfirmed, the instance whose
//!   footprint stands nearest where a reference box has stood this step is
//!   the candidate; once a reference has been seen anywhere, it is
//!   confirmed only with one within 3 m; one without is set aside, and
//!   taken when a bounded search finds none with (docs/perception.md,
//!   "Relations"). A step that begins facing more
//!   than a scan turn off the route's course confirms an instance off the
//!   course only after looking along it; right after a MOVE, one more than
//!   1 m behind where the MOVE ended is set aside like one without its
//!   reference, and taken only when the search finds none ahead.
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
//!
//! One file per behaviour, each an `impl Mission` block with its tests
//! beside it: `drive.rs` (MOVE, RETURN, and the approach to a found
//! target), `find.rs` (FIND: detection, the class vote, relations),
//! `follow.rs` (FOLLOW), `explore.rs` (the bounded exploration),
//! `landmarks.rs` (objects seen on the way) and `metrics.rs`. This file
//! holds the protocol types, the dispatch of frames, replies and stage
//! failures, the outage handling, and the step's start and end.

use nalgebra::Vector3;

use super::model::*;
use crate::config::ExecutorParams;
use drive::move_anchor;
use explore::{Explore, ExploreGoalFor};
use find::FindRun;
use metrics::MetricsAcc;

mod drive;
mod explore;
mod find;
mod follow;
mod landmarks;
mod metrics;
mod size;
#[cfg(test)]
mod test_support;

pub(crate) use landmarks::{Landmark, remembered};

/// Sensor seconds a stage may stay unreachable before the mission fails.
pub(crate) const STAGE_OUTAGE_S: f64 = 10.0;
/// The first retry after a stage failed waits this long, sensor seconds; each
/// further failure doubles the wait, up to `STAGE_RETRY_MAX_S`.
const STAGE_RETRY_S: f64 = 0.1;
const STAGE_RETRY_MAX_S: f64 = 1.0;

/// Reference footprints this close (metres) are one object seen again: the
/// newer replaces the older. At most `REFERENCE_PLACES` are kept, the oldest
/// forgotten first.
const REFERENCE_SAME_M: f64 = 0.75;
const REFERENCE_PLACES: usize = 16;

/// A heading more than this off the route's course (the heading of the last
/// MOVE's or FIND's goal) is off it, rad: a FIND that begins so looks along
/// the course first, and an instance seen so far off it waits for that look
/// (docs/perception.md, "a look-around").
const OFF_COURSE_RAD: f64 = std::f64::consts::FRAC_PI_6;

/// A goal relative to `anchor`: turn by `yaw`, then drive `f_dist` metres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct MoveQuery {
    pub(crate) anchor: Pose2,
    pub(crate) f_dist: f64,
    pub(crate) yaw: f64,
    pub(crate) d_s: f64,
}

/// What the machine needs from the stages, about the current frame.
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum Request {
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
    /// vote against it), otherwise people only; all at once. The reply's
    /// no-go points and person boxes go with this frame's `Drive`.
    Perceive { detect: Option<(i32, f32)> },
    /// Which of `boxes` is the person `name`.
    Identify { boxes: Vec<Detection>, name: String },
    /// The target in `detection`, fused with the track's earlier sightings,
    /// and the goal `d_s` short of it.
    Locate { track_key: String, detection: Detection, d_s: f64, moving: bool },
    /// An odometry goal for an exploration turn or search leg.
    MoveGoal(MoveQuery),
    /// One local-planner step toward `goal` on this frame's depth, keeping
    /// clear of the frame's `obstacles` (as `Perceive` found them; none when
    /// nothing was perceived on this frame).
    Drive { goal: Goal, obstacles: Obstacles },
}

/// The stages' answer to a [`Request`].
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum Reply {
    StepStarted {
        goal: Option<Goal>,
    },
    /// The boxes asked for (none outside a FIND) and what the local planner
    /// must keep clear of.
    Perceived {
        boxes: Vec<Detection>,
        obstacles: Obstacles,
    },
    Identified(Vec<Identity>),
    Located(Estimate),
    Goal(Goal),
    /// The local planner's step and the primitive it chose (`base_link`),
    /// which only the live view draws.
    Driven {
        answer: DriveAnswer,
        path: Vec<[f64; 2]>,
    },
}

/// A stage service failed for this frame.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("the {stage} service failed: {message}")]
pub(crate) struct StageFailure {
    pub(crate) stage: &'static str,
    pub(crate) message: String,
}

/// The frame's answer to the robot.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Command {
    pub(crate) twist: Twist,
    /// False while the robot may idle (waiting for the user or for a stage).
    pub(crate) active: bool,
    /// Set when the mission reached a terminal state on this frame.
    pub(crate) finished: Option<Outcome>,
}

#[derive(Clone, Debug, PartialEq)]
pub(crate) enum Next {
    Call(Request),
    Done(Command),
}

/// What the planner is asked after the user answered a question.
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum PlannerQuery {
    /// The question came before anything ran: the answer is the instruction now.
    Plan { instruction: String },
    /// Revise the plan from the step that failed.
    Replan { instruction: String, plan: Vec<PlanStep>, failed_step: u32, failure: String, answer: String },
}

#[derive(Clone, Debug, PartialEq)]
pub(crate) enum PlannerReply {
    Plan { steps: Vec<PlanStep>, plan_json: String },
    Question(Question),
}

#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("mission {0} is not waiting for an answer")]
pub(crate) struct NotAwaiting(pub String);

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
    /// Since when, and where, the local planner first said Waiting (for a
    /// person) since the robot last got closer or moved on (drive.rs).
    waiting_since: Option<(f64, nalgebra::Vector2<f64>)>,
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

/// A stage outage: since when, how many failures, the latest one, and when to try again.
#[derive(Debug)]
struct Outage {
    since: f64,
    failures: u32,
    last: StageFailure,
    retry_at: f64,
}

/// One mission on one robot.
#[derive(Debug)]
pub(crate) struct Mission {
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
    /// Since when an emergency stop has held the mission (`Frame::estop`).
    paused_since: Option<f64>,
    /// A step has been started (the local planner holds this mission's state).
    started: bool,
    /// The frame being handled and where its work stands.
    frame: Frame,
    /// What this frame's perception found for its local-planner step.
    obstacles: Obstacles,
    pending: Option<Pending>,
    events: Vec<Stamped>,
}

impl Mission {
    /// A mission running `plan`; `question` holds one asked before execution.
    pub(crate) fn new(
        mission_id: String,
        instruction: String,
        plan: Vec<PlanStep>,
        question: Option<Question>,
    ) -> Self {
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
            paused_since: None,
            started: false,
            frame: Frame::default(),
            obstacles: Obstacles::default(),
            pending: None,
            events: Vec::new(),
        }
    }

    pub(crate) fn is_awaiting(&self) -> bool {
        self.awaiting.is_some()
    }

    /// Whether a step is under way (its trace span is the parent of this frame's work).
    pub(crate) fn has_step(&self) -> bool {
        self.step.is_some()
    }

    pub(crate) fn plan(&self) -> &[PlanStep] {
        &self.plan
    }

    /// The events since the last call, in order.
    pub(crate) fn take_events(&mut self) -> Vec<Stamped> {
        std::mem::take(&mut self.events)
    }

    fn emit(&mut self, event: Event) {
        self.events.push(Stamped { stamp: self.frame.stamp, event });
    }

    /// Ends the mission with `outcome`, stamped with the last frame's time.
    pub(crate) fn finish(&mut self, outcome: Outcome, reason: String) {
        let stamp = self.metrics.last_stamp;
        let metrics = self.metrics();
        let current_step = self.index as u32;
        self.events.push(Stamped { stamp, event: Event::Finished { outcome, reason, metrics, current_step } });
        self.step = None;
        self.pending = None;
    }

    pub(crate) fn cancel(&mut self) {
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

    /// A local-planner step toward `goal`, clear of this frame's obstacles.
    fn drive(&self, goal: Goal) -> Request {
        Request::Drive { goal, obstacles: self.obstacles.clone() }
    }

    /// A new sensor frame: the start of one control cycle.
    pub(crate) fn on_frame(&mut self, p: &ExecutorParams, frame: Frame) -> Next {
        self.pending = None;
        self.obstacles = Obstacles::default();
        if self.awaiting.is_some() {
            return Next::Done(Command { twist: Twist::ZERO, active: false, finished: None });
        }
        self.metrics.observe(frame.stamp, &frame.pose, frame.truth.as_ref());
        self.start_pose.get_or_insert(frame.pose);
        self.frame = frame;
        if self.frame.estop {
            // The edge agent holds the robot at zero; nothing runs out
            // while the mission waits for the e-stop's release.
            if self.paused_since.is_none() {
                tracing::info!(mission = %self.mission_id, stamp = self.frame.stamp, "an emergency stop is engaged: the mission pauses");
                self.paused_since = Some(self.frame.stamp);
            }
            return Next::Done(Command { twist: Twist::ZERO, active: false, finished: None });
        }
        if let Some(since) = self.paused_since.take() {
            let stamp = self.frame.stamp;
            tracing::info!(mission = %self.mission_id, stamp, paused_s = stamp - since, "the emergency stop is released: the mission resumes");
            self.restart_clocks(stamp);
            if let Some(o) = &mut self.outage {
                o.since = stamp;
                o.retry_at = stamp;
            }
        }
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
    pub(crate) fn on_stage_error(&mut self, failure: StageFailure) -> Next {
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
                set_aside: Vec::new(),
                set_aside_since: None,
                reference_waived: false,
                course_first: self
                    .course
                    .filter(|c| vlnav_geometry::wrap_angle(c - self.frame.pose.theta).abs() > OFF_COURSE_RAD),
                // `course` is that goal's heading, unless a question since
                // cleared it.
                route_end: self
                    .index
                    .checked_sub(1)
                    .and_then(|i| self.plan.get(i))
                    .filter(|s| s.action == Action::Move && self.course.is_some())
                    .and(self.last_goal),
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
                search_heading: None,
                frontier: Vec::new(),
            })),
        };
        let index = self.index as u32;
        if let StepRun::Find(f) = &run {
            tracing::debug!(mission = %self.mission_id, step = index, revisit = ?f.revisit, landmarks = ?self.landmarks, "find starts");
        }
        self.emit(Event::StepStarted { index, step, anchor });
        self.step =
            Some(Active { started: self.frame.stamp, progress: None, stuck_since: None, waiting_since: None, run });
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
    pub(crate) fn on_reply(&mut self, p: &ExecutorParams, mut reply: Reply) -> Next {
        if let Reply::Perceived { obstacles, .. } = &mut reply {
            self.obstacles = std::mem::take(obstacles);
        }
        let Some(pending) = self.pending.take() else { return self.hold() };
        match (pending, reply) {
            (Pending::Start { step, anchor, d_s }, Reply::StepStarted { goal }) => {
                self.step_started(p, step, anchor, d_s, goal)
            }
            (Pending::DrivePerceived { goal }, Reply::Perceived { .. }) => {
                self.call(Pending::DrivePlanned { goal }, self.drive(goal))
            }
            (Pending::DrivePlanned { goal } | Pending::FindPlanned { goal }, Reply::Driven { answer, .. }) => {
                self.drive_outcome(p, &goal, answer)
            }
            (Pending::FindPerceived, Reply::Perceived { boxes, .. }) => self.find_box(p, boxes),
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
            (Pending::FollowPlanned, Reply::Driven { answer, .. }) => {
                // Following: being within d_s is where we want to stay, not the end.
                let twist = if answer.status == DriveStatus::Reached { Twist::ZERO } else { answer.cmd };
                self.done(twist, None)
            }
            (Pending::ExploreGoal(what), Reply::Goal(goal)) => self.explore_goal(what, goal),
            (Pending::ExploreDriven(state), Reply::Driven { answer, .. }) => self.explore_driven(p, state, answer),
            (pending, reply) => {
                tracing::error!(mission = %self.mission_id, ?pending, ?reply, "a stage reply that answers nothing asked");
                self.on_stage_error(StageFailure { stage: "gateway", message: "an answer out of order".into() })
            }
        }
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

    /// What to ask the planner with the user's answer.
    pub(crate) fn planner_query(&self, answer: &str) -> Result<PlannerQuery, NotAwaiting> {
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
    pub(crate) fn on_planner_reply(&mut self, answer: &str, reply: PlannerReply) -> Result<Vec<PlanStep>, Question> {
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

/// The direction from `pose` to `target` (odom), rad.
fn bearing(pose: Pose2, target: &Vector3<f64>) -> f64 {
    (target.y - pose.y).atan2(target.x - pose.x)
}

#[cfg(test)]
#[path = "mission_tests.rs"]
mod tests;
