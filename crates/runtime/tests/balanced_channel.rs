//! Client-side load balancing (`dns:///` addresses): requests spread over the
//! replicas a resolver returns, go to the less busy of two, follow the
//! resolver when replicas come and go, fail with UNAVAILABLE (never hang)
//! when there are none, and reach replicas over mutual TLS.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use tonic::{Request, Response, Status};
use vlnav_proto::v1::detector_service_client::DetectorServiceClient;
use vlnav_proto::v1::detector_service_server::{DetectorService, DetectorServiceServer};
use vlnav_proto::v1::{DetectRequest, DetectResponse, GetModelInfoRequest, ModelInfo};
use vlnav_runtime::client::{TracedChannel, balanced, channel, channel_with};
use vlnav_runtime::server::{ServerConfig, ServiceSet};
use vlnav_runtime::testing::{TestServer, start};

/// A replica that answers GetModelInfo with its own name, after a delay.
#[derive(Clone)]
struct Replica(&'static str, Duration);

#[tonic::async_trait]
impl DetectorService for Replica {
    async fn detect(&self, _: Request<DetectRequest>) -> Result<Response<DetectResponse>, Status> {
        Err(Status::unimplemented("not used here"))
    }
    async fn get_model_info(&self, _: Request<GetModelInfoRequest>) -> Result<Response<ModelInfo>, Status> {
        tokio::time::sleep(self.1).await;
        Ok(Response::new(ModelInfo { model: self.0.into(), ..Default::default() }))
    }
}

async fn replica(name: &'static str) -> TestServer {
    slow_replica(name, Duration::ZERO).await
}

async fn slow_replica(name: &'static str, delay: Duration) -> TestServer {
    start(&ServerConfig::default(), ServiceSet::new().add("detect", DetectorServiceServer::new(Replica(name, delay))))
        .await
        .expect("replica starts")
}

/// A resolver that always returns `addrs`.
fn fixed(
    addrs: Vec<SocketAddr>,
) -> impl FnMut() -> std::future::Ready<std::io::Result<std::vec::IntoIter<SocketAddr>>> {
    move || std::future::ready(Ok(addrs.clone().into_iter()))
}

/// Who answered `n` calls.
async fn answers(client: &mut DetectorServiceClient<TracedChannel>, n: usize) -> HashMap<String, usize> {
    let mut seen = HashMap::new();
    for _ in 0..n {
        let info = client.get_model_info(GetModelInfoRequest {}).await.expect("a replica answers").into_inner();
        *seen.entry(info.model).or_insert(0) += 1;
    }
    seen
}

const REFRESH: Duration = Duration::from_millis(50);

#[tokio::test]
async fn requests_spread_over_the_resolved_replicas_and_follow_changes() {
    let (a, b) = (replica("a").await, replica("b").await);
    let resolved: Arc<Mutex<Vec<SocketAddr>>> = Arc::new(Mutex::new(vec![a.addr(), b.addr()]));
    let r = resolved.clone();
    let resolve = move || {
        let addrs = r.lock().unwrap().clone();
        async move { Ok::<_, std::io::Error>(addrs.into_iter()) }
    };
    // Nothing listens at the fallback: while replicas are known it gets no requests.
    let dead = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap().local_addr().unwrap();
    let ch = balanced(&format!("http://{dead}"), resolve, REFRESH).expect("a balanced channel");
    let mut client = DetectorServiceClient::new(ch);
    tokio::time::sleep(4 * REFRESH).await;

    let seen = answers(&mut client, 60).await;
    assert_eq!(seen.values().sum::<usize>(), 60, "{seen:?}");
    assert!(
        seen.get("a").copied().unwrap_or(0) >= 10 && seen.get("b").copied().unwrap_or(0) >= 10,
        "both replicas take load: {seen:?}"
    );

    // A third replica appears: it takes load after a refresh.
    let c = replica("c").await;
    resolved.lock().unwrap().push(c.addr());
    tokio::time::sleep(4 * REFRESH).await;
    let seen = answers(&mut client, 90).await;
    assert!(seen.get("c").copied().unwrap_or(0) >= 10, "the new replica takes load: {seen:?}");

    // Replica a is scaled away: removed from DNS first, then stopped. No request fails.
    resolved.lock().unwrap().retain(|addr| *addr != a.addr());
    tokio::time::sleep(4 * REFRESH).await;
    a.stop().await.unwrap();
    let seen = answers(&mut client, 40).await;
    assert!(!seen.contains_key("a"), "{seen:?}");
    assert_eq!(seen.values().sum::<usize>(), 40);
    drop((b, c));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_call_goes_to_the_replica_with_fewer_calls_in_flight() {
    let slow = slow_replica("slow", Duration::from_secs(2)).await;
    let fast = replica("fast").await;
    let dead = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap().local_addr().unwrap();
    let ch = balanced(&format!("http://{dead}"), fixed(vec![slow.addr(), fast.addr()]), REFRESH).unwrap();
    tokio::time::sleep(4 * REFRESH).await;
    // Two calls at once: the second goes to the replica the first left idle,
    // so one of them holds the slow replica for 2 s.
    let held: Vec<_> = (0..2)
        .map(|_| {
            let mut client = DetectorServiceClient::new(ch.clone());
            tokio::spawn(async move { answers(&mut client, 1).await })
        })
        .collect();
    tokio::time::sleep(Duration::from_millis(300)).await;
    // Meanwhile every call finds the fast replica with none in flight and
    // the slow one busy. Picked at random, half would wait out the 2 s.
    let seen = answers(&mut DetectorServiceClient::new(ch.clone()), 20).await;
    assert_eq!(seen.get("fast"), Some(&20), "calls go to the idle replica: {seen:?}");
    let mut first: HashMap<String, usize> = HashMap::new();
    for h in held {
        for (k, v) in h.await.unwrap() {
            *first.entry(k).or_insert(0) += v;
        }
    }
    assert_eq!(first, HashMap::from([("slow".to_string(), 1), ("fast".to_string(), 1)]), "the two first calls");
}

#[tokio::test]
async fn a_dns_address_over_mutual_tls_verifies_each_replica_for_the_name() {
    let dir = tempfile::tempdir().unwrap();
    let pki = vlnav_runtime::security::DevPki::ensure(dir.path(), &[]).unwrap();
    let cfg = ServerConfig { tls: pki.server_args(), ..Default::default() };
    let set = ServiceSet::new()
        .add("detect", DetectorServiceServer::new(Replica("tls", Duration::ZERO)))
        .callers(vlnav_runtime::CallerPolicy::stages());
    let server = start(&cfg, set).await.unwrap();
    let ca = std::fs::read(pki.ca()).unwrap();
    let gateway = vlnav_runtime::security::ClientTls::from_files(ca, &pki.gateway_cert(), &pki.gateway_key()).unwrap();
    let security = |tls| vlnav_runtime::security::ClientSecurity::new(Some(tls), None);
    let uri = format!("dns:///127.0.0.1:{}", server.addr().port());
    let mut client = DetectorServiceClient::new(channel_with(&uri, &security(gateway)).unwrap());
    tokio::time::sleep(4 * REFRESH).await;
    let info = client.get_model_info(GetModelInfoRequest {}).await.expect("served over TLS").into_inner();
    assert_eq!(info.model, "tls");

    // A client that trusts another CA does not accept the replica's
    // certificate: the call fails UNAVAILABLE, it does not hang.
    let other_dir = tempfile::tempdir().unwrap();
    let other = vlnav_runtime::security::DevPki::ensure(other_dir.path(), &[]).unwrap();
    let stranger = vlnav_runtime::security::ClientTls::from_files(
        std::fs::read(other.ca()).unwrap(),
        &other.gateway_cert(),
        &other.gateway_key(),
    )
    .unwrap();
    let mut client = DetectorServiceClient::new(channel_with(&uri, &security(stranger)).unwrap());
    let status = tokio::time::timeout(Duration::from_secs(30), client.get_model_info(GetModelInfoRequest {}))
        .await
        .expect("the call returns")
        .expect_err("the replica's certificate is not trusted");
    assert_eq!(status.code(), tonic::Code::Unavailable, "{status:?}");
}

#[tokio::test]
async fn with_no_replica_a_request_fails_unavailable_instead_of_waiting() {
    let dead = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap().local_addr().unwrap();
    let resolve = || async { Ok::<_, std::io::Error>(Vec::<SocketAddr>::new().into_iter()) };
    let ch = balanced(&format!("http://{dead}"), resolve, REFRESH).expect("a balanced channel");
    let mut client = DetectorServiceClient::new(ch);
    // The guard only turns a hang into a failure; a refused connection returns at once.
    let status = tokio::time::timeout(Duration::from_secs(30), client.get_model_info(GetModelInfoRequest {}))
        .await
        .expect("the call returns")
        .expect_err("nothing serves");
    assert_eq!(status.code(), tonic::Code::Unavailable, "{status:?}");

    // A replica comes up: the next calls reach it.
    let a = replica("a").await;
    let addr = a.addr();
    let resolve = move || async move { Ok::<_, std::io::Error>(vec![addr].into_iter()) };
    let mut client = DetectorServiceClient::new(balanced(&format!("http://{dead}"), resolve, REFRESH).unwrap());
    tokio::time::sleep(4 * REFRESH).await;
    assert_eq!(answers(&mut client, 5).await.get("a"), Some(&5));
}

#[tokio::test]
async fn a_dns_address_resolves_a_name_and_bad_addresses_say_what_to_write() {
    let a = replica("a").await;
    // A literal address resolves to itself: the whole dns:/// path end to end.
    let mut client = DetectorServiceClient::new(channel(&format!("dns:///127.0.0.1:{}", a.addr().port())).unwrap());
    tokio::time::sleep(4 * REFRESH).await;
    let info = client.get_model_info(GetModelInfoRequest {}).await.expect("served").into_inner();
    assert_eq!(info.model, "a");

    for bad in ["dns:///detector", "dns:///detector:port", "dns:///:50053", "not a uri"] {
        let e = channel(bad).expect_err(bad).to_string();
        assert!(e.contains("host:port"), "{bad}: {e}");
    }
}

#[test]
fn a_dns_address_outside_a_runtime_is_an_error_not_a_panic() {
    let e = channel("dns:///detector:50053").expect_err("no runtime").to_string();
    assert!(e.contains("Tokio runtime"), "{e}");
}
