//! Fuzzing the gateway's check of what an edge agent sends
//! ([`check_frame`], [`check_pose`]) and the checked frame the rest of the
//! gateway takes ([`CheckedFrame`]): structured corruptions of valid frames
//! (`vlnav_fuzzgen::frames`: sizes 0 to u32::MAX, NaN and infinities,
//! lengths that disagree with the sizes, unknown encodings, lying PNG and
//! JPEG data) and byte-level mutations of a valid encoded `EdgeMessage`
//! decoded with prost. Property: no panic; an accepted frame is consistent
//! (finite numbers, sizes within the limit, buffers as long as the sizes
//! say); a refusal says why; checking allocates nothing that grows with a
//! declared size; every valid frame is accepted.
//!
//! Short by default; the full run:
//! `VLNAV_FUZZ_CASES=1000000 cargo test --release -p vlnav-gateway --test fuzz_frames -- --nocapture`.

use prost::Message;
use rand::Rng as _;
use vlnav_fuzzgen::{self as fuzz, PeakAlloc, Rng, frames};
use vlnav_gateway::frames::{CheckedFrame, FrameError, MAX_SIDE, check_frame, check_pose};
use vlnav_geometry::rgb::{Encoding, header_size};
use vlnav_proto::v1::{EdgeMessage, ImageEncoding, RgbdFrame, SensorFrame, edge_message};

#[global_allocator]
static ALLOC: PeakAlloc = PeakAlloc;

#[derive(Debug)]
struct Case {
    frame: RgbdFrame,
    previous_stamp: Option<f64>,
}

fn edge_message_of(frame: RgbdFrame) -> Vec<u8> {
    EdgeMessage { kind: Some(edge_message::Kind::Frame(SensorFrame { frame: Some(frame), ..Default::default() })) }
        .encode_to_vec()
}

fn case(rng: &mut Rng) -> Case {
    let frame = match rng.random_range(0..10) {
        0 => frames::small_valid_frame(rng),
        1..=6 => frames::corrupt_frame(rng),
        _ => {
            // An edge agent's message, mutated on the wire, decoded as the gateway does.
            let valid: Vec<Vec<u8>> = (0..3).map(|_| edge_message_of(frames::small_valid_frame(rng))).collect();
            let donors: Vec<&[u8]> = valid.iter().map(Vec::as_slice).collect();
            let mut bytes = valid[0].clone();
            fuzz::mutate_bytes(rng, &mut bytes, &donors, 1 << 20);
            match EdgeMessage::decode(bytes.as_slice()) {
                Ok(EdgeMessage { kind: Some(edge_message::Kind::Frame(SensorFrame { frame: Some(f), .. })) }) => f,
                _ => frames::corrupt_frame(rng),
            }
        }
    };
    let previous_stamp = match rng.random_range(0..4) {
        0 => None,
        1 => Some(fuzz::interesting_f64(rng)),
        _ => Some(frame.stamp - rng.random_range(-1.0..1.0)),
    };
    Case { frame, previous_stamp }
}

/// What an accepted frame must satisfy.
fn assert_consistent(f: &RgbdFrame, previous: Option<f64>) {
    assert!(f.stamp.is_finite() && f.stamp >= 0.0, "stamp {}", f.stamp);
    if let Some(p) = previous {
        assert!(f.stamp.partial_cmp(&p) != Some(std::cmp::Ordering::Less), "stamp {} before {p}", f.stamp);
    }
    let pose = f.odom.as_ref().expect("odom");
    assert!(pose.x.is_finite() && pose.y.is_finite() && pose.theta.is_finite(), "{pose:?}");
    let cam = f.camera.as_ref().expect("camera");
    assert!((1..=MAX_SIDE).contains(&cam.width) && (1..=MAX_SIDE).contains(&cam.height), "{cam:?}");
    let k = cam.intrinsics.as_ref().expect("intrinsics");
    assert!(k.fx > 0.0 && k.fy > 0.0 && k.fx.is_finite() && k.fy.is_finite(), "{k:?}");
    let pixels = cam.width as usize * cam.height as usize;
    let depth = f.depth.as_ref().expect("depth");
    assert_eq!((depth.width, depth.height, depth.data_mm.len()), (cam.width, cam.height, pixels * 2));
    if let Some(rgb) = &f.rgb {
        match ImageEncoding::try_from(rgb.encoding) {
            Ok(ImageEncoding::Rgb8) => assert_eq!(rgb.data.len(), pixels * 3),
            Ok(enc @ (ImageEncoding::Png | ImageEncoding::Jpeg)) => {
                let encoding = if enc == ImageEncoding::Png { Encoding::Png } else { Encoding::Jpeg };
                let size = header_size(encoding, &rgb.data).expect("an accepted image has a readable header");
                assert_eq!(size, Some((cam.width, cam.height)), "accepted a {enc:?} of another size");
            }
            other => panic!("accepted an image encoded as {other:?}"),
        }
    }
    if let Some(l) = &f.labels {
        assert_eq!((l.width, l.height, l.instance_ids.len()), (cam.width, cam.height, pixels * 2));
    }
}

#[test]
fn frame_checks_never_panic_and_accept_only_consistent_frames() {
    let report = fuzz::run("gateway frame check", 3_000, case, |c| {
        let f = &c.frame;
        let (result, used) = fuzz::metered(|| check_frame(f, c.previous_stamp));
        assert!(used.largest <= 4096, "checking a frame allocated {} bytes at once", used.largest);
        if let Some(p) = &f.odom {
            let pose_ok = check_pose(f.seq, p).is_ok();
            assert_eq!(pose_ok, p.x.is_finite() && p.y.is_finite() && p.theta.is_finite());
        }
        // What the robot's actor is given: the same verdict, and the camera the executor reads.
        let sensor = SensorFrame { frame: Some(f.clone()), truth: None };
        let checked = CheckedFrame::check(sensor, c.previous_stamp);
        assert_eq!(checked.as_ref().err().map(|e| e.to_string()), result.as_ref().err().map(|e| e.to_string()));
        match result {
            Ok(()) => {
                assert_consistent(f, c.previous_stamp);
                let checked = checked.expect("accepted");
                assert_eq!(checked.frame(), f);
                let cam = f.camera.as_ref().expect("camera");
                assert_eq!((checked.camera().width, checked.camera().height), (cam.width, cam.height));
                "accepted".into()
            }
            Err(e) => {
                assert!(!e.to_string().is_empty());
                match e {
                    FrameError::Missing { .. } => "missing part",
                    FrameError::NotFinite { .. } => "not finite",
                    FrameError::Invalid { .. } => "invalid",
                    FrameError::StampBackwards { .. } => "stamp backwards",
                }
                .into()
            }
        }
    });
    report.assert_no_panics();
    for outcome in ["accepted", "missing part", "not finite", "invalid", "stamp backwards"] {
        assert!(report.count(outcome) > 0, "{outcome}: {report}");
    }
}

#[test]
fn valid_frames_pass_the_check() {
    fuzz::run("valid frames (gateway)", 300, frames::small_valid_frame, |f| {
        check_frame(f, Some(f.stamp)).unwrap_or_else(|e| panic!("{e}"));
        "accepted".into()
    })
    .assert_no_panics();
}

#[test]
fn a_huge_declared_frame_with_ten_bytes_is_refused_without_allocating_for_it() {
    let mut f = frames::valid_frame(&mut fuzz::case_rng(2, 0), 4, 3, ImageEncoding::Rgb8);
    let cam = f.camera.as_mut().unwrap();
    (cam.width, cam.height) = (4096, 4096);
    let depth = f.depth.as_mut().unwrap();
    (depth.width, depth.height, depth.data_mm) = (4096, 4096, vec![0; 10].into());
    let (r, used) = fuzz::metered(|| check_frame(&f, None));
    assert!(r.unwrap_err().to_string().contains("33554432 bytes of u16 millimetres are expected"));
    assert!(used.largest < 4096, "{used:?}");
}
