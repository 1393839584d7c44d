//! Malformed and hostile messages on every streaming method of every server
//! (listed from the proto descriptor set: FleetService.Attach, bidi;
//! IngressService.Transcribe, client streaming; MissionService.WatchMission,
//! server streaming; and any added later): each call ends with a status or
//! a clean end of stream, within a time limit, never a panic or a dropped
//! connection, and the server still answers its health check after.
//! Messages are hostile protobuf, valid messages of the method's type
//! mutated at the byte level, and valid ones, in streams of one to six.
//! The unary methods: `malformed.rs`.
//!
//! `VLNAV_MALFORMED_RUNS` sets the calls per method (default 24).

mod common;

use std::time::Duration;

use common::RawCodec;
use prost::Message;
use rand::Rng as _;
use vlnav_e2e::TestStack;
use vlnav_fuzzgen::{self as fuzz, Rng, frames};
use vlnav_proto::v1 as pb;

/// Valid messages of `input_type` to mutate (none: hostile bytes only).
fn samples(input_type: &str, rng: &mut Rng, call: usize) -> Vec<Vec<u8>> {
    let robot_id = format!("fuzz-{call}");
    match input_type {
        "vlnav.v1.EdgeMessage" => {
            let hello = pb::EdgeMessage {
                kind: Some(pb::edge_message::Kind::Hello(pb::EdgeHello {
                    robot_id: robot_id.clone(),
                    driver: "fuzz".into(),
                    camera: frames::small_valid_frame(rng).camera,
                    ..Default::default()
                })),
            };
            let frame = |rng: &mut Rng| {
                let mut f =
                    if rng.random_bool(0.5) { frames::small_valid_frame(rng) } else { frames::corrupt_frame(rng) };
                f.robot_id = robot_id.clone();
                pb::EdgeMessage {
                    kind: Some(pb::edge_message::Kind::Frame(pb::SensorFrame { frame: Some(f), truth: None })),
                }
            };
            let odometry = pb::EdgeMessage {
                kind: Some(pb::edge_message::Kind::Odometry(pb::OdometryUpdate {
                    stamp: fuzz::interesting_f64(rng),
                    pose: Some(pb::Pose2D { x: fuzz::interesting_f64(rng), y: 0.0, theta: 0.0 }),
                    twist: None,
                })),
            };
            vec![
                hello.encode_to_vec(),
                frame(rng).encode_to_vec(),
                frame(rng).encode_to_vec(),
                odometry.encode_to_vec(),
            ]
        }
        "vlnav.v1.AudioChunk" => {
            // A fraction of a second at most: whatever decodes stays cheap to transcribe.
            let n = rng.random_range(0..800);
            let chunk = pb::AudioChunk {
                format: fuzz::interesting_i32(rng, 2),
                sample_rate: if rng.random_bool(0.7) { 16000 } else { fuzz::interesting_u32(rng) },
                data: fuzz::random_bytes(rng, n).into(),
            };
            vec![chunk.encode_to_vec()]
        }
        "vlnav.v1.WatchMissionRequest" => {
            vec![
                pb::WatchMissionRequest { mission_id: ["m-1", "", "../x"][rng.random_range(0..3)].into() }
                    .encode_to_vec(),
            ]
        }
        _ => Vec::new(),
    }
}

/// One to six messages for a stream: the first is often a valid one (a
/// hello, a first chunk), so the server reads on to the malformed ones.
fn messages(input_type: &str, rng: &mut Rng, call: usize) -> Vec<Vec<u8>> {
    let valid = samples(input_type, rng, call);
    let donors: Vec<&[u8]> = valid.iter().map(Vec::as_slice).collect();
    let n = rng.random_range(1..=6);
    (0..n)
        .map(|i| match valid.first() {
            Some(first) if i == 0 && rng.random_bool(0.5) => first.clone(),
            _ => fuzz::wire_bytes(rng, &donors, 1 << 16),
        })
        .collect()
}

const CALL_LIMIT: Duration = Duration::from_secs(30);

/// Reads a response stream to its end; the outcome's name.
async fn drain(path: &str, mut stream: tonic::Streaming<Vec<u8>>) -> String {
    let mut n = 0;
    loop {
        match tokio::time::timeout(CALL_LIMIT, stream.message()).await {
            Err(_) => panic!("{path}: the response stream neither ended nor sent within {CALL_LIMIT:?}"),
            Ok(Ok(Some(_))) => n += 1,
            Ok(Ok(None)) => return if n == 0 { "clean end".into() } else { "messages, clean end".into() },
            Ok(Err(status)) => return status_outcome(path, &status),
        }
    }
}

fn status_outcome(path: &str, status: &tonic::Status) -> String {
    assert!(!common::is_crash(status.code()), "{path}: {status:?}: a panic or a dropped connection");
    assert!(!status.message().is_empty(), "{path}: a status says why: {status:?}");
    format!("{:?}", status.code())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_streaming_method_answers_malformed_streams_with_a_status_or_an_end() {
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
    let runs: usize = std::env::var("VLNAV_MALFORMED_RUNS").ok().and_then(|v| v.parse().ok()).unwrap_or(24);
    let mut outcomes = std::collections::BTreeMap::<String, usize>::new();
    let (mut methods, mut calls) = (Vec::new(), 0);
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
                let (client, server) = (method.client_streaming(), method.server_streaming());
                if !client && !server {
                    continue;
                }
                let path = format!("/{}.{}/{}", file.package(), name, method.name());
                let input = method.input_type().trim_start_matches('.');
                methods.push(path.clone());
                for i in 0..runs {
                    let mut rng = fuzz::case_rng(fuzz::seed() ^ 0x5157, (methods.len() * 100_000 + i) as u64);
                    let msgs = if i == 0 { vec![Vec::new()] } else { messages(input, &mut rng, i) };
                    let mut grpc = tonic::client::Grpc::new(channel.clone());
                    grpc.ready().await.expect("the server is up");
                    let route = http::uri::PathAndQuery::try_from(path.as_str()).unwrap();
                    let call = async {
                        let outgoing = tokio_stream::iter(msgs.clone());
                        match (client, server) {
                            (true, true) => {
                                match grpc.streaming(tonic::Request::new(outgoing), route, RawCodec).await {
                                    Ok(r) => drain(&path, r.into_inner()).await,
                                    Err(s) => status_outcome(&path, &s),
                                }
                            }
                            (true, false) => {
                                match grpc.client_streaming(tonic::Request::new(outgoing), route, RawCodec).await {
                                    Ok(_) => "answer".into(),
                                    Err(s) => status_outcome(&path, &s),
                                }
                            }
                            _ => {
                                let req = tonic::Request::new(msgs[0].clone());
                                match grpc.server_streaming(req, route, RawCodec).await {
                                    Ok(r) => drain(&path, r.into_inner()).await,
                                    Err(s) => status_outcome(&path, &s),
                                }
                            }
                        }
                    };
                    let outcome = tokio::time::timeout(2 * CALL_LIMIT, call)
                        .await
                        .unwrap_or_else(|_| panic!("{path} hung on {msgs:02x?}"));
                    calls += 1;
                    *outcomes.entry(format!("{}: {outcome}", method.name())).or_default() += 1;
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
    for m in [
        "/vlnav.v1.FleetService/Attach",
        "/vlnav.v1.IngressService/Transcribe",
        "/vlnav.v1.MissionService/WatchMission",
    ] {
        assert!(methods.iter().any(|p| p == m), "{m} is among the streaming methods: {methods:?}");
    }
    eprintln!("{calls} malformed streams over {} streaming methods {methods:?}: {outcomes:?}", methods.len());
}
