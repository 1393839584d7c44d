//! Client channels that carry the caller's trace context (W3C `traceparent`)
//! in gRPC metadata, so one mission is one trace across every hop, and that
//! open a client span around every call: the client span less the server's
//! span under it is what the hop itself costs — waiting for the connection,
//! encoding, TLS, the network and the reply's way back (docs/architecture.md,
//! "Where a control cycle's time goes").

use std::collections::HashSet;
use std::future::Future;
use std::net::SocketAddr;
use std::pin::Pin;
use std::task::{Context, Poll};
use std::time::Duration;

use opentelemetry::propagation::Injector;
use tonic::body::Body;
use tonic::transport::channel::Change;
use tonic::transport::{Channel, Endpoint};
use tracing::Instrument;
use tracing_opentelemetry::OpenTelemetrySpanExt;

use crate::security::{ClientSecurity, ClientTls};
pub use crate::transport::{CONNECTION_WINDOW, STREAM_WINDOW};
use crate::transport::{KEEPALIVE_INTERVAL, KEEPALIVE_TIMEOUT};

/// Injects the current span's context into outgoing request headers, and
/// the caller's bearer token when it has one (docs/security.md).
#[derive(Clone, Debug, Default)]
pub struct InjectTraceContext {
    bearer: Option<http::HeaderValue>,
}

impl InjectTraceContext {
    /// Also sends `authorization: Bearer <token>`.
    pub fn with_bearer(token: &str) -> Result<Self, AddressError> {
        let value = http::HeaderValue::from_str(&format!("Bearer {token}"))
            .map_err(|_| AddressError("the bearer token holds characters a header cannot carry".into()))?;
        Ok(Self { bearer: Some(value) })
    }

    /// Writes the current span's context (and the bearer token) into
    /// outgoing request headers.
    fn inject_headers(&self, headers: &mut http::HeaderMap) {
        let cx = tracing::Span::current().context();
        opentelemetry::global::get_text_map_propagator(|p| p.inject_context(&cx, &mut HeaderInjector(headers)));
        if let Some(b) = &self.bearer {
            headers.insert(http::header::AUTHORIZATION, b.clone());
        }
    }
}

struct HeaderInjector<'a>(&'a mut http::HeaderMap);

impl Injector for HeaderInjector<'_> {
    fn set(&mut self, key: &str, value: String) {
        if let (Ok(k), Ok(v)) =
            (http::header::HeaderName::from_bytes(key.as_bytes()), http::header::HeaderValue::from_str(&value))
        {
            self.0.insert(k, v);
        }
    }
}

/// A channel whose every call is a client span (`call <Method>`, kind
/// client) and carries that span's trace context, so the server's span is
/// its child.
#[derive(Clone, Debug)]
pub struct TracedChannel {
    inner: Channel,
    inject: InjectTraceContext,
}

impl TracedChannel {
    pub fn new(inner: Channel, inject: InjectTraceContext) -> Self {
        Self { inner, inject }
    }
}

impl tower::Service<http::Request<Body>> for TracedChannel {
    type Response = http::Response<Body>;
    type Error = tonic::transport::Error;
    type Future = Pin<Box<dyn Future<Output = Result<Self::Response, Self::Error>> + Send>>;

    fn poll_ready(&mut self, cx: &mut Context<'_>) -> Poll<Result<(), Self::Error>> {
        self.inner.poll_ready(cx)
    }

    fn call(&mut self, mut req: http::Request<Body>) -> Self::Future {
        let path = req.uri().path();
        let (service, method) = path.trim_start_matches('/').split_once('/').unwrap_or((path, ""));
        let span = tracing::info_span!(
            "call",
            otel.name = %format_args!("call {method}"),
            otel.kind = "client",
            rpc.system = "grpc",
            rpc.service = %service,
            rpc.method = %method,
        );
        span.in_scope(|| self.inject.inject_headers(req.headers_mut()));
        // Clone-and-swap keeps the channel that was polled ready for this call.
        let clone = self.inner.clone();
        let mut inner = std::mem::replace(&mut self.inner, clone);
        Box::pin(async move { inner.call(req).await }.instrument(span))
    }
}

/// How often a `dns:///` address is resolved again.
pub const DNS_REFRESH: Duration = Duration::from_secs(10);

/// A service address that cannot be used, with what to write instead.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct AddressError(String);

/// The endpoint settings every client connection uses; `https://` addresses
/// are verified against `tls` (and present its certificate), with `domain`
/// the name the server's certificate must carry when it is not the URI's host.
fn endpoint(uri: &str, tls: Option<&ClientTls>, domain: Option<&str>) -> Result<Endpoint, AddressError> {
    let ep = Endpoint::from_shared(uri.to_string())
        .map_err(|e| AddressError(format!("{uri:?} is not a URI ({e}); write http://host:port or dns:///host:port")))?
        .connect_timeout(Duration::from_secs(5))
        .tcp_nodelay(true)
        // Pings find a vanished server (or a partition) within interval +
        // timeout, also between requests (docs/architecture.md, "Overload").
        .http2_keep_alive_interval(KEEPALIVE_INTERVAL)
        .keep_alive_timeout(KEEPALIVE_TIMEOUT)
        .keep_alive_while_idle(true)
        // RGB-D frames are megabytes: h2's default 64 KiB windows would cost a
        // round trip per 64 KiB of every frame.
        .initial_stream_window_size(STREAM_WINDOW)
        .initial_connection_window_size(CONNECTION_WINDOW);
    if !uri.starts_with("https://") {
        return Ok(ep);
    }
    let tls = tls.ok_or_else(|| {
        AddressError(format!(
            "{uri:?} is TLS but no CA to verify it against was given: pass --tls-ca (VLNAV_TLS_CA), or use http:// for a plaintext server"
        ))
    })?;
    ep.tls_config(tls.config(domain)).map_err(|e| AddressError(format!("{uri:?}: cannot set up TLS: {e}")))
}

/// A lazily connecting channel to `uri`: the service may start after its
/// callers, and reconnects are automatic.
///
/// - `http://host:port`: one HTTP/2 connection. Behind a Kubernetes
///   ClusterIP Service that is one replica per client: kube-proxy balances
///   connections, and gRPC keeps its connection.
/// - `dns:///host:port`: every address `host` resolves to, resolved again
///   every [`DNS_REFRESH`], each request sent to the less loaded of two
///   ready replicas picked at random (tower's power-of-two-choices
///   balancer). Pointed at a headless Service, new replicas take load within
///   one refresh and removed ones stop getting any. Needs a Tokio runtime.
pub fn channel(uri: &str) -> Result<TracedChannel, AddressError> {
    channel_with(uri, &ClientSecurity::none())
}

/// [`channel`] with TLS and a bearer token: `https://host:port` is verified
/// against `security.tls`, and `dns:///host:port` connects to each replica
/// with TLS (verified for `host`) whenever `security.tls` is given.
pub fn channel_with(uri: &str, security: &ClientSecurity) -> Result<TracedChannel, AddressError> {
    let tls = security.tls.as_ref();
    let ch = match uri.strip_prefix("dns:///") {
        Some(target) => {
            let (host, port) = host_port(target).ok_or_else(|| {
                AddressError(format!("{uri:?}: write dns:///host:port (a name or an address, and a port)"))
            })?;
            let name = format!("{host}:{port}");
            let scheme = if tls.is_some() { "https" } else { "http" };
            balanced_with(
                &format!("{scheme}://{name}"),
                move || tokio::net::lookup_host(name.clone()),
                DNS_REFRESH,
                tls,
                Some(host),
            )?
        }
        None => match (uri.strip_prefix("https://"), tls) {
            // TLS by a connector of ours (crate::tls): the client
            // certificate is read again from its files when they change.
            (Some(rest), Some(tls)) => {
                let connector =
                    tls.connector(None).map_err(|e| AddressError(format!("{uri:?}: cannot set up TLS: {e:#}")))?;
                endpoint(&format!("http://{rest}"), None, None)?.connect_with_connector_lazy(connector)
            }
            _ => endpoint(uri, tls, None)?.connect_lazy(),
        },
    };
    let interceptor = match &security.bearer {
        Some(token) => InjectTraceContext::with_bearer(token)?,
        None => InjectTraceContext::default(),
    };
    Ok(TracedChannel::new(ch, interceptor))
}

fn host_port(target: &str) -> Option<(&str, u16)> {
    let (host, port) = target.rsplit_once(':')?;
    let host = host.strip_prefix('[').and_then(|h| h.strip_suffix(']')).unwrap_or(host);
    if host.is_empty() || host.contains('/') {
        return None;
    }
    Some((host, port.parse().ok()?))
}

/// One member of a balanced channel.
#[derive(Clone, Debug, Hash, PartialEq, Eq)]
enum Member {
    /// A resolved replica.
    Replica(SocketAddr),
    /// The unresolved name, used while no replica is known: with an empty
    /// set the balancer would hold requests forever, with the name a request
    /// fails with UNAVAILABLE and the caller's own outage handling runs.
    Name,
}

/// A channel balanced over the addresses `resolve` returns, called now and
/// then every `refresh`. `fallback_uri` is what requests go to while it
/// returns none. The resolver task ends when the channel is dropped.
pub fn balanced<R, F, I>(fallback_uri: &str, resolve: R, refresh: Duration) -> Result<Channel, AddressError>
where
    R: FnMut() -> F + Send + 'static,
    F: Future<Output = std::io::Result<I>> + Send,
    I: Iterator<Item = SocketAddr>,
{
    balanced_with(fallback_uri, resolve, refresh, None, None)
}

/// [`balanced`] over TLS when `fallback_uri` is `https://`: every replica is
/// verified against `tls` as `domain`.
fn balanced_with<R, F, I>(
    fallback_uri: &str,
    mut resolve: R,
    refresh: Duration,
    tls: Option<&ClientTls>,
    domain: Option<&str>,
) -> Result<Channel, AddressError>
where
    R: FnMut() -> F + Send + 'static,
    F: Future<Output = std::io::Result<I>> + Send,
    I: Iterator<Item = SocketAddr>,
{
    let runtime = tokio::runtime::Handle::try_current().map_err(|_| {
        AddressError("a dns:/// address is resolved in the background and needs a Tokio runtime".into())
    })?;
    let fallback = endpoint(fallback_uri, tls, domain)?;
    let scheme = if fallback_uri.starts_with("https://") { "https" } else { "http" };
    let (tls, domain) = (tls.cloned(), domain.map(str::to_string));
    let (channel, changes) = Channel::balance_channel::<Member>(64);
    changes
        .try_send(Change::Insert(Member::Name, fallback.clone()))
        .map_err(|e| AddressError(format!("cannot start the balancer: {e}")))?;
    let label = fallback_uri.to_string();
    runtime.spawn(async move {
        let mut members: HashSet<Member> = HashSet::from([Member::Name]);
        let mut tick = tokio::time::interval(refresh);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            tick.tick().await;
            if changes.is_closed() {
                return;
            }
            let next: HashSet<Member> = match resolve().await {
                Ok(addrs) => addrs.map(Member::Replica).collect(),
                Err(e) => {
                    tracing::warn!(service = %label, "cannot resolve: {e}; keeping the {} known replicas", members.len());
                    continue;
                }
            };
            let next = if next.is_empty() { HashSet::from([Member::Name]) } else { next };
            for member in members.difference(&next) {
                tracing::info!(service = %label, ?member, "replica removed");
                if changes.send(Change::Remove(member.clone())).await.is_err() {
                    return;
                }
            }
            for member in next.difference(&members) {
                let ep = match member {
                    Member::Replica(addr) => match endpoint(&format!("{scheme}://{addr}"), tls.as_ref(), domain.as_deref()) {
                        Ok(ep) => ep,
                        Err(e) => {
                            tracing::warn!(service = %label, "{e}");
                            continue;
                        }
                    },
                    Member::Name => fallback.clone(),
                };
                tracing::info!(service = %label, ?member, "replica added");
                if changes.send(Change::Insert(member.clone(), ep)).await.is_err() {
                    return;
                }
            }
            members = next;
        }
    });
    Ok(channel)
}
