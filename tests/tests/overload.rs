//! A client flooding the gateway with submissions is refused at once with
//! RESOURCE_EXHAUSTED — never left hanging — while a robot already on a
//! mission goes on to finish it (docs/architecture.md, "Overload").

use std::time::Duration;

use vlnav_e2e::TestStack;
use vlnav_proto::v1::{MissionState, SubmitMissionRequest, submit_mission_request::Instruction};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_flood_of_submissions_is_refused_at_once_and_the_running_mission_finishes() {
    // The command line's default limit (tests run without one).
    let t = TestStack::start(|a| a.submit_per_minute = 60).await;
    let mut missions = t.missions().await;
    let running = missions
        .submit_mission(SubmitMissionRequest {
            robot_id: "husky-1".into(),
            instruction: Some(Instruction::Text("go to the bicycle".into())),
            dry_run: false,
        })
        .await
        .expect("the mission is accepted")
        .into_inner();

    // 200 plans at once from one caller over one connection.
    let flood: Vec<_> = (0..200)
        .map(|i| {
            let mut client = missions.clone();
            tokio::spawn(async move {
                let request = SubmitMissionRequest {
                    robot_id: "husky-1".into(),
                    instruction: Some(Instruction::Text(format!("move {} m ahead", 1 + i % 5))),
                    dry_run: true,
                };
                tokio::time::timeout(Duration::from_secs(60), client.submit_mission(request)).await
            })
        })
        .collect();
    let (mut planned, mut refused, mut other) = (0, 0, Vec::new());
    for call in flood {
        match call.await.unwrap().expect("every call is answered, none hangs") {
            Ok(_) => planned += 1,
            Err(s) if s.code() == tonic::Code::ResourceExhausted => {
                assert!(s.message().contains("try again in"), "an actionable refusal: {}", s.message());
                refused += 1;
            }
            Err(s) => other.push(s),
        }
    }
    assert!(other.is_empty(), "only refusals for load: {other:?}");
    // The burst (20, of which the running mission took one) and at most a
    // few refills (60 a minute) get through.
    assert!((19..=30).contains(&planned), "planned {planned}, refused {refused}");
    assert_eq!(planned + refused, 200);

    let (_, mission) = t.follow(&running.mission_id, Duration::from_secs(240)).await;
    assert_eq!(mission.state, MissionState::Succeeded as i32, "{}", mission.reason);
}
