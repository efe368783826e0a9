"""Receives AgentKeypoints until N arrived (or a timeout) and prints a checksum line per message."""

import faulthandler
import sys
import time

import rclpy
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

from yowo_common.ros.context import ros_context
from yowo_msgs.msg import AgentKeypoints


def main():
    count = int(sys.argv[1])
    received = []
    faulthandler.dump_traceback_later(55, exit=True)  # see kp_talker
    with ros_context():
        node = rclpy.create_node("kp_listener")
        qos = QoSProfile(depth=1, history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
        node.create_subscription(AgentKeypoints, "/cmc/cam0/agent_keypoints", received.append, qos)
        deadline = time.monotonic() + 40.0
        while len(received) < count and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.1)
        node.destroy_node()
    for msg in received:
        print(msg.camera_name, " ".join(f"{k.id}:{k.x}:{k.y}:{k.confidence}" for k in msg.keypoints))
    sys.exit(0 if len(received) == count else 1)


if __name__ == "__main__":
    main()
