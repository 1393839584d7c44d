//! FOLLOW, scripted.

use super::super::test_support::*;
use super::super::*;

/// Cycles of 0.5 s until the FOLLOW step ends; the step count.
fn follow_cycles(p: &ExecutorParams, follow: PlanStep) -> i32 {
    let mut m = mission(vec![follow]);
    let mut k = 0;
    let near = |r: &Request| -> Result<Reply, StageFailure> {
        Ok(match r {
            Request::StartStep { .. } => Reply::StepStarted { goal: None },
            Request::Perceive { .. } => {
                Reply::Perceived { obstacles: Obstacles::default(), boxes: vec![person(70.0, 95.0)] }
            }
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
