//! Objects seen on the way, scripted: remembered, and looked for there first.

use std::f64::consts::FRAC_PI_6;

use super::super::test_support::*;
use super::super::*;
use super::*;

fn plant(x_min: f32, x_max: f32, y_max: f32) -> Detection {
    Detection { class_id: 58, label: "potted plant".into(), y_min: y_max - 20.0, y_max, ..chair(x_min, x_max) }
}

/// "Stop before the chair, then stop before the potted plant": the chair
/// step's frames show a plant in `plant_frames` of them, 4 m ahead and
/// 2.25 m to the right (box bottom 10 px below the horizon, right of the
/// middle); the plant step sees nothing. Returns the plant step's first
/// exploration goal and its events.
fn plant_step_after_the_chair(plant_frames: u32) -> (MoveQuery, Vec<Event>) {
    let p = ExecutorParams { unseen_frames: 2, ..Default::default() };
    let mut m = mission(vec![find(56, "chair"), find(58, "potted plant")]);
    let mut frame = 0;
    // The chair step: confirmed over its vote window, then reached.
    while m.index == 0 {
        assert!(frame < 40, "the chair step ends");
        let mut boxes = vec![chair(60.0, 100.0)];
        if frame < plant_frames {
            boxes.push(plant(120.0, 130.0, 70.0));
        }
        let reached = frame >= 12;
        cycle(&mut m, &p, at(f64::from(frame) * 0.2, 0.0, 0.0, 0.0), |r| {
            Ok(match r {
                Request::StartStep { .. } => Reply::StepStarted { goal: None },
                Request::Perceive { .. } => Reply::Perceived { obstacles: Obstacles::default(), boxes: boxes.clone() },
                Request::Locate { .. } => located(Pose2::new(1.0, 0.0, 0.0)),
                Request::Drive { .. } if reached => driven(DriveStatus::Reached, 0.0, 0.0),
                Request::Drive { .. } => driven(DriveStatus::Moving, 0.5, 1.0),
                other => panic!("frame {frame}: unexpected {other:?}"),
            })
        });
        frame += 1;
    }
    events(&mut m);
    loop {
        assert!(frame < 80, "the plant step explores");
        let (_, asked) = cycle(
            &mut m,
            &p,
            at(f64::from(frame) * 0.2, 0.0, 0.0, 0.0),
            blind(|_| driven(DriveStatus::Moving, 0.5, 1.0)),
        );
        frame += 1;
        if let Some(q) = asked.iter().find_map(|r| match r {
            Request::MoveGoal(q) => Some(*q),
            _ => None,
        }) {
            return (q, events(&mut m));
        }
    }
}

#[test]
fn a_target_an_earlier_step_saw_is_looked_for_there_first() {
    // Seen behind the chair on the way: the plant step drives toward where
    // it stood (4.3 m ahead, 2.25 m right of the robot) before looking
    // around, at least one search leg and never past the stopping distance.
    let (q, events) = plant_step_after_the_chair(6);
    let bearing = (-2.25f64).atan2(4.3);
    assert!((q.yaw - bearing).abs() < 0.05, "{q:?} toward {bearing}");
    let room = 4.3f64.hypot(2.25) - ExecutorParams::default().default_d_s;
    let leg = (room / 2.0).max(ExecutorParams::default().search_leg_m).min(room);
    assert!((q.f_dist - leg).abs() < 1e-9, "{q:?}");
    assert!(
        events.iter().any(|e| matches!(e, Event::Exploring { phase: ExplorePhase::Revisit, attempt: 1, .. })),
        "{events:?}"
    );
    // One stray box of the class is not a place: the plant step looks around.
    let (q, events) = plant_step_after_the_chair(1);
    assert!(q.f_dist == 0.0 && (q.yaw - FRAC_PI_6).abs() < 1e-9, "{q:?}");
    assert!(events.iter().all(|e| !matches!(e, Event::Exploring { phase: ExplorePhase::Revisit, .. })), "{events:?}");
}

#[test]
fn objects_seen_again_are_one_landmark_and_the_least_seen_are_forgotten_first() {
    let mut marks = Vec::new();
    remember_landmarks(&mut marks, [(58, Vector2::new(4.0, 0.0)), (58, Vector2::new(4.4, 0.2))], 0);
    remember_landmarks(&mut marks, [(56, Vector2::new(4.0, 0.0)), (58, Vector2::new(9.0, 0.0))], 1);
    assert_eq!(marks.len(), 3, "{marks:?}");
    assert_eq!((marks[0].sightings, marks[0].step), (2, 0));
    assert!((marks[0].at - Vector2::new(4.2, 0.1)).norm() < 1e-9, "the running mean: {marks:?}");
    let here = Pose2::new(0.0, 0.0, 0.0);
    assert_eq!(remembered(&marks, 58, 2, 2, here), Some(marks[0].at));
    assert_eq!(remembered(&marks, 58, 2, 1, Pose2::new(10.0, 0.0, 0.0)), Some(Vector2::new(9.0, 0.0)));
    assert_eq!(remembered(&marks, 58, 0, 1, here), None, "only earlier steps' landmarks");
    for i in 0..LANDMARK_PLACES {
        remember_landmarks(&mut marks, [(1, Vector2::new(20.0 + 2.0 * i as f64, 0.0))], 3);
    }
    assert_eq!(marks.len(), LANDMARK_PLACES);
    assert!(marks.iter().any(|l| l.sightings == 2), "the landmark seen twice is kept");
}
