//! The Jaeger query client against a local HTTP server that answers
//! `GET /api/traces/{id}` with a trace in Jaeger's JSON model
//! (tests/data/jaeger-trace.json), 404 for any other trace.

use std::path::Path;
use std::sync::{Arc, Mutex};

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpListener;
use vlnav_traces::cli::{SpanSource, profile_trace};
use vlnav_traces::jaeger::{JaegerError, fetch_trace, spans_from_jaeger_json};
use vlnav_traces::{AttrValue, SpanKind, SpanStatus};

const TRACE: &str = "5b8efff798038103d269b633813fc60c";

fn fixture() -> String {
    std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/jaeger-trace.json")).unwrap()
}

/// A minimal HTTP/1.1 server: one response per connection; records request lines.
async fn jaeger_server() -> (String, Arc<Mutex<Vec<String>>>) {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let url = format!("http://{}", listener.local_addr().unwrap());
    let seen = Arc::new(Mutex::new(Vec::new()));
    let log = seen.clone();
    let body = fixture();
    tokio::spawn(async move {
        loop {
            let Ok((mut sock, _)) = listener.accept().await else { return };
            let mut buf = vec![0u8; 8192];
            let mut n = 0;
            while !buf[..n].windows(4).any(|w| w == b"\r\n\r\n") {
                match sock.read(&mut buf[n..]).await {
                    Ok(0) | Err(_) => break,
                    Ok(k) => n += k,
                }
            }
            let request = String::from_utf8_lossy(&buf[..n]).to_string();
            let line = request.lines().next().unwrap_or("").to_string();
            log.lock().unwrap().push(line.clone());
            let (status, payload) = if line.starts_with(&format!("GET /api/traces/{TRACE} ")) {
                ("200 OK", body.clone())
            } else if line.starts_with("GET /api/traces/") {
                (
                    "404 Not Found",
                    r#"{"data":null,"total":0,"limit":0,"offset":0,"errors":[{"code":404,"msg":"trace not found"}]}"#
                        .to_string(),
                )
            } else {
                ("500 Internal Server Error", "boom".to_string())
            };
            let resp = format!(
                "HTTP/1.1 {status}\r\ncontent-type: application/json\r\ncontent-length: {}\r\nconnection: close\r\n\r\n{payload}",
                payload.len()
            );
            let _ = sock.write_all(resp.as_bytes()).await;
            let _ = sock.shutdown().await;
        }
    });
    (url, seen)
}

#[test]
fn jaeger_json_becomes_spans() {
    let spans = spans_from_jaeger_json(&fixture()).unwrap();
    assert_eq!(spans.len(), 7);
    let mission = &spans[0];
    assert_eq!((mission.name.as_str(), mission.service.as_str()), ("mission", "vlnav-gateway"));
    assert_eq!(mission.parent_id, None);
    assert_eq!(mission.start_ns, 1_763_700_000_000_000_000);
    assert_eq!(mission.duration_ns(), 900_000_000);
    let detect = spans.iter().find(|s| s.name == "detect" && s.span_id == "2b1c2d3e4f506172").unwrap();
    assert_eq!(detect.service, "vlnav-detector");
    assert_eq!(detect.kind, SpanKind::Server);
    assert_eq!(detect.parent_id.as_deref(), Some("b1b2c3d4e5f60718"));
    assert_eq!(detect.duration_ns(), 52_000_000);
    assert_eq!(detect.status, SpanStatus::Error { message: "tensor shape mismatch".into() });
    assert_eq!(detect.attributes["rpc.grpc.status_code"], AttrValue::Int(13));
    assert!(!detect.attributes.contains_key("span.kind") && !detect.attributes.contains_key("otel.status_code"));
    let lp = spans.iter().find(|s| s.name == "local-plan").unwrap();
    assert_eq!(lp.attributes["best_cost"], AttrValue::Float(0.4375));
    assert_eq!(lp.status, SpanStatus::Unset);
    assert!(
        spans_from_jaeger_json(r#"{"data":null,"errors":[{"code":404,"msg":"trace not found"}]}"#)
            .unwrap_err()
            .contains("trace not found")
    );
    assert!(spans_from_jaeger_json("<html>").is_err());
}

#[tokio::test]
async fn fetches_a_trace_over_http_and_profiles_it() {
    let (url, seen) = jaeger_server().await;
    // Upper case and a trailing slash are normalized.
    let spans = fetch_trace(&format!("{url}/"), &TRACE.to_uppercase()).await.unwrap();
    assert_eq!(spans.len(), 7);
    assert_eq!(seen.lock().unwrap()[0], format!("GET /api/traces/{TRACE} HTTP/1.1"));

    let report = profile_trace(&SpanSource::Jaeger(url.clone()), TRACE, "control-cycle").await.unwrap();
    let detect = report.lines().find(|l| l.trim_start().starts_with("detect ")).unwrap_or_else(|| panic!("{report}"));
    let cols: Vec<&str> = detect.split_whitespace().collect();
    assert_eq!(cols[..9], ["detect", "vlnav-detector", "server", "2", "1", "31.5", "52.0", "52.0", "52.0"], "{report}");
    assert!(report.contains("2 `control-cycle` cycles: p50 80.0 ms"), "{report}");

    let other = "0123456789abcdef0123456789abcdef";
    match fetch_trace(&url, other).await {
        Err(JaegerError::NotFound { trace_id, .. }) => assert_eq!(trace_id, other),
        other => panic!("expected NotFound, got {other:?}"),
    }
    assert!(matches!(fetch_trace("jaeger:16686", TRACE).await, Err(JaegerError::BadUrl { .. })));
}

#[tokio::test]
async fn unreachable_jaeger_is_reported_with_its_address() {
    let closed = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let url = format!("http://{}", closed.local_addr().unwrap());
    drop(closed);
    let err = fetch_trace(&url, TRACE).await.unwrap_err();
    assert!(matches!(err, JaegerError::Unreachable { .. }), "{err:?}");
    assert!(err.to_string().contains(&url), "{err}");
}
