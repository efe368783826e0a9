"""rclpy process lifetime helpers."""

from __future__ import annotations

import contextlib
import signal
import sys
import time

import rclpy
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.qos import ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions

# On Ctrl-C, how long a node waits at most for every matched reader to acknowledge what it
# published: a stage stopped right after its final status (the supervisor of its host saw
# it at once) took it with it before a reader on another host had it; one lost UDP packet
# is re-sent only by a writer still alive (CI at 3a1a918: a split run's other host never
# heard that fusion had finished).
FLUSH_S = 5.0
# A process hosting several nodes of one executable (the supervisor's trackers) gets their
# names on its command line, before --ros-args: `--nodes keypoint_tracker_a,keypoint_tracker_b`.
NODES_ARG = "--nodes"


@contextlib.contextmanager
def ros_context(args=None, signal_handlers: bool = True):
    """`with rclpy.init()` for Jazzy (whose init() is not a context manager):
    init, run, and shut down cleanly on Ctrl-C or an external shutdown.
    `signal_handlers=False`: rclpy's own (which shut the context down at once) are not
    installed; Ctrl-C and SIGTERM are Python's KeyboardInterrupt, and the context is still
    usable in its handler."""
    rclpy.init(args=args, signal_handler_options=None if signal_handlers else SignalHandlerOptions.NO)
    if not signal_handlers:
        signal.signal(signal.SIGTERM, signal.default_int_handler)
    try:
        yield
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        rclpy.try_shutdown()


def flush_publishers(node, timeout_s: float = FLUSH_S) -> bool:
    """Wait (at most `timeout_s` in all) until every matched reader of each reliable
    publisher of `node` acknowledged all it was sent; whether they all did."""
    end = time.monotonic() + timeout_s
    for pub in list(node.publishers):
        if pub.qos_profile.reliability != ReliabilityPolicy.RELIABLE or not pub.get_subscription_count():
            continue
        if not pub.wait_for_all_acked(Duration(seconds=max(0.0, end - time.monotonic()))):
            return False
    return True


def hosted_node_names(args=None) -> list[str]:
    """The node names given with NODES_ARG (before --ros-args), [] without it."""
    argv = list(sys.argv if args is None else args)
    end = argv.index("--ros-args") if "--ros-args" in argv else len(argv)
    if NODES_ARG in argv[:end] and argv.index(NODES_ARG) + 1 < end:
        return [n for n in argv[argv.index(NODES_ARG) + 1].split(",") if n]
    return []


def spin_node(node_factory, args=None) -> None:
    """Entry point body of a node executable: create the node (with NODES_ARG, one node of
    each name: `node_factory(name)`), spin single-threaded (a multi-threaded executor burns
    a core here); on Ctrl-C deliver what they published (see FLUSH_S), then shut down."""
    names = hosted_node_names(args)
    with ros_context(args, signal_handlers=False):
        nodes = [node_factory(n) for n in names] if names else [node_factory()]
        executor = SingleThreadedExecutor()
        for node in nodes:
            executor.add_node(node)
        try:
            executor.spin()
        except KeyboardInterrupt:
            for node in nodes:
                if not flush_publishers(node):
                    node.get_logger().warning(
                        f"stopped with messages not acknowledged by every reader after {FLUSH_S:.0f} s"
                    )
        finally:
            for node in nodes:
                node.destroy_node()
