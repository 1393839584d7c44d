//! Conversions between the drivers' plain types and the `vlnav.v1` messages.

use std::borrow::Cow;

use vlnav_geometry::convert::pose_to_proto;
use vlnav_proto::v1 as pb;
use vlnav_sim::camera::CameraConfig;
use vlnav_sim::{Frame, Pose2, Truth, Twist};

use crate::safety::Limits;
use crate::{Codecs, ColourCodec, DepthCodec};

/// The robot description sent in `EdgeHello`.
#[derive(Clone, Debug, PartialEq)]
pub struct RobotDescription {
    pub limits: Limits,
    pub footprint_length: f64,
    pub footprint_width: f64,
}

pub fn twist(t: &Twist) -> pb::Twist2D {
    pb::Twist2D { linear: t.linear, angular: t.angular }
}

pub fn limits(d: &RobotDescription) -> pb::RobotLimits {
    pb::RobotLimits {
        max_linear: d.limits.max_linear,
        max_angular: d.limits.max_angular,
        max_linear_accel: d.limits.max_linear_accel,
        max_angular_accel: d.limits.max_angular_accel,
        footprint_length: d.footprint_length,
        footprint_width: d.footprint_width,
    }
}

/// Camera info of the simulated camera.
pub fn sim_camera_info(c: &CameraConfig) -> pb::CameraInfo {
    pb::CameraInfo {
        width: c.width,
        height: c.height,
        intrinsics: Some(pb::CameraIntrinsics { fx: c.fx, fy: c.fy, cx: c.cx, cy: c.cy }),
        mount: Some(pb::CameraMount {
            translation: Some(pb::Point3 { x: c.mount[0], y: c.mount[1], z: c.mount[2] }),
            roll: 0.0,
            pitch: 0.0,
            yaw: c.mount_yaw,
        }),
        depth_min_m: c.depth_min_m,
        depth_max_m: c.depth_max_m,
    }
}

/// Little-endian bytes of a u16 image.
pub fn u16_le(data: &[u16]) -> Vec<u8> {
    let mut out = Vec::with_capacity(data.len() * 2);
    for v in data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

/// Everything an `RgbdFrame` carries besides the images.
#[derive(Clone, Debug)]
pub struct FrameMeta<'a> {
    pub robot_id: &'a str,
    pub seq: u64,
    pub stamp: f64,
    pub camera: pb::CameraInfo,
    pub odom: Pose2,
    pub odom_twist: Twist,
    pub codecs: Codecs,
}

/// A depth image of `width`×`height` millimetres (0: no return) as
/// `codecs.depth` sends it. A disparity step the codec refuses (the agent's
/// options are checked at start, so only a step set in code) sends raw depth,
/// with a warning: a frame sent larger keeps the robot driven.
pub fn depth_image(width: u32, height: u32, depth_mm: &[u16], codecs: Codecs) -> pb::DepthImage {
    let step = codecs.disparity_step;
    let (data_mm, encoding, disparity_step) = match codecs.depth {
        DepthCodec::Raw => (u16_le(depth_mm), pb::DepthEncoding::RawU16, 0.0),
        DepthCodec::Rvl => (vlnav_geometry::rvl::encode(depth_mm), pb::DepthEncoding::Rvl, 0.0),
        DepthCodec::Disparity => match vlnav_geometry::disparity::encode(depth_mm, width as usize, step) {
            Ok(data) => (data, pb::DepthEncoding::Disparity, step),
            Err(e) => {
                tracing::warn!("depth sent raw: {e}");
                (u16_le(depth_mm), pb::DepthEncoding::RawU16, 0.0)
            }
        },
    };
    pb::DepthImage { width, height, data_mm: data_mm.into(), encoding: encoding as i32, disparity_step }
}

/// A colour image of `width`×`height` 8-bit RGB as `codecs` sends it. If
/// the JPEG encoder refuses it (it cannot, at a size the gateway accepts,
/// with the length the drivers check) it goes raw, with a warning: a frame
/// sent larger keeps the robot driven, where a frame not sent would stop it.
pub fn colour_image(width: u32, height: u32, rgb: Cow<'_, [u8]>, codecs: Codecs) -> pb::Image {
    let raw = |rgb: Cow<'_, [u8]>| pb::Image {
        width,
        height,
        encoding: pb::ImageEncoding::Rgb8 as i32,
        data: rgb.into_owned().into(),
    };
    match codecs.colour {
        ColourCodec::Raw => raw(rgb),
        ColourCodec::Jpeg => match vlnav_geometry::rgb::encode_jpeg(width, height, &rgb, codecs.jpeg_quality) {
            Ok(jpeg) => pb::Image { width, height, encoding: pb::ImageEncoding::Jpeg as i32, data: jpeg.into() },
            Err(e) => {
                tracing::warn!("colour sent raw: {e}");
                raw(rgb)
            }
        },
    }
}

/// Bytes of a frame's images as sent (colour and depth): what a real
/// robot's frame carries, without the simulator's labels.
pub fn image_bytes(f: &pb::RgbdFrame) -> usize {
    f.rgb.as_ref().map_or(0, |i| i.data.len()) + f.depth.as_ref().map_or(0, |d| d.data_mm.len())
}

/// A rendered simulator frame as an `RgbdFrame` (with its label image).
pub fn sim_frame(meta: FrameMeta<'_>, f: &Frame) -> pb::RgbdFrame {
    pb::RgbdFrame {
        robot_id: meta.robot_id.to_string(),
        seq: meta.seq,
        stamp: meta.stamp,
        camera: Some(meta.camera),
        rgb: Some(colour_image(f.width, f.height, Cow::Borrowed(&f.rgb), meta.codecs)),
        depth: Some(depth_image(f.width, f.height, &f.depth_mm, meta.codecs)),
        odom: Some(pose_to_proto(&meta.odom)),
        odom_twist: Some(twist(&meta.odom_twist)),
        labels: Some(pb::LabelImage {
            width: f.width,
            height: f.height,
            instance_ids: u16_le(&f.labels).into(),
            instances: f
                .instances
                .iter()
                .enumerate()
                .map(|(i, e)| pb::LabelInstance {
                    instance_id: e.instance_id as u32,
                    class_id: e.class_id,
                    identity: e.identity.clone(),
                    semantic: e.semantic.as_str().to_string(),
                    visible_fraction: f.visible_fraction.get(i).copied().unwrap_or(1.0),
                })
                .collect(),
        }),
    }
}

pub fn sim_truth(t: &Truth) -> pb::SimTruth {
    pb::SimTruth {
        pose: Some(pose_to_proto(&t.pose)),
        path_length_m: t.path_length_m,
        hard_collisions: t.hard_collisions,
        soft_collisions: t.soft_collisions,
        odom_origin: Some(pose_to_proto(&t.odom_origin)),
    }
}

pub fn edge(kind: pb::edge_message::Kind) -> pb::EdgeMessage {
    pb::EdgeMessage { kind: Some(kind) }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A first frame's metadata for `sim`'s camera, standing at the origin.
    fn meta_for(sim: &vlnav_sim::Simulator, codecs: Codecs) -> FrameMeta<'static> {
        FrameMeta {
            robot_id: "husky-1",
            seq: 0,
            stamp: 0.0,
            camera: sim_camera_info(sim.camera()),
            odom: Pose2::default(),
            odom_twist: Twist::ZERO,
            codecs,
        }
    }

    #[test]
    fn u16_images_are_little_endian() {
        assert_eq!(u16_le(&[0x0102, 0xa0b0]), vec![0x02, 0x01, 0xb0, 0xa0]);
    }

    #[test]
    fn a_rendered_frame_converts_with_its_label_table() {
        let world = vlnav_sim::load_scenario("demo").unwrap();
        let mut sim = vlnav_sim::Simulator::new(world, 0);
        sim.set_camera(sim.camera().clone().with_resolution(64, 48).unwrap());
        let f = sim.render();
        let meta = FrameMeta { seq: 3, stamp: 0.3, ..meta_for(&sim, Codecs::default()) };
        let m = sim_frame(meta.clone(), &f);
        let rgb = m.rgb.unwrap();
        assert_eq!((rgb.width, rgb.height, rgb.data.len()), (64, 48, 64 * 48 * 3));
        assert_eq!(m.depth.unwrap().data_mm.len(), 64 * 48 * 2);
        // RVL carries the same millimetres in fewer bytes.
        let rvl_codecs = Codecs { depth: DepthCodec::Rvl, ..Codecs::default() };
        let rvl = sim_frame(FrameMeta { codecs: rvl_codecs, ..meta.clone() }, &f).depth.unwrap();
        assert_eq!(rvl.encoding, pb::DepthEncoding::Rvl as i32);
        assert!(rvl.data_mm.len() < 64 * 48 * 2);
        assert_eq!(vlnav_geometry::rvl::decode(&rvl.data_mm, 64 * 48).unwrap(), f.depth_mm);
        // Quantised disparity carries the step it was written with, and
        // every pixel within its bound, in fewer bytes still.
        let step = 0.01;
        let q_codecs = Codecs { depth: DepthCodec::Disparity, disparity_step: step, ..Codecs::default() };
        let q = sim_frame(FrameMeta { codecs: q_codecs, ..meta }, &f).depth.unwrap();
        assert_eq!((q.encoding, q.disparity_step), (pb::DepthEncoding::Disparity as i32, step));
        assert!(q.data_mm.len() < rvl.data_mm.len(), "{} against RVL's {}", q.data_mm.len(), rvl.data_mm.len());
        let back = vlnav_geometry::disparity::decode(&q.data_mm, 64, 48, step).unwrap();
        for (d, b) in f.depth_mm.iter().zip(back) {
            assert!((*d as f64 - b as f64).abs() <= vlnav_geometry::disparity::max_error_mm(*d, step), "{d} -> {b}");
        }
        let labels = m.labels.unwrap();
        assert_eq!(labels.instance_ids.len(), 64 * 48 * 2);
        assert!(labels.instances.iter().any(|i| i.semantic == "floor" && i.class_id == -1));
        let cam = m.camera.unwrap();
        assert!((cam.intrinsics.unwrap().fx - 343.159 / 10.0).abs() < 1e-9);
        assert!((cam.mount.unwrap().translation.unwrap().z - 0.6).abs() < 1e-12);
    }

    #[test]
    fn jpeg_colour_is_a_small_share_of_raw_and_decodes_to_the_frame_within_a_bounded_error() {
        let world = vlnav_sim::load_scenario("lab").unwrap();
        let mut sim = vlnav_sim::Simulator::new(world, 0);
        let f = sim.render();
        let (w, h) = (f.width, f.height);
        assert_eq!((w, h), (640, 480));
        let codecs =
            Codecs { colour: ColourCodec::Jpeg, jpeg_quality: 85, depth: DepthCodec::Rvl, ..Codecs::default() };
        let meta = meta_for(&sim, codecs);
        let m = sim_frame(meta, &f);
        let rgb = m.rgb.as_ref().unwrap();
        assert_eq!((rgb.encoding, rgb.width, rgb.height), (pb::ImageEncoding::Jpeg as i32, w, h));
        assert!(rgb.data.len() * 10 < f.rgb.len(), "{} bytes of JPEG", rgb.data.len());
        assert!(image_bytes(&m) * 3 < f.rgb.len() + f.depth_mm.len() * 2, "{} bytes", image_bytes(&m));
        // The stages' decoder gives back the rendered picture.
        let img = vlnav_geometry::convert::encoded_image_from_proto(rgb).unwrap().decode().unwrap();
        assert_eq!(img.dimensions(), (w, h));
        let errors: Vec<u8> = f.rgb.iter().zip(img.as_raw()).map(|(a, b)| a.abs_diff(*b)).collect();
        let mean = errors.iter().map(|e| f64::from(*e)).sum::<f64>() / errors.len() as f64;
        assert!(mean < 3.0, "mean error {mean:.2}");
    }

    #[test]
    fn colour_the_encoder_refuses_goes_raw() {
        let jpeg = Codecs { colour: ColourCodec::Jpeg, ..Codecs::default() };
        // A buffer one byte short (no driver sends one): raw, as it came, rather than a panic.
        let img = colour_image(2, 2, Cow::Owned(vec![7; 11]), jpeg);
        assert_eq!((img.encoding, img.data.len()), (pb::ImageEncoding::Rgb8 as i32, 11));
        let img = colour_image(2, 2, Cow::Owned(vec![7; 12]), jpeg);
        assert_eq!(img.encoding, pb::ImageEncoding::Jpeg as i32);
        let raw = colour_image(2, 2, Cow::Owned(vec![7; 12]), Codecs::default());
        assert_eq!((raw.encoding, raw.data.len()), (pb::ImageEncoding::Rgb8 as i32, 12));
    }
}
