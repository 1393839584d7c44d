//! Logs and traces. Traces are always recorded (so trace ids exist and are
//! propagated); they are exported over OTLP/gRPC when the standard
//! `OTEL_EXPORTER_OTLP_ENDPOINT` (or `OTEL_EXPORTER_OTLP_TRACES_ENDPOINT`)
//! is set, under `OTEL_SERVICE_NAME` (default: the binary's service name).
//! An `https://` endpoint is verified against `OTEL_EXPORTER_OTLP_CERTIFICATE`
//! (a CA file, required: no system roots are trusted), and the exporter
//! presents `OTEL_EXPORTER_OTLP_CLIENT_CERTIFICATE` / `_CLIENT_KEY` when
//! both are set (docs/security.md). Logs go to stderr, filtered by `RUST_LOG` (default `info`).

use opentelemetry::trace::TracerProvider as _;
use opentelemetry_sdk::Resource;
use opentelemetry_sdk::metrics::SdkMeterProvider;
use opentelemetry_sdk::propagation::TraceContextPropagator;
use opentelemetry_sdk::trace::SdkTracerProvider;
use tracing_subscriber::layer::SubscriberExt;
use tracing_subscriber::util::SubscriberInitExt;
use tracing_subscriber::{EnvFilter, Layer};

/// Flushes and shuts the exporters down when dropped.
pub struct Telemetry {
    tracer_provider: SdkTracerProvider,
    meter_provider: Option<SdkMeterProvider>,
}

impl Telemetry {
    /// Pushes every finished span out now (tests and short-lived commands).
    pub fn flush(&self) {
        let _ = self.tracer_provider.force_flush();
        if let Some(m) = &self.meter_provider {
            let _ = m.force_flush();
        }
    }
}

impl Drop for Telemetry {
    fn drop(&mut self) {
        let _ = self.tracer_provider.shutdown();
        if let Some(m) = &self.meter_provider {
            let _ = m.shutdown();
        }
    }
}

/// The OTLP endpoint from the standard environment variables, if any.
pub fn otlp_endpoint() -> Option<String> {
    ["OTEL_EXPORTER_OTLP_TRACES_ENDPOINT", "OTEL_EXPORTER_OTLP_ENDPOINT"]
        .iter()
        .find_map(|k| std::env::var(k).ok().filter(|v| !v.trim().is_empty()))
}

/// The OTLP exporter's TLS from the standard variables read through `var`:
/// none for an `http://` endpoint; for `https://`, the CA of
/// `OTEL_EXPORTER_OTLP_CERTIFICATE` and the client identity of
/// `OTEL_EXPORTER_OTLP_CLIENT_CERTIFICATE` / `_CLIENT_KEY` when given.
pub fn otlp_tls(
    endpoint: &str,
    var: impl Fn(&str) -> Option<String>,
) -> anyhow::Result<Option<tonic::transport::ClientTlsConfig>> {
    let var = |k: &str| var(k).filter(|v| !v.trim().is_empty());
    if !endpoint.starts_with("https://") {
        if var("OTEL_EXPORTER_OTLP_CERTIFICATE").is_some() {
            tracing::warn!(%endpoint, "OTEL_EXPORTER_OTLP_CERTIFICATE is set but the endpoint is not https://: spans go in plaintext");
        }
        return Ok(None);
    }
    let Some(ca) = var("OTEL_EXPORTER_OTLP_CERTIFICATE") else {
        anyhow::bail!(
            "the OTLP endpoint {endpoint} is https:// but OTEL_EXPORTER_OTLP_CERTIFICATE (the CA file to verify the collector with) is not set"
        );
    };
    let read = |what: &str, path: &str| {
        std::fs::read(path).map_err(|e| anyhow::anyhow!("{what} {path} (for the OTLP exporter): {e}"))
    };
    let identity = match (var("OTEL_EXPORTER_OTLP_CLIENT_CERTIFICATE"), var("OTEL_EXPORTER_OTLP_CLIENT_KEY")) {
        (Some(c), Some(k)) => Some((read("client certificate", &c)?, read("client key", &k)?)),
        (None, None) => None,
        _ => anyhow::bail!(
            "set both OTEL_EXPORTER_OTLP_CLIENT_CERTIFICATE and OTEL_EXPORTER_OTLP_CLIENT_KEY, or neither"
        ),
    };
    Ok(Some(crate::security::ClientTls::new(read("CA", &ca)?, identity).config(None)))
}

/// Installs the global tracing subscriber, tracer and meter providers and the
/// W3C trace-context propagator. Must run inside a Tokio runtime (the OTLP
/// exporter's client needs it). Safe to call more than once per process: a
/// later call keeps the first subscriber.
pub fn init(default_service_name: &str) -> anyhow::Result<Telemetry> {
    opentelemetry::global::set_text_map_propagator(TraceContextPropagator::new());
    let service_name = std::env::var("OTEL_SERVICE_NAME")
        .ok()
        .filter(|s| !s.is_empty())
        .unwrap_or_else(|| default_service_name.to_string());
    let resource = Resource::builder().with_service_name(service_name).build();

    let mut tracer_builder = SdkTracerProvider::builder().with_resource(resource.clone());
    let mut meter_provider = None;
    if let Some(endpoint) = otlp_endpoint() {
        use opentelemetry_otlp::{WithExportConfig, WithTonicConfig};
        let tls = otlp_tls(&endpoint, |k| std::env::var(k).ok())?;
        let mut spans = opentelemetry_otlp::SpanExporter::builder().with_tonic().with_endpoint(endpoint.clone());
        if let Some(tls) = &tls {
            spans = spans.with_tls_config(tls.clone());
        }
        let spans = spans.build()?;
        // A mission emits thousands of spans in seconds of lockstep simulation:
        // a deep queue and a short delay keep them all.
        let batch = opentelemetry_sdk::trace::BatchConfigBuilder::default()
            .with_max_queue_size(1 << 16)
            .with_max_export_batch_size(2048)
            .with_scheduled_delay(std::time::Duration::from_millis(200))
            .build();
        let processor = opentelemetry_sdk::trace::BatchSpanProcessor::builder(spans).with_batch_config(batch).build();
        tracer_builder = tracer_builder.with_span_processor(processor);
        let mut metrics = opentelemetry_otlp::MetricExporter::builder().with_tonic().with_endpoint(endpoint);
        if let Some(tls) = tls {
            metrics = metrics.with_tls_config(tls);
        }
        let metrics = metrics.build()?;
        let mp = SdkMeterProvider::builder().with_resource(resource).with_periodic_exporter(metrics).build();
        opentelemetry::global::set_meter_provider(mp.clone());
        meter_provider = Some(mp);
    }
    let tracer_provider = tracer_builder.build();
    opentelemetry::global::set_tracer_provider(tracer_provider.clone());
    let tracer = tracer_provider.tracer("vlnav");

    let log_filter = EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| EnvFilter::new("info,h2=warn,hyper=warn,tower=warn,tonic=warn"));
    let fmt = tracing_subscriber::fmt::layer().with_writer(std::io::stderr).with_target(false).with_filter(log_filter);
    // Spans for traces are kept at info and above whatever the log filter says.
    let otel = tracing_opentelemetry::layer()
        .with_tracer(tracer)
        .with_filter(EnvFilter::new("info,h2=off,hyper=off,tower=off,tonic=off"));
    let _ = tracing_subscriber::registry().with(fmt).with(otel).try_init();
    Ok(Telemetry { tracer_provider, meter_provider })
}

/// The W3C trace id (32 hex digits) of the current span, if it is sampled.
pub fn current_trace_id() -> Option<String> {
    use opentelemetry::trace::TraceContextExt;
    use tracing_opentelemetry::OpenTelemetrySpanExt;
    let cx = tracing::Span::current().context();
    let sc = cx.span().span_context().clone();
    sc.is_valid().then(|| sc.trace_id().to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn env(pairs: &[(&str, &str)]) -> impl Fn(&str) -> Option<String> + use<> {
        let m: std::collections::HashMap<String, String> =
            pairs.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect();
        move |k| m.get(k).cloned()
    }

    #[test]
    fn an_https_collector_needs_a_ca_and_a_whole_client_identity() {
        let dir = tempfile::tempdir().unwrap();
        let pki = crate::security::DevPki::ensure(dir.path(), &[]).unwrap();
        let (ca, cert, key) = (pki.ca(), pki.gateway_cert(), pki.gateway_key());
        let (ca, cert, key) = (ca.to_str().unwrap(), cert.to_str().unwrap(), key.to_str().unwrap());
        assert!(otlp_tls("http://c:4317", env(&[])).unwrap().is_none());
        let e = otlp_tls("https://c:4317", env(&[])).unwrap_err().to_string();
        assert!(e.contains("OTEL_EXPORTER_OTLP_CERTIFICATE"), "{e}");
        let e = otlp_tls(
            "https://c:4317",
            env(&[("OTEL_EXPORTER_OTLP_CERTIFICATE", ca), ("OTEL_EXPORTER_OTLP_CLIENT_CERTIFICATE", cert)]),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("OTEL_EXPORTER_OTLP_CLIENT_KEY"), "{e}");
        let e = otlp_tls("https://c:4317", env(&[("OTEL_EXPORTER_OTLP_CERTIFICATE", "/nonexistent/ca.pem")]))
            .unwrap_err()
            .to_string();
        assert!(e.contains("/nonexistent/ca.pem"), "{e}");
        let full = env(&[
            ("OTEL_EXPORTER_OTLP_CERTIFICATE", ca),
            ("OTEL_EXPORTER_OTLP_CLIENT_CERTIFICATE", cert),
            ("OTEL_EXPORTER_OTLP_CLIENT_KEY", key),
        ]);
        assert!(otlp_tls("https://c:4317", full).unwrap().is_some());
    }
}
