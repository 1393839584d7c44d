//! The executor's domain types: what it knows of a frame, of a plan, of the
//! stages' answers, and the events it reports. No generated types live here;
//! the gRPC adapter (`executor/grpc.rs`) converts at the edge.

use nalgebra::Vector3;
use vlnav_geometry::camera::Camera;
pub(crate) use vlnav_geometry::{GoalSpec as Goal, Pose2};

pub(crate) use vlnav_geometry::Twist;

/// COCO's class index for a person (YOLOv8 numbering).
pub(crate) const PERSON_CLASS: i32 = 0;

/// One sensor frame as the state machine sees it: when, where, and how the
/// camera looks. Pixels stay with the adapter, which hands them to the stages.
#[derive(Clone, Debug, Default)]
pub(crate) struct Frame {
    /// Sensor time, seconds: every timeout and rate reads this.
    pub(crate) stamp: f64,
    /// `base_link` in `odom`.
    pub(crate) pose: Pose2,
    /// The camera model, when the frame carries a usable one.
    pub(crate) camera: Option<Camera>,
    /// Simulation ground truth, for the mission's metrics.
    pub(crate) truth: Option<Truth>,
    /// An emergency stop is engaged — the robot's own or its edge agent's
    /// (their last `EdgeStatus`): the edge agent holds the robot at zero,
    /// and the mission pauses.
    pub(crate) estop: bool,
}

/// Simulation ground truth attached to a frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct Truth {
    pub(crate) pose: Option<Pose2>,
    pub(crate) path_length_m: f64,
    pub(crate) hard_collisions: u32,
    pub(crate) soft_collisions: u32,
    /// The odometry frame's origin in the world, to map odom goals to truth.
    pub(crate) odom_origin: Option<Pose2>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Action {
    Unspecified,
    Move,
    Find,
    Follow,
    Return,
}

/// One validated plan step (docs/design.md, "Action plan").
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct PlanStep {
    pub(crate) action: Action,
    pub(crate) desc: String,
    /// MOVE: metres to drive after turning.
    pub(crate) f_dist: f64,
    /// MOVE: radians to turn first, counter-clockwise positive.
    pub(crate) yaw: f64,
    /// FIND / FOLLOW: the target phrase and its COCO-80 class id.
    pub(crate) target: String,
    pub(crate) class_id: i32,
    /// FIND / FOLLOW: a named person, recognised by ReID.
    pub(crate) person: String,
    /// Stopping distance, metres (0: the default).
    pub(crate) d_s: f64,
    /// FOLLOW: seconds to follow (0: the default).
    pub(crate) duration_s: f64,
    /// FIND / FOLLOW: the object the target was described by ("the chair next
    /// to the table"), carried with the plan.
    pub(crate) reference: Option<TargetReference>,
    /// The instruction's words the step came from (planner `ActionStep.source`).
    pub(crate) source: String,
}

/// An object a target is described by its relation to.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct TargetReference {
    pub(crate) relation: String,
    pub(crate) target: String,
    pub(crate) class_id: i32,
}

/// A detected box in image pixels.
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct Detection {
    pub(crate) x_min: f32,
    pub(crate) y_min: f32,
    pub(crate) x_max: f32,
    pub(crate) y_max: f32,
    pub(crate) class_id: i32,
    pub(crate) score: f32,
    pub(crate) label: String,
}

impl Detection {
    pub(crate) fn center(&self) -> (f32, f32) {
        ((self.x_min + self.x_max) / 2.0, (self.y_min + self.y_max) / 2.0)
    }
}

/// ReID's answer for one box.
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct Identity {
    pub(crate) box_index: u32,
    pub(crate) name: String,
    pub(crate) similarity: f32,
    pub(crate) matched: bool,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum EstimateStatus {
    Unspecified,
    Ok,
    NoDepth,
    Outlier,
}

/// The subgoal estimator's answer for one box: the (fused) target and the
/// goal at the stopping distance.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Estimate {
    pub(crate) status: EstimateStatus,
    pub(crate) goal: Option<Goal>,
    pub(crate) fused_target: Option<Vector3<f64>>,
    /// This frame's own estimate of where the box's object stands (`odom`):
    /// none without valid depth in the box.
    pub(crate) observed: Option<Vector3<f64>>,
    pub(crate) range_m: f64,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum DriveStatus {
    Unspecified,
    Moving,
    Rotating,
    Reached,
    Blocked,
    NoProgress,
    /// Stopped for a person in the way: no lack of progress, waited for
    /// within a bound (`drive.rs`).
    Waiting,
}

/// What the current frame's perception found that its local-planner step
/// takes along (`Reply::Perceived`, then `Request::Drive`): the machine keeps
/// it for the frame, so everything a step is decided on passes through the
/// machine.
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct Obstacles {
    /// The segmenter's virtual obstacle points, `base_link`.
    pub(crate) no_go: Vec<Vector3<f64>>,
    /// The detector's person boxes, for the local planner to keep clear of
    /// walkers (docs/design.md §4).
    pub(crate) people: Vec<Detection>,
}

/// The local planner's answer for one control step.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct DriveAnswer {
    pub(crate) status: DriveStatus,
    pub(crate) cmd: Twist,
    pub(crate) path_id: i32,
    pub(crate) distance_to_goal: f64,
    pub(crate) heading_error: f64,
    pub(crate) free_paths: u32,
    /// The nearest edges of the space the depth has not seen, `odom` (x, y),
    /// nearest first, where the local planner keeps them
    /// (`--local-planner-frontier`).
    pub(crate) frontier: Vec<[f64; 2]>,
}

/// A question for the user.
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct Question {
    pub(crate) question: String,
    pub(crate) reason: String,
    pub(crate) options: Vec<String>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Outcome {
    Succeeded,
    Failed,
    Cancelled,
}

/// A mission's figures, from frame stamps and (in simulation) ground truth.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct Metrics {
    pub(crate) duration_s: f64,
    pub(crate) odom_path_length_m: f64,
    pub(crate) steps_completed: u32,
    pub(crate) steps_total: u32,
    pub(crate) frames: u32,
    pub(crate) replans: u32,
    pub(crate) has_ground_truth: bool,
    pub(crate) true_path_length_m: f64,
    pub(crate) hard_collisions: u32,
    pub(crate) soft_collisions: u32,
    pub(crate) final_error_m: f64,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum ExplorePhase {
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
pub(crate) enum Event {
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
pub(crate) struct Stamped {
    pub(crate) stamp: f64,
    pub(crate) event: Event,
}
