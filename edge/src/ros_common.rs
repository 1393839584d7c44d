//! What the ROS drivers (`ros1`, `ros2`) share: the conversions of ROS
//! images, the sensor clock, the pairing of colour and depth into frames,
//! and the loop that drives a ROS robot from the gateway's link.
//!
//! A driver owns its node and publishes `cmd_vel` ([`RosPlatform`]); its
//! subscriptions write into [`Sensors`]. Everything else — the control tick,
//! the governor (deadman in sensor time, limits, e-stop), frames up and
//! commands down, reconnecting with backoff while the robot is held at zero
//! — is here, once, for both.

use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use tokio::sync::mpsc;
use vlnav_geometry::convert::pose_to_proto;
use vlnav_proto::v1 as pb;
use vlnav_runtime::CancellationToken;
use vlnav_sim::{Pose2, Twist};

use crate::convert::{self, RobotDescription};
use crate::link::{LastCommand, Link, RobotState, SessionEnd, StatusReporter};
use crate::safety::{Backoff, Governor, Limits, Verdict};
use crate::{EdgeOptions, Hooks, StepRecord};

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

/// "Now" in sensor time. On the robot's clock: the newest sensor stamp plus
/// the wall time since it arrived, so the deadman keeps running (and stops
/// the robot) even when the sensors fall silent. On a simulation's clock
/// (`use_sim_time`): the newest `/clock`, which stands still while the
/// simulation is paused.
#[derive(Clone, Copy, Debug, Default)]
pub struct SensorClock {
    latest: Option<(f64, Instant)>,
    simulated: Option<f64>,
    use_sim_time: bool,
}

impl SensorClock {
    /// A clock that reads `/clock` only.
    pub fn simulated() -> Self {
        Self { use_sim_time: true, ..Self::default() }
    }

    pub fn observe(&mut self, stamp: f64, at: Instant) {
        if stamp.is_finite() && self.latest.is_none_or(|(s, _)| stamp >= s) {
            self.latest = Some((stamp, at));
        }
    }

    /// A `/clock` message (ignored unless the clock is simulated).
    pub fn observe_clock(&mut self, t: f64) {
        if self.use_sim_time && t.is_finite() && self.simulated.is_none_or(|s| t >= s) {
            self.simulated = Some(t);
        }
    }

    pub fn now(&self, at: Instant) -> Option<f64> {
        if self.use_sim_time {
            return self.simulated;
        }
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

/// What the subscriptions of a ROS driver have received, and the pairing of
/// colour with depth into frames at the frame rate.
pub struct Sensors {
    clock: SensorClock,
    odom: Option<(f64, Pose2, Twist)>,
    color: Option<Image>,
    depth: Option<Image>,
    intrinsics: Option<pb::CameraIntrinsics>,
    last_frame_stamp: f64,
    /// The robot's own e-stop, as its newest message said (std_msgs/Bool
    /// carries no stamp); released until one arrives.
    platform_estop: bool,
    battery: Option<pb::BatteryStatus>,
    min_period: f64,
    tolerance: f64,
    frames: mpsc::Sender<RosFrame>,
}

impl Sensors {
    /// Shared sensors and the receiver of the frames they assemble.
    pub fn new(opts: &EdgeOptions, clock: SensorClock) -> (Arc<Mutex<Sensors>>, mpsc::Receiver<RosFrame>) {
        let (frames, rx) = mpsc::channel(2);
        let s = Sensors {
            clock,
            odom: None,
            color: None,
            depth: None,
            intrinsics: None,
            last_frame_stamp: f64::NEG_INFINITY,
            platform_estop: false,
            battery: None,
            min_period: 0.9 / opts.frame_rate,
            tolerance: 0.5 / opts.frame_rate,
            frames,
        };
        (Arc::new(Mutex::new(s)), rx)
    }

    /// Locks the sensors; a callback that panicked holding them left nothing half-written.
    pub fn lock(s: &Mutex<Sensors>) -> MutexGuard<'_, Sensors> {
        s.lock().unwrap_or_else(|e| e.into_inner())
    }

    pub fn on_odometry(&mut self, stamp: f64, pose: Pose2, twist: Twist) {
        self.clock.observe(stamp, Instant::now());
        self.odom = Some((stamp, pose, twist));
    }

    /// A camera_info's K matrix (row-major 3×3); ignored unless fx, fy > 0.
    pub fn on_camera_info(&mut self, k: &[f64; 9]) {
        if k[0] > 0.0 && k[4] > 0.0 {
            self.intrinsics = Some(pb::CameraIntrinsics { fx: k[0], fy: k[4], cx: k[2], cy: k[5] });
        }
    }

    /// A colour image, already RGB8.
    pub fn on_color(&mut self, stamp: f64, width: u32, height: u32, rgb: Vec<u8>) {
        self.clock.observe(stamp, Instant::now());
        self.color = Some(Image { stamp, width, height, data: rgb });
        self.offer_frame();
    }

    /// A depth image, already little-endian u16 millimetres.
    pub fn on_depth(&mut self, stamp: f64, width: u32, height: u32, mm_le: Vec<u8>) {
        self.clock.observe(stamp, Instant::now());
        self.depth = Some(Image { stamp, width, height, data: mm_le });
        self.offer_frame();
    }

    pub fn on_clock(&mut self, t: f64) {
        self.clock.observe_clock(t);
    }

    /// The robot's e-stop message (DDS delivers one writer's messages in order).
    pub fn on_platform_estop(&mut self, engaged: bool) {
        self.platform_estop = engaged;
    }

    pub fn on_battery(&mut self, b: pb::BatteryStatus) {
        self.battery = Some(b);
    }

    pub fn now(&self) -> Option<f64> {
        self.clock.now(Instant::now())
    }

    pub fn odom(&self) -> Option<(f64, Pose2, Twist)> {
        self.odom
    }

    pub fn intrinsics(&self) -> Option<pb::CameraIntrinsics> {
        self.intrinsics
    }

    pub fn robot_state(&self) -> RobotState {
        RobotState { platform_estop: self.platform_estop, battery: self.battery }
    }

    fn offer_frame(&mut self) {
        if let Some(f) = self.try_assemble() {
            // A full queue drops the frame: the next one is fresher.
            let _ = self.frames.try_send(f);
        }
    }

    /// Pairs the newest colour and depth images when their stamps agree.
    fn try_assemble(&mut self) -> Option<RosFrame> {
        // A frame without intrinsics cannot be projected: wait for camera_info.
        self.intrinsics?;
        let (c, d) = (self.color.as_ref()?, self.depth.as_ref()?);
        if (c.stamp - d.stamp).abs() > self.tolerance || c.width != d.width || c.height != d.height {
            return None;
        }
        if c.stamp - self.last_frame_stamp < self.min_period {
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

/// A ROS robot as the drive loop sees it: its sensors and its `cmd_vel`.
pub trait RosPlatform {
    /// The driver's name in `EdgeHello`.
    fn driver(&self) -> &'static str;
    fn sensors(&self) -> &Arc<Mutex<Sensors>>;
    fn frames(&mut self) -> &mut mpsc::Receiver<RosFrame>;
    /// Publishes a velocity on `cmd_vel`, stamped `stamp` (sensor time) where
    /// the message carries a stamp.
    fn publish(&self, t: Twist, stamp: Option<f64>);

    fn now(&self) -> Option<f64> {
        Sensors::lock(self.sensors()).now()
    }

    /// Holds the robot at zero.
    fn stop(&self) {
        let now = self.now();
        self.publish(Twist::ZERO, now);
    }
}

pub fn limits_of(opts: &EdgeOptions) -> Limits {
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

/// Drives a started ROS robot until shutdown: the gateway link reconnects
/// with backoff while `cmd_vel` holds zero.
pub async fn drive(
    opts: &EdgeOptions,
    robot: &mut impl RosPlatform,
    shutdown: CancellationToken,
    hooks: Hooks,
) -> anyhow::Result<()> {
    let mut backoff =
        Backoff::new(Duration::from_secs_f64(opts.reconnect_initial_s), Duration::from_secs_f64(opts.reconnect_max_s));
    let limits = limits_of(opts);
    // The Husky's footprint (A200 and A300 alike, within a centimetre).
    let desc = RobotDescription { limits, footprint_length: 0.988, footprint_width: 0.670 };
    let mut gov = Governor::new(limits, opts.deadman_timeout_s);
    let mut status = StatusReporter::default();
    let control = Duration::from_secs_f64(1.0 / opts.control_rate_hz);
    let topics = opts.ros_topics();
    tracing::info!(robot = %opts.robot_id, gateway = %opts.gateway, cmd_vel = %topics.cmd_vel, driver = robot.driver(), "ROS edge agent starting");
    loop {
        // The camera's size is known once a frame has arrived; say hello with what we know.
        let intrinsics = Sensors::lock(robot.sensors()).intrinsics();
        let hello = pb::EdgeHello {
            robot_id: opts.robot_id.clone(),
            driver: robot.driver().into(),
            limits: Some(convert::limits(&desc)),
            camera: Some(camera_info(opts, 0, 0, intrinsics)),
            lockstep: false,
        };
        let connect = Link::connect(opts, hello);
        tokio::pin!(connect);
        // Hold the robot stopped while connecting.
        let mut tick = tokio::time::interval(control);
        let connected = loop {
            tokio::select! {
                _ = shutdown.cancelled() => { robot.stop(); return Ok(()); }
                r = &mut connect => break r,
                _ = tick.tick() => robot.stop(),
            }
        };
        let end = match connected {
            Ok(mut link) => {
                backoff.reset();
                status.reset();
                tracing::info!(robot = %opts.robot_id, "attached to the gateway");
                let mut session =
                    Session { opts, robot: &mut *robot, gov: &mut gov, link: &mut link, status: &mut status };
                session.run(&hooks, &shutdown).await
            }
            Err(e) => SessionEnd::Lost(format!("{e:#}")),
        };
        gov.drop_command();
        robot.stop();
        match end {
            SessionEnd::Finished => return Ok(()),
            SessionEnd::Lost(reason) => {
                let delay = backoff.next_delay();
                tracing::warn!(robot = %opts.robot_id, %reason, retry_in_s = delay.as_secs_f64(), "gateway link down; robot held stopped");
                let until = tokio::time::Instant::now() + delay;
                let mut tick = tokio::time::interval(control);
                loop {
                    tokio::select! {
                        _ = shutdown.cancelled() => { robot.stop(); return Ok(()); }
                        _ = tokio::time::sleep_until(until) => break,
                        _ = tick.tick() => robot.stop(),
                    }
                }
            }
        }
    }
}

/// One attached link's worth of driving a ROS robot.
struct Session<'a, R: RosPlatform> {
    opts: &'a EdgeOptions,
    robot: &'a mut R,
    gov: &'a mut Governor,
    link: &'a mut Link,
    status: &'a mut StatusReporter,
}

impl<R: RosPlatform> Session<'_, R> {
    async fn run(&mut self, hooks: &Hooks, shutdown: &CancellationToken) -> SessionEnd {
        let Session { opts, robot, gov, link, status } = self;
        let opts = *opts;
        let liveness = Duration::from_secs_f64(opts.liveness_timeout_s);
        let mut tick = tokio::time::interval(Duration::from_secs_f64(1.0 / opts.control_rate_hz));
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
        let mut last = LastCommand::new(gov);
        let mut seq = 0u64;
        let driver = robot.driver();
        loop {
            tokio::select! {
                _ = shutdown.cancelled() => { robot.stop(); return SessionEnd::Finished; }
                m = link.recv() => match m {
                    Err(e) => return SessionEnd::Lost(e),
                    Ok(pb::GatewayCommand { kind: Some(pb::gateway_command::Kind::Velocity(v)) }) => last.take(gov, v),
                    Ok(pb::GatewayCommand { kind: Some(pb::gateway_command::Kind::ResetOdometry(_)) }) => {
                        tracing::warn!(driver, "ResetOdometry is not supported by the ROS drivers; odometry goals stay in the robot's odom frame");
                    }
                    Ok(pb::GatewayCommand { kind: Some(pb::gateway_command::Kind::Mission(a)) }) => last.announce(&a),
                    Ok(_) => {}
                },
                Some(f) = robot.frames().recv() => {
                    let odom = Sensors::lock(robot.sensors()).odom();
                    let (odom_pose, odom_twist) = odom.map(|(_, p, t)| (p, t)).unwrap_or_default();
                    let frame = pb::RgbdFrame {
                        robot_id: opts.robot_id.clone(),
                        seq,
                        stamp: f.stamp,
                        camera: Some(camera_info(opts, f.width, f.height, f.intrinsics)),
                        rgb: Some(convert::colour_image(f.width, f.height, std::borrow::Cow::Owned(f.rgb), opts.codecs())),
                        depth: Some(depth_le(f.width, f.height, f.depth_mm_le, opts.codecs())),
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
                        robot.stop();
                        return SessionEnd::Lost(format!("nothing from the gateway for {} s", opts.liveness_timeout_s));
                    }
                    let (now, state, odom) = {
                        let s = Sensors::lock(robot.sensors());
                        (s.now(), s.robot_state(), s.odom())
                    };
                    // Either e-stop holds the robot: the agent's own and the robot's.
                    gov.set_estop(hooks.estop.is_engaged() || state.platform_estop);
                    let (out, verdict) = match now {
                        Some(now) => gov.output(now),
                        None => (Twist::ZERO, Verdict::NoCommand),
                    };
                    robot.publish(out, now);
                    let now = now.unwrap_or(0.0);
                    if let Some(s) = status.update_with(now, verdict, state) && let Err(e) = link.offer(s) {
                        return SessionEnd::Lost(e);
                    }
                    if let Some(obs) = &hooks.observer {
                        let _ = obs.send(StepRecord {
                            seq,
                            stamp: now,
                            odom: odom.map(|(_, p, _)| p).unwrap_or_default(),
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
}

/// The camera's little-endian millimetres as `codecs.depth` sends them.
fn depth_le(width: u32, height: u32, mm_le: Vec<u8>, codecs: crate::Codecs) -> pb::DepthImage {
    match codecs.depth {
        crate::DepthCodec::Raw => pb::DepthImage {
            width,
            height,
            data_mm: mm_le.into(),
            encoding: pb::DepthEncoding::RawU16 as i32,
            disparity_step: 0.0,
        },
        crate::DepthCodec::Rvl | crate::DepthCodec::Disparity => {
            let mm: Vec<u16> = mm_le.chunks_exact(2).map(|b| u16::from_le_bytes([b[0], b[1]])).collect();
            convert::depth_image(width, height, &mm, codecs)
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
        c.observe(f64::NAN, t0);
        let later = t0 + Duration::from_millis(250);
        assert!((c.now(later).unwrap() - 100.25).abs() < 1e-9);
        c.observe_clock(500.0);
        assert!((c.now(later).unwrap() - 100.25).abs() < 1e-9, "/clock is ignored without use_sim_time");
    }

    #[test]
    fn a_simulated_clock_reads_clock_only_and_stands_still_while_paused() {
        let t0 = Instant::now();
        let mut c = SensorClock::simulated();
        c.observe(100.0, t0);
        assert_eq!(c.now(t0), None, "no /clock yet");
        c.observe_clock(12.5);
        c.observe_clock(12.0); // reordered
        assert_eq!(c.now(t0 + Duration::from_secs(10)), Some(12.5));
    }

    fn sensors() -> (Arc<Mutex<Sensors>>, mpsc::Receiver<RosFrame>) {
        Sensors::new(&EdgeOptions { frame_rate: 10.0, ..EdgeOptions::default() }, SensorClock::default())
    }

    #[test]
    fn frames_pair_colour_and_depth_by_stamp_at_the_frame_rate() {
        let (s, mut rx) = sensors();
        let mut s = Sensors::lock(&s);
        let img = || vec![0; 6];
        s.on_color(1.0, 2, 1, img());
        s.on_depth(1.01, 2, 1, vec![0; 4]);
        assert!(rx.try_recv().is_err(), "no frames before camera_info");
        s.on_camera_info(&[1.0, 0.0, 1.0, 0.0, 1.0, 0.5, 0.0, 0.0, 1.0]);
        s.on_depth(1.3, 2, 1, vec![0; 4]);
        assert!(rx.try_recv().is_err(), "stamps 0.3 s apart do not pair");
        s.on_depth(1.01, 2, 1, vec![0; 4]);
        assert_eq!(rx.try_recv().unwrap().stamp, 1.0);
        s.on_color(1.05, 2, 1, img());
        s.on_depth(1.05, 2, 1, vec![0; 4]);
        assert!(rx.try_recv().is_err(), "faster than the frame rate");
        s.on_color(1.1, 2, 1, img());
        s.on_depth(1.1, 2, 1, vec![0; 4]);
        assert_eq!(rx.try_recv().unwrap().stamp, 1.1);
    }
}
