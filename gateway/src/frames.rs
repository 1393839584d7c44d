//! Checks of what an edge agent sends, before anything acts on it. A frame
//! is checked once, where it enters the gateway (`link.rs`), into a
//! [`CheckedFrame`]: the robot's actor, the executor and the live view take
//! only that type, so none of them checks a frame again.

use vlnav_geometry::camera::Camera;
use vlnav_geometry::rgb::{Encoding, header_size};
use vlnav_proto::v1::{DepthEncoding, ImageEncoding, Pose2D, RgbdFrame, SensorFrame, SimTruth};

/// Largest accepted image side, pixels.
pub const MAX_SIDE: u32 = 4096;

/// Why a frame (or an odometry update) was refused; each names the frame's
/// `seq` and says what was expected.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum FrameError {
    /// A part the gateway needs is absent.
    #[error("frame {seq}: {field} is missing")]
    Missing {
        /// The frame's sequence number.
        seq: u64,
        /// The absent field.
        field: &'static str,
    },
    /// A number is NaN or infinite.
    #[error("frame {seq}: {field} is not a finite number ({value})")]
    NotFinite {
        /// The frame's sequence number.
        seq: u64,
        /// The field.
        field: &'static str,
        /// Its value.
        value: f64,
    },
    /// Sizes, encodings or the camera model do not add up.
    #[error("frame {seq}: {what}")]
    Invalid {
        /// The frame's sequence number.
        seq: u64,
        /// What is wrong and what was expected.
        what: String,
    },
    /// Sensor time went backwards.
    #[error(
        "frame {seq}: stamp {stamp} s is older than the previous frame's {previous} s; sensor time must not go backwards"
    )]
    StampBackwards {
        /// The frame's sequence number.
        seq: u64,
        /// Its stamp, seconds.
        stamp: f64,
        /// The previous frame's stamp, seconds.
        previous: f64,
    },
}

fn finite(seq: u64, field: &'static str, value: f64) -> Result<(), FrameError> {
    if value.is_finite() { Ok(()) } else { Err(FrameError::NotFinite { seq, field, value }) }
}

/// Checks a pose for non-finite values.
pub fn check_pose(seq: u64, pose: &Pose2D) -> Result<(), FrameError> {
    finite(seq, "odom.x", pose.x)?;
    finite(seq, "odom.y", pose.y)?;
    finite(seq, "odom.theta", pose.theta)
}

/// Whether the frame's depth needs [`decode_depth`] (anything but raw).
pub(crate) fn is_encoded(frame: &RgbdFrame) -> bool {
    frame.depth.as_ref().is_some_and(|d| d.encoding != DepthEncoding::RawU16 as i32)
}

/// Decodes depth compressed on the robot's link (RVL or quantised
/// disparity, docs/architecture.md "Frames") in place, so that everything
/// past the gateway reads raw u16 millimetres. The declared size bounds what
/// is decoded, whatever the stream says.
pub(crate) fn decode_depth(frame: &mut RgbdFrame) -> Result<(), FrameError> {
    let seq = frame.seq;
    let Some(depth) = frame.depth.as_mut() else { return Ok(()) };
    let (w, h) = (depth.width, depth.height);
    let size = || {
        if w == 0 || h == 0 || w > MAX_SIDE || h > MAX_SIDE {
            Err(FrameError::Invalid {
                seq,
                what: format!("depth size {w}x{h} is outside 1..={MAX_SIDE} pixels per side"),
            })
        } else {
            Ok((w as usize, h as usize))
        }
    };
    let raw = match DepthEncoding::try_from(depth.encoding) {
        Ok(DepthEncoding::RawU16) => return Ok(()),
        Ok(DepthEncoding::Rvl) => {
            let (w, h) = size()?;
            vlnav_geometry::rvl::decode_le_bytes(&depth.data_mm, w * h)
                .map_err(|e| FrameError::Invalid { seq, what: format!("depth (RVL): {e}") })?
        }
        Ok(DepthEncoding::Disparity) => {
            let (w, h) = size()?;
            vlnav_geometry::disparity::decode_le_bytes(&depth.data_mm, w, h, depth.disparity_step)
                .map_err(|e| FrameError::Invalid { seq, what: format!("depth (quantised disparity): {e}") })?
        }
        Err(_) => {
            return Err(FrameError::Invalid {
                seq,
                what: format!(
                    "depth encoding {} is unknown (0: raw u16 millimetres, 1: RVL, 2: quantised disparity)",
                    depth.encoding
                ),
            });
        }
    };
    depth.data_mm = raw.into();
    depth.encoding = DepthEncoding::RawU16 as i32;
    depth.disparity_step = 0.0;
    Ok(())
}

/// A sensor frame that passed [`check_frame`] (its depth decoded first,
/// [`decode_depth`]), with the camera model the check read from it.
#[derive(Clone, Debug)]
pub struct CheckedFrame {
    frame: RgbdFrame,
    truth: Option<SimTruth>,
    camera: Camera,
}

impl CheckedFrame {
    /// Checks `sensor`'s frame as [`check_frame`] does; a message without a
    /// frame is refused as missing one.
    pub fn check(sensor: SensorFrame, previous_stamp: Option<f64>) -> Result<Self, FrameError> {
        let SensorFrame { frame, truth } = sensor;
        let frame = frame.ok_or(FrameError::Missing { seq: 0, field: "frame" })?;
        let camera = check(&frame, previous_stamp)?;
        Ok(Self { frame, truth, camera })
    }

    /// The checked frame.
    pub fn frame(&self) -> &RgbdFrame {
        &self.frame
    }

    /// The simulator's ground truth sent with the frame, if any (not checked:
    /// it is read only for the evaluation's metrics).
    pub(crate) fn truth(&self) -> Option<&SimTruth> {
        self.truth.as_ref()
    }

    /// The frame's camera model, as every stage reads it.
    pub fn camera(&self) -> &Camera {
        &self.camera
    }

    /// The message as the robot sent it (depth decoded).
    pub(crate) fn into_sensor(self) -> SensorFrame {
        SensorFrame { frame: Some(self.frame), truth: self.truth }
    }
}

/// Validates a sensor frame: camera model, image sizes against the camera,
/// finite pose and velocity, and a stamp not older than `previous_stamp`.
pub fn check_frame(frame: &RgbdFrame, previous_stamp: Option<f64>) -> Result<(), FrameError> {
    check(frame, previous_stamp).map(|_| ())
}

/// [`check_frame`], returning the camera model it read.
fn check(frame: &RgbdFrame, previous_stamp: Option<f64>) -> Result<Camera, FrameError> {
    let seq = frame.seq;
    finite(seq, "stamp", frame.stamp)?;
    if frame.stamp < 0.0 {
        return Err(FrameError::Invalid { seq, what: format!("stamp {} s is negative", frame.stamp) });
    }
    if let Some(previous) = previous_stamp
        && frame.stamp < previous
    {
        return Err(FrameError::StampBackwards { seq, stamp: frame.stamp, previous });
    }
    let pose = frame.odom.as_ref().ok_or(FrameError::Missing { seq, field: "odom" })?;
    check_pose(seq, pose)?;
    if let Some(t) = &frame.odom_twist {
        finite(seq, "odom_twist.linear", t.linear)?;
        finite(seq, "odom_twist.angular", t.angular)?;
    }
    let cam = frame.camera.as_ref().ok_or(FrameError::Missing { seq, field: "camera" })?;
    let (w, h) = (cam.width, cam.height);
    if w == 0 || h == 0 || w > MAX_SIDE || h > MAX_SIDE {
        return Err(FrameError::Invalid {
            seq,
            what: format!("camera size {w}x{h} is outside 1..={MAX_SIDE} pixels per side"),
        });
    }
    let k = cam.intrinsics.as_ref().ok_or(FrameError::Missing { seq, field: "camera.intrinsics" })?;
    for (field, v) in [("camera.intrinsics.fx", k.fx), ("camera.intrinsics.fy", k.fy)] {
        finite(seq, field, v)?;
        if v <= 0.0 {
            return Err(FrameError::Invalid { seq, what: format!("{field} = {v} must be positive") });
        }
    }
    finite(seq, "camera.intrinsics.cx", k.cx)?;
    finite(seq, "camera.intrinsics.cy", k.cy)?;
    // The rest of the camera model (mount, depth range) as the executor and every stage read
    // it: a frame accepted here has a camera they accept.
    let camera =
        vlnav_geometry::convert::camera_from_proto(Some(cam), "camera", vlnav_geometry::convert::DepthDefaults::UNSET)
            .map_err(|e| FrameError::Invalid { seq, what: e.to_string() })?;
    let pixels = w as usize * h as usize;
    let depth = frame.depth.as_ref().ok_or(FrameError::Missing { seq, field: "depth" })?;
    if depth.encoding != DepthEncoding::RawU16 as i32 {
        return Err(FrameError::Invalid {
            seq,
            what: "depth must be decoded (decode_depth) before it is checked".into(),
        });
    }
    if depth.width != w || depth.height != h || depth.data_mm.len() != pixels * 2 {
        return Err(FrameError::Invalid {
            seq,
            what: format!(
                "depth is {}x{} with {} bytes; the camera is {w}x{h}, so {} bytes of u16 millimetres are expected",
                depth.width,
                depth.height,
                depth.data_mm.len(),
                pixels * 2
            ),
        });
    }
    if let Some(rgb) = &frame.rgb {
        match ImageEncoding::try_from(rgb.encoding) {
            Ok(ImageEncoding::Rgb8) => {
                if rgb.width != w || rgb.height != h || rgb.data.len() != pixels * 3 {
                    return Err(FrameError::Invalid {
                        seq,
                        what: format!(
                            "rgb is {}x{} with {} bytes; the camera is {w}x{h}, so {} bytes of RGB8 are expected",
                            rgb.width,
                            rgb.height,
                            rgb.data.len(),
                            pixels * 3
                        ),
                    });
                }
            }
            Ok(enc @ (ImageEncoding::Png | ImageEncoding::Jpeg)) => {
                // Passed on encoded: each stage decodes it (vlnav_geometry::rgb). Here only the
                // size its header declares is read (no pixels decoded), so that an image that
                // cannot be the camera's is refused where it enters, not by every stage.
                let (encoding, format) =
                    if enc == ImageEncoding::Png { (Encoding::Png, "PNG") } else { (Encoding::Jpeg, "JPEG") };
                let declared = header_size(encoding, &rgb.data)
                    .map_err(|e| FrameError::Invalid { seq, what: format!("rgb: {e}") })?
                    .unwrap_or_default();
                let fits = |side: u32, camera: u32| side == 0 || side == camera;
                if declared != (w, h) || !fits(rgb.width, w) || !fits(rgb.height, h) {
                    return Err(FrameError::Invalid {
                        seq,
                        what: format!(
                            "rgb is a {format} of {}x{} (declared {}x{}); the camera is {w}x{h}, so the image \
                             must be {w}x{h}",
                            declared.0, declared.1, rgb.width, rgb.height
                        ),
                    });
                }
            }
            _ => {
                return Err(FrameError::Invalid {
                    seq,
                    what: format!(
                        "rgb encoding {} with {} bytes is not a usable image (RGB8, PNG or JPEG)",
                        rgb.encoding,
                        rgb.data.len()
                    ),
                });
            }
        }
    }
    if let Some(labels) = &frame.labels
        && (labels.width != w || labels.height != h || labels.instance_ids.len() != pixels * 2)
    {
        return Err(FrameError::Invalid {
            seq,
            what: format!(
                "labels are {}x{} with {} bytes; the camera is {w}x{h}, so {} bytes of u16 ids are expected",
                labels.width,
                labels.height,
                labels.instance_ids.len(),
                pixels * 2
            ),
        });
    }
    Ok(camera)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use vlnav_proto::v1::{CameraInfo, CameraIntrinsics, DepthImage, Image};

    pub(crate) fn frame(w: u32, h: u32) -> RgbdFrame {
        RgbdFrame {
            robot_id: "husky-1".into(),
            seq: 7,
            stamp: 1.5,
            camera: Some(CameraInfo {
                width: w,
                height: h,
                intrinsics: Some(CameraIntrinsics { fx: 343.159, fy: 343.159, cx: 320.5, cy: 240.5 }),
                mount: None,
                depth_min_m: 0.3,
                depth_max_m: 10.0,
            }),
            rgb: Some(Image {
                width: w,
                height: h,
                encoding: ImageEncoding::Rgb8 as i32,
                data: vec![0; (w * h * 3) as usize].into(),
            }),
            depth: Some(DepthImage {
                width: w,
                height: h,
                data_mm: vec![0; (w * h * 2) as usize].into(),
                encoding: 0,
                disparity_step: 0.0,
            }),
            odom: Some(Pose2D { x: 0.0, y: 0.0, theta: 0.0 }),
            odom_twist: None,
            labels: None,
        }
    }

    #[test]
    fn a_well_formed_frame_passes() {
        assert_eq!(check_frame(&frame(64, 48), Some(1.0)), Ok(()));
    }

    #[test]
    fn rvl_depth_is_decoded_in_place_and_then_checked_like_raw_depth() {
        let mut f = frame(8, 6);
        let mm: Vec<u16> = (0..48).map(|i| if i % 7 == 0 { 0 } else { 1000 + i }).collect();
        let depth = f.depth.as_mut().unwrap();
        depth.data_mm = vlnav_geometry::rvl::encode(&mm).into();
        depth.encoding = DepthEncoding::Rvl as i32;
        // Still encoded: refused by the check, with what to do.
        assert!(check_frame(&f, None).unwrap_err().to_string().contains("decode_depth"));
        decode_depth(&mut f).unwrap();
        let depth = f.depth.as_ref().unwrap();
        assert_eq!(depth.encoding, DepthEncoding::RawU16 as i32);
        let back: Vec<u16> = depth.data_mm.chunks_exact(2).map(|b| u16::from_le_bytes([b[0], b[1]])).collect();
        assert_eq!(back, mm);
        assert_eq!(check_frame(&f, None), Ok(()));
        // Quantised disparity comes back within its bound.
        let mut q = frame(8, 6);
        let step = vlnav_geometry::disparity::D455_STEP_PER_M;
        let depth = q.depth.as_mut().unwrap();
        depth.data_mm = vlnav_geometry::disparity::encode(&mm, 8, step).unwrap().into();
        (depth.encoding, depth.disparity_step) = (DepthEncoding::Disparity as i32, step);
        decode_depth(&mut q).unwrap();
        let depth = q.depth.as_ref().unwrap();
        assert_eq!((depth.encoding, depth.disparity_step), (DepthEncoding::RawU16 as i32, 0.0));
        let back = depth.data_mm.chunks_exact(2).map(|b| u16::from_le_bytes([b[0], b[1]]));
        for (d, b) in mm.iter().zip(back) {
            assert!((*d as f64 - b as f64).abs() <= vlnav_geometry::disparity::max_error_mm(*d, step), "{d} -> {b}");
        }
        assert_eq!(check_frame(&q, None), Ok(()));
        // Raw depth is left alone.
        let mut raw = frame(8, 6);
        decode_depth(&mut raw).unwrap();
        assert_eq!(raw, frame(8, 6));
    }

    #[test]
    fn broken_or_unknown_depth_encodings_are_named() {
        let mut f = frame(8, 6);
        let depth = f.depth.as_mut().unwrap();
        depth.data_mm = vec![0xFF; 9].into();
        depth.encoding = DepthEncoding::Rvl as i32;
        let e = decode_depth(&mut f).unwrap_err().to_string();
        assert!(e.starts_with("frame 7: depth (RVL): the RVL stream"), "{e}");
        // A disparity stream without its step names the step.
        (f.depth.as_mut().unwrap().encoding, f.depth.as_mut().unwrap().disparity_step) =
            (DepthEncoding::Disparity as i32, 0.0);
        let e = decode_depth(&mut f).unwrap_err().to_string();
        assert!(e.starts_with("frame 7: depth (quantised disparity): the disparity step 0"), "{e}");
        f.depth.as_mut().unwrap().encoding = 9;
        let e = decode_depth(&mut f).unwrap_err().to_string();
        assert!(e.contains("depth encoding 9 is unknown"), "{e}");
        // A declared size past the limit is refused before anything is decoded.
        let mut f = frame(8, 6);
        let depth = f.depth.as_mut().unwrap();
        (depth.width, depth.height, depth.encoding) = (100_000, 100_000, DepthEncoding::Rvl as i32);
        assert!(decode_depth(&mut f).unwrap_err().to_string().contains("outside 1..=4096"));
    }

    /// A 640×480 colour picture with gradients and edges.
    fn picture(w: u32, h: u32) -> Vec<u8> {
        (0..h)
            .flat_map(|y| {
                (0..w).flat_map(move |x| {
                    let stripe = if (x / 24 + y / 24) % 2 == 0 { 70 } else { 0 };
                    [(x * 255 / w) as u8, (y * 255 / h) as u8, 90 + stripe]
                })
            })
            .collect()
    }

    fn with_jpeg(w: u32, h: u32, jpeg: Vec<u8>) -> RgbdFrame {
        let mut f = frame(w, h);
        f.rgb = Some(Image { width: w, height: h, encoding: ImageEncoding::Jpeg as i32, data: jpeg.into() });
        f
    }

    #[test]
    fn a_jpeg_frame_passes_and_decodes_to_the_camera_size_within_a_bounded_error() {
        let (w, h) = (640, 480);
        let raw = picture(w, h);
        let jpeg = vlnav_geometry::rgb::encode_jpeg(w, h, &raw, 85).unwrap();
        assert!(jpeg.len() * 10 < raw.len(), "{} bytes of JPEG for {} raw", jpeg.len(), raw.len());
        let f = with_jpeg(w, h, jpeg);
        let checked = CheckedFrame::check(SensorFrame { frame: Some(f), truth: None }, None).unwrap();
        // Passed on as the robot sent it; decoded as every stage decodes it.
        let rgb = checked.frame().rgb.as_ref().unwrap();
        assert_eq!(rgb.encoding, ImageEncoding::Jpeg as i32);
        let img = vlnav_geometry::convert::encoded_image_from_proto(rgb).unwrap().decode().unwrap();
        assert_eq!(img.dimensions(), (w, h));
        let (mut sum, mut max) = (0u64, 0u8);
        for (a, b) in raw.iter().zip(img.as_raw()) {
            let d = a.abs_diff(*b);
            sum += u64::from(d);
            max = max.max(d);
        }
        let mean = sum as f64 / raw.len() as f64;
        assert!(mean < 2.0 && max < 48, "mean error {mean:.2}, max {max}");
    }

    #[test]
    fn a_jpeg_of_another_size_or_cut_short_is_refused_with_what_was_expected() {
        let jpeg = vlnav_geometry::rgb::encode_jpeg(32, 24, &picture(32, 24), 85).unwrap();
        let e = check_frame(&with_jpeg(64, 48, jpeg.clone()), None).unwrap_err().to_string();
        assert!(e.contains("rgb is a JPEG of 32x24 (declared 64x48); the camera is 64x48"), "{e}");
        // Declared 0×0 leaves the size to the header, as the stages read it.
        let mut f = with_jpeg(32, 24, jpeg.clone());
        let rgb = f.rgb.as_mut().unwrap();
        (rgb.width, rgb.height) = (0, 0);
        assert_eq!(check_frame(&f, None), Ok(()));
        let e = check_frame(&with_jpeg(32, 24, jpeg[..jpeg.len() / 2].to_vec()), None).unwrap_err().to_string();
        assert!(e.contains("rgb: cannot decode the JPEG image") && e.contains("end-of-image"), "{e}");
        let e = check_frame(&with_jpeg(32, 24, Vec::new()), None).unwrap_err().to_string();
        assert!(e.contains("no frame header"), "{e}");
    }

    #[test]
    fn a_nan_pose_is_named() {
        let mut f = frame(8, 6);
        f.odom.as_mut().unwrap().theta = f64::NAN;
        let e = check_frame(&f, None).unwrap_err();
        assert!(e.to_string().contains("odom.theta is not a finite number"), "{e}");
    }

    #[test]
    fn a_short_depth_image_says_what_was_expected() {
        let mut f = frame(8, 6);
        f.depth.as_mut().unwrap().data_mm.truncate(10);
        let e = check_frame(&f, None).unwrap_err().to_string();
        assert!(e.contains("96 bytes of u16 millimetres are expected"), "{e}");
    }

    #[test]
    fn a_wrong_rgb_size_and_a_time_reversal_are_rejected() {
        let mut f = frame(8, 6);
        let data = &mut f.rgb.as_mut().unwrap().data;
        data.truncate(data.len() - 1);
        assert!(check_frame(&f, None).unwrap_err().to_string().contains("RGB8"));
        let f = frame(8, 6);
        assert!(matches!(check_frame(&f, Some(2.0)), Err(FrameError::StampBackwards { .. })));
    }

    #[test]
    fn missing_parts_and_absurd_cameras_are_rejected() {
        let mut f = frame(8, 6);
        f.depth = None;
        assert_eq!(check_frame(&f, None), Err(FrameError::Missing { seq: 7, field: "depth" }));
        let mut f = frame(8, 6);
        f.camera.as_mut().unwrap().width = 100_000;
        assert!(check_frame(&f, None).unwrap_err().to_string().contains("outside 1..=4096"));
        let mut f = frame(8, 6);
        f.camera.as_mut().unwrap().intrinsics.as_mut().unwrap().fx = 0.0;
        assert!(check_frame(&f, None).unwrap_err().to_string().contains("must be positive"));
        // A camera the stages would refuse (found by fuzzing: the executor then had no camera).
        let mut f = frame(8, 6);
        f.camera.as_mut().unwrap().depth_min_m = 20.0;
        let e = check_frame(&f, None).unwrap_err().to_string();
        assert!(e.contains("invalid camera.depth_max_m: must exceed depth_min_m"), "{e}");
        let mut f = frame(8, 6);
        f.camera.as_mut().unwrap().mount =
            Some(vlnav_proto::v1::CameraMount { pitch: f64::INFINITY, ..Default::default() });
        assert!(check_frame(&f, None).unwrap_err().to_string().contains("camera.mount.pitch"));
    }
}
