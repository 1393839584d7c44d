//! Missions persist: a restarted gateway still lists past missions, and a
//! mission that was running when it stopped is marked FAILED with the reason
//! (it is not resumed: the robot may have moved since).

use std::time::Duration;

use vlnav_e2e::TestStack;
use vlnav_proto::v1::{
    GetMissionRequest, ListMissionsRequest, MissionState, SubmitMissionRequest, submit_mission_request::Instruction,
};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_restarted_gateway_lists_past_missions_and_fails_the_unfinished_one() {
    let data = tempfile::tempdir().unwrap();
    let dir = data.path().to_path_buf();
    let t = TestStack::start(|a| a.data_dir = dir.clone()).await;
    let mut missions = t.missions().await;
    let planned = missions
        .submit_mission(SubmitMissionRequest {
            robot_id: "husky-1".into(),
            instruction: Some(Instruction::Text("turn left and move 2 m".into())),
            dry_run: true,
        })
        .await
        .unwrap()
        .into_inner();
    let running = missions
        .submit_mission(SubmitMissionRequest {
            robot_id: "husky-1".into(),
            instruction: Some(Instruction::Text("move 8 m ahead".into())),
            dry_run: false,
        })
        .await
        .unwrap()
        .into_inner();
    // Let it start moving.
    for _ in 0..200 {
        let m = missions
            .get_mission(GetMissionRequest { mission_id: running.mission_id.clone() })
            .await
            .unwrap()
            .into_inner();
        if m.state == MissionState::Running as i32 {
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    t.stack.shutdown().await.unwrap();

    let t = TestStack::start(|a| {
        a.data_dir = dir.clone();
        a.no_robot = true;
    })
    .await;
    let mut missions = t.missions().await;
    let listed = missions
        .list_missions(ListMissionsRequest { robot_id: String::new(), limit: 0 })
        .await
        .unwrap()
        .into_inner()
        .missions;
    let find =
        |id: &str| listed.iter().find(|m| m.mission_id == id).unwrap_or_else(|| panic!("{id} listed after restart"));
    assert_eq!(find(&planned.mission_id).state, MissionState::Planned as i32);
    let failed = find(&running.mission_id);
    assert_eq!(failed.state, MissionState::Failed as i32);
    assert!(failed.reason.contains("gateway restarted"), "{}", failed.reason);
    let (events, _) = t.follow(&running.mission_id, Duration::from_secs(10)).await;
    assert!(matches!(
        events.last().and_then(|e| e.kind.as_ref()),
        Some(vlnav_proto::v1::mission_event::Kind::Finished(_))
    ));
    t.stack.shutdown().await.unwrap();
}
