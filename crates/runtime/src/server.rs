//! Server bootstrap shared by every vlnav service: one call serves a set of
//! tonic services with health, reflection (v1 and v1alpha — grpcurl 1.8.6
//! speaks only v1alpha), tonic's own request timeout (it answers
//! DEADLINE_EXCEEDED instead of resetting the stream), a telemetry layer,
//! authorisation of callers by their certificate's identity
//! ([`crate::authz`]) and graceful shutdown.

use std::collections::HashMap;
use std::convert::Infallible;
use std::net::SocketAddr;
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::{Duration, Instant};

use futures::future::BoxFuture;
use opentelemetry::KeyValue;
use opentelemetry::propagation::Extractor;
use tokio::net::TcpListener;
use tokio_util::sync::CancellationToken;
use tonic::body::Body;
use tonic::server::NamedService;
use tonic::service::RoutesBuilder;
use tonic::transport::server::TcpIncoming;
use tracing::Instrument;
use tracing_opentelemetry::OpenTelemetrySpanExt;

use crate::transport::{CONNECTION_WINDOW, STREAM_WINDOW};
pub use crate::transport::{KEEPALIVE_INTERVAL, KEEPALIVE_TIMEOUT};

/// Settings every server takes (flags or environment).
#[derive(clap::Args, Clone, Debug)]
pub struct ServerConfig {
    /// Address to listen on (default: the service's own port on 127.0.0.1).
    #[arg(long, env = "VLNAV_LISTEN")]
    pub listen: Option<SocketAddr>,
    /// Requests running longer than this get DEADLINE_EXCEEDED, seconds.
    #[arg(long, env = "VLNAV_REQUEST_TIMEOUT_S", default_value_t = 30.0)]
    pub request_timeout_s: f64,
    /// Largest accepted or sent gRPC message, bytes.
    #[arg(long, env = "VLNAV_MAX_MESSAGE_BYTES", default_value_t = 16 * 1024 * 1024)]
    pub max_message_bytes: usize,
    #[command(flatten)]
    pub tls: crate::security::ServerTlsArgs,
    /// Serve plaintext on a non-loopback address (refused otherwise):
    /// anyone who reaches the port can then call every method.
    #[arg(long, env = "VLNAV_INSECURE")]
    pub insecure: bool,
    /// Callers without a client certificate pass the TLS handshake (the
    /// gateway: people authenticate with tokens, robots with certificates).
    #[arg(skip)]
    pub client_cert_optional: bool,
    /// Also serve grpc.health.v1 alone, in plaintext, on this address, for
    /// probes that speak no TLS (Kubernetes' gRPC probes). It answers
    /// nothing but health, so it needs neither TLS nor --insecure.
    #[arg(long, env = "VLNAV_HEALTH_LISTEN")]
    pub health_listen: Option<SocketAddr>,
    /// Requests one connection may have in flight; one more is refused at
    /// once with RESOURCE_EXHAUSTED (load shedding) instead of queueing. A
    /// streaming call holds its place only until its response begins.
    #[arg(long, env = "VLNAV_MAX_CONCURRENT_REQUESTS", default_value_t = 256)]
    pub max_concurrent_requests: usize,
    /// HTTP/2 streams one connection may open at a time (SETTINGS_MAX_CONCURRENT_STREAMS).
    #[arg(long, env = "VLNAV_MAX_CONCURRENT_STREAMS", default_value_t = 512)]
    pub max_concurrent_streams: u32,
}

impl Default for ServerConfig {
    fn default() -> Self {
        Self {
            listen: None,
            request_timeout_s: 30.0,
            max_message_bytes: 16 * 1024 * 1024,
            tls: Default::default(),
            insecure: false,
            client_cert_optional: false,
            health_listen: None,
            max_concurrent_requests: 256,
            max_concurrent_streams: 512,
        }
    }
}

impl ServerConfig {
    /// The configured address, or `127.0.0.1:default_port`.
    pub fn listen_addr(&self, default_port: u16) -> SocketAddr {
        self.listen.unwrap_or_else(|| SocketAddr::from(([127, 0, 0, 1], default_port)))
    }
}

/// The tonic services one server hosts, each with the pipeline stage its
/// spans are named after ("plan", "detect", "local-plan", …), and who may
/// call them ([`ServiceSet::callers`]; by default nobody but health and
/// reflection over TLS).
#[derive(Default)]
pub struct ServiceSet {
    routes: RoutesBuilder,
    stages: HashMap<&'static str, &'static str>,
    callers: crate::authz::CallerPolicy,
}

impl ServiceSet {
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds a service; its server spans are named `stage`.
    pub fn add<S>(mut self, stage: &'static str, svc: S) -> Self
    where
        S: tower::Service<http::Request<Body>, Response = http::Response<Body>, Error = Infallible>
            + NamedService
            + Clone
            + Send
            + Sync
            + 'static,
        S::Future: Send + 'static,
    {
        self.stages.insert(S::NAME, stage);
        self.routes.add_service(svc);
        self
    }

    /// The identities this server answers, method by method (checked on
    /// TLS connections; health and reflection stay open).
    pub fn callers(mut self, policy: crate::authz::CallerPolicy) -> Self {
        self.callers = policy;
        self
    }

    pub fn names(&self) -> impl Iterator<Item = &'static str> + '_ {
        self.stages.keys().copied()
    }
}

/// Serves `services` on `listener` until `shutdown` is cancelled, then drains
/// in-flight requests. Health reports SERVING for each service (and for the
/// server as a whole, name "") until shutdown begins. On TLS every call is
/// checked against the set's [`crate::authz::CallerPolicy`].
pub async fn serve(
    cfg: &ServerConfig,
    listener: TcpListener,
    services: ServiceSet,
    shutdown: CancellationToken,
) -> anyhow::Result<()> {
    let (health, health_svc) = tonic_health::server::health_reporter();
    let mut names: Vec<&'static str> = services.names().collect();
    names.sort();
    let reflection = || {
        names.iter().fold(
            tonic_reflection::server::Builder::configure()
                .register_encoded_file_descriptor_set(vlnav_proto::FILE_DESCRIPTOR_SET)
                .register_encoded_file_descriptor_set(tonic_health::pb::FILE_DESCRIPTOR_SET)
                .with_service_name("grpc.health.v1.Health")
                .with_service_name("grpc.reflection.v1.ServerReflection")
                .with_service_name("grpc.reflection.v1alpha.ServerReflection"),
            |b, name| b.with_service_name(*name),
        )
    };
    let reflection_v1 = reflection().build_v1()?;
    let reflection_v1alpha = reflection().build_v1alpha()?;
    for name in &names {
        health.set_service_status(*name, tonic_health::ServingStatus::Serving).await;
    }
    health.set_service_status("", tonic_health::ServingStatus::Serving).await;

    let callers = services.callers;
    let mut stages = services.stages;
    stages.insert("grpc.health.v1.Health", "health");
    stages.insert("grpc.reflection.v1.ServerReflection", "reflection");
    stages.insert("grpc.reflection.v1alpha.ServerReflection", "reflection");
    let mut routes = services.routes;
    routes.add_service(health_svc.clone()).add_service(reflection_v1).add_service(reflection_v1alpha);

    let addr = listener.local_addr()?;
    let tls = cfg.tls.load(cfg.client_cert_optional)?;
    check_exposure(addr, tls.is_some(), cfg.insecure)?;
    check_callers(&names, &callers, tls.is_some(), cfg.tls.tls_client_ca.is_some())?;
    tracing::info!(
        %addr,
        services = ?names,
        tls = tls.is_some(),
        mutual_tls = cfg.tls.tls_client_ca.is_some(),
        callers = %if tls.is_some() { callers.to_string() } else { "not checked (plaintext)".into() },
        "serving"
    );
    let drain = {
        let shutdown = shutdown.clone();
        let health = health.clone();
        let names = names.clone();
        async move {
            shutdown.cancelled().await;
            for name in names {
                health.set_service_status(name, tonic_health::ServingStatus::NotServing).await;
            }
            health.set_service_status("", tonic_health::ServingStatus::NotServing).await;
            tracing::info!(%addr, "shutting down, draining in-flight requests");
        }
    };
    if let Some(health_addr) = cfg.health_listen {
        let probe = TcpListener::bind(health_addr)
            .await
            .map_err(|e| anyhow::anyhow!("cannot listen for health probes on {health_addr}: {e}"))?;
        tracing::info!(addr = %probe.local_addr()?, "serving grpc.health.v1 only, plaintext, for probes");
        let health_only = tonic::transport::Server::builder()
            .tcp_nodelay(true)
            .add_service(health_svc.clone())
            .serve_with_incoming_shutdown(
                TcpIncoming::from(probe).with_nodelay(Some(true)),
                shutdown.clone().cancelled_owned(),
            );
        tokio::spawn(async move {
            if let Err(e) = health_only.await {
                tracing::error!("health probe port stopped: {e}");
            }
        });
    }
    let revoked = tls.as_ref().and_then(|t| t.revoked());
    let router = tonic::transport::Server::builder()
        .timeout(Duration::from_secs_f64(cfg.request_timeout_s.max(0.001)))
        // Overload: a connection past its in-flight limit is refused at once
        // (RESOURCE_EXHAUSTED), never queued behind work it cannot see.
        .concurrency_limit_per_connection(cfg.max_concurrent_requests.max(1))
        .load_shed(true)
        .max_concurrent_streams(cfg.max_concurrent_streams.max(1))
        // A peer that vanished without closing (a partition, a powered-off
        // robot) is found within keepalive interval + timeout.
        .http2_keepalive_interval(Some(KEEPALIVE_INTERVAL))
        .http2_keepalive_timeout(Some(KEEPALIVE_TIMEOUT))
        .tcp_nodelay(true)
        .initial_stream_window_size(STREAM_WINDOW)
        .initial_connection_window_size(CONNECTION_WINDOW)
        .layer(TelemetryLayer { stages: Arc::new(stages) })
        // Inside the telemetry layer, so a refusal is traced and counted; a
        // revoked certificate is refused before its identity is looked at.
        .layer(crate::revocation::RevocationLayer::new(revoked))
        .layer(crate::authz::AuthzLayer::new(callers))
        .add_routes(routes.routes());
    match tls {
        // TLS handshakes of our own (crate::tls): the certificate and the
        // revocation list are read again when their files change.
        Some(tls) => router.serve_with_incoming_shutdown(tls.incoming(listener, shutdown.clone()), drain).await?,
        // The builder's tcp_nodelay applies only to listeners tonic binds
        // itself; accepted sockets of ours need it set here, or Nagle holds
        // a response's last segment until the client's delayed ACK (~40 ms).
        None => {
            router.serve_with_incoming_shutdown(TcpIncoming::from(listener).with_nodelay(Some(true)), drain).await?
        }
    }
    Ok(())
}

/// Refuses plaintext on an address other hosts can reach unless `insecure`
/// says so explicitly, and then warns (docs/security.md).
pub fn check_exposure(addr: SocketAddr, tls: bool, insecure: bool) -> anyhow::Result<()> {
    if tls || addr.ip().is_loopback() {
        return Ok(());
    }
    if !insecure {
        anyhow::bail!(
            "refusing plaintext gRPC on {addr}, which other hosts can reach: give --tls-cert and --tls-key \
             (VLNAV_TLS_CERT, VLNAV_TLS_KEY), listen on a loopback address, or pass --insecure (VLNAV_INSECURE=true) \
             to accept that anyone who reaches {addr} can call every method"
        );
    }
    tracing::warn!(%addr, "INSECURE: plaintext gRPC on a non-loopback address; anyone who reaches it can call every method");
    Ok(())
}

/// Refuses to serve over TLS without asking callers for a certificate when
/// the policy authorises callers by one: every call would be refused.
pub fn check_callers(
    names: &[&str],
    callers: &crate::authz::CallerPolicy,
    tls: bool,
    client_ca: bool,
) -> anyhow::Result<()> {
    if tls && !client_ca && !names.is_empty() && callers.wants_certificates() {
        anyhow::bail!(
            "{} authorises callers by their certificate ({callers}), but without --tls-client-ca \
             (VLNAV_TLS_CLIENT_CA) no caller is asked for one: give the CA that signed the callers' certificates",
            names.join(", ")
        );
    }
    Ok(())
}

/// Completes on SIGINT or SIGTERM (what Kubernetes sends before a kill).
pub async fn shutdown_signal() {
    let ctrl_c = tokio::signal::ctrl_c();
    #[cfg(unix)]
    {
        let mut term = match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(s) => s,
            Err(_) => {
                let _ = ctrl_c.await;
                return;
            }
        };
        tokio::select! {
            _ = ctrl_c => {},
            _ = term.recv() => {},
        }
    }
    #[cfg(not(unix))]
    let _ = ctrl_c.await;
}

/// Per-request server span (named by stage, parented on the caller's W3C
/// trace context) and the `rpc.server.duration` metric by method and status.
#[derive(Clone)]
struct TelemetryLayer {
    stages: Arc<HashMap<&'static str, &'static str>>,
}

impl<S> tower::Layer<S> for TelemetryLayer {
    type Service = TelemetryService<S>;
    fn layer(&self, inner: S) -> Self::Service {
        TelemetryService { inner, stages: self.stages.clone() }
    }
}

#[derive(Clone)]
struct TelemetryService<S> {
    inner: S,
    stages: Arc<HashMap<&'static str, &'static str>>,
}

struct HeaderExtractor<'a>(&'a http::HeaderMap);

impl Extractor for HeaderExtractor<'_> {
    fn get(&self, key: &str) -> Option<&str> {
        self.0.get(key).and_then(|v| v.to_str().ok())
    }
    fn keys(&self) -> Vec<&str> {
        self.0.keys().map(|k| k.as_str()).collect()
    }
}

fn duration_histogram() -> &'static opentelemetry::metrics::Histogram<f64> {
    static H: std::sync::OnceLock<opentelemetry::metrics::Histogram<f64>> = std::sync::OnceLock::new();
    H.get_or_init(|| {
        opentelemetry::global::meter("vlnav")
            .f64_histogram("rpc.server.duration")
            .with_unit("ms")
            .with_description("gRPC server latency by method and status code")
            .build()
    })
}

impl<S, B> tower::Service<http::Request<B>> for TelemetryService<S>
where
    S: tower::Service<http::Request<B>, Response = http::Response<Body>> + Clone + Send + 'static,
    S::Future: Send + 'static,
    B: Send + 'static,
{
    type Response = S::Response;
    type Error = S::Error;
    type Future = BoxFuture<'static, Result<Self::Response, Self::Error>>;

    fn poll_ready(&mut self, cx: &mut Context<'_>) -> Poll<Result<(), Self::Error>> {
        self.inner.poll_ready(cx)
    }

    fn call(&mut self, req: http::Request<B>) -> Self::Future {
        let path = req.uri().path().to_string();
        let (service, method) = path.trim_start_matches('/').split_once('/').unwrap_or((path.as_str(), ""));
        let (service, method) = (service.to_string(), method.to_string());
        let stage = self.stages.get(service.as_str()).copied().unwrap_or("grpc");
        let quiet = matches!(stage, "health" | "reflection");
        let parent = opentelemetry::global::get_text_map_propagator(|p| p.extract(&HeaderExtractor(req.headers())));
        let span = if quiet {
            tracing::debug_span!("grpc", otel.name = stage, rpc.service = %service, rpc.method = %method)
        } else {
            tracing::info_span!(
                "grpc",
                otel.name = stage,
                otel.kind = "server",
                rpc.system = "grpc",
                rpc.service = %service,
                rpc.method = %method,
                rpc.grpc.status_code = tracing::field::Empty,
            )
        };
        let _ = span.set_parent(parent);
        // Clone-and-swap keeps the service that was polled ready for this call.
        let clone = self.inner.clone();
        let mut inner = std::mem::replace(&mut self.inner, clone);
        let started = Instant::now();
        Box::pin(
            async move {
                let result = inner.call(req).await;
                let code = match &result {
                    // Errors are trailers-only responses: grpc-status is in the headers.
                    Ok(resp) => resp
                        .headers()
                        .get("grpc-status")
                        .and_then(|v| v.to_str().ok())
                        .and_then(|v| v.parse::<i32>().ok())
                        .unwrap_or(0),
                    Err(_) => 2,
                };
                tracing::Span::current().record("rpc.grpc.status_code", code);
                if !quiet {
                    duration_histogram().record(
                        started.elapsed().as_secs_f64() * 1e3,
                        &[
                            KeyValue::new("rpc.service", service),
                            KeyValue::new("rpc.method", method),
                            KeyValue::new("rpc.grpc.status_code", code as i64),
                        ],
                    );
                }
                result
            }
            .instrument(span),
        )
    }
}

/// The whole `main` of a standalone service: telemetry, bind, serve until
/// SIGINT/SIGTERM, drain. `build` loads models and spawns actors.
pub async fn serve_main<F>(service_name: &str, default_port: u16, cfg: ServerConfig, build: F) -> anyhow::Result<()>
where
    F: std::future::Future<Output = anyhow::Result<ServiceSet>>,
{
    let telemetry = crate::telemetry::init(service_name)?;
    let services = build.await?;
    let addr = cfg.listen_addr(default_port);
    let listener =
        TcpListener::bind(addr).await.map_err(|e| anyhow::anyhow!("{service_name}: cannot listen on {addr}: {e}"))?;
    let token = CancellationToken::new();
    let trigger = token.clone();
    tokio::spawn(async move {
        shutdown_signal().await;
        trigger.cancel();
    });
    let result = serve(&cfg, listener, services, token).await;
    telemetry.flush();
    result
}

/// Default ports of the standalone servers (all on 127.0.0.1 unless configured).
pub mod ports {
    pub const GATEWAY: u16 = 50051;
    pub const INGRESS: u16 = 50052;
    pub const PLANNER: u16 = 50053;
    pub const DETECTOR: u16 = 50054;
    pub const REID: u16 = 50055;
    pub const SEGMENTER: u16 = 50056;
    pub const SUBGOAL: u16 = 50057;
    pub const LOCAL_PLANNER: u16 = 50058;
    /// OTLP/gRPC trace receiver built into `vlnav up`.
    pub const TRACE_RECEIVER: u16 = 4317;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::authz::CallerPolicy;

    #[test]
    fn plaintext_is_refused_where_other_hosts_can_reach_it_unless_insecure_is_explicit() {
        let open: SocketAddr = "0.0.0.0:50051".parse().unwrap();
        let lo: SocketAddr = "127.0.0.1:50051".parse().unwrap();
        let e = check_exposure(open, false, false).unwrap_err().to_string();
        assert!(e.contains("--tls-cert") && e.contains("--insecure"), "{e}");
        assert!(check_exposure(open, true, false).is_ok());
        assert!(check_exposure(open, false, true).is_ok());
        assert!(check_exposure(lo, false, false).is_ok());
    }

    #[test]
    fn tls_without_a_client_ca_is_refused_where_callers_are_authorised_by_certificate() {
        let stages = CallerPolicy::stages();
        let e = check_callers(&["vlnav.v1.PlannerService"], &stages, true, false).unwrap_err().to_string();
        assert!(e.contains("--tls-client-ca") && e.contains("vlnav.v1.PlannerService"), "{e}");
        assert!(check_callers(&["vlnav.v1.PlannerService"], &stages, true, true).is_ok());
        assert!(check_callers(&["vlnav.v1.PlannerService"], &stages, false, false).is_ok(), "plaintext");
        assert!(check_callers(&[], &CallerPolicy::new(), true, false).is_ok(), "nothing but health");
        let people = CallerPolicy::new().allow(crate::authz::Methods::All, [crate::authz::Callers::Uncertified], "");
        assert!(check_callers(&["vlnav.v1.MissionService"], &people, true, false).is_ok());
    }
}
