//! The frames, plans and scripted stages the state machine's tests share:
//! each test answers the machine's requests as the stages would and drives
//! it with sensor time alone.

use vlnav_geometry::camera::{Camera, Intrinsics, Mount};
use vlnav_geometry::wrap_angle as wrap;

use super::*;

pub(super) fn step(action: Action) -> PlanStep {
    PlanStep {
        action,
        desc: format!("{action:?}"),
        f_dist: 0.0,
        yaw: 0.0,
        target: String::new(),
        class_id: 0,
        person: String::new(),
        d_s: 0.0,
        duration_s: 0.0,
        reference: None,
        source: String::new(),
    }
}

pub(super) fn mv(f_dist: f64, yaw: f64) -> PlanStep {
    PlanStep { f_dist, yaw, ..step(Action::Move) }
}

pub(super) fn find(class_id: i32, target: &str) -> PlanStep {
    PlanStep { class_id, target: target.into(), ..step(Action::Find) }
}

pub(super) fn camera() -> Camera {
    Camera {
        width: 160,
        height: 120,
        intrinsics: Intrinsics { fx: 80.0, fy: 80.0, cx: 80.0, cy: 60.0 },
        mount: Mount { translation: Vector3::new(0.3, 0.0, 0.5), ..Mount::default() },
        depth_min_m: 0.0,
        depth_max_m: 1e3,
    }
}

pub(super) fn at(stamp: f64, x: f64, y: f64, theta: f64) -> Frame {
    Frame { stamp, pose: Pose2::new(x, y, theta), camera: Some(camera()), truth: None, estop: false }
}

pub(super) fn mission(plan: Vec<PlanStep>) -> Mission {
    Mission::new("m-1".into(), "an instruction".into(), plan, None)
}

/// The subgoal estimator's MOVE rule (docs/design.md, "Subgoals").
pub(super) fn goal_of(q: &MoveQuery) -> Goal {
    let heading = wrap(q.anchor.theta + q.yaw);
    let rotation_only = q.f_dist.abs() < 0.1;
    Goal {
        pose: Pose2::new(q.anchor.x + q.f_dist * heading.cos(), q.anchor.y + q.f_dist * heading.sin(), heading),
        position_tolerance: 0.25,
        yaw_tolerance: 0.2,
        rotation_only,
        landmark: None,
    }
}

pub(super) fn driven(status: DriveStatus, linear: f64, distance_to_goal: f64) -> Reply {
    let answer = DriveAnswer {
        status,
        cmd: Twist { linear, angular: 0.0 },
        path_id: 0,
        distance_to_goal,
        heading_error: 0.0,
        free_paths: 10,
        frontier: Vec::new(),
    };
    Reply::Driven { answer, path: Vec::new() }
}

pub(super) fn chair(x_min: f32, x_max: f32) -> Detection {
    Detection { x_min, y_min: 40.0, x_max, y_max: 80.0, class_id: 56, score: 0.9, label: "chair".into() }
}

pub(super) fn person(x_min: f32, x_max: f32) -> Detection {
    Detection { class_id: 0, label: "person".into(), ..chair(x_min, x_max) }
}

pub(super) fn located(goal: Pose2) -> Reply {
    Reply::Located(Estimate {
        status: EstimateStatus::Ok,
        goal: Some(Goal {
            pose: goal,
            position_tolerance: 0.25,
            yaw_tolerance: 0.2,
            rotation_only: false,
            landmark: None,
        }),
        fused_target: Some(Vector3::new(goal.x + 1.5, goal.y, 0.5)),
        observed: Some(Vector3::new(goal.x + 1.5, goal.y, 0.5)),
        range_m: 3.0,
    })
}

/// One control cycle: answers every request with `answer`; returns the
/// command and the requests in the order they were made.
pub(super) fn cycle(
    m: &mut Mission,
    p: &ExecutorParams,
    frame: Frame,
    mut answer: impl FnMut(&Request) -> Result<Reply, StageFailure>,
) -> (Command, Vec<Request>) {
    let mut next = m.on_frame(p, frame);
    let mut asked = Vec::new();
    loop {
        match next {
            Next::Done(command) => return (command, asked),
            Next::Call(request) => {
                let reply = answer(&request);
                asked.push(request);
                next = match reply {
                    Ok(reply) => m.on_reply(p, reply),
                    Err(failure) => m.on_stage_error(failure),
                };
            }
        }
    }
}

/// Stages that see nothing and drive with `drive` toward any goal.
pub(super) fn blind(drive: impl Fn(&Goal) -> Reply) -> impl FnMut(&Request) -> Result<Reply, StageFailure> {
    move |r| {
        Ok(match r {
            Request::StartStep { move_goal, .. } => Reply::StepStarted { goal: move_goal.as_ref().map(goal_of) },
            Request::Perceive { .. } => Reply::Perceived { obstacles: Obstacles::default(), boxes: vec![] },
            Request::MoveGoal(q) => Reply::Goal(goal_of(q)),
            Request::Drive { goal, .. } => drive(goal),
            other => panic!("unexpected request {other:?}"),
        })
    }
}

pub(super) fn events(m: &mut Mission) -> Vec<Event> {
    m.take_events().into_iter().map(|s| s.event).collect()
}

/// Stages that see the chair box and answer `located` with the fused
/// target `target(frame)`; the frame number comes from the stamp.
pub(super) fn tally(
    target: impl Fn(u32) -> Vector3<f64>,
    f: u32,
    boxes: Vec<Detection>,
) -> impl FnMut(&Request) -> Result<Reply, StageFailure> {
    move |r| {
        Ok(match r {
            Request::StartStep { .. } => Reply::StepStarted { goal: None },
            Request::Perceive { .. } => Reply::Perceived { obstacles: Obstacles::default(), boxes: boxes.clone() },
            Request::Locate { .. } => {
                let t = target(f);
                Reply::Located(Estimate {
                    status: EstimateStatus::Ok,
                    goal: Some(Goal {
                        pose: Pose2::new(t.x - 1.5, t.y, 0.0),
                        position_tolerance: 0.25,
                        yaw_tolerance: 0.2,
                        rotation_only: false,
                        landmark: None,
                    }),
                    fused_target: Some(t),
                    observed: Some(t),
                    range_m: t.x,
                })
            }
            Request::Drive { .. } => driven(DriveStatus::Moving, 0.5, 2.0),
            other => panic!("frame {f}: unexpected {other:?}"),
        })
    }
}
