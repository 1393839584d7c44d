//! A robot that sends recorded frames again, in real time: the load
//! generator of `vlnav bench fleet --replay` (docs/architecture.md, "Fleet
//! benchmark"). Rendering a 640×480 frame costs the simulator ~9.5 ms, so
//! simulated robots saturate a small machine before the stack does; a
//! replayed frame costs a few reference-counted clones.
//!
//! - **Images:** the recording's frames in turn, then from the start again.
//!   They are converted once, when loaded, to the codecs the robot sends
//!   with (`--colour-codec`, `--depth-codec`), so each frame is sent as a
//!   robot with those codecs sends it.
//! - **Odometry:** the robot's own, integrated from the commands the
//!   governor lets through (a unicycle, no slip), so missions drive, reach
//!   their goals and end as the executor decides. The images do not follow
//!   the robot: what it sees is the recorded mission's view.
//! - **Everything else** (the link, the governor, the deadman, reconnecting)
//!   is the `sim` driver's session (`crate::sim`).

use std::sync::Arc;

use vlnav_geometry::convert::pose_to_proto;
use vlnav_geometry::rgb;
use vlnav_proto::v1 as pb;
use vlnav_runtime::CancellationToken;
use vlnav_sim::{Pose2, Truth, Twist};

use crate::convert::{self, RobotDescription};
use crate::sim::{World, drive, limits_of};
use crate::{Codecs, ColourCodec, DepthCodec, EdgeOptions, Hooks};

/// Recorded frames, shared by every robot that replays them.
#[derive(Clone, Debug)]
pub struct Recorded {
    frames: Arc<[pb::RgbdFrame]>,
    truths: Arc<[Option<pb::SimTruth>]>,
    camera: pb::CameraInfo,
}

impl Recorded {
    /// The frames of a recording, each converted to `codecs`. Refuses an
    /// empty list, a frame without images or camera, and frames of more than
    /// one camera.
    pub fn new(frames: Vec<pb::SensorFrame>, codecs: Codecs) -> anyhow::Result<Self> {
        let Some(camera) = frames.first().and_then(|f| f.frame.as_ref()).and_then(|f| f.camera) else {
            anyhow::bail!("no frame to replay: the recording's first frame has no camera info");
        };
        let mut images = Vec::with_capacity(frames.len());
        let mut truths = Vec::with_capacity(frames.len());
        for (i, sf) in frames.into_iter().enumerate() {
            let Some(mut f) = sf.frame else { anyhow::bail!("recorded frame {i} has no RGB-D frame") };
            if f.camera != Some(camera) {
                anyhow::bail!("recorded frame {i} has another camera than the first: one camera per replay");
            }
            let (w, h) = (camera.width, camera.height);
            let colour = f.rgb.take().ok_or_else(|| anyhow::anyhow!("recorded frame {i} has no colour image"))?;
            f.rgb = Some(colour_as(colour, w, h, codecs).map_err(|e| anyhow::anyhow!("recorded frame {i}: {e}"))?);
            let depth = f.depth.take().ok_or_else(|| anyhow::anyhow!("recorded frame {i} has no depth image"))?;
            f.depth = Some(depth_as(depth, codecs).map_err(|e| anyhow::anyhow!("recorded frame {i}: {e}"))?);
            images.push(f);
            truths.push(sf.truth);
        }
        Ok(Self { frames: images.into(), truths: truths.into(), camera })
    }

    pub fn len(&self) -> usize {
        self.frames.len()
    }

    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    pub fn camera(&self) -> pb::CameraInfo {
        self.camera
    }
}

/// A recorded colour image as `codecs` sends it: decoded to RGB8, or
/// encoded as JPEG at `codecs.jpeg_quality` (a recorded JPEG is sent as it is).
fn colour_as(img: pb::Image, width: u32, height: u32, codecs: Codecs) -> anyhow::Result<pb::Image> {
    let jpeg = img.encoding == pb::ImageEncoding::Jpeg as i32;
    match codecs.colour {
        ColourCodec::Jpeg if jpeg => Ok(img),
        ColourCodec::Raw if img.encoding == pb::ImageEncoding::Rgb8 as i32 => Ok(img),
        _ => {
            let encoded = vlnav_geometry::convert::encoded_image_from_proto(&img)?;
            let decoded = rgb::decode(encoded.encoding, width, height, &encoded.data)?;
            Ok(convert::colour_image(width, height, decoded.into_raw().into(), codecs))
        }
    }
}

/// A recorded depth image as `codecs.depth` sends it.
fn depth_as(d: pb::DepthImage, codecs: Codecs) -> anyhow::Result<pb::DepthImage> {
    let pixels = d.width as usize * d.height as usize;
    let codec = codecs.depth;
    let mm: Vec<u16> = match pb::DepthEncoding::try_from(d.encoding) {
        Ok(pb::DepthEncoding::RawU16) if codec == DepthCodec::Raw => return Ok(d),
        Ok(pb::DepthEncoding::Rvl) if codec == DepthCodec::Rvl => return Ok(d),
        Ok(pb::DepthEncoding::Disparity)
            if codec == DepthCodec::Disparity && d.disparity_step == codecs.disparity_step =>
        {
            return Ok(d);
        }
        Ok(pb::DepthEncoding::RawU16) => {
            if d.data_mm.len() != pixels * 2 {
                anyhow::bail!("raw depth of {} bytes for {}×{}", d.data_mm.len(), d.width, d.height);
            }
            d.data_mm.chunks_exact(2).map(|b| u16::from_le_bytes([b[0], b[1]])).collect()
        }
        Ok(pb::DepthEncoding::Rvl) => vlnav_geometry::rvl::decode(&d.data_mm, pixels)?,
        Ok(pb::DepthEncoding::Disparity) => {
            vlnav_geometry::disparity::decode(&d.data_mm, d.width as usize, d.height as usize, d.disparity_step)?
        }
        _ => anyhow::bail!("depth encoding {} cannot be replayed", d.encoding),
    };
    Ok(convert::depth_image(d.width, d.height, &mm, codecs))
}

/// One robot replaying [`Recorded`] frames.
struct ReplayRobot {
    recorded: Recorded,
    robot_id: String,
    period: f64,
    seq: u64,
    time: f64,
    odom: Pose2,
    twist: Twist,
    max_time: Option<f64>,
}

impl World for ReplayRobot {
    fn capture(&mut self) -> (pb::SensorFrame, pb::OdometryUpdate) {
        let i = (self.seq % self.recorded.frames.len() as u64) as usize;
        let mut frame = self.recorded.frames[i].clone();
        frame.robot_id.clone_from(&self.robot_id);
        frame.seq = self.seq;
        frame.stamp = self.time;
        frame.odom = Some(pose_to_proto(&self.odom));
        frame.odom_twist = Some(convert::twist(&self.twist));
        let odo = pb::OdometryUpdate {
            stamp: self.time,
            pose: Some(pose_to_proto(&self.odom)),
            twist: Some(convert::twist(&self.twist)),
        };
        self.seq += 1;
        (pb::SensorFrame { frame: Some(frame), truth: self.recorded.truths[i] }, odo)
    }

    fn step(&mut self, cmd: Twist) {
        self.odom = unicycle(self.odom, cmd, self.period);
        self.twist = cmd;
        self.time += self.period;
    }

    fn time(&self) -> f64 {
        self.time
    }

    fn period(&self) -> f64 {
        self.period
    }

    fn frames(&self) -> u64 {
        self.seq
    }

    fn reset_odometry(&mut self) {
        self.odom = Pose2::default();
    }

    fn odometry(&self) -> Pose2 {
        self.odom
    }

    fn truth(&self) -> Option<Truth> {
        None
    }

    fn time_is_up(&self) -> bool {
        self.max_time.is_some_and(|m| self.time >= m - 1e-9)
    }
}

/// `pose` moved by `cmd` for `dt` seconds along the arc it drives.
fn unicycle(pose: Pose2, cmd: Twist, dt: f64) -> Pose2 {
    let dtheta = cmd.angular * dt;
    // Exact for a constant twist: the chord of the arc, at the mean heading.
    let chord =
        if dtheta.abs() < 1e-9 { cmd.linear * dt } else { 2.0 * cmd.linear / cmd.angular * (dtheta / 2.0).sin() };
    let mid = pose.theta + dtheta / 2.0;
    let theta = (pose.theta + dtheta + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI;
    Pose2::new(pose.x + chord * mid.cos(), pose.y + chord * mid.sin(), theta)
}

/// Runs a robot that replays `recorded` through the gateway (real time or
/// lockstep, as `opts` says) until `shutdown` or `--max-sim-time-s`. The
/// robot introduces itself as a Husky A200 with the recording's camera.
pub async fn run_replay(
    opts: &EdgeOptions,
    recorded: Recorded,
    shutdown: CancellationToken,
    hooks: Hooks,
) -> anyhow::Result<()> {
    // `Recorded::new` refuses a recording without frames.
    opts.validate()?;
    let params = vlnav_sim::HuskyParams::default();
    let desc =
        RobotDescription { limits: limits_of(&params), footprint_length: params.length, footprint_width: params.width };
    let hello = pb::EdgeHello {
        robot_id: opts.robot_id.clone(),
        driver: "replay".into(),
        limits: Some(convert::limits(&desc)),
        camera: Some(recorded.camera()),
        lockstep: opts.lockstep,
    };
    let mut robot = ReplayRobot {
        recorded,
        robot_id: opts.robot_id.clone(),
        period: 1.0 / opts.frame_rate,
        seq: 0,
        time: 0.0,
        odom: Pose2::default(),
        twist: Twist::default(),
        max_time: opts.max_sim_time_s,
    };
    tracing::info!(robot = %opts.robot_id, frames = robot.recorded.len(), gateway = %opts.gateway, "replaying edge agent starting");
    drive(opts, &mut robot, hello, desc.limits, shutdown, hooks).await
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(seq: u64, w: u32, h: u32) -> pb::SensorFrame {
        let rgb: Vec<u8> = (0..w * h * 3).map(|i| (i * 7 % 251) as u8).collect();
        let depth: Vec<u16> =
            (0..w * h).map(|i| if i % 5 == 0 { 0 } else { 1000 + (i % 300) as u16 + seq as u16 }).collect();
        let codecs = Codecs::default();
        pb::SensorFrame {
            frame: Some(pb::RgbdFrame {
                robot_id: "recorded".into(),
                seq,
                stamp: seq as f64 * 0.1,
                camera: Some(pb::CameraInfo { width: w, height: h, ..Default::default() }),
                rgb: Some(convert::colour_image(w, h, rgb.into(), codecs)),
                depth: Some(convert::depth_image(w, h, &depth, Codecs::default())),
                odom: Some(pose_to_proto(&Pose2::new(5.0, 1.0, 0.3))),
                ..Default::default()
            }),
            truth: None,
        }
    }

    fn robot(recorded: Recorded) -> ReplayRobot {
        ReplayRobot {
            recorded,
            robot_id: "husky-7".into(),
            period: 0.1,
            seq: 0,
            time: 0.0,
            odom: Pose2::default(),
            twist: Twist::default(),
            max_time: Some(0.25),
        }
    }

    #[test]
    fn frames_come_in_turn_then_again_with_the_robots_own_stamp_and_odometry() {
        let rec = Recorded::new(vec![frame(40, 8, 6), frame(41, 8, 6)], Codecs::default()).unwrap();
        let mut r = robot(rec);
        let mut seen = Vec::new();
        for _ in 0..3 {
            let (sf, odo) = r.capture();
            let f = sf.frame.unwrap();
            assert_eq!(f.robot_id, "husky-7");
            assert_eq!(f.odom, odo.pose, "the frame carries the robot's odometry, not the recorded one");
            seen.push((f.seq, f.stamp, f.depth.unwrap().data_mm));
            r.step(Twist { linear: 1.0, angular: 0.0 });
        }
        assert_eq!(seen.iter().map(|s| s.0).collect::<Vec<_>>(), [0, 1, 2]);
        assert!((seen[2].1 - 0.2).abs() < 1e-12);
        assert_eq!(seen[0].2, seen[2].2, "the third frame is the first recorded one again");
        assert_ne!(seen[0].2, seen[1].2);
        assert!((r.odometry().x - 0.3).abs() < 1e-9);
        assert!(r.time_is_up());
        r.reset_odometry();
        assert_eq!(r.odometry(), Pose2::default());
    }

    #[test]
    fn the_odometry_follows_an_arc_exactly() {
        // A quarter circle of radius 1 m in 10 steps ends at (1, 1), facing left.
        let (v, w) = (std::f64::consts::FRAC_PI_2, std::f64::consts::FRAC_PI_2);
        let mut p = Pose2::default();
        for _ in 0..10 {
            p = unicycle(p, Twist { linear: v, angular: w }, 0.1);
        }
        assert!((p.x - 1.0).abs() < 1e-9 && (p.y - 1.0).abs() < 1e-9, "{p:?}");
        assert!((p.theta - std::f64::consts::FRAC_PI_2).abs() < 1e-9);
    }

    #[test]
    fn recorded_images_are_sent_with_the_robots_codecs_and_decode_to_the_same_depth() {
        let raw = Recorded::new(vec![frame(0, 16, 12)], Codecs::default()).unwrap();
        let codecs =
            Codecs { colour: ColourCodec::Jpeg, jpeg_quality: 90, depth: DepthCodec::Rvl, ..Codecs::default() };
        let packed = Recorded::new(vec![frame(0, 16, 12)], codecs).unwrap();
        let (r, p) = (&raw.frames[0], &packed.frames[0]);
        assert_eq!(p.rgb.as_ref().unwrap().encoding, pb::ImageEncoding::Jpeg as i32);
        let d = p.depth.as_ref().unwrap();
        assert_eq!(d.encoding, pb::DepthEncoding::Rvl as i32);
        let back = depth_as(d.clone(), Codecs::default()).unwrap();
        assert_eq!(back.data_mm, r.depth.as_ref().unwrap().data_mm, "RVL is lossless");
        // And back to raw colour from the JPEG: the right size.
        let again =
            Recorded::new(vec![pb::SensorFrame { frame: Some(p.clone()), truth: None }], Codecs::default()).unwrap();
        let c = again.frames[0].rgb.as_ref().unwrap();
        assert_eq!((c.encoding, c.data.len()), (pb::ImageEncoding::Rgb8 as i32, 16 * 12 * 3));
    }

    #[test]
    fn a_recording_without_frames_or_images_is_refused_with_why() {
        let e = Recorded::new(vec![], Codecs::default()).unwrap_err().to_string();
        assert!(e.contains("no frame to replay"), "{e}");
        let mut f = frame(0, 8, 6);
        f.frame.as_mut().unwrap().depth = None;
        let e = Recorded::new(vec![frame(0, 8, 6), f], Codecs::default()).unwrap_err().to_string();
        assert!(e.contains("recorded frame 1 has no depth image"), "{e}");
        let e = Recorded::new(vec![frame(0, 8, 6), frame(1, 4, 3)], Codecs::default()).unwrap_err().to_string();
        assert!(e.contains("another camera"), "{e}");
    }
}
