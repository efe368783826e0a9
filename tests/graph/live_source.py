"""A live camera source: publishes every message of a recording on its topic (as
drivers would: reliable, no end-of-stream announcement) once every subscriber of a
CMC-only graph has matched, then waits until all of them are acknowledged."""
import sys
import time

import rclpy
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

from yowo_common.ros.bag import list_topics, message_class, read_messages
from yowo_common.ros.context import ros_context


def main():
    bag = sys.argv[1]
    with ros_context():
        node = rclpy.create_node("live_source")
        qos = QoSProfile(depth=1, history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
        pubs = {t.name: node.create_publisher(message_class(t.msgtype), t.name, qos)
                for t in list_topics(bag) if t.name.startswith("/cmc/")}
        # A camera's topics are read by its tracker alone.
        def unmatched():
            return [t for t, p in pubs.items() if p.get_subscription_count() < 1]
        deadline = time.monotonic() + 60.0
        while unmatched() and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.05)
        if unmatched():
            sys.exit(f"live_source: not every subscriber matched after 60 s: {unmatched()}")
        for topic, _, msg in read_messages(bag, list(pubs)):
            pubs[topic].publish(msg)
        for p in pubs.values():
            if not p.wait_for_all_acked(rclpy.duration.Duration(seconds=30)):
                sys.exit("live_source: messages not acknowledged within 30 s")
        node.destroy_node()


if __name__ == "__main__":
    main()
