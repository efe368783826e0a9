"""Counts messages on the given topics (`topic=pkg/msg/Type` args) with a slow callback,
until the replay reports FINISHED and every played topic has all its messages; prints JSON."""

import json
import sys
import time

import rclpy
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from yowo_common.ros.bag import message_class
from yowo_common.ros.context import ros_context
from yowo_msgs.msg import ReplayStatus


def main():
    delay_s = float(sys.argv[1])
    specs = dict(a.split("=") for a in sys.argv[2:])
    counts = {t: 0 for t in specs}
    finished = []

    def counter(topic):
        def cb(_msg):
            counts[topic] += 1
            time.sleep(delay_s)  # a stage slower than the recording

        return cb

    with ros_context():
        node = rclpy.create_node("count_listener")
        qos = QoSProfile(depth=1, history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
        for topic, msgtype in specs.items():
            node.create_subscription(message_class(msgtype), topic, counter(topic), qos)
        latched = QoSProfile(
            depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
        )
        node.create_subscription(
            ReplayStatus,
            "/yowo/replay/status",
            lambda m: finished.append(m) if m.state == ReplayStatus.STATE_FINISHED else None,
            latched,
        )
        deadline = time.monotonic() + 90.0
        while time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.05)
            if finished:
                played = dict(zip(finished[-1].topics, finished[-1].published_counts))
                if all(counts.get(t, 0) >= n for t, n in played.items() if t in counts):
                    break
        node.destroy_node()
    played = dict(zip(finished[-1].topics, finished[-1].published_counts)) if finished else {}
    print(json.dumps({"received": counts, "published": played}))


if __name__ == "__main__":
    main()
