//! One hop of a control cycle at the D455's 640×480, without the stage's
//! work: a `Segment` call carrying colour and depth (921,600 + 614,400 B)
//! to a stage that answers at once, served by the real [`serve`] (telemetry,
//! caller checks, limits), over plaintext and over mutual TLS as the
//! deployment runs it (`DevPki`, the gateway's certificate, stages that
//! answer only the gateway). Beside it, what protobuf alone costs: the
//! request encoded and decoded once. The difference between the two
//! transports is what TLS adds to a hop; docs/architecture.md, "Where a
//! control cycle's time goes", puts the figures beside the fleet's traces.
//!
//! `cargo bench -p vlnav-runtime --bench hop`

use std::time::Duration;

use criterion::{BatchSize, Criterion, Throughput, criterion_group, criterion_main};
use prost::Message;
use tonic::{Request, Response, Status};
use vlnav_proto::v1::segmenter_service_client::SegmenterServiceClient;
use vlnav_proto::v1::segmenter_service_server::{SegmenterService, SegmenterServiceServer};
use vlnav_proto::v1::{
    DepthImage, GetSegmenterInfoRequest, Image, ImageEncoding, RgbdFrame, SegmentRequest, SegmentResponse,
    SegmenterInfo,
};
use vlnav_runtime::CallerPolicy;
use vlnav_runtime::client::{TracedChannel, channel_with};
use vlnav_runtime::security::{ClientSecurity, ClientTls, DevPki};
use vlnav_runtime::server::{ServerConfig, ServiceSet};
use vlnav_runtime::testing::{TestServer, start};

const W: u32 = 640;
const H: u32 = 480;

/// A stage that reads the frame's size and answers at once.
struct Answer;

#[tonic::async_trait]
impl SegmenterService for Answer {
    async fn segment(&self, req: Request<SegmentRequest>) -> Result<Response<SegmentResponse>, Status> {
        let frame = req.into_inner().frame.unwrap_or_default();
        let rgb = frame.rgb.unwrap_or_default();
        Ok(Response::new(SegmentResponse { width: rgb.width, height: rgb.height, ..Default::default() }))
    }

    async fn get_segmenter_info(&self, _: Request<GetSegmenterInfoRequest>) -> Result<Response<SegmenterInfo>, Status> {
        Ok(Response::new(SegmenterInfo::default()))
    }
}

/// A 640×480 frame whose bytes vary (so nothing downstream sees a pattern).
fn request() -> SegmentRequest {
    let n = (W * H) as usize;
    let rgb: Vec<u8> = (0..3 * n).map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8).collect();
    let depth: Vec<u8> = (0..n).flat_map(|i| (500 + (i % 7_000) as u16).to_le_bytes()).collect();
    SegmentRequest {
        frame: Some(RgbdFrame {
            robot_id: "husky-1".into(),
            rgb: Some(Image { width: W, height: H, encoding: ImageEncoding::Rgb8 as i32, data: rgb.into() }),
            depth: Some(DepthImage { width: W, height: H, data_mm: depth.into(), ..Default::default() }),
            ..Default::default()
        }),
        ..Default::default()
    }
}

async fn stage(cfg: &ServerConfig) -> TestServer {
    let set = ServiceSet::new().add("segment", SegmenterServiceServer::new(Answer)).callers(CallerPolicy::stages());
    start(cfg, set).await.expect("the stage starts")
}

fn hop(c: &mut Criterion) {
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().unwrap();
    // Channels connect on the runtime's tasks.
    let _runtime = rt.enter();
    let req = request();
    let bytes = req.encoded_len() as u64;
    let dir = tempfile::tempdir().unwrap();
    let pki = DevPki::ensure(dir.path(), &[]).unwrap();
    let gateway =
        ClientTls::from_files(std::fs::read(pki.ca()).unwrap(), &pki.gateway_cert(), &pki.gateway_key()).unwrap();
    let (plain, tls) = rt.block_on(async {
        let plain = stage(&ServerConfig::default()).await;
        let tls = stage(&ServerConfig { tls: pki.server_args(), ..Default::default() }).await;
        (plain, tls)
    });
    let channels: [(&str, TracedChannel); 2] = [
        ("plaintext", channel_with(&plain.uri(), &ClientSecurity::none()).unwrap()),
        (
            "mutual TLS",
            channel_with(&format!("https://{}", tls.addr()), &ClientSecurity::new(Some(gateway), None)).unwrap(),
        ),
    ];

    let mut g = c.benchmark_group("hop 640x480 colour+depth");
    g.throughput(Throughput::Bytes(bytes));
    g.measurement_time(Duration::from_secs(8));
    g.bench_function("protobuf encode + decode", |b| {
        let mut buf = Vec::with_capacity(bytes as usize);
        b.iter(|| {
            buf.clear();
            req.encode(&mut buf).unwrap();
            SegmentRequest::decode(buf.as_slice()).unwrap()
        })
    });
    for (name, ch) in channels {
        let mut client = SegmenterServiceClient::new(ch);
        // Connect (and for TLS, shake hands) before measuring.
        rt.block_on(client.segment(req.clone())).expect("the stage answers");
        g.bench_function(format!("Segment call, {name}"), |b| {
            // The request is built outside the measurement (its images are
            // shared `Bytes`), as the gateway builds it before its call.
            b.to_async(&rt).iter_batched(
                || (client.clone(), req.clone()),
                |(mut client, req)| async move { client.segment(req).await.unwrap().into_inner().width },
                BatchSize::SmallInput,
            )
        });
    }
    g.finish();
    drop((plain, tls));
}

criterion_group!(benches, hop);
criterion_main!(benches);
