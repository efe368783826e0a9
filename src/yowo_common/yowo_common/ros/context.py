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
