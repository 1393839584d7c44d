//! The state machine's port to the stage services: each [`Request`] becomes
//! the gRPC calls that answer it, and every generated type is converted here,
//! once, at the edge.

use std::time::Duration;

use nalgebra::Vector3;
use vlnav_proto::v1 as pb;

use vlnav_geometry::convert::{self, goal_to_proto, pose_to_proto};

use super::machine::{MoveQuery, PlannerReply, Reply, Request, StageFailure};
use super::model::*;
use crate::frames::CheckedFrame;
use crate::pipeline::{KnownInputs, Pipeline};

/// A stage's error status as the mission's failure: a call past its
/// deadline says how long it was waited for.
fn stage(stage: &'static str, deadline: Duration) -> impl FnOnce(tonic::Status) -> StageFailure {
    move |s| {
        let past_deadline = s.code() == tonic::Code::DeadlineExceeded
            || (s.code() == tonic::Code::Cancelled && s.message().contains("Timeout expired"));
        let message = if past_deadline {
            format!("it did not answer within {:.1} s (--stage-timeout-s)", deadline.as_secs_f64())
        } else {
            s.message().to_string()
        };
        StageFailure { stage, message }
    }
}

/// The stages, over gRPC, for one robot and one frame.
pub(crate) struct Stages<'a> {
    pub(crate) pipeline: &'a Pipeline,
    pub(crate) robot_id: &'a str,
    pub(crate) frame: &'a pb::RgbdFrame,
    /// The segmenter's points of a `Perceive` whose detection then failed:
    /// the machine gets no reply, but the live view still shows them.
    pub(crate) segmented_unanswered: Option<Vec<Vector3<f64>>>,
}

impl Stages<'_> {
    /// `message` as a request with the stage deadline: the channel ends the
    /// call at the deadline (tonic enforces `grpc-timeout` on the client
    /// side too), and the stage sees it.
    fn deadline<T>(&self, message: T) -> tonic::Request<T> {
        let mut request = tonic::Request::new(message);
        request.set_timeout(self.pipeline.stage_timeout);
        request
    }

    /// `stage`'s error mapping, naming this pipeline's deadline.
    fn failed(&self, name: &'static str) -> impl FnOnce(tonic::Status) -> StageFailure + use<> {
        stage(name, self.pipeline.stage_timeout)
    }

    pub(crate) async fn call(&mut self, request: Request) -> Result<Reply, StageFailure> {
        let pipeline = self.pipeline;
        match request {
            Request::StartStep { move_goal, forget, .. } => {
                if forget {
                    pipeline
                        .local_planner
                        .clone()
                        .reset_robot(self.deadline(pb::ResetRobotRequest { robot_id: self.robot_id.to_string() }))
                        .await
                        .map_err(self.failed("local-planner"))?;
                }
                let goal = match move_goal {
                    Some(q) => Some(self.move_goal(q).await?),
                    None => None,
                };
                Ok(Reply::StepStarted { goal })
            }
            Request::Perceive { detect } => {
                // A FIND asks for every class (the machine weighs other
                // classes' boxes against the target's); otherwise people
                // only, at the detector's default score, for the local
                // planner to track (services/local-planner/src/people.rs).
                let (class_ids, min_score) = match detect {
                    Some((_, min_score)) => (vec![], min_score),
                    None => (vec![PERSON_CLASS], 0.0),
                };
                let detected = async {
                    let ask = |inputs: &pb::FrameInputs| {
                        let frame = Some(frame_with(self.frame, inputs));
                        let request =
                            self.deadline(pb::DetectRequest { frame, class_ids: class_ids.clone(), min_score });
                        let mut detector = pipeline.detector.clone();
                        async move { detector.detect(request).await }
                    };
                    self.with_inputs(&pipeline.detector_inputs, || self.detector_inputs(), ask).await
                };
                let (detected, no_go) = tokio::join!(detected, self.segment());
                let no_go: Vec<Vector3<f64>> = no_go?.iter().map(|p| Vector3::new(p.x, p.y, p.z)).collect();
                let boxes = match (detected, detect) {
                    (Ok(d), _) => d.into_inner().boxes,
                    (Err(s), Some(_)) => {
                        self.segmented_unanswered = Some(no_go);
                        return Err(self.failed("detector")(s));
                    }
                    // Driving needs only depth: without the detector the
                    // robot goes on without knowing who is a person.
                    (Err(s), None) => {
                        let failure = self.failed("detector")(s);
                        tracing::warn!(robot = self.robot_id, "driving without person boxes: {failure}");
                        Vec::new()
                    }
                };
                let people = boxes.iter().filter(|b| b.class_id == PERSON_CLASS).map(detection_from_proto).collect();
                let boxes =
                    if detect.is_some() { boxes.iter().map(detection_from_proto).collect() } else { Vec::new() };
                Ok(Reply::Perceived { boxes, obstacles: Obstacles { no_go, people } })
            }
            Request::Identify { boxes, name } => {
                let identities = pipeline
                    .reid
                    .clone()
                    .identify(self.deadline(pb::IdentifyRequest {
                        frame: Some(self.frame.clone()),
                        boxes: boxes.iter().map(detection_to_proto).collect(),
                        threshold: 0.0,
                        name,
                    }))
                    .await
                    .map_err(self.failed("reid"))?
                    .into_inner()
                    .identities;
                Ok(Reply::Identified(
                    identities
                        .into_iter()
                        .map(|i| Identity {
                            box_index: i.box_index,
                            name: i.name,
                            similarity: i.similarity,
                            matched: i.matched,
                        })
                        .collect(),
                ))
            }
            Request::Locate { track_key, detection, d_s, moving } => {
                let est = pipeline
                    .subgoal
                    .clone()
                    .target_goal(self.deadline(pb::TargetGoalRequest {
                        track_key,
                        frame: Some(depth_only(self.frame)),
                        r#box: Some(detection_to_proto(&detection)),
                        d_s,
                        moving,
                    }))
                    .await
                    .map_err(self.failed("subgoal"))?
                    .into_inner();
                let status = match pb::EstimateStatus::try_from(est.status) {
                    Ok(pb::EstimateStatus::Ok) => EstimateStatus::Ok,
                    Ok(pb::EstimateStatus::NoDepth) => EstimateStatus::NoDepth,
                    Ok(pb::EstimateStatus::Outlier) => EstimateStatus::Outlier,
                    _ => EstimateStatus::Unspecified,
                };
                Ok(Reply::Located(Estimate {
                    status,
                    goal: est.goal.as_ref().map(goal_from_proto).transpose()?,
                    fused_target: est.fused_target.map(|p| Vector3::new(p.x, p.y, p.z)),
                    observed: est.observed_target.map(|p| Vector3::new(p.x, p.y, p.z)),
                    range_m: est.range_m,
                }))
            }
            Request::MoveGoal(q) => Ok(Reply::Goal(self.move_goal(q).await?)),
            Request::Drive { goal, obstacles } => {
                let plan = pipeline
                    .local_planner
                    .clone()
                    .plan_step(self.deadline(pb::PlanStepRequest {
                        robot_id: self.robot_id.to_string(),
                        frame: Some(depth_only(self.frame)),
                        goal: Some(goal_to_proto(&goal)),
                        no_go_points: obstacles.no_go.iter().map(|p| pb::Point3 { x: p.x, y: p.y, z: p.z }).collect(),
                        max_speed: 0.0,
                        people: obstacles.people.iter().map(detection_to_proto).collect(),
                    }))
                    .await
                    .map_err(self.failed("local-planner"))?
                    .into_inner();
                let status = match pb::LocalPlanStatus::try_from(plan.status) {
                    Ok(pb::LocalPlanStatus::Moving) => DriveStatus::Moving,
                    Ok(pb::LocalPlanStatus::Rotating) => DriveStatus::Rotating,
                    Ok(pb::LocalPlanStatus::Reached) => DriveStatus::Reached,
                    Ok(pb::LocalPlanStatus::Blocked) => DriveStatus::Blocked,
                    Ok(pb::LocalPlanStatus::NoProgress) => DriveStatus::NoProgress,
                    Ok(pb::LocalPlanStatus::Waiting) => DriveStatus::Waiting,
                    _ => DriveStatus::Unspecified,
                };
                let answer = DriveAnswer {
                    status,
                    cmd: plan.cmd.map_or(Twist::ZERO, |c| Twist { linear: c.linear, angular: c.angular }),
                    path_id: plan.path_id,
                    distance_to_goal: plan.distance_to_goal,
                    heading_error: plan.heading_error,
                    free_paths: plan.free_paths,
                    frontier: plan.frontier.iter().map(|f| [f.x, f.y]).collect(),
                };
                Ok(Reply::Driven { answer, path: plan.path.iter().map(|p| [p.x, p.y]).collect() })
            }
        }
    }

    async fn move_goal(&self, q: MoveQuery) -> Result<Goal, StageFailure> {
        let goal = self
            .pipeline
            .subgoal
            .clone()
            .move_goal(self.deadline(pb::MoveGoalRequest {
                anchor: Some(pose_to_proto(&q.anchor)),
                f_dist: q.f_dist,
                yaw: q.yaw,
                d_s: q.d_s,
            }))
            .await
            .map_err(self.failed("subgoal"))?
            .into_inner();
        goal_from_proto(&goal)
    }

    async fn segment(&self) -> Result<Vec<pb::Point3>, StageFailure> {
        let ask = |inputs: &pb::FrameInputs| {
            let request = self.deadline(pb::SegmentRequest {
                frame: Some(frame_with(self.frame, inputs)),
                classes: vec![],
                return_mask: false,
                point_stride: 0,
            });
            let mut segmenter = self.pipeline.segmenter.clone();
            async move { segmenter.segment(request).await }
        };
        let segmented = self.with_inputs(&self.pipeline.segmenter_inputs, || self.segmenter_inputs(), ask).await;
        Ok(segmented.map_err(self.failed("segmenter"))?.into_inner().virtual_points)
    }

    /// What the detector reads of a frame (asked once, then kept).
    async fn detector_inputs(&self) -> Result<Option<pb::FrameInputs>, tonic::Status> {
        let info = self.pipeline.detector.clone().get_model_info(self.deadline(pb::GetModelInfoRequest {})).await?;
        Ok(info.into_inner().inputs)
    }

    /// What the segmenter reads of a frame (asked once, then kept).
    async fn segmenter_inputs(&self) -> Result<Option<pb::FrameInputs>, tonic::Status> {
        let info =
            self.pipeline.segmenter.clone().get_segmenter_info(self.deadline(pb::GetSegmenterInfoRequest {})).await?;
        Ok(info.into_inner().inputs)
    }

    /// Calls a frame-reading stage with only the parts of the frame it
    /// reads: `known` holds what it said it reads, `ask_inputs` asks it when
    /// that is not known yet, `call` makes the call with a frame cut to
    /// those parts. A stage that cannot say (it is not up, or predates the
    /// question) gets the whole frame, and is asked again next time unless
    /// it does not know the question. A stage that refuses a cut frame as
    /// invalid (its backend changed since it said) gets the whole frame at
    /// once, and is asked again next time: no frame is lost to it.
    async fn with_inputs<T, A, C, F>(
        &self,
        known: &KnownInputs,
        ask_inputs: impl FnOnce() -> A,
        call: C,
    ) -> Result<tonic::Response<T>, tonic::Status>
    where
        A: Future<Output = Result<Option<pb::FrameInputs>, tonic::Status>>,
        C: Fn(&pb::FrameInputs) -> F,
        F: Future<Output = Result<tonic::Response<T>, tonic::Status>>,
    {
        let inputs = match known.get() {
            Some(inputs) => inputs,
            None => match ask_inputs().await {
                Ok(said) => {
                    let inputs = said.unwrap_or(ALL_INPUTS);
                    known.set(Some(inputs));
                    inputs
                }
                Err(s) => {
                    if s.code() == tonic::Code::Unimplemented {
                        known.set(Some(ALL_INPUTS));
                    }
                    ALL_INPUTS
                }
            },
        };
        match call(&inputs).await {
            Err(s) if s.code() == tonic::Code::InvalidArgument && inputs != ALL_INPUTS => {
                tracing::info!(
                    robot = self.robot_id,
                    "a stage refused a frame cut to the inputs it said it reads ({}); sending it whole, and asking again",
                    s.message()
                );
                known.set(None);
                call(&ALL_INPUTS).await
            }
            other => other,
        }
    }
}

/// A frame's every part: what a stage that has not said what it reads gets.
const ALL_INPUTS: pb::FrameInputs = pb::FrameInputs { rgb: true, depth: true, labels: true };

/// The frame with only `inputs` of its images (camera, stamp and
/// odometry always): shared buffers, not copies.
fn frame_with(f: &pb::RgbdFrame, inputs: &pb::FrameInputs) -> pb::RgbdFrame {
    pb::RgbdFrame {
        robot_id: f.robot_id.clone(),
        seq: f.seq,
        stamp: f.stamp,
        camera: f.camera,
        rgb: if inputs.rgb { f.rgb.clone() } else { None },
        depth: if inputs.depth { f.depth.clone() } else { None },
        odom: f.odom,
        odom_twist: f.odom_twist,
        labels: if inputs.labels { f.labels.clone() } else { None },
    }
}

/// The frame with only what geometry needs (depth, camera, pose).
fn depth_only(f: &pb::RgbdFrame) -> pb::RgbdFrame {
    frame_with(f, &pb::FrameInputs { rgb: false, depth: true, labels: false })
}

/// A pose the robot reported (a frame's odometry, a goal the robot was
/// given): the edge agent's frame checks (`gateway/src/frames.rs`) have
/// already refused non-finite ones.
fn pose_from_proto(p: &pb::Pose2D) -> Pose2 {
    Pose2::new(p.x, p.y, p.theta)
}

/// A goal from the subgoal service, checked.
fn goal_from_proto(g: &pb::Goal) -> Result<Goal, StageFailure> {
    convert::goal_from_proto(Some(g), "goal")
        .map_err(|e| StageFailure { stage: "subgoal", message: format!("it returned an unusable goal: {e}") })
}

pub(crate) fn detection_from_proto(b: &pb::BoundingBox) -> Detection {
    Detection {
        x_min: b.x_min,
        y_min: b.y_min,
        x_max: b.x_max,
        y_max: b.y_max,
        class_id: b.class_id,
        score: b.score,
        label: b.label.clone(),
    }
}

fn detection_to_proto(b: &Detection) -> pb::BoundingBox {
    pb::BoundingBox {
        x_min: b.x_min,
        y_min: b.y_min,
        x_max: b.x_max,
        y_max: b.y_max,
        class_id: b.class_id,
        score: b.score,
        label: b.label.clone(),
    }
}

/// What the state machine sees of a checked sensor frame.
pub(crate) fn frame_from_proto(checked: &CheckedFrame, estop: bool) -> Frame {
    let f = checked.frame();
    Frame {
        estop,
        stamp: f.stamp,
        pose: f.odom.as_ref().map(pose_from_proto).unwrap_or_default(),
        camera: Some(*checked.camera()),
        truth: checked.truth().map(|t| Truth {
            pose: t.pose.as_ref().map(pose_from_proto),
            path_length_m: t.path_length_m,
            hard_collisions: t.hard_collisions,
            soft_collisions: t.soft_collisions,
            odom_origin: t.odom_origin.as_ref().map(pose_from_proto),
        }),
    }
}

pub(crate) fn action_from_proto(a: i32) -> Action {
    match pb::ActionKind::try_from(a) {
        Ok(pb::ActionKind::Move) => Action::Move,
        Ok(pb::ActionKind::Find) => Action::Find,
        Ok(pb::ActionKind::Follow) => Action::Follow,
        Ok(pb::ActionKind::Return) => Action::Return,
        _ => Action::Unspecified,
    }
}

fn action_to_proto(a: Action) -> pb::ActionKind {
    match a {
        Action::Move => pb::ActionKind::Move,
        Action::Find => pb::ActionKind::Find,
        Action::Follow => pb::ActionKind::Follow,
        Action::Return => pb::ActionKind::Return,
        Action::Unspecified => pb::ActionKind::Unspecified,
    }
}

pub(crate) fn step_from_proto(s: &pb::ActionStep) -> PlanStep {
    PlanStep {
        action: action_from_proto(s.action),
        desc: s.desc.clone(),
        f_dist: s.f_dist,
        yaw: s.yaw,
        target: s.target.clone(),
        class_id: s.class_id,
        person: s.person.clone(),
        d_s: s.d_s,
        duration_s: s.duration_s,
        reference: s.reference.as_ref().map(|r| TargetReference {
            relation: r.relation.clone(),
            target: r.target.clone(),
            class_id: r.class_id,
        }),
        source: s.source.clone(),
    }
}

pub(crate) fn step_to_proto(s: &PlanStep) -> pb::ActionStep {
    pb::ActionStep {
        action: action_to_proto(s.action) as i32,
        desc: s.desc.clone(),
        f_dist: s.f_dist,
        yaw: s.yaw,
        target: s.target.clone(),
        class_id: s.class_id,
        person: s.person.clone(),
        d_s: s.d_s,
        duration_s: s.duration_s,
        reference: s.reference.as_ref().map(|r| pb::TargetReference {
            relation: r.relation.clone(),
            target: r.target.clone(),
            class_id: r.class_id,
        }),
        source: s.source.clone(),
    }
}

pub(crate) fn question_from_proto(c: &pb::Clarification) -> Question {
    Question { question: c.question.clone(), reason: c.reason.clone(), options: c.options.clone() }
}

pub(crate) fn question_to_proto(q: &Question) -> pb::Clarification {
    pb::Clarification { question: q.question.clone(), reason: q.reason.clone(), options: q.options.clone() }
}

pub(crate) fn outcome_to_proto(o: Outcome) -> pb::MissionState {
    match o {
        Outcome::Succeeded => pb::MissionState::Succeeded,
        Outcome::Failed => pb::MissionState::Failed,
        Outcome::Cancelled => pb::MissionState::Cancelled,
    }
}

fn metrics_to_proto(m: &Metrics) -> pb::MissionMetrics {
    pb::MissionMetrics {
        duration_s: m.duration_s,
        odom_path_length_m: m.odom_path_length_m,
        steps_completed: m.steps_completed,
        steps_total: m.steps_total,
        frames: m.frames,
        replans: m.replans,
        has_ground_truth: m.has_ground_truth,
        true_path_length_m: m.true_path_length_m,
        hard_collisions: m.hard_collisions,
        soft_collisions: m.soft_collisions,
        final_error_m: m.final_error_m,
    }
}

/// The planner's response as the state machine takes it.
pub(crate) fn planner_reply(resp: pb::PlanResponse) -> Result<PlannerReply, tonic::Status> {
    match resp.outcome {
        Some(pb::plan_response::Outcome::Plan(p)) => {
            Ok(PlannerReply::Plan { steps: p.steps.iter().map(step_from_proto).collect(), plan_json: resp.plan_json })
        }
        Some(pb::plan_response::Outcome::Clarification(c)) => Ok(PlannerReply::Question(question_from_proto(&c))),
        None => Err(tonic::Status::internal("the planner returned neither a plan nor a question")),
    }
}

/// A mission-record change that comes with an event.
pub(crate) type Change = Box<dyn FnOnce(&mut pb::Mission) + Send>;

/// An event as the mission store records it, with the change it makes to the mission.
pub(crate) fn event_to_proto(event: Event) -> (pb::mission_event::Kind, Change) {
    use pb::mission_event::Kind;
    match event {
        Event::StepStarted { index, step, anchor } => (
            Kind::StepStarted(pb::StepStarted {
                index,
                step: Some(step_to_proto(&step)),
                anchor: Some(pose_to_proto(&anchor)),
            }),
            Box::new(move |m| {
                m.current_step = index;
                m.state = pb::MissionState::Running as i32;
            }),
        ),
        Event::TargetSeen { index, detection, target, goal, range_m, identity, identity_similarity } => (
            Kind::TargetSeen(pb::TargetSeen {
                index,
                r#box: Some(detection_to_proto(&detection)),
                target: target.map(|t| pb::Point3 { x: t.x, y: t.y, z: t.z }),
                goal: goal.as_ref().map(pose_to_proto),
                range_m,
                identity,
                identity_similarity,
            }),
            Box::new(|_| {}),
        ),
        Event::Exploring { index, phase, attempt } => {
            let phase = match phase {
                ExplorePhase::Scan => "scan",
                ExplorePhase::Search => "search",
                ExplorePhase::Revisit => "revisit",
            };
            (Kind::Exploring(pb::Exploring { index, phase: phase.into(), attempt }), Box::new(|_| {}))
        }
        Event::SubgoalReached { index, pose, goal, error_m } => (
            Kind::SubgoalReached(pb::SubgoalReached {
                index,
                pose: Some(pose_to_proto(&pose)),
                goal: Some(pose_to_proto(&goal)),
                error_m,
            }),
            Box::new(move |m| m.current_step = index + 1),
        ),
        Event::StepFailed { index, reason } => (Kind::StepFailed(pb::StepFailed { index, reason }), Box::new(|_| {})),
        Event::ClarificationNeeded { index, question } => {
            let c = question_to_proto(&question);
            let c2 = c.clone();
            (
                Kind::ClarificationNeeded(pb::ClarificationNeeded { index, clarification: Some(c) }),
                Box::new(move |m| {
                    m.state = pb::MissionState::AwaitingClarification as i32;
                    m.clarification = Some(c2);
                }),
            )
        }
        Event::Replanned { plan, plan_json, answer, resume_index } => {
            let full = pb::ActionPlan { steps: plan.iter().map(step_to_proto).collect() };
            let (full2, json2) = (full.clone(), plan_json.clone());
            (
                Kind::Replanned(pb::Replanned { plan: Some(full), plan_json, answer, resume_index }),
                Box::new(move |m| {
                    m.plan = Some(full2);
                    // The planner's JSON covers the revised steps (from resume_index on).
                    if resume_index == 0 {
                        m.plan_json = json2;
                    }
                    m.state = pb::MissionState::Running as i32;
                    m.clarification = None;
                }),
            )
        }
        Event::Finished { outcome, reason, metrics, current_step } => (
            Kind::Finished(pb::Finished {
                state: outcome_to_proto(outcome) as i32,
                reason,
                metrics: Some(metrics_to_proto(&metrics)),
            }),
            Box::new(move |m| m.current_step = current_step),
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_machine_reads_the_checked_frame_with_the_camera_its_check_read() {
        let f = crate::frames::tests::frame(8, 6);
        let checked = CheckedFrame::check(pb::SensorFrame { frame: Some(f.clone()), truth: None }, None).unwrap();
        let seen = frame_from_proto(&checked, false);
        assert_eq!(seen.stamp, f.stamp);
        let camera = convert::camera_from_proto(f.camera.as_ref(), "frame.camera", convert::DepthDefaults::UNSET);
        assert_eq!(seen.camera, Some(camera.unwrap()));
    }

    use std::sync::Mutex;

    fn pipeline() -> Pipeline {
        let ports = crate::config::StagePorts {
            ingress: 1,
            planner: 1,
            detector: 1,
            reid: 1,
            segmenter: 1,
            subgoal: 1,
            local_planner: 1,
        };
        Pipeline::connect(&crate::config::GatewayOptions::loopback(&ports, std::env::temp_dir())).unwrap()
    }

    const COLOUR: pb::FrameInputs = pb::FrameInputs { rgb: true, depth: true, labels: false };

    /// A stage that reads `reads`: it refuses, as invalid, a frame cut to
    /// less, and records what each call was sent.
    fn stage<'a>(
        reads: pb::FrameInputs,
        sent: &'a Mutex<Vec<pb::FrameInputs>>,
    ) -> impl Fn(&pb::FrameInputs) -> std::future::Ready<Result<tonic::Response<()>, tonic::Status>> + 'a {
        move |inputs: &pb::FrameInputs| {
            sent.lock().unwrap().push(*inputs);
            let enough =
                (inputs.rgb || !reads.rgb) && (inputs.depth || !reads.depth) && (inputs.labels || !reads.labels);
            std::future::ready(if enough {
                Ok(tonic::Response::new(()))
            } else {
                Err(tonic::Status::invalid_argument("frame.rgb is required by this backend"))
            })
        }
    }

    #[test]
    fn a_frame_cut_to_a_stages_inputs_shares_their_buffers_and_keeps_camera_stamp_and_pose() {
        let f = crate::frames::tests::frame(8, 6);
        let cut = frame_with(&f, &pb::FrameInputs { rgb: false, depth: true, labels: false });
        assert!(cut.rgb.is_none() && cut.labels.is_none());
        let (depth, whole) = (&cut.depth.as_ref().unwrap().data_mm, &f.depth.as_ref().unwrap().data_mm);
        assert_eq!(depth.as_ptr(), whole.as_ptr(), "shared, not copied");
        assert_eq!((cut.camera, cut.stamp, cut.seq, cut.odom), (f.camera, f.stamp, f.seq, f.odom));
        assert_eq!(frame_with(&f, &ALL_INPUTS), f);
    }

    #[tokio::test]
    async fn a_stage_is_asked_once_what_it_reads_and_then_sent_only_that() {
        let (pipeline, f) = (pipeline(), crate::frames::tests::frame(8, 6));
        let stages = Stages { pipeline: &pipeline, robot_id: "husky-1", frame: &f, segmented_unanswered: None };
        let (known, sent, asked) = (KnownInputs::default(), Mutex::new(Vec::new()), Mutex::new(0));
        for _ in 0..3 {
            let ask = || async {
                *asked.lock().unwrap() += 1;
                Ok(Some(COLOUR))
            };
            stages.with_inputs(&known, ask, stage(COLOUR, &sent)).await.unwrap();
        }
        assert_eq!(*asked.lock().unwrap(), 1);
        assert_eq!(*sent.lock().unwrap(), vec![COLOUR; 3]);
    }

    #[tokio::test]
    async fn a_stage_that_refuses_a_cut_frame_gets_it_whole_at_once_and_is_asked_again() {
        let (pipeline, f) = (pipeline(), crate::frames::tests::frame(8, 6));
        let stages = Stages { pipeline: &pipeline, robot_id: "husky-1", frame: &f, segmented_unanswered: None };
        // It said labels and depth, then its backend became the colour one.
        let (known, sent) = (KnownInputs::default(), Mutex::new(Vec::new()));
        known.set(Some(pb::FrameInputs { rgb: false, depth: true, labels: true }));
        let never = || async { panic!("not asked while known") };
        stages.with_inputs(&known, never, stage(COLOUR, &sent)).await.expect("answered: no frame lost");
        assert_eq!(sent.lock().unwrap().last(), Some(&ALL_INPUTS));
        assert_eq!(known.get(), None, "asked again next time");
        // An error that is not about the frame is the stage's answer, not retried.
        let (known, sent) = (KnownInputs::default(), Mutex::new(Vec::new()));
        known.set(Some(COLOUR));
        let down = |_: &pb::FrameInputs| {
            sent.lock().unwrap().push(COLOUR);
            std::future::ready(Err::<tonic::Response<()>, _>(tonic::Status::unavailable("down")))
        };
        let err = stages.with_inputs(&known, never, down).await.unwrap_err();
        assert_eq!((err.code(), sent.lock().unwrap().len()), (tonic::Code::Unavailable, 1));
    }

    #[tokio::test]
    async fn a_stage_that_cannot_say_gets_whole_frames_and_is_asked_again_unless_it_lacks_the_question() {
        let (pipeline, f) = (pipeline(), crate::frames::tests::frame(8, 6));
        let stages = Stages { pipeline: &pipeline, robot_id: "husky-1", frame: &f, segmented_unanswered: None };
        let sent = Mutex::new(Vec::new());
        let everything = pb::FrameInputs { rgb: true, depth: true, labels: true };
        for (answer, kept) in [
            (Err(tonic::Status::unavailable("starting")), None),
            (Err(tonic::Status::unimplemented("an older stage")), Some(ALL_INPUTS)),
            (Ok(None), Some(ALL_INPUTS)),
        ] {
            let known = KnownInputs::default();
            let ask = || std::future::ready(answer);
            stages.with_inputs(&known, ask, stage(everything, &sent)).await.unwrap();
            assert_eq!(sent.lock().unwrap().last(), Some(&ALL_INPUTS));
            assert_eq!(known.get(), kept);
        }
    }
}
