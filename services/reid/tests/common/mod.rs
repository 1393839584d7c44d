//! Shared by the ReID integration tests: model and photo paths, a real server.
#![allow(dead_code)]

use std::path::PathBuf;

use vlnav_proto::v1::reid_service_client::ReidServiceClient;
use vlnav_runtime::ServerConfig;
use vlnav_runtime::testing::{self, Connected};

/// `$VLNAV_MODELS_DIR`, or the workspace's `models/`.
pub fn models_dir() -> PathBuf {
    std::env::var_os("VLNAV_MODELS_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../models"))
}

/// A model or asset file that must exist; fails the test naming the set-up step otherwise.
pub fn require(rel: &str) -> PathBuf {
    let p = models_dir().join(rel);
    assert!(
        p.is_file(),
        "{} is missing: run deploy/fetch-models.sh (it fetches and converts the test models and photos)",
        p.display()
    );
    p
}

pub fn photo(name: &str) -> image::RgbImage {
    let p = require(&format!("photos/{name}"));
    image::open(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display())).to_rgb8()
}

/// Person boxes (x_min, y_min, x_max, y_max in pixels), drawn by hand on the
/// photos fetched by deploy/fetch-models.sh; used only as crop regions.
pub mod boxes {
    /// ultralytics bus.jpg (810×1080): the man in the beige coat, the man in the black coat, the walker at the right edge.
    pub const BUS: [(&str, [f32; 4]); 3] = [
        ("bus-beige-coat", [50.0, 400.0, 245.0, 905.0]),
        ("bus-black-coat", [222.0, 405.0, 345.0, 860.0]),
        ("bus-right-walker", [670.0, 380.0, 810.0, 875.0]),
    ];
    /// ultralytics zidane.jpg (1280×720): the bald man shouting (left), the grey-haired man pointing (right).
    pub const ZIDANE: [(&str, [f32; 4]); 2] =
        [("zidane-left", [123.0, 197.0, 710.0, 716.0]), ("zidane-right", [747.0, 41.0, 1141.0, 712.0])];
    /// candle-examples bike.jpg (800×556): the four front riders, left to right.
    pub const BIKE: [(&str, [f32; 4]); 4] = [
        ("bike-rider-1", [105.0, 95.0, 250.0, 470.0]),
        ("bike-rider-2", [262.0, 88.0, 405.0, 490.0]),
        ("bike-rider-3", [405.0, 88.0, 505.0, 450.0]),
        ("bike-rider-4", [475.0, 112.0, 600.0, 465.0]),
    ];
}

/// A running server and a client connected to it.
pub type Running = Connected<ReidServiceClient<tonic::transport::Channel>>;

pub async fn start(opts: &vlnav_reid::Options) -> Running {
    let cfg = ServerConfig::default();
    let set = vlnav_reid::services(opts, &cfg).await.expect("services");
    let make = |ch| ReidServiceClient::new(ch).max_decoding_message_size(64 << 20).max_encoding_message_size(64 << 20);
    testing::start_client(&cfg, set, make).await.unwrap()
}

/// Deterministic photometric and geometric augmentation of a box crop:
/// shift by up to 6 % of the box, scale 0.92–1.08, optional mirror,
/// brightness ×0.85–1.15, contrast ×0.85–1.15, saturation ×0.8–1.2.
pub fn augmented_crop(img: &image::RgbImage, b: [f32; 4], seed: u64, mirror: bool) -> image::RgbImage {
    let mut s = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
    let mut uniform = |lo: f32, hi: f32| {
        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        lo + (hi - lo) * ((s >> 40) as f32 / (1u64 << 24) as f32)
    };
    let (w, h) = (b[2] - b[0], b[3] - b[1]);
    let scale = uniform(0.92, 1.08);
    let (cx, cy) = ((b[0] + b[2]) / 2.0 + uniform(-0.06, 0.06) * w, (b[1] + b[3]) / 2.0 + uniform(-0.06, 0.06) * h);
    let (nw, nh) = (w * scale, h * scale);
    let x0 = (cx - nw / 2.0).clamp(0.0, img.width() as f32 - 2.0) as u32;
    let y0 = (cy - nh / 2.0).clamp(0.0, img.height() as f32 - 2.0) as u32;
    let x1 = ((cx + nw / 2.0) as u32).min(img.width());
    let y1 = ((cy + nh / 2.0) as u32).min(img.height());
    let mut crop = image::imageops::crop_imm(img, x0, y0, x1 - x0, y1 - y0).to_image();
    if mirror {
        crop = image::imageops::flip_horizontal(&crop);
    }
    let (brightness, contrast, saturation) = (uniform(0.85, 1.15), uniform(0.85, 1.15), uniform(0.8, 1.2));
    vlnav_geometry::rgb::jitter_colour(&mut crop, brightness, contrast, saturation);
    crop
}
