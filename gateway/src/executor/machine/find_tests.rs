//! FIND, scripted: confirmation, the class vote, identities, projection, references.

use std::f64::consts::FRAC_PI_2;

use super::super::test_support::*;
use super::super::*;
use super::*;

/// The `k`-th located sighting: odd ones with depth (a goal 2 m ahead), even
/// ones without.
fn every_other_without_depth(k: u32) -> Reply {
    if k.is_multiple_of(2) {
        Reply::Located(Estimate {
            status: EstimateStatus::NoDepth,
            goal: None,
            fused_target: None,
            observed: None,
            range_m: 0.0,
        })
    } else {
        located(Pose2::new(2.0, 0.0, 0.0))
    }
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
                Reply::Perceived { obstacles: Obstacles::default(), boxes: vec![chair(70.0, 95.0)] }
            }
            Request::Locate { detection, d_s, moving: false, .. } => {
                assert_eq!(detection.x_min, 70.0);
                assert_eq!(*d_s, p.default_d_s);
                located(goal)
            }
            Request::Drive { goal: g, .. } => {
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
            Request::Perceive { .. } => {
                Reply::Perceived { obstacles: Obstacles::default(), boxes: vec![chair(70.0, 95.0)] }
            }
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
                Request::Perceive { .. } => Reply::Perceived { obstacles: Obstacles::default(), boxes: boxes.clone() },
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
fn a_person_walking_in_front_of_a_candidate_hides_it_and_does_not_outvote_it() {
    // The chair stands 3.5 m ahead; in frames 1–4 a person passes 1 m in
    // front of it, their box centred where the chair projects, the floor
    // under it 1 m away. The same four frames of a couch where the chair
    // stands drop it (above); a person in front is no vote: the chair is
    // watched on and confirmed.
    let p = ExecutorParams::default();
    let mut m = mission(vec![find(56, "chair")]);
    let passer = Detection { y_min: 20.0, y_max: 115.0, ..person(70.0, 95.0) };
    let mut confirmed_at = None;
    for f in 0..12u32 {
        let boxes = if (1..5).contains(&f) { vec![passer.clone()] } else { vec![chair(70.0, 95.0)] };
        cycle(&mut m, &p, at(f64::from(f) * 0.2, 0.0, 0.0, 0.0), tally(|_| Vector3::new(3.5, 0.0, 0.5), f, boxes));
        if seen(&mut m) > 0 {
            confirmed_at.get_or_insert(f);
        }
    }
    let f = m.find().expect("a FIND step");
    assert!(f.rejected.is_empty(), "the chair's place was not dropped: {:?}", f.rejected);
    assert_eq!(f.votes_against, 0);
    assert!(confirmed_at.is_some(), "the chair is confirmed once seen again");
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
            Request::Perceive { .. } => {
                Reply::Perceived { obstacles: Obstacles::default(), boxes: vec![chair(70.0, 95.0)] }
            }
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
            Request::Perceive { .. } => Reply::Perceived {
                obstacles: Obstacles::default(),
                boxes: vec![person(10.0, 30.0), person(70.0, 95.0)],
            },
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
    // Every frame a chair box, each putting the chair 2 m from the last
    // (the box a chair's 0.9 m at that depth): false positives at random
    // places, not one object. None counts for another's candidate, so
    // nothing is confirmed and nothing driven to.
    let p = ExecutorParams::default();
    let mut m = mission(vec![find(56, "chair")]);
    let place = |f: u32| Vector3::new(3.0 + 2.0 * f64::from(f % 5), if f.is_multiple_of(2) { 2.0 } else { -2.0 }, 0.5);
    for f in 0..20u32 {
        let h = (0.9 * 80.0 / (place(f).x - 0.3)) as f32;
        let b = Detection { y_min: 60.0 - h / 2.0, y_max: 60.0 + h / 2.0, ..chair(70.0, 95.0) };
        let (cmd, _) = cycle(&mut m, &p, at(f64::from(f) * 0.2, 0.0, 0.0, 0.0), tally(place, f, vec![b]));
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
fn with_the_size_check_boxes_too_small_for_a_person_on_a_wall_a_metre_away_never_confirm_one() {
    // A false positive in every frame, each on the same wall 1 m ahead and
    // 30 px tall: 0.38 m at that depth (fy 80), no person. The same boxes
    // 60 px tall (0.75 m, a person half hidden) are confirmed; without the
    // check (the default), so are the small ones.
    for (size_check, h, confirmed) in [(true, 30.0, 0), (true, 60.0, 1), (false, 30.0, 1)] {
        let p = ExecutorParams { size_check, ..ExecutorParams::default() };
        let mut m = mission(vec![find(0, "person")]);
        let b = Detection { y_min: 60.0 - h / 2.0, y_max: 60.0 + h / 2.0, ..person(70.0, 90.0) };
        for f in 0..10u32 {
            let wall = Vector3::new(1.3, 0.1 * f64::from(f % 3), 0.6);
            let mut answer = tally(move |_| wall, f, vec![b.clone()]);
            // Nothing counts as a sighting: the robot goes looking.
            cycle(&mut m, &p, at(f64::from(f) * 0.2, 0.0, 0.0, 0.0), |r| match r {
                Request::MoveGoal(q) => Ok(Reply::Goal(goal_of(q))),
                other => answer(other),
            });
        }
        assert_eq!(seen(&mut m), confirmed, "{h} px, size check {size_check}");
    }
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
                Request::Perceive { .. } => {
                    Reply::Perceived { obstacles: Obstacles::default(), boxes: frame_boxes.clone() }
                }
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

/// Stages that see `boxes(frame)` and locate the chair (the only box of
/// the target's class) at `chair_at`; every drive and turn reached at once.
fn sees_until(
    f: u32,
    boxes: impl Fn(u32) -> Vec<Detection>,
    chair_at: Vector3<f64>,
) -> impl FnMut(&Request) -> Result<Reply, StageFailure> {
    sees_driving(f, boxes, chair_at, DriveStatus::Reached)
}

/// `sees_until`, every drive answered with `status`.
fn sees_driving(
    f: u32,
    boxes: impl Fn(u32) -> Vec<Detection>,
    chair_at: Vector3<f64>,
    status: DriveStatus,
) -> impl FnMut(&Request) -> Result<Reply, StageFailure> {
    move |r| {
        Ok(match r {
            Request::StartStep { move_goal, .. } => Reply::StepStarted { goal: move_goal.as_ref().map(goal_of) },
            Request::Perceive { .. } => Reply::Perceived { obstacles: Obstacles::default(), boxes: boxes(f) },
            Request::Locate { .. } => Reply::Located(Estimate {
                status: EstimateStatus::Ok,
                goal: Some(Goal {
                    pose: Pose2::new(chair_at.x - 1.5, chair_at.y, 0.0),
                    position_tolerance: 0.25,
                    yaw_tolerance: 0.2,
                    rotation_only: false,
                    landmark: None,
                }),
                fused_target: Some(chair_at),
                observed: Some(chair_at),
                range_m: chair_at.x,
            }),
            Request::MoveGoal(q) => Reply::Goal(goal_of(q)),
            Request::Drive { .. } => driven(status, 0.0, 0.0),
            other => panic!("frame {f}: unexpected {other:?}"),
        })
    }
}

fn asked_anything(m: &mut Mission) -> (usize, bool) {
    let ev = events(m);
    let seen = ev.iter().filter(|e| matches!(e, Event::TargetSeen { .. })).count();
    (seen, ev.iter().any(|e| matches!(e, Event::ClarificationNeeded { .. })))
}

/// "The chair next to the table", every frame showing `boxes` and the
/// chair at (3.5, −1): how often it is confirmed over one vote window and
/// the frame after it.
fn confirmed_in_one_window(boxes: Vec<Detection>) -> usize {
    let p = ExecutorParams::default();
    let mut m = mission(vec![chair_next_to_the_table()]);
    let mut seen = 0;
    for f in 0..p.confirm_window + 1 {
        let scene = |_| boxes.clone();
        cycle(&mut m, &p, at(f64::from(f) * 0.1, 0.0, 0.0, 0.0), sees_until(f, scene, Vector3::new(3.5, -1.0, 0.5)));
        seen += asked_anything(&mut m).0;
    }
    seen
}

#[test]
fn a_candidate_with_its_reference_next_to_it_is_confirmed_in_the_usual_window() {
    // The chair 3.5 m ahead, 1 m right; the table's footprint 1.4 m from it.
    assert_eq!(confirmed_in_one_window(vec![chair(110.0, 125.0), table(128.0, 158.0)]), 1);
}

/// A table 4.3 m ahead and 3.5 m left: over 4 m from the chair at
/// (3.5, −1) that `a_lone_chair_set_aside` shows.
fn a_table_elsewhere() -> Detection {
    Detection { y_min: 50.0, y_max: 70.0, ..table(0.0, 20.0) }
}

/// "The chair next to the table": a chair in view for the first 12 frames
/// (0.1 s apart), and a table, but far from it; every drive answered with
/// `status`.
/// Runs `frames` frames; returns the frame the chair was confirmed in and
/// the goal then driven to.
fn a_lone_chair_set_aside(p: &ExecutorParams, frames: u32, status: DriveStatus) -> (Option<u32>, Option<Pose2>) {
    let mut m = mission(vec![chair_next_to_the_table()]);
    let chair_at = Vector3::new(3.5, -1.0, 0.5);
    let (mut seen_at, mut driven_to) = (None, None);
    for f in 0..frames {
        let scene = move |_| if f < 12 { vec![chair(110.0, 125.0), a_table_elsewhere()] } else { Vec::new() };
        let (_, asked) =
            cycle(&mut m, p, at(f64::from(f) * 0.1, 0.0, 0.0, 0.0), sees_driving(f, scene, chair_at, status));
        let (seen, question) = asked_anything(&mut m);
        assert!(!question, "frame {f}: asked the user");
        if seen > 0 {
            seen_at.get_or_insert(f);
            driven_to = asked.iter().find_map(|r| match r {
                Request::Drive { goal, .. } if !goal.rotation_only => Some(goal.pose),
                _ => None,
            });
        }
    }
    (seen_at, driven_to)
}

#[test]
fn a_candidate_with_no_reference_next_to_it_is_set_aside_then_taken_when_the_search_finds_none() {
    // It passes the vote (frame 7) but is set aside while the robot looks
    // around; the look-around finds no chair by a table, so the robot goes
    // to the one it saw instead of asking.
    let p = ExecutorParams { unseen_frames: 2, scan_turns: 2, look_frames: 1, search_legs: 0, ..Default::default() };
    let (seen_at, goal) = a_lone_chair_set_aside(&p, 40, DriveStatus::Reached);
    assert!(seen_at.is_some_and(|f| f > 12), "taken after the search, not in the vote: {seen_at:?}");
    assert_eq!(goal, Some(Pose2::new(2.0, -1.0, 0.0)), "driven to the chair's approach goal");
}

#[test]
fn a_candidate_is_not_set_aside_when_no_reference_was_seen_anywhere() {
    // No table in any frame: it may only be too small for the detector at
    // this range, so the chair is confirmed in the usual window.
    assert_eq!(confirmed_in_one_window(vec![chair(110.0, 125.0)]), 1);
}

#[test]
fn the_search_for_an_instance_next_to_its_reference_is_bounded_in_time() {
    // The default exploration, every turn and leg taking its full time
    // (12 turns of 4 s, then four search legs of 24 s, each with a fan),
    // would run on for minutes; the set-aside chair is taken at the end of
    // the first look after REFERENCE_SEARCH_S (a look-around, a leg, a turn).
    let p = ExecutorParams::default();
    let (seen_at, goal) = a_lone_chair_set_aside(&p, 1200, DriveStatus::Moving);
    let set_aside_s = f64::from(p.confirm_window - 1) * 0.1;
    let after = f64::from(seen_at.expect("taken")) * 0.1 - set_aside_s;
    assert!((REFERENCE_SEARCH_S..REFERENCE_SEARCH_S + 30.0).contains(&after), "taken {after} s after set aside");
    assert!(goal.is_some());
}

#[test]
fn an_instance_off_the_course_waits_for_a_look_along_the_course() {
    // A 3 m MOVE along +x ended facing 1 rad left of its course; a chair is
    // in view on the left, 57° off the course. The robot first turns to
    // look along the course, then (nothing there) takes the chair.
    let p = ExecutorParams { unseen_frames: 2, look_frames: 1, ..Default::default() };
    let mut m = mission(vec![mv(3.0, 0.0), find(56, "chair")]);
    cycle(&mut m, &p, at(0.0, 0.0, 0.0, 0.0), blind(|_| driven(DriveStatus::Moving, 1.0, 3.0)));
    cycle(&mut m, &p, at(5.0, 3.0, 0.0, 1.0), blind(|_| driven(DriveStatus::Reached, 0.0, 0.02)));
    let chair_at = Vector3::new(3.0 + 2.0 * 1.0f64.cos(), 2.0 * 1.0f64.sin(), 0.5);
    let mut turns = Vec::new();
    for f in 0..20u32 {
        let (_, asked) = cycle(
            &mut m,
            &p,
            at(5.1 + f64::from(f) * 0.1, 3.0, 0.0, 1.0),
            sees_until(f, |_| vec![chair(70.0, 95.0)], chair_at),
        );
        assert_eq!(asked_anything(&mut m).0, 0, "frame {f}: confirmed off the course");
        turns.extend(asked.iter().filter_map(|r| match r {
            Request::MoveGoal(q) => Some(wrap_angle(q.anchor.theta + q.yaw)),
            _ => None,
        }));
    }
    assert!(turns.first().is_some_and(|h| h.abs() < 1e-9), "first turn to the course: {turns:?}");
    // Facing the course, nothing in view; then the chair comes round again.
    cycle(&mut m, &p, at(7.2, 3.0, 0.0, 0.0), sees_until(0, |_| Vec::new(), chair_at));
    let mut seen = 0;
    for f in 0..p.confirm_window + 1 {
        let stamp = 7.3 + f64::from(f) * 0.1;
        cycle(&mut m, &p, at(stamp, 3.0, 0.0, 1.0), sees_until(f, |_| vec![chair(70.0, 95.0)], chair_at));
        seen += asked_anything(&mut m).0;
    }
    assert_eq!(seen, 1, "taken once the course was looked along");
}

/// A 3 m MOVE along +x, then a FIND of a chair the stages put at
/// `chair_at`, in view for 12 frames: the frame its sighting is taken, if
/// any (the search is a look-around of two turns, no legs).
fn chair_after_a_move(chair_at: Vector3<f64>) -> Option<u32> {
    let p = ExecutorParams { unseen_frames: 2, scan_turns: 2, look_frames: 1, search_legs: 0, ..Default::default() };
    let mut m = mission(vec![mv(3.0, 0.0), find(56, "chair")]);
    cycle(&mut m, &p, at(0.0, 0.0, 0.0, 0.0), blind(|_| driven(DriveStatus::Moving, 1.0, 3.0)));
    cycle(&mut m, &p, at(5.0, 3.0, 0.0, 0.0), blind(|_| driven(DriveStatus::Reached, 0.0, 0.02)));
    let mut seen_at = None;
    for f in 0..40u32 {
        let scene = move |_| if f < 12 { vec![chair(70.0, 95.0)] } else { Vec::new() };
        cycle(&mut m, &p, at(5.1 + f64::from(f) * 0.1, 3.0, 0.0, 0.0), sees_until(f, scene, chair_at));
        let (seen, question) = asked_anything(&mut m);
        assert!(!question, "frame {f}: asked the user");
        if seen > 0 {
            seen_at.get_or_insert(f);
        }
    }
    seen_at
}

#[test]
fn an_instance_behind_where_the_move_ended_is_taken_only_when_the_search_finds_none_ahead() {
    // "Move 3 meters forward, then stop before the chair": a chair 2 m
    // ahead of where the MOVE ended is confirmed in the vote; one 2.5 m
    // behind that point (seen over the shoulder) is set aside while the
    // robot looks on, and taken when the search finds none ahead.
    let p = ExecutorParams::default();
    let ahead = chair_after_a_move(Vector3::new(5.0, 0.5, 0.5));
    assert!(ahead.is_some_and(|f| f <= p.confirm_window), "ahead: confirmed in the vote, {ahead:?}");
    let behind = chair_after_a_move(Vector3::new(0.5, 1.0, 0.5));
    assert!(behind.is_some_and(|f| f >= 12), "behind: taken after the search, not in the vote, {behind:?}");
}
