//! Revoking a robot while it works (docs/security.md, "Certificates:
//! revoke"): `vlnav credentials revoke --robot ID` on a running stack, no
//! restart. The robot's Attach stream is ended with PERMISSION_DENIED naming
//! the revocation (what the edge agent logs as the reason its link went
//! down), its reconnects are refused at the TLS handshake, its deadman stops
//! it within the deadman window, and it stays stopped; another robot keeps
//! its link.

use std::time::Duration;

use tokio::time::Instant;
use vlnav::credentials::{RevokeArgs, revoke};
use vlnav_e2e::robot::SimRobot;
use vlnav_e2e::{TestStack, stops};
use vlnav_edge_agent::EdgeOptions;
use vlnav_edge_agent::agent::Link;
use vlnav_proto::v1::{
    EdgeHello, ListRobotsRequest, RobotInfo, SubmitMissionRequest, submit_mission_request::Instruction,
};

fn hello(robot: &str) -> EdgeHello {
    EdgeHello { robot_id: robot.into(), driver: "test".into(), ..Default::default() }
}

async fn robot_info(t: &TestStack, robot_id: &str) -> Option<RobotInfo> {
    let robots = t.fleet().list_robots(ListRobotsRequest {}).await.ok()?.into_inner().robots;
    robots.into_iter().find(|r| r.robot_id == robot_id)
}

fn revoke_robot(t: &TestStack, robot_id: &str, reason: &str) {
    let args = RevokeArgs {
        robots: vec![robot_id.into()],
        reason: reason.into(),
        dir: t.security().pki.dir.clone(),
        ..Default::default()
    };
    revoke(&args).expect("revoked");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_robot_revoked_mid_mission_is_cut_off_and_stopped_by_its_deadman() {
    let t = TestStack::start(|a| a.no_robot = true).await;
    let sec = t.security();

    // A bystander attached as husky-5, and husky-4 driving a mission.
    let bystander_opts = EdgeOptions {
        gateway: t.uri(),
        robot_id: "husky-5".into(),
        tls: sec.robot("husky-5").unwrap(),
        ..Default::default()
    };
    let mut bystander = Link::connect(&bystander_opts, hello("husky-5")).await.expect("husky-5 attaches");
    let opts = EdgeOptions {
        gateway: t.uri(),
        robot_id: "husky-4".into(),
        tls: sec.robot("husky-4").unwrap(),
        lockstep: false,
        width: Some(320),
        height: Some(240),
        ..Default::default()
    };
    let robot = SimRobot::start(opts.clone());
    let deadline = Instant::now() + Duration::from_secs(60);
    while !robot_info(&t, "husky-4").await.is_some_and(|r| r.connected && r.frames_received > 0) {
        assert!(Instant::now() < deadline, "husky-4 did not attach");
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    let mission = t
        .missions()
        .await
        .submit_mission(SubmitMissionRequest {
            robot_id: "husky-4".into(),
            instruction: Some(Instruction::Text("move 8 m ahead".into())),
            dry_run: false,
        })
        .await
        .expect("submitted")
        .into_inner();
    let deadline = Instant::now() + Duration::from_secs(60);
    while !robot.latest().is_some_and(|r| r.mission_id == mission.mission_id && stops::moving(&r)) {
        assert!(Instant::now() < deadline, "husky-4 never moved under the mission: {:?}", robot.latest());
        tokio::time::sleep(Duration::from_millis(20)).await;
    }

    let revoked_at = robot.now();
    revoke_robot(&t, "husky-4", "stolen");

    // The deadman stops it: commanded zero within the deadman window after
    // its last command to move, and it moves no more.
    let deadman = robot.opts.deadman_timeout_s;
    let deadline = Instant::now() + Duration::from_secs(20);
    let stop = loop {
        if let Some(s) = stops::stop_after(&robot.records(), revoked_at) {
            break s;
        }
        assert!(Instant::now() < deadline, "husky-4 was never commanded zero after the revocation");
        tokio::time::sleep(Duration::from_millis(100)).await;
    };
    assert!(stop.within_deadman(deadman, robot.period()), "{stop:?} (deadman {deadman} s)");
    tokio::time::sleep(Duration::from_secs(3)).await;
    let still_from = stop.applied_zero.unwrap_or(stop.commanded_zero);
    let records = robot.records();
    let moved = stops::moved_between(&records, still_from, robot.now());
    assert!(moved.is_empty(), "husky-4 moved after its stop: {:?}", moved.first());
    assert!(!robot_info(&t, "husky-4").await.is_some_and(|r| r.connected), "husky-4 is no longer attached");

    // Its reconnects are refused at the TLS handshake: in TLS 1.3 the
    // gateway's alert is what the robot reads after its handshake.
    Link::connect(&opts, hello("husky-4")).await.err().expect("refused");
    let tls = opts.tls.load().unwrap().unwrap();
    let port = t.stack.gateway_addr.port();
    let mut conn = tls.connector(None).unwrap().connect("127.0.0.1", port).await.unwrap();
    let e = tokio::io::AsyncReadExt::read(&mut conn, &mut [0u8; 64]).await.expect_err("refused");
    assert_eq!(e.to_string(), "received fatal alert: CertificateRevoked");
    robot.stop().await.expect("the edge agent ends cleanly");

    // The bystander's link is untouched; revoked in turn, its stream ends with
    // the reason the edge agent logs.
    assert!(robot_info(&t, "husky-5").await.is_some_and(|r| r.connected));
    revoke_robot(&t, "husky-5", "decommissioned");
    let reason = tokio::time::timeout(Duration::from_secs(5), async {
        loop {
            if let Err(e) = bystander.recv().await {
                return e;
            }
        }
    })
    .await
    .expect("the stream ends within a few seconds of the revocation");
    assert!(
        reason.contains("identity spiffe://vlnav/robot/husky-5 is revoked (decommissioned)")
            && reason.contains("PermissionDenied"),
        "{reason}"
    );
    // Graceful shutdown waits for open connections.
    drop((bystander, conn));
    t.stack.shutdown().await.unwrap();
}
