"""The run's own node: it follows every stage's status, the replay's and the graph's
outputs for graph_runner.execute; and `yowo end-walk`'s announcement."""

from __future__ import annotations

import time

import rclpy
from rclpy.node import Node

from yowo_common import topics
from yowo_common.ros.bag import message_class
from yowo_common.ros.context import ros_context
from yowo_common.ros.stage import DURABLE_STREAM, LATCHED, RunFilter
from yowo_msgs.msg import ReplayStatus, StageStatus

from .progress import DONE, FAILED, RUNNING, WAITING, RunProgress, final_step_rates, stage_kind

# A stage that receives none of a replayed topic's messages this long is named on the console.
SILENT_INPUT_S = 60.0


def silent_inputs(
    replay, statuses: dict, unreceived: dict, told: set, now_s: float, after_s: float = SILENT_INPUT_S
) -> list[str]:
    """Once each (`told`): a running stage that has received none of a topic's messages
    `after_s` seconds after it first saw the replay had published some (`unreceived`:
    (stage, topic) -> then); such messages never reach it."""
    if replay is None:
        return []
    played = dict(zip(replay.topics, replay.published_counts))
    said = []
    for stage, msg in statuses.items():
        if msg.state != StageStatus.STATE_RUNNING:
            continue
        for topic, received in zip(msg.input_topics, msg.received_counts):
            if received or not played.get(topic):
                continue
            since = unreceived.setdefault((stage, topic), now_s)
            if now_s - since > after_s and (stage, topic) not in told:
                told.add((stage, topic))
                said.append(
                    f"stage '{stage}' has received none of the {played[topic]} messages the replay "
                    f"published on {topic} in {now_s - since:.0f} s (see logs/{stage}.log)"
                )
    return said


class RunMonitor(Node):
    def __init__(
        self, stages: list[str], outputs: dict[str, str], run_id: str = "", streams: dict[str, str] | None = None
    ):
        super().__init__("yowo_run")
        self.run_id = run_id
        self.runs = RunFilter(run_id)
        self.status: dict[str, StageStatus] = {}
        self.replay: ReplayStatus | None = None
        self.outputs: dict[str, object] = {}
        self.final_rates = final_step_rates()  # this machine's history of the stages' final steps
        self.finishing_since: dict[str, float] = {}
        self.replayed_at: float | None = None  # elapsed time when the replay was seen finished
        self.done_at: dict[str, float] = {}
        for s in stages:
            self.create_subscription(StageStatus, topics.status(s), lambda m, s=s: self._on_status(s, m), LATCHED)
        self.create_subscription(ReplayStatus, topics.REPLAY_STATUS, self._on_replay, LATCHED)
        self._relay = None
        self._announced = None
        self._playing_since: float | None = None
        self._unreceived: dict[tuple[str, str], float] = {}  # (stage, topic) -> when first seen unreceived
        self._told: set[tuple[str, str]] = set()
        for topic, msgtype in outputs.items():
            self.create_subscription(
                message_class(msgtype), topic, lambda m, t=topic: self.outputs.__setitem__(t, m), LATCHED
            )
        # Streams: every message, in `outputs` as a list (the stages publish them durable), and
        # when each arrived here (seconds since this node started).
        self.arrivals: dict[str, list[float]] = {}
        self._started = time.monotonic()
        for topic, msgtype in (streams or {}).items():
            self.create_subscription(
                message_class(msgtype), topic, lambda m, t=topic: self._on_stream(t, m), DURABLE_STREAM
            )

    def _on_stream(self, topic: str, msg) -> None:
        self.outputs.setdefault(topic, []).append(msg)
        self.arrivals.setdefault(topic, []).append(time.monotonic() - self._started)

    def _on_status(self, stage: str, msg: StageStatus) -> None:
        if self.runs.accept(msg):
            self.status[stage] = msg

    def _on_replay(self, msg: ReplayStatus) -> None:
        if self.runs.accept(msg):
            self.replay = msg
        if msg.run_id in ("", self.run_id) and msg.state == ReplayStatus.STATE_FINISHED:
            self._announced = msg  # `yowo end-walk` (to this or to any live run)

    def relay_end_of_walk(self) -> None:
        """Live runs: take `yowo end-walk`'s announcement for this run and keep it latched
        for the rest of the run, so a stage whose subscription matches late still gets it."""
        if self._relay is None and self._announced is not None:
            self.replay = self._announced
            self.replay.run_id = self.run_id
            self._relay = self.create_publisher(ReplayStatus, topics.REPLAY_STATUS, LATCHED)
            self._relay.publish(self.replay)

    def finished(self, stage: str) -> StageStatus | None:
        msg = self.status.get(stage)
        return msg if msg is not None and msg.state != StageStatus.STATE_RUNNING else None

    def progress(self, stages: list[str], elapsed_s: float, total: int) -> RunProgress:
        played = sum(self.replay.published_counts) if self.replay else 0
        if played and self._playing_since is None:
            self._playing_since = elapsed_s
        states, consumed = {}, {}
        published = dict(zip(self.replay.topics, self.replay.published_counts)) if self.replay else {}
        for s in stages:
            msg = self.status.get(s)
            states[s] = (
                WAITING
                if msg is None
                else RUNNING
                if msg.state == StageStatus.STATE_RUNNING
                else FAILED
                if msg.state == StageStatus.STATE_FAILED
                else DONE
            )
            if states[s] == RUNNING:
                # Of the replayed messages meant for it, how many it has taken in.
                mine = [(int(n), published[t]) for t, n in zip(msg.input_topics, msg.received_counts) if t in published]
                if sum(p for _, p in mine):
                    consumed[s] = min(1.0, sum(n for n, _ in mine) / sum(p for _, p in mine))
        self._note_final_steps(states, consumed, elapsed_s)
        return RunProgress(
            elapsed_s=elapsed_s,
            played=played,
            total=total,
            resent=self.replay.resent_messages if self.replay else 0,
            playing_since_s=self._playing_since,
            stages=states,
            consumed=consumed,
            final_rates=self.final_rates,
            finishing_since_s={s: t for s, t in self.finishing_since.items() if states.get(s) == RUNNING},
        )

    def _note_final_steps(self, states: dict[str, str], consumed: dict[str, float], elapsed_s: float) -> None:
        """When each stage's final step began (a replay-fed stage: it had taken in every
        replayed message; a stage fed by stages: they had all ended) and when it ended."""
        if self.replay is not None and self.replay.state == ReplayStatus.STATE_FINISHED and self.replayed_at is None:
            self.replayed_at = elapsed_s
        for s, state in states.items():
            fed_by_stages = s in (topics.GROUP_SFM_STAGE, topics.FUSION_STAGE)
            upstream = [
                u for u in states if u != s and (s == topics.FUSION_STAGE or stage_kind(u) == topics.TRACKER_STAGE)
            ]
            if fed_by_stages:
                began = all(states[u] in (DONE, FAILED) for u in upstream)
            else:  # a stage that ended before a status showed all its input taken in began at the replay's end
                began = self.replayed_at is not None and (consumed.get(s, 0.0) >= 1.0 or state in (DONE, FAILED))
            if state != WAITING and began:
                ended_unseen = not fed_by_stages and state in (DONE, FAILED)
                self.finishing_since.setdefault(s, self.replayed_at if ended_unseen else elapsed_s)
            if state in (DONE, FAILED):
                self.done_at.setdefault(s, elapsed_s)

    def final_steps(self) -> dict[str, float]:
        """Each stage's final step [s], as seen from here (for the history)."""
        return {s: self.done_at[s] - t for s, t in self.finishing_since.items() if s in self.done_at}

    def spin_once(self, timeout_s: float) -> None:
        rclpy.spin_once(self, timeout_sec=timeout_s)

    def silent_inputs(self, now_s: float) -> list[str]:
        return silent_inputs(self.replay, self.status, self._unreceived, self._told, now_s)

    def strays(self) -> dict[str, int]:
        """Status messages of other runs each node heard and ignored."""
        counts = {s: int(m.stray_messages) for s, m in self.status.items()}
        return {"yowo_run": self.runs.strays, **counts}


def end_walk(linger_s: float = 5.0, run_id: str = "") -> None:
    """Live operation: announce the end of the walk (what a replay does at the end of a
    recording), so every stage finalises with what it has received. Without a run id the
    announcement goes to any live run on the domain (its monitor relays it to its stages)."""
    from yowo_common.ros.stage import REPLAY

    with ros_context([]):
        node = Node("yowo_end_walk")
        pub = node.create_publisher(ReplayStatus, topics.REPLAY_STATUS, LATCHED)
        pub.publish(ReplayStatus(state=ReplayStatus.STATE_FINISHED, bag=f"live ({REPLAY} not used)", run_id=run_id))
        # Latched: stages that match while we linger still get it. Discovery on a busy
        # machine takes seconds, so the linger starts once a first stage has matched.
        deadline = time.monotonic() + 60.0
        while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.1)
        end = time.monotonic() + linger_s
        while time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.1)
        node.destroy_node()
