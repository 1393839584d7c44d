#!/usr/bin/env python3
"""A stand-in for the Husky's sensor side in the ros1 driver test: publishes
small RealSense-like colour, aligned depth and camera-info at 10 Hz and
odometry at 50 Hz, stamped with ROS time, until killed."""
import math
import sys

import rospy
from nav_msgs.msg import Odometry
from sensor_msgs.msg import CameraInfo, Image

W, H = 32, 24


def main():
    rospy.init_node("fake_husky", anonymous=True, disable_signals=True)
    color = rospy.Publisher("/camera/color/image_raw", Image, queue_size=2)
    depth = rospy.Publisher("/camera/aligned_depth_to_color/image_raw", Image, queue_size=2)
    info = rospy.Publisher("/camera/color/camera_info", CameraInfo, queue_size=2)
    odom = rospy.Publisher("/odometry/filtered", Odometry, queue_size=10)
    rgb = bytes([200, 30, 30] * (W * H))
    depth_mm = b"".join(int(1500 + 10 * (i % W)).to_bytes(2, "little") for i in range(W * H))
    rate = rospy.Rate(50)
    k = 0
    print("fake husky publishing", flush=True)
    while not rospy.is_shutdown():
        now = rospy.Time.now()
        o = Odometry()
        o.header.stamp = now
        o.header.frame_id = "odom"
        o.child_frame_id = "base_link"
        o.pose.pose.position.x = 0.01 * k
        o.pose.pose.orientation.z = math.sin(0.05)
        o.pose.pose.orientation.w = math.cos(0.05)
        odom.publish(o)
        if k % 5 == 0:
            for pub, enc, step, data in ((color, "rgb8", 3 * W, rgb), (depth, "16UC1", 2 * W, depth_mm)):
                m = Image()
                m.header.stamp = now
                m.header.frame_id = "camera_color_optical_frame"
                m.width, m.height, m.encoding, m.is_bigendian, m.step, m.data = W, H, enc, 0, step, data
                pub.publish(m)
            ci = CameraInfo()
            ci.header.stamp = now
            ci.width, ci.height = W, H
            ci.K = [17.2, 0, 16.0, 0, 17.2, 12.0, 0, 0, 1]
            info.publish(ci)
        k += 1
        rate.sleep()


if __name__ == "__main__":
    sys.exit(main())
