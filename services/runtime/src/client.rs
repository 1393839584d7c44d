//! Client channels that carry the caller's trace context (W3C `traceparent`)
//! in gRPC metadata, so one mission is one trace across every hop.

use std::time::Duration;

use opentelemetry::propagation::Injector;
use tonic::service::Interceptor;
use tonic::service::interceptor::InterceptedService;
use tonic::transport::{Channel, Endpoint};
use tracing_opentelemetry::OpenTelemetrySpanExt;

/// Injects the current span's context into outgoing request metadata.
#[derive(Clone, Copy, Debug, Default)]
pub struct InjectTraceContext;

struct MetadataInjector<'a>(&'a mut tonic::metadata::MetadataMap);

impl Injector for MetadataInjector<'_> {
    fn set(&mut self, key: &str, value: String) {
        if let (Ok(k), Ok(v)) = (
            tonic::metadata::MetadataKey::from_bytes(key.as_bytes()),
            tonic::metadata::MetadataValue::try_from(value.as_str()),
        ) {
            self.0.insert(k, v);
        }
    }
}

impl Interceptor for InjectTraceContext {
    fn call(&mut self, mut request: tonic::Request<()>) -> Result<tonic::Request<()>, tonic::Status> {
        let cx = tracing::Span::current().context();
        opentelemetry::global::get_text_map_propagator(|p| {
            p.inject_context(&cx, &mut MetadataInjector(request.metadata_mut()))
        });
        Ok(request)
    }
}

/// HTTP/2 flow-control windows sized for RGB-D frames, bytes.
pub const STREAM_WINDOW: u32 = 16 * 1024 * 1024;
pub const CONNECTION_WINDOW: u32 = 64 * 1024 * 1024;

/// A channel whose every request carries the caller's trace context.
pub type TracedChannel = InterceptedService<Channel, InjectTraceContext>;

/// A lazily connecting channel to `uri` (e.g. `http://127.0.0.1:50053`):
/// the service may start after its callers, and reconnects are automatic.
pub fn channel(uri: &str) -> Result<TracedChannel, tonic::transport::Error> {
    let ch = Endpoint::from_shared(uri.to_string())?
        .connect_timeout(Duration::from_secs(5))
        .tcp_nodelay(true)
        .http2_keep_alive_interval(Duration::from_secs(30))
        // RGB-D frames are megabytes: h2's default 64 KiB windows would cost a
        // round trip per 64 KiB of every frame.
        .initial_stream_window_size(STREAM_WINDOW)
        .initial_connection_window_size(CONNECTION_WINDOW)
        .connect_lazy();
    Ok(InterceptedService::new(ch, InjectTraceContext))
}
