//! Embedding latency per model (domain) and Identify latency over gRPC
//! (service level) on the machine at hand. MobileNetV2 uses the real weights
//! from deploy/fetch-models.sh; OSNet uses generated weights of the real shapes.

use std::path::PathBuf;

use candle_core::{DType, Device};
use candle_nn::VarBuilder;
use criterion::{Criterion, criterion_group, criterion_main};
use vlnav_proto::v1::reid_service_client::ReidServiceClient;
use vlnav_proto::v1::{BoundingBox, EnrollPersonRequest, IdentifyRequest, Image, ImageEncoding, RgbdFrame};
use vlnav_reid::embedder::{Embedder, ModelKind, default_device};
use vlnav_reid::osnet::{OsnetVariant, random_state_dict};
use vlnav_reid::preprocess::CropBox;

fn models_dir() -> PathBuf {
    std::env::var_os("VLNAV_MODELS_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../models"))
}

fn frame_image() -> image::RgbImage {
    image::RgbImage::from_fn(640, 480, |x, y| image::Rgb([(x % 256) as u8, (y % 256) as u8, ((x + y) % 256) as u8]))
}

/// A person-sized box in a 640×480 frame.
const PERSON: CropBox = CropBox { x_min: 250.0, y_min: 100.0, x_max: 370.0, y_max: 420.0 };

fn load(kind: ModelKind, device: &Device) -> Embedder {
    match kind {
        ModelKind::MobileNetV2 => {
            let path = kind.default_weights(&models_dir());
            Embedder::load(kind, &path, device).unwrap_or_else(|e| panic!("{e}"))
        }
        ModelKind::Osnet(v) => {
            let t = random_state_dict(v, 751, 1, device).unwrap();
            Embedder::from_var_builder(kind, VarBuilder::from_tensors(t, DType::F32, device)).unwrap()
        }
    }
}

const KINDS: [ModelKind; 3] =
    [ModelKind::MobileNetV2, ModelKind::Osnet(OsnetVariant::X0_25), ModelKind::Osnet(OsnetVariant::X1_0)];

fn embed(c: &mut Criterion) {
    let device = default_device();
    let img = frame_image();
    let mut g = c.benchmark_group("embed");
    g.sample_size(10);
    for kind in KINDS {
        let e = load(kind, &device);
        g.bench_function(format!("{}/1-crop", kind.name()), |b| b.iter(|| e.embed_regions(&img, &[PERSON]).unwrap()));
        let eight = [PERSON; 8];
        g.bench_function(format!("{}/8-crops", kind.name()), |b| b.iter(|| e.embed_regions(&img, &eight).unwrap()));
    }
    g.finish();
}

fn service(c: &mut Criterion) {
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let img = frame_image();
    let rgb =
        Image { width: 640, height: 480, encoding: ImageEncoding::Rgb8 as i32, data: img.as_raw().clone().into() };
    let mut g = c.benchmark_group("service");
    g.sample_size(10);
    for kind in KINDS {
        let weights = match kind {
            ModelKind::MobileNetV2 => None,
            ModelKind::Osnet(v) => {
                let p = dir.path().join(format!("{}.safetensors", v.name()));
                candle_core::safetensors::save(&random_state_dict(v, 751, 1, &Device::Cpu).unwrap(), &p).unwrap();
                Some(p)
            }
        };
        let opts = vlnav_reid::Options {
            backend: kind.name().into(),
            weights,
            models_dir: models_dir(),
            data_dir: dir.path().join(kind.name()),
            threshold: None,
            ..vlnav_reid::Options::default()
        };
        let cfg = vlnav_runtime::ServerConfig::default();
        let mut served = rt.block_on(async {
            let set = vlnav_reid::services(&opts, &cfg).await.unwrap_or_else(|e| panic!("{e:#}"));
            let mut served = vlnav_runtime::testing::start_client(&cfg, set, ReidServiceClient::new).await.unwrap();
            let crop = image::imageops::crop_imm(&img, 250, 100, 120, 320).to_image();
            let person =
                Image { width: 120, height: 320, encoding: ImageEncoding::Rgb8 as i32, data: crop.into_raw().into() };
            served
                .client
                .enroll_person(EnrollPersonRequest { name: "ana".into(), images: vec![person] })
                .await
                .unwrap();
            served
        });
        let req = IdentifyRequest {
            frame: Some(RgbdFrame { rgb: Some(rgb.clone()), ..Default::default() }),
            boxes: vec![BoundingBox {
                x_min: 250.0,
                y_min: 100.0,
                x_max: 370.0,
                y_max: 420.0,
                class_id: 0,
                score: 0.9,
                label: "person".into(),
            }],
            threshold: 0.0,
            name: String::new(),
        };
        g.bench_function(format!("identify/{}/640x480-1-box", kind.name()), |b| {
            b.iter(|| rt.block_on(served.client.identify(req.clone())).unwrap())
        });
        drop(served);
    }
    g.finish();
}

criterion_group!(benches, embed, service);
criterion_main!(benches);
