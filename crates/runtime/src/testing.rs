//! Integration-test support: a [`ServiceSet`] served on an ephemeral loopback
//! port by the real [`serve`] (health, reflection, limits, telemetry layer,
//! graceful shutdown), and channels to it for the generated tonic clients.
//!
//! ```text
//! let cfg = ServerConfig::default();
//! let set = vlnav_subgoal::services(&opts, &cfg).await?;
//! let mut s = vlnav_runtime::testing::start_client(&cfg, set, SubgoalServiceClient::new).await?;
//! s.client.move_goal(…).await?;
//! s.stop().await?; // or just drop it: dropping cancels without waiting
//! ```
//!
//! [`start`] alone gives the [`TestServer`], for tests that make their own
//! channels ([`TestServer::connect`], [`TestServer::traced_channel`]).

use std::net::SocketAddr;

use tokio::net::TcpListener;
use tokio::task::JoinHandle;
use tokio_util::sync::CancellationToken;
use tonic::transport::{Channel, Endpoint};

use crate::client::TracedChannel;
use crate::server::{ServerConfig, ServiceSet, serve};

/// A server running on `127.0.0.1:<ephemeral port>`. Dropping it begins the
/// graceful shutdown without waiting for it; [`TestServer::stop`] waits and
/// reports how serving ended.
pub struct TestServer {
    addr: SocketAddr,
    shutdown: CancellationToken,
    task: Option<JoinHandle<anyhow::Result<()>>>,
}

/// Binds `127.0.0.1:0` and serves `services` with `cfg` on a spawned task.
/// Needs a Tokio runtime; the server accepts connections once this returns.
pub async fn start(cfg: &ServerConfig, services: ServiceSet) -> anyhow::Result<TestServer> {
    let listener = TcpListener::bind("127.0.0.1:0").await?;
    let addr = listener.local_addr()?;
    let shutdown = CancellationToken::new();
    let token = shutdown.clone();
    let cfg = cfg.clone();
    let task = tokio::spawn(async move { serve(&cfg, listener, services, token).await });
    Ok(TestServer { addr, shutdown, task: Some(task) })
}

/// A running server and a client connected to it. Dropping it shuts the
/// server down without waiting, like dropping the [`TestServer`].
pub struct Connected<C> {
    pub client: C,
    pub server: TestServer,
}

impl<C> Connected<C> {
    /// Shuts the server down and waits: see [`TestServer::stop`].
    pub async fn stop(self) -> anyhow::Result<()> {
        self.server.stop().await
    }
}

/// [`start`], then a client made by `make` from a connected plain channel
/// (a generated client's `new`, or a closure that also sets its limits).
pub async fn start_client<C>(
    cfg: &ServerConfig,
    services: ServiceSet,
    make: impl FnOnce(Channel) -> C,
) -> anyhow::Result<Connected<C>> {
    let server = start(cfg, services).await?;
    let client = make(server.connect().await?);
    Ok(Connected { client, server })
}

impl TestServer {
    /// The bound address.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// `http://127.0.0.1:<port>`.
    pub fn uri(&self) -> String {
        format!("http://{}", self.addr)
    }

    /// A connected plain channel (what a generated client's `connect` makes).
    pub async fn connect(&self) -> Result<Channel, tonic::transport::Error> {
        Endpoint::from_shared(self.uri())?.connect().await
    }

    /// A lazily connecting channel that carries the caller's trace context,
    /// as the services' own clients use ([`crate::client::channel`]).
    pub fn traced_channel(&self) -> Result<TracedChannel, crate::client::AddressError> {
        crate::client::channel(&self.uri())
    }

    /// The token whose cancellation shuts the server down.
    pub fn shutdown_token(&self) -> CancellationToken {
        self.shutdown.clone()
    }

    /// Shuts down, drains in-flight requests and returns what [`serve`] returned.
    pub async fn stop(mut self) -> anyhow::Result<()> {
        self.shutdown.cancel();
        match self.task.take() {
            Some(task) => task.await?,
            None => Ok(()),
        }
    }
}

impl Drop for TestServer {
    fn drop(&mut self) {
        self.shutdown.cancel();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tonic_health::pb::HealthCheckRequest;
    use tonic_health::pb::health_check_response::ServingStatus;
    use tonic_health::pb::health_client::HealthClient;

    #[tokio::test]
    async fn serves_on_a_loopback_port_until_stopped() {
        let server = start(&ServerConfig::default(), ServiceSet::new()).await.unwrap();
        assert!(server.addr().ip().is_loopback() && server.addr().port() != 0);
        assert_eq!(server.uri(), format!("http://127.0.0.1:{}", server.addr().port()));
        let whole = || HealthCheckRequest { service: String::new() };
        let mut plain = HealthClient::new(server.connect().await.unwrap());
        assert_eq!(plain.check(whole()).await.unwrap().into_inner().status(), ServingStatus::Serving);
        let mut traced = HealthClient::new(server.traced_channel().unwrap());
        assert_eq!(traced.check(whole()).await.unwrap().into_inner().status(), ServingStatus::Serving);
        let addr = server.addr();
        drop((plain, traced));
        server.stop().await.unwrap();
        assert!(tokio::net::TcpStream::connect(addr).await.is_err(), "the port is closed after stop");
    }

    #[tokio::test]
    async fn a_started_client_talks_to_its_server_until_stopped() {
        let mut s = start_client(&ServerConfig::default(), ServiceSet::new(), HealthClient::new).await.unwrap();
        let r = s.client.check(HealthCheckRequest { service: String::new() }).await.unwrap().into_inner();
        assert_eq!(r.status(), ServingStatus::Serving);
        let addr = s.server.addr();
        s.stop().await.unwrap();
        assert!(tokio::net::TcpStream::connect(addr).await.is_err(), "the port is closed after stop");
    }

    /// A service whose one method, `/vlnav.test.Slow/Wait`, answers after 500 ms.
    #[derive(Clone)]
    struct Slow;

    impl tonic::server::NamedService for Slow {
        const NAME: &'static str = "vlnav.test.Slow";
    }

    impl tower::Service<http::Request<tonic::body::Body>> for Slow {
        type Response = http::Response<tonic::body::Body>;
        type Error = std::convert::Infallible;
        type Future = futures::future::BoxFuture<'static, Result<Self::Response, Self::Error>>;

        fn poll_ready(&mut self, _: &mut std::task::Context<'_>) -> std::task::Poll<Result<(), Self::Error>> {
            std::task::Poll::Ready(Ok(()))
        }

        fn call(&mut self, req: http::Request<tonic::body::Body>) -> Self::Future {
            struct Wait;
            impl tonic::server::UnaryService<()> for Wait {
                type Response = ();
                type Future = futures::future::BoxFuture<'static, Result<tonic::Response<()>, tonic::Status>>;
                fn call(&mut self, _: tonic::Request<()>) -> Self::Future {
                    Box::pin(async {
                        tokio::time::sleep(std::time::Duration::from_millis(500)).await;
                        Ok(tonic::Response::new(()))
                    })
                }
            }
            Box::pin(async move {
                let mut grpc = tonic::server::Grpc::new(tonic_prost::ProstCodec::<(), ()>::default());
                Ok(grpc.unary(Wait, req).await)
            })
        }
    }

    async fn wait(channel: Channel) -> Result<(), tonic::Status> {
        let mut grpc = tonic::client::Grpc::new(channel);
        grpc.ready().await.map_err(|e| tonic::Status::unknown(e.to_string()))?;
        let path = http::uri::PathAndQuery::from_static("/vlnav.test.Slow/Wait");
        grpc.unary(tonic::Request::new(()), path, tonic_prost::ProstCodec::<(), ()>::default()).await.map(|_| ())
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_connection_past_its_request_limit_is_refused_at_once_not_queued() {
        let cfg = ServerConfig { max_concurrent_requests: 2, ..ServerConfig::default() };
        let server = start(&cfg, ServiceSet::new().add("slow", Slow)).await.unwrap();
        let channel = server.connect().await.unwrap();
        // Two slow calls hold the connection's two places for 500 ms.
        let held: Vec<_> = (0..2).map(|_| tokio::spawn(wait(channel.clone()))).collect();
        tokio::time::sleep(std::time::Duration::from_millis(150)).await;
        let refused = tokio::time::timeout(std::time::Duration::from_millis(400), wait(channel.clone()))
            .await
            .expect("a refusal at once, not a wait behind the slow calls")
            .unwrap_err();
        assert_eq!(refused.code(), tonic::Code::ResourceExhausted, "{refused:?}");
        // Another connection has its own places.
        let other = tokio::time::timeout(std::time::Duration::from_millis(400), async {
            let mut health = HealthClient::new(server.connect().await.unwrap());
            health.check(HealthCheckRequest { service: String::new() }).await
        });
        assert!(other.await.expect("served at once").is_ok());
        for h in held {
            h.await.unwrap().expect("the calls that held places are served");
        }
        wait(channel).await.expect("freed places serve again");
    }

    #[tokio::test]
    async fn dropping_the_server_shuts_it_down() {
        let server = start(&ServerConfig::default(), ServiceSet::new()).await.unwrap();
        let token = server.shutdown_token();
        assert!(!token.is_cancelled());
        drop(server);
        assert!(token.is_cancelled());
    }
}

/// A detector stage that detects nothing and names its model "stub": the
/// smallest real gRPC service for tests of the server's layers (caller
/// identity, revocation), which look only at who calls.
#[derive(Clone)]
pub struct StubDetector;

#[tonic::async_trait]
impl vlnav_proto::v1::detector_service_server::DetectorService for StubDetector {
    async fn detect(
        &self,
        _: tonic::Request<vlnav_proto::v1::DetectRequest>,
    ) -> Result<tonic::Response<vlnav_proto::v1::DetectResponse>, tonic::Status> {
        Err(tonic::Status::invalid_argument("the stub detects nothing"))
    }
    async fn get_model_info(
        &self,
        _: tonic::Request<vlnav_proto::v1::GetModelInfoRequest>,
    ) -> Result<tonic::Response<vlnav_proto::v1::ModelInfo>, tonic::Status> {
        Ok(tonic::Response::new(vlnav_proto::v1::ModelInfo { model: "stub".into(), ..Default::default() }))
    }
}
