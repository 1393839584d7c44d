//! Client-side load balancing (`dns:///` addresses): requests spread over the
//! replicas a resolver returns, follow it when replicas come and go, and fail
//! with UNAVAILABLE (never hang) when there are none.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use tonic::{Request, Response, Status};
use vlnav_proto::v1::detector_service_client::DetectorServiceClient;
use vlnav_proto::v1::detector_service_server::{DetectorService, DetectorServiceServer};
use vlnav_proto::v1::{DetectRequest, DetectResponse, GetModelInfoRequest, ModelInfo};
use vlnav_runtime::client::{balanced, channel};
use vlnav_runtime::server::{ServerConfig, ServiceSet};
use vlnav_runtime::testing::{TestServer, start};

/// A replica that answers GetModelInfo with its own name.
#[derive(Clone)]
struct Replica(&'static str);

#[tonic::async_trait]
impl DetectorService for Replica {
    async fn detect(&self, _: Request<DetectRequest>) -> Result<Response<DetectResponse>, Status> {
        Err(Status::unimplemented("not used here"))
    }
    async fn get_model_info(&self, _: Request<GetModelInfoRequest>) -> Result<Response<ModelInfo>, Status> {
        Ok(Response::new(ModelInfo { model: self.0.into(), ..Default::default() }))
    }
}

async fn replica(name: &'static str) -> TestServer {
    start(&ServerConfig::default(), ServiceSet::new().add("detect", DetectorServiceServer::new(Replica(name))))
        .await
        .expect("replica starts")
}

/// Who answered `n` calls.
async fn answers(client: &mut DetectorServiceClient<tonic::transport::Channel>, n: usize) -> HashMap<String, usize> {
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
