//! The receiver against the real OpenTelemetry SDK and OTLP/gRPC exporter
//! (the ones every vlnav process uses): spans exported by two "services"
//! arrive over a real socket, land in per-trace files another process reads,
//! and profile into a report. Over mutual TLS, only services may export.

use std::sync::Arc;
use std::time::{Duration, SystemTime};

use opentelemetry::trace::{Span as _, SpanKind, TraceContextExt, Tracer, TracerProvider as _};
use opentelemetry::{Context, KeyValue};
use opentelemetry_otlp::WithExportConfig;
use opentelemetry_sdk::Resource;
use opentelemetry_sdk::trace::SdkTracerProvider;
use tokio::net::TcpListener;
use tokio_util::sync::CancellationToken;
use vlnav_traces::cli::{SpanSource, profile_trace};
use vlnav_traces::{ProfileArgs, SpanStatus, SpanStore, run_profile, serve_receiver};

fn provider(endpoint: &str, service: &str) -> SdkTracerProvider {
    let exporter = opentelemetry_otlp::SpanExporter::builder()
        .with_tonic()
        .with_endpoint(endpoint.to_string())
        .build()
        .expect("OTLP exporter");
    SdkTracerProvider::builder()
        .with_resource(Resource::builder().with_service_name(service.to_string()).build())
        .with_batch_exporter(exporter)
        .build()
}

fn at(ms: u64) -> SystemTime {
    SystemTime::UNIX_EPOCH + Duration::from_secs(1_763_700_000) + Duration::from_millis(ms)
}

async fn flush(p: &SdkTracerProvider) {
    let p = p.clone();
    tokio::task::spawn_blocking(move || p.force_flush().expect("flush spans")).await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sdk_exports_land_in_the_store_and_profile() {
    let dir = tempfile::tempdir().unwrap();
    let store = Arc::new(SpanStore::open(dir.path()).unwrap());
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let endpoint = format!("http://{}", listener.local_addr().unwrap());
    let shutdown = CancellationToken::new();
    let server = tokio::spawn(serve_receiver(listener, store.clone(), shutdown.clone()));

    let gateway = provider(&endpoint, "vlnav-gateway");
    let detector = provider(&endpoint, "vlnav-detector");
    let gw = gateway.tracer("vlnav");
    let det = detector.tracer("vlnav");

    // mission 0..1000 ms with 3 control cycles of 100 ms; in each, the
    // detector's server span takes 60 ms (the 3rd cycle: 90 ms, failing).
    let mut mission = gw.build(gw.span_builder("mission").with_start_time(at(0)));
    let mission_cx = Context::new().with_remote_span_context(mission.span_context().clone());
    for (i, detect_ms) in [60u64, 60, 90].into_iter().enumerate() {
        let t = 100 + 200 * i as u64;
        let mut cycle = gw.build_with_context(gw.span_builder("control-cycle").with_start_time(at(t)), &mission_cx);
        // The detector runs in another process: it only sees the propagated context.
        let remote = Context::new().with_remote_span_context(cycle.span_context().clone());
        let mut detect = det.build_with_context(
            det.span_builder("detect")
                .with_kind(SpanKind::Server)
                .with_start_time(at(t + 5))
                .with_attributes([KeyValue::new("rpc.method", "Detect")]),
            &remote,
        );
        if detect_ms == 90 {
            detect.set_status(opentelemetry::trace::Status::error("model not loaded"));
        }
        detect.end_with_timestamp(at(t + 5 + detect_ms));
        cycle.end_with_timestamp(at(t + 100));
    }
    mission.end_with_timestamp(at(1000));
    let trace_id = mission.span_context().trace_id().to_string();
    flush(&detector).await;
    flush(&gateway).await;

    // Another process reading the directory sees the whole trace.
    let reader = SpanStore::open(dir.path()).unwrap();
    let spans = reader.spans_of_trace(&trace_id).unwrap();
    assert_eq!(spans.len(), 7, "{spans:#?}");
    let detects: Vec<_> = spans.iter().filter(|s| s.name == "detect").collect();
    assert_eq!(detects.len(), 3);
    assert!(detects.iter().all(|s| s.service == "vlnav-detector" && s.kind == vlnav_traces::SpanKind::Server));
    assert_eq!(detects[0].attributes["rpc.method"].to_string(), "Detect");
    assert_eq!(detects[2].status, SpanStatus::Error { message: "model not loaded".into() });
    assert_eq!(detects[2].duration_ns(), 90_000_000);
    let cycles: Vec<_> = spans.iter().filter(|s| s.name == "control-cycle").collect();
    for (d, c) in detects.iter().zip(&cycles) {
        assert_eq!(d.parent_id.as_deref(), Some(c.span_id.as_str()), "detect is parented on its cycle");
        assert_eq!(c.service, "vlnav-gateway");
    }

    let report = profile_trace(&SpanSource::Dir(dir.path().to_path_buf()), &trace_id, "control-cycle").await.unwrap();
    assert!(report.contains(&format!("trace {trace_id} · 7 spans · 2 services")), "{report}");
    let detect_row =
        report.lines().find(|l| l.trim_start().starts_with("detect ")).unwrap_or_else(|| panic!("{report}"));
    let cols: Vec<&str> = detect_row.split_whitespace().collect();
    // stage service kind count err p50 p95 p99 max total
    assert_eq!(cols[..9], ["detect", "vlnav-detector", "server", "3", "1", "60.0", "90.0", "90.0", "90.0"], "{report}");
    assert!(report.contains("3 `control-cycle` cycles: p50 100 ms"), "{report}");
    // The detector dominates every cycle: 60 + 60 + 90 of 300 ms.
    let path_row = report
        .lines()
        .find(|l| l.trim_start().starts_with("detect [vlnav-detector, server]"))
        .unwrap_or_else(|| panic!("{report}"));
    assert!(path_row.contains("70.0%"), "{path_row}");
    assert!(path_row.trim_end().ends_with('3'), "dominant in all 3 cycles: {path_row}");

    // `vlnav profile --trace-id` reads the same files without a gateway.
    let args = ProfileArgs {
        mission_id: "m-1".into(),
        gateway: "http://127.0.0.1:9".into(),
        spans_dir: dir.path().to_path_buf(),
        jaeger: None,
        trace_id: Some(trace_id.clone()),
        cycle_span: "control-cycle".into(),
        caller: Default::default(),
    };
    let full = run_profile(args).await.unwrap();
    assert!(full.starts_with("mission m-1\n"), "{full}");
    assert!(full.contains(&report), "{full}");

    shutdown.cancel();
    server.await.unwrap().unwrap();
}

#[tokio::test]
async fn profile_explains_what_is_missing() {
    let dir = tempfile::tempdir().unwrap();
    let trace = "4bf92f3577b34da6a3ce929d0e0e4736";
    let err = profile_trace(&SpanSource::Dir(dir.path().join("nope")), trace, "control-cycle").await.unwrap_err();
    assert!(err.to_string().contains("does not exist: run `vlnav up`"), "{err}");
    let err = profile_trace(&SpanSource::Dir(dir.path().to_path_buf()), trace, "control-cycle").await.unwrap_err();
    assert!(err.to_string().contains(&format!("no spans of trace {trace}")), "{err}");
    let err = profile_trace(&SpanSource::Dir(dir.path().to_path_buf()), "not-hex", "control-cycle").await.unwrap_err();
    assert!(err.to_string().contains("not hexadecimal"), "{err}");

    // No gateway listening: the message says where it looked and what to do.
    let closed = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = closed.local_addr().unwrap();
    drop(closed);
    let args = ProfileArgs {
        mission_id: "m-1".into(),
        gateway: format!("http://{addr}"),
        spans_dir: dir.path().to_path_buf(),
        jaeger: None,
        trace_id: None,
        cycle_span: "control-cycle".into(),
        caller: Default::default(),
    };
    let err = run_profile(args).await.unwrap_err();
    assert!(err.to_string().contains(&format!("cannot reach the gateway at http://{addr}")), "{err}");
}

#[tokio::test]
async fn over_mutual_tls_only_services_may_export() {
    use opentelemetry_proto::tonic::collector::metrics::v1::ExportMetricsServiceRequest;
    use opentelemetry_proto::tonic::collector::metrics::v1::metrics_service_client::MetricsServiceClient;
    use opentelemetry_proto::tonic::collector::trace::v1::ExportTraceServiceRequest;
    use opentelemetry_proto::tonic::collector::trace::v1::trace_service_client::TraceServiceClient;
    use vlnav_runtime::security::{ClientSecurity, ClientTls, DevPki};

    let dir = tempfile::tempdir().unwrap();
    let pki = DevPki::ensure(&dir.path().join("pki"), &["husky-1"]).unwrap();
    let store = Arc::new(SpanStore::open(dir.path().join("spans")).unwrap());
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let uri = format!("https://{}", listener.local_addr().unwrap());
    let shutdown = CancellationToken::new();
    let tls = pki.server_args().load(false).unwrap();
    let server = tokio::spawn(vlnav_traces::serve_receiver_with(listener, store, tls, shutdown.clone()));

    let read = |p: std::path::PathBuf| std::fs::read(p).unwrap();
    let channel = |cert: std::path::PathBuf, key: std::path::PathBuf| {
        let tls = ClientTls::new(read(pki.ca()), Some((read(cert), read(key))));
        vlnav_runtime::client::channel_with(&uri, &ClientSecurity::new(Some(tls), None)).unwrap()
    };
    let gateway = channel(pki.gateway_cert(), pki.gateway_key());
    TraceServiceClient::new(gateway.clone())
        .export(ExportTraceServiceRequest::default())
        .await
        .expect("the gateway's certificate exports spans");
    MetricsServiceClient::new(gateway).export(ExportMetricsServiceRequest::default()).await.expect("and metrics");

    let robot = channel(pki.robot_cert("husky-1"), pki.robot_key("husky-1"));
    let e = TraceServiceClient::new(robot.clone()).export(ExportTraceServiceRequest::default()).await.unwrap_err();
    assert_eq!(e.code(), tonic::Code::PermissionDenied, "{e:?}");
    assert!(
        e.message().starts_with(
            "spiffe://vlnav/robot/husky-1 may not call /opentelemetry.proto.collector.trace.v1.TraceService/Export"
        ),
        "{}",
        e.message()
    );
    let e = MetricsServiceClient::new(robot).export(ExportMetricsServiceRequest::default()).await.unwrap_err();
    assert_eq!(e.code(), tonic::Code::PermissionDenied, "{e:?}");

    shutdown.cancel();
    server.await.unwrap().unwrap();
}
