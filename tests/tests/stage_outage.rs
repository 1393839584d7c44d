//! Fault tier: a stage service dies mid-mission. The executor holds the robot
//! stopped (zero commands) while the stage is down and carries on when it is
//! back; a stage that stays down fails the mission cleanly, with the reason,
//! and the gateway keeps serving.

use std::time::Duration;

use vlnav_e2e::TestStack;
use vlnav_proto::v1::{
    GetMissionRequest, ListRobotsRequest, MissionState, SubmitMissionRequest, submit_mission_request::Instruction,
};

async fn wait_running(t: &TestStack, id: &str) {
    let mut missions = t.missions().await;
    for _ in 0..400 {
        let m = missions.get_mission(GetMissionRequest { mission_id: id.into() }).await.unwrap().into_inner();
        if m.state == MissionState::Running as i32 {
            return;
        }
        tokio::time::sleep(Duration::from_millis(25)).await;
    }
    panic!("mission {id} never started running");
}

fn move_mission(text: &str) -> SubmitMissionRequest {
    SubmitMissionRequest {
        robot_id: "husky-1".into(),
        instruction: Some(Instruction::Text(text.into())),
        dry_run: false,
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_local_planner_restart_mid_mission_is_ridden_out() {
    let mut t = TestStack::start(|_| {}).await;
    let mut missions = t.missions().await;
    let m = missions.submit_mission(move_mission("move 3 m ahead")).await.unwrap().into_inner();
    wait_running(&t, &m.mission_id).await;
    t.stack.stop_stage("local-planner").unwrap();
    tokio::time::sleep(Duration::from_millis(500)).await;
    t.stack.restart_stage("local-planner").await.unwrap();
    let (_, mission) = t.follow(&m.mission_id, Duration::from_secs(240)).await;
    assert_eq!(mission.state, MissionState::Succeeded as i32, "{}", mission.reason);
    t.stack.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stage_that_stays_down_fails_the_mission_cleanly() {
    let mut t = TestStack::start(|_| {}).await;
    let mut missions = t.missions().await;
    let m = missions.submit_mission(move_mission("move 6 m ahead")).await.unwrap().into_inner();
    wait_running(&t, &m.mission_id).await;
    t.stack.stop_stage("local-planner").unwrap();
    let (events, mission) = t.follow(&m.mission_id, Duration::from_secs(240)).await;
    assert_eq!(mission.state, MissionState::Failed as i32);
    assert!(mission.reason.contains("local-planner"), "the reason names the stage: {}", mission.reason);
    assert!(events.last().is_some_and(|e| matches!(e.kind, Some(vlnav_proto::v1::mission_event::Kind::Finished(_)))));
    // Everyone else is still served.
    let mut fleet = t.fleet();
    let robots = fleet.list_robots(ListRobotsRequest {}).await.unwrap().into_inner().robots;
    assert!(
        robots.iter().any(|r| r.robot_id == "husky-1" && r.connected && r.active_mission_id.is_empty()),
        "husky-1 is attached and free again: {robots:?}"
    );
    t.stack.shutdown().await.unwrap();
}
