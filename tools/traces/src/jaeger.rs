//! Jaeger query client: `GET {base}/api/traces/{traceId}` (the JSON API the
//! Jaeger UI uses) → [`Span`]s.

use std::collections::{BTreeMap, HashMap};
use std::time::Duration;

use serde::Deserialize;

use crate::span::{AttrValue, IdError, Span, SpanKind, SpanStatus, normalize_span_id, normalize_trace_id};

#[derive(Debug, thiserror::Error)]
pub enum JaegerError {
    #[error(transparent)]
    BadId(#[from] IdError),
    #[error("invalid Jaeger URL {url:?}: {reason}")]
    BadUrl { url: String, reason: String },
    #[error("cannot reach Jaeger at {url}: {source}")]
    Unreachable { url: String, source: reqwest::Error },
    #[error(
        "trace {trace_id} not found in Jaeger at {url} (spans are exported in batches: wait a few seconds after the mission ends, and check that the collector forwards to Jaeger)"
    )]
    NotFound { trace_id: String, url: String },
    #[error("Jaeger at {url} answered HTTP {status}: {body}")]
    Http { url: String, status: u16, body: String },
    #[error("unexpected Jaeger response from {url}: {reason}")]
    BadResponse { url: String, reason: String },
}

#[derive(Deserialize)]
struct Response {
    #[serde(default)]
    data: Option<Vec<JTrace>>,
    #[serde(default)]
    errors: Option<Vec<JErr>>,
}

#[derive(Deserialize)]
struct JErr {
    #[serde(default)]
    code: i64,
    #[serde(default)]
    msg: String,
}

#[derive(Deserialize)]
struct JTrace {
    #[serde(default)]
    spans: Vec<JSpan>,
    #[serde(default)]
    processes: HashMap<String, JProcess>,
}

#[derive(Deserialize)]
#[serde(rename_all = "camelCase")]
struct JSpan {
    #[serde(rename = "traceID")]
    trace_id: String,
    #[serde(rename = "spanID")]
    span_id: String,
    operation_name: String,
    #[serde(default)]
    references: Vec<JRef>,
    /// Microseconds since the Unix epoch.
    start_time: u64,
    /// Microseconds.
    duration: u64,
    #[serde(default)]
    tags: Vec<JTag>,
    #[serde(rename = "processID", default)]
    process_id: String,
}

#[derive(Deserialize)]
#[serde(rename_all = "camelCase")]
struct JRef {
    ref_type: String,
    #[serde(rename = "spanID")]
    span_id: String,
}

#[derive(Deserialize)]
struct JTag {
    key: String,
    #[serde(rename = "type", default)]
    kind: String,
    value: serde_json::Value,
}

#[derive(Deserialize)]
#[serde(rename_all = "camelCase")]
struct JProcess {
    service_name: String,
}

fn tag_value(tag: &JTag) -> Option<AttrValue> {
    use serde_json::Value;
    Some(match (tag.kind.as_str(), &tag.value) {
        (_, Value::Bool(b)) => AttrValue::Bool(*b),
        ("float64", Value::Number(n)) => AttrValue::Float(n.as_f64()?),
        (_, Value::Number(n)) => match n.as_i64() {
            Some(i) => AttrValue::Int(i),
            None => AttrValue::Float(n.as_f64()?),
        },
        (_, Value::String(s)) => AttrValue::Str(s.clone()),
        (_, other) => AttrValue::Str(other.to_string()),
    })
}

/// Parses a Jaeger `/api/traces/{id}` response body into spans. Tags become
/// attributes, except `span.kind` and the OpenTelemetry status tags
/// (`otel.status_code`, `otel.status_description`, `error`), which become
/// [`SpanKind`] and [`SpanStatus`].
pub fn spans_from_jaeger_json(body: &str) -> Result<Vec<Span>, String> {
    let resp: Response = serde_json::from_str(body).map_err(|e| format!("not a Jaeger trace response: {e}"))?;
    if let Some(errors) = resp.errors.filter(|e| !e.is_empty()) {
        let msgs: Vec<String> = errors.iter().map(|e| format!("{} {}", e.code, e.msg)).collect();
        return Err(format!("Jaeger reported errors: {}", msgs.join("; ")));
    }
    let mut out = Vec::new();
    for trace in resp.data.unwrap_or_default() {
        for js in trace.spans {
            let service = trace
                .processes
                .get(&js.process_id)
                .map(|p| p.service_name.clone())
                .unwrap_or_else(|| crate::otlp::UNKNOWN_SERVICE.to_string());
            let parent = js
                .references
                .iter()
                .find(|r| r.ref_type == "CHILD_OF")
                .or_else(|| js.references.iter().find(|r| r.ref_type == "FOLLOWS_FROM"))
                .map(|r| normalize_span_id(&r.span_id))
                .transpose()
                .map_err(|e| e.to_string())?;
            let mut kind = SpanKind::Internal;
            let mut status_code = String::new();
            let mut status_message = String::new();
            let mut error_tag = false;
            let mut attributes = BTreeMap::new();
            for tag in &js.tags {
                match (tag.key.as_str(), &tag.value) {
                    ("span.kind", serde_json::Value::String(k)) => kind = SpanKind::parse(k).unwrap_or_default(),
                    ("otel.status_code", serde_json::Value::String(c)) => status_code = c.clone(),
                    ("otel.status_description", serde_json::Value::String(m)) => status_message = m.clone(),
                    ("error", serde_json::Value::Bool(b)) => error_tag = *b,
                    _ => {
                        if let Some(v) = tag_value(tag) {
                            attributes.insert(tag.key.clone(), v);
                        }
                    }
                }
            }
            let status = match status_code.as_str() {
                "ERROR" => SpanStatus::Error { message: status_message },
                "OK" => SpanStatus::Ok,
                _ if error_tag => SpanStatus::Error { message: status_message },
                _ => SpanStatus::Unset,
            };
            let start_ns = js.start_time.saturating_mul(1000);
            out.push(Span {
                trace_id: normalize_trace_id(&js.trace_id).map_err(|e| e.to_string())?,
                span_id: normalize_span_id(&js.span_id).map_err(|e| e.to_string())?,
                parent_id: parent,
                name: js.operation_name,
                service,
                kind,
                start_ns,
                end_ns: start_ns.saturating_add(js.duration.saturating_mul(1000)),
                attributes,
                status,
            });
        }
    }
    Ok(out)
}

/// Fetches one trace from Jaeger's query service (`base_url` like
/// `http://jaeger-query:16686`).
pub async fn fetch_trace(base_url: &str, trace_id: &str) -> Result<Vec<Span>, JaegerError> {
    let trace_id = normalize_trace_id(trace_id)?;
    let base = base_url.trim_end_matches('/');
    if !(base.starts_with("http://") || base.starts_with("https://")) {
        return Err(JaegerError::BadUrl { url: base_url.to_string(), reason: "expected http://host:port".into() });
    }
    let url = format!("{base}/api/traces/{trace_id}");
    // reqwest is built with rustls where other crates of the binary ask for
    // it; a TLS-capable client then needs the process's crypto provider.
    // Installing it is idempotent (an already installed one is kept).
    let _ = rustls::crypto::ring::default_provider().install_default();
    let client = reqwest::Client::builder()
        .timeout(Duration::from_secs(30))
        .build()
        .map_err(|e| JaegerError::BadUrl { url: base_url.to_string(), reason: e.to_string() })?;
    let resp = client
        .get(&url)
        .header("accept", "application/json")
        .send()
        .await
        .map_err(|source| JaegerError::Unreachable { url: url.clone(), source })?;
    let status = resp.status().as_u16();
    let body = resp.text().await.map_err(|source| JaegerError::Unreachable { url: url.clone(), source })?;
    if status == 404 {
        return Err(JaegerError::NotFound { trace_id, url });
    }
    if !(200..300).contains(&status) {
        let body: String = body.chars().take(300).collect();
        return Err(JaegerError::Http { url, status, body });
    }
    let spans =
        spans_from_jaeger_json(&body).map_err(|reason| JaegerError::BadResponse { url: url.clone(), reason })?;
    if spans.is_empty() {
        return Err(JaegerError::NotFound { trace_id, url });
    }
    Ok(spans)
}
