//! The mission executor: runs a validated plan step by step, one sensor frame
//! at a time, through the stage services. All timing reads frame stamps.
//!
//! - MOVE: subgoal estimator → goal relative to the anchor (the odometry pose
//!   re-anchored at the last reached subgoal) → local planner until reached.
//!   After a reached MOVE or FIND the anchor keeps that step's heading (the
//!   MOVE's course; facing the FIND's target), not the heading the robot
//!   arrived with: "move 10 m, then turn left 30°" turns from the direction
//!   of the first leg, "stop before the person, then turn right 45°" from
//!   facing the person, and a swerve or a settle at the end of the step
//!   would otherwise rotate everything after it.
//! - FIND: detector (+ ReID for a named person) → subgoal estimator (fused
//!   target) → confirmed after `confirm_frames` consecutive sightings → local
//!   planner until within d_s. Once a fixed target is confirmed, each frame's
//!   box is the one where the fused target projects (camera model, odometry
//!   pose), not the one nearest last frame's box: a turning robot shifts the
//!   image by tens of pixels a frame, and a second chair swinging into view
//!   must not take the first one's place. Unseen for `unseen_frames` → bounded
//!   exploration (scan: turn 30°, look; then forward search legs) → a
//!   clarification question → the user's answer → the planner revises the
//!   remaining plan.
//! - FOLLOW: FIND with a moving-target track, kept for `duration_s`.
//! - RETURN: back to the odometry pose where the mission started.

use std::time::Duration;

use tracing::Instrument;
use tracing_opentelemetry::OpenTelemetrySpanExt;
use vlnav_proto::v1::{
    ActionKind, ActionStep, BoundingBox, Clarification, ClarificationNeeded, DetectRequest, EstimateStatus, Exploring,
    Finished, Goal, IdentifyRequest, LocalPlanStatus, MissionMetrics, MissionState, MoveGoalRequest, PlanStepRequest,
    Point3, Pose2D, ReplanRequest, Replanned, ResetRobotRequest, RgbdFrame, SegmentRequest, SensorFrame, SimTruth,
    StepFailed, StepStarted, SubgoalReached, TargetGoalRequest, TargetSeen, Twist2D, mission_event::Kind,
    plan_response,
};

use crate::config::ExecutorParams;
use crate::hub::Hub;
use crate::pipeline::Pipeline;

/// A stage service failed for this frame.
#[derive(Debug, thiserror::Error)]
#[error("the {stage} service failed: {message}")]
pub struct StageError {
    pub stage: &'static str,
    pub code: tonic::Code,
    pub message: String,
}

fn stage(stage: &'static str) -> impl FnOnce(tonic::Status) -> StageError {
    move |s| StageError { stage, code: s.code(), message: s.message().to_string() }
}

/// What the executor tells the robot after a frame.
pub struct Tick {
    pub twist: Twist2D,
    /// False while waiting for the user: the robot may idle.
    pub active: bool,
    /// Set when the mission reached a terminal state on this frame.
    pub finished: Option<MissionState>,
    /// The control-cycle span of this frame (parent of the edge-forward span).
    pub span: tracing::Span,
}

/// Sensor seconds a stage may stay unreachable before the mission fails.
const STAGE_OUTAGE_S: f64 = 10.0;

/// A step makes progress when it gets this much closer to its goal, m …
const PROGRESS_M: f64 = 0.1;
/// … or, turning in place, this much closer to its heading, rad.
const PROGRESS_RAD: f64 = 0.05;
/// A drive that stops converging within this distance beyond its goal's
/// tolerance has arrived: it settles instead of asking, m.
const SETTLE_M: f64 = 0.25;
/// Sensor seconds one scan turn of exploration may take before looking anyway.
const SCAN_TURN_LIMIT_S: f64 = 4.0;
/// A search leg slower than this on average ends early, m/s.
const SEARCH_MIN_SPEED: f64 = 0.2;

pub struct Ctx<'a> {
    pub pipeline: &'a Pipeline,
    pub params: &'a ExecutorParams,
    pub hub: &'a Hub,
}

#[derive(Default)]
struct MetricsAcc {
    first_stamp: Option<f64>,
    last_stamp: f64,
    last_pose: Option<Pose2D>,
    odom_path: f64,
    frames: u32,
    truth_start: Option<SimTruth>,
    truth_last: Option<SimTruth>,
}

impl MetricsAcc {
    fn observe(&mut self, stamp: f64, pose: &Pose2D, truth: Option<&SimTruth>) {
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

    fn to_proto(
        &self,
        steps_completed: u32,
        steps_total: u32,
        replans: u32,
        last_goal: Option<&Pose2D>,
    ) -> MissionMetrics {
        let mut m = MissionMetrics {
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
                let world_goal = compose(origin, goal);
                m.final_error_m = (truth.x - world_goal.x).hypot(truth.y - world_goal.y);
            }
        }
        m
    }
}

/// `a ⊕ b`: pose b expressed in a's frame, mapped to a's parent frame.
pub fn compose(a: &Pose2D, b: &Pose2D) -> Pose2D {
    let (s, c) = a.theta.sin_cos();
    Pose2D { x: a.x + c * b.x - s * b.y, y: a.y + s * b.x + c * b.y, theta: wrap(a.theta + b.theta) }
}

/// Angle wrapped to (−π, π] (the subgoal estimator's, so both wrap alike).
pub use vlnav_subgoal::geometry::wrap_angle as wrap;

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
        origin: Pose2D,
    },
    Look {
        frames_left: u32,
        turn: u32,
        leg: u32,
        origin: Pose2D,
    },
    Search {
        goal: Goal,
        leg: u32,
        since: f64,
    },
}

struct FindRun {
    track_key: String,
    class_id: i32,
    person: String,
    target: String,
    d_s: f64,
    moving: bool,
    streak: u32,
    confirmed: bool,
    goal: Option<Goal>,
    /// The fused target (odom) of the latest accepted observation.
    fused: Option<Point3>,
    last_center: Option<(f32, f32)>,
    unseen: u32,
    last_seen: Option<f64>,
    follow_until: Option<f64>,
    explore: Explore,
}

enum StepRun {
    Drive { goal: Goal },
    Find(Box<FindRun>),
}

struct Active {
    started: f64,
    /// The best distance (rotation goals: yaw error) so far and when it was reached.
    progress: Option<(f64, f64)>,
    /// Since when the local planner has said Blocked or NoProgress without a break.
    stuck_since: Option<f64>,
    run: StepRun,
    span: tracing::Span,
}

pub struct MissionRun {
    pub mission_id: String,
    pub robot_id: String,
    instruction: String,
    plan: Vec<ActionStep>,
    index: usize,
    step: Option<Active>,
    start_pose: Option<Pose2D>,
    last_goal: Option<Pose2D>,
    /// The heading (odom) of the last reached MOVE's or FIND's goal: the
    /// course the next MOVE turns from.
    course: Option<f64>,
    metrics: MetricsAcc,
    replans: u32,
    /// The question waiting for an answer, and the failure that caused it.
    awaiting: Option<(Clarification, String)>,
    stage_failing_since: Option<f64>,
    span: tracing::Span,
}

fn center(b: &BoundingBox) -> (f32, f32) {
    ((b.x_min + b.x_max) / 2.0, (b.y_min + b.y_max) / 2.0)
}

/// The frame with only what geometry needs (depth, camera, pose).
fn depth_only(f: &RgbdFrame) -> RgbdFrame {
    RgbdFrame {
        robot_id: f.robot_id.clone(),
        seq: f.seq,
        stamp: f.stamp,
        camera: f.camera,
        rgb: None,
        depth: f.depth.clone(),
        odom: f.odom,
        odom_twist: f.odom_twist,
        labels: None,
    }
}

/// Where a MOVE starts from: the robot's position, facing the course of the
/// MOVE or FIND reached just before (if any), else its own heading.
fn move_anchor(pose: &Pose2D, course: Option<f64>) -> Pose2D {
    Pose2D { theta: course.unwrap_or(pose.theta), ..*pose }
}

/// Where a target fixed in `odom` appears in this frame.
#[derive(Clone, Copy, Debug, PartialEq)]
enum TargetView {
    /// At this pixel.
    At(f32, f32),
    /// Behind the camera or outside the image: any box seen is something else.
    OutOfView,
}

fn target_view(frame: &RgbdFrame, pose: &Pose2D, target: &Point3) -> Option<TargetView> {
    let defaults = vlnav_subgoal::grpc::DepthDefaults { min_m: 0.0, max_m: 1e3 };
    let camera = vlnav_subgoal::grpc::camera_from_proto(frame.camera.as_ref(), "frame.camera", defaults).ok()?;
    let (w, h) = (camera.width as f64, camera.height as f64);
    let base = vlnav_subgoal::geometry::Pose2::new(pose.x, pose.y, pose.theta)
        .odom_to_base(&nalgebra::Vector2::new(target.x, target.y));
    let pixel =
        vlnav_subgoal::camera::Projector::new(&camera).pixel_of(nalgebra::Vector3::new(base.x, base.y, target.z));
    Some(match pixel {
        Some((u, v, _)) if (0.0..w).contains(&u) && (0.0..h).contains(&v) => TargetView::At(u as f32, v as f32),
        _ => TargetView::OutOfView,
    })
}

/// The box showing the target predicted at `(u, v)`: the nearest whose
/// extent, grown by half its size on every side, holds the prediction.
fn box_at(boxes: &[BoundingBox], u: f32, v: f32) -> Option<&BoundingBox> {
    boxes
        .iter()
        .filter(|b| {
            let (mx, my) = ((b.x_max - b.x_min) / 2.0, (b.y_max - b.y_min) / 2.0);
            (b.x_min - mx..=b.x_max + mx).contains(&u) && (b.y_min - my..=b.y_max + my).contains(&v)
        })
        .min_by(|a, b| {
            let d = |x: &BoundingBox| (center(x).0 - u).hypot(center(x).1 - v);
            d(a).total_cmp(&d(b))
        })
}

fn zero() -> Twist2D {
    Twist2D { linear: 0.0, angular: 0.0 }
}

impl MissionRun {
    /// A run of `plan`; `awaiting` holds a question asked before execution.
    pub fn new(
        mission_id: String,
        robot_id: String,
        instruction: String,
        plan: Vec<ActionStep>,
        awaiting: Option<Clarification>,
        span: tracing::Span,
    ) -> Self {
        Self {
            mission_id,
            robot_id,
            instruction,
            plan,
            index: 0,
            step: None,
            start_pose: None,
            last_goal: None,
            course: None,
            metrics: MetricsAcc::default(),
            replans: 0,
            awaiting: awaiting.map(|c| {
                let reason = c.reason.clone();
                (c, reason)
            }),
            stage_failing_since: None,
            span,
        }
    }

    pub fn is_awaiting(&self) -> bool {
        self.awaiting.is_some()
    }

    fn emit(&self, ctx: &Ctx<'_>, stamp: f64, kind: Kind, change: impl FnOnce(&mut vlnav_proto::v1::Mission)) {
        if let Err(e) = ctx.hub.record(&self.mission_id, stamp, Some(kind), change) {
            tracing::error!(mission = %self.mission_id, "cannot record event: {e}");
        }
    }

    fn metrics(&self) -> MissionMetrics {
        self.metrics.to_proto(self.index as u32, self.plan.len() as u32, self.replans, self.last_goal.as_ref())
    }

    /// Ends the mission with `state`.
    pub fn finish(&mut self, ctx: &Ctx<'_>, state: MissionState, reason: String) {
        let stamp = self.metrics.last_stamp;
        let metrics = self.metrics();
        let current = self.index as u32;
        self.emit(ctx, stamp, Kind::Finished(Finished { state: state as i32, reason, metrics: Some(metrics) }), |m| {
            m.current_step = current
        });
        self.step = None;
    }

    /// One sensor frame in, one velocity command out.
    pub async fn on_frame(&mut self, ctx: &Ctx<'_>, sf: &SensorFrame) -> Tick {
        let Some(frame) = sf.frame.as_ref() else {
            return Tick { twist: zero(), active: false, finished: None, span: tracing::Span::none() };
        };
        let pose = frame.odom.unwrap_or_default();
        if self.awaiting.is_some() {
            return Tick { twist: zero(), active: false, finished: None, span: tracing::Span::none() };
        }
        self.metrics.observe(frame.stamp, &pose, sf.truth.as_ref());
        self.start_pose.get_or_insert(pose);
        let step_span = self.step.as_ref().map_or_else(|| self.span.clone(), |s| s.span.clone());
        let cycle =
            tracing::info_span!(parent: &step_span, "control-cycle", frame.seq = frame.seq, frame.stamp = frame.stamp);
        let result = self.tick(ctx, frame, &pose).instrument(cycle.clone()).await;
        match result {
            Ok((twist, finished)) => {
                self.stage_failing_since = None;
                Tick { twist, active: finished.is_none() && self.awaiting.is_none(), finished, span: cycle }
            }
            Err(e) => {
                tracing::warn!(parent: &cycle, mission = %self.mission_id, "holding the robot: {e}");
                let since = *self.stage_failing_since.get_or_insert(frame.stamp);
                // Pace a lockstep robot so an outage is measured in sensor seconds
                // that correspond to real retry attempts.
                tokio::time::sleep(Duration::from_millis(100)).await;
                if frame.stamp - since >= STAGE_OUTAGE_S {
                    self.finish(
                        ctx,
                        MissionState::Failed,
                        format!("{e} for {:.0} s of robot time; the robot was stopped", frame.stamp - since),
                    );
                    return Tick { twist: zero(), active: false, finished: Some(MissionState::Failed), span: cycle };
                }
                Tick { twist: zero(), active: true, finished: None, span: cycle }
            }
        }
    }

    async fn tick(
        &mut self,
        ctx: &Ctx<'_>,
        frame: &RgbdFrame,
        pose: &Pose2D,
    ) -> Result<(Twist2D, Option<MissionState>), StageError> {
        if self.step.is_none() {
            if self.index >= self.plan.len() {
                self.finish(ctx, MissionState::Succeeded, "every step completed".into());
                return Ok((zero(), Some(MissionState::Succeeded)));
            }
            self.start_step(ctx, frame, pose).await?;
        }
        let stamp = frame.stamp;
        let started = self.step.as_ref().map_or(stamp, |s| s.started);
        if stamp - started > ctx.params.step_timeout_s {
            let what = self.plan[self.index].desc.clone();
            self.ask(
                ctx,
                stamp,
                format!("step {} ({what}) did not finish within {:.0} s", self.index + 1, ctx.params.step_timeout_s),
                "This is taking much longer than expected. Should I keep going, skip this step, or stop?".into(),
            );
            return Ok((zero(), None));
        }
        let is_find = matches!(self.step.as_ref().map(|s| &s.run), Some(StepRun::Find(_)));
        if is_find {
            self.find_tick(ctx, frame, pose).await
        } else {
            let Some(Active { run: StepRun::Drive { goal }, .. }) = self.step.as_ref() else { unreachable!() };
            let goal = *goal;
            let no_go = self.segment(ctx, frame).await?;
            let plan = self.local_plan(ctx, frame, &goal, no_go).await?;
            self.drive_outcome(ctx, stamp, pose, &goal, plan)
        }
    }

    /// Applies a local-planner answer for a drive toward the step's goal.
    fn drive_outcome(
        &mut self,
        ctx: &Ctx<'_>,
        stamp: f64,
        pose: &Pose2D,
        goal: &Goal,
        plan: vlnav_proto::v1::PlanStepResponse,
    ) -> Result<(Twist2D, Option<MissionState>), StageError> {
        let status = LocalPlanStatus::try_from(plan.status).unwrap_or(LocalPlanStatus::Unspecified);
        tracing::debug!(
            mission = %self.mission_id, step = self.index, stamp, ?status, distance = plan.distance_to_goal,
            heading_error = plan.heading_error, free_paths = plan.free_paths, x = pose.x, y = pose.y, theta = pose.theta,
            v = plan.cmd.map_or(0.0, |c| c.linear), w = plan.cmd.map_or(0.0, |c| c.angular), path = plan.path_id,
            "drive"
        );
        if status == LocalPlanStatus::Reached {
            self.complete_step(ctx, stamp, pose, goal);
            return Ok((zero(), None));
        }
        // Progress is measured here, over the whole step, in sensor time: the
        // local planner's own watchdog fires once per window and then moves
        // again, so a robot circling its goal would never count as stuck.
        let (measure, step_m) = if goal.rotation_only {
            (plan.heading_error.abs(), PROGRESS_RAD)
        } else {
            (plan.distance_to_goal, PROGRESS_M)
        };
        let step = self.step.as_mut().expect("a step is active");
        let since = match &mut step.progress {
            Some(p) => {
                if measure < p.0 - step_m {
                    *p = (measure, stamp);
                }
                p.1
            }
            None => {
                step.progress = Some((measure, stamp));
                stamp
            }
        };
        let stuck_since = if matches!(status, LocalPlanStatus::Blocked | LocalPlanStatus::NoProgress) {
            *step.stuck_since.get_or_insert(stamp)
        } else {
            step.stuck_since = None;
            stamp
        };
        let params = ctx.params;
        if !goal.rotation_only
            && plan.distance_to_goal <= goal.position_tolerance + SETTLE_M
            && stamp - since >= params.settle_after_s
        {
            // Close to the goal and no longer converging: settle where we are.
            self.complete_step(ctx, stamp, pose, goal);
            return Ok((zero(), None));
        }
        if stamp - stuck_since < params.stuck_timeout_s && stamp - since < params.progress_timeout_s {
            return Ok((plan.cmd.unwrap_or_default(), None));
        }
        let why = if status == LocalPlanStatus::Blocked { "my way is blocked" } else { "I am not getting closer" };
        self.ask(
            ctx,
            stamp,
            format!("step {}: {why} ({:.1} m from the goal)", self.index + 1, plan.distance_to_goal),
            format!("{} — should I try another way, skip this step, or stop?", capitalise(why)),
        );
        Ok((zero(), None))
    }

    async fn start_step(&mut self, ctx: &Ctx<'_>, frame: &RgbdFrame, pose: &Pose2D) -> Result<(), StageError> {
        let step = self.plan[self.index].clone();
        let action = ActionKind::try_from(step.action).unwrap_or(ActionKind::Unspecified);
        let span = tracing::info_span!(parent: &self.span, "step", step.index = self.index, step.action = ?action, step.desc = %step.desc);
        let d_s = if step.d_s > 0.0 { step.d_s } else { ctx.params.default_d_s };
        let anchor = match action {
            ActionKind::Move => move_anchor(pose, self.course),
            _ => *pose,
        };
        let run = async {
            ctx.pipeline
                .local_planner
                .clone()
                .reset_robot(ResetRobotRequest { robot_id: self.robot_id.clone() })
                .await
                .map_err(stage("local-planner"))?;
            Ok::<_, StageError>(match action {
                ActionKind::Move => {
                    let goal = ctx
                        .pipeline
                        .subgoal
                        .clone()
                        .move_goal(MoveGoalRequest {
                            anchor: Some(anchor),
                            f_dist: step.f_dist,
                            yaw: step.yaw,
                            d_s: step.d_s,
                        })
                        .await
                        .map_err(stage("subgoal"))?
                        .into_inner();
                    StepRun::Drive { goal }
                }
                ActionKind::Return => {
                    let home = self.start_pose.unwrap_or(*pose);
                    StepRun::Drive {
                        goal: Goal {
                            pose: Some(home),
                            position_tolerance: 0.5_f64.max(step.d_s),
                            yaw_tolerance: std::f64::consts::PI,
                            rotation_only: false,
                        },
                    }
                }
                ActionKind::Find | ActionKind::Follow => StepRun::Find(Box::new(FindRun {
                    track_key: format!("{}/{}/{}", self.mission_id, self.replans, self.index),
                    class_id: step.class_id,
                    person: step.person.clone(),
                    target: if step.target.is_empty() {
                        vlnav_proto::coco::name(step.class_id).unwrap_or("target").to_string()
                    } else {
                        step.target.clone()
                    },
                    d_s,
                    moving: action == ActionKind::Follow,
                    streak: 0,
                    confirmed: false,
                    goal: None,
                    fused: None,
                    last_center: None,
                    unseen: 0,
                    last_seen: None,
                    follow_until: None,
                    explore: Explore::Idle,
                })),
                ActionKind::Unspecified => {
                    return Err(StageError {
                        stage: "planner",
                        code: tonic::Code::Internal,
                        message: format!("step {} has no action", self.index + 1),
                    });
                }
            })
        }
        .instrument(span.clone())
        .await?;
        let index = self.index as u32;
        self.emit(
            ctx,
            frame.stamp,
            Kind::StepStarted(StepStarted { index, step: Some(step), anchor: Some(anchor) }),
            |m| {
                m.current_step = index;
                m.state = MissionState::Running as i32;
            },
        );
        self.step = Some(Active { started: frame.stamp, progress: None, stuck_since: None, run, span });
        Ok(())
    }

    fn complete_step(&mut self, ctx: &Ctx<'_>, stamp: f64, pose: &Pose2D, goal: &Goal) {
        let g = goal.pose.unwrap_or_default();
        let error = (pose.x - g.x).hypot(pose.y - g.y);
        self.last_goal = Some(g);
        // A MOVE's goal heads along its course, a FIND's faces its target; a
        // FOLLOW ends wherever the person led, a RETURN at the start pose.
        let sets_course = self
            .plan
            .get(self.index)
            .is_some_and(|s| s.action == ActionKind::Move as i32 || s.action == ActionKind::Find as i32);
        self.course = sets_course.then_some(g.theta);
        let index = self.index as u32;
        self.emit(
            ctx,
            stamp,
            Kind::SubgoalReached(SubgoalReached { index, pose: Some(*pose), goal: Some(g), error_m: error }),
            |m| m.current_step = index + 1,
        );
        // Re-anchor: the next step is relative to where this one ended.
        self.index += 1;
        self.step = None;
    }

    fn ask(&mut self, ctx: &Ctx<'_>, stamp: f64, reason: String, question: String) {
        let index = self.index as u32;
        let clarification = Clarification {
            question,
            reason: reason.clone(),
            options: vec!["skip this step".into(), "try again".into(), "cancel the mission".into()],
        };
        // Whatever the answer, the robot goes on from where it stands.
        self.course = None;
        self.emit(ctx, stamp, Kind::StepFailed(StepFailed { index, reason: reason.clone() }), |_| {});
        let c = clarification.clone();
        self.emit(
            ctx,
            stamp,
            Kind::ClarificationNeeded(ClarificationNeeded { index, clarification: Some(clarification.clone()) }),
            move |m| {
                m.state = MissionState::AwaitingClarification as i32;
                m.clarification = Some(c);
            },
        );
        self.awaiting = Some((clarification, reason));
        self.step = None;
    }

    /// The user's answer: the planner revises the steps from the one that
    /// failed on. Returns the revised full plan, or a further question.
    pub async fn answer(
        &mut self,
        ctx: &Ctx<'_>,
        answer: &str,
    ) -> Result<Result<Vec<ActionStep>, Clarification>, tonic::Status> {
        let Some((_, failure)) = self.awaiting.clone() else {
            return Err(tonic::Status::failed_precondition(format!(
                "mission {} is not waiting for an answer",
                self.mission_id
            )));
        };
        // A question asked before anything ran: the answer is the instruction now.
        let resp = if self.plan.is_empty() {
            ctx.pipeline
                .planner
                .clone()
                .plan(vlnav_proto::v1::PlanRequest { instruction: answer.to_string(), backend: String::new() })
                .instrument(self.span.clone())
                .await?
                .into_inner()
        } else {
            self.replan(ctx, answer, failure).await?
        };
        let stamp = self.metrics.last_stamp;
        match resp.outcome {
            Some(plan_response::Outcome::Plan(p)) => {
                let mut plan = self.plan[..self.index.min(self.plan.len())].to_vec();
                plan.extend(p.steps);
                self.plan = plan.clone();
                self.replans += 1;
                self.awaiting = None;
                let plan_json = resp.plan_json.clone();
                let full = vlnav_proto::v1::ActionPlan { steps: plan.clone() };
                let resume = self.index as u32;
                let full2 = full.clone();
                self.emit(
                    ctx,
                    stamp,
                    Kind::Replanned(Replanned {
                        plan: Some(full),
                        plan_json: plan_json.clone(),
                        answer: answer.to_string(),
                        resume_index: resume,
                    }),
                    move |m| {
                        m.plan = Some(full2);
                        // The planner's JSON covers the revised steps (from resume_index on).
                        if resume == 0 {
                            m.plan_json = plan_json;
                        }
                        m.state = MissionState::Running as i32;
                        m.clarification = None;
                    },
                );
                Ok(Ok(plan))
            }
            Some(plan_response::Outcome::Clarification(c)) => {
                let index = self.index as u32;
                let c2 = c.clone();
                self.emit(
                    ctx,
                    stamp,
                    Kind::ClarificationNeeded(ClarificationNeeded { index, clarification: Some(c.clone()) }),
                    move |m| m.clarification = Some(c2),
                );
                if let Some(a) = self.awaiting.as_mut() {
                    a.0 = c.clone();
                }
                Ok(Err(c))
            }
            None => Err(tonic::Status::internal("the planner returned neither a plan nor a question")),
        }
    }

    async fn replan(
        &self,
        ctx: &Ctx<'_>,
        answer: &str,
        failure: String,
    ) -> Result<vlnav_proto::v1::PlanResponse, tonic::Status> {
        Ok(ctx
            .pipeline
            .planner
            .clone()
            .replan(ReplanRequest {
                instruction: self.instruction.clone(),
                plan: Some(vlnav_proto::v1::ActionPlan { steps: self.plan.clone() }),
                failed_step: self.index as u32,
                failure,
                answer: answer.to_string(),
                backend: String::new(),
            })
            .instrument(self.span.clone())
            .await?
            .into_inner())
    }

    async fn segment(&self, ctx: &Ctx<'_>, frame: &RgbdFrame) -> Result<Vec<Point3>, StageError> {
        let resp = ctx
            .pipeline
            .segmenter
            .clone()
            .segment(SegmentRequest {
                frame: Some(frame.clone()),
                classes: vec![],
                return_mask: false,
                point_stride: 0,
            })
            .await
            .map_err(stage("segmenter"))?
            .into_inner();
        Ok(resp.virtual_points)
    }

    async fn local_plan(
        &self,
        ctx: &Ctx<'_>,
        frame: &RgbdFrame,
        goal: &Goal,
        no_go: Vec<Point3>,
    ) -> Result<vlnav_proto::v1::PlanStepResponse, StageError> {
        Ok(ctx
            .pipeline
            .local_planner
            .clone()
            .plan_step(PlanStepRequest {
                robot_id: self.robot_id.clone(),
                frame: Some(depth_only(frame)),
                goal: Some(*goal),
                no_go_points: no_go,
                max_speed: 0.0,
            })
            .await
            .map_err(stage("local-planner"))?
            .into_inner())
    }

    /// The target's box in this frame, if any: a named person must match ReID.
    async fn find_box(
        &self,
        ctx: &Ctx<'_>,
        f: &FindRun,
        frame: &RgbdFrame,
        pose: &Pose2D,
        boxes: Vec<BoundingBox>,
    ) -> Result<Option<(BoundingBox, String, f32)>, StageError> {
        if boxes.is_empty() {
            return Ok(None);
        }
        if !f.person.is_empty() {
            let ids = ctx
                .pipeline
                .reid
                .clone()
                .identify(IdentifyRequest {
                    frame: Some(frame.clone()),
                    boxes: boxes.clone(),
                    threshold: 0.0,
                    name: f.person.clone(),
                })
                .await
                .map_err(stage("reid"))?
                .into_inner();
            let best = ids
                .identities
                .iter()
                .filter(|i| i.matched && i.name.eq_ignore_ascii_case(&f.person))
                .max_by(|a, b| a.similarity.total_cmp(&b.similarity));
            return Ok(
                best.and_then(|i| boxes.get(i.box_index as usize).map(|b| (b.clone(), i.name.clone(), i.similarity)))
            );
        }
        // A confirmed fixed target: the box where it projects, if it is in view.
        if f.confirmed && !f.moving {
            let view = f.fused.as_ref().and_then(|t| target_view(frame, pose, t));
            match view {
                Some(TargetView::At(u, v)) => return Ok(box_at(&boxes, u, v).map(|b| (b.clone(), String::new(), 0.0))),
                Some(TargetView::OutOfView) => return Ok(None),
                None => {}
            }
        }
        // Keep to the instance we were tracking; otherwise the most confident.
        let chosen = match f.last_center {
            Some((cx, cy)) => boxes.iter().min_by(|a, b| {
                let da = (center(a).0 - cx).hypot(center(a).1 - cy);
                let db = (center(b).0 - cx).hypot(center(b).1 - cy);
                da.total_cmp(&db)
            }),
            None => boxes.iter().max_by(|a, b| a.score.total_cmp(&b.score)),
        };
        Ok(chosen.map(|b| (b.clone(), String::new(), 0.0)))
    }

    async fn find_tick(
        &mut self,
        ctx: &Ctx<'_>,
        frame: &RgbdFrame,
        pose: &Pose2D,
    ) -> Result<(Twist2D, Option<MissionState>), StageError> {
        let stamp = frame.stamp;
        let params = ctx.params;
        let Some(Active { run: StepRun::Find(f), .. }) = self.step.as_ref() else { unreachable!() };
        let mut detector = ctx.pipeline.detector.clone();
        let detect = detector.detect(DetectRequest {
            frame: Some(frame.clone()),
            class_ids: vec![f.class_id],
            min_score: params.min_score,
        });
        let (detected, no_go) = tokio::join!(detect, self.segment(ctx, frame));
        let boxes = detected.map_err(stage("detector"))?.into_inner().boxes;
        let no_go = no_go?;
        let seen = self.find_box(ctx, f, frame, pose, boxes).await?;
        let mut observation = None;
        if let Some((b, identity, similarity)) = seen {
            let est = ctx
                .pipeline
                .subgoal
                .clone()
                .target_goal(TargetGoalRequest {
                    track_key: f.track_key.clone(),
                    frame: Some(depth_only(frame)),
                    r#box: Some(b.clone()),
                    d_s: f.d_s,
                    moving: f.moving,
                })
                .await
                .map_err(stage("subgoal"))?
                .into_inner();
            let status = EstimateStatus::try_from(est.status).unwrap_or(EstimateStatus::Unspecified);
            if matches!(status, EstimateStatus::Ok | EstimateStatus::Outlier) && est.goal.is_some() {
                observation = Some((b, identity, similarity, est));
            }
        }
        let index = self.index as u32;
        let Some(Active { run: StepRun::Find(f), .. }) = self.step.as_mut() else { unreachable!() };
        match observation {
            Some((b, identity, similarity, est)) => {
                f.unseen = 0;
                f.streak += 1;
                f.last_seen = Some(stamp);
                f.goal = est.goal;
                f.fused = est.fused_target.or(f.fused);
                f.last_center = Some(center(&b));
                if !f.confirmed && f.streak >= params.confirm_frames {
                    f.confirmed = true;
                    f.explore = Explore::Idle;
                    let seen = TargetSeen {
                        index,
                        r#box: Some(b),
                        target: est.fused_target,
                        goal: est.goal.and_then(|g| g.pose),
                        range_m: est.range_m,
                        identity,
                        identity_similarity: similarity,
                    };
                    self.emit(ctx, stamp, Kind::TargetSeen(seen), |_| {});
                }
            }
            None => {
                f.streak = 0;
                f.unseen += 1;
                if f.moving && f.confirmed && f.last_seen.is_some_and(|t| stamp - t > params.follow_lost_s) {
                    f.confirmed = false;
                }
            }
        }
        let Some(Active { run: StepRun::Find(f), .. }) = self.step.as_mut() else { unreachable!() };
        if f.confirmed {
            let goal = f.goal.expect("a confirmed target has a goal");
            if f.moving {
                let until = *f.follow_until.get_or_insert(stamp + params.follow_default_s);
                if stamp >= until {
                    self.complete_step(ctx, stamp, pose, &goal);
                    return Ok((zero(), None));
                }
                let plan = self.local_plan(ctx, frame, &goal, no_go).await?;
                let reached = plan.status == LocalPlanStatus::Reached as i32;
                // Following: being within d_s is where we want to stay, not the end.
                return Ok((if reached { zero() } else { plan.cmd.unwrap_or_default() }, None));
            }
            let plan = self.local_plan(ctx, frame, &goal, no_go).await?;
            return self.drive_outcome(ctx, stamp, pose, &goal, plan);
        }
        if f.streak > 0 || f.unseen < params.unseen_frames {
            // A candidate to confirm, or still looking from here: hold still.
            return Ok((zero(), None));
        }
        self.explore_tick(ctx, frame, pose, no_go).await
    }

    async fn explore_tick(
        &mut self,
        ctx: &Ctx<'_>,
        frame: &RgbdFrame,
        pose: &Pose2D,
        no_go: Vec<Point3>,
    ) -> Result<(Twist2D, Option<MissionState>), StageError> {
        let stamp = frame.stamp;
        let params = ctx.params;
        let index = self.index as u32;
        // Scan turn `turn` (0-based) of the look-around that began at `origin`.
        let turn_goal = |ctx: &Ctx<'_>, origin: Pose2D, turn: u32| {
            let mut subgoal = ctx.pipeline.subgoal.clone();
            let yaw = wrap(params.scan_turn_rad * f64::from(turn + 1));
            let req = MoveGoalRequest { anchor: Some(origin), f_dist: 0.0, yaw, d_s: 0.0 };
            async move { subgoal.move_goal(req).await.map(|r| r.into_inner()).map_err(stage("subgoal")) }
        };
        let Some(Active { run: StepRun::Find(f), .. }) = self.step.as_mut() else { unreachable!() };
        let state = std::mem::replace(&mut f.explore, Explore::Idle);
        let (next, twist) = match state {
            Explore::Idle => {
                let goal = turn_goal(ctx, *pose, 0).await?;
                self.emit(ctx, stamp, Kind::Exploring(Exploring { index, phase: "scan".into(), attempt: 1 }), |_| {});
                (Explore::Turn { goal, turn: 0, leg: 0, since: stamp, origin: *pose }, zero())
            }
            Explore::Turn { goal, turn, leg, since, origin } => {
                let plan = self.local_plan(ctx, frame, &goal, no_go).await?;
                // A scan turn that does not finish in time (a wheel stalled
                // short of the heading) looks from where it got to.
                if plan.status == LocalPlanStatus::Reached as i32 || stamp - since >= SCAN_TURN_LIMIT_S {
                    (Explore::Look { frames_left: params.look_frames, turn, leg, origin }, zero())
                } else {
                    (Explore::Turn { goal, turn, leg, since, origin }, plan.cmd.unwrap_or_default())
                }
            }
            Explore::Look { frames_left, turn, leg, origin } if frames_left > 1 => {
                (Explore::Look { frames_left: frames_left - 1, turn, leg, origin }, zero())
            }
            Explore::Look { turn, leg, origin, .. } => match after_look(turn, leg, params) {
                ExplorePlan::Turn(t) => (
                    Explore::Turn { goal: turn_goal(ctx, origin, t).await?, turn: t, leg, since: stamp, origin },
                    zero(),
                ),
                ExplorePlan::Search(l) => {
                    let goal = ctx
                        .pipeline
                        .subgoal
                        .clone()
                        .move_goal(MoveGoalRequest {
                            anchor: Some(*pose),
                            f_dist: params.search_leg_m,
                            yaw: 0.0,
                            d_s: 0.0,
                        })
                        .await
                        .map_err(stage("subgoal"))?
                        .into_inner();
                    self.emit(
                        ctx,
                        stamp,
                        Kind::Exploring(Exploring { index, phase: "search".into(), attempt: l }),
                        |_| {},
                    );
                    (Explore::Search { goal, leg: l, since: stamp }, zero())
                }
                ExplorePlan::Ask => {
                    let (target, person) = match self.step.as_ref().map(|s| &s.run) {
                        Some(StepRun::Find(f)) => (f.target.clone(), f.person.clone()),
                        _ => (String::new(), String::new()),
                    };
                    let who = if person.is_empty() { format!("the {target}") } else { format!("{person} ({target})") };
                    self.ask(
                        ctx,
                        stamp,
                        format!(
                            "step {}: {who} not found after looking all around and {} search leg(s)",
                            index + 1,
                            params.search_legs
                        ),
                        format!("I could not find {who}. Where should I look, or should I skip it?"),
                    );
                    return Ok((zero(), None));
                }
            },
            Explore::Search { goal, leg, since } => {
                let plan = self.local_plan(ctx, frame, &goal, no_go).await?;
                let status = LocalPlanStatus::try_from(plan.status).unwrap_or(LocalPlanStatus::Unspecified);
                let overdue = stamp - since >= params.search_leg_m / SEARCH_MIN_SPEED + SCAN_TURN_LIMIT_S;
                if overdue
                    || matches!(
                        status,
                        LocalPlanStatus::Reached | LocalPlanStatus::Blocked | LocalPlanStatus::NoProgress
                    )
                {
                    self.emit(
                        ctx,
                        stamp,
                        Kind::Exploring(Exploring { index, phase: "scan".into(), attempt: leg + 1 }),
                        |_| {},
                    );
                    (
                        Explore::Turn {
                            goal: turn_goal(ctx, *pose, 0).await?,
                            turn: 0,
                            leg,
                            since: stamp,
                            origin: *pose,
                        },
                        zero(),
                    )
                } else {
                    (Explore::Search { goal, leg, since }, plan.cmd.unwrap_or_default())
                }
            }
        };
        if let Some(Active { run: StepRun::Find(f), .. }) = self.step.as_mut() {
            f.explore = next;
        }
        Ok((twist, None))
    }

    /// The W3C trace id of this mission.
    pub fn trace_id(&self) -> String {
        use opentelemetry::trace::TraceContextExt;
        self.span.context().span().span_context().trace_id().to_string()
    }
}

fn capitalise(s: &str) -> String {
    let mut c = s.chars();
    c.next().map(|f| f.to_uppercase().collect::<String>() + c.as_str()).unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn composing_poses_follows_rep105() {
        let a = Pose2D { x: 1.0, y: 2.0, theta: std::f64::consts::FRAC_PI_2 };
        let b = Pose2D { x: 1.0, y: 0.0, theta: 0.0 };
        let c = compose(&a, &b);
        assert!((c.x - 1.0).abs() < 1e-12 && (c.y - 3.0).abs() < 1e-12);
        assert!((c.theta - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
    }

    #[test]
    fn wrap_keeps_angles_in_half_open_pi_range() {
        assert!((wrap(3.0 * std::f64::consts::PI) - std::f64::consts::PI).abs() < 1e-12);
        assert!((wrap(-std::f64::consts::PI) - std::f64::consts::PI).abs() < 1e-12);
        assert!((wrap(0.5) - 0.5).abs() < 1e-12);
    }

    #[test]
    fn a_move_after_a_move_turns_from_that_moves_course_not_the_arrival_heading() {
        // The first leg ran along +x but the robot arrived swerved 0.58 rad to the right.
        let arrived = Pose2D { x: 9.8, y: 0.1, theta: -0.58 };
        let anchor = move_anchor(&arrived, Some(0.0));
        assert_eq!((anchor.x, anchor.y, anchor.theta), (9.8, 0.1, 0.0));
        // After a FOLLOW, a RETURN or a failure there is no course: the robot's own heading counts.
        assert_eq!(move_anchor(&arrived, None).theta, -0.58);
    }

    fn frame_with_camera() -> RgbdFrame {
        RgbdFrame {
            camera: Some(vlnav_proto::v1::CameraInfo {
                width: 160,
                height: 120,
                intrinsics: Some(vlnav_proto::v1::CameraIntrinsics { fx: 80.0, fy: 80.0, cx: 80.0, cy: 60.0 }),
                mount: Some(vlnav_proto::v1::CameraMount {
                    translation: Some(Point3 { x: 0.3, y: 0.0, z: 0.5 }),
                    ..Default::default()
                }),
                ..Default::default()
            }),
            ..Default::default()
        }
    }

    fn bbox(x_min: f32, x_max: f32) -> BoundingBox {
        BoundingBox { x_min, y_min: 40.0, x_max, y_max: 80.0, class_id: 56, score: 0.9, label: "chair".into() }
    }

    #[test]
    fn a_confirmed_target_is_found_where_it_projects() {
        let frame = frame_with_camera();
        // Robot at (1, 1) facing +y; the chair 3 m ahead of it, 0.5 m high (the camera's height).
        let pose = Pose2D { x: 1.0, y: 1.0, theta: std::f64::consts::FRAC_PI_2 };
        let chair = Point3 { x: 1.0, y: 4.3, z: 0.5 };
        let Some(TargetView::At(u, v)) = target_view(&frame, &pose, &chair) else { panic!("the chair is in view") };
        assert!((u - 80.0).abs() < 0.5 && (v - 60.0).abs() < 0.5, "({u}, {v})");
        // Two chairs in the image: the one at the prediction, not the first or the most confident.
        let other = BoundingBox { score: 0.99, ..bbox(5.0, 40.0) };
        let boxes = vec![other, bbox(70.0, 95.0)];
        assert_eq!(box_at(&boxes, u, v).map(|b| b.x_min), Some(70.0));
        // Only the other chair in view: nothing is the target.
        assert_eq!(box_at(&boxes[..1], u, v), None);
        // Turned away (the chair is now on the robot's left, outside the ±45° view).
        let turned = Pose2D { theta: 0.0, ..pose };
        assert_eq!(target_view(&frame, &turned, &chair), Some(TargetView::OutOfView));
        // No camera in the frame: no prediction (the image-space rule applies).
        assert_eq!(target_view(&RgbdFrame::default(), &pose, &chair), None);
    }

    #[test]
    fn exploration_is_bounded_scan_then_search_then_ask() {
        let p = ExecutorParams { scan_turns: 3, search_legs: 1, ..Default::default() };
        assert_eq!(after_look(0, 0, &p), ExplorePlan::Turn(1));
        assert_eq!(after_look(1, 0, &p), ExplorePlan::Turn(2));
        assert_eq!(after_look(2, 0, &p), ExplorePlan::Search(1));
        assert_eq!(after_look(0, 1, &p), ExplorePlan::Turn(1));
        assert_eq!(after_look(2, 1, &p), ExplorePlan::Ask);
    }

    #[test]
    fn metrics_come_from_frame_stamps_and_ground_truth() {
        let mut m = MetricsAcc::default();
        let truth = |x: f64, len: f64, soft: u32| SimTruth {
            pose: Some(Pose2D { x, y: 0.0, theta: 0.0 }),
            path_length_m: len,
            hard_collisions: 0,
            soft_collisions: soft,
            odom_origin: Some(Pose2D::default()),
        };
        m.observe(10.0, &Pose2D { x: 0.0, y: 0.0, theta: 0.0 }, Some(&truth(0.0, 5.0, 1)));
        m.observe(10.1, &Pose2D { x: 0.3, y: 0.4, theta: 0.0 }, Some(&truth(0.5, 5.5, 1)));
        m.observe(12.0, &Pose2D { x: 0.3, y: 1.4, theta: 0.0 }, Some(&truth(0.6, 6.6, 2)));
        let p = m.to_proto(2, 3, 1, Some(&Pose2D { x: 1.0, y: 0.0, theta: 0.0 }));
        assert!((p.duration_s - 2.0).abs() < 1e-9);
        assert!((p.odom_path_length_m - 1.5).abs() < 1e-9);
        assert_eq!(p.frames, 3);
        assert!(p.has_ground_truth);
        assert!((p.true_path_length_m - 1.6).abs() < 1e-9);
        assert_eq!(p.soft_collisions, 1);
        assert!((p.final_error_m - 0.4).abs() < 1e-9);
    }
}
