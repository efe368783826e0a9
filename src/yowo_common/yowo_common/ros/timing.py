"""Where a node's wall time goes (issue #19's profile of the graph): per input topic how
long messages waited in the node's queue before their callback ran and how long the
callbacks took, and the node's milestones (created, first and last input, finalised).
The supervisor names a `stats_file` per node and puts them into run_log.yaml. No rclpy."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml


@dataclass
class TopicTiming:
    waits_ms: list[float] = field(default_factory=list)  # received by the middleware -> callback starts
    latency_ms: list[float] = field(default_factory=list)  # published -> callback starts
    handling_s: float = 0.0  # in the callbacks
    first: float = 0.0  # wall clock (epoch s) of the first callback
    last: float = 0.0

    def summary(self) -> dict:
        def q(values):
            v = np.asarray(values)
            return {
                "p50": round(float(np.median(v)), 1),
                "p95": round(float(np.percentile(v, 95)), 1),
                "max": round(float(v.max()), 1),
            }

        return {
            "messages": len(self.waits_ms),
            "queue_wait_ms": q(self.waits_ms),
            "latency_ms": q(self.latency_ms),
            "handling_s": round(self.handling_s, 3),
            "first": self.first,
            "last": self.last,
        }


@dataclass
class NodeTiming:
    created: float = field(default_factory=time.time)
    topics: dict[str, TopicTiming] = field(default_factory=dict)
    marks: dict[str, float] = field(default_factory=dict)  # e.g. finalize_start, finalize_end
    seconds: dict[str, float] = field(default_factory=dict)  # accumulated, e.g. the replay's ack waits

    def received(self, topic: str, info: dict, started_ns: int, ended_ns: int) -> None:
        """One callback: `info` is rclpy's message info (source and received timestamps, ns),
        `started_ns`/`ended_ns` the wall clock (time.time_ns) around the callback."""
        t = self.topics.setdefault(topic, TopicTiming(first=started_ns / 1e9))
        t.waits_ms.append((started_ns - info["received_timestamp"]) / 1e6)
        t.latency_ms.append((started_ns - info["source_timestamp"]) / 1e6)
        t.handling_s += (ended_ns - started_ns) / 1e9
        t.last = ended_ns / 1e9

    def mark(self, name: str) -> None:
        self.marks[name] = time.time()

    def add_seconds(self, name: str, seconds: float) -> None:
        self.seconds[name] = self.seconds.get(name, 0.0) + seconds

    def write(self, path: str | Path) -> None:
        Path(path).write_text(
            yaml.safe_dump(
                {
                    "created": self.created,
                    "marks": self.marks,
                    "seconds": {k: round(v, 3) for k, v in self.seconds.items()},
                    "topics": {t: s.summary() for t, s in self.topics.items()},
                },
                sort_keys=False,
            )
        )


def relative_to(doc: dict, t0: float) -> dict:
    """A written NodeTiming with its wall-clock times as seconds since `t0` (the run's start)."""

    def rel(t: float):
        return round(t - t0, 2) if t else None

    return {
        "created_s": rel(doc.get("created", 0.0)),
        **{f"{k}_s": rel(v) for k, v in doc.get("marks", {}).items()},
        **({"seconds": doc["seconds"]} if doc.get("seconds") else {}),
        "topics": {
            t: {
                **{k: v for k, v in s.items() if k not in ("first", "last")},
                "first_s": rel(s["first"]),
                "last_s": rel(s["last"]),
            }
            for t, s in doc.get("topics", {}).items()
        },
    }
