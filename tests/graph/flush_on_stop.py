"""`pub <go_file>`: a node run by `spin_node` prints "matched" once its reader matched, latches
one message once `go_file` exists too, prints "published", and spins until stopped;
`sub <seconds>`: prints "matched" once a publisher matched, then the message it receives."""

import sys
import time
from pathlib import Path

import rclpy
from std_msgs.msg import String

from yowo_common.ros.context import ros_context, spin_node
from yowo_common.ros.stage import LATCHED

TOPIC = "/yowo/test/flush"


class Publisher(rclpy.node.Node):
    def __init__(self, go_file: Path):
        super().__init__("flush_pub")
        self.pub, self.go_file = self.create_publisher(String, TOPIC, LATCHED), go_file
        self.matched = self.sent = False
        self.create_timer(0.05, self._tick)

    def _tick(self):
        if not self.matched and self.pub.get_subscription_count():
            self.matched = True
            print("matched", flush=True)
        if self.matched and not self.sent and self.go_file.exists():
            self.pub.publish(String(data="final status"))
            self.sent = True
            print("published", flush=True)


def main():
    if sys.argv[1] == "pub":
        spin_node(lambda: Publisher(Path(sys.argv[2])))
        return
    got = []
    with ros_context():
        node = rclpy.create_node("flush_sub")
        node.create_subscription(String, TOPIC, lambda m: got.append(m.data), LATCHED)
        end = time.monotonic() + float(sys.argv[2])
        while not node.count_publishers(TOPIC) and time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.05)
        print("matched", flush=True)
        while not got and time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.05)
        print(*got, flush=True)
        node.destroy_node()
    sys.exit(0 if got else 1)


if __name__ == "__main__":
    main()
