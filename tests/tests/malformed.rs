//! Malformed and hostile bytes, sent as the request of every unary method of
//! every server (listed from the proto descriptor set, so a new method is
//! covered without touching this file), get a gRPC status: no panic, no
//! reset connection, and the server still answers its health check after.
//! Random bytes mostly fail to decode; those that do decode are arbitrary
//! messages (huge sizes, NaNs, unknown enums) that the services must refuse
//! or answer.

use std::time::Duration;

use bytes::{Buf, BufMut};
use prost::Message;
use rand::{Rng, SeedableRng};
use tonic::codec::{Codec, DecodeBuf, Decoder, EncodeBuf, Encoder};
use vlnav_e2e::TestStack;

/// Passes bytes through as the message, both ways.
#[derive(Default)]
struct RawCodec;

struct RawEncoder;
struct RawDecoder;

impl Encoder for RawEncoder {
    type Item = Vec<u8>;
    type Error = tonic::Status;
    fn encode(&mut self, item: Vec<u8>, dst: &mut EncodeBuf<'_>) -> Result<(), tonic::Status> {
        dst.put_slice(&item);
        Ok(())
    }
}

impl Decoder for RawDecoder {
    type Item = Vec<u8>;
    type Error = tonic::Status;
    fn decode(&mut self, src: &mut DecodeBuf<'_>) -> Result<Option<Vec<u8>>, tonic::Status> {
        let mut out = vec![0; src.remaining()];
        src.copy_to_slice(&mut out);
        Ok(Some(out))
    }
}

impl Codec for RawCodec {
    type Encode = Vec<u8>;
    type Decode = Vec<u8>;
    type Encoder = RawEncoder;
    type Decoder = RawDecoder;
    fn encoder(&mut self) -> RawEncoder {
        RawEncoder
    }
    fn decoder(&mut self) -> RawDecoder {
        RawDecoder
    }
}

/// A protobuf-looking payload: fields with random numbers and wire types,
/// lengths that lie, varints that never end.
fn hostile(rng: &mut rand_chacha::ChaCha8Rng) -> Vec<u8> {
    let mut out = Vec::new();
    match rng.random_range(0..4) {
        0 => out.extend((0..rng.random_range(0..64)).map(|_| rng.random::<u8>())),
        1 => {
            for _ in 0..rng.random_range(1..12) {
                let field: u32 = rng.random_range(1..20);
                let wire: u32 = rng.random_range(0..6);
                prost::encoding::encode_varint(((field << 3) | wire) as u64, &mut out);
                match wire {
                    0 => prost::encoding::encode_varint(rng.random(), &mut out),
                    1 => out.extend(rng.random::<u64>().to_le_bytes()),
                    2 => {
                        let len: usize = rng.random_range(0..40);
                        // Sometimes the length claims more than follows.
                        let claimed =
                            if rng.random_bool(0.2) { len as u64 + rng.random_range(1..1 << 30) } else { len as u64 };
                        prost::encoding::encode_varint(claimed, &mut out);
                        out.extend((0..len).map(|_| rng.random::<u8>()));
                    }
                    5 => out.extend(rng.random::<u32>().to_le_bytes()),
                    _ => {}
                }
            }
        }
        2 => out.extend(std::iter::repeat_n(0xFF, rng.random_range(1..16))),
        _ => {
            // A frame-like message: nested messages with huge sizes and NaNs.
            let mut inner = Vec::new();
            for field in 1..=9u32 {
                prost::encoding::encode_varint(((field << 3) | 1) as u64, &mut inner);
                let v = [f64::NAN, f64::INFINITY, -1.0, 1e300, 0.0][rng.random_range(0..5)];
                inner.extend(v.to_le_bytes());
            }
            prost::encoding::encode_varint(((rng.random_range(1..8u32) << 3) | 2) as u64, &mut out);
            prost::encoding::encode_varint(inner.len() as u64, &mut out);
            out.extend(inner);
        }
    }
    out
}

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
                            !matches!(
                                status.code(),
                                tonic::Code::Unknown | tonic::Code::Unavailable | tonic::Code::Cancelled
                            ),
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
