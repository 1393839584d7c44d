//! The bounded exploration, scripted: look-arounds, search legs, the question.

use std::f64::consts::{FRAC_PI_2, FRAC_PI_6};

use super::super::test_support::*;
use super::*;
use crate::executor::Reply;

/// Cycles `m` on frames 0.2 s apart, numbered from `first`, every drive
/// reached at once, until it asks (within `limit` frames); the robot faces
/// the heading `turned` gives after each goal asked for (from the goal and
/// the heading before). Returns every MOVE goal asked for, in order.
fn search_until_asked(
    m: &mut Mission,
    p: &ExecutorParams,
    first: u32,
    limit: u32,
    mut turned: impl FnMut(&MoveQuery, f64) -> f64,
) -> Vec<MoveQuery> {
    let (mut goals, mut heading) = (Vec::new(), 0.0);
    for frame in first.. {
        if m.is_awaiting() {
            return goals;
        }
        assert!(frame < limit, "exploration is bounded");
        let (cmd, asked) = cycle(
            m,
            p,
            at(f64::from(frame) * 0.2, 0.0, 0.0, heading),
            blind(|_| driven(DriveStatus::Reached, 0.0, 0.0)),
        );
        assert_eq!(cmd.twist, Twist::ZERO, "a goal reached at once leaves nothing to drive");
        for q in asked.into_iter().filter_map(|r| match r {
            Request::MoveGoal(q) => Some(q),
            _ => None,
        }) {
            heading = turned(&q, heading);
            goals.push(q);
        }
    }
    unreachable!()
}

#[test]
fn an_unseen_target_is_searched_for_boundedly_then_asked_about() {
    let p = ExecutorParams { unseen_frames: 2, scan_turns: 3, look_frames: 1, search_legs: 1, ..Default::default() };
    let mut m = mission(vec![find(1, "bicycle")]);
    let turns = search_until_asked(&mut m, &p, 0, 200, |_, h| h);
    // Three turns of a look-around from where it began, a search leg, then
    // the fan about the way ahead: one and two turns left, one and two right.
    let turns_of_30: Vec<f64> = turns.iter().map(|q| q.yaw / FRAC_PI_6).collect();
    for (got, want) in turns_of_30.iter().zip([1.0, 2.0, 3.0, 0.0, 1.0, 2.0, -1.0, -2.0]) {
        assert!((got - want).abs() < 1e-9, "{turns_of_30:?}");
    }
    assert_eq!(turns_of_30.len(), 8);
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
    let p = ExecutorParams { scan_turns: 3, search_legs: 1, search_fan_turns: 1, ..Default::default() };
    assert_eq!(after_look(0, 0, &p), ExplorePlan::Turn(1));
    assert_eq!(after_look(1, 0, &p), ExplorePlan::Turn(2));
    assert_eq!(after_look(2, 0, &p), ExplorePlan::Search(1));
    // After a leg, the fan: one turn each side.
    assert_eq!(after_look(0, 1, &p), ExplorePlan::Turn(1));
    assert_eq!(after_look(1, 1, &p), ExplorePlan::Ask);
}

#[test]
fn the_look_after_a_search_leg_fans_about_the_way_ahead_and_the_next_leg_keeps_it() {
    // Before the first leg, all around; after one, the way ahead only:
    // what lies behind was looked at before the leg.
    let p = ExecutorParams::default();
    let all: Vec<f64> = (0..p.scan_turns).map(|t| look_yaw(t, 0, &p)).collect();
    assert!((all[0] - FRAC_PI_6).abs() < 1e-9 && all[p.scan_turns as usize - 1].abs() < 1e-9, "{all:?}");
    let fan: Vec<f64> = (0..2 * p.search_fan_turns).map(|t| look_yaw(t, 1, &p) / FRAC_PI_6).collect();
    assert_eq!(fan.iter().map(|k| k.round() as i32).collect::<Vec<_>>(), vec![1, 2, -1, -2]);
    // Scripted: a target never seen, every turn and leg reached at once,
    // each leg ending facing a radian left of where it set off (round
    // something). Every leg sets off along the search's heading, the first
    // look's origin, not where the last leg or the fan ended facing.
    let p = ExecutorParams { unseen_frames: 2, look_frames: 1, search_legs: 2, ..Default::default() };
    let mut m = mission(vec![find(1, "bicycle")]);
    let goals = search_until_asked(&mut m, &p, 0, 400, |q, _| {
        // The robot turns to each scan heading at once; a leg ends a radian left.
        wrap(q.anchor.theta + q.yaw + if q.f_dist > 0.0 { 1.0 } else { 0.0 })
    });
    let legs: Vec<f64> = goals.iter().filter(|q| q.f_dist > 0.0).map(|q| wrap(q.anchor.theta + q.yaw)).collect();
    assert_eq!(legs.len(), 2, "{legs:?}");
    assert!(legs.iter().all(|h| h.abs() < 1e-9), "every leg along the search's heading: {legs:?}");
}

#[test]
fn search_legs_after_a_look_that_began_off_the_course_go_along_the_course() {
    // The MOVE ended facing 73° left of its course (+x): the look-around
    // begins a scan turn short of the course, so that its first turn faces
    // it, and the search legs after it go along the course itself, not
    // that scan turn off it.
    let p = ExecutorParams { unseen_frames: 2, scan_turns: 3, look_frames: 1, search_legs: 2, ..Default::default() };
    let mut m = mission(vec![mv(3.0, 0.0), find(56, "chair")]);
    cycle(&mut m, &p, at(0.0, 0.0, 0.0, 0.0), blind(|_| driven(DriveStatus::Moving, 1.0, 3.0)));
    cycle(&mut m, &p, at(5.0, 3.0, 0.0, 1.27), blind(|_| driven(DriveStatus::Reached, 0.0, 0.02)));
    let (mut heading, mut legs) = (1.27, Vec::new());
    for k in 0..400 {
        if m.is_awaiting() {
            break;
        }
        let pose = at(5.2 + 0.2 * f64::from(k), 3.0, 0.0, heading);
        let (_, asked) = cycle(&mut m, &p, pose, blind(|_| driven(DriveStatus::Reached, 0.0, 0.0)));
        for q in asked.iter().filter_map(|r| match r {
            Request::MoveGoal(q) => Some(*q),
            _ => None,
        }) {
            heading = wrap(q.anchor.theta + q.yaw);
            if q.f_dist > 0.0 {
                legs.push(heading);
            }
        }
    }
    assert!(m.is_awaiting(), "the search ends in a question");
    assert_eq!(legs.len(), 2, "{legs:?}");
    assert!(legs.iter().all(|h| h.abs() < 1e-9), "every leg along the course: {legs:?}");
}

#[test]
fn a_search_leg_heads_for_the_last_unconfirmed_sighting() {
    // One glimpse of a chair 8 m away, 30° to the left, never confirmed:
    // after the look-around the search leg goes toward it, half the way to
    // the stopping distance but at least a leg's length; with no glimpse,
    // straight ahead.
    let p = ExecutorParams { unseen_frames: 2, scan_turns: 3, look_frames: 1, search_legs: 1, ..Default::default() };
    let glimpse = Vector3::new(8.0 * FRAC_PI_6.cos(), 8.0 * FRAC_PI_6.sin(), 0.5);
    let mut m = mission(vec![find(56, "chair")]);
    // A box 10 px tall: a chair's 0.9 m at that range (fy 80).
    let far_chair = Detection { y_min: 55.0, y_max: 65.0, ..chair(70.0, 95.0) };
    cycle(&mut m, &p, at(0.0, 0.0, 0.0, 0.0), tally(move |_| glimpse, 0, vec![far_chair]));
    let legs: Vec<MoveQuery> =
        search_until_asked(&mut m, &p, 1, 300, |_, h| h).into_iter().filter(|q| q.f_dist > 0.0).collect();
    assert_eq!(legs.len(), 1, "{legs:?}");
    assert!((legs[0].anchor.theta + legs[0].yaw - FRAC_PI_6).abs() < 1e-9, "toward the glimpse: {:?}", legs[0]);
    let room = 8.0 - p.default_d_s;
    assert!((legs[0].f_dist - (room / 2.0).max(p.search_leg_m).min(room)).abs() < 1e-9, "{:?}", legs[0]);

    let pose = Pose2::new(1.0, 2.0, FRAC_PI_2);
    assert_eq!(search_leg(pose, None, 1.5, &p), MoveQuery { anchor: pose, f_dist: p.search_leg_m, yaw: 0.0, d_s: 0.0 });
    // A lead within reach: straight ahead; a near one: no farther than the stopping distance.
    let near = Vector3::new(1.0, 3.8, 0.0);
    assert_eq!(search_leg(pose, Some(&near), 1.5, &p).yaw, 0.0);
    let q = search_leg(pose, Some(&Vector3::new(1.0, 5.0, 0.0)), 1.5, &p);
    assert!((q.f_dist - 1.5).abs() < 1e-9 && q.yaw.abs() < 1e-9, "{q:?}");
}

#[test]
fn spent_search_legs_go_on_to_the_frontier_the_local_planner_reports() {
    // Every answer of the local planner reports edges of unseen space: one
    // at (3, 4), 53° off the search's heading (+x, where the look-around
    // began), one nearer but behind, at (−2, 0). The one search leg goes
    // along the heading as without them; then `FRONTIER_LEGS` legs go toward
    // the edge ahead, each to 0.75 m short of it, before the question.
    let p = ExecutorParams { unseen_frames: 2, scan_turns: 3, look_frames: 1, search_legs: 1, ..Default::default() };
    let mut m = mission(vec![find(1, "bicycle")]);
    let mut goals = Vec::new();
    for frame in 0..600u32 {
        if m.is_awaiting() {
            break;
        }
        let with_frontier = |_: &Goal| {
            let Reply::Driven { mut answer, path } = driven(DriveStatus::Reached, 0.0, 0.0) else { unreachable!() };
            answer.frontier = vec![[-2.0, 0.0], [3.0, 4.0]];
            Reply::Driven { answer, path }
        };
        let (_, asked) = cycle(&mut m, &p, at(f64::from(frame) * 0.2, 0.0, 0.0, 0.0), blind(with_frontier));
        goals.extend(asked.into_iter().filter_map(|r| match r {
            Request::MoveGoal(q) => Some(q),
            _ => None,
        }));
    }
    assert!(m.is_awaiting(), "asked after the legs");
    let legs: Vec<&MoveQuery> = goals.iter().filter(|q| q.f_dist > 0.0).collect();
    assert_eq!(legs.len(), 1 + FRONTIER_LEGS as usize, "{legs:?}");
    assert_eq!((legs[0].anchor.theta, legs[0].f_dist), (0.0, p.search_leg_m));
    for leg in &legs[1..] {
        assert!((leg.anchor.theta - 4f64.atan2(3.0)).abs() < 1e-9, "{leg:?}");
        assert!((leg.f_dist - (5.0 - FRONTIER_SHORT_M)).abs() < 1e-9 && leg.yaw == 0.0, "{leg:?}");
    }
    let failed: Vec<String> = events(&mut m)
        .iter()
        .filter_map(|e| match e {
            Event::StepFailed { reason, .. } => Some(reason.clone()),
            _ => None,
        })
        .collect();
    assert_eq!(failed, vec!["step 1: the bicycle not found after looking all around and 3 search leg(s)"]);

    // Facing +y from (1, 2): none reported, one where the robot stands, or
    // only one behind: no frontier leg; a far one: `FRONTIER_LEG_MAX_M`
    // toward it; of two, the nearer counting the turn off the heading.
    let pose = Pose2::new(1.0, 2.0, FRAC_PI_2);
    assert_eq!(frontier_leg(pose, &[]), None);
    assert_eq!(frontier_leg(pose, &[[1.2, 2.6]]), None);
    assert_eq!(frontier_leg(pose, &[[1.0, -3.0]]), None);
    let far = frontier_leg(pose, &[[1.0, 22.0]]).expect("a far frontier");
    assert_eq!((far.f_dist, far.anchor.theta, far.yaw), (FRONTIER_LEG_MAX_M, FRAC_PI_2, 0.0));
    // 3 m to the right (a quarter turn, +4 m) against 6 m ahead: ahead.
    let ahead = frontier_leg(pose, &[[4.0, 2.0], [1.0, 8.0]]).expect("one of two");
    assert!((ahead.anchor.theta - FRAC_PI_2).abs() < 1e-9, "{ahead:?}");
}
