//! Fuzzing the proto → domain converters every service runs on a frame
//! (camera, depth, pose, goal, colour image and its decoding, labels):
//! structured corruptions of valid frames (`vlnav_fuzzgen::frames`) and
//! byte-level mutations of a valid encoded frame decoded with prost.
//! Property: no panic; what is accepted is consistent (sizes within the
//! limits and matching the camera, finite numbers); what is refused names a
//! field; no allocation grows with a declared size rather than with the
//! bytes that came (a frame that claims 4096×4096 with ten bytes of data is
//! refused without allocating for 4096×4096).
//!
//! Short by default; the full run:
//! `VLNAV_FUZZ_CASES=1000000 cargo test --release -p vlnav-geometry --test fuzz_convert -- --nocapture`.

use prost::Message;
use rand::Rng as _;
use vlnav_fuzzgen::{self as fuzz, PeakAlloc, Rng, frames};
use vlnav_geometry::convert::{
    DepthDefaults, camera_from_proto, depth_from_proto, encoded_image_from_proto, goal_from_proto,
    label_ids_from_proto, pose_from_proto,
};
use vlnav_geometry::rgb::MAX_SIDE;
use vlnav_proto::v1::{Goal, ImageEncoding, RgbdFrame};

#[global_allocator]
static ALLOC: PeakAlloc = PeakAlloc;

/// Bytes any conversion may allocate beyond what the input holds.
const SLACK: usize = 64 << 10;

/// Bytes a PNG or JPEG may decode to per input byte: deflate's ceiling of
/// 1032:1, from a 1-bit palette to 8-bit RGBA (×32). A JPEG's ceiling is
/// lower (one bit for an 8×8 block at the least: 512 pixels a byte).
const MAX_EXPANSION: usize = 1032 * 32;

#[derive(Debug)]
struct Case {
    frame: RgbdFrame,
    goal: Goal,
    defaults: DepthDefaults,
    /// The size the labels are checked against (the camera's, or any).
    label_size: Option<(u32, u32)>,
}

fn valid_encodings(rng: &mut Rng) -> Vec<Vec<u8>> {
    (0..4).map(|_| frames::small_valid_frame(rng).encode_to_vec()).collect()
}

fn case(rng: &mut Rng) -> Case {
    let frame = match rng.random_range(0..10) {
        0 => frames::small_valid_frame(rng),
        1..=6 => frames::corrupt_frame(rng),
        _ => {
            // Bytes of a valid frame, mutated, then decoded as the services would.
            let valid = valid_encodings(rng);
            let donors: Vec<&[u8]> = valid.iter().map(Vec::as_slice).collect();
            let mut bytes = valid[0].clone();
            fuzz::mutate_bytes(rng, &mut bytes, &donors, 1 << 20);
            RgbdFrame::decode(bytes.as_slice()).unwrap_or_else(|_| frames::corrupt_frame(rng))
        }
    };
    // The defaults are the service's configuration (finite numbers), not the wire's.
    let defaults = match rng.random_range(0..4) {
        0 => DepthDefaults::UNSET,
        1 => DepthDefaults { min_m: rng.random_range(-1.0..5.0), max_m: rng.random_range(-1.0..20.0) },
        _ => DepthDefaults { min_m: 0.3, max_m: 10.0 },
    };
    let label_size = rng.random_bool(0.3).then(|| (fuzz::interesting_u32(rng), fuzz::interesting_u32(rng)));
    Case { frame, goal: frames::goal(rng), defaults, label_size }
}

/// Converts everything but the image (which [`check_image`] decodes);
/// returns the outcome's name.
fn convert(c: &Case) -> String {
    let f = &c.frame;
    let mut refused = false;
    match pose_from_proto(f.odom.as_ref(), "frame.odom") {
        Ok(p) => assert!(p.x.is_finite() && p.y.is_finite() && p.theta.is_finite(), "{p:?}"),
        Err(e) => {
            assert!(e.field.starts_with("frame.odom") && !e.reason.is_empty(), "{e:?}");
            refused = true;
        }
    }
    match goal_from_proto(Some(&c.goal), "goal") {
        Ok(g) => {
            assert!(g.pose.x.is_finite() && g.pose.y.is_finite() && g.pose.theta.is_finite(), "{g:?}");
            assert!(g.position_tolerance >= 0.0 && g.yaw_tolerance >= 0.0, "{g:?}");
            assert!(if g.rotation_only { g.yaw_tolerance > 0.0 } else { g.position_tolerance > 0.0 }, "{g:?}");
        }
        Err(e) => assert!(e.field.starts_with("goal") && !e.reason.is_empty(), "{e:?}"),
    }
    match camera_from_proto(f.camera.as_ref(), "frame.camera", c.defaults) {
        Err(e) => {
            assert!(e.field.starts_with("frame.camera") && !e.reason.is_empty(), "{e:?}");
            refused = true;
        }
        Ok(cam) => {
            assert!((1..=MAX_SIDE).contains(&cam.width) && (1..=MAX_SIDE).contains(&cam.height), "{cam:?}");
            let k = &cam.intrinsics;
            assert!(k.fx > 0.0 && k.fy > 0.0 && k.fx.is_finite() && k.fy.is_finite(), "{cam:?}");
            assert!(k.cx.is_finite() && k.cy.is_finite(), "{cam:?}");
            assert!(cam.depth_max_m <= 0.0 || cam.depth_max_m > cam.depth_min_m, "{cam:?}");
            match depth_from_proto(f.depth.as_ref(), &cam, "frame.depth") {
                Ok(d) => {
                    assert_eq!((d.width(), d.height()), (cam.width as usize, cam.height as usize));
                    // The last reading is in bounds.
                    d.mm(d.width() - 1, d.height() - 1);
                }
                Err(e) => {
                    assert!(e.field.starts_with("frame.depth") && !e.reason.is_empty(), "{e:?}");
                    refused = true;
                }
            }
        }
    }
    if let Some(l) = &f.labels {
        let (w, h) = c.label_size.unwrap_or_else(|| f.camera.as_ref().map_or((0, 0), |c| (c.width, c.height)));
        match label_ids_from_proto(l, w, h, "frame.labels") {
            Ok(ids) => {
                assert_eq!(ids.len() as u128, w as u128 * h as u128);
            }
            Err(e) => {
                assert!(e.field.starts_with("frame.labels") && !e.reason.is_empty(), "{e:?}");
                refused = true;
            }
        }
    }
    if refused { "frame refused".into() } else { "frame accepted".into() }
}

/// Reads the colour image as the services do; returns the outcome's name.
fn check_image(f: &RgbdFrame) -> &'static str {
    let Some(img) = &f.rgb else { return "no image" };
    let encoded = match encoded_image_from_proto(img) {
        Ok(e) => e,
        Err(e) => {
            assert!(e.in_field("frame.rgb").field.starts_with("frame.rgb"), "{e:?}");
            return "encoding refused";
        }
    };
    match encoded.decode() {
        Ok(rgb) => {
            let (w, h) = rgb.dimensions();
            assert!((1..=MAX_SIDE).contains(&w) && (1..=MAX_SIDE).contains(&h), "{w}x{h}");
            assert!(img.width == 0 || img.width == w, "declared {} wide, decoded {w}", img.width);
            assert!(img.height == 0 || img.height == h, "declared {} high, decoded {h}", img.height);
            assert_eq!(rgb.as_raw().len(), w as usize * h as usize * 3);
            match ImageEncoding::try_from(img.encoding) {
                Ok(ImageEncoding::Png) => "PNG decoded",
                Ok(ImageEncoding::Jpeg) => "JPEG decoded",
                _ => "RGB8 accepted",
            }
        }
        Err(e) => {
            let field = e.in_field("frame.rgb");
            assert!(field.field.starts_with("frame.rgb") && !field.reason.is_empty(), "{e:?}");
            "image refused"
        }
    }
}

#[test]
fn frame_conversions_never_panic_and_allocate_by_what_came() {
    let report = fuzz::run("frame conversions", 2_000, case, |c| {
        let encoded = c.frame.encoded_len() + c.goal.encoded_len();
        let (outcome, used) = fuzz::metered(|| convert(c));
        assert!(
            used.largest <= SLACK + encoded,
            "converting a frame of {encoded} bytes allocated {} bytes at once",
            used.largest
        );
        let data = c.frame.rgb.as_ref().map_or(0, |i| i.data.len());
        let (image, used) = fuzz::metered(|| check_image(&c.frame));
        assert!(
            used.largest <= SLACK + MAX_EXPANSION * data,
            "{image}: {data} bytes of image data made an allocation of {} bytes",
            used.largest
        );
        format!("{outcome}, {image}")
    });
    report.assert_no_panics();
    assert!(report.count("frame accepted, RGB8 accepted") > 0, "{report}");
    assert!(report.count("frame refused, image refused") > 0, "{report}");
}

/// Valid frames of every encoding are accepted whole.
#[test]
fn valid_frames_are_accepted() {
    fuzz::run("valid frames", 300, frames::small_valid_frame, |f| {
        let cam = camera_from_proto(f.camera.as_ref(), "frame.camera", DepthDefaults::UNSET).expect("camera");
        depth_from_proto(f.depth.as_ref(), &cam, "frame.depth").expect("depth");
        pose_from_proto(f.odom.as_ref(), "frame.odom").expect("pose");
        if let Some(l) = &f.labels {
            label_ids_from_proto(l, cam.width, cam.height, "frame.labels").expect("labels");
        }
        let img = encoded_image_from_proto(f.rgb.as_ref().expect("rgb")).expect("encoding").decode().expect("decode");
        assert_eq!(img.dimensions(), (cam.width, cam.height));
        "accepted".into()
    })
    .assert_no_panics();
}

/// Inputs the fuzzer found, each refused now (cheaply, and without a panic).
#[test]
fn fuzz_findings_stay_fixed() {
    let mut rng = fuzz::case_rng(1, 0);
    // Labels declaring u32::MAX a side: the byte count overflowed (a panic in debug builds).
    let mut f = frames::valid_frame(&mut rng, 4, 3, ImageEncoding::Rgb8);
    let labels = vlnav_proto::v1::LabelImage { width: u32::MAX, height: u32::MAX, ..Default::default() };
    assert!(label_ids_from_proto(&labels, u32::MAX, u32::MAX, "frame.labels").is_err());
    // A JPEG of a few hundred bytes whose header claims 8192×4096 decoded to 100 MB of grey.
    let jpeg = frames::jpeg_claiming(&mut rng, 8192, 4096, 100);
    let img = vlnav_proto::v1::Image { width: 0, height: 0, encoding: ImageEncoding::Jpeg as i32, data: jpeg.into() };
    let (r, used) = fuzz::metered(|| encoded_image_from_proto(&img).unwrap().decode());
    let e = r.unwrap_err();
    assert!(e.to_string().contains("too short for the 8192×4096 picture"), "{e}");
    assert!(used.largest < 1 << 20, "{used:?}");
    // A PNG header claiming 4096×4096 RGBA with ten bytes of image data.
    let png = frames::png_claiming(4096, 4096, 6, &[0x78, 0x9c, 1, 2, 3, 4, 5, 6, 7, 8]);
    let img =
        vlnav_proto::v1::Image { width: 4096, height: 4096, encoding: ImageEncoding::Png as i32, data: png.into() };
    let (r, used) = fuzz::metered(|| encoded_image_from_proto(&img).unwrap().decode());
    assert!(r.unwrap_err().to_string().contains("too short"));
    assert!(used.largest < 1 << 20, "{used:?}");
    // A frame whose every part declares 4096×4096 and carries ten bytes.
    let cam = f.camera.as_mut().unwrap();
    (cam.width, cam.height) = (4096, 4096);
    let depth = f.depth.as_mut().unwrap();
    (depth.width, depth.height, depth.data_mm) = (4096, 4096, vec![0; 10].into());
    let rgb = f.rgb.as_mut().unwrap();
    (rgb.width, rgb.height, rgb.data) = (4096, 4096, vec![0; 10].into());
    let (r, used) = fuzz::metered(|| {
        let cam = camera_from_proto(f.camera.as_ref(), "frame.camera", DepthDefaults::UNSET).unwrap();
        let depth = depth_from_proto(f.depth.as_ref(), &cam, "frame.depth").map(|_| ());
        let rgb = encoded_image_from_proto(f.rgb.as_ref().unwrap()).unwrap().decode().map(|_| ());
        (depth, rgb)
    });
    assert!(r.0.is_err() && r.1.is_err(), "{r:?}");
    assert!(used.largest < 64 << 10, "{used:?}");
}
