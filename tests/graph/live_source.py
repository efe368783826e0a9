"""A live camera source: publishes every message of a recording on its topic (as
drivers would: reliable, no end-of-stream announcement) once every subscriber of a
CMC-only graph has matched, then waits until all of them are acknowledged, until every
tracker reports (in its status) that it has taken them all in, and until the group SfM
has taken in all the trackers published."""

import sys
import time

import rclpy
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

from yowo_common import topics
from yowo_common.ros.bag import list_topics, message_class, read_messages
from yowo_common.ros.context import ros_context
from yowo_common.ros.stage import LATCHED
from yowo_msgs.msg import StageStatus


def main():
    bag = sys.argv[1]
    with ros_context():
        node = rclpy.create_node("live_source")
        qos = QoSProfile(depth=1, history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
        pubs = {
            t.name: node.create_publisher(message_class(t.msgtype), t.name, qos)
            for t in list_topics(bag)
            if t.name.startswith("/cmc/")
        }

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
        # Acknowledged is not processed: a stage may still hold messages in its queue, and
        # what a tracker published may not have reached the group SfM yet.
        expected = {t.name: t.count for t in list_topics(bag) if t.name in pubs}
        statuses: dict[str, StageStatus] = {}

        def on_status(msg):
            statuses[msg.stage] = msg
            if msg.stage != topics.GROUP_SFM_STAGE:  # a tracker's outputs are the group SfM's inputs
                expected.update(zip(msg.topics, msg.published_counts))

        stages = sorted({f"keypoint_tracker_{topics.parse_cmc_topic(t)[0]}" for t in pubs}) + [topics.GROUP_SFM_STAGE]
        subs = [node.create_subscription(StageStatus, topics.status(s), on_status, LATCHED) for s in stages]
        deadline = time.monotonic() + 60.0

        def behind():
            late = {
                f"{m.stage} {t}": f"{n}/{expected[t]}"
                for m in statuses.values()
                for t, n in zip(m.input_topics, m.received_counts)
                if t in expected and n < expected[t]
            }
            return {**{s: "no status yet" for s in stages if s not in statuses}, **late}

        while behind() and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.1)
        if behind():
            sys.exit(f"live_source: not every message was taken in after 60 s: {behind()}")
        for s in subs:
            node.destroy_subscription(s)
        node.destroy_node()


if __name__ == "__main__":
    main()
