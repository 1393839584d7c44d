//! Client channels that carry the caller's trace context (W3C `traceparent`)
//! in gRPC metadata, so one mission is one trace across every hop.

use std::collections::HashSet;
use std::future::Future;
use std::net::SocketAddr;
use std::time::Duration;

use opentelemetry::propagation::Injector;
use tonic::service::Interceptor;
use tonic::service::interceptor::InterceptedService;
use tonic::transport::channel::Change;
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

/// How often a `dns:///` address is resolved again.
pub const DNS_REFRESH: Duration = Duration::from_secs(10);

/// A service address that cannot be used, with what to write instead.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct AddressError(String);

/// The endpoint settings every client connection uses.
fn endpoint(uri: &str) -> Result<Endpoint, AddressError> {
    Ok(Endpoint::from_shared(uri.to_string())
        .map_err(|e| AddressError(format!("{uri:?} is not a URI ({e}); write http://host:port or dns:///host:port")))?
        .connect_timeout(Duration::from_secs(5))
        .tcp_nodelay(true)
        .http2_keep_alive_interval(Duration::from_secs(30))
        // RGB-D frames are megabytes: h2's default 64 KiB windows would cost a
        // round trip per 64 KiB of every frame.
        .initial_stream_window_size(STREAM_WINDOW)
        .initial_connection_window_size(CONNECTION_WINDOW))
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
    let ch = match uri.strip_prefix("dns:///") {
        Some(target) => {
            let (host, port) = host_port(target).ok_or_else(|| {
                AddressError(format!("{uri:?}: write dns:///host:port (a name or an address, and a port)"))
            })?;
            let name = format!("{host}:{port}");
            balanced(&format!("http://{name}"), move || tokio::net::lookup_host(name.clone()), DNS_REFRESH)?
        }
        None => endpoint(uri)?.connect_lazy(),
    };
    Ok(InterceptedService::new(ch, InjectTraceContext))
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
pub fn balanced<R, F, I>(fallback_uri: &str, mut resolve: R, refresh: Duration) -> Result<Channel, AddressError>
where
    R: FnMut() -> F + Send + 'static,
    F: Future<Output = std::io::Result<I>> + Send,
    I: Iterator<Item = SocketAddr>,
{
    let runtime = tokio::runtime::Handle::try_current().map_err(|_| {
        AddressError("a dns:/// address is resolved in the background and needs a Tokio runtime".into())
    })?;
    let fallback = endpoint(fallback_uri)?;
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
                    Member::Replica(addr) => match endpoint(&format!("http://{addr}")) {
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
