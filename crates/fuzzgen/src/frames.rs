//! Sensor frames for fuzzing: valid `RgbdFrame`s (RGB8, PNG or JPEG colour,
//! depth, labels, odometry) and structured corruptions of them (sizes at and
//! beyond the limits, NaN and infinities, lengths that disagree with the
//! sizes, unknown encodings, truncated or lying PNG and JPEG streams).

use rand::Rng as _;
use vlnav_proto::v1::{
    self as pb, CameraInfo, CameraIntrinsics, CameraMount, DepthImage, Image, ImageEncoding, LabelImage, LabelInstance,
    Point3, Pose2D, RgbdFrame, Twist2D,
};

use crate::{Rng, interesting_f64, interesting_i32, interesting_u32, near_len, plausible_f64, random_bytes};

/// A small picture of `w`×`h` noise and gradients.
pub fn picture(rng: &mut Rng, w: u32, h: u32) -> image::RgbImage {
    let seed: u8 = rng.random();
    image::RgbImage::from_fn(w, h, |x, y| {
        image::Rgb([(x as u8).wrapping_mul(seed), (y as u8).wrapping_add(seed), (x ^ y) as u8])
    })
}

fn encode(img: &image::RgbImage, format: image::ImageFormat) -> Vec<u8> {
    let mut out = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut out), format).expect("encoding a picture in memory");
    out
}

pub fn png(rng: &mut Rng, w: u32, h: u32) -> Vec<u8> {
    encode(&picture(rng, w, h), image::ImageFormat::Png)
}

pub fn jpeg(rng: &mut Rng, w: u32, h: u32) -> Vec<u8> {
    encode(&picture(rng, w, h), image::ImageFormat::Jpeg)
}

/// CRC-32 (IEEE) as PNG chunks carry it.
pub fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in bytes {
        crc ^= b as u32;
        for _ in 0..8 {
            crc = if crc & 1 != 0 { (crc >> 1) ^ 0xEDB8_8320 } else { crc >> 1 };
        }
    }
    !crc
}

fn png_chunk(out: &mut Vec<u8>, kind: &[u8; 4], data: &[u8]) {
    out.extend((data.len() as u32).to_be_bytes());
    let start = out.len();
    out.extend(kind);
    out.extend(data);
    let crc = crc32(&out[start..]);
    out.extend(crc.to_be_bytes());
}

/// A well-formed PNG header that declares `w`×`h` (colour type and bit
/// depth from `color`: 0 grey, 2 RGB, 6 RGBA at 8 bits, 16 for 16-bit RGBA)
/// followed by `idat` as its only image data: a tiny file claiming a huge picture.
pub fn png_claiming(w: u32, h: u32, color: u8, idat: &[u8]) -> Vec<u8> {
    let mut out = b"\x89PNG\r\n\x1a\n".to_vec();
    let (color_type, depth) = match color {
        16 => (6, 16),
        c => (c, 8),
    };
    let mut ihdr = Vec::new();
    ihdr.extend(w.to_be_bytes());
    ihdr.extend(h.to_be_bytes());
    ihdr.extend([depth, color_type, 0, 0, 0]);
    png_chunk(&mut out, b"IHDR", &ihdr);
    png_chunk(&mut out, b"IDAT", idat);
    png_chunk(&mut out, b"IEND", &[]);
    out
}

/// A real JPEG whose frame header (SOF) is rewritten to claim `w`×`h`, and
/// whose scan is cut to `keep` bytes before the end-of-image marker.
pub fn jpeg_claiming(rng: &mut Rng, w: u16, h: u16, keep: usize) -> Vec<u8> {
    let mut data = jpeg(rng, 16, 16);
    if let Some(sof) = data.windows(2).position(|m| m[0] == 0xFF && matches!(m[1], 0xC0..=0xC2)) {
        data[sof + 5..sof + 7].copy_from_slice(&h.to_be_bytes());
        data[sof + 7..sof + 9].copy_from_slice(&w.to_be_bytes());
    }
    if let Some(sos) = data.windows(2).position(|m| m == [0xFF, 0xDA]) {
        let header_len = u16::from_be_bytes([data[sos + 2], data[sos + 3]]) as usize;
        let scan = sos + 2 + header_len;
        let end = (scan + keep).min(data.len().saturating_sub(2));
        data.truncate(end.max(scan.min(data.len())));
        data.extend([0xFF, 0xD9]);
    }
    data
}

/// A consistent frame of `w`×`h` with colour in `encoding`.
pub fn valid_frame(rng: &mut Rng, w: u32, h: u32, encoding: ImageEncoding) -> RgbdFrame {
    let pixels = (w * h) as usize;
    let rgb_data = match encoding {
        ImageEncoding::Png => png(rng, w, h),
        ImageEncoding::Jpeg => jpeg(rng, w, h),
        _ => picture(rng, w, h).into_raw(),
    };
    let depth: Vec<u8> = (0..pixels).flat_map(|_| rng.random_range(0u16..12000).to_le_bytes()).collect();
    let labels = rng.random_bool(0.5).then(|| {
        let n = rng.random_range(0..4u32);
        LabelImage {
            width: w,
            height: h,
            instance_ids: (0..pixels)
                .flat_map(|_| rng.random_range(0..=n as u16).to_le_bytes())
                .collect::<Vec<u8>>()
                .into(),
            instances: (1..=n)
                .map(|i| LabelInstance {
                    instance_id: i,
                    class_id: rng.random_range(0..80),
                    identity: if rng.random_bool(0.2) { "david".into() } else { String::new() },
                    semantic: String::new(),
                    visible_fraction: rng.random_range(0.0..1.0),
                })
                .collect(),
        }
    });
    RgbdFrame {
        robot_id: "husky-1".into(),
        seq: rng.random_range(0..1_000_000),
        stamp: rng.random_range(0.0..10_000.0),
        camera: Some(CameraInfo {
            width: w,
            height: h,
            intrinsics: Some(CameraIntrinsics {
                fx: rng.random_range(50.0..1000.0),
                fy: rng.random_range(50.0..1000.0),
                cx: w as f64 / 2.0,
                cy: h as f64 / 2.0,
            }),
            mount: rng.random_bool(0.7).then(|| CameraMount {
                translation: Some(Point3 { x: 0.3, y: 0.0, z: rng.random_range(0.2..1.5) }),
                roll: 0.0,
                pitch: rng.random_range(-0.3..0.3),
                yaw: 0.0,
            }),
            depth_min_m: [0.0, 0.3][rng.random_range(0..2)],
            depth_max_m: [0.0, 6.0, 10.0][rng.random_range(0..3)],
        }),
        rgb: Some(Image { width: w, height: h, encoding: encoding as i32, data: rgb_data.into() }),
        depth: Some(DepthImage { width: w, height: h, data_mm: depth.into(), encoding: 0, disparity_step: 0.0 }),
        odom: Some(Pose2D {
            x: rng.random_range(-50.0..50.0),
            y: rng.random_range(-50.0..50.0),
            theta: rng.random_range(-3.2..3.2),
        }),
        odom_twist: rng
            .random_bool(0.5)
            .then(|| Twist2D { linear: rng.random_range(-1.0..1.0), angular: rng.random_range(-1.0..1.0) }),
        labels,
    }
}

/// A valid frame of a random small size and encoding.
pub fn small_valid_frame(rng: &mut Rng) -> RgbdFrame {
    let (w, h) = (rng.random_range(1..=24), rng.random_range(1..=24));
    let encoding = [ImageEncoding::Rgb8, ImageEncoding::Png, ImageEncoding::Jpeg][rng.random_range(0..3)];
    valid_frame(rng, w, h, encoding)
}

/// Colour bytes that are not what they claim: cut short, padded, a lying
/// header, another format, or noise.
fn bad_image_bytes(rng: &mut Rng, img: &Image) -> Vec<u8> {
    let data = img.data.to_vec();
    match rng.random_range(0..8) {
        0 => data[..rng.random_range(0..=data.len())].to_vec(),
        1 => {
            let mut d = data;
            crate::mutate_bytes(rng, &mut d, &[], 1 << 20);
            d
        }
        2 => {
            let color = [0, 2, 6, 16][rng.random_range(0..4)];
            let n = rng.random_range(0..40);
            let idat = random_bytes(rng, n);
            png_claiming(interesting_u32(rng), interesting_u32(rng), color, &idat)
        }
        3 => {
            let side = |rng: &mut Rng| [1u16, 8, 640, 4096, 8192, 8193, 65535][rng.random_range(0..7)];
            let (w, h, keep) = (side(rng), side(rng), rng.random_range(0..200));
            jpeg_claiming(rng, w, h, keep)
        }
        4 => {
            let mut d = data;
            let n = rng.random_range(1..16);
            d.extend(random_bytes(rng, n));
            d
        }
        5 => {
            let n = rng.random_range(0..64);
            random_bytes(rng, n)
        }
        6 => Vec::new(),
        _ => {
            let other = if rng.random_bool(0.5) { png(rng, 4, 3) } else { jpeg(rng, 4, 3) };
            other[..rng.random_range(0..=other.len())].to_vec()
        }
    }
}

/// A frame with one to four structured corruptions of a valid one.
pub fn corrupt_frame(rng: &mut Rng) -> RgbdFrame {
    let mut f = small_valid_frame(rng);
    for _ in 0..rng.random_range(1..=4) {
        match rng.random_range(0..16) {
            0 => {
                let cam = f.camera.get_or_insert_default();
                if rng.random_bool(0.5) {
                    cam.width = interesting_u32(rng);
                } else {
                    cam.height = interesting_u32(rng);
                }
            }
            1 => {
                // Every part declares the same (possibly huge) size, the data stays small.
                let (w, h) = (interesting_u32(rng), interesting_u32(rng));
                if let Some(c) = f.camera.as_mut() {
                    (c.width, c.height) = (w, h);
                }
                if let Some(d) = f.depth.as_mut() {
                    (d.width, d.height) = (w, h);
                }
                if let Some(i) = f.rgb.as_mut() {
                    (i.width, i.height) = (w, h);
                }
                if let Some(l) = f.labels.as_mut() {
                    (l.width, l.height) = (w, h);
                }
            }
            2 => {
                if let Some(k) = f.camera.as_mut().and_then(|c| c.intrinsics.as_mut()) {
                    match rng.random_range(0..4) {
                        0 => k.fx = interesting_f64(rng),
                        1 => k.fy = interesting_f64(rng),
                        2 => k.cx = interesting_f64(rng),
                        _ => k.cy = interesting_f64(rng),
                    }
                }
            }
            3 => {
                let cam = f.camera.get_or_insert_default();
                match rng.random_range(0..5) {
                    0 => cam.depth_min_m = interesting_f64(rng),
                    1 => cam.depth_max_m = interesting_f64(rng),
                    2 => cam.intrinsics = None,
                    3 => {
                        let m = cam.mount.get_or_insert_default();
                        m.pitch = interesting_f64(rng);
                        m.translation =
                            Some(Point3 { x: interesting_f64(rng), y: 0.0, z: plausible_f64(rng, 0.0, 2.0) });
                    }
                    _ => cam.mount = Some(CameraMount::default()),
                }
            }
            4 => {
                let d = f.depth.get_or_insert_default();
                let exact = d.data_mm.len();
                let n = near_len(rng, exact);
                let mut v = d.data_mm.to_vec();
                v.resize(n, 0);
                d.data_mm = v.into();
            }
            5 => {
                let d = f.depth.get_or_insert_default();
                if rng.random_bool(0.5) {
                    d.width = interesting_u32(rng);
                } else {
                    d.height = interesting_u32(rng);
                }
            }
            6 => {
                if let Some(img) = f.rgb.as_mut() {
                    img.encoding = interesting_i32(rng, 3);
                }
            }
            7 | 8 => {
                if let Some(img) = f.rgb.as_mut() {
                    img.data = bad_image_bytes(rng, img).into();
                }
            }
            9 => {
                if let Some(img) = f.rgb.as_mut() {
                    match rng.random_range(0..3) {
                        0 => img.width = interesting_u32(rng),
                        1 => img.height = interesting_u32(rng),
                        _ => (img.width, img.height) = (0, 0),
                    }
                }
            }
            10 => {
                let l = f.labels.get_or_insert_default();
                match rng.random_range(0..4) {
                    0 => l.width = interesting_u32(rng),
                    1 => l.height = interesting_u32(rng),
                    2 => {
                        let n = near_len(rng, l.instance_ids.len());
                        let mut v = l.instance_ids.to_vec();
                        v.resize(n, 0xff);
                        l.instance_ids = v.into();
                    }
                    _ => l.instances.push(LabelInstance {
                        instance_id: interesting_u32(rng),
                        class_id: interesting_i32(rng, 79),
                        identity: String::new(),
                        semantic: String::new(),
                        visible_fraction: interesting_f64(rng) as f32,
                    }),
                }
            }
            11 => {
                let p = f.odom.get_or_insert_default();
                match rng.random_range(0..3) {
                    0 => p.x = interesting_f64(rng),
                    1 => p.y = interesting_f64(rng),
                    _ => p.theta = interesting_f64(rng),
                }
            }
            12 => {
                let t = f.odom_twist.get_or_insert_default();
                t.linear = interesting_f64(rng);
                t.angular = plausible_f64(rng, -1.0, 1.0);
            }
            13 => f.stamp = interesting_f64(rng),
            14 => match rng.random_range(0..6) {
                0 => f.camera = None,
                1 => f.rgb = None,
                2 => f.depth = None,
                3 => f.odom = None,
                4 => f.labels = None,
                _ => f.camera.as_mut().map_or((), |c| c.intrinsics = None),
            },
            _ => f.robot_id = crate::arbitrary_text(rng, 40),
        }
    }
    f
}

/// A goal as the subgoal service sends it, sometimes with odd numbers.
pub fn goal(rng: &mut Rng) -> pb::Goal {
    let odd = rng.random_bool(0.3);
    let num = |rng: &mut Rng, lo: f64, hi: f64| if odd { plausible_f64(rng, lo, hi) } else { rng.random_range(lo..hi) };
    pb::Goal {
        pose: rng.random_bool(0.95).then(|| Pose2D {
            x: num(rng, -20.0, 20.0),
            y: num(rng, -20.0, 20.0),
            theta: num(rng, -3.2, 3.2),
        }),
        position_tolerance: num(rng, -0.1, 1.0),
        yaw_tolerance: num(rng, -0.1, 0.5),
        rotation_only: rng.random_bool(0.3),
        landmark: rng.random_bool(0.3).then(|| Point3 { x: num(rng, -20.0, 20.0), y: num(rng, -20.0, 20.0), z: 0.0 }),
    }
}
