//! The executor's domain types: what it knows of a frame, of a plan, of the
//! stages' answers, and the events it reports. No generated types live here;
//! the gRPC adapter (`executor/grpc.rs`) converts at the edge.

use nalgebra::Vector3;
use vlnav_geometry::camera::Camera;
pub use vlnav_geometry::{GoalSpec as Goal, Pose2};

pub use vlnav_geometry::Twist;

/// COCO's class index for a person (YOLOv8 numbering).
pub const PERSON_CLASS: i32 = 0;

/// One sensor frame as the state machine sees it: when, where, and how the
/// camera looks. Pixels stay with the adapter, which hands them to the stages.
#[derive(Clone, Debug, Default)]
pub struct Frame {
    pub seq: u64,
    /// Sensor time, seconds: every timeout and rate reads this.
    pub stamp: f64,
    /// `base_link` in `odom`.
    pub pose: Pose2,
    /// The camera model, when the frame carries a usable one.
    pub camera: Option<Camera>,
    /// Simulation ground truth, for the mission's metrics.
    pub truth: Option<Truth>,
}

/// Simulation ground truth attached to a frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Truth {
    pub pose: Option<Pose2>,
    pub path_length_m: f64,
    pub hard_collisions: u32,
    pub soft_collisions: u32,
    /// The odometry frame's origin in the world, to map odom goals to truth.
    pub odom_origin: Option<Pose2>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Action {
    Unspecified,
    Move,
    Find,
    Follow,
    Return,
}

/// One validated plan step (docs/design.md, "Action plan").
#[derive(Clone, Debug, PartialEq)]
pub struct PlanStep {
    pub action: Action,
    pub desc: String,
    /// MOVE: metres to drive after turning.
    pub f_dist: f64,
    /// MOVE: radians to turn first, counter-clockwise positive.
    pub yaw: f64,
    /// FIND / FOLLOW: the target phrase and its COCO-80 class id.
    pub target: String,
    pub class_id: i32,
    /// FIND / FOLLOW: a named person, recognised by ReID.
    pub person: String,
    /// Stopping distance, metres (0: the default).
    pub d_s: f64,
    /// FOLLOW: seconds to follow (0: the default).
    pub duration_s: f64,
    /// FIND / FOLLOW: the object the target was described by ("the chair next
    /// to the table"), carried with the plan.
    pub reference: Option<TargetReference>,
    /// The instruction's words the step came from (planner `ActionStep.source`).
    pub source: String,
}

/// An object a target is described by its relation to.
#[derive(Clone, Debug, PartialEq)]
pub struct TargetReference {
    pub relation: String,
    pub target: String,
    pub class_id: i32,
}

/// A detected box in image pixels.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Detection {
    pub x_min: f32,
    pub y_min: f32,
    pub x_max: f32,
    pub y_max: f32,
    pub class_id: i32,
    pub score: f32,
    pub label: String,
}

impl Detection {
    pub fn center(&self) -> (f32, f32) {
        ((self.x_min + self.x_max) / 2.0, (self.y_min + self.y_max) / 2.0)
    }
}

/// ReID's answer for one box.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Identity {
    pub box_index: u32,
    pub name: String,
    pub similarity: f32,
    pub matched: bool,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EstimateStatus {
    Unspecified,
    Ok,
    NoDepth,
    Outlier,
}

/// The subgoal estimator's answer for one box: the (fused) target and the
/// goal at the stopping distance.
#[derive(Clone, Debug, PartialEq)]
pub struct Estimate {
    pub status: EstimateStatus,
    pub goal: Option<Goal>,
    pub fused_target: Option<Vector3<f64>>,
    pub range_m: f64,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DriveStatus {
    Unspecified,
    Moving,
    Rotating,
    Reached,
    Blocked,
    NoProgress,
}

/// The local planner's answer for one control step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DriveAnswer {
    pub status: DriveStatus,
    pub cmd: Twist,
    pub path_id: i32,
    pub distance_to_goal: f64,
    pub heading_error: f64,
    pub free_paths: u32,
}

/// A question for the user.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Question {
    pub question: String,
    pub reason: String,
    pub options: Vec<String>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Outcome {
    Succeeded,
    Failed,
    Cancelled,
}

/// A mission's figures, from frame stamps and (in simulation) ground truth.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Metrics {
    pub duration_s: f64,
    pub odom_path_length_m: f64,
    pub steps_completed: u32,
    pub steps_total: u32,
    pub frames: u32,
    pub replans: u32,
    pub has_ground_truth: bool,
    pub true_path_length_m: f64,
    pub hard_collisions: u32,
    pub soft_collisions: u32,
    pub final_error_m: f64,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ExplorePhase {
    /// Turning in place and looking.
    Scan,
    /// A bounded forward search leg.
    Search,
    /// A leg toward where an earlier step of the mission saw an object of
    /// the target's class, to look again from closer.
    Revisit,
}

/// What happened, in the order it happened, stamped with sensor time.
#[derive(Clone, Debug, PartialEq)]
pub enum Event {
    StepStarted {
        index: u32,
        step: PlanStep,
        anchor: Pose2,
    },
    TargetSeen {
        index: u32,
        detection: Detection,
        target: Option<Vector3<f64>>,
        goal: Option<Pose2>,
        range_m: f64,
        identity: String,
        identity_similarity: f32,
    },
    Exploring {
        index: u32,
        phase: ExplorePhase,
        attempt: u32,
    },
    SubgoalReached {
        index: u32,
        pose: Pose2,
        goal: Pose2,
        error_m: f64,
    },
    StepFailed {
        index: u32,
        reason: String,
    },
    /// The mission waits for an answer to `question`.
    ClarificationNeeded {
        index: u32,
        question: Question,
    },
    /// The user's answer revised the plan from `resume_index` on.
    Replanned {
        plan: Vec<PlanStep>,
        plan_json: String,
        answer: String,
        resume_index: u32,
    },
    Finished {
        outcome: Outcome,
        reason: String,
        metrics: Metrics,
        current_step: u32,
    },
}

/// An event and the sensor time it happened at.
#[derive(Clone, Debug, PartialEq)]
pub struct Stamped {
    pub stamp: f64,
    pub event: Event,
}
