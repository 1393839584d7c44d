//! The one span type every source (OTLP receiver, span files, Jaeger) is
//! converted to, and the identifiers it carries.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

/// A finished span, independent of where it was read from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Span {
    /// W3C trace id: 32 lowercase hex digits.
    pub trace_id: String,
    /// 16 lowercase hex digits.
    pub span_id: String,
    /// The parent's span id; `None` for a trace's root (or a span whose
    /// parent lives in a process that did not export it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub parent_id: Option<String>,
    /// Operation name; vlnav names spans by pipeline stage ("detect", "control-cycle", …).
    pub name: String,
    /// `service.name` of the process that recorded the span.
    pub service: String,
    #[serde(default)]
    pub kind: SpanKind,
    /// Unix time, nanoseconds.
    pub start_ns: u64,
    pub end_ns: u64,
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub attributes: BTreeMap<String, AttrValue>,
    #[serde(default)]
    pub status: SpanStatus,
}

impl Span {
    /// `end − start`, zero for a span whose clock went backwards.
    pub fn duration_ns(&self) -> u64 {
        self.end_ns.saturating_sub(self.start_ns)
    }

    pub fn is_error(&self) -> bool {
        matches!(self.status, SpanStatus::Error { .. })
    }
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SpanKind {
    #[default]
    Internal,
    Server,
    Client,
    Producer,
    Consumer,
}

impl SpanKind {
    pub fn as_str(self) -> &'static str {
        match self {
            SpanKind::Internal => "internal",
            SpanKind::Server => "server",
            SpanKind::Client => "client",
            SpanKind::Producer => "producer",
            SpanKind::Consumer => "consumer",
        }
    }

    /// Parses the lowercase names used by OTLP (without prefix) and Jaeger's `span.kind` tag.
    pub fn parse(s: &str) -> Option<Self> {
        Some(match s.to_ascii_lowercase().as_str() {
            "internal" => SpanKind::Internal,
            "server" => SpanKind::Server,
            "client" => SpanKind::Client,
            "producer" => SpanKind::Producer,
            "consumer" => SpanKind::Consumer,
            _ => return None,
        })
    }
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(tag = "code", rename_all = "lowercase")]
pub enum SpanStatus {
    #[default]
    Unset,
    Ok,
    Error {
        #[serde(default)]
        message: String,
    },
}

/// An attribute value (OTLP's AnyValue without the nesting of maps, which
/// are kept as their JSON text).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum AttrValue {
    Bool(bool),
    Int(i64),
    Float(f64),
    Str(String),
    Array(Vec<AttrValue>),
}

impl std::fmt::Display for AttrValue {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            AttrValue::Bool(v) => write!(f, "{v}"),
            AttrValue::Int(v) => write!(f, "{v}"),
            AttrValue::Float(v) => write!(f, "{v}"),
            AttrValue::Str(v) => f.write_str(v),
            AttrValue::Array(items) => {
                f.write_str("[")?;
                for (i, v) in items.iter().enumerate() {
                    if i > 0 {
                        f.write_str(", ")?;
                    }
                    write!(f, "{v}")?;
                }
                f.write_str("]")
            }
        }
    }
}

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum IdError {
    #[error("{what} {id:?} is not hexadecimal (expected up to {digits} hex digits)")]
    NotHex { what: &'static str, id: String, digits: usize },
    #[error("{what} {id:?} has {len} hex digits, more than {digits}")]
    TooLong { what: &'static str, id: String, len: usize, digits: usize },
    #[error("{what} is all zeros or empty, which W3C trace context defines as invalid")]
    Zero { what: &'static str },
}

fn normalize_hex(what: &'static str, id: &str, digits: usize) -> Result<String, IdError> {
    let id = id.trim();
    if !id.bytes().all(|b| b.is_ascii_hexdigit()) {
        return Err(IdError::NotHex { what, id: id.to_string(), digits });
    }
    if id.len() > digits {
        return Err(IdError::TooLong { what, id: id.to_string(), len: id.len(), digits });
    }
    if id.bytes().all(|b| b == b'0') {
        return Err(IdError::Zero { what });
    }
    // Jaeger prints 128-bit ids whose high half is zero with 16 digits, and
    // drops leading zeros in places: pad back to the W3C width.
    Ok(format!("{:0>digits$}", id.to_ascii_lowercase()))
}

/// A W3C trace id in canonical form (32 lowercase hex digits); shorter hex
/// is left-padded with zeros. Safe to use as a file name.
pub fn normalize_trace_id(id: &str) -> Result<String, IdError> {
    normalize_hex("trace id", id, 32)
}

/// A span id in canonical form (16 lowercase hex digits).
pub fn normalize_span_id(id: &str) -> Result<String, IdError> {
    normalize_hex("span id", id, 16)
}

/// Lowercase hex of raw id bytes (OTLP carries ids as bytes).
pub fn hex(bytes: &[u8]) -> String {
    use std::fmt::Write;
    bytes.iter().fold(String::with_capacity(bytes.len() * 2), |mut s, b| {
        let _ = write!(s, "{b:02x}");
        s
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trace_ids_are_padded_lowercased_and_checked() {
        assert_eq!(normalize_trace_id("ABCDEF").unwrap(), format!("{}abcdef", "0".repeat(26)));
        assert_eq!(
            normalize_trace_id(" 4bf92f3577b34da6a3ce929d0e0e4736 ").unwrap(),
            "4bf92f3577b34da6a3ce929d0e0e4736"
        );
        assert!(matches!(normalize_trace_id("../etc/passwd"), Err(IdError::NotHex { .. })));
        assert!(matches!(normalize_trace_id(&"a".repeat(33)), Err(IdError::TooLong { len: 33, .. })));
        assert!(matches!(normalize_trace_id("0000"), Err(IdError::Zero { .. })));
        assert!(matches!(normalize_trace_id(""), Err(IdError::Zero { .. })));
        assert_eq!(normalize_span_id("1").unwrap(), "0000000000000001");
    }

    #[test]
    fn hex_of_bytes() {
        assert_eq!(hex(&[0x00, 0xab, 0x10]), "00ab10");
    }

    #[test]
    fn span_round_trips_through_json() {
        let mut attributes = BTreeMap::new();
        attributes.insert("rpc.grpc.status_code".to_string(), AttrValue::Int(0));
        attributes.insert("ratio".to_string(), AttrValue::Float(0.5));
        attributes.insert("ok".to_string(), AttrValue::Bool(true));
        attributes.insert("rpc.method".to_string(), AttrValue::Str("Detect".into()));
        attributes.insert("ids".to_string(), AttrValue::Array(vec![AttrValue::Int(1), AttrValue::Int(2)]));
        let span = Span {
            trace_id: "4bf92f3577b34da6a3ce929d0e0e4736".into(),
            span_id: "00f067aa0ba902b7".into(),
            parent_id: Some("00f067aa0ba902b6".into()),
            name: "detect".into(),
            service: "vlnav-detector".into(),
            kind: SpanKind::Server,
            start_ns: 1_700_000_000_000_000_000,
            end_ns: 1_700_000_000_012_000_000,
            attributes,
            status: SpanStatus::Error { message: "model missing".into() },
        };
        let json = serde_json::to_string(&span).unwrap();
        let back: Span = serde_json::from_str(&json).unwrap();
        assert_eq!(back, span);
        assert_eq!(back.duration_ns(), 12_000_000);
        assert!(back.is_error());
    }
}
