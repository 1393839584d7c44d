//! The `ros2` driver: a ROS 2 node on DDS (ros2-client, pure Rust on
//! RustDDS; no ROS 2 installation needed to build) beside a Husky A300 on
//! Jazzy or an A200 on Humble or Jazzy.
//!
//! Publishes the governor's output on `<ns>/cmd_vel` at the control rate:
//! `geometry_msgs/msg/TwistStamped` on Jazzy (what Clearpath's Jazzy platform
//! listens to), `Twist` on Humble. Subscribes to the platform's odometry,
//! its emergency stop and battery, and the RealSense colour, aligned depth
//! and camera-info topics (sensor-data QoS: best effort, which matches both
//! best-effort and reliable publishers). The drive loop, sensor clock and
//! frame pairing are shared with `ros1` (`src/ros_common.rs`).
//!
//! Sensor time comes from the header stamps; with `--use-sim-time`, from
//! `/clock`. The robot's own e-stop holds `cmd_vel` at zero exactly as the
//! agent's does, whatever the gateway sends.

use std::sync::{Arc, Mutex};

use futures::StreamExt;
use ros2_client::qos::{Durability, History, WhenFull};
use ros2_client::{Context, MessageTypeName, Name, Node, NodeName, NodeOptions, Publisher, QosProfile};
use tokio::sync::mpsc;
use tokio::task::JoinSet;
use vlnav_proto::v1 as pb;
use vlnav_runtime::CancellationToken;
use vlnav_sim::{Pose2, Twist};

use crate::ros_common::{RosFrame, RosPlatform, SensorClock, Sensors, depth_from_ros, drive, rgb_from_ros, yaw_of};
use crate::{EdgeOptions, Hooks, RosDistro};

/// The ROS 2 messages the driver uses, laid out field for field as their
/// `.msg` definitions (CDR encodes fields in order, with no names).
pub mod msg {
    use serde::{Deserialize, Serialize};

    /// builtin_interfaces/msg/Time.
    #[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
    pub struct Time {
        pub sec: i32,
        pub nanosec: u32,
    }

    impl Time {
        pub fn seconds(&self) -> f64 {
            self.sec as f64 + self.nanosec as f64 * 1e-9
        }

        /// The stamp for `t` seconds; saturates outside what the message can hold.
        pub fn from_seconds(t: f64) -> Self {
            if !t.is_finite() || t <= 0.0 {
                return Self::default();
            }
            let sec = t.floor().min(i32::MAX as f64);
            let nanosec = ((t - sec) * 1e9).round().clamp(0.0, 999_999_999.0);
            Self { sec: sec as i32, nanosec: nanosec as u32 }
        }
    }

    /// std_msgs/msg/Header.
    #[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
    pub struct Header {
        pub stamp: Time,
        pub frame_id: String,
    }

    /// geometry_msgs/msg/Vector3 (also Point: the same three doubles).
    #[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
    pub struct Vector3 {
        pub x: f64,
        pub y: f64,
        pub z: f64,
    }

    /// geometry_msgs/msg/Quaternion.
    #[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
    pub struct Quaternion {
        pub x: f64,
        pub y: f64,
        pub z: f64,
        pub w: f64,
    }

    /// geometry_msgs/msg/Twist.
    #[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
    pub struct Twist {
        pub linear: Vector3,
        pub angular: Vector3,
    }

    /// geometry_msgs/msg/TwistStamped.
    #[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
    pub struct TwistStamped {
        pub header: Header,
        pub twist: Twist,
    }

    /// geometry_msgs/msg/Pose.
    #[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
    pub struct Pose {
        pub position: Vector3,
        pub orientation: Quaternion,
    }

    /// A fixed array of doubles, `double[N]`: CDR writes its N elements and
    /// no length. (De)serialised in a loop in a function of its own: serde's
    /// derive unrolls arrays, and the unrolled reads of an Odometry's two
    /// covariances overflow LLVM's stack while it optimises them.
    #[derive(Clone, Copy, Debug, PartialEq)]
    pub struct F64Array<const N: usize>(pub [f64; N]);

    impl<const N: usize> Default for F64Array<N> {
        fn default() -> Self {
            Self([0.0; N])
        }
    }

    impl<const N: usize> Serialize for F64Array<N> {
        #[inline(never)]
        fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
            use serde::ser::SerializeTuple;
            let mut t = s.serialize_tuple(N)?;
            for v in &self.0 {
                t.serialize_element(v)?;
            }
            t.end()
        }
    }

    impl<'de, const N: usize> Deserialize<'de> for F64Array<N> {
        #[inline(never)]
        fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
            struct Visit<const N: usize>;
            impl<'de, const N: usize> serde::de::Visitor<'de> for Visit<N> {
                type Value = F64Array<N>;
                fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                    write!(f, "{N} doubles")
                }
                #[inline(never)]
                fn visit_seq<A: serde::de::SeqAccess<'de>>(self, mut seq: A) -> Result<Self::Value, A::Error> {
                    let mut out = [0.0; N];
                    for (i, v) in out.iter_mut().enumerate() {
                        *v = seq.next_element()?.ok_or_else(|| serde::de::Error::invalid_length(i, &self))?;
                    }
                    Ok(F64Array(out))
                }
            }
            d.deserialize_tuple(N, Visit::<N>)
        }
    }

    /// A 6×6 covariance, row-major.
    pub type Covariance = F64Array<36>;

    /// geometry_msgs/msg/PoseWithCovariance.
    #[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
    pub struct PoseWithCovariance {
        pub pose: Pose,
        pub covariance: Covariance,
    }

    /// geometry_msgs/msg/TwistWithCovariance.
    #[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
    pub struct TwistWithCovariance {
        pub twist: Twist,
        pub covariance: Covariance,
    }

    /// nav_msgs/msg/Odometry.
    #[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
    pub struct Odometry {
        pub header: Header,
        pub child_frame_id: String,
        pub pose: PoseWithCovariance,
        pub twist: TwistWithCovariance,
    }

    /// sensor_msgs/msg/Image.
    #[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
    pub struct Image {
        pub header: Header,
        pub height: u32,
        pub width: u32,
        pub encoding: String,
        pub is_bigendian: u8,
        pub step: u32,
        pub data: Vec<u8>,
    }

    /// sensor_msgs/msg/RegionOfInterest.
    #[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
    pub struct RegionOfInterest {
        pub x_offset: u32,
        pub y_offset: u32,
        pub height: u32,
        pub width: u32,
        pub do_rectify: bool,
    }

    /// sensor_msgs/msg/CameraInfo.
    #[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
    pub struct CameraInfo {
        pub header: Header,
        pub height: u32,
        pub width: u32,
        pub distortion_model: String,
        pub d: Vec<f64>,
        pub k: F64Array<9>,
        pub r: F64Array<9>,
        pub p: F64Array<12>,
        pub binning_x: u32,
        pub binning_y: u32,
        pub roi: RegionOfInterest,
    }

    /// std_msgs/msg/Bool.
    #[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
    pub struct Bool {
        pub data: bool,
    }

    /// sensor_msgs/msg/BatteryState.
    #[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
    pub struct BatteryState {
        pub header: Header,
        pub voltage: f32,
        pub temperature: f32,
        pub current: f32,
        pub charge: f32,
        pub capacity: f32,
        pub design_capacity: f32,
        pub percentage: f32,
        pub power_supply_status: u8,
        pub power_supply_health: u8,
        pub power_supply_technology: u8,
        pub present: bool,
        pub cell_voltage: Vec<f32>,
        pub cell_temperature: Vec<f32>,
        pub location: String,
        pub serial_number: String,
    }

    /// rosgraph_msgs/msg/Clock.
    #[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
    pub struct Clock {
        pub clock: Time,
    }
}

/// The absolute name of `topic` in namespace `ns` (ROS 2 name resolution
/// without `~` and substitutions): a name starting with `/` is absolute; any
/// other is under the namespace.
pub fn resolve_topic(ns: &str, topic: &str) -> Result<String, String> {
    let topic = topic.trim();
    if topic.is_empty() || topic.ends_with('/') || topic.contains("//") {
        return Err(format!("`{topic}` is not a ROS 2 topic name"));
    }
    if topic.starts_with('/') {
        return Ok(topic.to_string());
    }
    let ns = ns.trim().trim_matches('/');
    Ok(if ns.is_empty() { format!("/{topic}") } else { format!("/{ns}/{topic}") })
}

/// The node's namespace: `/` or `/<ns>`.
fn node_namespace(ns: &str) -> String {
    format!("/{}", ns.trim().trim_matches('/'))
}

/// The battery as the gateway is told it: the charge only where the
/// message gives one (BatteryState says NaN when unknown).
pub fn battery_status(stamp: f64, b: &msg::BatteryState, low_below: f64) -> pb::BatteryStatus {
    let fraction = if b.percentage.is_finite() && b.percentage >= 0.0 { (b.percentage as f64).min(1.0) } else { -1.0 };
    let voltage = if b.voltage.is_finite() && b.voltage > 0.0 { b.voltage as f64 } else { 0.0 };
    pb::BatteryStatus { stamp, fraction, voltage, low: fraction >= 0.0 && fraction < low_below }
}

/// Best effort, volatile, the newest few: what ROS 2 calls sensor data QoS.
/// A best-effort reader matches reliable and best-effort writers alike.
fn sensor_qos(depth: usize) -> QosProfile {
    QosProfile::subscription_default()
        .reliability_best_effort()
        .durability(Durability::Volatile)
        .history(History::KeepLast { depth })
}

/// `cmd_vel`: reliable (a ROS 2 controller's default), keep the newest.
fn command_qos() -> QosProfile {
    QosProfile::publisher_default()
        .reliability_reliable(WhenFull::DEFAULT)
        .durability(Durability::Volatile)
        .history(History::KeepLast { depth: 1 })
}

enum CmdVel {
    Stamped(Publisher<msg::TwistStamped>),
    Plain(Publisher<msg::Twist>),
}

/// The ROS 2 node: the `cmd_vel` publisher and the subscriptions' tasks.
pub struct Ros2Robot {
    // Declared first so the tasks holding the subscriptions end before the node.
    tasks: JoinSet<()>,
    cmd_vel: CmdVel,
    cmd_vel_topic: String,
    frame_id: String,
    sensors: Arc<Mutex<Sensors>>,
    frames: mpsc::Receiver<RosFrame>,
    _node: Node,
    _context: Context,
}

impl Ros2Robot {
    /// Joins the DDS domain (`ROS_DOMAIN_ID`, default 0) and creates the
    /// publisher and subscriptions. Must run inside a tokio runtime.
    pub fn start(opts: &EdgeOptions) -> anyhow::Result<Ros2Robot> {
        let topics = opts.ros_topics();
        let ns = &opts.ros_namespace;
        let domain = match std::env::var("ROS_DOMAIN_ID") {
            Ok(v) if !v.trim().is_empty() => v
                .trim()
                .parse::<u16>()
                .ok()
                .filter(|d| *d <= 232)
                .ok_or_else(|| anyhow::anyhow!("ROS_DOMAIN_ID={v} is not a domain id (0 to 232)"))?,
            _ => 0,
        };
        let context = Context::with_options(ros2_client::ContextOptions::new().domain_id(domain))
            .map_err(|e| anyhow::anyhow!("cannot join DDS domain {domain}: {e:?}"))?;
        let node_name = NodeName::new(&node_namespace(ns), &opts.ros_node)
            .map_err(|e| anyhow::anyhow!("bad ROS 2 node name {}/{}: {e}", node_namespace(ns), opts.ros_node))?;
        let mut node = context
            .new_node(node_name, NodeOptions::new().enable_rosout(false).start_parameter_services(false))
            .map_err(|e| anyhow::anyhow!("cannot create ROS 2 node: {e:?}"))?;
        let clock = if opts.use_sim_time { SensorClock::simulated() } else { SensorClock::default() };
        let (sensors, frames) = Sensors::new(opts, clock);

        let name = |topic: &str| -> anyhow::Result<(String, Name)> {
            let full = resolve_topic(ns, topic).map_err(anyhow::Error::msg)?;
            let n = Name::parse(&full).map_err(|e| anyhow::anyhow!("bad ROS 2 topic name {full}: {e}"))?;
            Ok((full, n))
        };

        let (cmd_vel_topic, cmd_name) = name(&topics.cmd_vel)?;
        let cmd_vel = match opts.ros_distro {
            RosDistro::Jazzy => {
                let t = node
                    .create_topic(&cmd_name, MessageTypeName::new("geometry_msgs", "TwistStamped"), &command_qos())
                    .map_err(|e| anyhow::anyhow!("cannot create topic {cmd_vel_topic}: {e:?}"))?;
                CmdVel::Stamped(
                    node.create_publisher(&t, None)
                        .map_err(|e| anyhow::anyhow!("cannot advertise {cmd_vel_topic}: {e:?}"))?,
                )
            }
            RosDistro::Humble => {
                let t = node
                    .create_topic(&cmd_name, MessageTypeName::new("geometry_msgs", "Twist"), &command_qos())
                    .map_err(|e| anyhow::anyhow!("cannot create topic {cmd_vel_topic}: {e:?}"))?;
                CmdVel::Plain(
                    node.create_publisher(&t, None)
                        .map_err(|e| anyhow::anyhow!("cannot advertise {cmd_vel_topic}: {e:?}"))?,
                )
            }
        };

        let mut tasks = JoinSet::new();
        // Subscribes `topic` with `qos` and hands each message to `on`.
        macro_rules! subscribe {
            ($topic:expr, $pkg:literal, $ty:literal, $msg:ty, $qos:expr, $on:expr) => {{
                let (full, n) = name($topic)?;
                let t = node
                    .create_topic(&n, MessageTypeName::new($pkg, $ty), &$qos)
                    .map_err(|e| anyhow::anyhow!("cannot create topic {full}: {e:?}"))?;
                let sub = node
                    .create_subscription::<$msg>(&t, None)
                    .map_err(|e| anyhow::anyhow!("cannot subscribe to {full}: {e:?}"))?;
                let on = $on;
                tasks.spawn(async move {
                    let mut stream = std::pin::pin!(sub.async_stream());
                    while let Some(m) = stream.next().await {
                        match m {
                            Ok((m, _info)) => on(m),
                            Err(e) => tracing::warn!(topic = %full, "dropping a message that does not decode: {e:?}"),
                        }
                    }
                });
            }};
        }

        let s = sensors.clone();
        subscribe!(&topics.odom, "nav_msgs", "Odometry", msg::Odometry, sensor_qos(10), move |m: msg::Odometry| {
            let p = &m.pose.pose;
            let pose = Pose2::new(
                p.position.x,
                p.position.y,
                yaw_of(p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w),
            );
            let twist = Twist::new(m.twist.twist.linear.x, m.twist.twist.angular.z);
            Sensors::lock(&s).on_odometry(m.header.stamp.seconds(), pose, twist);
        });
        let s = sensors.clone();
        subscribe!(
            &topics.camera_info,
            "sensor_msgs",
            "CameraInfo",
            msg::CameraInfo,
            sensor_qos(1),
            move |m: msg::CameraInfo| Sensors::lock(&s).on_camera_info(&m.k.0)
        );
        let s = sensors.clone();
        let color_topic = topics.color.clone();
        subscribe!(&topics.color, "sensor_msgs", "Image", msg::Image, sensor_qos(2), move |m: msg::Image| {
            match rgb_from_ros(&m.encoding, m.width, m.height, m.step, &m.data) {
                Ok(rgb) => Sensors::lock(&s).on_color(m.header.stamp.seconds(), m.width, m.height, rgb),
                Err(e) => tracing::warn!(topic = %color_topic, "dropping colour image: {e}"),
            }
        });
        let s = sensors.clone();
        let depth_topic = topics.depth.clone();
        subscribe!(&topics.depth, "sensor_msgs", "Image", msg::Image, sensor_qos(2), move |m: msg::Image| {
            match depth_from_ros(&m.encoding, m.is_bigendian != 0, m.width, m.height, m.step, &m.data) {
                Ok(mm) => Sensors::lock(&s).on_depth(m.header.stamp.seconds(), m.width, m.height, mm),
                Err(e) => tracing::warn!(topic = %depth_topic, "dropping depth image: {e}"),
            }
        });
        let s = sensors.clone();
        let estop_topic = topics.estop.clone();
        subscribe!(&topics.estop, "std_msgs", "Bool", msg::Bool, sensor_qos(1), move |m: msg::Bool| {
            let mut g = Sensors::lock(&s);
            if g.robot_state().platform_estop != m.data {
                tracing::warn!(topic = %estop_topic, engaged = m.data, "the robot's emergency stop changed");
            }
            g.on_platform_estop(m.data);
        });
        let s = sensors.clone();
        let low = opts.battery_low;
        subscribe!(
            &topics.battery,
            "sensor_msgs",
            "BatteryState",
            msg::BatteryState,
            sensor_qos(1),
            move |m: msg::BatteryState| {
                let mut g = Sensors::lock(&s);
                let stamp = m.header.stamp.seconds();
                g.on_battery(battery_status(stamp, &m, low));
            }
        );
        if opts.use_sim_time {
            let s = sensors.clone();
            subscribe!("/clock", "rosgraph_msgs", "Clock", msg::Clock, sensor_qos(1), move |m: msg::Clock| {
                Sensors::lock(&s).on_clock(m.clock.seconds())
            });
        }
        tracing::info!(namespace = %node_namespace(ns), domain, cmd_vel = %cmd_vel_topic, distro = ?opts.ros_distro, "ROS 2 node up");
        Ok(Ros2Robot {
            tasks,
            cmd_vel,
            cmd_vel_topic,
            frame_id: "base_link".into(),
            sensors,
            frames,
            _node: node,
            _context: context,
        })
    }
}

impl Drop for Ros2Robot {
    fn drop(&mut self) {
        self.tasks.abort_all();
    }
}

impl RosPlatform for Ros2Robot {
    fn driver(&self) -> &'static str {
        "ros2"
    }

    fn sensors(&self) -> &Arc<Mutex<Sensors>> {
        &self.sensors
    }

    fn frames(&mut self) -> &mut mpsc::Receiver<RosFrame> {
        &mut self.frames
    }

    /// Publishes on `cmd_vel`, stamped (Jazzy) with sensor time: the robot's
    /// clock, or the simulation's with `--use-sim-time`; 0 before the first
    /// sensor message (only zero velocities are published then).
    fn publish(&self, t: Twist, stamp: Option<f64>) {
        let twist = msg::Twist {
            linear: msg::Vector3 { x: t.linear, ..Default::default() },
            angular: msg::Vector3 { z: t.angular, ..Default::default() },
        };
        let sent = match &self.cmd_vel {
            CmdVel::Stamped(p) => {
                let header = msg::Header {
                    stamp: msg::Time::from_seconds(stamp.unwrap_or(0.0)),
                    frame_id: self.frame_id.clone(),
                };
                p.publish(msg::TwistStamped { header, twist }).map_err(|e| format!("{e:?}"))
            }
            CmdVel::Plain(p) => p.publish(twist).map_err(|e| format!("{e:?}")),
        };
        if let Err(e) = sent {
            tracing::warn!(topic = %self.cmd_vel_topic, "cannot publish: {e}");
        }
    }
}

/// Runs the `ros2` driver until shutdown.
pub async fn run_ros2(opts: &EdgeOptions, shutdown: CancellationToken, hooks: Hooks) -> anyhow::Result<()> {
    let mut robot = Ros2Robot::start(opts)?;
    drive(opts, &mut robot, shutdown, hooks).await
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn topic_names_resolve_under_the_robots_namespace() {
        assert_eq!(resolve_topic("a300_0001", "cmd_vel").unwrap(), "/a300_0001/cmd_vel");
        assert_eq!(
            resolve_topic("/a300_0001/", "platform/odom/filtered").unwrap(),
            "/a300_0001/platform/odom/filtered"
        );
        assert_eq!(resolve_topic("", "cmd_vel").unwrap(), "/cmd_vel");
        assert_eq!(
            resolve_topic("a300_0001", "/camera/camera/color/image_raw").unwrap(),
            "/camera/camera/color/image_raw"
        );
        assert!(resolve_topic("a", "cmd_vel/").is_err());
        assert!(resolve_topic("a", "a//b").is_err());
        assert!(resolve_topic("a", " ").is_err());
        assert_eq!(node_namespace(""), "/");
        assert_eq!(node_namespace("/a300_0001/"), "/a300_0001");
    }

    #[test]
    fn stamps_round_trip_and_saturate() {
        let t = msg::Time::from_seconds(1795821753.25);
        assert_eq!((t.sec, t.nanosec), (1795821753, 250_000_000));
        assert!((t.seconds() - 1795821753.25).abs() < 1e-6);
        assert_eq!(msg::Time::from_seconds(f64::NAN), msg::Time::default());
        assert_eq!(msg::Time::from_seconds(-3.0), msg::Time::default());
        assert_eq!(msg::Time::from_seconds(1e12).sec, i32::MAX);
    }

    #[test]
    fn battery_reports_unknown_charge_as_negative_and_flags_low() {
        let b = |percentage: f32, voltage: f32| msg::BatteryState { percentage, voltage, ..Default::default() };
        let s = battery_status(1.0, &b(0.15, 25.2), 0.2);
        assert!((s.fraction - 0.15).abs() < 1e-6 && s.low && (s.voltage - 25.2).abs() < 1e-4);
        let s = battery_status(1.0, &b(f32::NAN, f32::NAN), 0.2);
        assert_eq!((s.fraction, s.voltage, s.low), (-1.0, 0.0, false));
        assert!(!battery_status(1.0, &b(0.8, 26.0), 0.2).low);
        assert_eq!(battery_status(1.0, &b(1.7, 26.0), 0.2).fraction, 1.0);
    }
}
