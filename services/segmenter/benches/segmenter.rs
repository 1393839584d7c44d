//! Segmentation latency at 640×480: the colour pipeline alone (HSV, floor
//! check, points) and a Segment call over gRPC.

use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::Vector3;
use vlnav_geometry::camera::{Camera, Intrinsics, Mount, Projector};
use vlnav_geometry::convert::camera_to_proto;
use vlnav_proto::v1::segmenter_service_client::SegmenterServiceClient;
use vlnav_proto::v1::{DepthImage, Image, ImageEncoding, RgbdFrame, SegmentRequest};
use vlnav_segmenter::colour::default_classes;
use vlnav_segmenter::segment::{ColourBackend, FrameView, PointSettings, segment};

const W: u32 = 640;
const H: u32 = 480;

fn camera() -> Camera {
    Camera {
        width: W,
        height: H,
        intrinsics: Intrinsics { fx: 388.6187, fy: 388.6187, cx: 320.6609, cy: 239.7847 },
        mount: Mount { translation: Vector3::new(0.3, 0.0, 0.6), roll: 0.0, pitch: 0.35, yaw: 0.0 },
        depth_min_m: 0.4,
        depth_max_m: 12.0,
    }
}

/// A floor seen by the camera with a red zone 2–2.5 m ahead; sky where the ray misses the floor.
fn scene(cam: &Camera) -> (Vec<u8>, Vec<u16>) {
    let p = Projector::new(cam);
    let origin = p.project(cam.intrinsics.cx, cam.intrinsics.cy, 0.0);
    let (mut rgb, mut depth) = (Vec::new(), Vec::new());
    for v in 0..H {
        for u in 0..W {
            let dir: Vector3<f64> = p.project(u as f64, v as f64, 1.0) - origin;
            if dir.z < -1e-6 {
                let t = -origin.z / dir.z;
                let hit = origin + dir * t;
                let red = (2.0..2.5).contains(&hit.x) && hit.y.abs() < 0.25;
                rgb.extend_from_slice(if red { &[205, 25, 30] } else { &[150, 150, 145] });
                depth.push((t * 1000.0).min(65_000.0) as u16);
            } else {
                rgb.extend_from_slice(&[90, 120, 200]);
                depth.push(0);
            }
        }
    }
    (rgb, depth)
}

fn pipeline(c: &mut Criterion) {
    let cam = camera();
    let (rgb, depth) = scene(&cam);
    let backend = ColourBackend::new(default_classes());
    let frame = FrameView { camera: cam, rgb: &rgb, depth_mm: &depth, semantics: None };
    let settings = PointSettings::default();
    let mut g = c.benchmark_group("segment");
    g.sample_size(20);
    g.bench_function("colour/640x480/stride-4", |b| b.iter(|| segment(&backend, &frame, None, 4, &settings).unwrap()));
    g.finish();
}

fn service(c: &mut Criterion) {
    let cam = camera();
    let (rgb, depth) = scene(&cam);
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().unwrap();
    let cfg = vlnav_runtime::ServerConfig::default();
    let (server, mut client) = rt.block_on(async {
        let set = vlnav_segmenter::services(&Default::default(), &cfg).await.unwrap();
        let server = vlnav_runtime::testing::start(&cfg, set).await.unwrap();
        // The channel the gateway uses (HTTP/2 windows sized for frames).
        let client = SegmenterServiceClient::new(server.traced_channel().unwrap());
        (server, client)
    });
    let frame = RgbdFrame {
        camera: Some(camera_to_proto(&cam)),
        rgb: Some(Image { width: W, height: H, encoding: ImageEncoding::Rgb8 as i32, data: rgb.into() }),
        depth: Some(DepthImage {
            width: W,
            height: H,
            data_mm: depth.iter().flat_map(|d| d.to_le_bytes()).collect(),
            encoding: 0,
            disparity_step: 0.0,
        }),
        ..Default::default()
    };
    let req = SegmentRequest { frame: Some(frame), classes: vec![], return_mask: true, point_stride: 4 };
    let mut g = c.benchmark_group("service");
    g.sample_size(20);
    g.bench_function("segment/colour/640x480-mask-stride-4", |b| {
        b.iter(|| rt.block_on(client.segment(req.clone())).unwrap())
    });
    g.finish();
    drop((client, server));
}

criterion_group!(benches, pipeline, service);
criterion_main!(benches);
