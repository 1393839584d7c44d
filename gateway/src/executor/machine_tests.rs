//! The state machine's decisions, scripted: each test answers the machine's
//! requests as the stages would and drives it with sensor time alone.

use std::f64::consts::{FRAC_PI_2, FRAC_PI_6};

use super::*;
use vlnav_geometry::camera::{Camera, Intrinsics, Mount};

fn step(action: Action) -> PlanStep {
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

fn mv(f_dist: f64, yaw: f64) -> PlanStep {
    PlanStep { f_dist, yaw, ..step(Action::Move) }
}

fn find(class_id: i32, target: &str) -> PlanStep {
    PlanStep { class_id, target: target.into(), ..step(Action::Find) }
}

fn camera() -> Camera {
    Camera {
        width: 160,
        height: 120,
        intrinsics: Intrinsics { fx: 80.0, fy: 80.0, cx: 80.0, cy: 60.0 },
        mount: Mount { translation: Vector3::new(0.3, 0.0, 0.5), ..Mount::default() },
        depth_min_m: 0.0,
        depth_max_m: 1e3,
    }
}

fn at(stamp: f64, x: f64, y: f64, theta: f64) -> Frame {
    Frame {
        seq: (stamp * 10.0).round() as u64,
        stamp,
        pose: Pose2::new(x, y, theta),
        camera: Some(camera()),
        truth: None,
    }
}

fn mission(plan: Vec<PlanStep>) -> Mission {
    Mission::new("m-1".into(), "an instruction".into(), plan, None)
}

/// The subgoal estimator's MOVE rule (docs/design.md, "Subgoals").
fn goal_of(q: &MoveQuery) -> Goal {
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

fn driven(status: DriveStatus, linear: f64, distance_to_goal: f64) -> Reply {
    Reply::Driven(DriveAnswer {
        status,
        cmd: Twist { linear, angular: 0.0 },
        path_id: 0,
        distance_to_goal,
        heading_error: 0.0,
        free_paths: 10,
    })
}

fn chair(x_min: f32, x_max: f32) -> Detection {
    Detection { x_min, y_min: 40.0, x_max, y_max: 80.0, class_id: 56, score: 0.9, label: "chair".into() }
}

fn person(x_min: f32, x_max: f32) -> Detection {
    Detection { class_id: 0, label: "person".into(), ..chair(x_min, x_max) }
}

/// The `k`-th located sighting: odd ones with depth (a goal 2 m ahead), even
/// ones without.
fn every_other_without_depth(k: u32) -> Reply {
    if k.is_multiple_of(2) {
        Reply::Located(Estimate { status: EstimateStatus::NoDepth, goal: None, fused_target: None, range_m: 0.0 })
    } else {
        located(Pose2::new(2.0, 0.0, 0.0))
    }
}

fn located(goal: Pose2) -> Reply {
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
        range_m: 3.0,
    })
}

/// One control cycle: answers every request with `answer`; returns the
/// command and the requests in the order they were made.
fn cycle(
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
fn blind(drive: impl Fn(&Goal) -> Reply) -> impl FnMut(&Request) -> Result<Reply, StageFailure> {
    move |r| {
        Ok(match r {
            Request::StartStep { move_goal, .. } => Reply::StepStarted { goal: move_goal.as_ref().map(goal_of) },
            Request::Perceive { .. } => Reply::Perceived { boxes: vec![] },
            Request::MoveGoal(q) => Reply::Goal(goal_of(q)),
            Request::Drive { goal } => drive(goal),
            other => panic!("unexpected request {other:?}"),
        })
    }
}

fn events(m: &mut Mission) -> Vec<Event> {
    m.take_events().into_iter().map(|s| s.event).collect()
}

#[test]
fn a_move_starts_perceives_drives_and_completes_when_reached() {
    let p = ExecutorParams::default();
    let mut m = mission(vec![mv(2.0, 0.0)]);
    let (cmd, asked) = cycle(&mut m, &p, at(0.0, 0.0, 0.0, 0.0), blind(|_| driven(DriveStatus::Moving, 0.5, 2.0)));
    let query = MoveQuery { anchor: Pose2::new(0.0, 0.0, 0.0), f_dist: 2.0, yaw: 0.0, d_s: 0.0 };
    assert_eq!(
        asked,
        vec![
            Request::StartStep {
                index: 0,
                action: Action::Move,
                desc: "Move".into(),
                move_goal: Some(query),
                forget: true
            },
            Request::Perceive { detect: None },
            Request::Drive { goal: goal_of(&query) },
        ]
    );
    assert_eq!(cmd, Command { twist: Twist { linear: 0.5, angular: 0.0 }, active: true, finished: None });
    assert!(matches!(events(&mut m)[..], [Event::StepStarted { index: 0, .. }]));

    let (cmd, _) = cycle(&mut m, &p, at(4.0, 1.9, 0.0, 0.0), blind(|_| driven(DriveStatus::Reached, 0.0, 0.1)));
    assert_eq!(cmd.twist, Twist::ZERO);
    match &events(&mut m)[..] {
        [Event::SubgoalReached { index: 0, error_m, .. }] => assert!((error_m - 0.1).abs() < 1e-9),
        other => panic!("{other:?}"),
    }
    let (cmd, asked) = cycle(&mut m, &p, at(4.1, 1.9, 0.0, 0.0), blind(|_| unreachable!()));
    assert!(asked.is_empty());
    assert_eq!(cmd.finished, Some(Outcome::Succeeded));
    assert!(!cmd.active);
    match &events(&mut m)[..] {
        [Event::Finished { outcome: Outcome::Succeeded, metrics, current_step: 1, .. }] => {
            assert_eq!((metrics.steps_completed, metrics.steps_total, metrics.frames), (1, 1, 3));
            assert!((metrics.duration_s - 4.1).abs() < 1e-9);
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_move_after_a_move_turns_from_that_moves_course_not_the_arrival_heading() {
    let p = ExecutorParams::default();
    let mut m = mission(vec![mv(10.0, 0.0), mv(2.0, FRAC_PI_6)]);
    cycle(&mut m, &p, at(0.0, 0.0, 0.0, 0.0), blind(|_| driven(DriveStatus::Moving, 1.0, 10.0)));
    // The first leg ran along +x but the robot arrived swerved 0.58 rad to the right.
    cycle(&mut m, &p, at(12.0, 9.8, 0.1, -0.58), blind(|_| driven(DriveStatus::Reached, 0.0, 0.2)));
    let (_, asked) = cycle(&mut m, &p, at(12.1, 9.8, 0.1, -0.58), blind(|_| driven(DriveStatus::Moving, 1.0, 2.0)));
    match &asked[0] {
        Request::StartStep { move_goal: Some(q), .. } => {
            assert_eq!((q.anchor.x, q.anchor.y, q.anchor.theta), (9.8, 0.1, 0.0));
            assert_eq!(q.yaw, FRAC_PI_6);
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn only_the_missions_first_step_makes_the_local_planner_forget() {
    // A turn that opens the second step must know what the first one passed.
    let p = ExecutorParams::default();
    let mut m = mission(vec![mv(3.0, 0.0), mv(0.0, -FRAC_PI_6)]);
    let (_, asked) = cycle(&mut m, &p, at(0.0, 0.0, 0.0, 0.0), blind(|_| driven(DriveStatus::Moving, 1.0, 3.0)));
    assert!(matches!(asked[0], Request::StartStep { index: 0, forget: true, .. }), "{asked:?}");
    cycle(&mut m, &p, at(3.0, 3.0, 0.0, 0.0), blind(|_| driven(DriveStatus::Reached, 0.0, 0.0)));
    let (_, asked) = cycle(&mut m, &p, at(3.2, 3.0, 0.0, 0.0), blind(|_| driven(DriveStatus::Moving, 0.0, 0.5)));
    assert!(matches!(asked[0], Request::StartStep { index: 1, forget: false, .. }), "{asked:?}");
}

#[test]
fn a_target_is_confirmed_after_consecutive_sightings_then_approached() {
    let p = ExecutorParams { confirm_frames: 3, confirm_window: 3, ..ExecutorParams::default() };
    let mut m = mission(vec![find(56, "chair")]);
    let goal = Pose2::new(2.0, 0.0, 0.0);
    let mut drives = 0;
    let mut sees = |r: &Request| -> Result<Reply, StageFailure> {
        Ok(match r {
            Request::StartStep { move_goal: None, .. } => Reply::StepStarted { goal: None },
            Request::Perceive { detect: Some((56, score)) } => {
                assert_eq!(*score, p.min_score);
                Reply::Perceived { boxes: vec![chair(70.0, 95.0)] }
            }
            Request::Locate { detection, d_s, moving: false, .. } => {
                assert_eq!(detection.x_min, 70.0);
                assert_eq!(*d_s, p.default_d_s);
                located(goal)
            }
            Request::Drive { goal: g } => {
                drives += 1;
                assert_eq!(g.pose, goal);
                driven(DriveStatus::Moving, 0.6, 2.0)
            }
            other => panic!("unexpected {other:?}"),
        })
    };
    for k in 0..2 {
        let (cmd, _) = cycle(&mut m, &p, at(f64::from(k) * 0.2, 0.0, 0.0, 0.0), &mut sees);
        assert_eq!(cmd.twist, Twist::ZERO, "a candidate is not confirmed yet: hold still");
    }
    let (cmd, _) = cycle(&mut m, &p, at(0.4, 0.0, 0.0, 0.0), &mut sees);
    assert_eq!(cmd.twist.linear, 0.6);
    assert_eq!(drives, 1);
    let seen: Vec<_> = events(&mut m).into_iter().filter(|e| matches!(e, Event::TargetSeen { .. })).collect();
    assert_eq!(seen.len(), 1, "confirmed once");
}

#[test]
fn intermittent_sightings_confirm_within_the_window_and_misses_do_not_count() {
    // A detector that sees the chair every other frame (and, between, a box
    // without depth): the class vote watches a full window of 8 frames, and
    // the first sighting after it (the 9th frame, the 5th sighting) confirms.
    let p = ExecutorParams { confirm_frames: 3, confirm_window: 8, ..ExecutorParams::default() };
    let mut m = mission(vec![find(56, "chair")]);
    let (mut k, mut drives) = (0, 0);
    let mut flaky = |r: &Request| -> Result<Reply, StageFailure> {
        Ok(match r {
            Request::StartStep { .. } => Reply::StepStarted { goal: None },
            Request::Perceive { .. } => Reply::Perceived { boxes: vec![chair(70.0, 95.0)] },
            Request::Locate { .. } => {
                k += 1;
                every_other_without_depth(k)
            }
            Request::Drive { .. } => {
                drives += 1;
                driven(DriveStatus::Moving, 0.5, 2.0)
            }
            other => panic!("unexpected {other:?}"),
        })
    };
    for f in 0..8 {
        let (cmd, _) = cycle(&mut m, &p, at(f64::from(f) * 0.2, 0.0, 0.0, 0.0), &mut flaky);
        assert_eq!(cmd.twist, Twist::ZERO, "frame {f}: still watching");
    }
    let (cmd, _) = cycle(&mut m, &p, at(1.6, 0.0, 0.0, 0.0), &mut flaky);
    assert_eq!((cmd.twist.linear, drives), (0.5, 1), "confirmed once the window is full");
    assert_eq!(events(&mut m).iter().filter(|e| matches!(e, Event::TargetSeen { .. })).count(), 1);
}

#[test]
fn a_candidate_another_class_outvotes_is_dropped_and_its_place_ignored() {
    // One chair sighting, then four frames in which the detector calls the
    // same object a couch: the chair candidate is dropped; later chair boxes
    // at that place are that couch again and never confirm.
    let p = ExecutorParams::default();
    let mut m = mission(vec![find(56, "chair")]);
    let couch = Detection { class_id: 57, label: "couch".into(), ..chair(70.0, 95.0) };
    let mut keys = Vec::new();
    for f in 0..10 {
        let boxes = if (1..5).contains(&f) { vec![couch.clone()] } else { vec![chair(70.0, 95.0)] };
        cycle(&mut m, &p, at(f64::from(f) * 0.2, 0.0, 0.0, 0.0), |r| {
            Ok(match r {
                Request::StartStep { .. } => Reply::StepStarted { goal: None },
                Request::Perceive { .. } => Reply::Perceived { boxes: boxes.clone() },
                Request::Locate { track_key, .. } => {
                    keys.push(track_key.clone());
                    located(Pose2::new(2.0, 0.0, 0.0))
                }
                other => panic!("frame {f}: never confirmed, so never driven: {other:?}"),
            })
        });
    }
    assert!(!events(&mut m).iter().any(|e| matches!(e, Event::TargetSeen { .. })));
    assert_eq!(keys.len(), 6, "located in every frame with a chair box");
    assert!(!keys[0].contains('#') && keys[1..].iter().all(|k| k.ends_with("#1")), "{keys:?}");
}

#[test]
fn three_couch_frames_against_one_chair_sighting_do_not_drop_a_real_chair() {
    // Chair, then couch three times, then chairs: at the shipped detector's
    // confusion rate (one in five) the odds after 1 : 3 are 16 : 1 for a
    // couch, and a real chair shows this in a few trials of a hundred
    // (evaluation, indoor, trial 18). It is watched on, and once its
    // sightings are twice the couch frames (6 : 3) it is confirmed.
    let p = ExecutorParams::default();
    let mut m = mission(vec![find(56, "chair")]);
    let couch = Detection { class_id: 57, label: "couch".into(), ..chair(70.0, 95.0) };
    for f in 0..9u32 {
        let boxes = if (1..4).contains(&f) { vec![couch.clone()] } else { vec![chair(70.0, 95.0)] };
        cycle(&mut m, &p, at(f64::from(f) * 0.2, 0.0, 0.0, 0.0), tally(|_| Vector3::new(3.5, 0.0, 0.5), f, boxes));
        assert_eq!(seen(&mut m), usize::from(f == 8), "frame {f}");
    }
}

#[test]
fn a_sighting_without_depth_breaks_the_streak() {
    // A window as long as the count demands an unbroken streak.
    let p = ExecutorParams { confirm_frames: 2, confirm_window: 2, ..ExecutorParams::default() };
    let mut m = mission(vec![find(56, "chair")]);
    let mut k = 0;
    let mut flaky = |r: &Request| -> Result<Reply, StageFailure> {
        Ok(match r {
            Request::StartStep { .. } => Reply::StepStarted { goal: None },
            Request::Perceive { .. } => Reply::Perceived { boxes: vec![chair(70.0, 95.0)] },
            Request::Locate { .. } => {
                k += 1;
                every_other_without_depth(k)
            }
            other => panic!("never confirmed, so never driven: {other:?}"),
        })
    };
    for f in 0..6 {
        cycle(&mut m, &p, at(f64::from(f) * 0.2, 0.0, 0.0, 0.0), &mut flaky);
    }
    assert!(!events(&mut m).iter().any(|e| matches!(e, Event::TargetSeen { .. })));
}

#[test]
fn a_named_person_is_located_in_the_box_reid_matches_only() {
    let p = ExecutorParams::default();
    let mut m = mission(vec![PlanStep { person: "Alice".into(), ..find(0, "person") }]);
    let mut located_box = None;
    cycle(&mut m, &p, at(0.0, 0.0, 0.0, 0.0), |r| {
        Ok(match r {
            Request::StartStep { .. } => Reply::StepStarted { goal: None },
            Request::Perceive { .. } => Reply::Perceived { boxes: vec![person(10.0, 30.0), person(70.0, 95.0)] },
            Request::Identify { boxes, name } => {
                assert_eq!((boxes.len(), name.as_str()), (2, "Alice"));
                Reply::Identified(vec![
                    Identity { box_index: 0, name: "bob".into(), similarity: 0.95, matched: true },
                    Identity { box_index: 1, name: "alice".into(), similarity: 0.8, matched: true },
                ])
            }
            Request::Locate { detection, .. } => {
                located_box = Some(detection.x_min);
                located(Pose2::new(2.0, 0.0, 0.0))
            }
            other => panic!("unexpected {other:?}"),
        })
    });
    assert_eq!(located_box, Some(70.0));
}

#[test]
fn a_confirmed_target_is_found_where_it_projects() {
    // Robot at (1, 1) facing +y; the chair 3 m ahead of it, 0.5 m high (the camera's height).
    let frame = at(0.0, 1.0, 1.0, FRAC_PI_2);
    let chair_at = Vector3::new(1.0, 4.3, 0.5);
    let Some(TargetView::At(u, v)) = target_view(&frame, &chair_at) else { panic!("the chair is in view") };
    assert!((u - 80.0).abs() < 0.5 && (v - 60.0).abs() < 0.5, "({u}, {v})");
    // Two chairs in the image: the one at the prediction, not the first or the most confident.
    let other = Detection { score: 0.99, ..chair(5.0, 40.0) };
    let boxes = vec![other, chair(70.0, 95.0)];
    assert_eq!(box_at(&boxes, u, v).map(|b| b.x_min), Some(70.0));
    // Only the other chair in view: nothing is the target.
    assert_eq!(box_at(&boxes[..1], u, v), None);
    // Turned away (the chair is now on the robot's left, outside the ±45° view).
    assert_eq!(target_view(&at(0.0, 1.0, 1.0, 0.0), &chair_at), Some(TargetView::OutOfView));
    // No camera in the frame: no prediction (the image-space rule applies).
    assert_eq!(target_view(&Frame { camera: None, ..frame }, &chair_at), None);
}

#[test]
fn an_unseen_target_is_searched_for_boundedly_then_asked_about() {
    let p = ExecutorParams { unseen_frames: 2, scan_turns: 3, look_frames: 1, search_legs: 1, ..Default::default() };
    let mut m = mission(vec![find(1, "bicycle")]);
    let mut turns = Vec::new();
    let mut frame = 0;
    while !m.is_awaiting() {
        assert!(frame < 200, "exploration is bounded");
        let (cmd, asked) = cycle(
            &mut m,
            &p,
            at(f64::from(frame) * 0.2, 0.0, 0.0, 0.0),
            blind(|_| driven(DriveStatus::Reached, 0.0, 0.0)),
        );
        assert_eq!(cmd.twist, Twist::ZERO);
        turns.extend(asked.into_iter().filter_map(|r| match r {
            Request::MoveGoal(q) => Some(q),
            _ => None,
        }));
        frame += 1;
    }
    // Three turns of a look-around from where it began, a 2 m search leg, three more turns.
    let turns_of_30: Vec<f64> = turns.iter().map(|q| q.yaw / FRAC_PI_6).collect();
    for (got, want) in turns_of_30.iter().zip([1.0, 2.0, 3.0, 0.0, 1.0, 2.0, 3.0]) {
        assert!((got - want).abs() < 1e-9, "{turns_of_30:?}");
    }
    assert_eq!(turns_of_30.len(), 7);
    assert_eq!(turns[3].f_dist, p.search_leg_m);
    let kinds: Vec<String> = events(&mut m)
        .iter()
        .filter_map(|e| match e {
            Event::Exploring { phase, attempt, .. } => Some(format!("{phase:?} {attempt}")),
            Event::StepFailed { reason, .. } => Some(reason.clone()),
            Event::ClarificationNeeded { question, .. } => Some(question.question.clone()),
            _ => None,
        })
        .collect();
    assert_eq!(
        kinds,
        vec![
            "Scan 1",
            "Search 1",
            "Scan 2",
            "step 1: the bicycle not found after looking all around and 1 search leg(s)",
            "I could not find the bicycle. Where should I look, or should I skip it?",
        ]
    );
    // Waiting for the user: the robot idles and no stage is asked anything.
    let (cmd, asked) = cycle(&mut m, &p, at(100.0, 0.0, 0.0, 0.0), blind(|_| unreachable!()));
    assert!(asked.is_empty() && !cmd.active && cmd.twist == Twist::ZERO);
}

/// The first scan turn of a FIND for an unseen chair after a 3 m MOVE along
/// +x that the robot ended facing `arrival` (rad): the look-around's origin
/// and the first turn's heading.
fn first_scan_after_a_move_arriving_at(arrival: f64) -> (Pose2, f64) {
    let p = ExecutorParams { unseen_frames: 2, look_frames: 1, ..Default::default() };
    let mut m = mission(vec![mv(3.0, 0.0), find(56, "chair")]);
    cycle(&mut m, &p, at(0.0, 0.0, 0.0, 0.0), blind(|_| driven(DriveStatus::Moving, 1.0, 3.0)));
    cycle(&mut m, &p, at(5.0, 3.0, 0.0, arrival), blind(|_| driven(DriveStatus::Reached, 0.0, 0.02)));
    for k in 0..50 {
        let (_, asked) = cycle(
            &mut m,
            &p,
            at(5.2 + 0.2 * f64::from(k), 3.0, 0.0, arrival),
            blind(|_| driven(DriveStatus::Reached, 0.0, 0.0)),
        );
        if let Some(q) = asked.iter().find_map(|r| match r {
            Request::MoveGoal(q) => Some(*q),
            _ => None,
        }) {
            return (q.anchor, wrap(q.anchor.theta + q.yaw));
        }
    }
    panic!("no scan turn");
}

#[test]
fn a_look_around_after_a_move_that_ended_facing_off_its_course_looks_along_the_course_first() {
    // Round a cable's end the MOVE ended facing 73° left of its course:
    // the first look after the view it arrived with is along the course,
    // where the instruction's next landmark is (evaluation, lab).
    let (origin, first) = first_scan_after_a_move_arriving_at(1.27);
    assert!((origin.x, origin.y) == (3.0, 0.0), "{origin:?}");
    assert!(first.abs() < 1e-9, "first turn to {first} rad");
    // Within a scan turn of the course, the view it arrived with covered
    // it: the look-around turns on from where the robot faces.
    let (origin, first) = first_scan_after_a_move_arriving_at(0.3);
    assert!((origin.theta - 0.3).abs() < 1e-9, "{origin:?}");
    assert!((first - (0.3 + FRAC_PI_6)).abs() < 1e-9, "first turn to {first} rad");
}

#[test]
fn a_scan_turn_with_no_room_to_turn_looks_at_once_and_the_search_ends_in_a_question() {
    // Wedged: every drive answers BLOCKED. Each scan turn looks from where
    // the robot stands at once rather than after the turn's time limit, so
    // the exploration asks within seconds instead of waiting out every turn.
    let p = ExecutorParams::default();
    let mut m = mission(vec![find(1, "bicycle")]);
    let mut frame = 0u32;
    while !m.is_awaiting() {
        let stamp = f64::from(frame) * 0.2;
        assert!(stamp < 40.0, "asked by {stamp} s");
        cycle(&mut m, &p, at(stamp, 0.0, 0.0, 0.0), blind(|_| driven(DriveStatus::Blocked, 0.0, 1.0)));
        frame += 1;
    }
    // 12 turns of 4 s each for three look-arounds would take 144 s.
    assert!(f64::from(frame) * 0.2 < 40.0);
}

#[test]
fn exploration_is_bounded_scan_then_search_then_ask() {
    let p = ExecutorParams { scan_turns: 3, search_legs: 1, ..Default::default() };
    assert_eq!(after_look(0, 0, &p), ExplorePlan::Turn(1));
    assert_eq!(after_look(1, 0, &p), ExplorePlan::Turn(2));
    assert_eq!(after_look(2, 0, &p), ExplorePlan::Search(1));
    assert_eq!(after_look(0, 1, &p), ExplorePlan::Turn(1));
    assert_eq!(after_look(2, 1, &p), ExplorePlan::Ask);
}

#[test]
fn a_drive_that_stops_converging_near_its_goal_settles_there() {
    let p = ExecutorParams::default();
    let mut m = mission(vec![mv(2.0, 0.0)]);
    let mut t = 0.0;
    // 0.4 m from a goal reached within 0.25 m: within the settle margin, but no closer for 3 s.
    while t < p.settle_after_s {
        cycle(&mut m, &p, at(t, 1.6, 0.0, 0.0), blind(|_| driven(DriveStatus::Moving, 0.1, 0.4)));
        assert!(!events(&mut m).iter().any(|e| matches!(e, Event::SubgoalReached { .. })), "settled early at {t}");
        t += 0.5;
    }
    cycle(&mut m, &p, at(t, 1.6, 0.0, 0.0), blind(|_| driven(DriveStatus::Moving, 0.1, 0.4)));
    assert!(events(&mut m).iter().any(|e| matches!(e, Event::SubgoalReached { index: 0, .. })));
}

/// A confirmed chair (fused at (3.5, 0), its goal at (2, 0)) approached to
/// `(x, y)`, where the local planner reports BLOCKED; the events after
/// `seconds` of it.
fn blocked_beside_the_goal(x: f64, y: f64, seconds: f64) -> (Mission, Vec<Event>) {
    let p = ExecutorParams { confirm_frames: 3, confirm_window: 3, ..ExecutorParams::default() };
    let mut m = mission(vec![find(56, "chair")]);
    let goal = Pose2::new(2.0, 0.0, 0.0);
    let to_goal = (x - goal.x).hypot(y - goal.y);
    let mut sees = |r: &Request| -> Result<Reply, StageFailure> {
        Ok(match r {
            Request::StartStep { move_goal: None, .. } => Reply::StepStarted { goal: None },
            Request::Perceive { .. } => Reply::Perceived { boxes: vec![chair(70.0, 95.0)] },
            Request::Locate { .. } => located(goal),
            Request::Drive { .. } => driven(DriveStatus::Blocked, 0.0, to_goal),
            other => panic!("unexpected {other:?}"),
        })
    };
    for k in 0..3 {
        cycle(&mut m, &p, at(f64::from(k) * 0.2, 0.0, 0.0, 0.0), &mut sees);
    }
    let mut t = 1.0;
    while t <= 1.0 + seconds {
        cycle(&mut m, &p, at(t, x, y, 0.0), &mut sees);
        t += 0.2;
    }
    let events = events(&mut m);
    (m, events)
}

#[test]
fn a_drive_blocked_at_the_landmarks_stopping_distance_but_off_its_goal_settles_there() {
    let p = ExecutorParams::default();
    // 1.49 m from the chair, which the goal puts 1.5 m away, but 1.72 m
    // from the goal (beyond a cable, say): the instruction holds here.
    let (m, events) = blocked_beside_the_goal(3.0, 1.4, p.settle_after_s + 0.5);
    assert!(!m.is_awaiting());
    assert!(
        events
            .iter()
            .any(|e| matches!(e, Event::SubgoalReached { index: 0, error_m, .. } if (error_m - 1.72).abs() < 0.01)),
        "{events:?}"
    );
    // Not before the settle time (counted from the first drive, at 0.4 s).
    let (_, events) = blocked_beside_the_goal(3.0, 1.4, p.settle_after_s - 1.2);
    assert!(!events.iter().any(|e| matches!(e, Event::SubgoalReached { .. })), "{events:?}");
    // Farther from the chair than the goal, blocked: it asks the way.
    let (m, events) = blocked_beside_the_goal(0.5, 1.0, p.stuck_timeout_s + 0.5);
    assert!(m.is_awaiting());
    assert!(!events.iter().any(|e| matches!(e, Event::SubgoalReached { .. })), "{events:?}");
}

#[test]
fn a_blocked_drive_asks_after_the_stuck_timeout() {
    let p = ExecutorParams::default();
    let mut m = mission(vec![mv(6.0, 0.0)]);
    let mut t = 0.0;
    while !m.is_awaiting() {
        assert!(t <= p.stuck_timeout_s + 0.5, "still not asking at {t}");
        cycle(&mut m, &p, at(t, 0.0, 0.0, 0.0), blind(|_| driven(DriveStatus::Blocked, 0.0, 6.0)));
        t += 0.5;
    }
    assert!(t > p.stuck_timeout_s);
    match &events(&mut m)[..] {
        [Event::StepStarted { .. }, Event::StepFailed { reason, .. }, Event::ClarificationNeeded { question, .. }] => {
            assert_eq!(reason, "step 1: my way is blocked (6.0 m from the goal)");
            assert!(question.question.starts_with("My way is blocked"));
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_step_that_outlasts_its_time_limit_asks() {
    let p = ExecutorParams { step_timeout_s: 5.0, ..Default::default() };
    let mut m = mission(vec![mv(60.0, 0.0)]);
    for k in 0..=30 {
        cycle(&mut m, &p, at(f64::from(k) * 0.2, 0.0, 0.0, 0.0), blind(|_| driven(DriveStatus::Moving, 1.0, 60.0)));
    }
    assert!(m.is_awaiting());
    assert!(
        events(&mut m)
            .iter()
            .any(|e| matches!(e, Event::StepFailed { reason, .. } if reason.contains("did not finish within 5 s")))
    );
}

#[test]
fn a_failing_stage_is_retried_with_backoff_in_sensor_time_and_fails_the_mission_after_the_outage_limit() {
    let p = ExecutorParams::default();
    let mut m = mission(vec![mv(2.0, 0.0)]);
    let segmenter_down = |r: &Request| match r {
        Request::StartStep { move_goal, .. } => Ok(Reply::StepStarted { goal: move_goal.as_ref().map(goal_of) }),
        Request::Perceive { .. } => Err(StageFailure { stage: "segmenter", message: "connection refused".into() }),
        other => panic!("unexpected {other:?}"),
    };
    let mut tries = Vec::new();
    let mut finished = None;
    for k in 0..=110 {
        let t = f64::from(k) * 0.1;
        let (cmd, asked) = cycle(&mut m, &p, at(t, 0.0, 0.0, 0.0), segmenter_down);
        assert_eq!(cmd.twist, Twist::ZERO, "the robot is held while a stage is down");
        if !asked.is_empty() {
            tries.push(t);
        }
        if cmd.finished.is_some() {
            finished = Some((t, cmd));
            break;
        }
        assert!(!cmd.active, "a held robot may idle (a lockstep robot is then paced in real time)");
    }
    // Tries at 0, 0.1, 0.3, 0.7, 1.5, then every second.
    assert_eq!(&tries[..5].iter().map(|t| (t * 10.0_f64).round() as i32).collect::<Vec<_>>(), &[0, 1, 3, 7, 15]);
    assert!(tries.len() < 20, "{tries:?}");
    let (t, cmd) = finished.expect("the mission fails");
    assert!((t - STAGE_OUTAGE_S).abs() < 1e-9, "failed at {t}");
    assert_eq!(cmd.finished, Some(Outcome::Failed));
    match events(&mut m).last() {
        Some(Event::Finished { reason, .. }) => {
            assert_eq!(
                reason,
                "the segmenter service failed: connection refused for 10 s of robot time; the robot was stopped"
            )
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_stage_that_comes_back_resumes_the_step() {
    let p = ExecutorParams::default();
    let mut m = mission(vec![mv(2.0, 0.0)]);
    let down = |r: &Request| match r {
        Request::StartStep { .. } => Err(StageFailure { stage: "local-planner", message: "unavailable".into() }),
        other => panic!("unexpected {other:?}"),
    };
    cycle(&mut m, &p, at(0.0, 0.0, 0.0, 0.0), down);
    let (cmd, asked) = cycle(&mut m, &p, at(0.3, 0.0, 0.0, 0.0), blind(|_| driven(DriveStatus::Moving, 0.7, 2.0)));
    assert_eq!(asked.len(), 3, "start, perceive, drive: {asked:?}");
    assert_eq!((cmd.twist.linear, cmd.active), (0.7, true));
    // Recovered: a later failure starts a fresh outage (retry after 0.1 s).
    cycle(&mut m, &p, at(20.0, 0.0, 0.0, 0.0), |_| Err(StageFailure { stage: "segmenter", message: "x".into() }));
    let (_, asked) = cycle(&mut m, &p, at(20.1, 0.0, 0.0, 0.0), blind(|_| driven(DriveStatus::Moving, 0.7, 2.0)));
    assert!(!asked.is_empty());
}

#[test]
fn the_users_answer_replans_from_the_failed_step_and_the_mission_resumes() {
    let p = ExecutorParams { step_timeout_s: 1.0, ..Default::default() };
    let mut m = mission(vec![mv(1.0, 0.0), find(1, "bicycle")]);
    assert!(m.planner_query("go on").is_err(), "nothing was asked yet");
    cycle(&mut m, &p, at(0.0, 0.0, 0.0, 0.0), blind(|_| driven(DriveStatus::Reached, 0.0, 0.0)));
    for k in 1..=8 {
        cycle(&mut m, &p, at(f64::from(k) * 0.2, 1.0, 0.0, 0.0), blind(|_| driven(DriveStatus::Reached, 0.0, 0.0)));
    }
    assert!(m.is_awaiting());
    let Ok(PlannerQuery::Replan { failed_step, failure, answer, plan, .. }) = m.planner_query("skip it") else {
        panic!("a replan")
    };
    assert_eq!((failed_step, answer.as_str(), plan.len()), (1, "skip it", 2));
    assert!(failure.contains("did not finish within 1 s"), "{failure}");
    // A further question keeps the mission waiting.
    let q = Question { question: "Skip which?".into(), ..Default::default() };
    assert_eq!(m.on_planner_reply("skip it", PlannerReply::Question(q.clone())), Err(q));
    assert!(m.is_awaiting());
    let revised =
        m.on_planner_reply("go 1 m", PlannerReply::Plan { steps: vec![mv(1.0, 0.0)], plan_json: "[]".into() });
    assert_eq!(revised.map(|p| p.len()), Ok(2), "the reached step and the revised rest");
    assert!(!m.is_awaiting());
    let (_, asked) = cycle(&mut m, &p, at(2.0, 1.0, 0.0, 0.0), blind(|_| driven(DriveStatus::Moving, 0.5, 1.0)));
    assert!(matches!(asked[0], Request::StartStep { index: 1, action: Action::Move, .. }));
    assert!(events(&mut m).iter().any(|e| matches!(e, Event::Replanned { resume_index: 1, .. })));
}

/// Cycles of 0.5 s until the FOLLOW step ends; the step count.
fn follow_cycles(p: &ExecutorParams, follow: PlanStep) -> i32 {
    let mut m = mission(vec![follow]);
    let mut k = 0;
    let near = |r: &Request| -> Result<Reply, StageFailure> {
        Ok(match r {
            Request::StartStep { .. } => Reply::StepStarted { goal: None },
            Request::Perceive { .. } => Reply::Perceived { boxes: vec![person(70.0, 95.0)] },
            Request::Locate { moving, .. } => {
                assert!(moving);
                located(Pose2::new(1.0, 0.0, 0.0))
            }
            Request::Drive { .. } => driven(DriveStatus::Reached, 0.3, 0.0),
            other => panic!("unexpected {other:?}"),
        })
    };
    loop {
        let (cmd, _) = cycle(&mut m, p, at(f64::from(k) * 0.5, 0.0, 0.0, 0.0), near);
        // Within d_s is where a follower stays: zero, but still active.
        assert_eq!((cmd.twist, cmd.active), (Twist::ZERO, true));
        if events(&mut m).iter().any(|e| matches!(e, Event::SubgoalReached { .. })) {
            break;
        }
        k += 1;
        assert!(k < 40);
    }
    k
}

#[test]
fn a_follow_stays_with_its_target_until_its_time_is_up() {
    let p = ExecutorParams { confirm_frames: 1, follow_default_s: 2.0, ..Default::default() };
    let follow = PlanStep { class_id: 0, target: "person".into(), ..step(Action::Follow) };
    assert_eq!(follow_cycles(&p, follow.clone()), 4, "followed for the default 2 s of sensor time");
    // The plan's own duration wins over the default ("follow him for 5 seconds").
    assert_eq!(follow_cycles(&p, PlanStep { duration_s: 5.0, ..follow }), 10, "followed for the asked 5 s");
}

#[test]
fn metrics_come_from_frame_stamps_and_ground_truth() {
    let mut m = MetricsAcc::default();
    let truth = |x: f64, len: f64, soft: u32| Truth {
        pose: Some(Pose2::new(x, 0.0, 0.0)),
        path_length_m: len,
        hard_collisions: 0,
        soft_collisions: soft,
        odom_origin: Some(Pose2::default()),
    };
    m.observe(10.0, &Pose2::new(0.0, 0.0, 0.0), Some(&truth(0.0, 5.0, 1)));
    m.observe(10.1, &Pose2::new(0.3, 0.4, 0.0), Some(&truth(0.5, 5.5, 1)));
    m.observe(12.0, &Pose2::new(0.3, 1.4, 0.0), Some(&truth(0.6, 6.6, 2)));
    let p = m.metrics(2, 3, 1, Some(&Pose2::new(1.0, 0.0, 0.0)));
    assert!((p.duration_s - 2.0).abs() < 1e-9);
    assert!((p.odom_path_length_m - 1.5).abs() < 1e-9);
    assert_eq!(p.frames, 3);
    assert!(p.has_ground_truth);
    assert!((p.true_path_length_m - 1.6).abs() < 1e-9);
    assert_eq!(p.soft_collisions, 1);
    assert!((p.final_error_m - 0.4).abs() < 1e-9);
}

/// Stages that see the chair box and answer `located` with the fused
/// target `target(frame)`; the frame number comes from the stamp.
fn tally(
    target: impl Fn(u32) -> Vector3<f64>,
    f: u32,
    boxes: Vec<Detection>,
) -> impl FnMut(&Request) -> Result<Reply, StageFailure> {
    move |r| {
        Ok(match r {
            Request::StartStep { .. } => Reply::StepStarted { goal: None },
            Request::Perceive { .. } => Reply::Perceived { boxes: boxes.clone() },
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
                    range_m: t.x,
                })
            }
            Request::Drive { .. } => driven(DriveStatus::Moving, 0.5, 2.0),
            other => panic!("frame {f}: unexpected {other:?}"),
        })
    }
}

fn seen(m: &mut Mission) -> usize {
    events(m).iter().filter(|e| matches!(e, Event::TargetSeen { .. })).count()
}

#[test]
fn a_bare_majority_over_another_class_does_not_confirm_twice_as_many_sightings_do() {
    // Chair, couch, chair, couch, chair, couch, chair, chair: 5 sightings to
    // 3 frames of another class on the same spot. A bare majority; the
    // detector that confuses one frame in five could show this of a couch.
    // One more chair (6 to 3) confirms.
    let p = ExecutorParams::default();
    let mut m = mission(vec![find(56, "chair")]);
    let couch = Detection { class_id: 57, label: "couch".into(), ..chair(70.0, 95.0) };
    for f in 0..9u32 {
        let boxes = if [1, 3, 5].contains(&f) { vec![couch.clone()] } else { vec![chair(70.0, 95.0)] };
        let (cmd, _) =
            cycle(&mut m, &p, at(f64::from(f) * 0.2, 0.0, 0.0, 0.0), tally(|_| Vector3::new(3.5, 0.0, 0.5), f, boxes));
        assert_eq!(seen(&mut m), usize::from(f == 8), "frame {f}");
        assert_eq!(cmd.twist.linear != 0.0, f == 8, "frame {f}: driven once confirmed");
    }
}

#[test]
fn sightings_scattered_far_apart_never_confirm_a_target() {
    // Every frame a chair box, each putting the chair 2 m from the last:
    // false positives at random places, not one object. None counts for
    // another's candidate, so nothing is confirmed and nothing driven to.
    let p = ExecutorParams::default();
    let mut m = mission(vec![find(56, "chair")]);
    for f in 0..20u32 {
        let (cmd, _) = cycle(
            &mut m,
            &p,
            at(f64::from(f) * 0.2, 0.0, 0.0, 0.0),
            tally(
                |f| Vector3::new(3.0 + 2.0 * f64::from(f % 5), if f % 2 == 0 { 2.0 } else { -2.0 }, 0.5),
                f,
                vec![chair(70.0, 95.0)],
            ),
        );
        assert_eq!(cmd.twist, Twist::ZERO, "frame {f}");
    }
    assert_eq!(seen(&mut m), 0);
    // The same detector on one object, its estimates within centimetres:
    // confirmed after the vote's window.
    let mut m = mission(vec![find(56, "chair")]);
    for f in 0..8u32 {
        let wobble = 0.05 * f64::from(f % 3);
        cycle(
            &mut m,
            &p,
            at(f64::from(f) * 0.2, 0.0, 0.0, 0.0),
            tally(move |_| Vector3::new(3.5 + wobble, 0.0, 0.5), f, vec![chair(70.0, 95.0)]),
        );
    }
    assert_eq!(seen(&mut m), 1);
}

#[test]
fn a_search_leg_heads_for_the_last_unconfirmed_sighting() {
    // One glimpse of a chair 8 m away, 30° to the left, never confirmed:
    // after the look-around the search leg goes toward it, half the way to
    // the stopping distance; with no glimpse, straight ahead.
    let p = ExecutorParams { unseen_frames: 2, scan_turns: 3, look_frames: 1, search_legs: 1, ..Default::default() };
    let glimpse = Vector3::new(8.0 * FRAC_PI_6.cos(), 8.0 * FRAC_PI_6.sin(), 0.5);
    let mut m = mission(vec![find(56, "chair")]);
    cycle(&mut m, &p, at(0.0, 0.0, 0.0, 0.0), tally(move |_| glimpse, 0, vec![chair(70.0, 95.0)]));
    let mut legs = Vec::new();
    let mut frame = 1;
    while !m.is_awaiting() {
        assert!(frame < 300, "exploration is bounded");
        let (_, asked) = cycle(
            &mut m,
            &p,
            at(f64::from(frame) * 0.2, 0.0, 0.0, 0.0),
            blind(|_| driven(DriveStatus::Reached, 0.0, 0.0)),
        );
        legs.extend(asked.into_iter().filter_map(|r| match r {
            Request::MoveGoal(q) if q.f_dist > 0.0 => Some(q),
            _ => None,
        }));
        frame += 1;
    }
    assert_eq!(legs.len(), 1, "{legs:?}");
    assert!((legs[0].yaw - FRAC_PI_6).abs() < 1e-9, "{:?}", legs[0]);
    assert!((legs[0].f_dist - (8.0 - p.default_d_s) / 2.0).abs() < 1e-9, "{:?}", legs[0]);

    let pose = Pose2::new(1.0, 2.0, FRAC_PI_2);
    assert_eq!(search_leg(pose, None, 1.5, &p), MoveQuery { anchor: pose, f_dist: p.search_leg_m, yaw: 0.0, d_s: 0.0 });
    // A lead within reach: straight ahead; a near one: no farther than the stopping distance.
    let near = Vector3::new(1.0, 3.8, 0.0);
    assert_eq!(search_leg(pose, Some(&near), 1.5, &p).yaw, 0.0);
    let q = search_leg(pose, Some(&Vector3::new(1.0, 5.0, 0.0)), 1.5, &p);
    assert!((q.f_dist - 1.5).abs() < 1e-9 && q.yaw.abs() < 1e-9, "{q:?}");
}

fn table(x_min: f32, x_max: f32) -> Detection {
    Detection { class_id: 60, label: "dining table".into(), score: 0.8, ..chair(x_min, x_max) }
}

fn chair_next_to_the_table() -> PlanStep {
    PlanStep {
        reference: Some(TargetReference { relation: "next to".into(), target: "table".into(), class_id: 60 }),
        ..find(56, "chair")
    }
}

/// Runs `frames` frames of a FIND, each frame's boxes from `boxes(f)`;
/// returns the x_min of the box located in each frame and its track key.
fn located_boxes(step: PlanStep, frames: u32, boxes: impl Fn(u32) -> Vec<Detection>) -> Vec<(f32, String)> {
    let p = ExecutorParams::default();
    let mut m = mission(vec![step]);
    let mut out = Vec::new();
    for f in 0..frames {
        let frame_boxes = boxes(f);
        cycle(&mut m, &p, at(f64::from(f) * 0.2, 0.0, 0.0, 0.0), |r| {
            Ok(match r {
                Request::StartStep { .. } => Reply::StepStarted { goal: None },
                Request::Perceive { .. } => Reply::Perceived { boxes: frame_boxes.clone() },
                Request::Locate { detection, track_key, .. } => {
                    out.push((detection.x_min, track_key.clone()));
                    // Where the located box is: left of the image is +y.
                    let y = if detection.x_min < 80.0 { 1.0 } else { -1.0 };
                    located(Pose2::new(2.0, y, 0.0))
                }
                Request::Drive { .. } => driven(DriveStatus::Moving, 0.5, 2.0),
                other => panic!("frame {f}: unexpected {other:?}"),
            })
        });
    }
    out
}

#[test]
fn a_target_described_by_a_reference_is_the_instance_nearest_it() {
    // Two chairs: the more confident one on the left, the other on the right
    // beside a table. "The chair next to the table" is the right one; a
    // plain "chair" is the most confident.
    let scene = |_| vec![Detection { score: 0.95, ..chair(10.0, 30.0) }, chair(110.0, 125.0), table(128.0, 158.0)];
    let plain = located_boxes(find(56, "chair"), 3, scene);
    assert!(plain.iter().all(|(x, _)| *x == 10.0), "{plain:?}");
    let described = located_boxes(chair_next_to_the_table(), 3, scene);
    assert!(described.iter().all(|(x, _)| *x == 110.0), "{described:?}");
}

#[test]
fn a_candidate_gives_way_to_the_instance_by_the_reference_once_the_reference_is_seen() {
    // The table comes into view in frame 3: the left chair, tracked so far,
    // gives way to the right one on a new track, which is kept when the
    // table is out of view again (frame 6 on).
    let got = located_boxes(chair_next_to_the_table(), 8, |f| {
        let mut b = vec![Detection { score: 0.95, ..chair(10.0, 30.0) }, chair(110.0, 125.0)];
        if (3..6).contains(&f) {
            b.push(table(128.0, 158.0));
        }
        b
    });
    let xs: Vec<f32> = got.iter().map(|(x, _)| *x).collect();
    assert_eq!(xs, [10.0, 10.0, 10.0, 110.0, 110.0, 110.0, 110.0, 110.0]);
    assert!(
        got[..3].iter().all(|(_, k)| !k.contains('#')) && got[3..].iter().all(|(_, k)| k.ends_with("#1")),
        "{got:?}"
    );
}

#[test]
fn two_instances_about_as_near_the_reference_do_not_take_turns() {
    // A table between two chairs. The left one is nearer it in even frames
    // (0.73 m to 0.83 m on the ground), the right one in odd frames, by
    // 0.1 m, less than the margin: the first choice is kept, on one track.
    let got = located_boxes(chair_next_to_the_table(), 6, |f| {
        let right = if f % 2 == 1 { chair(98.0, 114.0) } else { chair(106.0, 122.0) };
        vec![chair(44.0, 60.0), right, table(66.0, 96.0)]
    });
    assert!(got.iter().all(|(x, k)| *x == 44.0 && !k.contains('#')), "{got:?}");
}

#[test]
fn a_reference_seen_in_an_earlier_frame_still_singles_out_the_instance() {
    // The table is seen alone first (a scan turning past it), the chairs
    // only later, without it: where the table stood is remembered in odom.
    let got = located_boxes(chair_next_to_the_table(), 6, |f| {
        if f < 3 {
            vec![table(128.0, 158.0)]
        } else {
            vec![Detection { score: 0.95, ..chair(10.0, 30.0) }, chair(110.0, 125.0)]
        }
    });
    assert_eq!(got.iter().map(|(x, _)| *x).collect::<Vec<_>>(), [110.0, 110.0, 110.0], "{got:?}");
}

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
                Request::Perceive { .. } => Reply::Perceived { boxes: boxes.clone() },
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
    assert!((q.f_dist - ExecutorParams::default().search_leg_m).abs() < 1e-9, "{q:?}");
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
