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
use tonic::transport::{Channel, Endpoint};
use tower::balance::p2c::Balance;
use tower::buffer::Buffer;
use tower::discover::Change;
use tower::load::{CompleteOnResponse, PendingRequests};
use tower::util::BoxService;
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

/// The error a call through a [`TracedChannel`] fails with before it has a
/// gRPC status (tonic turns it into UNAVAILABLE, UNKNOWN, …).
pub type BoxError = Box<dyn std::error::Error + Send + Sync>;

type BoxFuture<T> = Pin<Box<dyn Future<Output = T> + Send>>;

/// Requests spread over the replicas of a `dns:///` address ([`balanced`]).
type BalancedChannel = Buffer<http::Request<Body>, BoxFuture<Result<http::Response<Body>, BoxError>>>;

/// Where a [`TracedChannel`]'s calls go.
#[derive(Clone)]
enum Route {
    /// One address: one HTTP/2 connection, reconnected when it drops.
    One(Channel),
    /// The replicas behind a name, each call to the less loaded of two
    /// picked at random ([`Replica`]).
    Balanced(BalancedChannel),
}

impl std::fmt::Debug for Route {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Route::One(c) => f.debug_tuple("One").field(c).finish(),
            Route::Balanced(_) => f.write_str("Balanced"),
        }
    }
}

/// A channel whose every call is a client span (`call <Method>`, kind
/// client) and carries that span's trace context, so the server's span is
/// its child.
#[derive(Clone, Debug)]
pub struct TracedChannel {
    route: Route,
    inject: InjectTraceContext,
}

impl TracedChannel {
    pub fn new(inner: Channel, inject: InjectTraceContext) -> Self {
        Self { route: Route::One(inner), inject }
    }
}

impl tower::Service<http::Request<Body>> for TracedChannel {
    type Response = http::Response<Body>;
    type Error = BoxError;
    type Future = BoxFuture<Result<Self::Response, Self::Error>>;

    fn poll_ready(&mut self, cx: &mut Context<'_>) -> Poll<Result<(), Self::Error>> {
        match &mut self.route {
            Route::One(c) => c.poll_ready(cx).map_err(Into::into),
            Route::Balanced(b) => b.poll_ready(cx),
        }
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
        match &mut self.route {
            Route::One(c) => {
                let mut ready = take_ready(c);
                Box::pin(async move { ready.call(req).await.map_err(Into::into) }.instrument(span))
            }
            Route::Balanced(b) => {
                let mut ready = take_ready(b);
                Box::pin(async move { ready.call(req).await }.instrument(span))
            }
        }
    }
}

/// The service that was polled ready, leaving a fresh clone in its place.
fn take_ready<S: Clone>(svc: &mut S) -> S {
    let clone = svc.clone();
    std::mem::replace(svc, clone)
}

/// How often a `dns:///` address is resolved again.
pub const DNS_REFRESH: Duration = Duration::from_secs(10);

/// A service address that cannot be used, with what to write instead.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct AddressError(String);

/// The endpoint settings every client connection uses (TLS, when wanted,
/// is a connector's: [`Connect`]).
fn endpoint(uri: &str) -> Result<Endpoint, AddressError> {
    Endpoint::from_shared(uri.to_string())
        .map_err(|e| AddressError(format!("{uri:?} is not a URI ({e}); write http://host:port or dns:///host:port")))
        .map(|ep| {
            ep.connect_timeout(Duration::from_secs(5))
                .tcp_nodelay(true)
                // Pings find a vanished server (or a partition) within interval +
                // timeout, also between requests (docs/architecture.md, "Overload").
                .http2_keep_alive_interval(KEEPALIVE_INTERVAL)
                .keep_alive_timeout(KEEPALIVE_TIMEOUT)
                .keep_alive_while_idle(true)
                // RGB-D frames are megabytes: h2's default 64 KiB windows would cost a
                // round trip per 64 KiB of every frame.
                .initial_stream_window_size(STREAM_WINDOW)
                .initial_connection_window_size(CONNECTION_WINDOW)
        })
}

/// A lazily connecting channel to `uri`: the service may start after its
/// callers, and reconnects are automatic.
///
/// - `http://host:port`: one HTTP/2 connection. Behind a Kubernetes
///   ClusterIP Service that is one replica per client: kube-proxy balances
///   connections, and gRPC keeps its connection.
/// - `dns:///host:port`: every address `host` resolves to, resolved again
///   every [`DNS_REFRESH`], each request sent to the less loaded of two
///   ready replicas picked at random (tower's power-of-two-choices balancer,
///   load being calls in flight: [`Replica`]). Pointed at a headless Service, new
///   replicas take load within one refresh and removed ones stop getting
///   any. Needs a Tokio runtime.
pub fn channel(uri: &str) -> Result<TracedChannel, AddressError> {
    channel_with(uri, &ClientSecurity::none())
}

/// [`channel`] with TLS and a bearer token: `https://host:port` is verified
/// against `security.tls`, and `dns:///host:port` connects to each replica
/// with TLS (verified for `host`) whenever `security.tls` is given. Either
/// way TLS is the connector of [`crate::tls`]: a client certificate is read
/// again from its files before each new connection when they changed.
pub fn channel_with(uri: &str, security: &ClientSecurity) -> Result<TracedChannel, AddressError> {
    let tls = security.tls.as_ref();
    let route = match uri.strip_prefix("dns:///") {
        Some(target) => {
            let (host, port) = host_port(target).ok_or_else(|| {
                AddressError(format!("{uri:?}: write dns:///host:port (a name or an address, and a port)"))
            })?;
            let name = authority(host, port);
            let fallback = name.clone();
            let connect = Connect::new(uri, tls, Some(host))?;
            let resolve = move || tokio::net::lookup_host(name.clone());
            Route::Balanced(balanced_with(&fallback, resolve, DNS_REFRESH, connect)?)
        }
        None => match uri.strip_prefix("https://") {
            Some(rest) => Route::One(Connect::new(uri, tls, None)?.lazy(rest)?),
            None => Route::One(endpoint(uri)?.connect_lazy()),
        },
    };
    let inject = match &security.bearer {
        Some(token) => InjectTraceContext::with_bearer(token)?,
        None => InjectTraceContext::default(),
    };
    Ok(TracedChannel { route, inject })
}

/// How a channel reaches one address: plain TCP, or TLS by the connector of
/// [`crate::tls`].
#[derive(Clone)]
struct Connect(Option<crate::tls::ClientConnector>);

impl Connect {
    /// TLS when `tls` is given (`domain`: the name the server's certificate
    /// must carry when it is not the address's host); an `https://` `uri`
    /// without it is an error that says what to pass.
    fn new(uri: &str, tls: Option<&ClientTls>, domain: Option<&str>) -> Result<Self, AddressError> {
        match tls {
            Some(tls) => tls
                .connector(domain)
                .map(|c| Self(Some(c)))
                .map_err(|e| AddressError(format!("{uri:?}: cannot set up TLS: {e:#}"))),
            None if uri.starts_with("https://") => Err(AddressError(format!(
                "{uri:?} is TLS but no CA to verify it against was given: pass --tls-ca (VLNAV_TLS_CA), or use http:// for a plaintext server"
            ))),
            None => Ok(Self(None)),
        }
    }

    /// A lazily connecting channel to `authority` (`host:port`).
    fn lazy(&self, authority: &str) -> Result<Channel, AddressError> {
        let ep = endpoint(&format!("http://{authority}"))?;
        Ok(match &self.0 {
            Some(connector) => ep.connect_with_connector_lazy(connector.clone()),
            None => ep.connect_lazy(),
        })
    }
}

/// `host:port`, an IPv6 address in brackets (what a resolver and a URI take).
fn authority(host: &str, port: u16) -> String {
    if host.contains(':') { format!("[{host}]:{port}") } else { format!("{host}:{port}") }
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
/// then every `refresh`, in plaintext. `fallback_uri` (`http://host:port`)
/// is what requests go to while it returns none. The resolver task ends when
/// the channel and its clones are dropped.
pub fn balanced<R, F, I>(fallback_uri: &str, resolve: R, refresh: Duration) -> Result<TracedChannel, AddressError>
where
    R: FnMut() -> F + Send + 'static,
    F: Future<Output = std::io::Result<I>> + Send,
    I: Iterator<Item = SocketAddr>,
{
    let authority = fallback_uri
        .strip_prefix("http://")
        .ok_or_else(|| AddressError(format!("{fallback_uri:?}: write http://host:port")))?;
    let route = Route::Balanced(balanced_with(authority, resolve, refresh, Connect(None))?);
    Ok(TracedChannel { route, inject: InjectTraceContext::default() })
}

/// A replica of a balanced channel, weighed by its calls in flight: of two
/// replicas the one still busy with more calls gets the next one, so a slow
/// or overloaded replica gets fewer calls than an idle one, and equal ones
/// share evenly. (Weighing by round-trip time as well, tower's `PeakEwma`,
/// leaves a replica whose first call paid for the connection without calls
/// for tens of seconds.)
type Replica = PendingRequests<Channel>;

/// [`balanced`], each replica reached by `connect`; `fallback` is the
/// `host:port` requests go to while no replica is known.
fn balanced_with<R, F, I>(
    fallback: &str,
    mut resolve: R,
    refresh: Duration,
    connect: Connect,
) -> Result<BalancedChannel, AddressError>
where
    R: FnMut() -> F + Send + 'static,
    F: Future<Output = std::io::Result<I>> + Send,
    I: Iterator<Item = SocketAddr>,
{
    let runtime = tokio::runtime::Handle::try_current().map_err(|_| {
        AddressError("a dns:/// address is resolved in the background and needs a Tokio runtime".into())
    })?;
    let weigh = |c: Channel| PendingRequests::new(c, CompleteOnResponse::default());
    let fallback_channel = connect.lazy(fallback)?;
    let (changes, discovered) =
        tokio::sync::mpsc::channel::<Result<Change<Member, Replica>, std::convert::Infallible>>(64);
    changes
        .try_send(Ok(Change::Insert(Member::Name, weigh(fallback_channel.clone()))))
        .map_err(|e| AddressError(format!("cannot start the balancer: {e}")))?;
    let balance = Balance::new(tokio_stream::wrappers::ReceiverStream::new(discovered));
    let (channel, worker) = Buffer::pair(BoxService::new(balance), 1024);
    runtime.spawn(worker);
    let label = fallback.to_string();
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
                if changes.send(Ok(Change::Remove(member.clone()))).await.is_err() {
                    return;
                }
            }
            for member in next.difference(&members) {
                let svc = match member {
                    Member::Replica(addr) => match connect.lazy(&addr.to_string()) {
                        Ok(c) => weigh(c),
                        Err(e) => {
                            tracing::warn!(service = %label, "{e}");
                            continue;
                        }
                    },
                    Member::Name => weigh(fallback_channel.clone()),
                };
                tracing::info!(service = %label, ?member, "replica added");
                if changes.send(Ok(Change::Insert(member.clone(), svc))).await.is_err() {
                    return;
                }
            }
            members = next;
        }
    });
    Ok(channel)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn a_dns_target_splits_into_an_authority_the_resolver_takes() {
        for (target, want) in [
            ("detector-replicas:50054", "detector-replicas:50054"),
            ("10.0.0.7:50054", "10.0.0.7:50054"),
            ("[::1]:50054", "[::1]:50054"),
        ] {
            let (host, port) = host_port(target).unwrap();
            let name = authority(host, port);
            assert_eq!(name, want);
            // An address literal resolves without DNS.
            if host.parse::<std::net::IpAddr>().is_ok() {
                let addrs: Vec<SocketAddr> = tokio::net::lookup_host(&name).await.unwrap().collect();
                assert_eq!(addrs, [name.parse::<SocketAddr>().unwrap()], "{target}");
            }
        }
        assert_eq!(host_port("[::1]"), None);
    }
}
