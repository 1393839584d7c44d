//! Proto ↔ domain at the edge of every service: the frame's pose, camera,
//! depth, colour image and labels, and the goal, each checked field by field.
//! A refusal is an [`InvalidField`] (or, for images, an
//! [`ImageError`](crate::rgb::ImageError)) that names the field and says what
//! was expected; every service maps it to `INVALID_ARGUMENT`.

use nalgebra::{Vector2, Vector3};
use vlnav_proto::v1 as pb;

use crate::camera::{Camera, Intrinsics, Mount};
use crate::depth::{DepthSizeError, DepthView, le_u16};
use crate::pose::{GoalSpec, Pose2};
use crate::rgb::{EncodedImage, Encoding, ImageError, MAX_SIDE};

/// A malformed field: which one and what was expected.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("invalid {field}: {reason}")]
pub struct InvalidField {
    pub field: String,
    pub reason: String,
}

impl InvalidField {
    pub fn new(field: impl Into<String>, reason: impl Into<String>) -> Self {
        Self { field: field.into(), reason: reason.into() }
    }
}

impl ImageError {
    /// This refusal as a malformed field of the `Image` message at `image`
    /// (e.g. `frame.rgb`, `images[2]`): its `.data`, its `.encoding`, or the
    /// image as a whole (its size).
    pub fn in_field(&self, image: &str) -> InvalidField {
        let field = match self {
            ImageError::WrongLength { .. } | ImageError::Decode { .. } => format!("{image}.data"),
            ImageError::Unspecified | ImageError::UnknownEncoding(_) => format!("{image}.encoding"),
            ImageError::MissingSize { .. } | ImageError::TooLarge { .. } | ImageError::SizeMismatch { .. } => {
                image.to_string()
            }
        };
        InvalidField::new(field, self.to_string())
    }
}

/// `v` if it is a finite number.
pub fn finite(field: &str, v: f64) -> Result<f64, InvalidField> {
    if v.is_finite() { Ok(v) } else { Err(InvalidField::new(field, format!("must be a finite number, got {v}"))) }
}

/// A required planar pose; every component must be finite.
pub fn pose_from_proto(p: Option<&pb::Pose2D>, field: &str) -> Result<Pose2, InvalidField> {
    let p = p.ok_or_else(|| InvalidField::new(field, "is required (x, y in metres, theta in radians)"))?;
    Ok(Pose2::new(
        finite(&format!("{field}.x"), p.x)?,
        finite(&format!("{field}.y"), p.y)?,
        finite(&format!("{field}.theta"), p.theta)?,
    ))
}

pub fn pose_to_proto(p: &Pose2) -> pb::Pose2D {
    pb::Pose2D { x: p.x, y: p.y, theta: p.theta }
}

/// A required goal: a finite pose, and a positive tolerance for what it asks
/// (heading for a pure rotation, position otherwise); the other tolerance is
/// clamped to ≥ 0.
pub fn goal_from_proto(g: Option<&pb::Goal>, field: &str) -> Result<GoalSpec, InvalidField> {
    let g =
        g.ok_or_else(|| InvalidField::new(field, "is required (odom pose and tolerances, from the subgoal service)"))?;
    let pose = pose_from_proto(g.pose.as_ref(), &format!("{field}.pose"))?;
    if g.rotation_only {
        if !(g.yaw_tolerance.is_finite() && g.yaw_tolerance > 0.0) {
            return Err(InvalidField::new(
                format!("{field}.yaw_tolerance"),
                format!("must be a positive angle in radians for a rotation, got {}", g.yaw_tolerance),
            ));
        }
    } else if !(g.position_tolerance.is_finite() && g.position_tolerance > 0.0) {
        return Err(InvalidField::new(
            format!("{field}.position_tolerance"),
            format!("must be a positive distance in metres, got {}", g.position_tolerance),
        ));
    }
    let landmark = match g.landmark.as_ref() {
        None => None,
        Some(l) if l.x.is_finite() && l.y.is_finite() => Some(Vector2::new(l.x, l.y)),
        Some(l) => {
            return Err(InvalidField::new(
                format!("{field}.landmark"),
                format!("must be a finite odom position in metres, got ({}, {})", l.x, l.y),
            ));
        }
    };
    Ok(GoalSpec {
        pose,
        position_tolerance: if g.position_tolerance.is_finite() { g.position_tolerance.max(0.0) } else { 0.0 },
        yaw_tolerance: if g.yaw_tolerance.is_finite() { g.yaw_tolerance.max(0.0) } else { 0.0 },
        rotation_only: g.rotation_only,
        landmark,
    })
}

pub fn goal_to_proto(g: &GoalSpec) -> pb::Goal {
    pb::Goal {
        pose: Some(pose_to_proto(&g.pose)),
        position_tolerance: g.position_tolerance,
        yaw_tolerance: g.yaw_tolerance,
        rotation_only: g.rotation_only,
        landmark: g.landmark.map(|l| pb::Point3 { x: l.x, y: l.y, z: 0.0 }),
    }
}

/// Depth bounds used when the frame's `CameraInfo` leaves them at 0 (or
/// below). A default ≤ 0 leaves that bound unset, which
/// [`Projector::valid_depth`](crate::camera::Projector::valid_depth) does
/// not enforce.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DepthDefaults {
    pub min_m: f64,
    pub max_m: f64,
}

impl DepthDefaults {
    /// Keep the frame's bounds; an unset one stays unset.
    pub const UNSET: DepthDefaults = DepthDefaults { min_m: 0.0, max_m: 0.0 };
}

/// `frame.camera` → [`Camera`]: size 1–[`MAX_SIDE`] a side, positive focal
/// lengths, finite numbers everywhere; a missing mount is a level camera at
/// the origin; depth bounds ≤ 0 take `defaults`, and when both bounds are set
/// the maximum must exceed the minimum.
pub fn camera_from_proto(
    info: Option<&pb::CameraInfo>,
    field: &str,
    defaults: DepthDefaults,
) -> Result<Camera, InvalidField> {
    let info = info.ok_or_else(|| InvalidField::new(field, "is required (size, intrinsics, mount, depth range)"))?;
    if info.width == 0 || info.height == 0 || info.width > MAX_SIDE || info.height > MAX_SIDE {
        return Err(InvalidField::new(
            format!("{field}.width/height"),
            format!("must be 1–{MAX_SIDE} pixels a side, got {}x{}", info.width, info.height),
        ));
    }
    let k = info
        .intrinsics
        .as_ref()
        .ok_or_else(|| InvalidField::new(format!("{field}.intrinsics"), "is required (fx, fy, cx, cy in pixels)"))?;
    for (name, v) in [("fx", k.fx), ("fy", k.fy)] {
        if !(v.is_finite() && v > 0.0) {
            return Err(InvalidField::new(
                format!("{field}.intrinsics.{name}"),
                format!("must be a positive focal length in pixels, got {v}"),
            ));
        }
    }
    let cx = finite(&format!("{field}.intrinsics.cx"), k.cx)?;
    let cy = finite(&format!("{field}.intrinsics.cy"), k.cy)?;
    let mount = match &info.mount {
        None => Mount::default(),
        Some(m) => {
            let t = m.translation.unwrap_or_default();
            let f = |n: &str, v: f64| finite(&format!("{field}.mount.{n}"), v);
            Mount {
                translation: Vector3::new(f("translation.x", t.x)?, f("translation.y", t.y)?, f("translation.z", t.z)?),
                roll: f("roll", m.roll)?,
                pitch: f("pitch", m.pitch)?,
                yaw: f("yaw", m.yaw)?,
            }
        }
    };
    let min = finite(&format!("{field}.depth_min_m"), info.depth_min_m)?;
    let max = finite(&format!("{field}.depth_max_m"), info.depth_max_m)?;
    let min = if min > 0.0 { min } else { defaults.min_m };
    let max = if max > 0.0 { max } else { defaults.max_m };
    if max > 0.0 && max <= min {
        return Err(InvalidField::new(
            format!("{field}.depth_max_m"),
            format!("must exceed depth_min_m ({min} m), got {max} m"),
        ));
    }
    Ok(Camera {
        width: info.width,
        height: info.height,
        intrinsics: Intrinsics { fx: k.fx, fy: k.fy, cx, cy },
        mount,
        depth_min_m: min,
        depth_max_m: max,
    })
}

/// [`Camera`] → `CameraInfo`, the inverse of [`camera_from_proto`].
pub fn camera_to_proto(c: &Camera) -> pb::CameraInfo {
    let (k, m) = (&c.intrinsics, &c.mount);
    pb::CameraInfo {
        width: c.width,
        height: c.height,
        intrinsics: Some(pb::CameraIntrinsics { fx: k.fx, fy: k.fy, cx: k.cx, cy: k.cy }),
        mount: Some(pb::CameraMount {
            translation: Some(pb::Point3 { x: m.translation.x, y: m.translation.y, z: m.translation.z }),
            roll: m.roll,
            pitch: m.pitch,
            yaw: m.yaw,
        }),
        depth_min_m: c.depth_min_m,
        depth_max_m: c.depth_max_m,
    }
}

/// The frame's depth image, checked against the camera size.
pub fn depth_from_proto<'a>(
    depth: Option<&'a pb::DepthImage>,
    cam: &Camera,
    field: &str,
) -> Result<DepthView<'a>, InvalidField> {
    let d =
        depth.ok_or_else(|| InvalidField::new(field, "is required (little-endian u16 millimetres, width × height)"))?;
    if d.encoding != pb::DepthEncoding::RawU16 as i32 {
        return Err(InvalidField::new(
            format!("{field}.encoding"),
            format!(
                "is {}; stages take raw u16 depth (only the link from a robot to the gateway carries RVL, and the gateway decodes it)",
                d.encoding
            ),
        ));
    }
    if d.width != cam.width || d.height != cam.height {
        return Err(InvalidField::new(
            format!("{field}.width/height"),
            format!(
                "must match the camera's {}x{} (depth aligned to colour), got {}x{}",
                cam.width, cam.height, d.width, d.height
            ),
        ));
    }
    DepthView::new(d.width, d.height, &d.data_mm)
        .map_err(|e: DepthSizeError| InvalidField::new(format!("{field}.data_mm"), e.to_string()))
}

/// A colour image ready for [`decode_off_thread`](crate::rgb::decode_off_thread):
/// the encoding must be one the decoder reads.
pub fn encoded_image_from_proto(img: &pb::Image) -> Result<EncodedImage, ImageError> {
    let encoding = match pb::ImageEncoding::try_from(img.encoding) {
        Ok(pb::ImageEncoding::Rgb8) => Encoding::Rgb8,
        Ok(pb::ImageEncoding::Png) => Encoding::Png,
        Ok(pb::ImageEncoding::Jpeg) => Encoding::Jpeg,
        Ok(pb::ImageEncoding::Unspecified) => return Err(ImageError::Unspecified),
        Err(_) => return Err(ImageError::UnknownEncoding(img.encoding)),
    };
    Ok(EncodedImage { encoding, width: img.width, height: img.height, data: img.data.clone() })
}

/// The per-pixel instance ids of a label image that must be `width`×`height`.
pub fn label_ids_from_proto(
    l: &pb::LabelImage,
    width: u32,
    height: u32,
    field: &str,
) -> Result<Vec<u16>, InvalidField> {
    if (l.width, l.height) != (width, height) {
        return Err(InvalidField::new(
            format!("{field}.width/height"),
            format!("must match the frame's {width}×{height}, got {}×{}", l.width, l.height),
        ));
    }
    // In u128: a declared size near u32::MAX a side overflows usize.
    let want = u128::from(width) * u128::from(height) * 2;
    if l.instance_ids.len() as u128 != want {
        return Err(InvalidField::new(
            format!("{field}.instance_ids"),
            format!("{width}×{height} little-endian u16 ids need {want} bytes, got {}", l.instance_ids.len()),
        ));
    }
    Ok(le_u16(&l.instance_ids))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::depth::encode_depth_mm;

    fn info() -> pb::CameraInfo {
        pb::CameraInfo {
            width: 4,
            height: 2,
            intrinsics: Some(pb::CameraIntrinsics { fx: 2.0, fy: 2.0, cx: 1.5, cy: 0.5 }),
            mount: Some(pb::CameraMount {
                translation: Some(pb::Point3 { x: 0.3, y: 0.0, z: 0.5 }),
                roll: 0.0,
                pitch: 0.1,
                yaw: 0.0,
            }),
            depth_min_m: 0.0,
            depth_max_m: 8.0,
        }
    }

    const DEFAULTS: DepthDefaults = DepthDefaults { min_m: 0.5, max_m: 10.0 };

    fn field_of<T: std::fmt::Debug>(r: Result<T, InvalidField>) -> String {
        r.unwrap_err().field
    }

    #[test]
    fn a_camera_info_becomes_the_camera_model_with_default_depth_bounds() {
        let cam = camera_from_proto(Some(&info()), "frame.camera", DEFAULTS).unwrap();
        assert_eq!((cam.width, cam.height, cam.depth_min_m, cam.depth_max_m), (4, 2, 0.5, 8.0));
        assert_eq!(cam.intrinsics, Intrinsics { fx: 2.0, fy: 2.0, cx: 1.5, cy: 0.5 });
        assert_eq!(cam.mount.translation, Vector3::new(0.3, 0.0, 0.5));
        assert_eq!(cam.mount.pitch, 0.1);
        assert_eq!(camera_from_proto(Some(&camera_to_proto(&cam)), "c", DEFAULTS).unwrap(), cam);
        // Unset bounds stay unset with DepthDefaults::UNSET (the projector then enforces neither).
        let open = pb::CameraInfo { depth_max_m: 0.0, mount: None, ..info() };
        let cam = camera_from_proto(Some(&open), "c", DepthDefaults::UNSET).unwrap();
        assert_eq!((cam.depth_min_m, cam.depth_max_m, cam.mount), (0.0, 0.0, Mount::default()));
    }

    #[test]
    fn a_bad_camera_info_names_the_field() {
        let f = |i: pb::CameraInfo| field_of(camera_from_proto(Some(&i), "frame.camera", DEFAULTS));
        assert_eq!(field_of(camera_from_proto(None, "frame.camera", DEFAULTS)), "frame.camera");
        assert_eq!(f(pb::CameraInfo { width: 0, ..info() }), "frame.camera.width/height");
        assert_eq!(f(pb::CameraInfo { height: MAX_SIDE + 1, ..info() }), "frame.camera.width/height");
        assert_eq!(f(pb::CameraInfo { intrinsics: None, ..info() }), "frame.camera.intrinsics");
        let mut i = info();
        i.intrinsics.as_mut().unwrap().fy = -1.0;
        assert_eq!(f(i), "frame.camera.intrinsics.fy");
        let mut i = info();
        i.intrinsics.as_mut().unwrap().cx = f64::NAN;
        assert_eq!(f(i), "frame.camera.intrinsics.cx");
        let mut i = info();
        i.mount.as_mut().unwrap().yaw = f64::INFINITY;
        assert_eq!(f(i), "frame.camera.mount.yaw");
        assert_eq!(f(pb::CameraInfo { depth_min_m: f64::NAN, ..info() }), "frame.camera.depth_min_m");
        assert_eq!(f(pb::CameraInfo { depth_min_m: 9.0, ..info() }), "frame.camera.depth_max_m");
    }

    #[test]
    fn depth_must_match_the_camera() {
        let cam = camera_from_proto(Some(&info()), "frame.camera", DEFAULTS).unwrap();
        let d = pb::DepthImage {
            width: 4,
            height: 2,
            data_mm: encode_depth_mm(&[1.0; 8]).into(),
            encoding: 0,
            disparity_step: 0.0,
        };
        assert_eq!(depth_from_proto(Some(&d), &cam, "frame.depth").unwrap().mm(3, 1), 1000);
        assert_eq!(field_of(depth_from_proto(None, &cam, "frame.depth")), "frame.depth");
        let wide = pb::DepthImage { width: 8, height: 1, ..d.clone() };
        assert_eq!(field_of(depth_from_proto(Some(&wide), &cam, "frame.depth")), "frame.depth.width/height");
        let short = pb::DepthImage { data_mm: vec![0; 15].into(), ..d };
        assert_eq!(field_of(depth_from_proto(Some(&short), &cam, "frame.depth")), "frame.depth.data_mm");
    }

    #[test]
    fn poses_and_goals_round_trip_and_refuse_non_finite_numbers() {
        let p = Pose2::new(1.0, -2.0, 0.5);
        assert_eq!(pose_from_proto(Some(&pose_to_proto(&p)), "anchor").unwrap(), p);
        let bad = pb::Pose2D { theta: f64::NAN, ..pose_to_proto(&p) };
        assert_eq!(field_of(pose_from_proto(Some(&bad), "anchor")), "anchor.theta");
        assert_eq!(field_of(pose_from_proto(None, "anchor")), "anchor");
        let g = GoalSpec { pose: p, position_tolerance: 0.3, yaw_tolerance: 0.2, rotation_only: false, landmark: None };
        assert_eq!(goal_from_proto(Some(&goal_to_proto(&g)), "goal").unwrap(), g);
        let at = GoalSpec { landmark: Some(Vector2::new(2.0, -1.0)), ..g };
        assert_eq!(goal_from_proto(Some(&goal_to_proto(&at)), "goal").unwrap(), at);
        let lost = pb::Goal { landmark: Some(pb::Point3 { x: f64::INFINITY, y: 0.0, z: 0.0 }), ..goal_to_proto(&g) };
        assert_eq!(field_of(goal_from_proto(Some(&lost), "goal")), "goal.landmark");
        let no_tol = pb::Goal { position_tolerance: 0.0, ..goal_to_proto(&g) };
        assert_eq!(field_of(goal_from_proto(Some(&no_tol), "goal")), "goal.position_tolerance");
        let turn = pb::Goal { rotation_only: true, yaw_tolerance: f64::NAN, ..goal_to_proto(&g) };
        assert_eq!(field_of(goal_from_proto(Some(&turn), "goal")), "goal.yaw_tolerance");
    }

    #[test]
    fn image_encodings_and_label_sizes_are_checked() {
        let img =
            pb::Image { width: 1, height: 1, encoding: pb::ImageEncoding::Rgb8 as i32, data: vec![1, 2, 3].into() };
        assert_eq!(encoded_image_from_proto(&img).unwrap().decode().unwrap().into_raw(), vec![1, 2, 3]);
        let unset = pb::Image { encoding: pb::ImageEncoding::Unspecified as i32, ..img.clone() };
        assert_eq!(encoded_image_from_proto(&unset).unwrap_err(), ImageError::Unspecified);
        let odd = pb::Image { encoding: 77, ..img.clone() };
        assert_eq!(encoded_image_from_proto(&odd).unwrap_err(), ImageError::UnknownEncoding(77));
        assert_eq!(ImageError::UnknownEncoding(77).in_field("images[1]").field, "images[1].encoding");
        let e = encoded_image_from_proto(&pb::Image { data: vec![1].into(), ..img }).unwrap().decode().unwrap_err();
        let f = e.in_field("frame.rgb");
        assert_eq!(f.field, "frame.rgb.data");
        assert!(f.to_string().starts_with("invalid frame.rgb.data: RGB8 data has 1 bytes"), "{f}");

        let l = pb::LabelImage { width: 2, height: 1, instance_ids: vec![1, 0, 2, 1].into(), instances: vec![] };
        assert_eq!(label_ids_from_proto(&l, 2, 1, "frame.labels").unwrap(), vec![1, 258]);
        assert_eq!(field_of(label_ids_from_proto(&l, 1, 2, "frame.labels")), "frame.labels.width/height");
        let short = pb::LabelImage { instance_ids: vec![1].into(), ..l };
        assert_eq!(field_of(label_ids_from_proto(&short, 2, 1, "frame.labels")), "frame.labels.instance_ids");
        // A declared size whose byte count overflows is refused, not a panic.
        let huge = pb::LabelImage { width: u32::MAX, height: u32::MAX, ..short };
        let e = label_ids_from_proto(&huge, u32::MAX, u32::MAX, "frame.labels").unwrap_err();
        assert!(e.reason.contains("36893488130239234050 bytes"), "{e}");
    }
}
