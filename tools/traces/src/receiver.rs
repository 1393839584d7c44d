//! An OTLP/gRPC receiver (opentelemetry-proto's generated `TraceService`
//! server) that stores every span in a [`SpanStore`]. It also accepts OTLP
//! metrics — the services export them to the same endpoint — counting their
//! data points without storing them: the latency profile comes from spans.
//!
//! Deliberately served without vlnav's telemetry layer: a receiver that
//! traced its own Export calls would feed itself a span per export, forever.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use opentelemetry_proto::tonic::collector::metrics::v1::metrics_service_server::{
    MetricsService, MetricsServiceServer,
};
use opentelemetry_proto::tonic::collector::metrics::v1::{ExportMetricsServiceRequest, ExportMetricsServiceResponse};
use opentelemetry_proto::tonic::collector::trace::v1::trace_service_server::{TraceService, TraceServiceServer};
use opentelemetry_proto::tonic::collector::trace::v1::{
    ExportTracePartialSuccess, ExportTraceServiceRequest, ExportTraceServiceResponse,
};
use opentelemetry_proto::tonic::metrics::v1::metric::Data;
use tokio::net::TcpListener;
use tokio_util::sync::CancellationToken;
use tonic::{Request, Response, Status};

use vlnav_runtime::authz::{AuthzLayer, CallerPolicy, Callers, Methods};

use crate::otlp::spans_from_export;
use crate::store::{SpanStore, StoreError};

/// Largest accepted export request; the SDK's batch exporter sends at most
/// 512 spans per request, far below this.
pub const MAX_EXPORT_BYTES: usize = 32 * 1024 * 1024;

/// Counters of what the receiver has taken in.
#[derive(Debug, Default)]
pub struct ReceiverStats {
    pub spans_stored: AtomicU64,
    pub spans_rejected: AtomicU64,
    pub metric_points: AtomicU64,
}

/// The OTLP trace (and metrics) service backed by a span store.
#[derive(Clone)]
pub struct OtlpReceiver {
    store: Arc<SpanStore>,
    stats: Arc<ReceiverStats>,
}

impl OtlpReceiver {
    pub fn new(store: Arc<SpanStore>) -> Self {
        Self { store, stats: Arc::default() }
    }

    pub fn stats(&self) -> Arc<ReceiverStats> {
        self.stats.clone()
    }

    /// The tonic services to mount on a server.
    pub fn into_services(self) -> (TraceServiceServer<OtlpReceiver>, MetricsServiceServer<OtlpReceiver>) {
        let traces = TraceServiceServer::new(self.clone())
            .max_decoding_message_size(MAX_EXPORT_BYTES)
            .accept_compressed(tonic::codec::CompressionEncoding::Gzip);
        let metrics = MetricsServiceServer::new(self)
            .max_decoding_message_size(MAX_EXPORT_BYTES)
            .accept_compressed(tonic::codec::CompressionEncoding::Gzip);
        (traces, metrics)
    }
}

#[tonic::async_trait]
impl TraceService for OtlpReceiver {
    async fn export(
        &self,
        request: Request<ExportTraceServiceRequest>,
    ) -> Result<Response<ExportTraceServiceResponse>, Status> {
        let converted = spans_from_export(request.get_ref());
        let stored = converted.spans.len() as u64;
        let store = self.store.clone();
        // File appends are blocking I/O.
        tokio::task::spawn_blocking(move || store.insert(converted.spans))
            .await
            .map_err(|e| Status::internal(format!("span store task failed: {e}")))?
            .map_err(|e| match e {
                StoreError::BadTraceId(e) => Status::invalid_argument(e.to_string()),
                StoreError::Io { .. } => Status::unavailable(format!("cannot persist spans: {e}")),
            })?;
        self.stats.spans_stored.fetch_add(stored, Ordering::Relaxed);
        let partial_success = if converted.rejected.is_empty() {
            None
        } else {
            self.stats.spans_rejected.fetch_add(converted.rejected.len() as u64, Ordering::Relaxed);
            Some(ExportTracePartialSuccess {
                rejected_spans: converted.rejected.len() as i64,
                error_message: converted.rejected.join("; "),
            })
        };
        Ok(Response::new(ExportTraceServiceResponse { partial_success }))
    }
}

#[tonic::async_trait]
impl MetricsService for OtlpReceiver {
    async fn export(
        &self,
        request: Request<ExportMetricsServiceRequest>,
    ) -> Result<Response<ExportMetricsServiceResponse>, Status> {
        let points: usize = request
            .get_ref()
            .resource_metrics
            .iter()
            .flat_map(|rm| &rm.scope_metrics)
            .flat_map(|sm| &sm.metrics)
            .map(|m| match &m.data {
                Some(Data::Gauge(g)) => g.data_points.len(),
                Some(Data::Sum(s)) => s.data_points.len(),
                Some(Data::Histogram(h)) => h.data_points.len(),
                Some(Data::ExponentialHistogram(h)) => h.data_points.len(),
                Some(Data::Summary(s)) => s.data_points.len(),
                None => 0,
            })
            .sum();
        self.stats.metric_points.fetch_add(points as u64, Ordering::Relaxed);
        Ok(Response::new(ExportMetricsServiceResponse { partial_success: None }))
    }
}

/// Serves the OTLP/gRPC receiver on `listener` (conventionally port 4317,
/// `vlnav_runtime::ports::TRACE_RECEIVER`) until `shutdown` is cancelled,
/// storing every received span in `store`.
pub async fn serve_receiver(
    listener: TcpListener,
    store: Arc<SpanStore>,
    shutdown: CancellationToken,
) -> anyhow::Result<()> {
    serve_receiver_with(listener, store, None, shutdown).await
}

/// Who may export to the receiver over TLS: services
/// (`spiffe://vlnav/service/*`; every process of `vlnav up` exports with the
/// gateway's certificate), not robots nor certificates naming no service.
pub fn exporter_policy() -> CallerPolicy {
    CallerPolicy::new().allow(
        Methods::All,
        [Callers::services()],
        "the trace receiver takes spans and metrics only from services (spiffe://vlnav/service/*)",
    )
}

/// [`serve_receiver`] over TLS when `tls` is given. `tls` must carry a client
/// CA: only exporters with a certificate from that CA naming a service
/// ([`exporter_policy`]) may send; others get PERMISSION_DENIED.
pub async fn serve_receiver_with(
    listener: TcpListener,
    store: Arc<SpanStore>,
    tls: Option<vlnav_runtime::tls::ServerTls>,
    shutdown: CancellationToken,
) -> anyhow::Result<()> {
    let addr = listener.local_addr()?;
    let (traces, metrics) = OtlpReceiver::new(store.clone()).into_services();
    tracing::info!(%addr, dir = %store.dir().display(), tls = tls.is_some(), "OTLP trace receiver listening");
    let router = tonic::transport::Server::builder()
        .tcp_nodelay(true)
        .layer(AuthzLayer::new(exporter_policy()))
        .add_service(traces)
        .add_service(metrics);
    match tls {
        // The runtime's own handshakes (crates/runtime/src/tls.rs): the
        // certificate is read again when its files change.
        Some(tls) => {
            router
                .serve_with_incoming_shutdown(tls.incoming(listener, shutdown.clone()), shutdown.cancelled_owned())
                .await?
        }
        None => {
            router
                .serve_with_incoming_shutdown(
                    tonic::transport::server::TcpIncoming::from(listener).with_nodelay(Some(true)),
                    shutdown.cancelled_owned(),
                )
                .await?
        }
    }
    Ok(())
}
