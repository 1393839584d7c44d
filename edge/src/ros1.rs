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

//!
//! The drive loop, the sensor clock and the frame pairing are shared with
//! the `ros2` driver (`src/ros_common.rs`).

use std::sync::{Arc, Mutex};
use std::time::Duration;

use tokio::sync::mpsc;
use vlnav_runtime::CancellationToken;
use vlnav_sim::{Pose2, Twist};

use crate::EdgeOptions;
use crate::Hooks;
use crate::ros_common::{RosPlatform, Sensors, drive};
use crate::safety::Backoff;

/// Message types generated from the ROS 1 definitions (see `build.rs`).
pub mod rosmsg {
    rosrust::rosmsg_include!(geometry_msgs / Twist, nav_msgs / Odometry, sensor_msgs / Image, sensor_msgs / CameraInfo);
}

pub use crate::ros_common::{RosFrame, SensorClock, depth_from_ros, rgb_from_ros, yaw_of};

fn stamp_of(t: &rosrust::Time) -> f64 {
    t.sec as f64 + t.nsec as f64 * 1e-9
}

/// The ROS node: the `/cmd_vel` publisher and the sensor subscriptions.
pub struct RosRobot {
    _ros: rosrust::api::Ros,
    cmd_vel: rosrust::Publisher<rosmsg::geometry_msgs::Twist>,
    cmd_vel_topic: String,
    _subscribers: Vec<rosrust::Subscriber>,
    sensors: Arc<Mutex<Sensors>>,
    frames: mpsc::Receiver<RosFrame>,
}

impl RosRobot {
    /// Starts the node (blocking: it registers with the master named by `ROS_MASTER_URI`).
    pub fn start(opts: &EdgeOptions) -> anyhow::Result<RosRobot> {
        let topics = opts.ros_topics();
        let ros = rosrust::api::Ros::new(&opts.ros_node).map_err(|e| {
            anyhow::anyhow!("cannot start ROS node `{}` (is roscore running at ROS_MASTER_URI?): {e}", opts.ros_node)
        })?;
        let cmd_vel = ros
            .publish::<rosmsg::geometry_msgs::Twist>(&topics.cmd_vel, 1)
            .map_err(|e| anyhow::anyhow!("cannot advertise {}: {e}", topics.cmd_vel))?;
        let (sensors, frames) = Sensors::new(opts, SensorClock::default());
        let mut subs = Vec::new();

        let s = sensors.clone();
        subs.push(
            ros.subscribe(&topics.odom, 4, move |m: rosmsg::nav_msgs::Odometry| {
                let p = &m.pose.pose;
                let pose = Pose2::new(
                    p.position.x,
                    p.position.y,
                    yaw_of(p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w),
                );
                let twist = Twist::new(m.twist.twist.linear.x, m.twist.twist.angular.z);
                Sensors::lock(&s).on_odometry(stamp_of(&m.header.stamp), pose, twist);
            })
            .map_err(|e| anyhow::anyhow!("cannot subscribe to {}: {e}", topics.odom))?,
        );
        let s = sensors.clone();
        subs.push(
            ros.subscribe(&topics.camera_info, 1, move |m: rosmsg::sensor_msgs::CameraInfo| {
                Sensors::lock(&s).on_camera_info(&m.K);
            })
            .map_err(|e| anyhow::anyhow!("cannot subscribe to {}: {e}", topics.camera_info))?,
        );
        let s = sensors.clone();
        let color_topic = topics.color.clone();
        subs.push(
            ros.subscribe(&topics.color, 2, move |m: rosmsg::sensor_msgs::Image| {
                match rgb_from_ros(&m.encoding, m.width, m.height, m.step, &m.data) {
                    Ok(rgb) => Sensors::lock(&s).on_color(stamp_of(&m.header.stamp), m.width, m.height, rgb),
                    Err(e) => tracing::warn!(topic = %color_topic, "dropping colour image: {e}"),
                }
            })
            .map_err(|e| anyhow::anyhow!("cannot subscribe to {}: {e}", topics.color))?,
        );
        let s = sensors.clone();
        let depth_topic = topics.depth.clone();
        subs.push(
            ros.subscribe(&topics.depth, 2, move |m: rosmsg::sensor_msgs::Image| {
                match depth_from_ros(&m.encoding, m.is_bigendian != 0, m.width, m.height, m.step, &m.data) {
                    Ok(depth) => Sensors::lock(&s).on_depth(stamp_of(&m.header.stamp), m.width, m.height, depth),
                    Err(e) => tracing::warn!(topic = %depth_topic, "dropping depth image: {e}"),
                }
            })
            .map_err(|e| anyhow::anyhow!("cannot subscribe to {}: {e}", topics.depth))?,
        );
        Ok(RosRobot { _ros: ros, cmd_vel, cmd_vel_topic: topics.cmd_vel, _subscribers: subs, sensors, frames })
    }
}

impl RosPlatform for RosRobot {
    fn driver(&self) -> &'static str {
        "ros1"
    }

    fn sensors(&self) -> &Arc<Mutex<Sensors>> {
        &self.sensors
    }

    fn frames(&mut self) -> &mut mpsc::Receiver<RosFrame> {
        &mut self.frames
    }

    /// Publishes a velocity on `/cmd_vel` (geometry_msgs/Twist has no stamp).
    fn publish(&self, t: Twist, _stamp: Option<f64>) {
        let mut msg = rosmsg::geometry_msgs::Twist::default();
        msg.linear.x = t.linear;
        msg.angular.z = t.angular;
        if let Err(e) = self.cmd_vel.send(msg) {
            tracing::warn!(topic = %self.cmd_vel_topic, "cannot publish: {e}");
        }
    }
}

/// Runs the `ros1` driver until shutdown: the ROS node lives for the whole
/// run, started again with backoff until the master answers.
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
    drive(opts, &mut robot, shutdown, hooks).await
}
