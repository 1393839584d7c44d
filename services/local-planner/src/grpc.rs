//! The thin tonic layer of `vlnav.v1.LocalPlannerService`: validate, convert
//! proto → domain, call the actor, convert back.

use tonic::{Request, Response, Status};
use vlnav_geometry::convert::{
    DepthDefaults, InvalidField, camera_from_proto, depth_from_proto, goal_from_proto, pose_from_proto,
};
use vlnav_proto::v1 as pb;
use vlnav_proto::v1::local_planner_service_server::LocalPlannerService;
use vlnav_runtime::actor::{ActorGone, Mailbox};

use crate::actor::{Msg, StepReply, StepRequest};
use crate::cloud::PixelBox;
use crate::control::StepStatus;

/// Every way a local-planner request can fail.
#[derive(Debug, thiserror::Error)]
pub enum LocalPlannerError {
    #[error(transparent)]
    InvalidArgument(#[from] InvalidField),
    #[error(transparent)]
    ActorGone(#[from] ActorGone),
}

impl From<LocalPlannerError> for Status {
    fn from(e: LocalPlannerError) -> Self {
        match e {
            LocalPlannerError::InvalidArgument(e) => Status::invalid_argument(e.to_string()),
            LocalPlannerError::ActorGone(g) => g.into(),
        }
    }
}

fn invalid(field: &str, reason: impl Into<String>) -> LocalPlannerError {
    InvalidField::new(field, reason).into()
}

/// Validates a request into the actor's step (no copy of the depth bytes).
pub fn step_request(r: pb::PlanStepRequest, depth_defaults: DepthDefaults) -> Result<StepRequest, LocalPlannerError> {
    if r.robot_id.trim().is_empty() {
        return Err(invalid("robot_id", "must name the robot (e.g. \"husky-1\")"));
    }
    let mut frame = r
        .frame
        .ok_or_else(|| invalid("frame", "is required (depth, camera, odom pose and stamp of the current frame)"))?;
    if !frame.robot_id.is_empty() && frame.robot_id != r.robot_id {
        return Err(invalid(
            "frame.robot_id",
            format!("is {:?} but the request is for {:?}", frame.robot_id, r.robot_id),
        ));
    }
    if !frame.stamp.is_finite() {
        return Err(invalid("frame.stamp", format!("must be a finite sensor time in seconds, got {}", frame.stamp)));
    }
    let camera = camera_from_proto(frame.camera.as_ref(), "frame.camera", depth_defaults)?;
    depth_from_proto(frame.depth.as_ref(), &camera, "frame.depth")?;
    let pose = pose_from_proto(frame.odom.as_ref(), "frame.odom")?;
    let goal = goal_from_proto(r.goal.as_ref(), "goal")?;
    if !(r.max_speed.is_finite() && r.max_speed >= 0.0) {
        return Err(invalid(
            "max_speed",
            format!("must be a finite speed ≥ 0 in m/s (0: default), got {}", r.max_speed),
        ));
    }
    let mut no_go = Vec::with_capacity(r.no_go_points.len());
    for (i, p) in r.no_go_points.iter().enumerate() {
        if !(p.x.is_finite() && p.y.is_finite() && p.z.is_finite()) {
            return Err(invalid(
                &format!("no_go_points[{i}]"),
                format!("must be finite base_link coordinates, got ({}, {}, {})", p.x, p.y, p.z),
            ));
        }
        no_go.push([p.x, p.y, p.z]);
    }
    if r.people.len() > usize::from(u8::MAX) {
        return Err(invalid("people", format!("holds {} boxes; at most 255 people per frame", r.people.len())));
    }
    let mut people = Vec::with_capacity(r.people.len());
    for (i, b) in r.people.iter().enumerate() {
        let finite = [b.x_min, b.y_min, b.x_max, b.y_max].iter().all(|v| v.is_finite());
        if !(finite && b.x_min <= b.x_max && b.y_min <= b.y_max) {
            return Err(invalid(
                &format!("people[{i}]"),
                format!(
                    "must be a finite pixel box with x_min ≤ x_max and y_min ≤ y_max, got ({}, {}, {}, {})",
                    b.x_min, b.y_min, b.x_max, b.y_max
                ),
            ));
        }
        people.push(PixelBox {
            x_min: f64::from(b.x_min),
            y_min: f64::from(b.y_min),
            x_max: f64::from(b.x_max),
            y_max: f64::from(b.y_max),
        });
    }
    let depth_mm = std::mem::take(&mut frame.depth.as_mut().expect("checked above").data_mm);
    Ok(StepRequest {
        robot_id: r.robot_id,
        stamp: frame.stamp,
        pose,
        camera,
        depth_mm,
        goal,
        no_go,
        people,
        max_speed: r.max_speed,
    })
}

fn reply_to_proto(r: StepReply) -> pb::PlanStepResponse {
    let o = r.output;
    let status = match o.status {
        StepStatus::Moving => pb::LocalPlanStatus::Moving,
        StepStatus::Rotating => pb::LocalPlanStatus::Rotating,
        StepStatus::Reached => pb::LocalPlanStatus::Reached,
        StepStatus::Blocked => pb::LocalPlanStatus::Blocked,
        StepStatus::NoProgress => pb::LocalPlanStatus::NoProgress,
        StepStatus::Waiting => pb::LocalPlanStatus::Waiting,
    };
    let (path_id, rotation_index, cost) = match &o.selection {
        Some(s) => (s.path as i32, s.rotation as i32, s.cost),
        None => (-1, -1, 0.0),
    };
    pb::PlanStepResponse {
        cmd: Some(pb::Twist2D { linear: o.linear, angular: o.angular }),
        status: status as i32,
        path_id,
        rotation_index,
        path_scale: o.selection.as_ref().map_or(o.path_scale, |s| s.scale),
        cost,
        distance_to_goal: o.distance_to_goal,
        heading_error: o.heading_error,
        obstacle_points: r.obstacle_cells as u32,
        free_paths: o.free_paths as u32,
        frontier: o.frontier.iter().map(|f| pb::Point3 { x: f.x, y: f.y, z: 0.0 }).collect(),
        path: o
            .selection
            .as_ref()
            .map(|s| {
                // Every 10th sample: the library is sampled every 0.01 m of radius.
                s.points.iter().step_by(10).map(|p| pb::Point3 { x: p.x, y: p.y, z: 0.0 }).collect()
            })
            .unwrap_or_default(),
    }
}

/// The service; cheap to clone.
#[derive(Clone)]
pub struct LocalPlanner {
    pub(crate) mailbox: Mailbox<Msg>,
    pub(crate) depth_defaults: DepthDefaults,
}

#[tonic::async_trait]
impl LocalPlannerService for LocalPlanner {
    async fn plan_step(&self, request: Request<pb::PlanStepRequest>) -> Result<Response<pb::PlanStepResponse>, Status> {
        let step = Box::new(step_request(request.into_inner(), self.depth_defaults)?);
        let reply =
            self.mailbox.call(|reply| Msg::Step { request: step, reply }).await.map_err(LocalPlannerError::from)?;
        Ok(Response::new(reply_to_proto(reply)))
    }

    async fn reset_robot(
        &self,
        request: Request<pb::ResetRobotRequest>,
    ) -> Result<Response<pb::ResetRobotResponse>, Status> {
        let robot_id = request.into_inner().robot_id;
        if robot_id.trim().is_empty() {
            return Err(invalid("robot_id", "must name the robot whose state to forget").into());
        }
        self.mailbox.call(|reply| Msg::Reset { robot_id, reply }).await.map_err(LocalPlannerError::from)?;
        Ok(Response::new(pb::ResetRobotResponse {}))
    }
}
