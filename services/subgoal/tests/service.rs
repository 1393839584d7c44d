//! SubgoalService over a real socket: a server on 127.0.0.1:0 and a tonic client.

use std::f64::consts::FRAC_PI_2;

use nalgebra::Vector3;
use tonic::Code;
use vlnav_geometry::camera::{Camera, Intrinsics, Mount};
use vlnav_geometry::convert::camera_to_proto;
use vlnav_geometry::depth::encode_depth_mm;
use vlnav_proto::v1 as pb;
use vlnav_proto::v1::subgoal_service_client::SubgoalServiceClient;
use vlnav_runtime::ServerConfig;
use vlnav_runtime::testing::{self, Connected};

const W: u32 = 640;
const H: u32 = 480;
const FX: f64 = 388.6187;
const CX: f64 = 320.6609;
const CY: f64 = 239.7847;

async fn start() -> Connected<SubgoalServiceClient<tonic::transport::Channel>> {
    let cfg = ServerConfig::default();
    let set = vlnav_subgoal::services(&vlnav_subgoal::Options::default(), &cfg).await.unwrap();
    testing::start_client(&cfg, set, SubgoalServiceClient::new).await.unwrap()
}

fn pose(x: f64, y: f64, theta: f64) -> pb::Pose2D {
    pb::Pose2D { x, y, theta }
}

/// A frame of a flat object at `object_m` filling `object` (pixel rect) in
/// front of a background at 8 m; camera 0.5 m up, 0.3 m forward.
fn frame(object: (u32, u32, u32, u32), object_m: f64, odom: pb::Pose2D, stamp: f64) -> pb::RgbdFrame {
    let (u0, v0, u1, v1) = object;
    let depth: Vec<f64> = (0..W * H)
        .map(|i| {
            let (u, v) = (i % W, i / W);
            if (u0..u1).contains(&u) && (v0..v1).contains(&v) { object_m } else { 8.0 }
        })
        .collect();
    pb::RgbdFrame {
        robot_id: "husky-1".into(),
        seq: 1,
        stamp,
        camera: Some(camera_to_proto(&Camera {
            width: W,
            height: H,
            intrinsics: Intrinsics { fx: FX, fy: FX, cx: CX, cy: CY },
            mount: Mount { translation: Vector3::new(0.3, 0.0, 0.5), ..Mount::default() },
            depth_min_m: 0.5,
            depth_max_m: 10.0,
        })),
        rgb: None,
        depth: Some(pb::DepthImage {
            width: W,
            height: H,
            data_mm: encode_depth_mm(&depth).into(),
            encoding: 0,
            disparity_step: 0.0,
        }),
        odom: Some(odom),
        odom_twist: None,
        labels: None,
    }
}

fn bbox(x0: f32, y0: f32, x1: f32, y1: f32) -> pb::BoundingBox {
    pb::BoundingBox { x_min: x0, y_min: y0, x_max: x1, y_max: y1, class_id: 56, score: 0.8, label: "chair".into() }
}

fn target_request(key: &str, frame: pb::RgbdFrame, b: pb::BoundingBox) -> pb::TargetGoalRequest {
    pb::TargetGoalRequest { track_key: key.into(), frame: Some(frame), r#box: Some(b), d_s: 1.0, moving: false }
}

#[tokio::test]
async fn move_goal_turns_then_drives() {
    let mut s = start().await;
    let g = s
        .client
        .move_goal(pb::MoveGoalRequest {
            anchor: Some(pose(1.0, 2.0, FRAC_PI_2)),
            f_dist: 4.0,
            yaw: FRAC_PI_2,
            d_s: 0.0,
        })
        .await
        .unwrap()
        .into_inner();
    let p = g.pose.unwrap();
    assert!((p.x + 3.0).abs() < 1e-9 && (p.y - 2.0).abs() < 1e-9, "{p:?}");
    assert!(!g.rotation_only);
    assert_eq!(g.position_tolerance, 0.25);
    let g = s
        .client
        .move_goal(pb::MoveGoalRequest { anchor: Some(pose(0.0, 0.0, 0.0)), f_dist: 0.0, yaw: -1.57, d_s: 0.0 })
        .await
        .unwrap()
        .into_inner();
    assert!(g.rotation_only);
    assert_eq!(g.yaw_tolerance, 0.2);
}

#[tokio::test]
async fn move_goal_rejects_bad_numbers() {
    let mut s = start().await;
    let e = s
        .client
        .move_goal(pb::MoveGoalRequest { anchor: Some(pose(f64::NAN, 0.0, 0.0)), f_dist: 1.0, yaw: 0.0, d_s: 0.0 })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::InvalidArgument);
    assert!(e.message().contains("anchor.x"), "{}", e.message());
    let e =
        s.client.move_goal(pb::MoveGoalRequest { anchor: None, f_dist: 1.0, yaw: 0.0, d_s: 0.0 }).await.unwrap_err();
    assert_eq!(e.code(), Code::InvalidArgument);
    assert!(e.message().contains("anchor"));
    let e = s
        .client
        .move_goal(pb::MoveGoalRequest { anchor: Some(pose(0.0, 0.0, 0.0)), f_dist: 1.0, yaw: 0.0, d_s: -1.0 })
        .await
        .unwrap_err();
    assert!(e.message().contains("d_s"));
}

#[tokio::test]
async fn target_goal_back_projects_the_box_and_stops_short() {
    let mut s = start().await;
    // Object centred on the principal point at 3 m; box twice its size.
    let f = frame((290, 210, 350, 270), 3.0, pose(2.0, 1.0, FRAC_PI_2), 10.0);
    let r = s
        .client
        .target_goal(target_request(
            "m1/2",
            f,
            bbox(CX as f32 - 60.0, CY as f32 - 60.0, CX as f32 + 60.0, CY as f32 + 60.0),
        ))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.status(), pb::EstimateStatus::Ok);
    let t = r.observed_target.unwrap();
    // base (3.3, 0, 0.5) → odom (2, 1 + 3.3) at heading 90°.
    assert!((t.x - 2.0).abs() < 0.01 && (t.y - 4.3).abs() < 0.01 && (t.z - 0.5).abs() < 0.01, "{t:?}");
    let g = r.goal.unwrap().pose.unwrap();
    assert!((g.x - 2.0).abs() < 0.01 && (g.y - 3.3).abs() < 0.01, "{g:?}");
    assert!((g.theta - FRAC_PI_2).abs() < 0.01);
    assert_eq!(r.observations, 1);
    assert!((r.range_m - 3.3).abs() < 0.01);
}

#[tokio::test]
async fn repeated_estimates_are_fused_and_outliers_rejected() {
    let mut s = start().await;
    let b = bbox(280.0, 200.0, 360.0, 280.0);
    let mut last = None;
    for (i, depth) in [3.0, 3.05, 2.95, 3.02, 6.5, 2.98, 3.01].into_iter().enumerate() {
        let f = frame((270, 190, 370, 290), depth, pose(0.0, 0.0, 0.0), i as f64 * 0.2);
        let r = s.client.target_goal(target_request("chair", f, b.clone())).await.unwrap().into_inner();
        if depth > 6.0 {
            assert_eq!(r.status(), pb::EstimateStatus::Outlier, "{}", r.detail);
            assert!(r.detail.contains("outlier"));
        } else {
            assert_eq!(r.status(), pb::EstimateStatus::Ok);
        }
        last = Some(r);
    }
    let r = last.unwrap();
    assert_eq!((r.observations, r.rejected), (7, 1));
    let fused = r.fused_target.unwrap();
    // Mean of the six inliers, plus the mount's 0.3 m.
    assert!((fused.x - (3.0 + 3.05 + 2.95 + 3.02 + 2.98 + 3.01) / 6.0 - 0.3).abs() < 0.01, "{fused:?}");
    assert!(r.spread_m > 0.0 && r.spread_m < 0.1);
    // A new track key starts over; a reset forgets.
    s.client.reset_track(pb::ResetTrackRequest { track_key: "chair".into() }).await.unwrap();
    let f = frame((270, 190, 370, 290), 4.0, pose(0.0, 0.0, 0.0), 5.0);
    let r = s.client.target_goal(target_request("chair", f, b)).await.unwrap().into_inner();
    assert_eq!(r.observations, 1);
}

#[tokio::test]
async fn box_without_depth_is_no_depth_not_nan() {
    let mut s = start().await;
    // Everything at 12 m: beyond depth_max.
    let mut f = frame((0, 0, 0, 0), 0.0, pose(0.0, 0.0, 0.0), 1.0);
    f.depth.as_mut().unwrap().data_mm = encode_depth_mm(&vec![12.0; (W * H) as usize]).into();
    let r =
        s.client.target_goal(target_request("none", f, bbox(100.0, 100.0, 200.0, 200.0))).await.unwrap().into_inner();
    assert_eq!(r.status(), pb::EstimateStatus::NoDepth);
    assert!(r.goal.is_none());
    assert!(r.detail.contains("no depth"), "{}", r.detail);
    assert!(r.range_m.is_finite() && r.spread_m.is_finite());
}

#[tokio::test]
async fn moving_target_reports_velocity() {
    let mut s = start().await;
    let mut r = None;
    for i in 0..15 {
        // The person walks away at 0.5 m/s: depth grows 0.1 m per 0.2 s frame.
        let d = 2.5 + 0.1 * i as f64;
        let f = frame((300, 150, 340, 330), d, pose(0.0, 0.0, 0.0), 100.0 + 0.2 * i as f64);
        let mut req = target_request("follow/david", f, bbox(300.0, 150.0, 340.0, 330.0));
        req.moving = true;
        r = Some(s.client.target_goal(req).await.unwrap().into_inner());
    }
    let r = r.unwrap();
    assert!((r.velocity_x - 0.5).abs() < 0.1 && r.velocity_y.abs() < 0.1, "({}, {})", r.velocity_x, r.velocity_y);
}

#[tokio::test]
async fn bad_target_requests_name_the_field() {
    let mut s = start().await;
    let ok = || frame((290, 210, 350, 270), 3.0, pose(0.0, 0.0, 0.0), 1.0);
    let b = bbox(280.0, 200.0, 360.0, 280.0);
    let cases: Vec<(pb::TargetGoalRequest, &str)> = vec![
        (pb::TargetGoalRequest { frame: None, ..target_request("k", ok(), b.clone()) }, "frame"),
        (target_request("", ok(), b.clone()), "track_key"),
        (
            {
                let mut f = ok();
                f.depth.as_mut().unwrap().data_mm.truncate(1000);
                target_request("k", f, b.clone())
            },
            "frame.depth.data_mm",
        ),
        (
            {
                let mut f = ok();
                f.depth.as_mut().unwrap().width = 320;
                target_request("k", f, b.clone())
            },
            "frame.depth.width/height",
        ),
        (
            {
                let mut f = ok();
                f.odom = Some(pose(0.0, f64::NAN, 0.0));
                target_request("k", f, b.clone())
            },
            "frame.odom.y",
        ),
        (
            {
                let mut f = ok();
                f.camera.as_mut().unwrap().intrinsics.as_mut().unwrap().fx = 0.0;
                target_request("k", f, b.clone())
            },
            "frame.camera.intrinsics.fx",
        ),
        (target_request("k", ok(), bbox(300.0, 200.0, 290.0, 280.0)), "box"),
        (target_request("k", ok(), bbox(700.0, 200.0, 800.0, 280.0)), "box"),
        (pb::TargetGoalRequest { r#box: None, ..target_request("k", ok(), b.clone()) }, "box"),
    ];
    for (req, field) in cases {
        let e = s.client.target_goal(req).await.unwrap_err();
        assert_eq!(e.code(), Code::InvalidArgument, "{field}: {}", e.message());
        assert!(e.message().contains(&format!("invalid {field}")), "expected field {field}: {}", e.message());
    }
    let e = s.client.reset_track(pb::ResetTrackRequest { track_key: " ".into() }).await.unwrap_err();
    assert_eq!(e.code(), Code::InvalidArgument);
}
