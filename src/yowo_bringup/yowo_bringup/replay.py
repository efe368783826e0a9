"""Replay logic without ROS: which topics to play and when (pacing)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from yowo_common.topics import GT_PREFIX


@dataclass(frozen=True)
class ReplayParams:
    """The `replay` section of the configuration tree."""

    rate: float = 0.0  # playback speed; 0: as fast as the graph keeps up (lossless) [x real time]
    lossless: bool = True  # reliable KEEP_ALL + wait for acknowledgements every ack_window
    ack_window: int = 16  # messages per topic in flight at most [count]
    ack_timeout_s: float = 60.0  # a subscriber that acknowledges nothing this long is given up
    wait_timeout_s: float = 30.0  # for the stages' subscriptions before playing
    publish_clock: bool = True  # /clock at the recording's time
    exclude_prefixes: tuple[str, ...] = (GT_PREFIX,)  # never played (ground truth)
    # How long the replay stays up after every stage is done. Late joiners still get the latched
    # final status: under load the run monitor matches it late, and the run log would lose its counts.
    linger_s: float = 5.0


@dataclass
class Pacer:
    """Maps bag time to wall time at `rate` x real time (rate <= 0: as fast as possible).
    `gaps_ns`: (end, start) of the silences between recordings read as one: not waited for
    (a second walk may be recorded days after the first)."""

    rate: float
    gaps_ns: list[tuple[int, int]] = field(default_factory=list)
    _bag0: int | None = None
    _wall0: float = 0.0

    def delay_s(self, bag_time_ns: int, now_s: float | None = None) -> float:
        """Seconds to wait before playing a message stamped bag_time_ns."""
        now_s = time.monotonic() if now_s is None else now_s
        if self._bag0 is None:
            self._bag0, self._wall0 = bag_time_ns, now_s
        if self.rate <= 0:
            return 0.0
        skipped = sum(start - end for end, start in self.gaps_ns if self._bag0 <= end and start <= bag_time_ns)
        due = self._wall0 + (bag_time_ns - self._bag0 - skipped) / 1e9 / self.rate
        return max(0.0, due - now_s)

    def shift(self, seconds: float) -> None:
        """Playing paused this long (a catch-up): later messages are due that much later."""
        self._wall0 += seconds


def select_topics(all_topics: list[str], include: list[str], exclude_prefixes: list[str]) -> list[str]:
    """Topics to play: `include` (all when empty), minus those under an excluded prefix
    (ground truth by default: the pipeline never sees it)."""
    chosen = [t for t in all_topics if not include or t in include]
    return [t for t in chosen if not any(t.startswith(p) for p in exclude_prefixes)]
