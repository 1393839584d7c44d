//! LocalPlannerService over a real socket, fed with synthetic depth frames
//! ray-cast from small box worlds through the D455 model.

use nalgebra::Vector3;
use tonic::Code;
use vlnav_geometry::camera::{Camera, Intrinsics, Mount};
use vlnav_geometry::convert::camera_to_proto;
use vlnav_geometry::depth::encode_depth_mm;
use vlnav_proto::v1 as pb;
use vlnav_proto::v1::local_planner_service_client::LocalPlannerServiceClient;
use vlnav_runtime::ServerConfig;
use vlnav_runtime::testing::{self, Connected};

const W: u32 = 640;
const H: u32 = 480;
const STRAIGHT_PATH: i32 = 3 * 49 + 24;

async fn start() -> Connected<LocalPlannerServiceClient<tonic::transport::Channel>> {
    let cfg = ServerConfig::default();
    let set = vlnav_local_planner::services(&vlnav_local_planner::Options::default(), &cfg).await.unwrap();
    testing::start_client(&cfg, set, LocalPlannerServiceClient::new).await.unwrap()
}

fn camera() -> Camera {
    Camera {
        width: W,
        height: H,
        intrinsics: Intrinsics { fx: 388.6187, fy: 388.6187, cx: 320.6609, cy: 239.7847 },
        mount: Mount { translation: Vector3::new(0.3, 0.0, 0.5), ..Mount::default() },
        depth_min_m: 0.3,
        depth_max_m: 10.0,
    }
}

/// Axis-aligned boxes in base_link: (min corner, max corner).
type Boxes = Vec<([f64; 3], [f64; 3])>;

/// Depth (optical z) of every pixel: the nearest box face or the floor.
fn render(boxes: &Boxes) -> Vec<u8> {
    let cam = camera();
    let k = cam.intrinsics;
    let t = cam.mount.optical_to_base();
    let origin = t.apply(&Vector3::zeros());
    let mut depth = Vec::with_capacity((W * H) as usize);
    for v in 0..H {
        for u in 0..W {
            // Ray with unit optical z: the hit parameter is the depth.
            let d = t.apply(&Vector3::new((u as f64 - k.cx) / k.fx, (v as f64 - k.cy) / k.fy, 1.0)) - origin;
            let mut best = if d.z < 0.0 { -origin.z / d.z } else { f64::INFINITY };
            for (lo, hi) in boxes {
                let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
                for a in 0..3 {
                    if d[a].abs() < 1e-12 {
                        if origin[a] < lo[a] || origin[a] > hi[a] {
                            t0 = f64::INFINITY;
                        }
                        continue;
                    }
                    let (ta, tb) = ((lo[a] - origin[a]) / d[a], (hi[a] - origin[a]) / d[a]);
                    t0 = t0.max(ta.min(tb));
                    t1 = t1.min(ta.max(tb));
                }
                if t0 <= t1 && t0 > 0.0 {
                    best = best.min(t0);
                }
            }
            depth.push(if best.is_finite() { best } else { 0.0 });
        }
    }
    encode_depth_mm(&depth)
}

fn frame(boxes: &Boxes, odom: pb::Pose2D, stamp: f64) -> pb::RgbdFrame {
    pb::RgbdFrame {
        robot_id: "husky-1".into(),
        seq: 0,
        stamp,
        camera: Some(camera_to_proto(&camera())),
        rgb: None,
        depth: Some(pb::DepthImage {
            width: W,
            height: H,
            data_mm: render(boxes).into(),
            encoding: 0,
            disparity_step: 0.0,
        }),
        odom: Some(pb::Pose2D { x: odom.x, y: odom.y, theta: odom.theta }),
        odom_twist: None,
        labels: None,
    }
}

fn goal(x: f64, y: f64) -> pb::Goal {
    pb::Goal {
        pose: Some(pb::Pose2D { x, y, theta: 0.0 }),
        position_tolerance: 0.3,
        yaw_tolerance: 0.2,
        rotation_only: false,
        landmark: None,
    }
}

fn request(robot: &str, f: pb::RgbdFrame, g: pb::Goal) -> pb::PlanStepRequest {
    pb::PlanStepRequest {
        robot_id: robot.into(),
        frame: Some(f),
        goal: Some(g),
        no_go_points: vec![],
        max_speed: 0.0,
        people: vec![],
    }
}

fn at(x: f64, y: f64, theta: f64) -> pb::Pose2D {
    pb::Pose2D { x, y, theta }
}

#[tokio::test]
async fn open_floor_goes_straight_for_the_goal() {
    let mut s = start().await;
    let r = s
        .client
        .plan_step(request("husky-1", frame(&vec![], at(0.0, 0.0, 0.0), 1.0), goal(5.0, 0.0)))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.status(), pb::LocalPlanStatus::Moving);
    assert_eq!((r.path_id, r.rotation_index), (STRAIGHT_PATH, 4));
    assert_eq!(r.obstacle_points, 0, "the floor must be removed as ground");
    let cmd = r.cmd.unwrap();
    assert!(cmd.linear > 0.0 && cmd.linear <= 1.0 && cmd.angular.abs() < 1e-9);
    assert_eq!(r.free_paths, 9 * 343);
    assert!((r.distance_to_goal - 5.0).abs() < 1e-9);
}

#[tokio::test]
async fn box_in_the_depth_frame_turns_the_path_aside() {
    let mut s = start().await;
    let boxes = vec![([2.0, -0.4, 0.0], [2.6, 0.4, 0.8])];
    let r = s
        .client
        .plan_step(request("husky-1", frame(&boxes, at(0.0, 0.0, 0.0), 1.0), goal(5.0, 0.0)))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.status(), pb::LocalPlanStatus::Moving);
    assert!(r.obstacle_points > 0);
    assert!(r.free_paths < 9 * 343);
    assert!(r.path_id >= 0 && (r.path_id, r.rotation_index) != (STRAIGHT_PATH, 4));
    // The same obstacle as no-go points: also avoided, and costlier to pass close.
    let no_go: Vec<pb::Point3> = (0..9)
        .flat_map(|i| (0..9).map(move |j| pb::Point3 { x: 2.0 + 0.075 * i as f64, y: -0.4 + 0.1 * j as f64, z: 0.5 }))
        .collect();
    let mut f = frame(&vec![], at(0.0, 0.0, 0.0), 1.0);
    f.robot_id = "husky-2".into();
    let mut req = request("husky-2", f, goal(5.0, 0.0));
    req.no_go_points = no_go;
    let r = s.client.plan_step(req).await.unwrap().into_inner();
    assert_eq!(r.status(), pb::LocalPlanStatus::Moving);
    assert!((r.path_id, r.rotation_index) != (STRAIGHT_PATH, 4));
    assert!(r.free_paths < 9 * 343);
}

#[tokio::test]
async fn dead_end_is_blocked_and_the_robot_stops() {
    let mut s = start().await;
    // A dead end 1.0 m wide (walls in odom = base_link at the origin pose).
    let walls = [
        ([1.0, -0.6, 0.0], [1.1, 0.6, 1.0]),
        ([-1.0, 0.5, 0.0], [1.1, 0.6, 1.0]),
        ([-1.0, -0.6, 0.0], [1.1, -0.5, 1.0]),
    ];
    let shifted = |dx: f64| -> Boxes {
        walls.iter().map(|(lo, hi)| ([lo[0] - dx, lo[1], lo[2]], [hi[0] - dx, hi[1], hi[2]])).collect()
    };
    // From 1.5 m back the side walls are in view (and the open floor before the entrance).
    let r = s
        .client
        .plan_step(request("husky-1", frame(&shifted(-1.5), at(-1.5, 0.0, 0.0), 1.0), goal(5.0, 0.0)))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.status(), pb::LocalPlanStatus::Moving);
    assert!(r.obstacle_points > 40, "{} cells", r.obstacle_points);
    // Inside: the camera sees only the end wall; the side walls come from memory.
    let r = s
        .client
        .plan_step(request("husky-1", frame(&shifted(0.0), at(0.0, 0.0, 0.0), 2.0), goal(5.0, 0.0)))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.status(), pb::LocalPlanStatus::Blocked);
    let cmd = r.cmd.unwrap();
    assert_eq!((cmd.linear, cmd.angular), (0.0, 0.0));
    assert_eq!(r.path_id, -1);
    assert_eq!(r.free_paths, 0);
    // Without that memory (a fresh robot) the unseen sides look open.
    let mut f = frame(&shifted(0.0), at(0.0, 0.0, 0.0), 2.0);
    f.robot_id = "husky-3".into();
    let r = s.client.plan_step(request("husky-3", f, goal(5.0, 0.0))).await.unwrap().into_inner();
    assert_ne!(r.status(), pb::LocalPlanStatus::Blocked);
}

#[tokio::test]
async fn goal_behind_rotates_and_goal_here_is_reached() {
    let mut s = start().await;
    let r = s
        .client
        .plan_step(request("husky-1", frame(&vec![], at(1.0, 1.0, 0.0), 1.0), goal(-2.0, 0.5)))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.status(), pb::LocalPlanStatus::Rotating);
    let cmd = r.cmd.unwrap();
    assert_eq!(cmd.linear, 0.0);
    assert!(cmd.angular < 0.0, "goal behind on the right: turn right, got {}", cmd.angular);
    assert!(r.heading_error.abs() > 1.0);
    let r = s
        .client
        .plan_step(request("husky-1", frame(&vec![], at(1.0, 1.0, 0.0), 1.2), goal(1.0, 1.1)))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.status(), pb::LocalPlanStatus::Reached);
    s.client.reset_robot(pb::ResetRobotRequest { robot_id: "husky-1".into() }).await.unwrap();
}

#[tokio::test]
async fn bad_requests_name_the_field() {
    let mut s = start().await;
    let ok = || request("husky-1", frame(&vec![], at(0.0, 0.0, 0.0), 1.0), goal(5.0, 0.0));
    let cases: Vec<(pb::PlanStepRequest, &str)> = vec![
        (pb::PlanStepRequest { frame: None, ..ok() }, "frame"),
        (pb::PlanStepRequest { robot_id: "".into(), ..ok() }, "robot_id"),
        (pb::PlanStepRequest { goal: None, ..ok() }, "goal"),
        (
            {
                let mut r = ok();
                let d = &mut r.frame.as_mut().unwrap().depth.as_mut().unwrap().data_mm;
                d.truncate(d.len() - 1);
                r
            },
            "frame.depth.data_mm",
        ),
        (
            {
                let mut r = ok();
                r.frame.as_mut().unwrap().depth.as_mut().unwrap().height = 240;
                r
            },
            "frame.depth.width/height",
        ),
        (
            {
                let mut r = ok();
                r.frame.as_mut().unwrap().odom = Some(at(0.0, 0.0, f64::NAN));
                r
            },
            "frame.odom.theta",
        ),
        (
            {
                let mut r = ok();
                r.goal.as_mut().unwrap().pose.as_mut().unwrap().x = f64::INFINITY;
                r
            },
            "goal.pose.x",
        ),
        (
            {
                let mut r = ok();
                r.goal.as_mut().unwrap().position_tolerance = 0.0;
                r
            },
            "goal.position_tolerance",
        ),
        (
            {
                let mut r = ok();
                r.no_go_points.push(pb::Point3 { x: f64::NAN, y: 0.0, z: 0.5 });
                r
            },
            "no_go_points[0]",
        ),
        (pb::PlanStepRequest { max_speed: -1.0, ..ok() }, "max_speed"),
        (
            pb::PlanStepRequest {
                people: vec![pb::BoundingBox {
                    x_min: 40.0,
                    y_min: 10.0,
                    x_max: 20.0,
                    y_max: 90.0,
                    ..Default::default()
                }],
                ..ok()
            },
            "people[0]",
        ),
        (
            pb::PlanStepRequest {
                people: vec![pb::BoundingBox {
                    x_min: f32::NAN,
                    y_min: 10.0,
                    x_max: 20.0,
                    y_max: 90.0,
                    ..Default::default()
                }],
                ..ok()
            },
            "people[0]",
        ),
        (
            {
                let mut r = ok();
                r.frame.as_mut().unwrap().robot_id = "husky-9".into();
                r
            },
            "frame.robot_id",
        ),
    ];
    for (req, field) in cases {
        let e = s.client.plan_step(req).await.unwrap_err();
        assert_eq!(e.code(), Code::InvalidArgument, "{field}: {}", e.message());
        assert!(e.message().contains(&format!("invalid {field}")), "expected field {field}: {}", e.message());
    }
    let e = s.client.reset_robot(pb::ResetRobotRequest { robot_id: "".into() }).await.unwrap_err();
    assert_eq!(e.code(), Code::InvalidArgument);
}
