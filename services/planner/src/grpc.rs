//! The tonic layer: validate, convert proto ↔ domain, call the actor.

use std::sync::Arc;

use tonic::{Request, Response, Status};
use vlnav_proto::v1 as pb;
use vlnav_runtime::actor::Mailbox;

use crate::actor::Msg;
use crate::plan::{Action, Clarification, Outcome, Plan, Planned, Reference, Step};
use crate::planner::PlanError;
use crate::validate::{PLAN_SCHEMA, Validator};

pub struct PlannerGrpc {
    mailbox: Mailbox<Msg>,
    validator: Arc<Validator>,
}

impl PlannerGrpc {
    pub fn new(mailbox: Mailbox<Msg>, validator: Arc<Validator>) -> Self {
        PlannerGrpc { mailbox, validator }
    }
}

impl From<PlanError> for Status {
    fn from(e: PlanError) -> Status {
        match &e {
            PlanError::Input(_) | PlanError::UnknownBackend(_) | PlanError::InvalidPlan(_) | PlanError::Replan(_) => {
                Status::invalid_argument(e.to_string())
            }
            PlanError::Unavailable(_) => Status::failed_precondition(e.to_string()),
        }
    }
}

pub fn step_to_proto(s: &Step) -> pb::ActionStep {
    pb::ActionStep {
        action: match s.action {
            Action::Move => pb::ActionKind::Move,
            Action::Find => pb::ActionKind::Find,
            Action::Follow => pb::ActionKind::Follow,
            Action::Return => pb::ActionKind::Return,
        } as i32,
        desc: s.desc.clone(),
        f_dist: s.f_dist,
        yaw: s.yaw,
        target: s.target.clone(),
        class_id: s.class_id,
        person: s.person.clone().unwrap_or_default(),
        d_s: s.d_s.unwrap_or(0.0),
        duration_s: s.duration_s.unwrap_or(0.0),
        reference: s.reference.as_ref().map(|r| pb::TargetReference {
            relation: r.relation.clone(),
            target: r.target.clone(),
            class_id: r.class_id,
        }),
        source: s.source.clone(),
    }
}

pub fn plan_to_proto(p: &Plan) -> pb::ActionPlan {
    pb::ActionPlan { steps: p.steps.iter().map(step_to_proto).collect() }
}

/// Proto plan → domain plan; an unset action names the offending field.
pub fn plan_from_proto(p: &pb::ActionPlan) -> Result<Plan, Status> {
    let mut steps = Vec::with_capacity(p.steps.len());
    for (i, s) in p.steps.iter().enumerate() {
        let action = match pb::ActionKind::try_from(s.action) {
            Ok(pb::ActionKind::Move) => Action::Move,
            Ok(pb::ActionKind::Find) => Action::Find,
            Ok(pb::ActionKind::Follow) => Action::Follow,
            Ok(pb::ActionKind::Return) => Action::Return,
            _ => {
                return Err(Status::invalid_argument(format!(
                    "plan.steps[{i}].action: {} is not one of MOVE, FIND, FOLLOW, RETURN",
                    s.action
                )));
            }
        };
        let keyed = matches!(action, Action::Find | Action::Follow);
        steps.push(Step {
            action,
            desc: s.desc.clone(),
            f_dist: s.f_dist,
            yaw: s.yaw,
            target: if keyed { s.target.clone() } else { String::new() },
            class_id: if keyed { s.class_id } else { 0 },
            person: (keyed && !s.person.is_empty()).then(|| s.person.clone()),
            d_s: (keyed && s.d_s != 0.0).then_some(s.d_s),
            duration_s: (action == Action::Follow && s.duration_s != 0.0).then_some(s.duration_s),
            reference: s.reference.as_ref().filter(|_| keyed).map(|r| Reference {
                relation: r.relation.clone(),
                target: r.target.clone(),
                class_id: r.class_id,
            }),
            source: s.source.clone(),
        });
    }
    Ok(Plan::new(steps))
}

fn clarification_to_proto(c: &Clarification) -> pb::Clarification {
    pb::Clarification { question: c.question.clone(), reason: c.reason.clone(), options: c.options.clone() }
}

fn response(p: Planned) -> pb::PlanResponse {
    let plan_json = p.plan_json();
    let outcome = match &p.outcome {
        Outcome::Plan(plan) => pb::plan_response::Outcome::Plan(plan_to_proto(plan)),
        Outcome::Clarify(c) => pb::plan_response::Outcome::Clarification(clarification_to_proto(c)),
    };
    pb::PlanResponse { outcome: Some(outcome), plan_json, backend: p.backend, notes: p.notes, ungrounded: p.ungrounded }
}

#[tonic::async_trait]
impl pb::planner_service_server::PlannerService for PlannerGrpc {
    async fn plan(&self, request: Request<pb::PlanRequest>) -> Result<Response<pb::PlanResponse>, Status> {
        let r = request.into_inner();
        let planned =
            self.mailbox.call(|reply| Msg::Plan { instruction: r.instruction, backend: r.backend, reply }).await??;
        Ok(Response::new(response(planned)))
    }

    async fn replan(&self, request: Request<pb::ReplanRequest>) -> Result<Response<pb::PlanResponse>, Status> {
        let r = request.into_inner();
        let plan = plan_from_proto(&r.plan.unwrap_or_default())?;
        if plan.steps.is_empty() {
            return Err(Status::invalid_argument("plan: the plan to revise has no steps"));
        }
        let planned = self
            .mailbox
            .call(|reply| Msg::Replan {
                plan,
                failed_step: r.failed_step as usize,
                failure: r.failure,
                answer: r.answer,
                backend: r.backend,
                reply,
            })
            .await??;
        Ok(Response::new(response(planned)))
    }

    async fn validate_plan(
        &self,
        request: Request<pb::ValidatePlanRequest>,
    ) -> Result<Response<pb::ValidatePlanResponse>, Status> {
        let r = request.into_inner();
        if r.plan_json.trim().is_empty() {
            return Err(Status::invalid_argument("plan_json: empty; send a JSON array of steps"));
        }
        if r.plan_json.len() > 256 * 1024 {
            return Err(Status::invalid_argument(format!(
                "plan_json: {} bytes; at most 262144 accepted",
                r.plan_json.len()
            )));
        }
        let out = match self.validator.validate_text(&r.plan_json) {
            Ok(v) => pb::ValidatePlanResponse { valid: true, plan: Some(plan_to_proto(&v.plan)), errors: Vec::new() },
            Err(errors) => pb::ValidatePlanResponse { valid: false, plan: None, errors },
        };
        Ok(Response::new(out))
    }

    async fn get_plan_schema(&self, _: Request<pb::GetPlanSchemaRequest>) -> Result<Response<pb::PlanSchema>, Status> {
        Ok(Response::new(pb::PlanSchema {
            json_schema: PLAN_SCHEMA.to_string(),
            actions: Action::ALL.iter().map(|a| a.as_str().to_string()).collect(),
            classes: vlnav_proto::coco::CLASSES.iter().map(|c| c.to_string()).collect(),
        }))
    }
}
