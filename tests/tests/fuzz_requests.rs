//! Fuzzing request decoding: for the request type of every method of every
//! service (listed from the descriptor set; a method whose type has no entry
//! here fails the test), hostile and mutated bytes are decoded with prost,
//! and what decodes goes through the service's own request → domain
//! conversion where it has one (planner input checks and parser, plan
//! conversion and validator, detector filter and labels, local planner step,
//! ingress text normalisation and audio assembly, the frame converters and
//! the gateway's frame check). Property: no panic; a refusal carries a
//! message. The services over the network: `malformed.rs` (unary) and
//! `malformed_streams.rs` (streaming).
//!
//! Short by default; the full run:
//! `VLNAV_FUZZ_CASES=1000000 cargo test --release -p vlnav-e2e --test fuzz_requests -- --nocapture`.

use std::cell::RefCell;
use std::collections::BTreeMap;
use std::path::Path;

use prost::Message;
use rand::Rng as _;
use vlnav_fuzzgen::{self as fuzz, Rng, frames};
use vlnav_geometry::convert::{
    DepthDefaults, camera_from_proto, depth_from_proto, encoded_image_from_proto, label_ids_from_proto, pose_from_proto,
};
use vlnav_planner::grounding::Grounder;
use vlnav_planner::planner::Planner;
use vlnav_planner::validate::Validator;
use vlnav_proto::v1 as pb;

/// The largest message a case sends (the servers accept 64 MiB; mutations stay small).
const MAX_BYTES: usize = 1 << 20;

struct Ctx {
    planner: RefCell<Planner>,
    validator: Validator,
}

type Outcome = Result<(), String>;

fn refused<T>(e: impl std::fmt::Display) -> Result<T, String> {
    let msg = e.to_string();
    assert!(!msg.trim().is_empty(), "a refusal without a message");
    Err(msg)
}

/// The frame converters the stages run, and the gateway's check.
fn convert_frame(f: &pb::RgbdFrame) -> Outcome {
    let _ = vlnav_gateway::frames::check_frame(f, None).or_else(refused::<()>);
    let sensor = pb::SensorFrame { frame: Some(f.clone()), truth: None };
    let _ = vlnav_gateway::frames::CheckedFrame::check(sensor, None).or_else(refused);
    let cam = camera_from_proto(f.camera.as_ref(), "frame.camera", DepthDefaults { min_m: 0.3, max_m: 10.0 })
        .or_else(refused)?;
    depth_from_proto(f.depth.as_ref(), &cam, "frame.depth").or_else(refused)?;
    pose_from_proto(f.odom.as_ref(), "frame.odom").or_else(refused)?;
    if let Some(l) = &f.labels {
        label_ids_from_proto(l, cam.width, cam.height, "frame.labels").or_else(refused)?;
    }
    if let Some(img) = &f.rgb {
        encoded_image_from_proto(img).or_else(refused)?.decode().or_else(refused)?;
    }
    Ok(())
}

fn convert_images(images: &[pb::Image]) -> Outcome {
    for img in images.iter().take(4) {
        encoded_image_from_proto(img).or_else(refused)?.decode().or_else(refused)?;
    }
    Ok(())
}

fn convert_audio(format: i32, sample_rate: u32, data: &[u8]) -> Outcome {
    use vlnav_ingress::input::{AudioAssembler, Encoding};
    let encoding = match pb::AudioFormat::try_from(format) {
        Ok(pb::AudioFormat::Pcm16Mono) => Encoding::Pcm16Mono { sample_rate },
        Ok(pb::AudioFormat::Wav) => Encoding::Wav,
        _ => return refused("no usable audio format"),
    };
    let mut a = AudioAssembler::new(encoding, 30.0).or_else(refused)?;
    a.push(data).or_else(refused)?;
    a.finish(&vlnav_ingress::trim::TrimConfig::default()).or_else(refused)?;
    Ok(())
}

fn instruction(ctx: &Ctx, text: &str) -> Outcome {
    vlnav_ingress::grpc::normalize_request(text).or_else(refused)?;
    ctx.planner.borrow_mut().plan(text, "rules").or_else(refused)?;
    Ok(())
}

/// One request type: how to make valid ones, and what the service does with one.
struct Entry {
    name: &'static str,
    sample: fn(&mut Rng) -> Vec<u8>,
    check: fn(&[u8], &Ctx) -> Option<Outcome>,
}

macro_rules! entry {
    ($ty:ident, $sample:expr, $convert:expr) => {
        Entry {
            name: concat!("vlnav.v1.", stringify!($ty)),
            sample: |rng| {
                let make: fn(&mut Rng) -> pb::$ty = $sample;
                make(rng).encode_to_vec()
            },
            check: |bytes, ctx| {
                let convert: fn(pb::$ty, &Ctx) -> Outcome = $convert;
                pb::$ty::decode(bytes).ok().map(|m| convert(m, ctx))
            },
        }
    };
    ($ty:ident) => {
        entry!($ty, |_| pb::$ty::default(), |_, _| Ok(()))
    };
}

/// A valid frame or a structured corruption of one.
fn any_frame(rng: &mut Rng) -> pb::RgbdFrame {
    if rng.random_bool(0.5) { frames::small_valid_frame(rng) } else { frames::corrupt_frame(rng) }
}

fn text(rng: &mut Rng) -> String {
    const T: &[&str] = &["move 2 m ahead, then find the chair", "turn left", "follow the person for 10 seconds"];
    if rng.random_bool(0.5) { fuzz::mutate_text(rng, T, 4096) } else { fuzz::arbitrary_text(rng, 60) }
}

fn id(rng: &mut Rng) -> String {
    ["husky-1", "m-0001", "", "../../etc/passwd"][rng.random_range(0..4)].to_string()
}

fn pcm(rng: &mut Rng) -> (i32, u32, Vec<u8>) {
    let n = rng.random_range(0..4000);
    let format = fuzz::interesting_i32(rng, 2);
    let rate = if rng.random_bool(0.7) { 16000 } else { fuzz::interesting_u32(rng) };
    (format, rate, fuzz::random_bytes(rng, n))
}

fn plan(rng: &mut Rng) -> pb::ActionPlan {
    let n = rng.random_range(0..5);
    pb::ActionPlan {
        steps: (0..n)
            .map(|_| pb::ActionStep {
                action: fuzz::interesting_i32(rng, 4),
                f_dist: fuzz::plausible_f64(rng, -5.0, 20.0),
                yaw: fuzz::plausible_f64(rng, -3.2, 3.2),
                target: "chair".into(),
                class_id: fuzz::interesting_i32(rng, 79),
                ..Default::default()
            })
            .collect(),
    }
}

fn entries() -> Vec<Entry> {
    vec![
        entry!(
            DetectRequest,
            |rng| pb::DetectRequest {
                frame: Some(any_frame(rng)),
                class_ids: (0..rng.random_range(0..3)).map(|_| fuzz::interesting_i32(rng, 79)).collect(),
                min_score: fuzz::plausible_f64(rng, 0.0, 1.0) as f32,
            },
            |m, _| {
                vlnav_detector::grpc::filter_from_request(&m.class_ids, m.min_score, 0.25).or_else(refused)?;
                let frame = m.frame.unwrap_or_default();
                vlnav_detector::grpc::labels_input(&frame, true).or_else(refused)?;
                convert_frame(&frame)
            }
        ),
        entry!(GetModelInfoRequest),
        entry!(GetSegmenterInfoRequest),
        entry!(
            EdgeMessage,
            |rng| pb::EdgeMessage {
                kind: Some(match rng.random_range(0..4) {
                    0 => pb::edge_message::Kind::Hello(pb::EdgeHello {
                        robot_id: id(rng),
                        driver: "sim".into(),
                        camera: any_frame(rng).camera,
                        ..Default::default()
                    }),
                    1 => pb::edge_message::Kind::Odometry(pb::OdometryUpdate {
                        stamp: fuzz::plausible_f64(rng, 0.0, 100.0),
                        pose: any_frame(rng).odom,
                        twist: None,
                    }),
                    2 => pb::edge_message::Kind::Status(pb::EdgeStatus { detail: text(rng), ..Default::default() }),
                    _ => pb::edge_message::Kind::Frame(pb::SensorFrame { frame: Some(any_frame(rng)), truth: None }),
                }),
            },
            |m, _| match m.kind {
                Some(pb::edge_message::Kind::Frame(f)) => convert_frame(&f.frame.unwrap_or_default()),
                Some(pb::edge_message::Kind::Odometry(o)) => {
                    vlnav_gateway::frames::check_pose(0, &o.pose.unwrap_or_default()).or_else(refused)
                }
                Some(pb::edge_message::Kind::Hello(h)) => {
                    camera_from_proto(h.camera.as_ref(), "hello.camera", DepthDefaults::UNSET).or_else(refused)?;
                    Ok(())
                }
                _ => Ok(()),
            }
        ),
        entry!(ListRobotsRequest),
        entry!(
            AudioChunk,
            |rng| {
                let (format, sample_rate, data) = pcm(rng);
                pb::AudioChunk { format, sample_rate, data: data.into() }
            },
            |m, _| convert_audio(m.format, m.sample_rate, &m.data)
        ),
        entry!(NormalizeTextRequest, |rng| pb::NormalizeTextRequest { text: text(rng) }, |m, _| {
            vlnav_ingress::grpc::normalize_request(&m.text).map(|_| ()).or_else(refused)
        }),
        entry!(
            PlanStepRequest,
            |rng| pb::PlanStepRequest {
                robot_id: id(rng),
                frame: Some(any_frame(rng)),
                goal: Some(frames::goal(rng)),
                no_go_points: vec![pb::Point3 { x: fuzz::plausible_f64(rng, -5.0, 5.0), y: 0.0, z: 0.0 }],
                max_speed: fuzz::plausible_f64(rng, 0.0, 1.0),
                people: vec![pb::BoundingBox {
                    x_min: fuzz::plausible_f64(rng, 0.0, 640.0) as f32,
                    y_min: fuzz::plausible_f64(rng, 0.0, 480.0) as f32,
                    x_max: fuzz::plausible_f64(rng, 0.0, 640.0) as f32,
                    y_max: fuzz::plausible_f64(rng, 0.0, 480.0) as f32,
                    class_id: 0,
                    score: 0.8,
                    label: "person".into(),
                }],
            },
            |m, _| {
                vlnav_local_planner::grpc::step_request(m, DepthDefaults { min_m: 0.3, max_m: 10.0 })
                    .map(|_| ())
                    .or_else(refused)
            }
        ),
        entry!(ResetRobotRequest, |rng| pb::ResetRobotRequest { robot_id: id(rng) }, |_, _| Ok(())),
        entry!(
            SubmitMissionRequest,
            |rng| pb::SubmitMissionRequest {
                robot_id: id(rng),
                instruction: Some(if rng.random_bool(0.7) {
                    pb::submit_mission_request::Instruction::Text(text(rng))
                } else {
                    let (format, sample_rate, data) = pcm(rng);
                    pb::submit_mission_request::Instruction::Audio(pb::Audio { format, sample_rate, data: data.into() })
                }),
                dry_run: rng.random_bool(0.5),
            },
            |m, ctx| match m.instruction {
                Some(pb::submit_mission_request::Instruction::Text(t)) => instruction(ctx, &t),
                Some(pb::submit_mission_request::Instruction::Audio(a)) => {
                    convert_audio(a.format, a.sample_rate, &a.data)
                }
                None => refused("no instruction"),
            }
        ),
        entry!(WatchMissionRequest, |rng| pb::WatchMissionRequest { mission_id: id(rng) }, |_, _| Ok(())),
        entry!(GetMissionRequest, |rng| pb::GetMissionRequest { mission_id: id(rng) }, |_, _| Ok(())),
        entry!(
            ListMissionsRequest,
            |rng| pb::ListMissionsRequest { robot_id: id(rng), limit: fuzz::interesting_u32(rng) },
            |_, _| Ok(())
        ),
        entry!(CancelMissionRequest, |rng| pb::CancelMissionRequest { mission_id: id(rng) }, |_, _| Ok(())),
        entry!(
            AnswerClarificationRequest,
            |rng| pb::AnswerClarificationRequest { mission_id: id(rng), answer: text(rng) },
            |m, ctx| instruction(ctx, &m.answer)
        ),
        entry!(
            PlanRequest,
            |rng| pb::PlanRequest {
                instruction: text(rng),
                backend: ["", "rules", "gguf?"][rng.random_range(0..3)].into()
            },
            |m, ctx| instruction(ctx, &m.instruction)
        ),
        entry!(
            ReplanRequest,
            |rng| pb::ReplanRequest {
                instruction: text(rng),
                plan: Some(plan(rng)),
                failed_step: fuzz::interesting_u32(rng),
                failure: text(rng),
                answer: text(rng),
                backend: String::new(),
            },
            |m, ctx| {
                let plan = vlnav_planner::grpc::plan_from_proto(&m.plan.unwrap_or_default()).or_else(refused)?;
                ctx.planner
                    .borrow_mut()
                    .replan(&plan, m.failed_step as usize, &m.failure, &m.answer, "rules")
                    .or_else(refused)?;
                Ok(())
            }
        ),
        entry!(
            ValidatePlanRequest,
            |rng| {
                let p = vlnav_planner::grpc::plan_from_proto(&plan(rng))
                    .unwrap_or_else(|_| vlnav_planner::plan::Plan::new(vec![]));
                pb::ValidatePlanRequest { plan_json: p.to_json_string() }
            },
            |m, ctx| ctx.validator.validate_text(&m.plan_json).map(|_| ()).or_else(|e| refused(e.join("; ")))
        ),
        entry!(GetPlanSchemaRequest),
        entry!(
            EnrollPersonRequest,
            |rng| pb::EnrollPersonRequest {
                name: id(rng),
                images: (0..rng.random_range(0..3)).map(|_| any_frame(rng).rgb.unwrap_or_default()).collect(),
            },
            |m, _| convert_images(&m.images)
        ),
        entry!(
            IdentifyRequest,
            |rng| pb::IdentifyRequest {
                frame: Some(any_frame(rng)),
                boxes: vec![pb::BoundingBox { x_max: 4.0, y_max: 4.0, ..Default::default() }],
                threshold: fuzz::plausible_f64(rng, 0.0, 1.0) as f32,
                name: id(rng),
            },
            |m, _| convert_frame(&m.frame.unwrap_or_default())
        ),
        entry!(
            EmbedRequest,
            |rng| pb::EmbedRequest {
                images: (0..rng.random_range(0..3)).map(|_| any_frame(rng).rgb.unwrap_or_default()).collect(),
            },
            |m, _| convert_images(&m.images)
        ),
        entry!(ListGalleryRequest),
        entry!(RemovePersonRequest, |rng| pb::RemovePersonRequest { name: id(rng) }, |_, _| Ok(())),
        entry!(
            SegmentRequest,
            |rng| pb::SegmentRequest {
                frame: Some(any_frame(rng)),
                classes: vec!["chair".into()],
                return_mask: rng.random_bool(0.5),
                point_stride: fuzz::interesting_u32(rng),
            },
            |m, _| convert_frame(&m.frame.unwrap_or_default())
        ),
        entry!(
            MoveGoalRequest,
            |rng| pb::MoveGoalRequest {
                anchor: any_frame(rng).odom,
                f_dist: fuzz::plausible_f64(rng, -5.0, 10.0),
                yaw: fuzz::plausible_f64(rng, -3.2, 3.2),
                d_s: fuzz::plausible_f64(rng, 0.0, 2.0),
            },
            |m, _| pose_from_proto(m.anchor.as_ref(), "anchor").map(|_| ()).or_else(refused)
        ),
        entry!(
            TargetGoalRequest,
            |rng| pb::TargetGoalRequest {
                track_key: id(rng),
                frame: Some(any_frame(rng)),
                r#box: Some(pb::BoundingBox { x_max: 3.0, y_max: 3.0, ..Default::default() }),
                d_s: fuzz::plausible_f64(rng, 0.0, 2.0),
                moving: rng.random_bool(0.5),
            },
            |m, _| convert_frame(&m.frame.unwrap_or_default())
        ),
        entry!(ResetTrackRequest, |rng| pb::ResetTrackRequest { track_key: id(rng) }, |_, _| Ok(())),
    ]
}

/// Every method's request type, from the descriptor set.
fn request_types() -> Vec<String> {
    let fds = prost_types::FileDescriptorSet::decode(vlnav_proto::FILE_DESCRIPTOR_SET).expect("descriptor set");
    let mut types: Vec<String> = fds
        .file
        .iter()
        .flat_map(|f| f.service.iter())
        .flat_map(|s| s.method.iter())
        .map(|m| m.input_type().trim_start_matches('.').to_string())
        .collect();
    types.sort();
    types.dedup();
    types
}

#[test]
fn every_request_type_decodes_hostile_bytes_and_converts_without_a_panic() {
    let entries = entries();
    let known: Vec<&str> = entries.iter().map(|e| e.name).collect();
    let types = request_types();
    for t in &types {
        assert!(known.contains(&t.as_str()), "no fuzz entry for the request type {t}: add one to this test");
    }
    let ctx = Ctx {
        planner: RefCell::new(Planner::from_parts(Grounder::lexical_only(), None, None, Path::new("/nonexistent"))),
        validator: Validator::new(),
    };
    let mut per_type: BTreeMap<&str, [u64; 3]> = BTreeMap::new();
    let report = fuzz::run(
        "request decoding",
        4_000,
        |rng| {
            let k = rng.random_range(0..entries.len());
            let valid: Vec<Vec<u8>> = (0..2).map(|_| (entries[k].sample)(rng)).collect();
            let donors: Vec<&[u8]> = valid.iter().map(Vec::as_slice).collect();
            (k, fuzz::wire_bytes(rng, &donors, MAX_BYTES))
        },
        |(k, bytes)| {
            let e = &entries[*k];
            let outcome = (e.check)(bytes, &ctx);
            let slot = match &outcome {
                None => 0,
                Some(Ok(())) => 1,
                Some(Err(_)) => 2,
            };
            per_type.entry(e.name).or_default()[slot] += 1;
            match outcome {
                None => "undecodable",
                Some(Ok(())) => "decoded, accepted",
                Some(Err(_)) => "decoded, refused",
            }
            .into()
        },
    );
    eprintln!("per request type [undecodable, accepted, refused]:");
    for (name, counts) in &per_type {
        eprintln!("  {name}: {counts:?}");
    }
    report.assert_no_panics();
    assert!(report.count("decoded, accepted") > 0 && report.count("decoded, refused") > 0, "{report}");
}
