//! The PlannerService over a real socket with a real tonic client.

mod common;

use tonic::Code;
use vlnav_planner::Options;
use vlnav_proto::v1::planner_service_client::PlannerServiceClient;
use vlnav_proto::v1::{self as pb, plan_response::Outcome};
use vlnav_runtime::ServerConfig;
use vlnav_runtime::testing::TestServer;

async fn start() -> (PlannerServiceClient<vlnav_runtime::client::TracedChannel>, TestServer) {
    let opts = Options { models_dir: common::models_dir(), ..Options::default() };
    let cfg = ServerConfig::default();
    let set = vlnav_planner::services(&opts, &cfg).await.expect("planner services start");
    let server = vlnav_runtime::testing::start(&cfg, set).await.unwrap();
    let channel = server.traced_channel().expect("channel");
    (PlannerServiceClient::new(channel), server)
}

fn plan_of(r: &pb::PlanResponse) -> &pb::ActionPlan {
    match r.outcome.as_ref() {
        Some(Outcome::Plan(p)) => p,
        other => panic!("expected a plan, got {other:?}"),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn plans_the_papers_example_over_grpc() {
    let (mut c, server) = start().await;
    let r = c
        .plan(pb::PlanRequest {
            instruction: "Buddy take left turn, move 4 m ahead, then find the standing person to reach close to it, In your right you may see the visitor chair follow it. Finally go at spot where bicycle is standing.".into(),
            backend: String::new(),
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.backend, "rules");
    let p = plan_of(&r);
    let kinds: Vec<i32> = p.steps.iter().map(|s| s.action).collect();
    let (mv, find) = (pb::ActionKind::Move as i32, pb::ActionKind::Find as i32);
    assert_eq!(kinds, vec![mv, find, find, find]);
    assert_eq!((p.steps[0].f_dist, p.steps[0].yaw), (4.0, 1.57));
    assert_eq!(p.steps.iter().skip(1).map(|s| s.class_id).collect::<Vec<_>>(), vec![0, 56, 1]);
    // Every step quotes the words it came from.
    assert!(p.steps.iter().all(|s| !s.source.is_empty()), "{:?}", p.steps);
    // The JSON form is the same plan, less those words, and passes ValidatePlan.
    let v = c.validate_plan(pb::ValidatePlanRequest { plan_json: r.plan_json.clone() }).await.unwrap().into_inner();
    assert!(v.valid, "{:?}", v.errors);
    let mut unquoted = p.clone();
    unquoted.steps.iter_mut().for_each(|s| s.source.clear());
    assert_eq!(v.plan.as_ref(), Some(&unquoted));
    server.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn asks_for_ungroundable_targets_and_rejects_bad_input() {
    let (mut c, server) = start().await;
    let r = c
        .plan(pb::PlanRequest { instruction: "go to the pharmacy".into(), backend: String::new() })
        .await
        .unwrap()
        .into_inner();
    match r.outcome {
        Some(Outcome::Clarification(q)) => assert!(q.reason.contains("pharmacy"), "{q:?}"),
        other => panic!("expected a question, got {other:?}"),
    }
    assert!(r.plan_json.is_empty());

    for (instruction, field) in
        [(String::new(), "empty"), ("go ".repeat(2000), "bytes"), ("move\u{0}\u{1}\u{7f}ahead".to_string(), "control")]
    {
        let e = c.plan(pb::PlanRequest { instruction, backend: String::new() }).await.unwrap_err();
        assert_eq!(e.code(), Code::InvalidArgument);
        assert!(e.message().contains("instruction") && e.message().contains(field), "{}", e.message());
    }
    let e = c.plan(pb::PlanRequest { instruction: "go back".into(), backend: "gpt-17".into() }).await.unwrap_err();
    assert_eq!(e.code(), Code::InvalidArgument);
    assert!(e.message().contains("backend"));
    let e = c.plan(pb::PlanRequest { instruction: "go back".into(), backend: "openai".into() }).await.unwrap_err();
    assert_eq!(e.code(), Code::FailedPrecondition, "{}", e.message());

    let r = c
        .plan(pb::PlanRequest {
            instruction: "Geh zum Stuhl und dreh dich nach links, bitte schnell".into(),
            backend: String::new(),
        })
        .await
        .unwrap()
        .into_inner();
    assert!(matches!(r.outcome, Some(Outcome::Clarification(_))), "{r:?}");
    server.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn replans_after_a_failed_find() {
    let (mut c, server) = start().await;
    let r = c
        .plan(pb::PlanRequest {
            instruction: "move 2 m ahead, find the visitor chair, then find the bicycle".into(),
            backend: String::new(),
        })
        .await
        .unwrap()
        .into_inner();
    let plan = plan_of(&r).clone();
    let r = c
        .replan(pb::ReplanRequest {
            instruction: String::new(),
            plan: Some(plan.clone()),
            failed_step: 1,
            failure: "target not found after exploration".into(),
            answer: "it's the sofa".into(),
            backend: String::new(),
        })
        .await
        .unwrap()
        .into_inner();
    let p = plan_of(&r);
    assert_eq!(p.steps.len(), 2);
    assert_eq!((p.steps[0].target.as_str(), p.steps[0].class_id), ("sofa", 57));
    assert_eq!(p.steps[1].class_id, 1);

    let e = c
        .replan(pb::ReplanRequest {
            plan: Some(plan.clone()),
            failed_step: 9,
            answer: "skip it".into(),
            ..Default::default()
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::InvalidArgument);
    assert!(e.message().contains("failed_step"), "{}", e.message());
    let e = c.replan(pb::ReplanRequest { plan: None, answer: "skip".into(), ..Default::default() }).await.unwrap_err();
    assert!(e.message().contains("plan"), "{}", e.message());
    server.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn serves_the_schema_and_validates_plans() {
    let (mut c, server) = start().await;
    let s = c.get_plan_schema(pb::GetPlanSchemaRequest {}).await.unwrap().into_inner();
    let schema: serde_json::Value = serde_json::from_str(&s.json_schema).unwrap();
    assert_eq!(schema["$schema"], "https://json-schema.org/draft/2020-12/schema");
    assert_eq!(s.actions, vec!["MOVE", "FIND", "FOLLOW", "RETURN"]);
    assert_eq!(s.classes.len(), 80);
    assert_eq!(s.classes[56], "chair");

    let bad = c
        .validate_plan(pb::ValidatePlanRequest {
            plan_json: r#"[{"action":"FIND","target":"x","id":99},{"action":"EXPLODE"}]"#.into(),
        })
        .await
        .unwrap()
        .into_inner();
    assert!(!bad.valid);
    assert!(bad.errors.len() >= 2, "{:?}", bad.errors);
    let long = c
        .validate_plan(pb::ValidatePlanRequest { plan_json: r#"[{"action":"MOVE","f_dist":15,"yaw":0}]"#.into() })
        .await
        .unwrap()
        .into_inner();
    assert!(long.valid);
    assert_eq!(long.plan.unwrap().steps.iter().map(|s| s.f_dist).collect::<Vec<_>>(), vec![7.5, 7.5]);
    let e = c.validate_plan(pb::ValidatePlanRequest { plan_json: " ".into() }).await.unwrap_err();
    assert_eq!(e.code(), Code::InvalidArgument);
    server.stop().await.unwrap();
}

#[tokio::test]
async fn start_fails_naming_the_missing_model_and_the_fetch_script() {
    let dir = std::env::temp_dir().join(format!("vlnav-planner-empty-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let opts = Options { models_dir: dir.clone(), ..Options::default() };
    let err =
        vlnav_planner::services(&opts, &ServerConfig::default()).await.err().expect("start must fail").to_string();
    assert!(err.contains("model.safetensors") && err.contains("deploy/fetch-models.sh"), "{err}");
    let _ = std::fs::remove_dir(dir);
}
