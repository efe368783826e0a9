"""rclpy process lifetime helpers."""
from __future__ import annotations

import contextlib

import rclpy
from rclpy.executors import ExternalShutdownException


@contextlib.contextmanager
def ros_context(args=None):
    """`with rclpy.init()` for Jazzy (whose init() is not a context manager):
    init, run, and shut down cleanly on Ctrl-C or an external shutdown."""
    rclpy.init(args=args)
    try:
        yield
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        rclpy.try_shutdown()


def spin_node(node_factory, args=None) -> None:
    """Entry point body of a node executable: create the node, spin it single-threaded
    (a multi-threaded executor burns a core here), shut down cleanly on Ctrl-C/SIGTERM."""
    with ros_context(args):
        node = node_factory()
        try:
            rclpy.spin(node)
        finally:
            node.destroy_node()
