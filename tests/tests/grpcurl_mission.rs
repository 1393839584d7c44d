//! A user's first session, with the real grpcurl over TLS with the
//! credentials `vlnav up` wrote: list the services, check every stage's
//! health (mutual TLS, the gateway's certificate), submit the paper's Case 2
//! instruction with the operator token and watch it to
//! MISSION_STATE_SUCCEEDED in the demo world.
//!
//! The stack runs as `vlnav up` does by default — realistic perception,
//! the robot in lockstep — not with the oracle the plumbing tests use:
//! this is the mission a user's first session drives. The robot sends
//! frames of its frozen world while it waits for the mission, and each
//! draws new sensor noise, so how long grpcurl takes before it submits
//! changes the course the way another seed would (`vlnav demo --seed`).
//! With oracle perception the demo hall's statue is a person whose
//! clearance the paths do not keep, and some seeds end asking for the
//! way past it (docs/evaluation.md, "Known gaps").

use std::time::Duration;

use vlnav_e2e::{CASE_2, TestStack, grpcurl_with, json_objects, tool};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn case_2_through_grpcurl_succeeds_and_every_step_is_watched() {
    let t = TestStack::start(|a| a.perception = vlnav_runtime::perception::PerceptionMode::Realistic).await;
    let addr = t.addr();
    let sec = t.security();
    let op = t.grpcurl_auth(&sec.operator_token);
    let viewer = t.grpcurl_auth(&sec.viewer_token);
    // Stages accept only callers with a certificate the deployment's CA signed.
    let mtls: Vec<String> = [
        "-cacert".into(),
        sec.pki.ca().display().to_string(),
        "-cert".into(),
        sec.pki.gateway_cert().display().to_string(),
        "-key".into(),
        sec.pki.gateway_key().display().to_string(),
    ]
    .into();

    // Listing needs no token (reflection stays open for grpcurl list/describe).
    let services = grpcurl_with(&t.grpcurl_auth("")[..2], &[&addr, "list"]).expect("grpcurl list");
    for s in [
        "vlnav.v1.MissionService",
        "vlnav.v1.FleetService",
        "grpc.health.v1.Health",
        "grpc.reflection.v1alpha.ServerReflection",
    ] {
        assert!(services.lines().any(|l| l.trim() == s), "`grpcurl list` lacks {s}:\n{services}");
    }

    let p = t.stack.ports;
    for (port, service) in [
        (p.ingress, "vlnav.v1.IngressService"),
        (p.planner, "vlnav.v1.PlannerService"),
        (p.detector, "vlnav.v1.DetectorService"),
        (p.reid, "vlnav.v1.ReidService"),
        (p.segmenter, "vlnav.v1.SegmenterService"),
        (p.subgoal, "vlnav.v1.SubgoalService"),
        (p.local_planner, "vlnav.v1.LocalPlannerService"),
    ] {
        let target = format!("127.0.0.1:{port}");
        let body = format!(r#"{{"service":"{service}"}}"#);
        let out = grpcurl_with(&mtls, &["-d", &body, &target, "grpc.health.v1.Health/Check"]).expect("health check");
        assert!(out.contains("SERVING"), "{service} is not serving: {out}");
        let listed = grpcurl_with(&mtls, &[&target, "list"]).expect("stage list");
        assert!(listed.contains(service), "{service} not listed by its own server: {listed}");
    }

    let body = serde_json::json!({"robot_id": "husky-1", "text": CASE_2}).to_string();
    let out = grpcurl_with(&op, &["-d", &body, &addr, "vlnav.v1.MissionService/SubmitMission"]).expect("SubmitMission");
    let submitted: serde_json::Value = serde_json::from_str(&out).expect("JSON");
    let id = submitted["missionId"].as_str().expect("missionId").to_string();
    let plan_json: serde_json::Value =
        serde_json::from_str(submitted["planJson"].as_str().expect("planJson")).expect("plan_json is JSON");
    let actions: Vec<&str> =
        plan_json.as_array().expect("array").iter().map(|s| s["action"].as_str().unwrap()).collect();
    assert_eq!(actions, ["MOVE", "FIND", "FIND", "FIND"], "{plan_json}");

    // Watch with grpcurl until the mission ends. A mission that stops to ask
    // (AWAITING_CLARIFICATION) never ends by itself: GetMission, polled
    // meanwhile, fails the test at once with the question it asked.
    let watch_body = serde_json::json!({"mission_id": id}).to_string();
    let get_body = serde_json::json!({"mission_id": id}).to_string();
    let mut watch = tokio::process::Command::new(tool("grpcurl"))
        .args(viewer.iter().map(String::as_str))
        .args(["-max-time", "590", "-d", &watch_body, &addr, "vlnav.v1.MissionService/WatchMission"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .kill_on_drop(true)
        .spawn()
        .expect("grpcurl runs");
    let mut stdout = watch.stdout.take().expect("piped");
    let read = tokio::spawn(async move {
        let mut text = String::new();
        tokio::io::AsyncReadExt::read_to_string(&mut stdout, &mut text).await.map(|_| text)
    });
    let deadline = tokio::time::Instant::now() + Duration::from_secs(600);
    let mut asked = None;
    let status = loop {
        tokio::select! {
            status = watch.wait() => break status.expect("grpcurl exits"),
            _ = tokio::time::sleep(Duration::from_secs(2)) => {
                let got = grpcurl_with(&viewer, &["-d", &get_body, &addr, "vlnav.v1.MissionService/GetMission"])
                    .expect("GetMission");
                let m: serde_json::Value = serde_json::from_str(&got).expect("JSON");
                if m["state"] == "MISSION_STATE_AWAITING_CLARIFICATION" {
                    asked = Some(m["clarification"].to_string());
                    watch.start_kill().expect("the watch stops");
                    break watch.wait().await.expect("grpcurl exits");
                }
                assert!(tokio::time::Instant::now() < deadline, "the mission did not finish within 10 minutes: {got}");
            }
        }
    };
    let events = read.await.unwrap().expect("grpcurl's output");
    // A question is a failure; the events watched so far say where it came.
    assert!(asked.is_none(), "the mission asked: {}; events:\n{events}", asked.unwrap_or_default());
    assert!(status.success(), "WatchMission: {status}; printed:\n{events}");
    let events = json_objects(&events);
    let kinds: Vec<String> = events
        .iter()
        .map(|e| {
            e.as_object()
                .unwrap()
                .keys()
                .find(|k| !["missionId", "seq", "stamp"].contains(&k.as_str()))
                .cloned()
                .unwrap_or_default()
        })
        .collect();
    for step in 0..4 {
        let started =
            events.iter().any(|e| e.get("stepStarted").is_some_and(|s| s["index"].as_u64().unwrap_or(0) == step));
        let reached =
            events.iter().any(|e| e.get("subgoalReached").is_some_and(|s| s["index"].as_u64().unwrap_or(0) == step));
        assert!(started && reached, "step {step} was not both started and reached; events: {kinds:?}");
    }
    assert!(events.iter().filter(|e| e.get("targetSeen").is_some()).count() >= 3, "three targets seen: {kinds:?}");
    let last = events.last().expect("events");
    assert_eq!(last["finished"]["state"], "MISSION_STATE_SUCCEEDED", "{last}");

    let got = grpcurl_with(
        &viewer,
        &["-d", &serde_json::json!({"mission_id": id}).to_string(), &addr, "vlnav.v1.MissionService/GetMission"],
    )
    .expect("GetMission");
    let got: serde_json::Value = serde_json::from_str(&got).unwrap();
    assert_eq!(got["state"], "MISSION_STATE_SUCCEEDED");
    assert_eq!(got["submittedBy"], "local-operator", "{got}");
    t.stack.shutdown().await.unwrap();
}
