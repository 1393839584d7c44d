#!/usr/bin/env python3
"""A stand-in for a Clearpath Husky A300 on ROS 2 Jazzy (rclpy), for the
ros2 end-to-end test (tests/tests/ros2_robot.rs).

Under its namespace, as Clearpath's platform does:
- subscribes `cmd_vel` (geometry_msgs/TwistStamped; Twist with --distro humble)
  and integrates it into a unicycle pose, zero while the e-stop is engaged
  (the hardware cuts the motors);
- publishes `platform/odom/filtered` (nav_msgs/Odometry) at 50 Hz,
  `platform/emergency_stop` (std_msgs/Bool) at 10 Hz and
  `platform/bms/state` (sensor_msgs/BatteryState) at 1 Hz;
- publishes a RealSense's colour, aligned depth and camera info at 10 Hz,
  sensor-data QoS, generated: a grey floor and a wall 6 m ahead of the start,
  which comes closer as the robot drives towards it.

Every stamp is the node's clock. Each received command is printed as one
JSON line ({"cmd": ...}: its header stamp, the robot's clock on receipt, the
twist, whether the e-stop was engaged); every odometry message as {"odom": ...}
at 5 Hz. Lines on stdin: `estop on`, `estop off`.
"""
import argparse
import json
import math
import sys
import threading

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, qos_profile_sensor_data
from geometry_msgs.msg import Twist, TwistStamped
from nav_msgs.msg import Odometry
from sensor_msgs.msg import BatteryState, CameraInfo, Image
from std_msgs.msg import Bool

W, H = 64, 48
FX = 34.4  # a D455's 90° horizontal field of view at 64 px


def seconds(t):
    return t.sec + t.nanosec * 1e-9


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--namespace", default="a300_0001")
    ap.add_argument("--distro", choices=["jazzy", "humble"], default="jazzy")
    ap.add_argument("--wall-x", type=float, default=6.0)
    args = ap.parse_args()

    rclpy.init()
    node = rclpy.create_node("fake_a300", namespace=args.namespace)
    lock = threading.Lock()
    state = {"x": 0.0, "y": 0.0, "yaw": 0.0, "v": 0.0, "w": 0.0, "estop": False, "t": None}

    def out(obj):
        sys.stdout.write(json.dumps(obj) + "\n")
        sys.stdout.flush()

    def on_cmd(msg):
        now = seconds(node.get_clock().now().to_msg())
        if args.distro == "jazzy":
            stamp, tw = seconds(msg.header.stamp), msg.twist
        else:
            stamp, tw = None, msg
        with lock:
            state["v"], state["w"] = tw.linear.x, tw.angular.z
            estop = state["estop"]
        out({"cmd": {"stamp": stamp, "recv": now, "linear": tw.linear.x, "angular": tw.angular.z, "estop": estop}})

    cmd_type = TwistStamped if args.distro == "jazzy" else Twist
    node.create_subscription(cmd_type, "cmd_vel", on_cmd, QoSProfile(depth=10))
    odom_pub = node.create_publisher(Odometry, "platform/odom/filtered", 10)
    estop_pub = node.create_publisher(Bool, "platform/emergency_stop", 10)
    bms_pub = node.create_publisher(BatteryState, "platform/bms/state", 10)
    color_pub = node.create_publisher(Image, "/camera/camera/color/image_raw", qos_profile_sensor_data)
    depth_pub = node.create_publisher(Image, "/camera/camera/aligned_depth_to_color/image_raw", qos_profile_sensor_data)
    info_pub = node.create_publisher(CameraInfo, "/camera/camera/color/camera_info", qos_profile_sensor_data)

    # Colour: a grey floor below the horizon, a light wall above it.
    rgb = bytes(([200, 200, 190] * W) * (H // 2) + ([90, 90, 90] * W) * (H - H // 2))
    k = [0]

    def step():
        stamp = node.get_clock().now().to_msg()
        t = seconds(stamp)
        with lock:
            if state["t"] is not None:
                dt = max(0.0, t - state["t"])
                v, w = (0.0, 0.0) if state["estop"] else (state["v"], state["w"])
                state["x"] += v * math.cos(state["yaw"]) * dt
                state["y"] += v * math.sin(state["yaw"]) * dt
                state["yaw"] += w * dt
            state["t"] = t
            x, y, yaw, estop = state["x"], state["y"], state["yaw"], state["estop"]
            v, w = (0.0, 0.0) if estop else (state["v"], state["w"])
        o = Odometry()
        o.header.stamp = stamp
        o.header.frame_id = "odom"
        o.child_frame_id = "base_link"
        o.pose.pose.position.x, o.pose.pose.position.y = x, y
        o.pose.pose.orientation.z, o.pose.pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
        o.twist.twist.linear.x, o.twist.twist.angular.z = v, w
        odom_pub.publish(o)
        if k[0] % 10 == 0:
            out({"odom": {"stamp": t, "x": x, "y": y, "yaw": yaw}})
        if k[0] % 5 == 0:
            e = Bool()
            e.data = estop
            estop_pub.publish(e)
            # The wall ahead, in millimetres, nearer as the robot drives; the floor below the horizon.
            ahead_mm = int(max(300.0, (args.wall_x - x) * 1000.0))
            depth = bytearray()
            for row in range(H):
                for col in range(W):
                    if row < H // 2:
                        mm = ahead_mm
                    else:
                        # Floor 0.6 m below the camera: range along the ray.
                        below = (row - H / 2 + 0.5) / FX
                        mm = min(ahead_mm, int(600.0 / below))
                    depth += mm.to_bytes(2, "little")
            for pub, enc, step_bytes, data in ((color_pub, "rgb8", 3 * W, rgb), (depth_pub, "16UC1", 2 * W, bytes(depth))):
                m = Image()
                m.header.stamp = stamp
                m.header.frame_id = "camera_color_optical_frame"
                m.width, m.height, m.encoding, m.is_bigendian, m.step = W, H, enc, 0, step_bytes
                m.data = data
                pub.publish(m)
            ci = CameraInfo()
            ci.header.stamp = stamp
            ci.header.frame_id = "camera_color_optical_frame"
            ci.width, ci.height = W, H
            ci.k = [FX, 0.0, W / 2, 0.0, FX, H / 2, 0.0, 0.0, 1.0]
            info_pub.publish(ci)
        if k[0] % 50 == 0:
            b = BatteryState()
            b.header.stamp = stamp
            b.voltage = 25.6
            b.percentage = 0.87
            b.present = True
            bms_pub.publish(b)
        k[0] += 1

    node.create_timer(0.02, step)

    def read_stdin():
        for line in sys.stdin:
            cmd = line.strip()
            if cmd in ("estop on", "estop off"):
                with lock:
                    state["estop"] = cmd == "estop on"
                out({"estop": {"engaged": cmd == "estop on", "at": seconds(node.get_clock().now().to_msg())}})

    threading.Thread(target=read_stdin, daemon=True).start()
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    out({"ready": {"namespace": args.namespace, "distro": args.distro}})
    try:
        executor.spin()
    except (KeyboardInterrupt, rclpy.executors.ExternalShutdownException):
        pass


if __name__ == "__main__":
    sys.exit(main())
