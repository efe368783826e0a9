"""Base class of YOWO's pipeline nodes: counted inputs and outputs, status on
/yowo/status/<stage>, and finalisation once every upstream finished and every
message it announced has arrived (so no stage computes on a partial stream)."""

from __future__ import annotations

import time
import traceback
from collections import Counter

from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Header

from yowo_msgs.msg import ReplayStatus, StageStatus

from .. import topics
from ..config import describe_changes, load
from ..memory import release_free_memory
from ..streams import StreamCompletion
from .timing import NodeTiming

REPLAY = topics.REPLAY_STAGE
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
# Streams: reliable and never dropped by the history (the replay applies flow control).
STREAM = QoSProfile(depth=1, history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
# Stage-to-stage streams are also durable: a downstream stage that matches late (its
# subscription discovered after the first messages) still receives all of them.
DURABLE_STREAM = QoSProfile(
    depth=1,
    history=HistoryPolicy.KEEP_ALL,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)


# Topics between YOWO's own nodes (statuses, stage outputs and inputs) go without rclpy's
# default QoS-event handlers (incompatible QoS or type warnings): both ends are ours, and
# each handler is in the wait set the executor builds for every message (measured: half
# the executor's cost per message). Inputs from the replay or live drivers keep them.
OWN_PUB = {"event_callbacks": PublisherEventCallbacks(use_default_callbacks=False)}
OWN_SUB = {"event_callbacks": SubscriptionEventCallbacks(use_default_callbacks=False)}


class RunFilter:
    """Statuses of one run (isolation check): another run's are counted as stray and never
    used; one without a run id (`yowo end-walk`, relayed by a live run's monitor with its
    id) is ignored."""

    def __init__(self, run_id: str):
        self.run_id, self.strays = run_id, 0

    def accept(self, msg) -> bool:
        if msg.run_id == self.run_id:
            return True
        self.strays += bool(msg.run_id)
        return False


class StageNode(Node):
    """Subclasses declare inputs with `stream_input`, outputs with `output`, and
    implement `finalize()`; it runs once, when the inputs are complete."""

    def __init__(self, name: str):
        super().__init__(name)
        self.timing = NodeTiming()
        # Where to write self.timing once finalised ("": nowhere; the supervisor names one,
        # "{node}" in it standing for this node's name when one process hosts several).
        self._stats_file = self.declare_parameter("stats_file", "").value.replace("{node}", self.get_name())
        self.stage = self.get_name()  # a launcher may rename the node (one tracker per camera)
        # Isolation: statuses of other runs are counted and ignored. Incarnation: how often
        # the supervisor restarted this stage (upstream statuses and the replay re-send what
        # a restarted stage missed).
        self.run_id = self.declare_parameter("run_id", "").value
        self.runs = RunFilter(self.run_id)
        self.incarnation = self.declare_parameter("incarnation", 0).value
        # A replay re-sends a restarted stage its topics from the start; until it announces
        # that, the replayed messages reaching this incarnation are out of order: skipped.
        replayed = self.declare_parameter("replayed", False).value
        # Source time (the replay's clock) from which replayed messages count: messages the
        # replay published before its catch-up announcement may still wait in this stage's
        # queues after the announcement; the repetition is all published after it.
        self._replay_since_ns: int | None = 0 if self.incarnation == 0 or not replayed else None
        self.completion = StreamCompletion({})
        self.published: Counter = Counter()
        self._replay_readers: list = []
        self._status_pub = self.create_publisher(StageStatus, topics.status(self.stage), LATCHED, **OWN_PUB)
        self._watched: set[str] = set()
        self.upstream_summaries: dict[str, str] = {}  # upstream stage -> its final summary or failure
        self._finalized = False
        self._announced = False
        self.create_timer(0.2, self._check)
        self.create_timer(2.0, lambda: self.publish_status(StageStatus.STATE_RUNNING) if not self._finalized else None)

    def section(self, cls, where: str, parameter: str = "config"):
        """This node's section of the configuration tree (YAML in its `config` parameter;
        empty: the defaults), or another value of the tree in its own parameter."""
        params = load(cls, self.declare_parameter(parameter, "").value, where=where)
        self.get_logger().info(f"configuration: {describe_changes(params, where)}")
        return params

    # --- wiring -----------------------------------------------------------------
    def stream_input(self, msg_type, topic: str, callback, upstream: str = REPLAY, qos=None):
        """Subscribe to a counted input published by `upstream` (the replay or a stage)."""
        qos = qos or (STREAM if upstream == REPLAY else DURABLE_STREAM)
        self.completion.inputs[topic] = upstream
        self._watch(upstream)
        seen: set[int] | None = set() if upstream != REPLAY else None

        def counted(msg, info):
            if upstream == REPLAY and (
                self._replay_since_ns is None or info["source_timestamp"] < self._replay_since_ns
            ):
                return
            if seen is not None:
                # A restarted upstream stage publishes its stream again from the start; its
                # stamps are strictly increasing, so a stamp seen before is that repetition.
                stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
                if stamp in seen:
                    return
                seen.add(stamp)
            self.completion.on_received(topic)
            started = time.time_ns()
            try:
                callback(msg)
            except Exception as exc:  # a bad message must not kill the stage; it is reported
                self.get_logger().error(f"{topic}: {exc}\n{traceback.format_exc(limit=3)}")
            self.timing.received(topic, info, started, time.time_ns())

        sub = self.create_subscription(msg_type, topic, counted, qos, **({} if upstream == REPLAY else OWN_SUB))
        if upstream == REPLAY:
            self._replay_readers.append(sub)
        return sub

    def output(self, msg_type, topic: str, qos=DURABLE_STREAM):
        pub = self.create_publisher(msg_type, topic, qos, **OWN_PUB)
        stage = self

        class Counted:
            def publish(self, msg):
                pub.publish(msg)
                stage.published[topic] += 1

            def get_subscription_count(self):
                return pub.get_subscription_count()

        return Counted()

    def _watch(self, upstream: str) -> None:
        if upstream in self._watched:
            return
        self._watched.add(upstream)
        if upstream == REPLAY:
            self.create_subscription(ReplayStatus, topics.REPLAY_STATUS, self._on_replay_status, LATCHED, **OWN_SUB)
        else:
            self.create_subscription(
                StageStatus,
                topics.status(upstream),
                lambda m, up=upstream: self._on_stage_status(up, m),
                LATCHED,
                **OWN_SUB,
            )

    def _on_replay_status(self, msg: ReplayStatus, info: dict) -> None:
        if not self.runs.accept(msg):
            return
        if (msg.catch_up_stage, msg.catch_up_incarnation) == (self.stage, self.incarnation):
            self._replay_since_ns = info["source_timestamp"]
        if msg.state == ReplayStatus.STATE_FINISHED:
            if msg.error:
                self.get_logger().warning(f"replay ended early: {msg.error}")
            self.completion.on_upstream_finished(REPLAY, msg.topics, msg.published_counts)

    def _on_stage_status(self, upstream: str, msg: StageStatus) -> None:
        if not self.runs.accept(msg):
            return
        if msg.state in (StageStatus.STATE_FINISHED, StageStatus.STATE_FAILED):
            self.upstream_summaries[upstream] = msg.message
            self.completion.on_upstream_finished(upstream, msg.topics, msg.published_counts)

    # --- lifecycle ----------------------------------------------------------------
    def _check(self) -> None:
        if not self._announced:  # the first tick: wired (the replay waits for this status)
            self._announced = True
            self.publish_status(StageStatus.STATE_RUNNING)
        if self._finalized or not self.completion.inputs or not self.completion.complete or not self.ready():
            return
        self._finalized = True
        self.timing.mark("finalize_start")
        try:
            summary = self.finalize() or ""
        except Exception as exc:
            self.get_logger().error(f"{self.stage} failed: {exc}\n{traceback.format_exc()}")
            self._write_timing()
            self.publish_status(StageStatus.STATE_FAILED, str(exc))
            release_free_memory()
            return
        self._write_timing()
        self.publish_status(StageStatus.STATE_FINISHED, summary)
        self.get_logger().info(f"{self.stage} finished. {summary}")
        # The process stays until the run ends, next to the stages still working.
        release_free_memory()

    def ready(self) -> bool:
        """Whether finalize may run once the counted inputs are complete (a subclass may wait
        for an uncounted input too)."""
        return True

    def finalize(self) -> str | None:
        raise NotImplementedError

    def _write_timing(self) -> None:
        """Before the final status: the supervisor reads the file once the run is over."""
        self.timing.mark("finalize_end")
        if self._stats_file:
            self.timing.write(self._stats_file)

    def publish_status(self, state: int, message: str = "") -> None:
        c = self.completion
        self._status_pub.publish(
            StageStatus(
                header=Header(stamp=self.get_clock().now().to_msg()),
                stage=self.stage,
                state=state,
                topics=list(self.published),
                published_counts=list(self.published.values()),
                input_topics=list(c.inputs),
                received_counts=[c.received[t] for t in c.inputs],
                message=message,
                run_id=self.run_id,
                incarnation=self.incarnation,
                stray_messages=self.runs.strays,
                replay_reader_gids=self._reader_gids(),
            )
        )

    def _reader_gids(self) -> list[str]:
        """GIDs of this process's subscriptions to replayed topics, as the graph lists them."""
        gids = []
        for sub in self._replay_readers:
            gids += [
                bytes(e.endpoint_gid).hex()
                for e in self.get_subscriptions_info_by_topic(sub.topic_name)
                if e.node_name == self.get_name() and e.node_namespace == self.get_namespace()
            ]
        return gids

    @property
    def finished(self) -> bool:
        return self._finalized
