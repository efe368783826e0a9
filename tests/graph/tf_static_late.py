"""`pub`: latch one TFMessage on /tf_static (reliable, transient-local) and stay up for a while;
`sub`: join late, print the child frames received."""

import sys
import time

import numpy as np
import rclpy
from geometry_msgs.msg import TransformStamped
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Header
from tf2_msgs.msg import TFMessage

from yowo_common.geometry import look_at
from yowo_common.ros.context import ros_context
from yowo_common.rosconv import matrix_to_transform

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def main():
    role, seconds = sys.argv[1], float(sys.argv[2])
    with ros_context():
        node = rclpy.create_node(f"tf_static_{role}")
        if role == "pub":
            tfs = [
                TransformStamped(
                    header=Header(frame_id="map"),
                    child_frame_id=f"cam{i}_optical_frame",
                    transform=matrix_to_transform(look_at([i, 0, 3], [i, 2, 0])),
                )
                for i in range(3)
            ]
            node.create_publisher(TFMessage, "/tf_static", LATCHED).publish(TFMessage(transforms=tfs))
            print("published", flush=True)
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                rclpy.spin_once(node, timeout_sec=0.1)
        else:
            got = []
            node.create_subscription(TFMessage, "/tf_static", got.append, LATCHED)
            end = time.monotonic() + seconds
            while not got and time.monotonic() < end:
                rclpy.spin_once(node, timeout_sec=0.1)
            for msg in got:
                for tf in msg.transforms:
                    print(tf.child_frame_id, np.round(tf.transform.translation.x, 6))
            sys.exit(0 if got else 1)
        node.destroy_node()


if __name__ == "__main__":
    main()
