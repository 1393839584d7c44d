//! Malformed and hostile bytes, sent as the request of every unary method of
//! every server (listed from the proto descriptor set, so a new method is
//! covered without touching this file), get a gRPC status: no panic, no
//! reset connection, and the server still answers its health check after.
//! Random bytes mostly fail to decode; those that do decode are arbitrary
//! messages (huge sizes, NaNs, unknown enums) that the services must refuse
//! or answer.

mod common;

use std::time::Duration;

use common::RawCodec;
use prost::Message;
use rand::SeedableRng;
use vlnav_e2e::TestStack;
use vlnav_fuzzgen::hostile_protobuf as hostile;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_unary_method_answers_malformed_requests_with_a_status() {
    let t = TestStack::start(|a| {
        a.insecure = true;
        a.no_robot = true;
    })
    .await;
    let fds = prost_types::FileDescriptorSet::decode(vlnav_proto::FILE_DESCRIPTOR_SET).expect("descriptor set");
    let p = t.stack.ports;
    let port_of = |service: &str| match service {
        "MissionService" | "FleetService" => Some(t.stack.gateway_addr.port()),
        "IngressService" => Some(p.ingress),
        "PlannerService" => Some(p.planner),
        "DetectorService" => Some(p.detector),
        "ReidService" => Some(p.reid),
        "SegmenterService" => Some(p.segmenter),
        "SubgoalService" => Some(p.subgoal),
        "LocalPlannerService" => Some(p.local_planner),
        _ => None,
    };
    let runs: usize = std::env::var("VLNAV_MALFORMED_RUNS").ok().and_then(|v| v.parse().ok()).unwrap_or(60);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let (mut methods, mut calls) = (0, 0);
    let mut codes = std::collections::BTreeMap::<String, usize>::new();
    for file in &fds.file {
        for service in &file.service {
            let name = service.name();
            let port = port_of(name).unwrap_or_else(|| panic!("no server known for {name}: add it to this test"));
            let channel = tonic::transport::Endpoint::from_shared(format!("http://127.0.0.1:{port}"))
                .unwrap()
                .connect()
                .await
                .expect("connect");
            for method in &service.method {
                if method.client_streaming() || method.server_streaming() {
                    continue;
                }
                methods += 1;
                let path = format!("/{}.{}/{}", file.package(), name, method.name());
                for i in 0..runs {
                    let payload = if i == 0 { Vec::new() } else { hostile(&mut rng) };
                    let mut grpc = tonic::client::Grpc::new(channel.clone());
                    grpc.ready().await.expect("the server is up");
                    let call = grpc.unary(
                        tonic::Request::new(payload.clone()),
                        http::uri::PathAndQuery::try_from(path.as_str()).unwrap(),
                        RawCodec,
                    );
                    let result = tokio::time::timeout(Duration::from_secs(30), call)
                        .await
                        .unwrap_or_else(|_| panic!("{path} hung on {payload:02x?}"));
                    calls += 1;
                    *codes
                        .entry(result.as_ref().map_or_else(|s| format!("{:?}", s.code()), |_| "Ok".into()))
                        .or_default() += 1;
                    if let Err(status) = result {
                        assert!(
                            !common::is_crash(status.code()),
                            "{path} failed on {payload:02x?} with {status:?}: a panic or a dropped connection"
                        );
                        assert!(!status.message().is_empty(), "{path}: a status says why: {status:?}");
                    }
                }
                let mut health = tonic_health::pb::health_client::HealthClient::new(channel.clone());
                let served = health
                    .check(tonic_health::pb::HealthCheckRequest { service: String::new() })
                    .await
                    .unwrap_or_else(|e| panic!("{name} stopped answering after {path}: {e}"));
                assert_eq!(
                    served.into_inner().status(),
                    tonic_health::pb::health_check_response::ServingStatus::Serving
                );
            }
        }
    }
    assert!(methods >= 15, "every unary method of every server: {methods}");
    eprintln!("{calls} malformed requests over {methods} unary methods, each answered with a status: {codes:?}");
}
