//! OTLP (opentelemetry-proto) trace data → [`Span`].

use opentelemetry_proto::tonic::collector::trace::v1::ExportTraceServiceRequest;
use opentelemetry_proto::tonic::common::v1::{AnyValue, KeyValue, any_value};
use opentelemetry_proto::tonic::trace::v1::{span, status};

use crate::span::{AttrValue, Span, SpanKind, SpanStatus, hex};

/// Service name of a resource that did not set `service.name`, per the OTel
/// resource semantic conventions.
pub const UNKNOWN_SERVICE: &str = "unknown_service";

/// The spans of one export request, and why any were rejected.
#[derive(Debug, Default)]
pub struct Converted {
    pub spans: Vec<Span>,
    pub rejected: Vec<String>,
}

/// Converts every span of an export request. A span without a valid trace id
/// (16 bytes, not all zero) or span id (8 bytes, not all zero) is rejected
/// with a reason; the others are kept.
pub fn spans_from_export(req: &ExportTraceServiceRequest) -> Converted {
    let mut out = Converted::default();
    for rs in &req.resource_spans {
        let service = rs
            .resource
            .as_ref()
            .and_then(|r| r.attributes.iter().find(|kv| kv.key == "service.name"))
            .and_then(|kv| kv.value.as_ref())
            .and_then(|v| match &v.value {
                Some(any_value::Value::StringValue(s)) if !s.is_empty() => Some(s.clone()),
                _ => None,
            })
            .unwrap_or_else(|| UNKNOWN_SERVICE.to_string());
        for ss in &rs.scope_spans {
            for s in &ss.spans {
                match convert_span(s, &service) {
                    Ok(span) => out.spans.push(span),
                    Err(reason) => out.rejected.push(format!("span {:?}: {reason}", s.name)),
                }
            }
        }
    }
    out
}

fn valid_id(bytes: &[u8], len: usize) -> bool {
    bytes.len() == len && bytes.iter().any(|&b| b != 0)
}

fn convert_span(s: &opentelemetry_proto::tonic::trace::v1::Span, service: &str) -> Result<Span, String> {
    if !valid_id(&s.trace_id, 16) {
        return Err(format!("trace_id must be 16 bytes and not all zero, got {} bytes", s.trace_id.len()));
    }
    if !valid_id(&s.span_id, 8) {
        return Err(format!("span_id must be 8 bytes and not all zero, got {} bytes", s.span_id.len()));
    }
    let parent_id = if s.parent_span_id.is_empty() || s.parent_span_id.iter().all(|&b| b == 0) {
        None
    } else if s.parent_span_id.len() == 8 {
        Some(hex(&s.parent_span_id))
    } else {
        return Err(format!("parent_span_id must be 8 bytes or empty, got {} bytes", s.parent_span_id.len()));
    };
    let kind = match span::SpanKind::try_from(s.kind).unwrap_or(span::SpanKind::Unspecified) {
        span::SpanKind::Server => SpanKind::Server,
        span::SpanKind::Client => SpanKind::Client,
        span::SpanKind::Producer => SpanKind::Producer,
        span::SpanKind::Consumer => SpanKind::Consumer,
        span::SpanKind::Internal | span::SpanKind::Unspecified => SpanKind::Internal,
    };
    let status = match &s.status {
        None => SpanStatus::Unset,
        Some(st) => match status::StatusCode::try_from(st.code).unwrap_or(status::StatusCode::Unset) {
            status::StatusCode::Unset => SpanStatus::Unset,
            status::StatusCode::Ok => SpanStatus::Ok,
            status::StatusCode::Error => SpanStatus::Error { message: st.message.clone() },
        },
    };
    Ok(Span {
        trace_id: hex(&s.trace_id),
        span_id: hex(&s.span_id),
        parent_id,
        name: s.name.clone(),
        service: service.to_string(),
        kind,
        start_ns: s.start_time_unix_nano,
        end_ns: s.end_time_unix_nano.max(s.start_time_unix_nano),
        attributes: attributes(&s.attributes),
        status,
    })
}

fn attributes(kvs: &[KeyValue]) -> std::collections::BTreeMap<String, AttrValue> {
    kvs.iter().filter_map(|kv| Some((kv.key.clone(), attr_value(kv.value.as_ref()?)?))).collect()
}

fn attr_value(v: &AnyValue) -> Option<AttrValue> {
    Some(match v.value.as_ref()? {
        any_value::Value::StringValue(s) => AttrValue::Str(s.clone()),
        any_value::Value::BoolValue(b) => AttrValue::Bool(*b),
        any_value::Value::IntValue(i) => AttrValue::Int(*i),
        any_value::Value::DoubleValue(d) => AttrValue::Float(*d),
        any_value::Value::ArrayValue(a) => AttrValue::Array(a.values.iter().filter_map(attr_value).collect()),
        any_value::Value::KvlistValue(kv) => {
            let map: serde_json::Map<String, serde_json::Value> = attributes(&kv.values)
                .into_iter()
                .map(|(k, v)| (k, serde_json::to_value(v).unwrap_or(serde_json::Value::Null)))
                .collect();
            AttrValue::Str(serde_json::Value::Object(map).to_string())
        }
        any_value::Value::BytesValue(b) => AttrValue::Str(hex(b)),
        // Only meaningful for the profiling signal; ignored for traces.
        any_value::Value::StringValueStrindex(_) => return None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use opentelemetry_proto::tonic::resource::v1::Resource;
    use opentelemetry_proto::tonic::trace::v1::{ResourceSpans, ScopeSpans, Status};

    fn kv(key: &str, value: any_value::Value) -> KeyValue {
        KeyValue { key: key.into(), value: Some(AnyValue { value: Some(value) }), ..Default::default() }
    }

    fn otlp_span(
        name: &str,
        trace: Vec<u8>,
        id: Vec<u8>,
        parent: Vec<u8>,
    ) -> opentelemetry_proto::tonic::trace::v1::Span {
        opentelemetry_proto::tonic::trace::v1::Span {
            trace_id: trace,
            span_id: id,
            parent_span_id: parent,
            name: name.into(),
            kind: span::SpanKind::Server as i32,
            start_time_unix_nano: 1_000,
            end_time_unix_nano: 5_000,
            attributes: vec![
                kv("rpc.method", any_value::Value::StringValue("Detect".into())),
                kv("rpc.grpc.status_code", any_value::Value::IntValue(0)),
                kv("frame.bytes", any_value::Value::BytesValue(vec![0xde, 0xad])),
            ],
            status: Some(Status { message: "boom".into(), code: status::StatusCode::Error as i32 }),
            ..Default::default()
        }
    }

    #[test]
    fn export_request_becomes_spans_with_service_names() {
        let trace = (1..=16).collect::<Vec<u8>>();
        let req = ExportTraceServiceRequest {
            resource_spans: vec![
                ResourceSpans {
                    resource: Some(Resource {
                        attributes: vec![kv("service.name", any_value::Value::StringValue("vlnav-detector".into()))],
                        ..Default::default()
                    }),
                    scope_spans: vec![ScopeSpans {
                        spans: vec![
                            otlp_span(
                                "detect",
                                trace.clone(),
                                vec![0, 0, 0, 0, 0, 0, 0, 2],
                                vec![0, 0, 0, 0, 0, 0, 0, 1],
                            ),
                            otlp_span("bad", vec![0; 16], vec![1; 8], vec![]),
                            otlp_span("bad-id", trace.clone(), vec![1; 4], vec![]),
                        ],
                        ..Default::default()
                    }],
                    ..Default::default()
                },
                ResourceSpans {
                    resource: None,
                    scope_spans: vec![ScopeSpans {
                        spans: vec![otlp_span("mission", trace.clone(), vec![0, 0, 0, 0, 0, 0, 0, 1], vec![0; 8])],
                        ..Default::default()
                    }],
                    ..Default::default()
                },
            ],
        };
        let got = spans_from_export(&req);
        assert_eq!(got.rejected.len(), 2, "{:?}", got.rejected);
        assert!(got.rejected[0].contains("trace_id"));
        assert!(got.rejected[1].contains("span_id"));
        assert_eq!(got.spans.len(), 2);
        let detect = &got.spans[0];
        assert_eq!(detect.trace_id, "0102030405060708090a0b0c0d0e0f10");
        assert_eq!(detect.span_id, "0000000000000002");
        assert_eq!(detect.parent_id.as_deref(), Some("0000000000000001"));
        assert_eq!(detect.service, "vlnav-detector");
        assert_eq!(detect.kind, SpanKind::Server);
        assert_eq!(detect.duration_ns(), 4_000);
        assert_eq!(detect.status, SpanStatus::Error { message: "boom".into() });
        assert_eq!(detect.attributes["rpc.method"], AttrValue::Str("Detect".into()));
        assert_eq!(detect.attributes["rpc.grpc.status_code"], AttrValue::Int(0));
        assert_eq!(detect.attributes["frame.bytes"], AttrValue::Str("dead".into()));
        let mission = &got.spans[1];
        assert_eq!(mission.service, UNKNOWN_SERVICE);
        assert_eq!(mission.parent_id, None, "an all-zero parent id means no parent");
    }
}
