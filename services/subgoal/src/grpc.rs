//! The thin tonic layer of `vlnav.v1.SubgoalService`: validate, convert proto
//! → domain, compute the box depth (pure, outside the actor), let the actor
//! fuse, convert back. The frame, camera and pose conversions are
//! `vlnav_geometry::convert`'s.

use nalgebra::Vector3;
use tonic::{Request, Response, Status};
use vlnav_geometry::camera::Camera;
use vlnav_geometry::convert::{DepthDefaults, camera_from_proto};
use vlnav_geometry::convert::{InvalidField, depth_from_proto, finite, goal_to_proto, pose_from_proto};
use vlnav_proto::v1 as pb;
use vlnav_proto::v1::subgoal_service_server::SubgoalService;
use vlnav_runtime::actor::{ActorGone, Mailbox};

use crate::actor::Msg;
use crate::geometry::{BoxDepthParams, MoveParams, PixelBox, box_depth, move_goal, target_in_odom};
use crate::tracks::{EstimateStatus, Observation, TargetEstimate};

/// Every way a subgoal request can fail.
#[derive(Debug, thiserror::Error)]
pub enum SubgoalError {
    #[error(transparent)]
    InvalidArgument(#[from] InvalidField),
    #[error(transparent)]
    ActorGone(#[from] ActorGone),
}

impl SubgoalError {
    pub fn invalid(field: impl Into<String>, reason: impl Into<String>) -> Self {
        Self::InvalidArgument(InvalidField::new(field, reason))
    }
}

impl From<SubgoalError> for Status {
    fn from(e: SubgoalError) -> Self {
        match e {
            SubgoalError::InvalidArgument(e) => Status::invalid_argument(e.to_string()),
            SubgoalError::ActorGone(g) => g.into(),
        }
    }
}

fn box_from_proto(b: Option<&pb::BoundingBox>, cam: &Camera) -> Result<PixelBox, InvalidField> {
    let b = b.ok_or_else(|| InvalidField::new("box", "is required (pixel coordinates in the frame)"))?;
    let vals = [("box.x_min", b.x_min), ("box.y_min", b.y_min), ("box.x_max", b.x_max), ("box.y_max", b.y_max)];
    for (name, v) in vals {
        if !v.is_finite() {
            return Err(InvalidField::new(name, format!("must be a finite number, got {v}")));
        }
    }
    if b.x_max <= b.x_min || b.y_max <= b.y_min {
        return Err(InvalidField::new(
            "box",
            format!(
                "must have x_min < x_max and y_min < y_max, got ({}, {}, {}, {})",
                b.x_min, b.y_min, b.x_max, b.y_max
            ),
        ));
    }
    if b.x_max <= 0.0 || b.y_max <= 0.0 || b.x_min >= cam.width as f32 || b.y_min >= cam.height as f32 {
        return Err(InvalidField::new(
            "box",
            format!(
                "lies outside the {}x{} image: ({}, {}, {}, {})",
                cam.width, cam.height, b.x_min, b.y_min, b.x_max, b.y_max
            ),
        ));
    }
    Ok(PixelBox { x_min: b.x_min as f64, y_min: b.y_min as f64, x_max: b.x_max as f64, y_max: b.y_max as f64 })
}

fn stop_distance(d_s: f64) -> Result<f64, InvalidField> {
    if d_s.is_finite() && d_s >= 0.0 {
        Ok(d_s)
    } else {
        Err(InvalidField::new("d_s", format!("must be a finite distance ≥ 0 in metres (0: default), got {d_s}")))
    }
}

fn point(p: &Vector3<f64>) -> pb::Point3 {
    pb::Point3 { x: p.x, y: p.y, z: p.z }
}

fn estimate_to_proto(e: TargetEstimate) -> pb::TargetGoalResponse {
    let status = match e.status {
        EstimateStatus::Ok => pb::EstimateStatus::Ok,
        EstimateStatus::NoDepth => pb::EstimateStatus::NoDepth,
        EstimateStatus::Outlier => pb::EstimateStatus::Outlier,
    };
    pb::TargetGoalResponse {
        status: status as i32,
        detail: e.detail,
        goal: e.goal.as_ref().map(goal_to_proto),
        observed_target: e.observed.as_ref().map(point),
        fused_target: e.fused.as_ref().map(point),
        observations: e.observations,
        rejected: e.rejected,
        spread_m: e.spread_m,
        range_m: e.range_m,
        velocity_x: e.velocity.x,
        velocity_y: e.velocity.y,
    }
}

/// The service; cheap to clone (a mailbox handle and the settings).
#[derive(Clone)]
pub struct Subgoal {
    pub(crate) mailbox: Mailbox<Msg>,
    pub(crate) move_params: MoveParams,
    pub(crate) box_params: BoxDepthParams,
    pub(crate) depth_defaults: DepthDefaults,
}

impl Subgoal {
    fn move_goal(&self, r: &pb::MoveGoalRequest) -> Result<pb::Goal, SubgoalError> {
        let anchor = pose_from_proto(r.anchor.as_ref(), "anchor")?;
        let f_dist = finite("f_dist", r.f_dist)?;
        let yaw = finite("yaw", r.yaw)?;
        let d_s = stop_distance(r.d_s)?;
        Ok(goal_to_proto(&move_goal(anchor, f_dist, yaw, d_s, &self.move_params)))
    }

    /// Validates the request and measures this frame's target (pure).
    fn observation(&self, r: &pb::TargetGoalRequest) -> Result<Observation, SubgoalError> {
        if r.track_key.trim().is_empty() {
            return Err(SubgoalError::invalid("track_key", "must name the target's track (e.g. \"<mission>/<step>\")"));
        }
        let frame = r
            .frame
            .as_ref()
            .ok_or_else(|| SubgoalError::invalid("frame", "is required (depth, camera and odom of the detection)"))?;
        let stamp = finite("frame.stamp", frame.stamp)?;
        let cam = camera_from_proto(frame.camera.as_ref(), "frame.camera", self.depth_defaults)?;
        let depth = depth_from_proto(frame.depth.as_ref(), &cam, "frame.depth")?;
        let robot = pose_from_proto(frame.odom.as_ref(), "frame.odom")?;
        let pixel_box = box_from_proto(r.r#box.as_ref(), &cam)?;
        let d_s = stop_distance(r.d_s)?;
        let target = box_depth(&depth, &pixel_box, &cam, &self.box_params)
            .map(|z| target_in_odom(&cam, &pixel_box, z.depth_m, &robot));
        Ok(Observation { stamp, robot, target, d_s, moving: r.moving })
    }
}

#[tonic::async_trait]
impl SubgoalService for Subgoal {
    async fn move_goal(&self, request: Request<pb::MoveGoalRequest>) -> Result<Response<pb::Goal>, Status> {
        Ok(Response::new(self.move_goal(request.get_ref())?))
    }

    async fn target_goal(
        &self,
        request: Request<pb::TargetGoalRequest>,
    ) -> Result<Response<pb::TargetGoalResponse>, Status> {
        let r = request.into_inner();
        let obs = self.observation(&r)?;
        let key = r.track_key;
        let estimate = self.mailbox.call(|reply| Msg::Observe { key, obs, reply }).await.map_err(SubgoalError::from)?;
        Ok(Response::new(estimate_to_proto(estimate)))
    }

    async fn reset_track(
        &self,
        request: Request<pb::ResetTrackRequest>,
    ) -> Result<Response<pb::ResetTrackResponse>, Status> {
        let key = request.into_inner().track_key;
        if key.trim().is_empty() {
            return Err(SubgoalError::invalid("track_key", "must name the track to forget").into());
        }
        self.mailbox.call(|reply| Msg::Reset { key, reply }).await.map_err(SubgoalError::from)?;
        Ok(Response::new(pb::ResetTrackResponse {}))
    }
}
