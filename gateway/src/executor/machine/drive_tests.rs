//! MOVE and the approach to a goal, scripted: progress, settling, asking when stuck.

use std::f64::consts::FRAC_PI_6;

use super::super::test_support::*;
use super::super::*;
use super::PERSON_WAIT_S;

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
            Request::Drive { goal: goal_of(&query), obstacles: Obstacles::default() },
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
fn a_frames_obstacles_go_with_its_drive_and_are_forgotten_at_the_next_frame() {
    let p = ExecutorParams::default();
    let mut m = mission(vec![mv(2.0, 0.0)]);
    let seen = Obstacles { no_go: vec![Vector3::new(1.0, 0.2, 0.0)], people: vec![person(10.0, 30.0)] };
    let stages = |perceived: Obstacles| {
        move |r: &Request| -> Result<Reply, StageFailure> {
            Ok(match r {
                Request::StartStep { move_goal, .. } => Reply::StepStarted { goal: move_goal.as_ref().map(goal_of) },
                Request::Perceive { .. } => Reply::Perceived { boxes: vec![], obstacles: perceived.clone() },
                Request::Drive { .. } => driven(DriveStatus::Moving, 0.5, 2.0),
                other => panic!("unexpected request {other:?}"),
            })
        }
    };
    let drives = |asked: Vec<Request>| -> Vec<Obstacles> {
        asked
            .into_iter()
            .filter_map(|r| match r {
                Request::Drive { obstacles, .. } => Some(obstacles),
                _ => None,
            })
            .collect()
    };
    let (_, asked) = cycle(&mut m, &p, at(0.0, 0.0, 0.0, 0.0), stages(seen.clone()));
    assert_eq!(drives(asked), vec![seen]);
    // A frame whose perception fails drives nowhere; the next one drives with what it perceived.
    let (_, asked) = cycle(&mut m, &p, at(0.1, 0.0, 0.0, 0.0), |r| match r {
        Request::Perceive { .. } => Err(StageFailure { stage: "segmenter", message: "down".into() }),
        other => stages(Obstacles::default())(other),
    });
    assert!(drives(asked).is_empty());
    let (_, asked) = cycle(&mut m, &p, at(1.0, 0.0, 0.0, 0.0), stages(Obstacles::default()));
    assert_eq!(drives(asked), vec![Obstacles::default()]);
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
            Request::Perceive { .. } => {
                Reply::Perceived { obstacles: Obstacles::default(), boxes: vec![chair(70.0, 95.0)] }
            }
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
fn waiting_for_a_person_is_no_lack_of_progress_and_is_asked_about_after_its_own_bound() {
    let p = ExecutorParams::default();
    let mut m = mission(vec![mv(6.0, 0.0)]);
    let mut t = 0.0;
    // Blocked for just under the stuck timeout, then a person in the way for
    // longer than both the stuck and the progress timeouts together.
    while t < p.stuck_timeout_s - 1.0 {
        cycle(&mut m, &p, at(t, 0.0, 0.0, 0.0), blind(|_| driven(DriveStatus::Blocked, 0.0, 6.0)));
        t += 0.5;
    }
    let waiting_from = t;
    while !m.is_awaiting() {
        assert!(t <= waiting_from + PERSON_WAIT_S + 0.5, "still not asking at {t}");
        cycle(&mut m, &p, at(t, 0.0, 0.0, 0.0), blind(|_| driven(DriveStatus::Waiting, 0.0, 6.0)));
        t += 0.5;
    }
    assert!(t - waiting_from > PERSON_WAIT_S, "asked after {:.1} s of waiting", t - waiting_from);
    // The progress clock (no closer since t = 0) would have asked by now.
    assert!(t > p.progress_timeout_s);
    match &events(&mut m)[..] {
        [Event::StepStarted { .. }, Event::StepFailed { reason, .. }, Event::ClarificationNeeded { question, .. }] => {
            assert_eq!(reason, "step 1: a person is in my way (6.0 m from the goal)");
            assert!(question.question.starts_with("A person is in my way"));
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_wait_that_ends_restarts_the_stuck_clock_but_the_wait_counts_until_the_robot_gets_closer() {
    let p = ExecutorParams::default();
    let mut m = mission(vec![mv(6.0, 0.0)]);
    let mut t = 0.0;
    // Blocked and waiting in turns, each spell shorter than its own bound:
    // each wait breaks the blocked spell, so the way is never called
    // blocked; but the robot gets no closer, and once the first wait is
    // PERSON_WAIT_S old it asks about the person, at the next wait.
    let spell = p.stuck_timeout_s - 2.0;
    let mut waiting_from = None;
    while !m.is_awaiting() {
        assert!(t < 3.0 * PERSON_WAIT_S, "never asked");
        let status = if ((t / spell) as u32).is_multiple_of(2) { DriveStatus::Blocked } else { DriveStatus::Waiting };
        if status == DriveStatus::Waiting {
            waiting_from.get_or_insert(t);
        }
        cycle(&mut m, &p, at(t, 0.0, 0.0, 0.0), blind(move |_| driven(status, 0.0, 6.0)));
        t += 0.5;
    }
    let waited = t - 0.5 - waiting_from.unwrap();
    assert!((PERSON_WAIT_S..=PERSON_WAIT_S + spell).contains(&waited), "asked after {waited:.1} s");
    match &events(&mut m)[..] {
        [Event::StepStarted { .. }, Event::StepFailed { reason, .. }, Event::ClarificationNeeded { .. }] => {
            assert_eq!(reason, "step 1: a person is in my way (6.0 m from the goal)");
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn waiting_broken_by_short_moves_is_asked_about_unless_the_robot_gets_closer() {
    let p = ExecutorParams::default();
    // Stopped for a person, then a short creep that gets nowhere, and again:
    // asked once the first wait is PERSON_WAIT_S old.
    let mut m = mission(vec![mv(6.0, 0.0)]);
    let mut t = 0.0;
    while !m.is_awaiting() {
        assert!(t < 2.0 * PERSON_WAIT_S, "never asked");
        let status = if (t as u32).is_multiple_of(4) { DriveStatus::Moving } else { DriveStatus::Waiting };
        cycle(&mut m, &p, at(t, 0.0, 0.0, 0.0), blind(move |_| driven(status, 0.1, 6.0)));
        t += 0.5;
    }
    assert!(t - 0.5 >= PERSON_WAIT_S, "asked at {t}");
    // The same, but each move brings the robot 0.2 m closer: it is getting
    // somewhere, and waits on without asking.
    let mut m = mission(vec![mv(60.0, 0.0)]);
    let mut t = 0.0;
    let mut left = 60.0;
    while t < 3.0 * PERSON_WAIT_S {
        let moving = (t as u32).is_multiple_of(4);
        if moving {
            left -= 0.1;
        }
        let status = if moving { DriveStatus::Moving } else { DriveStatus::Waiting };
        cycle(&mut m, &p, at(t, 60.0 - left, 0.0, 0.0), blind(move |_| driven(status, 0.1, left)));
        assert!(!m.is_awaiting(), "asked at {t}");
        t += 0.5;
    }
}

#[test]
fn waiting_while_going_round_is_not_asked_about_but_waiting_in_place_is() {
    let p = ExecutorParams::default();
    // Going round something: stopped for a person now and then, moving on
    // sideways (0.1 m a second) without getting closer to the goal. Each
    // wait counts afresh once the robot is WAIT_MOVED_M from where it began.
    let mut m = mission(vec![mv(6.0, 0.0)]);
    let mut t = 0.0;
    let mut y = 0.0;
    while t < 3.0 * PERSON_WAIT_S {
        let moving = (t as u32).is_multiple_of(2);
        if moving {
            y += 0.05;
        }
        let status = if moving { DriveStatus::Moving } else { DriveStatus::Waiting };
        cycle(&mut m, &p, at(t, 0.0, y, 0.0), blind(move |_| driven(status, 0.1, 6.0)));
        assert!(!m.is_awaiting(), "asked at {t}, {y:.2} m on");
        t += 0.5;
    }
    // The same stops, the robot staying within WAIT_MOVED_M: asked.
    let mut m = mission(vec![mv(6.0, 0.0)]);
    let mut t = 0.0;
    while !m.is_awaiting() {
        assert!(t < 2.0 * PERSON_WAIT_S, "never asked");
        let moving = (t as u32).is_multiple_of(2);
        let status = if moving { DriveStatus::Moving } else { DriveStatus::Waiting };
        let y = 0.2 * (t / 4.0).sin();
        cycle(&mut m, &p, at(t, 0.0, y, 0.0), blind(move |_| driven(status, 0.1, 6.0)));
        t += 0.5;
    }
    assert!(t - 0.5 >= PERSON_WAIT_S, "asked at {t}");
}

#[test]
fn an_engaged_emergency_stop_pauses_the_mission_and_its_release_resumes_it() {
    let p = ExecutorParams::default();
    let mut m = mission(vec![mv(6.0, 0.0)]);
    // Moving, then held by the e-stop for far longer than every timeout:
    // no stage is asked, the command is zero and idle, nothing is asked.
    let (cmd, _) = cycle(&mut m, &p, at(0.0, 0.0, 0.0, 0.0), blind(|_| driven(DriveStatus::Moving, 0.5, 6.0)));
    assert_eq!(cmd.twist.linear, 0.5);
    let mut t = 0.5;
    while t < 3.0 * p.progress_timeout_s.max(p.stuck_timeout_s) {
        let frame = Frame { estop: true, ..at(t, 0.5, 0.0, 0.0) };
        let (cmd, asked) = cycle(&mut m, &p, frame, blind(|_| unreachable!("no stage while paused")));
        assert!(asked.is_empty());
        assert_eq!(cmd, Command { twist: Twist::ZERO, active: false, finished: None });
        t += 0.5;
    }
    // Released: the step goes on where it was, its clocks started afresh
    // (no closer than at t = 0, which without the restart is long past
    // the progress timeout).
    let (cmd, asked) = cycle(&mut m, &p, at(t, 0.5, 0.0, 0.0), blind(|_| driven(DriveStatus::Moving, 0.5, 6.0)));
    assert!(matches!(asked[..], [Request::Perceive { .. }, Request::Drive { .. }]), "{asked:?}");
    assert_eq!((cmd.twist.linear, cmd.active), (0.5, true));
    assert!(!m.is_awaiting());
    assert!(matches!(events(&mut m)[..], [Event::StepStarted { .. }]), "no step failed, nothing asked");
}
