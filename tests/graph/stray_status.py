"""Another run's graph on the same domain, as far as statuses go: latch a FINISHED replay
status and FINISHED stage statuses (no messages published) under a foreign run id, and
stay up for a while. A stage that used them would finalise on nothing."""

import sys
import time

import rclpy

from yowo_common import topics
from yowo_common.ros.context import ros_context
from yowo_common.ros.stage import LATCHED
from yowo_msgs.msg import ReplayStatus, StageStatus


def main():
    seconds, stages = float(sys.argv[1]), sys.argv[2:]
    with ros_context():
        node = rclpy.create_node("another_run")
        node.create_publisher(ReplayStatus, topics.REPLAY_STATUS, LATCHED).publish(
            ReplayStatus(state=ReplayStatus.STATE_FINISHED, bag="another recording", run_id="another-run")
        )
        for stage in stages:
            node.create_publisher(StageStatus, topics.status(stage), LATCHED).publish(
                StageStatus(stage=stage, state=StageStatus.STATE_FINISHED, run_id="another-run")
            )
        print("published", flush=True)
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.1)


if __name__ == "__main__":
    main()
