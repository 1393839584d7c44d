//! One mission is one distributed trace: spans from the gateway, planner,
//! detector, subgoal estimator and local planner, exported over OTLP to a
//! receiver built on the official opentelemetry-proto definitions, with
//! correct parent links: every stage's server span under the caller's
//! client span for that call (`call <Method>`), which the profile's hop
//! figures rest on.

use std::collections::HashMap;
use std::sync::Arc;
use std::time::Duration;

use vlnav_e2e::TestStack;
use vlnav_proto::v1::{MissionState, SubmitMissionRequest, submit_mission_request::Instruction};
use vlnav_traces::{Span, SpanKind, SpanStore, serve_receiver};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn one_mission_is_one_trace_with_every_stage_and_correct_parents() {
    let spans_dir = tempfile::tempdir().unwrap();
    let store = Arc::new(SpanStore::open(spans_dir.path()).unwrap());
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let endpoint = format!("http://{}", listener.local_addr().unwrap());
    let token = vlnav_runtime::CancellationToken::new();
    tokio::spawn(serve_receiver(listener, store.clone(), token.clone()));
    // SAFETY: this test binary holds one test; nothing else reads the environment yet.
    unsafe { std::env::set_var("OTEL_EXPORTER_OTLP_ENDPOINT", &endpoint) };
    let telemetry = vlnav_runtime::telemetry::init("vlnav-e2e").unwrap();

    let t = TestStack::start(|_| {}).await;
    let mut missions = t.missions().await;
    let submitted = missions
        .submit_mission(SubmitMissionRequest {
            robot_id: "husky-1".into(),
            instruction: Some(Instruction::Text(
                "take a left turn, move 4 m ahead, then find the standing person".into(),
            )),
            dry_run: false,
        })
        .await
        .unwrap()
        .into_inner();
    let (_, mission) = t.follow(&submitted.mission_id, Duration::from_secs(300)).await;
    assert_eq!(mission.state, MissionState::Succeeded as i32, "{}", mission.reason);
    assert_eq!(mission.trace_id.len(), 32);

    telemetry.flush();
    let mut spans: Vec<Span> = Vec::new();
    for _ in 0..100 {
        spans = store.spans_of_trace(&mission.trace_id).unwrap();
        if spans.iter().any(|s| s.name == "mission") {
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let by_id: HashMap<&str, &Span> = spans.iter().map(|s| (s.span_id.as_str(), s)).collect();
    let parent = |s: &Span| s.parent_id.as_deref().and_then(|p| by_id.get(p)).copied();
    // A server span's caller: the span its client span was opened in.
    let parent_name = |s: &Span| {
        let p = parent(s)?;
        let p = if p.kind == SpanKind::Client { parent(p)? } else { p };
        Some(p.name.as_str())
    };
    fn named<'a>(spans: &'a [Span], n: &'a str) -> impl Iterator<Item = &'a Span> + 'a {
        spans.iter().filter(move |s| s.name == n)
    }

    for stage in
        ["mission", "plan", "step", "control-cycle", "detect", "segment", "subgoal", "local-plan", "edge-forward"]
    {
        assert!(named(&spans, stage).count() > 0, "no `{stage}` span in the mission's trace ({} spans)", spans.len());
    }
    assert!(spans.iter().all(|s| s.trace_id == mission.trace_id));
    let mission_span = named(&spans, "mission").next().unwrap();
    // The planner's server span hangs off the mission span (the planner call is made inside it).
    assert!(named(&spans, "plan").all(|s| parent_name(s) == Some("mission")), "plan spans are children of the mission");
    assert!(named(&spans, "step").all(|s| s.parent_id.as_deref() == Some(mission_span.span_id.as_str())));
    // A cycle belongs to the step it ran in (the cycle that starts a step, or ends the mission, to the mission).
    assert!(named(&spans, "control-cycle").all(|s| matches!(parent_name(s), Some("step" | "mission"))));
    assert!(named(&spans, "control-cycle").filter(|s| parent_name(s) == Some("step")).count() > 10);
    for stage in ["detect", "segment", "local-plan", "edge-forward"] {
        // ResetRobot at the start of a step belongs to the step; every per-frame call to a cycle.
        let per_frame = |s: &&Span| !matches!(s.attributes.get("rpc.method"), Some(vlnav_traces::AttrValue::Str(m)) if m == "ResetRobot");
        let stray: Vec<Option<&str>> =
            named(&spans, stage).filter(per_frame).map(&parent_name).filter(|p| *p != Some("control-cycle")).collect();
        assert!(stray.is_empty(), "`{stage}` spans are children of a control cycle, not of {stray:?}");
    }
    // MOVE goals are computed at step start, FIND goals in the cycle.
    assert!(named(&spans, "subgoal").all(|s| matches!(parent_name(s), Some("control-cycle" | "step"))));
    // Each stage's server span is the child of a client span of the same
    // call, opened by the caller (the hop: client span less server span).
    for stage in ["plan", "detect", "segment", "subgoal", "local-plan"] {
        for span in named(&spans, stage) {
            let call = parent(span).unwrap_or_else(|| panic!("`{stage}` span {} has no parent", span.span_id));
            let method = match span.attributes.get("rpc.method") {
                Some(vlnav_traces::AttrValue::Str(m)) => m.as_str(),
                _ => panic!("`{stage}` span without rpc.method"),
            };
            assert_eq!(call.kind, SpanKind::Client, "`{stage}` span's parent is `{}`, not a client span", call.name);
            assert_eq!(call.name, format!("call {method}"));
            assert!(call.start_ns <= span.start_ns && span.end_ns <= call.end_ns, "the call holds its server span");
        }
    }
    // Services report who they are.
    let services: Vec<&str> = spans
        .iter()
        .filter_map(|s| match s.attributes.get("rpc.service") {
            Some(vlnav_traces::AttrValue::Str(v)) => Some(v.as_str()),
            _ => None,
        })
        .collect();
    for svc in [
        "vlnav.v1.PlannerService",
        "vlnav.v1.DetectorService",
        "vlnav.v1.SubgoalService",
        "vlnav.v1.LocalPlannerService",
    ] {
        assert!(services.contains(&svc), "no server span of {svc}");
    }
    t.stack.shutdown().await.unwrap();
    token.cancel();
}
