//! Planner scenarios in closed loop: a robot that executes each (v, ω) for
//! one frame period (5 fps), seeing only what is inside the D455's field of
//! view, plans every frame until the goal is reached.

use std::f64::consts::PI;
use std::sync::OnceLock;

use vlnav_geometry::{GoalSpec, Pose2};
use vlnav_local_planner::cloud::{CloudBuilder, CloudParams};
use vlnav_local_planner::control::{FollowParams, RobotState, StepInput, StepOutput, StepStatus, View};
use vlnav_local_planner::planner::{Planner, PlannerParams};

const HALF_WIDTH: f64 = 0.335;
const HALF_FOV: f64 = 43.0 * PI / 180.0;
const DT: f64 = 0.2;
const VIEW: View = View { yaw: 0.0, half_fov: HALF_FOV, floor_from_m: 0.0, camera_x_m: 0.0, camera_z_m: 0.0 };

fn planner() -> &'static Planner {
    static P: OnceLock<Planner> = OnceLock::new();
    P.get_or_init(|| Planner::new(PlannerParams::default()))
}

/// Obstacle surface points (odom, with height) and no-go zone points.
#[derive(Default)]
struct World {
    obstacles: Vec<[f64; 3]>,
    no_go: Vec<[f64; 3]>,
}

impl World {
    /// A box's vertical faces from the floor to `height`, sampled every 2 cm.
    fn add_box(&mut self, x0: f64, y0: f64, x1: f64, y1: f64, height: f64) {
        let step = 0.02;
        let mut z = 0.0;
        while z <= height {
            let mut t = 0.0;
            while t <= 1.0 {
                let (x, y) = (x0 + (x1 - x0) * t, y0 + (y1 - y0) * t);
                self.obstacles.extend([[x, y0, z], [x, y1, z], [x0, y, z], [x1, y, z]]);
                t += step / (x1 - x0).max(y1 - y0);
            }
            z += 0.05;
        }
    }

    /// A floor zone reported as virtual points 0.5 m high every 0.1 m.
    fn add_no_go_zone(&mut self, x0: f64, y0: f64, x1: f64, y1: f64) {
        let mut x = x0;
        while x <= x1 + 1e-9 {
            let mut y = y0;
            while y <= y1 + 1e-9 {
                self.no_go.push([x, y, 0.5]);
                y += 0.1;
            }
            x += 0.1;
        }
    }

    /// What the camera sees from `pose`, in base_link.
    fn sense(&self, pose: &Pose2, builder: &mut CloudBuilder) -> vlnav_local_planner::cloud::ObstacleCloud {
        let to_base = |p: &[f64; 3]| {
            let b = pose.inverse_transform(&nalgebra::Vector2::new(p[0], p[1]));
            [b.x, b.y, p[2]]
        };
        let visible = |b: &[f64; 3]| b[0] > 0.3 && b[1].atan2(b[0]).abs() < HALF_FOV && b[0].hypot(b[1]) < 6.0;
        let obstacles: Vec<[f64; 3]> = self.obstacles.iter().map(to_base).filter(visible).collect();
        let no_go: Vec<[f64; 3]> = self.no_go.iter().map(to_base).filter(visible).collect();
        builder.from_points(&obstacles, &no_go)
    }
}

fn goal_at(x: f64, y: f64, tolerance: f64) -> GoalSpec {
    GoalSpec {
        pose: Pose2::new(x, y, 0.0),
        position_tolerance: tolerance,
        yaw_tolerance: 0.2,
        rotation_only: false,
        landmark: None,
    }
}

/// A turn on the spot at the origin to `theta` (odom), within 0.2 rad.
fn turn_to(theta: f64) -> GoalSpec {
    GoalSpec { pose: Pose2::new(0.0, 0.0, theta), rotation_only: true, ..goal_at(0.0, 0.0, 0.5) }
}

struct Run {
    poses: Vec<Pose2>,
    outputs: Vec<StepOutput>,
}

/// The pose after executing `out`'s (v, ω) for one frame period (unicycle).
fn advance(pose: &Pose2, out: &StepOutput) -> Pose2 {
    let th = pose.theta + out.angular * DT / 2.0;
    Pose2::new(pose.x + out.linear * DT * th.cos(), pose.y + out.linear * DT * th.sin(), pose.theta + out.angular * DT)
}

/// Closed loop until REACHED (or `steps` frames).
fn drive(world: &World, start: Pose2, goal: GoalSpec, steps: usize) -> Run {
    drive_with(FollowParams::default(), world, start, goal, steps)
}

fn drive_with(params: FollowParams, world: &World, start: Pose2, goal: GoalSpec, steps: usize) -> Run {
    drive_on(planner(), params, world, start, goal, steps)
}

fn drive_on(planner: &Planner, params: FollowParams, world: &World, start: Pose2, goal: GoalSpec, steps: usize) -> Run {
    let mut builder = CloudBuilder::new(CloudParams::default());
    let mut state = RobotState::default();
    let mut pose = start;
    let mut run = Run { poses: vec![pose], outputs: vec![] };
    for i in 0..steps {
        let cloud = world.sense(&pose, &mut builder);
        let out = state.step(
            planner,
            &params,
            StepInput { stamp: 1000.0 + i as f64 * DT, pose, goal, cloud: &cloud, max_speed: 0.0, view: VIEW },
        );
        assert!(out.linear.abs() <= params.max_speed + 1e-9, "speed {}", out.linear);
        assert!(out.angular.abs() <= params.max_yaw_rate + 1e-9, "yaw rate {}", out.angular);
        let reached = out.status == StepStatus::Reached;
        pose = advance(&pose, &out);
        run.outputs.push(out);
        run.poses.push(pose);
        if reached {
            break;
        }
    }
    run
}

fn distance_to_rect(p: &Pose2, x0: f64, y0: f64, x1: f64, y1: f64) -> f64 {
    let dx = (x0 - p.x).max(0.0).max(p.x - x1);
    let dy = (y0 - p.y).max(0.0).max(p.y - y1);
    dx.hypot(dy)
}

#[test]
fn obstacle_dead_ahead_is_passed_around() {
    let mut world = World::default();
    world.add_box(2.7, -0.3, 3.3, 0.3, 0.6);
    let run = drive(&world, Pose2::new(0.0, 0.0, 0.0), goal_at(6.0, 0.0, 0.3), 200);
    assert_eq!(
        run.outputs.last().unwrap().status,
        StepStatus::Reached,
        "did not reach the goal in {} frames",
        run.outputs.len()
    );
    let closest = run.poses.iter().map(|p| distance_to_rect(p, 2.7, -0.3, 3.3, 0.3)).fold(f64::INFINITY, f64::min);
    assert!(closest > HALF_WIDTH + 0.05, "robot centre came within {closest:.3} m of the box");
    let widest = run.poses.iter().map(|p| p.y.abs()).fold(0.0, f64::max);
    assert!(widest > 0.6, "never left the straight line (max |y| {widest:.2})");
    assert!(run.outputs.iter().any(|o| o.status == StepStatus::Moving
        && o.selection.as_ref().is_some_and(|s| s.path != 3 * 49 + 24 || s.rotation != 4)));
}

#[test]
fn red_floor_zone_is_passed_around_never_crossed() {
    let mut world = World::default();
    world.add_no_go_zone(2.5, -0.7, 3.5, 0.7);
    let run = drive(&world, Pose2::new(0.0, 0.0, 0.0), goal_at(6.0, 0.0, 0.3), 200);
    assert_eq!(
        run.outputs.last().unwrap().status,
        StepStatus::Reached,
        "did not reach the goal in {} frames",
        run.outputs.len()
    );
    let closest = run.poses.iter().map(|p| distance_to_rect(p, 2.5, -0.7, 3.5, 0.7)).fold(f64::INFINITY, f64::min);
    // The footprint (half-width 0.335 m) never overlaps the zone.
    assert!(closest > HALF_WIDTH, "robot centre came within {closest:.3} m of the zone");
}

#[test]
fn box_on_one_side_and_zone_on_the_other_are_both_respected() {
    // A box to the front-left and a no-go zone to the front-right: the way
    // between them is the only one, at the default weights.
    let mut world = World::default();
    world.add_box(2.0, 0.3, 2.4, 1.5, 0.6);
    world.add_no_go_zone(3.0, -1.2, 3.8, 0.2);
    let run = drive(&world, Pose2::new(0.0, 0.0, 0.0), goal_at(6.0, 0.0, 0.3), 200);
    assert_eq!(
        run.outputs.last().unwrap().status,
        StepStatus::Reached,
        "did not reach the goal in {} frames",
        run.outputs.len()
    );
    let zone = run.poses.iter().map(|p| distance_to_rect(p, 3.0, -1.2, 3.8, 0.2)).fold(f64::INFINITY, f64::min);
    let obstacle = run.poses.iter().map(|p| distance_to_rect(p, 2.0, 0.3, 2.4, 1.5)).fold(f64::INFINITY, f64::min);
    assert!(zone > HALF_WIDTH, "footprint entered the zone: centre {zone:.3} m from it");
    assert!(obstacle > HALF_WIDTH + 0.05, "centre came within {obstacle:.3} m of the box");
}

#[test]
fn no_free_path_stops_with_blocked() {
    let out = &dead_end(FollowParams::default()).outputs[0];
    assert_eq!(out.status, StepStatus::Blocked);
    assert_eq!((out.linear, out.angular), (0.0, 0.0));
    assert!(out.selection.is_none());
    assert_eq!(out.free_paths, 0);
    // It tried the smallest scale before giving up.
    assert!((out.path_scale - 0.75).abs() < 1e-9);
}

/// One frame in a dead end as wide as the robot plus 0.33 m: side walls
/// and a wall 1 m ahead, the goal 5 m beyond it.
fn dead_end(params: FollowParams) -> Run {
    let mut world = World::default();
    world.add_box(1.0, -0.5, 1.1, 0.5, 1.0);
    world.add_box(-1.0, 0.5, 1.1, 0.6, 1.0);
    world.add_box(-1.0, -0.6, 1.1, -0.5, 1.0);
    drive_with(params, &world, Pose2::new(0.0, 0.0, 0.0), goal_at(5.0, 0.0, 0.3), 1)
}

#[test]
fn with_detours_no_free_path_plans_a_way_back_out() {
    let out = &dead_end(FollowParams { detour: true, ..FollowParams::default() }).outputs[0];
    assert_eq!((out.linear, out.angular), (0.0, 0.0));
    assert_eq!(out.free_paths, 0);
    // The grid (unknown counts as free) shows a way back out and round the
    // walls: the step stands this frame and reports the way's length,
    // longer than the straight 5 m, instead of BLOCKED.
    assert_eq!(out.status, StepStatus::Moving);
    assert!(out.distance_to_goal > 6.0, "{}", out.distance_to_goal);
}

#[test]
fn open_wall_far_away_leaves_paths_free_and_goes_straight() {
    // The same wall 4 m out is beyond the goal: it must not block the approach.
    let mut world = World::default();
    world.add_box(4.0, -3.0, 4.1, 3.0, 1.0);
    let run = drive(&world, Pose2::new(0.0, 0.0, 0.0), goal_at(2.5, 0.0, 0.3), 100);
    assert_eq!(run.outputs.last().unwrap().status, StepStatus::Reached);
    assert!(run.poses.iter().all(|p| p.y.abs() < 0.1));
}

#[test]
fn goal_behind_rotates_in_place_then_drives() {
    let world = World::default();
    let run = drive(&world, Pose2::new(0.0, 0.0, 0.0), goal_at(-3.0, 0.5, 0.3), 200);
    let first = &run.outputs[0];
    assert_eq!(first.status, StepStatus::Rotating);
    assert_eq!(first.linear, 0.0);
    assert!(first.angular > 0.0, "the goal is to the left-behind: turn left");
    assert!((first.angular - 1.57).abs() < 1e-9, "0.8·error clamped to the limit, got {}", first.angular);
    // Turning in place keeps the position.
    let rotating: Vec<_> = run.outputs.iter().take_while(|o| o.status == StepStatus::Rotating).collect();
    assert!(rotating.len() >= 3);
    assert!(run.poses[rotating.len()].x.abs() < 1e-9);
    assert_eq!(run.outputs.last().unwrap().status, StepStatus::Reached);
}

#[test]
fn a_detour_that_points_away_from_the_goal_is_not_undone_by_rotating_back() {
    // A wall across the direct line, 1 m ahead; its open end is to the left,
    // so the way round heads well over 1 rad away from the goal.
    let mut world = World::default();
    world.add_box(1.0, -2.5, 1.2, 0.6, 1.0);
    let (start, goal) = (Pose2::new(0.0, 0.0, 0.0), goal_at(2.6, -0.6, 0.25));
    let run = drive(&world, start, goal, 400);
    assert_eq!(run.outputs.last().unwrap().status, StepStatus::Reached, "{:?}", run.poses.last());
    // Rotating back toward the goal as soon as it is 1 rad off (the initial
    // alignment rule applied all the way) turns back and forth at the wall.
    let naive =
        FollowParams { rerotate_threshold: FollowParams::default().rotate_threshold, ..FollowParams::default() };
    let turning_back = drive_with(naive, &world, start, goal, 400);
    assert!(
        turning_back.outputs.len() > run.outputs.len(),
        "with the detour kept: {} frames; turning back: {} frames",
        run.outputs.len(),
        turning_back.outputs.len()
    );
}

#[test]
fn a_goal_one_metre_before_a_landmark_is_approached_straight_on() {
    // "Stop 1 m before the suitcase": the goal is 1 m short of the box, so
    // the box lies just beyond the goal. It must not push the paths aside.
    let mut world = World::default();
    world.add_box(1.92, -0.3, 2.22, 0.3, 0.7);
    let run = drive(&world, Pose2::new(0.0, 0.0, 0.13), goal_at(1.07, -0.03, 0.25), 100);
    assert_eq!(run.outputs.last().unwrap().status, StepStatus::Reached, "stopped at {:?}", run.poses.last());
    assert!(run.outputs.len() < 30, "{} frames for 1 m", run.outputs.len());
    assert!(run.poses.iter().all(|p| p.y.abs() < 0.25), "no weaving");
}

#[test]
fn rotation_only_goal_turns_until_within_yaw_tolerance() {
    let world = World::default();
    let goal = turn_to(-1.2);
    let run = drive(&world, Pose2::new(0.0, 0.0, 0.0), goal, 50);
    assert!(run.outputs[0].angular < 0.0);
    assert_eq!(run.outputs[0].status, StepStatus::Rotating);
    let last = run.outputs.last().unwrap();
    assert_eq!(last.status, StepStatus::Reached);
    assert!(last.heading_error.abs() < 0.2);
    assert!(run.poses.iter().all(|p| p.x == 0.0 && p.y == 0.0));
}

#[test]
fn stuck_robot_reports_no_progress_after_five_seconds_of_sensor_time() {
    let params = FollowParams::default();
    let mut state = RobotState::default();
    let mut builder = CloudBuilder::new(CloudParams::default());
    let cloud = builder.from_points(&[], &[]);
    let goal = goal_at(5.0, 0.0, 0.3);
    let pose = Pose2::new(0.0, 0.0, 0.0);
    let mut statuses = vec![];
    // Wheels spinning in mud: the pose never changes; frames at 10 Hz.
    for i in 0..80 {
        let out = state.step(
            planner(),
            &params,
            StepInput { stamp: 50.0 + i as f64 * 0.1, pose, goal, cloud: &cloud, max_speed: 0.0, view: VIEW },
        );
        statuses.push(out.status);
    }
    let first = statuses.iter().position(|s| *s == StepStatus::NoProgress).expect("no NO_PROGRESS reported");
    assert_eq!(first, 50, "5.0 s after the first frame");
    assert!(statuses[..first].iter().all(|s| *s == StepStatus::Moving));
    // Reported once, then the window restarts.
    assert_eq!(statuses.iter().filter(|s| **s == StepStatus::NoProgress).count(), 1);
}

#[test]
fn speed_ramps_with_frame_stamps() {
    let params = FollowParams::default();
    let mut state = RobotState::default();
    let mut builder = CloudBuilder::new(CloudParams::default());
    let cloud = builder.from_points(&[], &[]);
    let goal = goal_at(8.0, 0.0, 0.3);
    let pose = Pose2::new(0.0, 0.0, 0.0);
    let speeds: Vec<f64> = (0..8)
        .map(|i| {
            state
                .step(
                    planner(),
                    &params,
                    StepInput { stamp: i as f64 * 0.25, pose, goal, cloud: &cloud, max_speed: 0.6, view: VIEW },
                )
                .linear
        })
        .collect();
    // First frame: the nominal 0.2 s period; then 0.25 s per frame at 1 m/s², capped at 0.6.
    let expected = [0.2, 0.45, 0.6, 0.6, 0.6, 0.6, 0.6, 0.6];
    for (s, e) in speeds.iter().zip(expected) {
        assert!((s - e).abs() < 1e-9, "{speeds:?}");
    }
}

#[test]
fn a_goal_whose_footprint_holds_a_wall_is_moved_sideways_out_of_it() {
    // A wall whose face runs along y = 0.32 (the wall behind a hydrant), the
    // goal 2.5 m ahead on y = 0 facing +x: the robot's body (half-width
    // 0.335 m) would overlap the wall there. The goal moves right, across its
    // heading, and the robot stops clear of the wall, its distance ahead kept.
    let mut world = World::default();
    world.add_box(0.8, 0.32, 4.0, 0.42, 1.0);
    let run = drive(&world, Pose2::new(0.0, 0.0, 0.0), goal_at(2.5, 0.0, 0.3), 200);
    let last = run.outputs.last().expect("frames");
    let end = *run.poses.last().expect("poses");
    assert_eq!(last.status, StepStatus::Reached, "the robot stopped at {end:?}");
    // The body's left edge (the centre's y + 0.335, heading within a few degrees) clears the wall.
    let left_edge = end.y + 0.335 * end.theta.cos() + 0.495 * end.theta.sin().abs();
    assert!(left_edge < 0.32, "the robot ends at {end:?}, its left side at y = {left_edge:.3}");
    assert!(end.y > -0.45, "moved farther than needed: {end:?}");
    assert!((end.x - 2.5).abs() < 0.1, "the distance ahead changed: {end:?}");
}

#[test]
fn memory_follows_the_odometry_when_it_is_re_anchored() {
    let params = FollowParams::default();
    let mut state = RobotState::default();
    let mut builder = CloudBuilder::new(CloudParams::default());
    let post = builder.from_points(&[[1.5, 0.8, 0.3], [1.5, 0.8, 0.5]], &[]);
    let empty = builder.from_points(&[], &[]);
    let input =
        |stamp, pose, cloud, view| StepInput { stamp, pose, goal: goal_at(9.0, 0.0, 0.3), cloud, max_speed: 0.0, view };
    state.step(planner(), &params, input(0.0, Pose2::new(5.0, 2.0, 0.3), &post, VIEW));
    // A subgoal is reached and odometry re-anchored at the origin; the robot
    // has not moved, and the post (now out of view) is where it was relative to it.
    let behind = View { yaw: std::f64::consts::PI, ..VIEW };
    state.step(planner(), &params, input(0.2, Pose2::new(0.0, 0.0, 0.0), &empty, behind));
    assert_eq!(state.cloud.cells.len(), 1);
    let c = state.cloud.cells[0];
    assert!((c.x - 1.5).abs() < 0.06 && (c.y - 0.8).abs() < 0.06, "the post moved to ({}, {})", c.x, c.y);
}

#[test]
fn obstacles_out_of_view_are_remembered_for_a_while() {
    let params = FollowParams::default();
    let mut state = RobotState::default();
    let mut builder = CloudBuilder::new(CloudParams::default());
    let goal = goal_at(5.0, 0.0, 0.3);
    // A post 1.5 m ahead, then the robot turns 90° left: the camera no longer sees it.
    let seen = builder.from_points(&[[1.5, 0.0, 0.3], [1.5, 0.0, 0.5]], &[]);
    let mut step = |stamp: f64, theta: f64, cloud: &vlnav_local_planner::cloud::ObstacleCloud| {
        let input = StepInput { stamp, pose: Pose2::new(0.0, 0.0, theta), goal, cloud, max_speed: 0.0, view: VIEW };
        state.step(planner(), &params, input);
        state.cloud.cells.len()
    };
    assert_eq!(step(0.0, 0.0, &seen), 1);
    let empty = builder.from_points(&[], &[]);
    // Turned away: the post is merged from memory.
    assert_eq!(step(0.2, 1.5, &empty), 1);
    assert_eq!(step(19.9, 1.5, &empty), 1);
    // Expired after `memory_s` (20 s) of sensor time.
    assert_eq!(step(20.1, 1.5, &empty), 0);
    // Seen on two frames, then out of view: remembered once, not once per frame.
    assert_eq!(step(20.2, 0.0, &seen), 1);
    assert_eq!(step(20.4, 0.0, &seen), 1);
    assert_eq!(step(20.6, 1.5, &empty), 1);
    // Back in view and gone: the current frame wins at once.
    assert_eq!(step(20.8, 0.0, &empty), 0);
}

#[test]
fn a_turn_in_place_beside_a_parked_car_first_backs_away_until_its_corners_clear_it() {
    // A car's corner 0.59 m from the robot's centre, front left: turning
    // left on the spot would swing the Husky's front corner (0.60 m out)
    // into it.
    let mut world = World::default();
    world.add_box(0.55, 0.2, 2.5, 2.2, 1.5);
    let goal = turn_to(1.5);
    let run = drive(&world, Pose2::new(0.0, 0.0, 0.0), goal, 80);
    let first = &run.outputs[0];
    assert!(first.linear < 0.0 && first.angular == 0.0, "backs away first: {first:?}");
    assert_eq!(run.outputs.last().unwrap().status, StepStatus::Reached);
    for (pose, out) in run.poses.iter().zip(&run.outputs) {
        if out.angular != 0.0 {
            let d = distance_to_rect(pose, 0.55, 0.2, 2.5, 2.2);
            assert!(d >= 0.6, "turned with the car {d:.2} m from the centre at {pose:?}");
        }
    }
}

#[test]
fn a_turn_in_place_with_no_way_out_is_blocked_not_ground_through() {
    let p = FollowParams::default();
    let mut builder = CloudBuilder::new(CloudParams::default());
    // Something 0.55 m ahead and something 0.6 m behind, both in the sweep.
    let mut points = Vec::new();
    for z in [0.2, 0.4, 0.6] {
        for y in [-0.1, 0.0, 0.1] {
            points.push([0.55, y, z]);
            points.push([-0.6, y, z]);
        }
    }
    let cloud = builder.from_points(&points, &[]);
    let goal = turn_to(1.5);
    let mut state = RobotState::default();
    let out = state.step(
        planner(),
        &p,
        StepInput { stamp: 0.0, pose: Pose2::new(0.0, 0.0, 0.0), goal, cloud: &cloud, max_speed: 0.0, view: VIEW },
    );
    assert_eq!((out.status, out.linear, out.angular), (StepStatus::Blocked, 0.0, 0.0));
}

#[test]
fn a_move_ends_on_its_goal_not_at_the_tolerance_circle() {
    // A MOVE 4 m ahead with the subgoal estimator's 0.25 m tolerance: the
    // robot stops within a few centimetres of the commanded distance
    // (odometry), not 0.25 m short of it.
    let world = World::default();
    let run = drive(&world, Pose2::new(0.0, 0.0, 0.0), goal_at(4.0, 0.0, 0.25), 200);
    assert_eq!(run.outputs.last().unwrap().status, StepStatus::Reached);
    let end = run.poses.last().unwrap();
    assert!((end.x - 4.0).abs() <= 0.05 && end.y.abs() <= 0.05, "stopped at {end:?}");
    // Never past the goal by more than the arrival band.
    assert!(run.poses.iter().all(|p| p.x <= 4.0 + 0.03), "overshot");
}

/// A person's column of points at `at` (base_link), boxed by the detector:
/// their cells marked as the frame's first person, standing at `at`.
fn person_frame(builder: &mut CloudBuilder, at: (f64, f64)) -> vlnav_local_planner::cloud::ObstacleCloud {
    let points: Vec<[f64; 3]> = (0..20)
        .flat_map(|k| {
            let z = 0.2 + 0.05 * f64::from(k);
            [[at.0, at.1, z], [at.0 + 0.05, at.1 + 0.05, z], [at.0 + 0.05, at.1 - 0.05, z]]
        })
        .collect();
    let mut cloud = builder.from_points(&points, &[]);
    for c in &mut cloud.cells {
        c.person = 1;
    }
    cloud.people = vec![Some(nalgebra::Vector2::new(at.0, at.1))];
    cloud
}

#[test]
fn a_turn_in_place_waits_while_a_walking_person_crosses_within_reach() {
    let params = FollowParams::default();
    let mut builder = CloudBuilder::new(CloudParams::default());
    // The goal lies behind the robot, so it turns in place; a person crosses
    // 0.85 m ahead of its centre at 1.1 m/s, from its right to its left.
    // The robot's pose is held so every frame sees the person.
    let behind = goal_at(-3.0, 0.1, 0.3);
    let mut state = RobotState::default();
    let mut turning = Vec::new();
    for k in 0..25 {
        let stamp = f64::from(k) * DT;
        let cloud = person_frame(&mut builder, (0.85, -2.0 + 1.1 * stamp));
        let input = StepInput {
            stamp,
            pose: Pose2::new(0.0, 0.0, 0.0),
            goal: behind,
            cloud: &cloud,
            max_speed: 0.0,
            view: VIEW,
        };
        let out = state.step(planner(), &params, input);
        assert_eq!(out.status, StepStatus::Rotating, "frame {k}: {out:?}");
        turning.push(out.angular.abs() > 1e-9);
    }
    // Before a velocity is measured (two sightings 0.4 s apart) the turn
    // goes ahead; once the person is known to walk, it waits while turning
    // would bring a corner nearer them than standing still, and goes on
    // once they have walked past.
    assert!(turning[..2].iter().all(|t| *t), "{turning:?}");
    assert!(turning[2..12].iter().any(|t| !t), "waits while they come within reach: {turning:?}");
    assert!(turning[20..].iter().all(|t| *t), "turns once they are past: {turning:?}");

    // The same person standing 1.1 m ahead: the turn goes ahead. (Within
    // 0.65 m + 0.3 m the turn in place first moves away from a person,
    // walking or not: people sway and step while the corners swing.)
    let mut state = RobotState::default();
    for k in 0..10 {
        let stamp = f64::from(k) * DT;
        let cloud = person_frame(&mut builder, (1.1, 0.0));
        let input = StepInput {
            stamp,
            pose: Pose2::new(0.0, 0.0, 0.0),
            goal: behind,
            cloud: &cloud,
            max_speed: 0.0,
            view: VIEW,
        };
        let out = state.step(planner(), &params, input);
        assert!(out.angular.abs() > 1e-9, "frame {k}: a standing person out of the sweep holds nothing: {out:?}");
    }
}

#[test]
fn near_a_walking_person_the_robot_drives_no_faster_than_it_can_stop_within_their_reach() {
    let params = FollowParams::default();
    let pp = params.people;
    // The speed cap stops the robot within the straying margin the reach
    // test allows (one frame of reaction, then braking at max_accel) …
    let stop = |v: f64| v * params.nominal_period_s + v * v / (2.0 * params.max_accel);
    assert!(stop(pp.near_walker_mps) <= pp.spread_max_m + 1e-9, "stops in {:.3} m", stop(pp.near_walker_mps));
    assert!(stop(pp.near_walker_mps + 0.05) > pp.spread_max_m, "and is the fastest that does");
    // … from within what a walker (1.5 m/s) and the robot close in the
    // horizon, plus the half-length, the person's radius and the straying.
    let reach = (1.5 + params.max_speed) * pp.horizon_s + params.half_length_m + pp.radius_m + pp.spread_max_m;
    assert!((pp.near_walker_m - reach).abs() < 0.01, "{} vs {reach}", pp.near_walker_m);

    // Driving 12 m down a hall; a person 2 m ahead and 1.5 m to the left
    // walks the same way at 1 m/s (in view all along), or stands there.
    let mut top = Vec::new();
    for walking in [true, false] {
        let mut builder = CloudBuilder::new(CloudParams::default());
        let mut state = RobotState::default();
        let goal = goal_at(12.0, 0.0, 0.3);
        let mut pose = Pose2::new(0.0, 0.0, 0.0);
        let mut fastest_near: f64 = 0.0;
        for k in 0..30 {
            let stamp = f64::from(k) * DT;
            let person = nalgebra::Vector2::new(2.0 + if walking { stamp } else { 0.0 }, 1.5);
            let at = pose.inverse_transform(&person);
            let cloud = person_frame(&mut builder, (at.x, at.y));
            let input = StepInput { stamp, pose, goal, cloud: &cloud, max_speed: 0.0, view: VIEW };
            let out = state.step(planner(), &params, input);
            if k >= 5 && at.norm() < pp.near_walker_m {
                fastest_near = fastest_near.max(out.linear);
            }
            pose = advance(&pose, &out);
        }
        top.push(fastest_near);
    }
    assert!(top[0] > 0.5 && top[0] <= pp.near_walker_mps + 1e-9, "beside a walker: up to {:.2} m/s", top[0]);
    assert!(top[1] > 0.9, "beside a standing person the robot drives on at speed: {:.2} m/s", top[1]);
}

#[test]
fn a_no_go_zone_wider_than_the_paths_reach_is_gone_round_with_detours_on_and_off() {
    // A painted zone 7 m wide and 1 m deep across the route, room on both
    // sides: every path toward the goal crosses it at first.
    let mut world = World::default();
    world.add_no_go_zone(3.0, -3.5, 4.0, 3.5);
    for detour in [false, true] {
        let params = FollowParams { detour, ..FollowParams::default() };
        let run = drive_with(params, &world, Pose2::new(0.0, 0.0, 0.0), goal_at(8.0, 0.0, 0.3), 900);
        check_gone_round(&run);
    }
}

fn check_gone_round(run: &Run) {
    let last = run.outputs.last().unwrap();
    assert_eq!(
        last.status,
        StepStatus::Reached,
        "stopped at {:?} after {} frames",
        run.poses.last(),
        run.outputs.len()
    );
    let closest = run.poses.iter().map(|p| distance_to_rect(p, 3.0, -3.5, 4.0, 3.5)).fold(f64::INFINITY, f64::min);
    assert!(closest > HALF_WIDTH, "robot centre came within {closest:.3} m of the zone");
    assert!(!run.outputs.iter().any(|o| o.status == StepStatus::Blocked), "reported BLOCKED on the way");
}

/// The robot in a passage 1.2 m wide that opens 1.3 m ahead, the goal 4 m
/// beyond; in its mouth either a person (boxed by the detector) or a post of
/// the same size. Returns the status of each frame.
fn doorway_taken(by_person: bool) -> Vec<StepStatus> {
    let params = FollowParams::default();
    let mut builder = CloudBuilder::new(CloudParams::default());
    let mut world = World::default();
    world.add_box(-1.0, 0.6, 1.3, 0.7, 1.0);
    world.add_box(-1.0, -0.7, 1.3, -0.6, 1.0);
    // A column 0.3 m across, 1.2 m high, in its mouth.
    world.add_box(1.0, -0.15, 1.3, 0.15, 1.2);
    let goal = goal_at(5.0, 0.0, 0.3);
    let mut state = RobotState::default();
    (0..15)
        .map(|k| {
            let stamp = 1000.0 + f64::from(k) * DT;
            let pose = Pose2::new(0.0, 0.0, 0.0);
            let mut cloud = world.sense(&pose, &mut builder);
            if by_person {
                // The detector boxes the column as a person.
                for c in &mut cloud.cells {
                    c.person = u8::from(c.x > 0.9 && c.x < 1.4 && c.y.abs() < 0.2);
                }
                cloud.people = vec![Some(nalgebra::Vector2::new(1.15, 0.0))];
            }
            let input = StepInput { stamp, pose, goal, cloud: &cloud, max_speed: 0.0, view: VIEW };
            state.step(planner(), &params, input).status
        })
        .collect()
}

#[test]
fn a_person_in_the_doorway_is_waited_for_and_a_post_there_blocks() {
    let person = doorway_taken(true);
    let post = doorway_taken(false);
    // Once the tracker is sure of the person (three sightings), the robot
    // waits for them; a post in the same place is furniture: BLOCKED.
    assert!(person[3..].iter().all(|s| *s == StepStatus::Waiting), "{person:?}");
    assert!(post.iter().all(|s| *s == StepStatus::Blocked), "{post:?}");
}

#[test]
fn a_door_a_little_wider_than_the_robot_is_driven_through_with_narrow_passages_on() {
    // A wall across the way 2 m ahead with a door 0.88 m clear, its middle
    // 0.05 m left: the usual paths keep the centre line 0.45 m from the
    // jambs, which leaves no line through it.
    let mut world = World::default();
    world.add_box(2.0, -3.0, 2.1, -0.39, 1.0);
    world.add_box(2.0, 0.49, 2.1, 3.0, 1.0);
    let goal = goal_at(5.0, 0.05, 0.3);
    let passed = |run: &Run| run.poses.iter().any(|p| p.x > 3.0);
    let off = drive(&world, Pose2::new(0.0, 0.0, 0.0), goal, 300);
    assert!(!passed(&off), "through the door without narrow passages");
    assert!(off.outputs.iter().any(|o| o.status == StepStatus::NoProgress || o.status == StepStatus::Blocked));
    // With them (`--local-planner-narrow`): stuck once, then through, with
    // the centre line never nearer a jamb than the half width.
    static NARROW: OnceLock<Planner> = OnceLock::new();
    let narrow = NARROW.get_or_init(|| {
        Planner::new(PlannerParams {
            narrow_clearance_m: vlnav_local_planner::planner::NARROW_CLEARANCE_M,
            ..PlannerParams::default()
        })
    });
    // Here the robot stands 0.6 m off the wall and paces along it, past the
    // door, before it turns in (its goal comes no nearer while it paces,
    // so the narrow passage restarts every 8 s — `control/narrow.rs`,
    // "circling" — at 0.3 m/s): about 190 s of frames.
    let params = FollowParams { narrow: true, ..FollowParams::default() };
    let on = drive_on(narrow, params, &world, Pose2::new(0.0, 0.0, 0.0), goal, 1200);
    assert_eq!(on.outputs.last().map(|o| o.status), Some(StepStatus::Reached), "{:?}", on.poses.last());
    for p in &on.poses {
        let jamb = distance_to_rect(p, 2.0, -3.0, 2.1, -0.39).min(distance_to_rect(p, 2.0, 0.49, 2.1, 3.0));
        assert!(jamb > 0.335, "the centre {jamb:.3} m from a jamb at {p:?}");
    }
}
