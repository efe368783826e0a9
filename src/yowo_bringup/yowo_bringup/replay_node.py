"""replay_node: plays a rosbag2 recording (MCAP or sqlite3) into the graph with the
original stamps and /clock, and announces the end of the recording.

Lossless mode: every publisher is reliable with KEEP_ALL history, and after every
`ack_window` messages on a topic the node waits until all of them are acknowledged
by every matched subscriber (DDS flow control: a subscriber whose KEEP_ALL queue is
full stops acknowledging, so a slow stage slows the replay instead of losing data;
at most `ack_window` messages per topic are ever in flight).

Catch-up: the replay follows the stages' statuses of its run while it plays and until
every stage has finished. When the supervisor restarted a stage (a new incarnation in
its status), playing pauses, and once the replay has discovered the new process's
subscriptions, it sends that stage's topics again from the start up to where playing
is, then resumes. Only one stage reads each replayed topic (tracker or ego mapper),
so nobody else sees the repetition."""

from __future__ import annotations

import heapq
import os
import time
from pathlib import Path

import rclpy
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Header

from yowo_common import topics
from yowo_common.config import describe_changes, load
from yowo_common.ros.bag import (
    BagError,
    BagTopic,
    RawMessage,
    list_topics,
    message_class,
    read_raw,
    recording_damage,
    recording_gaps,
    recording_label,
    unknown_type_reason,
)
from yowo_common.ros.context import ros_context
from yowo_common.ros.stage import LATCHED, RunFilter
from yowo_common.ros.timing import NodeTiming
from yowo_common.rosconv import ns_to_time
from yowo_msgs.msg import ReplayStatus, StageStatus

from .replay import Pacer, ReplayParams, select_topics
from .video import VideoError, VideoInput, probe_video, video_images

# Fast DDS acknowledges only on its heartbeat (3 s by default); this profile shortens it.
FASTDDS_PROFILE = Path(__file__).parent / "config" / "replay_fastdds.xml"


class ReplayNode(Node):
    def __init__(self):
        super().__init__(topics.REPLAY_STAGE)
        # Start-up (until playing) and the time flow control held it back, per topic.
        self.timing = NodeTiming()
        self.stats_file = self.declare_parameter("stats_file", "").value
        # Several recordings read as one are joined by os.pathsep (as run.plan_run passes them).
        self.bag = self.declare_parameter("bag", "").value.split(os.pathsep)
        p = load(ReplayParams, self.declare_parameter("config", "").value, where="replay")
        self.get_logger().info(f"configuration: {describe_changes(p, 'replay')}")
        self.rate, self.lossless, self.publish_clock = p.rate, p.lossless, p.publish_clock
        self.exclude = list(p.exclude_prefixes)
        self.wait_timeout_s, self.ack_timeout_s, self.linger_s = p.wait_timeout_s, p.ack_timeout_s, p.linger_s
        self.ack_window = max(1, p.ack_window)
        self.include = list(self.declare_parameter("topics", [""]).value or [])
        # CCTV video files played as camera image topics: NAME=FILE@START (see video.py).
        self.video_rules = [r for r in self.declare_parameter("videos", [""]).value or [] if r]
        self.videos = []
        self.wait_for = list(self.declare_parameter("wait_for_topics", [""]).value or [])
        # Stages whose subscriptions must all be matched before playing: their status
        # lists their inputs, so each topic waits for exactly its subscribers.
        self.stages = [s for s in self.declare_parameter("stages", [""]).value or [] if s]
        self.run_id = self.declare_parameter("run_id", "").value
        self.recovered = ""  # what was recovered of a damaged recording
        self.state, self.error = ReplayStatus.STATE_PLAYING, ""
        self.start_ns = self.end_ns = 0  # log times of the first and the latest played message
        self.include = [t for t in self.include if t]
        self.wait_for = [t for t in self.wait_for if t]
        self.status_pub = self.create_publisher(ReplayStatus, topics.REPLAY_STATUS, LATCHED)
        self.clock_pub = self.create_publisher(Clock, topics.CLOCK, 10)
        self.pubs = {}
        self.counts: dict[str, int] = {}
        self.unacked: dict[str, int] = {}
        self.resent = 0
        self.stage_status: dict[str, StageStatus] = {}
        self.caught_up: dict[str, int] = {s: 0 for s in self.stages}  # incarnation each stage was served
        self.runs = RunFilter(self.run_id)
        for stage in self.stages:
            self.create_subscription(
                StageStatus, topics.status(stage), lambda m, st=stage: self._on_stage_status(st, m), LATCHED
            )
        self._last_spin = 0.0

    def _on_stage_status(self, stage: str, msg: StageStatus) -> None:
        if self.runs.accept(msg):
            self.stage_status[stage] = msg

    def _spin_now_and_then(self) -> None:
        """Take the stages' statuses while playing (at most every 50 ms: spinning costs)."""
        if time.monotonic() - self._last_spin > 0.05:
            rclpy.spin_once(self, timeout_sec=0)
            self._last_spin = time.monotonic()

    def _qos(self, latched: bool) -> QoSProfile:
        if latched:
            return LATCHED
        if self.lossless:
            return QoSProfile(depth=1, history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
        return QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)

    def _status(self, catch_up: tuple[str, int] = ("", 0)) -> None:
        self.status_pub.publish(
            ReplayStatus(
                catch_up_stage=catch_up[0],
                catch_up_incarnation=catch_up[1],
                header=Header(stamp=ns_to_time(self.end_ns)),
                state=self.state,
                bag=recording_label(self.bag),
                bag_start=ns_to_time(self.start_ns),
                bag_end=ns_to_time(self.end_ns),
                topics=list(self.counts),
                published_counts=list(self.counts.values()),
                error=self.error,
                run_id=self.run_id,
                resent_messages=self.resent,
            )
        )

    def _expected_subscribers(self, deadline: float) -> dict[str, int]:
        """topic -> number of stages that subscribe to it (from their latched status)."""
        while len(self.stage_status) < len(self.stages) and time.monotonic() < deadline:
            rclpy.spin_once(self, timeout_sec=0.05)
        missing = sorted(set(self.stages) - set(self.stage_status))
        if missing:
            self.get_logger().warning(f"no status from stage(s) {', '.join(missing)}")
        expected: dict[str, int] = {}
        for msg in self.stage_status.values():
            for t in msg.input_topics:
                expected[t] = expected.get(t, 0) + 1
        return expected

    def _restarted_stages(self) -> list[str]:
        return [s for s, m in self.stage_status.items() if m.incarnation > self.caught_up[s]]

    def _catch_up(self, stage: str) -> None:
        """Send a restarted stage its replayed topics again, up to where playing is."""
        t0 = time.monotonic()
        deadline = t0 + self.wait_timeout_s
        log = self.get_logger()
        log.info(
            f"{stage} restarted (incarnation {self.stage_status[stage].incarnation}): waiting for its subscriptions"
        )
        while time.monotonic() < deadline:
            status = self.stage_status[stage]
            wanted = [t for t in status.input_topics if t in self.pubs]
            known = {bytes(e.endpoint_gid).hex() for t in wanted for e in self.get_subscriptions_info_by_topic(t)}
            if len(status.replay_reader_gids) >= len(wanted) and known >= set(status.replay_reader_gids):
                break
            rclpy.spin_once(self, timeout_sec=0.05)
        else:
            log.warning(
                f"{stage} (restarted) has not matched the replay's topics after "
                f"{self.wait_timeout_s:.0f} s; sending anyway"
            )
        self.caught_up[stage] = status.incarnation
        # The stage takes replayed messages from this announcement on (acknowledged first,
        # so it is in the stage's queue before the first repeated message).
        self._status((stage, status.incarnation))
        if not self.status_pub.wait_for_all_acked(Duration(seconds=self.ack_timeout_s)):
            log.warning(f"{stage}: the catch-up announcement was not acknowledged")
        todo = {t: self.counts[t] for t in wanted if self.counts[t]}
        log.info(
            f"{stage}: matched after {time.monotonic() - t0:.1f} s; sending it {sum(todo.values())} messages again"
        )
        sent = dict.fromkeys(todo, 0)
        last_status = time.monotonic()
        if todo:
            for raw in played_messages(self.bag, list(todo), self.videos):
                if sent[raw.topic] >= todo[raw.topic]:
                    if all(sent[t] >= n for t, n in todo.items()):
                        break
                    continue
                self._publish(raw)
                sent[raw.topic] += 1
                self.resent += 1
                if time.monotonic() - last_status > 1.0:  # progress (not an announcement)
                    self._status()
                    last_status = time.monotonic()
            for topic in [t for t, n in self.unacked.items() if n]:
                self._wait_acked(topic)
        log.info(
            f"{stage} restarted (incarnation {status.incarnation}): sent it {sum(sent.values())} messages "
            f"again on {', '.join(todo) or 'no topic'} in {time.monotonic() - t0:.1f} s"
        )

    def _publish(self, raw) -> None:
        self.pubs[raw.topic].publish(raw.data)
        if self.lossless and not raw.latched:
            self.unacked[raw.topic] = self.unacked.get(raw.topic, 0) + 1
            if self.unacked[raw.topic] >= self.ack_window:
                self._wait_acked(raw.topic)

    def _wait_for_subscribers(self) -> None:
        """Publishers exist before the first message and every subscriber is matched to
        them: a message published before a subscription matched would be lost to it."""
        deadline = time.monotonic() + self.wait_timeout_s
        expected = self._expected_subscribers(deadline) if self.stages else {t: 1 for t in self.wait_for}
        self.timing.mark("announced")  # every stage's status is here (start-up: imports, discovery)
        missing = [t for t in expected if t in self.pubs]
        while missing and time.monotonic() < deadline:
            missing = [t for t in missing if self.pubs[t].get_subscription_count() < expected[t]]
            time.sleep(0.05)
        if missing:
            self.get_logger().warning(
                f"after {self.wait_timeout_s:.0f} s, not every subscriber is matched on: "
                + ", ".join(f"{t} ({self.pubs[t].get_subscription_count()}/{expected[t]})" for t in missing)
                + "; playing anyway"
            )

    def _wait_acked(self, topic: str) -> None:
        pub = self.pubs[topic]
        t0 = time.monotonic()
        if pub.get_subscription_count() and not pub.wait_for_all_acked(Duration(seconds=self.ack_timeout_s)):
            self.get_logger().error(
                f"{topic}: a subscriber did not acknowledge within {self.ack_timeout_s:.0f} s; continuing"
            )
        self.timing.add_seconds(f"ack_wait {topic}", time.monotonic() - t0)
        self.unacked[topic] = 0

    def run(self) -> int:
        try:
            self.videos = [probe_video(rule) for rule in self.video_rules]
            topics = list_topics(self.bag) + [BagTopic(v.topic, "sensor_msgs/msg/Image", v.frames) for v in self.videos]
            self.recovered = recording_damage(self.bag)
        except (BagError, VideoError) as exc:
            self.get_logger().error(str(exc))
            self.state, self.error = ReplayStatus.STATE_FINISHED, str(exc)
            self._status()
            return 2
        for t in topics:
            if why := unknown_type_reason(t.msgtype):
                self.get_logger().warning(f"{t.name}: skipped, {why}")
        played = select_topics(
            [t.name for t in topics if not unknown_type_reason(t.msgtype)], self.include, self.exclude
        )
        self.counts = {t: 0 for t in played}
        for t in topics:
            if t.name in played:
                self.pubs[t.name] = self.create_publisher(message_class(t.msgtype), t.name, self._qos(t.latched))
        self._wait_for_subscribers()
        self.timing.mark("playing")
        if self.recovered:
            self.get_logger().warning(self.recovered)
        pacer = Pacer(self.rate, gaps_ns=recording_gaps(self.bag))
        last_status = time.monotonic()
        self.get_logger().info(
            f"playing {len(played)} topics of {recording_label(self.bag)} at "
            f"{'max' if self.rate <= 0 else f'{self.rate:g}x'} speed"
            f"{' (lossless)' if self.lossless else ''}"
        )
        try:
            for raw in played_messages(self.bag, played, self.videos):
                self._spin_now_and_then()
                for stage in self._restarted_stages():
                    paused = time.monotonic()
                    self._catch_up(stage)
                    pacer.shift(time.monotonic() - paused)
                time.sleep(pacer.delay_s(raw.log_time_ns))
                self.start_ns = self.start_ns or raw.log_time_ns
                self.end_ns = raw.log_time_ns
                if self.publish_clock:
                    self.clock_pub.publish(Clock(clock=ns_to_time(raw.log_time_ns)))
                self._publish(raw)
                self.counts[raw.topic] += 1
                if time.monotonic() - last_status > 1.0:
                    self._status()
                    last_status = time.monotonic()
        except (BagError, VideoError) as exc:
            self.error = str(exc)
            self.get_logger().error(f"{self.error}; finishing with what was played")
        self.error = self.error or self.recovered
        for topic in [t for t, n in self.unacked.items() if n]:
            self._wait_acked(topic)
        self.state = ReplayStatus.STATE_FINISHED
        self.timing.mark("played")
        if self.stats_file:
            self.timing.write(self.stats_file)
        self._status()
        total = sum(self.counts.values())
        self.get_logger().info(
            f"finished: {total} messages published" + "".join(f"\n  {t}: {n}" for t, n in self.counts.items())
        )
        # Late joiners still get the latched status; a stage restarted from now on until
        # every stage is done is sent what it missed.
        end = time.monotonic() + self.linger_s
        while time.monotonic() < end or not self._stages_done():
            rclpy.spin_once(self, timeout_sec=0.1)
            for stage in self._restarted_stages():
                self._catch_up(stage)
        return 0 if total else 2

    def _stages_done(self) -> bool:
        return all(
            s in self.stage_status and self.stage_status[s].state != StageStatus.STATE_RUNNING for s in self.stages
        )


def played_messages(bag, wanted: list[str], videos: list[VideoInput]):
    """The recording's messages on `wanted` topics and the frames of the videos among them, as
    serialised messages in log-time order (a frame's log time is its stamp)."""

    def frames(video):
        for stamp_ns, msg in video_images(video):
            yield RawMessage(video.topic, "sensor_msgs/msg/Image", stamp_ns, serialize_message(msg), False)

    from_videos = [v for v in videos if v.topic in wanted]
    recorded = read_raw(bag, [t for t in wanted if t not in {v.topic for v in from_videos}])
    return heapq.merge(recorded, *map(frames, from_videos), key=lambda raw: raw.log_time_ns)


def main(args=None):
    os.environ.setdefault("FASTRTPS_DEFAULT_PROFILES_FILE", str(FASTDDS_PROFILE))  # before the DDS starts
    code = 0
    with ros_context(args):
        node = ReplayNode()
        code = node.run()
        node.destroy_node()
    raise SystemExit(code)


if __name__ == "__main__":
    main()
