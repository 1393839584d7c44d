//! A mission's dispatch, scripted: step start, time limit, stage outages, replanning.

use std::f64::consts::FRAC_PI_6;

use super::test_support::*;
use super::*;

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
