//! Logs and traces. Traces are always recorded (so trace ids exist and are
//! propagated); they are exported over OTLP/gRPC when the standard
//! `OTEL_EXPORTER_OTLP_ENDPOINT` (or `OTEL_EXPORTER_OTLP_TRACES_ENDPOINT`)
//! is set, under `OTEL_SERVICE_NAME` (default: the binary's service name).
//! Logs go to stderr, filtered by `RUST_LOG` (default `info`).

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
        use opentelemetry_otlp::WithExportConfig;
        let spans = opentelemetry_otlp::SpanExporter::builder().with_tonic().with_endpoint(endpoint.clone()).build()?;
        // A mission emits thousands of spans in seconds of lockstep simulation:
        // a deep queue and a short delay keep them all.
        let batch = opentelemetry_sdk::trace::BatchConfigBuilder::default()
            .with_max_queue_size(1 << 16)
            .with_max_export_batch_size(2048)
            .with_scheduled_delay(std::time::Duration::from_millis(200))
            .build();
        let processor = opentelemetry_sdk::trace::BatchSpanProcessor::builder(spans).with_batch_config(batch).build();
        tracer_builder = tracer_builder.with_span_processor(processor);
        let metrics = opentelemetry_otlp::MetricExporter::builder().with_tonic().with_endpoint(endpoint).build()?;
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
