//! The task that owns every robot's state (latest cloud, last path, speed,
//! progress window) and the cloud-building buffers; one plan per request.

use std::collections::HashMap;
use std::sync::Arc;

use tokio::sync::{mpsc, oneshot};
use vlnav_geometry::camera::Camera;
use vlnav_geometry::depth::DepthView;
use vlnav_geometry::{GoalSpec, Pose2};
use vlnav_runtime::actor::Mailbox;

use crate::cloud::{CloudBuilder, CloudParams, ObstacleCloud, PixelBox, SeenRange};
use crate::control::{FollowParams, RobotState, StepInput, StepOutput, View};
use crate::planner::Planner;

/// One validated frame and goal.
pub struct StepRequest {
    pub robot_id: String,
    pub stamp: f64,
    pub pose: Pose2,
    pub camera: Camera,
    /// Little-endian u16 mm, already checked against the camera size.
    pub depth_mm: bytes::Bytes,
    pub goal: GoalSpec,
    pub no_go: Vec<[f64; 3]>,
    /// People the detector boxed in the frame, pixels.
    pub people: Vec<PixelBox>,
    pub max_speed: f64,
}

/// A step's result and the size of the cloud it planned in.
pub struct StepReply {
    pub output: StepOutput,
    pub obstacle_cells: usize,
}

pub enum Msg {
    Step {
        request: Box<StepRequest>,
        reply: oneshot::Sender<StepReply>,
    },
    /// Replies whether the robot had state.
    Reset {
        robot_id: String,
        reply: oneshot::Sender<bool>,
    },
}

struct Actor {
    planner: Arc<Planner>,
    follow: FollowParams,
    builder: CloudBuilder,
    robots: HashMap<String, RobotState>,
}

/// Spawns the planner actor and returns its mailbox.
pub fn spawn(planner: Arc<Planner>, follow: FollowParams, cloud: CloudParams) -> Mailbox<Msg> {
    let (mailbox, rx) = Mailbox::channel("local-planner", 64);
    // A remembered cell's height is read in the cloud's own voxels.
    let follow = FollowParams { obstacle_height_m: cloud.obstacle_height, voxel_m: cloud.voxel, ..follow };
    let actor = Actor { planner, follow, builder: CloudBuilder::new(cloud), robots: HashMap::new() };
    tokio::spawn(run(actor, rx));
    mailbox
}

async fn run(mut a: Actor, mut rx: mpsc::Receiver<Msg>) {
    while let Some(msg) = rx.recv().await {
        match msg {
            Msg::Step { request, reply } => {
                let r = *request;
                let cloud = match DepthView::new(r.camera.width, r.camera.height, &r.depth_mm) {
                    Ok(depth) => a.builder.from_depth(&r.camera, &depth, &r.people, &r.no_go),
                    // The tonic layer checked the size; an empty cloud that saw
                    // nothing (so forgets nothing remembered) is the safe fallback.
                    Err(_) => {
                        ObstacleCloud { seen: Some(SeenRange::default()), ..a.builder.from_points(&[], &r.no_go) }
                    }
                };
                let state = a.robots.entry(r.robot_id).or_default();
                let output = state.step(
                    &a.planner,
                    &a.follow,
                    StepInput {
                        stamp: r.stamp,
                        pose: r.pose,
                        goal: r.goal,
                        cloud: &cloud,
                        max_speed: r.max_speed,
                        view: View::of_camera(&r.camera),
                    },
                );
                let obstacle_cells = state.cloud.cells.len();
                let _ = reply.send(StepReply { output, obstacle_cells });
            }
            Msg::Reset { robot_id, reply } => {
                let _ = reply.send(a.robots.remove(&robot_id).is_some());
            }
        }
    }
}
