//! The `ros1` driver: a ROS 1 node (rosrust) beside a Husky.
//!
//! Publishes `geometry_msgs/Twist` on `/cmd_vel` at the control rate (the
//! governor's output: zero unless a fresh command allows otherwise);
//! subscribes to `nav_msgs/Odometry` and the RealSense colour, aligned depth
//! and camera-info topics, and assembles them into `RgbdFrame`s.
//!
//! Sensor time is the ROS header stamps: "now" is the newest sensor stamp
//! plus the wall time since it arrived, so the deadman keeps running (and
//! stops the robot) even when the sensors fall silent.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tokio::sync::mpsc;
use vlnav_geometry::convert::pose_to_proto;
use vlnav_proto::v1 as pb;
use vlnav_runtime::CancellationToken;
use vlnav_sim::{Pose2, Twist};

use crate::convert::{self, RobotDescription};
use crate::link::{LastCommand, Link, SessionEnd, StatusReporter};
use crate::safety::{Backoff, Governor, Limits, Verdict};
use crate::{EdgeOptions, Hooks, StepRecord};

/// Message types generated from the ROS 1 definitions (see `build.rs`).
pub mod rosmsg {
    rosrust::rosmsg_include!(geometry_msgs / Twist, nav_msgs / Odometry, sensor_msgs / Image, sensor_msgs / CameraInfo);
}

/// Converts a ROS colour image to packed RGB8.
pub fn rgb_from_ros(encoding: &str, width: u32, height: u32, step: u32, data: &[u8]) -> Result<Vec<u8>, String> {
    let (channels, order): (usize, [usize; 3]) = match encoding {
        "rgb8" => (3, [0, 1, 2]),
        "bgr8" => (3, [2, 1, 0]),
        "rgba8" => (4, [0, 1, 2]),
        "bgra8" => (4, [2, 1, 0]),
        "mono8" => (1, [0, 0, 0]),
        other => return Err(format!("colour encoding `{other}` is not supported (rgb8, bgr8, rgba8, bgra8, mono8)")),
    };
    let (w, h, step) = (width as usize, height as usize, step as usize);
    if step < w * channels || data.len() < step * h.saturating_sub(1) + w * channels {
        return Err(format!("colour image {width}×{height} step {step} has {} bytes, too few", data.len()));
    }
    let mut out = Vec::with_capacity(w * h * 3);
    for row in 0..h {
        let r = &data[row * step..row * step + w * channels];
        for px in r.chunks_exact(channels) {
            out.extend_from_slice(&[px[order[0]], px[order[1]], px[order[2]]]);
        }
    }
    Ok(out)
}

/// Converts a ROS depth image (16UC1 millimetres or 32FC1 metres) to
/// little-endian u16 millimetres, 0 for invalid.
pub fn depth_from_ros(
    encoding: &str,
    big_endian: bool,
    width: u32,
    height: u32,
    step: u32,
    data: &[u8],
) -> Result<Vec<u8>, String> {
    let bytes_per = match encoding {
        "16UC1" | "mono16" => 2,
        "32FC1" => 4,
        other => return Err(format!("depth encoding `{other}` is not supported (16UC1 mm, 32FC1 m)")),
    };
    let (w, h, step) = (width as usize, height as usize, step as usize);
    if step < w * bytes_per || data.len() < step * h.saturating_sub(1) + w * bytes_per {
        return Err(format!("depth image {width}×{height} step {step} has {} bytes, too few", data.len()));
    }
    let mut out = Vec::with_capacity(w * h * 2);
    for row in 0..h {
        let r = &data[row * step..row * step + w * bytes_per];
        for px in r.chunks_exact(bytes_per) {
            let mm: u16 = if bytes_per == 2 {
                let b = [px[0], px[1]];
                if big_endian { u16::from_be_bytes(b) } else { u16::from_le_bytes(b) }
            } else {
                let b = [px[0], px[1], px[2], px[3]];
                let m = if big_endian { f32::from_be_bytes(b) } else { f32::from_le_bytes(b) };
                if m.is_finite() && m > 0.0 { (m as f64 * 1000.0).round().min(65535.0) as u16 } else { 0 }
            };
            out.extend_from_slice(&mm.to_le_bytes());
        }
    }
    Ok(out)
}

/// Heading (yaw about z) of a unit quaternion.
pub fn yaw_of(x: f64, y: f64, z: f64, w: f64) -> f64 {
    (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z))
}

fn stamp_of(t: &rosrust::Time) -> f64 {
    t.sec as f64 + t.nsec as f64 * 1e-9
}

/// The newest sensor stamp and when it arrived: "now" in sensor time.
#[derive(Clone, Copy, Debug, Default)]
pub struct SensorClock {
    latest: Option<(f64, Instant)>,
}

impl SensorClock {
    pub fn observe(&mut self, stamp: f64, at: Instant) {
        if self.latest.is_none_or(|(s, _)| stamp >= s) {
            self.latest = Some((stamp, at));
        }
    }

    pub fn now(&self, at: Instant) -> Option<f64> {
        self.latest.map(|(s, t)| s + at.saturating_duration_since(t).as_secs_f64())
    }
}

#[derive(Clone, Debug)]
struct Image {
    stamp: f64,
    width: u32,
    height: u32,
    data: Vec<u8>,
}

/// An assembled camera frame from the ROS topics.
#[derive(Clone, Debug)]
pub struct RosFrame {
    pub stamp: f64,
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<u8>,
    pub depth_mm_le: Vec<u8>,
    pub intrinsics: Option<pb::CameraIntrinsics>,
}

#[derive(Default)]
struct Shared {
    clock: SensorClock,
    odom: Option<(f64, Pose2, Twist)>,
    color: Option<Image>,
    depth: Option<Image>,
    intrinsics: Option<pb::CameraIntrinsics>,
    last_frame_stamp: f64,
}

impl Shared {
    /// Pairs the newest colour and depth images when their stamps agree.
    fn try_assemble(&mut self, min_period: f64, tolerance: f64) -> Option<RosFrame> {
        // A frame without intrinsics cannot be projected: wait for camera_info.
        self.intrinsics?;
        let (c, d) = (self.color.as_ref()?, self.depth.as_ref()?);
        if (c.stamp - d.stamp).abs() > tolerance || c.width != d.width || c.height != d.height {
            return None;
        }
        if c.stamp - self.last_frame_stamp < min_period {
            return None;
        }
        let (c, d) = (self.color.take()?, self.depth.take()?);
        self.last_frame_stamp = c.stamp;
        Some(RosFrame {
            stamp: c.stamp,
            width: c.width,
            height: c.height,
            rgb: c.data,
            depth_mm_le: d.data,
            intrinsics: self.intrinsics,
        })
    }
}

/// The ROS node: the `/cmd_vel` publisher and the sensor subscriptions.
pub struct RosRobot {
    _ros: rosrust::api::Ros,
    cmd_vel: rosrust::Publisher<rosmsg::geometry_msgs::Twist>,
    _subscribers: Vec<rosrust::Subscriber>,
    shared: Arc<Mutex<Shared>>,
    frames: mpsc::Receiver<RosFrame>,
}

impl RosRobot {
    /// Starts the node (blocking: it registers with the master named by `ROS_MASTER_URI`).
    pub fn start(opts: &EdgeOptions) -> anyhow::Result<RosRobot> {
        let ros = rosrust::api::Ros::new(&opts.ros_node).map_err(|e| {
            anyhow::anyhow!("cannot start ROS node `{}` (is roscore running at ROS_MASTER_URI?): {e}", opts.ros_node)
        })?;
        let cmd_vel = ros
            .publish::<rosmsg::geometry_msgs::Twist>(&opts.cmd_vel_topic, 1)
            .map_err(|e| anyhow::anyhow!("cannot advertise {}: {e}", opts.cmd_vel_topic))?;
        let shared = Arc::new(Mutex::new(Shared::default()));
        let (frame_tx, frames) = mpsc::channel(2);
        let min_period = 0.9 / opts.frame_rate;
        let tolerance = 0.5 / opts.frame_rate;
        let mut subs = Vec::new();

        let s = shared.clone();
        subs.push(
            ros.subscribe(&opts.odom_topic, 4, move |m: rosmsg::nav_msgs::Odometry| {
                let stamp = stamp_of(&m.header.stamp);
                let p = &m.pose.pose;
                let pose = Pose2::new(
                    p.position.x,
                    p.position.y,
                    yaw_of(p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w),
                );
                let twist = Twist::new(m.twist.twist.linear.x, m.twist.twist.angular.z);
                let mut g = s.lock().unwrap_or_else(|e| e.into_inner());
                g.clock.observe(stamp, Instant::now());
                g.odom = Some((stamp, pose, twist));
            })
            .map_err(|e| anyhow::anyhow!("cannot subscribe to {}: {e}", opts.odom_topic))?,
        );
        let s = shared.clone();
        subs.push(
            ros.subscribe(&opts.camera_info_topic, 1, move |m: rosmsg::sensor_msgs::CameraInfo| {
                let k = m.K;
                if k[0] > 0.0 && k[4] > 0.0 {
                    let mut g = s.lock().unwrap_or_else(|e| e.into_inner());
                    g.intrinsics = Some(pb::CameraIntrinsics { fx: k[0], fy: k[4], cx: k[2], cy: k[5] });
                }
            })
            .map_err(|e| anyhow::anyhow!("cannot subscribe to {}: {e}", opts.camera_info_topic))?,
        );
        let (s, tx) = (shared.clone(), frame_tx.clone());
        let color_topic = opts.color_topic.clone();
        subs.push(
            ros.subscribe(&opts.color_topic, 2, move |m: rosmsg::sensor_msgs::Image| {
                let stamp = stamp_of(&m.header.stamp);
                match rgb_from_ros(&m.encoding, m.width, m.height, m.step, &m.data) {
                    Ok(rgb) => {
                        let mut g = s.lock().unwrap_or_else(|e| e.into_inner());
                        g.clock.observe(stamp, Instant::now());
                        g.color = Some(Image { stamp, width: m.width, height: m.height, data: rgb });
                        if let Some(f) = g.try_assemble(min_period, tolerance) {
                            let _ = tx.try_send(f);
                        }
                    }
                    Err(e) => tracing::warn!(topic = %color_topic, "dropping colour image: {e}"),
                }
            })
            .map_err(|e| anyhow::anyhow!("cannot subscribe to {}: {e}", opts.color_topic))?,
        );
        let (s, tx) = (shared.clone(), frame_tx);
        let depth_topic = opts.depth_topic.clone();
        subs.push(
            ros.subscribe(&opts.depth_topic, 2, move |m: rosmsg::sensor_msgs::Image| {
                let stamp = stamp_of(&m.header.stamp);
                match depth_from_ros(&m.encoding, m.is_bigendian != 0, m.width, m.height, m.step, &m.data) {
                    Ok(depth) => {
                        let mut g = s.lock().unwrap_or_else(|e| e.into_inner());
                        g.clock.observe(stamp, Instant::now());
                        g.depth = Some(Image { stamp, width: m.width, height: m.height, data: depth });
                        if let Some(f) = g.try_assemble(min_period, tolerance) {
                            let _ = tx.try_send(f);
                        }
                    }
                    Err(e) => tracing::warn!(topic = %depth_topic, "dropping depth image: {e}"),
                }
            })
            .map_err(|e| anyhow::anyhow!("cannot subscribe to {}: {e}", opts.depth_topic))?,
        );
        Ok(RosRobot { _ros: ros, cmd_vel, _subscribers: subs, shared, frames })
    }

    /// Sensor time now, if any sensor message has arrived.
    pub fn now(&self) -> Option<f64> {
        self.shared.lock().unwrap_or_else(|e| e.into_inner()).clock.now(Instant::now())
    }

    fn odom(&self) -> Option<(f64, Pose2, Twist)> {
        self.shared.lock().unwrap_or_else(|e| e.into_inner()).odom
    }

    /// Publishes a velocity on `/cmd_vel`.
    pub fn publish(&self, t: Twist) {
        let mut msg = rosmsg::geometry_msgs::Twist::default();
        msg.linear.x = t.linear;
        msg.angular.z = t.angular;
        if let Err(e) = self.cmd_vel.send(msg) {
            tracing::warn!("cannot publish /cmd_vel: {e}");
        }
    }
}

fn limits_of(opts: &EdgeOptions) -> Limits {
    Limits {
        max_linear: opts.max_linear,
        max_angular: opts.max_angular,
        max_linear_accel: opts.max_linear_accel,
        max_angular_accel: opts.max_angular_accel,
    }
}

fn camera_info(
    opts: &EdgeOptions,
    width: u32,
    height: u32,
    intrinsics: Option<pb::CameraIntrinsics>,
) -> pb::CameraInfo {
    let m = &opts.camera_mount;
    pb::CameraInfo {
        width,
        height,
        intrinsics,
        mount: Some(pb::CameraMount {
            translation: Some(pb::Point3 { x: m[0], y: m[1], z: m[2] }),
            roll: 0.0,
            pitch: 0.0,
            yaw: m[3],
        }),
        // The D455's usable depth range (the paper limits subgoals to 10 m).
        depth_min_m: 0.3,
        depth_max_m: 10.0,
    }
}

/// Runs the `ros1` driver until shutdown: the ROS node lives for the whole
/// run; the gateway link reconnects with backoff while `/cmd_vel` holds zero.
pub async fn run_ros1(opts: &EdgeOptions, shutdown: CancellationToken, hooks: Hooks) -> anyhow::Result<()> {
    let mut backoff =
        Backoff::new(Duration::from_secs_f64(opts.reconnect_initial_s), Duration::from_secs_f64(opts.reconnect_max_s));
    let mut robot = loop {
        let o = opts.clone();
        match tokio::task::spawn_blocking(move || RosRobot::start(&o)).await? {
            Ok(r) => break r,
            Err(e) => {
                let d = backoff.next_delay();
                tracing::warn!("{e:#}; retrying in {:.1} s", d.as_secs_f64());
                tokio::select! {
                    _ = shutdown.cancelled() => return Ok(()),
                    _ = tokio::time::sleep(d) => {}
                }
            }
        }
    };
    backoff.reset();
    let limits = limits_of(opts);
    let desc = RobotDescription { limits, footprint_length: 0.988, footprint_width: 0.670 };
    let mut gov = Governor::new(limits, opts.deadman_timeout_s);
    let mut status = StatusReporter::default();
    let control = Duration::from_secs_f64(1.0 / opts.control_rate_hz);
    tracing::info!(robot = %opts.robot_id, gateway = %opts.gateway, cmd_vel = %opts.cmd_vel_topic, "ros1 edge agent starting");
    loop {
        // The camera's size is known once a frame has arrived; say hello with what we know.
        let hello = pb::EdgeHello {
            robot_id: opts.robot_id.clone(),
            driver: "ros1".into(),
            limits: Some(convert::limits(&desc)),
            camera: Some(camera_info(opts, 0, 0, robot.shared.lock().unwrap_or_else(|e| e.into_inner()).intrinsics)),
            lockstep: false,
        };
        let connect = Link::connect(opts, hello);
        tokio::pin!(connect);
        // Hold the robot stopped while connecting.
        let mut tick = tokio::time::interval(control);
        let connected = loop {
            tokio::select! {
                _ = shutdown.cancelled() => { robot.publish(Twist::ZERO); return Ok(()); }
                r = &mut connect => break r,
                _ = tick.tick() => robot.publish(Twist::ZERO),
            }
        };
        let end = match connected {
            Ok(mut link) => {
                backoff.reset();
                status.reset();
                tracing::info!(robot = %opts.robot_id, "attached to the gateway");
                ros_session(opts, &mut robot, &mut gov, &mut link, &mut status, &hooks, &shutdown).await
            }
            Err(e) => SessionEnd::Lost(format!("{e:#}")),
        };
        gov.drop_command();
        robot.publish(Twist::ZERO);
        match end {
            SessionEnd::Finished => return Ok(()),
            SessionEnd::Lost(reason) => {
                let delay = backoff.next_delay();
                tracing::warn!(robot = %opts.robot_id, %reason, retry_in_s = delay.as_secs_f64(), "gateway link down; robot held stopped");
                let until = tokio::time::Instant::now() + delay;
                let mut tick = tokio::time::interval(control);
                loop {
                    tokio::select! {
                        _ = shutdown.cancelled() => { robot.publish(Twist::ZERO); return Ok(()); }
                        _ = tokio::time::sleep_until(until) => break,
                        _ = tick.tick() => robot.publish(Twist::ZERO),
                    }
                }
            }
        }
    }
}

async fn ros_session(
    opts: &EdgeOptions,
    robot: &mut RosRobot,
    gov: &mut Governor,
    link: &mut Link,
    status: &mut StatusReporter,
    hooks: &Hooks,
    shutdown: &CancellationToken,
) -> SessionEnd {
    let liveness = Duration::from_secs_f64(opts.liveness_timeout_s);
    let mut tick = tokio::time::interval(Duration::from_secs_f64(1.0 / opts.control_rate_hz));
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let mut last = LastCommand::new(gov);
    let mut seq = 0u64;
    loop {
        tokio::select! {
            _ = shutdown.cancelled() => { robot.publish(Twist::ZERO); return SessionEnd::Finished; }
            m = link.recv() => match m {
                Err(e) => return SessionEnd::Lost(e),
                Ok(pb::GatewayCommand { kind: Some(pb::gateway_command::Kind::Velocity(v)) }) => last.take(gov, v),
                Ok(pb::GatewayCommand { kind: Some(pb::gateway_command::Kind::ResetOdometry(_)) }) => {
                    tracing::warn!("ResetOdometry is not supported by the ros1 driver; odometry goals stay in the robot's odom frame");
                }
                Ok(pb::GatewayCommand { kind: Some(pb::gateway_command::Kind::Mission(a)) }) => last.announce(&a),
                Ok(_) => {}
            },
            Some(f) = robot.frames.recv() => {
                let (odom_pose, odom_twist) = robot.odom().map(|(_, p, t)| (p, t)).unwrap_or_default();
                let frame = pb::RgbdFrame {
                    robot_id: opts.robot_id.clone(),
                    seq,
                    stamp: f.stamp,
                    camera: Some(camera_info(opts, f.width, f.height, f.intrinsics)),
                    rgb: Some(pb::Image { width: f.width, height: f.height, encoding: pb::ImageEncoding::Rgb8 as i32, data: f.rgb.into() }),
                    depth: Some(depth_le(f.width, f.height, f.depth_mm_le, opts.depth_codec)),
                    odom: Some(pose_to_proto(&odom_pose)),
                    odom_twist: Some(convert::twist(&odom_twist)),
                    labels: None,
                };
                seq += 1;
                let odo = pb::OdometryUpdate { stamp: f.stamp, pose: Some(pose_to_proto(&odom_pose)), twist: Some(convert::twist(&odom_twist)) };
                let stamp = frame.stamp;
                for msg in [convert::edge(pb::edge_message::Kind::Odometry(odo)), convert::edge(pb::edge_message::Kind::Frame(pb::SensorFrame { frame: Some(frame), truth: None }))] {
                    if let Err(e) = link.offer(msg) { return SessionEnd::Lost(e); }
                }
                last.frame_sent(stamp);
            },
            _ = tick.tick() => {
                if link.last_heard().elapsed() > liveness {
                    robot.publish(Twist::ZERO);
                    return SessionEnd::Lost(format!("nothing from the gateway for {} s", opts.liveness_timeout_s));
                }
                gov.set_estop(hooks.estop.is_engaged());
                let (out, verdict) = match robot.now() {
                    Some(now) => gov.output(now),
                    None => (Twist::ZERO, Verdict::NoCommand),
                };
                robot.publish(out);
                let now = robot.now().unwrap_or(0.0);
                if let Some(s) = status.update(now, verdict) && let Err(e) = link.offer(s) {
                    return SessionEnd::Lost(e);
                }
                if let Some(obs) = &hooks.observer {
                    let _ = obs.send(StepRecord {
                        seq,
                        stamp: now,
                        odom: robot.odom().map(|(_, p, _)| p).unwrap_or_default(),
                        truth: None,
                        command: gov.command(),
                        applied: out,
                        verdict,
                        idle: last.idle,
                        mission_id: last.mission.clone(),
                    });
                }
            }
        }
    }
}

/// The camera's little-endian millimetres as `codec` sends them.
fn depth_le(width: u32, height: u32, mm_le: Vec<u8>, codec: crate::DepthCodec) -> pb::DepthImage {
    match codec {
        crate::DepthCodec::Raw => {
            pb::DepthImage { width, height, data_mm: mm_le.into(), encoding: pb::DepthEncoding::RawU16 as i32 }
        }
        crate::DepthCodec::Rvl => {
            let mm: Vec<u16> = mm_le.chunks_exact(2).map(|b| u16::from_le_bytes([b[0], b[1]])).collect();
            convert::depth_image(width, height, &mm, codec)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn colour_images_convert_from_bgr_with_row_padding() {
        // 2×2 bgr8 with a 2-byte pad per row.
        let data = [1, 2, 3, 4, 5, 6, 0, 0, 7, 8, 9, 10, 11, 12, 0, 0];
        assert_eq!(rgb_from_ros("bgr8", 2, 2, 8, &data).unwrap(), vec![3, 2, 1, 6, 5, 4, 9, 8, 7, 12, 11, 10]);
        assert!(rgb_from_ros("yuv422", 2, 2, 8, &data).unwrap_err().contains("yuv422"));
        assert!(rgb_from_ros("rgb8", 2, 3, 8, &data).unwrap_err().contains("too few"));
    }

    #[test]
    fn depth_converts_from_millimetres_and_metres() {
        let be = [0x01, 0x02, 0x00, 0x00];
        assert_eq!(depth_from_ros("16UC1", true, 2, 1, 4, &be).unwrap(), vec![0x02, 0x01, 0, 0]);
        let mut f = Vec::new();
        for m in [1.5f32, f32::NAN, -1.0, 70.0] {
            f.extend_from_slice(&m.to_le_bytes());
        }
        let out = depth_from_ros("32FC1", false, 4, 1, 16, &f).unwrap();
        let mm: Vec<u16> = out.chunks_exact(2).map(|b| u16::from_le_bytes([b[0], b[1]])).collect();
        assert_eq!(mm, vec![1500, 0, 0, 65535]);
    }

    #[test]
    fn yaw_from_quaternion_and_sensor_clock() {
        let h = 0.7f64;
        assert!((yaw_of(0.0, 0.0, (h / 2.0).sin(), (h / 2.0).cos()) - h).abs() < 1e-12);
        let t0 = Instant::now();
        let mut c = SensorClock::default();
        assert_eq!(c.now(t0), None);
        c.observe(100.0, t0);
        c.observe(99.0, t0); // older stamp ignored
        let later = t0 + Duration::from_millis(250);
        assert!((c.now(later).unwrap() - 100.25).abs() < 1e-9);
    }

    #[test]
    fn frames_pair_colour_and_depth_by_stamp_at_the_frame_rate() {
        let img = |stamp| Some(Image { stamp, width: 2, height: 1, data: vec![0; 6] });
        let mut s = Shared { color: img(1.0), depth: img(1.01), ..Default::default() };
        assert!(s.try_assemble(0.09, 0.05).is_none(), "no frames before camera_info");
        s.intrinsics = Some(pb::CameraIntrinsics { fx: 1.0, fy: 1.0, cx: 1.0, cy: 0.5 });
        s.depth = img(1.3);
        assert!(s.try_assemble(0.09, 0.05).is_none(), "stamps 0.3 s apart do not pair");
        s.depth = img(1.01);
        let f = s.try_assemble(0.09, 0.05).unwrap();
        assert_eq!(f.stamp, 1.0);
        s.color = img(1.05);
        s.depth = img(1.05);
        assert!(s.try_assemble(0.09, 0.05).is_none(), "faster than the frame rate");
        s.color = img(1.1);
        s.depth = img(1.1);
        assert!(s.try_assemble(0.09, 0.05).is_some());
    }
}
