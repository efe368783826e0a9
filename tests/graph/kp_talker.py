"""Publishes N AgentKeypoints (reliable, keep-all) once a subscriber is matched, then waits for acks."""

import faulthandler
import sys
import time

import rclpy
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Header

from yowo_common.ros.context import ros_context
from yowo_msgs.msg import AgentKeypoints, Keypoint2D


def main():
    count = int(sys.argv[1])
    # A hang (seen once in CI, in an unknown stage) ends with every thread's stack on stderr.
    faulthandler.dump_traceback_later(50, exit=True)
    with ros_context():
        node = rclpy.create_node("kp_talker")
        qos = QoSProfile(depth=1, history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
        pub = node.create_publisher(AgentKeypoints, "/cmc/cam0/agent_keypoints", qos)
        deadline = time.monotonic() + 20.0
        while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.05)
        if pub.get_subscription_count() == 0:
            sys.exit("kp_talker: no subscriber matched within 20 s")
        print("matched", file=sys.stderr, flush=True)
        for i in range(count):
            kps = [Keypoint2D(id=j, x=i + 0.25 * j, y=2.0 * i - j, confidence=0.5) for j in range(3)]
            pub.publish(
                AgentKeypoints(header=Header(frame_id="cam0_optical_frame"), camera_name=f"cam{i}", keypoints=kps)
            )
        if not pub.wait_for_all_acked(rclpy.duration.Duration(seconds=20)):
            sys.exit("kp_talker: messages not acknowledged within 20 s")
        print("acknowledged", file=sys.stderr, flush=True)
        node.destroy_node()
    print("shut down", file=sys.stderr, flush=True)


if __name__ == "__main__":
    main()
