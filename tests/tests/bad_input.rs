//! Bad input gets the right status with a message a person can act on, and
//! the gateway keeps serving everyone else.

use vlnav_e2e::TestStack;
use vlnav_proto::v1::{
    CameraInfo, CameraIntrinsics, DepthImage, EdgeHello, EdgeMessage, ListRobotsRequest, Pose2D, RgbdFrame,
    SensorFrame, SubmitMissionRequest, edge_message, submit_mission_request::Instruction,
};

fn text(robot: &str, t: &str, dry_run: bool) -> SubmitMissionRequest {
    SubmitMissionRequest { robot_id: robot.into(), instruction: Some(Instruction::Text(t.into())), dry_run }
}

fn frame(robot: &str, seq: u64, w: u32, h: u32, theta: f64) -> EdgeMessage {
    EdgeMessage {
        kind: Some(edge_message::Kind::Frame(SensorFrame {
            frame: Some(RgbdFrame {
                robot_id: robot.into(),
                seq,
                stamp: seq as f64 * 0.1,
                camera: Some(CameraInfo {
                    width: w,
                    height: h,
                    intrinsics: Some(CameraIntrinsics { fx: 100.0, fy: 100.0, cx: w as f64 / 2.0, cy: h as f64 / 2.0 }),
                    mount: None,
                    depth_min_m: 0.3,
                    depth_max_m: 10.0,
                }),
                depth: Some(DepthImage {
                    width: w,
                    height: h,
                    data_mm: vec![0; (w * h * 2) as usize].into(),
                    encoding: 0,
                    disparity_step: 0.0,
                }),
                odom: Some(Pose2D { x: 0.0, y: 0.0, theta }),
                ..Default::default()
            }),
            truth: None,
        })),
    }
}

fn hello(robot: &str) -> EdgeMessage {
    EdgeMessage {
        kind: Some(edge_message::Kind::Hello(EdgeHello {
            robot_id: robot.into(),
            driver: "test".into(),
            ..Default::default()
        })),
    }
}

/// Attaches with `robot`'s certificate, sends `msgs`, returns the status that ends the command stream.
async fn attach_and_send(t: &TestStack, robot: &str, msgs: Vec<EdgeMessage>) -> tonic::Status {
    let mut fleet = t.fleet_as_robot(robot);
    let (tx, rx) = tokio::sync::mpsc::channel(8);
    for m in msgs {
        tx.send(m).await.unwrap();
    }
    let result = fleet.attach(tokio_stream::wrappers::ReceiverStream::new(rx)).await;
    let status = match result {
        Err(s) => s,
        Ok(resp) => {
            let mut commands = resp.into_inner();
            loop {
                match tokio::time::timeout(std::time::Duration::from_secs(20), commands.message())
                    .await
                    .expect("the gateway answers")
                {
                    Ok(Some(_)) => continue,
                    Ok(None) => panic!("stream ended without an error status"),
                    Err(s) => break s,
                }
            }
        }
    };
    drop(tx);
    status
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_input_gets_clear_statuses_and_the_gateway_keeps_serving() {
    let t = TestStack::start(|_| {}).await;
    let mut missions = t.missions().await;

    let e = missions.submit_mission(text("husky-1", "   ", false)).await.unwrap_err();
    assert_eq!(e.code(), tonic::Code::InvalidArgument);
    assert!(e.message().contains("empty"), "{}", e.message());

    let e = missions
        .submit_mission(SubmitMissionRequest { robot_id: "husky-1".into(), instruction: None, dry_run: false })
        .await
        .unwrap_err();
    assert_eq!(e.code(), tonic::Code::InvalidArgument);
    assert!(e.message().contains("`text` or `audio`"), "{}", e.message());

    let e = missions.submit_mission(text("no-such-robot", "move 2 m ahead", false)).await.unwrap_err();
    assert_eq!(e.code(), tonic::Code::NotFound);
    assert!(e.message().contains("husky-1"), "names the connected robots: {}", e.message());

    let e = missions.submit_mission(text("husky-1", &"go ".repeat(2000), false)).await.unwrap_err();
    assert_eq!(e.code(), tonic::Code::InvalidArgument);

    // A second mission on a busy robot.
    let first = missions.submit_mission(text("husky-1", "move 3 m ahead", false)).await.unwrap().into_inner();
    let e = missions.submit_mission(text("husky-1", "turn left", false)).await.unwrap_err();
    assert_eq!(e.code(), tonic::Code::FailedPrecondition);
    assert!(e.message().contains(&first.mission_id), "{}", e.message());

    // Malformed frames from an edge agent: NaN pose, wrong depth size, oversize, no hello.
    let s = attach_and_send(
        &t,
        "bad-1",
        vec![hello("bad-1"), frame("bad-1", 1, 8, 6, 0.0), frame("bad-1", 2, 8, 6, f64::NAN)],
    )
    .await;
    assert_eq!(s.code(), tonic::Code::InvalidArgument, "{s:?}");
    assert!(s.message().contains("odom.theta is not a finite number"), "{}", s.message());

    let mut short = frame("bad-2", 1, 8, 6, 0.0);
    if let Some(edge_message::Kind::Frame(f)) = &mut short.kind {
        f.frame.as_mut().unwrap().depth.as_mut().unwrap().data_mm.truncate(5);
    }
    let s = attach_and_send(&t, "bad-2", vec![hello("bad-2"), short]).await;
    assert_eq!(s.code(), tonic::Code::InvalidArgument);
    assert!(s.message().contains("u16 millimetres are expected"), "{}", s.message());

    let s = attach_and_send(&t, "bad-3", vec![hello("bad-3"), frame("bad-3", 1, 4000, 2500, 0.0)]).await;
    assert_eq!(s.code(), tonic::Code::ResourceExhausted, "oversized frame: {s:?}");

    let s = attach_and_send(&t, "bad-4", vec![frame("bad-4", 1, 8, 6, 0.0)]).await;
    assert_eq!(s.code(), tonic::Code::InvalidArgument);
    assert!(s.message().contains("EdgeHello"), "{}", s.message());

    let s = attach_and_send(&t, "husky-1", vec![hello("husky-1")]).await;
    assert_eq!(s.code(), tonic::Code::AlreadyExists, "{s:?}");

    // Everyone else is still served: the robot is attached and missions still plan.
    let mut fleet = t.fleet();
    let robots = fleet.list_robots(ListRobotsRequest {}).await.unwrap().into_inner().robots;
    assert!(robots.iter().any(|r| r.robot_id == "husky-1" && r.connected), "{robots:?}");
    let dry = missions.submit_mission(text("", "take a right turn and move 2 m", true)).await.unwrap().into_inner();
    assert!(!dry.plan_json.is_empty());
    t.stack.shutdown().await.unwrap();
}
