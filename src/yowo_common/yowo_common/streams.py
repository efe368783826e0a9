"""End-of-stream bookkeeping without ROS: a stage is complete when every upstream
has announced it finished and every message it announced has been received."""

from __future__ import annotations

from collections import Counter


class StreamCompletion:
    def __init__(self, inputs: dict[str, str]):
        """inputs: input topic -> name of the upstream that publishes it."""
        self.inputs = dict(inputs)
        self.received: Counter = Counter()
        self.expected: dict[str, int] = {}
        self.finished_upstreams: set[str] = set()

    def on_received(self, topic: str) -> None:
        self.received[topic] += 1

    def on_upstream_finished(self, upstream: str, topics, counts) -> None:
        announced = dict(zip(topics, (int(c) for c in counts)))
        self.finished_upstreams.add(upstream)
        for topic, source in self.inputs.items():
            if source == upstream:
                self.expected[topic] = announced.get(topic, 0)

    @property
    def complete(self) -> bool:
        return all(src in self.finished_upstreams for src in self.inputs.values()) and all(
            self.received[t] >= n for t, n in self.expected.items()
        )

    def waiting_for(self) -> str:
        """What is still outstanding, for progress and timeout messages."""
        parts = [f"{src} to finish" for src in sorted(set(self.inputs.values()) - self.finished_upstreams)]
        parts += [f"{t}: {self.received[t]}/{n}" for t, n in sorted(self.expected.items()) if self.received[t] < n]
        return ", ".join(parts) or "nothing"
