//! The mission executor: the pure state machine (`machine`) over domain types
//! (`model`), and this adapter, which feeds it sensor frames, answers its
//! requests through the stage services over gRPC (`grpc`), records its events
//! in the mission store and traces each control cycle.

pub(crate) mod grpc;
pub(crate) mod machine;
pub(crate) mod model;

use tracing::Instrument;
use vlnav_proto::v1::{ActionStep, Clarification, MissionState, Twist2D};

use crate::config::ExecutorParams;
use crate::frames::CheckedFrame;
use crate::hub::Hub;
use crate::pipeline::Pipeline;
use machine::{Mission, Next, PlannerQuery, Reply, Request};

/// What the executor works with: the stages, its parameters, the mission
/// store and where else its events go.
pub(crate) struct Ctx<'a> {
    pub(crate) pipeline: &'a Pipeline,
    pub(crate) params: &'a ExecutorParams,
    pub(crate) hub: &'a Hub,
    /// Takes the mission's events besides the store.
    pub(crate) events: &'a dyn EventSink,
}

/// Where the executor's events go besides the mission store. The robot's
/// actor connects the live view and the recordings to it (`robot.rs`), so
/// data flows one way: the executor knows nothing of who reads its events
/// (docs/architecture.md, "The gateway's modules").
pub(crate) trait EventSink: Sync {
    /// Whether anyone takes events now (each is copied for it).
    fn wants_events(&self) -> bool;
    /// A mission of robot `robot_id` recorded `event`.
    fn event(&self, robot_id: &str, event: vlnav_proto::v1::MissionEvent);
}

/// What the executor tells the robot after a frame.
pub(crate) struct Tick {
    pub(crate) twist: Twist2D,
    /// False while the robot may idle (waiting for the user or for a stage).
    pub(crate) active: bool,
    /// Set when the mission reached a terminal state on this frame.
    pub(crate) finished: Option<MissionState>,
    /// The control-cycle span of this frame (parent of the edge-forward span).
    pub(crate) span: tracing::Span,
    /// What the cycle perceived and decided, for the live view and recordings.
    pub(crate) seen: Seen,
}

impl Tick {
    fn idle() -> Self {
        Tick {
            twist: Twist2D::default(),
            active: false,
            finished: None,
            span: tracing::Span::none(),
            seen: Seen::default(),
        }
    }
}

/// What one control cycle perceived and decided, gathered from the state
/// machine's requests and the stages' answers; the live view and the mission
/// recordings draw it (docs/observability.md).
#[derive(Clone, Debug, Default)]
pub(crate) struct Seen {
    /// Every box the detector returned on this frame.
    pub(crate) boxes: Vec<model::Detection>,
    /// The box handed to the estimator: the target as the executor tracks it.
    pub(crate) target: Option<model::Detection>,
    /// The segmenter's virtual obstacle points, `base_link`.
    pub(crate) no_go: Vec<[f64; 3]>,
    /// The estimator's fused target, `odom`.
    pub(crate) fused_target: Option<[f64; 3]>,
    /// The goal driven toward on this frame, `odom`.
    pub(crate) goal: Option<model::Goal>,
    /// The local planner's answer and its chosen primitive (`base_link`).
    pub(crate) drive: Option<model::DriveAnswer>,
    pub(crate) path: Vec<[f64; 2]>,
    /// A plan step began on this frame (odometry is re-anchored there).
    pub(crate) step_started: bool,
}

impl Seen {
    fn request(&mut self, request: &Request) {
        match request {
            Request::StartStep { .. } => self.step_started = true,
            Request::Locate { detection, .. } => self.target = Some(detection.clone()),
            Request::Drive { goal, .. } => self.goal = Some(*goal),
            _ => {}
        }
    }

    fn reply(&mut self, reply: &machine::Reply) {
        match reply {
            machine::Reply::Perceived { boxes, obstacles } => {
                self.boxes = boxes.clone();
                self.no_go = obstacles.no_go.iter().map(|p| [p.x, p.y, p.z]).collect();
            }
            machine::Reply::Located(estimate) => {
                self.fused_target = estimate.fused_target.map(|p| [p.x, p.y, p.z]);
            }
            machine::Reply::Driven { answer, path } => {
                self.drive = Some(answer.clone());
                self.path = path.clone();
            }
            _ => {}
        }
    }
}

/// Runs one decision of the state machine. A panic there is a bug in the
/// gateway; it must not take the robot's actor (and every later mission on
/// that robot) down with it, nor leave the mission running with nobody
/// driving it: the mission fails, saying so, and the robot is stopped.
fn guarded(machine: &mut Mission, decide: impl FnOnce(&mut Mission) -> Next) -> Next {
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| decide(machine))) {
        Ok(next) => next,
        Err(panic) => {
            let what = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "a panic".into());
            tracing::error!("the executor failed: {what}");
            machine.finish(
                model::Outcome::Failed,
                format!("the gateway's executor failed ({what}); the robot was stopped. This is a bug: please report it with the mission id"),
            );
            Next::Done(machine::Command {
                twist: model::Twist::ZERO,
                active: false,
                finished: Some(model::Outcome::Failed),
            })
        }
    }
}

/// One mission on one robot: the state machine and its trace spans.
pub(crate) struct MissionRun {
    pub(crate) mission_id: String,
    pub(crate) robot_id: String,
    machine: Mission,
    span: tracing::Span,
    /// The span of the step under way.
    step_span: tracing::Span,
    /// The step under way: its index and description.
    step: Option<(u32, String)>,
    instruction: String,
}

impl MissionRun {
    /// A run of `plan`; `awaiting` holds a question asked before execution.
    pub(crate) fn new(
        mission_id: String,
        robot_id: String,
        instruction: String,
        plan: Vec<ActionStep>,
        awaiting: Option<Clarification>,
        span: tracing::Span,
    ) -> Self {
        let plan = plan.iter().map(grpc::step_from_proto).collect();
        let question = awaiting.as_ref().map(grpc::question_from_proto);
        Self {
            machine: Mission::new(mission_id.clone(), instruction.clone(), plan, question),
            instruction,
            mission_id,
            robot_id,
            span,
            step_span: tracing::Span::none(),
            step: None,
        }
    }

    /// The step under way (index, description), once one has started.
    pub(crate) fn step(&self) -> Option<&(u32, String)> {
        self.step.as_ref()
    }

    /// The instruction as the user gave it.
    pub(crate) fn instruction(&self) -> &str {
        &self.instruction
    }

    /// The plan being executed, as the planner's contract states it.
    pub(crate) fn plan_proto(&self) -> vlnav_proto::v1::ActionPlan {
        vlnav_proto::v1::ActionPlan { steps: self.machine.plan().iter().map(grpc::step_to_proto).collect() }
    }

    /// The plan's length.
    pub(crate) fn plan_len(&self) -> usize {
        self.machine.plan().len()
    }

    pub(crate) fn is_awaiting(&self) -> bool {
        self.machine.is_awaiting()
    }

    /// Writes the machine's new events to the mission store, in order.
    /// `on_frame` leaves its last frame's events for the robot's actor to
    /// flush once it has updated what it reports of the robot.
    pub(crate) fn flush(&mut self, ctx: &Ctx<'_>) {
        self.record(ctx);
    }

    fn record(&mut self, ctx: &Ctx<'_>) {
        for stamped in self.machine.take_events() {
            let (kind, change) = grpc::event_to_proto(stamped.event);
            let shown = ctx.events.wants_events().then(|| kind.clone());
            match ctx.hub.record(&self.mission_id, stamped.stamp, Some(kind), change) {
                Ok(_) => {
                    if let Some(kind) = shown {
                        let event = vlnav_proto::v1::MissionEvent {
                            mission_id: self.mission_id.clone(),
                            seq: 0,
                            stamp: stamped.stamp,
                            kind: Some(kind),
                        };
                        ctx.events.event(&self.robot_id, event);
                    }
                }
                Err(e) => tracing::error!(mission = %self.mission_id, "cannot record event: {e}"),
            }
        }
    }

    /// Ends the mission: the user cancelled it.
    pub(crate) fn cancel(&mut self, ctx: &Ctx<'_>) {
        self.machine.cancel();
        self.record(ctx);
    }

    /// One sensor frame in, one velocity command out; `estop`: an
    /// emergency stop is engaged (the robot's last status).
    pub(crate) async fn on_frame(&mut self, ctx: &Ctx<'_>, checked: &CheckedFrame, estop: bool) -> Tick {
        let frame = checked.frame();
        if self.machine.is_awaiting() {
            return Tick::idle();
        }
        let parent = if self.machine.has_step() { self.step_span.clone() } else { self.span.clone() };
        let cycle =
            tracing::info_span!(parent: &parent, "control-cycle", frame.seq = frame.seq, frame.stamp = frame.stamp);
        let robot_id = self.robot_id.clone();
        let mut stages =
            grpc::Stages { pipeline: ctx.pipeline, robot_id: &robot_id, frame, segmented_unanswered: None };
        let mut seen = Seen::default();
        // The person boxes of the frame's last perception, shown when no FIND asked for boxes.
        let mut people = Vec::new();
        let frame_in = grpc::frame_from_proto(checked, estop);
        let mut next = guarded(&mut self.machine, |m| m.on_frame(ctx.params, frame_in));
        let command = loop {
            let request = match next {
                Next::Done(command) => break command,
                Next::Call(request) => request,
            };
            self.record(ctx);
            seen.request(&request);
            let span = match &request {
                Request::StartStep { index, action, desc, .. } => {
                    self.step = Some((*index, desc.clone()));
                    self.step_span = tracing::info_span!(parent: &self.span, "step", step.index = index, step.action = ?action, step.desc = %desc);
                    self.step_span.clone()
                }
                _ => cycle.clone(),
            };
            next = match stages.call(request).instrument(span).await {
                Ok(reply) => {
                    seen.reply(&reply);
                    if let Reply::Perceived { obstacles, .. } = &reply {
                        people.clone_from(&obstacles.people);
                    }
                    guarded(&mut self.machine, |m| m.on_reply(ctx.params, reply))
                }
                Err(failure) => {
                    if let Some(no_go) = stages.segmented_unanswered.take() {
                        seen.no_go = no_go.iter().map(|p| [p.x, p.y, p.z]).collect();
                    }
                    tracing::warn!(parent: &cycle, mission = %self.mission_id, "holding the robot: {failure}");
                    guarded(&mut self.machine, |m| m.on_stage_error(failure))
                }
            };
        };
        if seen.boxes.is_empty() {
            // Outside a FIND the detector was asked for people only.
            seen.boxes = people;
        }
        Tick {
            twist: Twist2D { linear: command.twist.linear, angular: command.twist.angular },
            active: command.active,
            finished: command.finished.map(grpc::outcome_to_proto),
            span: cycle,
            seen,
        }
    }

    /// The user's answer: the planner revises the steps from the one that
    /// failed on. Returns the revised full plan, or a further question.
    pub(crate) async fn answer(
        &mut self,
        ctx: &Ctx<'_>,
        answer: &str,
    ) -> Result<Result<Vec<ActionStep>, Clarification>, tonic::Status> {
        let query =
            self.machine.planner_query(answer).map_err(|e| tonic::Status::failed_precondition(e.to_string()))?;
        let mut planner = ctx.pipeline.planner.clone();
        let response = match query {
            PlannerQuery::Plan { instruction } => {
                planner
                    .plan(vlnav_proto::v1::PlanRequest { instruction, backend: String::new() })
                    .instrument(self.span.clone())
                    .await
            }
            PlannerQuery::Replan { instruction, plan, failed_step, failure, answer } => {
                planner
                    .replan(vlnav_proto::v1::ReplanRequest {
                        instruction,
                        plan: Some(vlnav_proto::v1::ActionPlan {
                            steps: plan.iter().map(grpc::step_to_proto).collect(),
                        }),
                        failed_step,
                        failure,
                        answer,
                        backend: String::new(),
                    })
                    .instrument(self.span.clone())
                    .await
            }
        }?
        .into_inner();
        let result = self.machine.on_planner_reply(answer, grpc::planner_reply(response)?);
        self.record(ctx);
        Ok(result.map(|plan| plan.iter().map(grpc::step_to_proto).collect()).map_err(|q| grpc::question_to_proto(&q)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use model::{Event, Outcome, Twist};

    #[test]
    fn a_panic_in_the_state_machine_fails_the_mission_and_stops_the_robot() {
        let mut m = Mission::new("m-1".into(), "go".into(), Vec::new(), None);
        let next = guarded(&mut m, |_| panic!("index out of bounds"));
        let Next::Done(command) = next else { panic!("a command is returned") };
        assert_eq!((command.twist, command.active, command.finished), (Twist::ZERO, false, Some(Outcome::Failed)));
        let finished: Vec<_> = m
            .take_events()
            .into_iter()
            .filter_map(|e| match e.event {
                Event::Finished { outcome, reason, .. } => Some((outcome, reason)),
                _ => None,
            })
            .collect();
        assert_eq!(finished.len(), 1);
        assert_eq!(finished[0].0, Outcome::Failed);
        assert!(
            finished[0].1.contains("index out of bounds") && finished[0].1.contains("robot was stopped"),
            "{finished:?}"
        );
    }
}
