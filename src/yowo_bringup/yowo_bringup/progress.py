"""How far a run is, for the console: the share of the recording replayed, each
stage's state and the whole run's ETA (the slowest stage's intake, then the stages' final
steps as long as earlier runs on this machine took per replayed message); as a live bar on a
terminal, as a line every few seconds otherwise (logs, CI). No ROS here: the run monitor fills
RunProgress."""

from __future__ import annotations

import os
import statistics
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from yowo_common import topics

WAITING, RUNNING, DONE, FAILED = "waiting", "running", "done", "failed"
HISTORY_RUNS = 10  # final-step durations kept per stage kind


def stage_kind(stage: str) -> str:
    """The trackers are one kind (their final steps take alike); other stages are their own."""
    return topics.TRACKER_STAGE if stage.startswith(topics.TRACKER_STAGE) else stage


def history_path() -> Path:
    """Where the final steps of this machine's runs are kept (XDG cache)."""
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "yowo" / "final_steps.yaml"


def final_step_rates(path: Path | None = None) -> dict[str, float]:
    """Per stage kind, the median of its final step's seconds per replayed message over the last
    runs here (none: no history, or an unreadable file: the ETA then leaves the final steps out)."""
    path = path or history_path()
    try:
        doc = yaml.safe_load(path.read_text()) or {}
        return {k: statistics.median(float(x) for x in v) for k, v in doc.items() if v}
    except (OSError, yaml.YAMLError, TypeError, ValueError, AttributeError):
        return {}


def record_final_steps(seconds: dict[str, float], messages: int, path: Path | None = None) -> None:
    """Adds a finished run's final steps (stage -> seconds from its intake's end, or its
    upstreams' end, to its own) to the history."""
    if messages <= 0:
        return
    path = path or history_path()
    try:
        doc = yaml.safe_load(path.read_text()) if path.exists() else {}
        doc = doc if isinstance(doc, dict) else {}
        rates: dict[str, list[float]] = {}
        for stage, t in seconds.items():
            rates.setdefault(stage_kind(stage), []).append(max(0.0, float(t)) / messages)
        for kind, r in rates.items():
            doc[kind] = [*doc.get(kind, []), max(r)][-HISTORY_RUNS:]
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(yaml.safe_dump(doc))
    except (OSError, yaml.YAMLError, TypeError, ValueError):
        pass  # a history that cannot be kept costs the next runs their ETA's final steps only


@dataclass(kw_only=True)
class RunProgress:
    elapsed_s: float
    played: int  # messages the replay published
    total: int  # messages it will publish (0: unknown, a live run)
    resent: int = 0  # sent again to restarted stages
    playing_since_s: float | None = None  # elapsed time when the first message was played
    stages: dict[str, str] = field(default_factory=dict)  # stage -> WAITING | RUNNING | DONE | FAILED
    # running stage -> the share of the replayed messages meant for it that it has taken in
    consumed: dict[str, float] = field(default_factory=dict)
    # stage kind -> its final step's seconds per replayed message on this machine (history)
    final_rates: dict[str, float] = field(default_factory=dict)
    # running stage -> elapsed time when it had taken in all its messages (its final step began)
    finishing_since_s: dict[str, float] = field(default_factory=dict)

    @property
    def share(self) -> float | None:
        return min(1.0, self.played / self.total) if self.total else None

    @property
    def intake_eta_s(self) -> float | None:
        """Seconds until every stage has taken in the whole recording, at the pace so far of
        the slowest (a stage behind the replay sets it); 0 once all is in."""
        share = self.share
        if not share or self.playing_since_s is None:
            return None
        behind = min([share, *(share * c for c in self.consumed.values())])
        if behind <= 0.0:
            return None
        return max(0.0, (self.elapsed_s - self.playing_since_s) * (1.0 - behind) / behind)

    @property
    def eta_s(self) -> float | None:
        """Seconds until the run ends: the intake, then the final steps along the graph
        (trackers -> group SfM, with the ego mapper -> fusion), each as long as its history
        says less what it has already run. Without a history for every stage left, the intake
        alone (None once it is over)."""
        intake = self.intake_eta_s
        if intake is None:
            return None
        left = any(state in (WAITING, RUNNING) for state in self.stages.values())
        if not left or not self.eta_covers_final_steps:
            return intake if intake > 0 else None
        ends: dict[str, float] = {}
        for kind in (topics.TRACKER_STAGE, topics.EGO_STAGE, topics.GROUP_SFM_STAGE, topics.FUSION_STAGE):
            left = [s for s, state in self.stages.items() if stage_kind(s) == kind and state in (WAITING, RUNNING)]
            if not any(stage_kind(s) == kind for s in self.stages):
                continue
            after = {
                topics.GROUP_SFM_STAGE: [topics.TRACKER_STAGE],
                topics.FUSION_STAGE: [topics.TRACKER_STAGE, topics.EGO_STAGE, topics.GROUP_SFM_STAGE],
            }.get(kind, [])
            start = max([ends.get(k, 0.0) for k in after] + [0.0 if after else intake])
            final = self.final_rates.get(kind, 0.0) * self.total
            ends[kind] = max(
                [
                    start + final - (self.elapsed_s - self.finishing_since_s[s])
                    if s in self.finishing_since_s
                    else start + final
                    for s in left
                ]
                + [0.0]
            )
        return max(ends.values(), default=intake)

    @property
    def eta_covers_final_steps(self) -> bool:
        """Whether this machine's history covers every stage still to finish."""
        return all(stage_kind(s) in self.final_rates for s, st in self.stages.items() if st in (WAITING, RUNNING))

    def eta_text(self) -> str:
        eta = self.eta_s
        if eta is None:
            return ""
        return f"ETA {int(eta // 60)}:{int(eta % 60):02d}" + ("" if self.eta_covers_final_steps else "+")

    def stage_summary(self) -> str:
        by_state: dict[str, list[str]] = {}
        for name, state in self.stages.items():
            by_state.setdefault(state, []).append(name)
        return "; ".join(f"{state}: {', '.join(names)}" for state, names in sorted(by_state.items()))

    def line(self) -> str:
        played = f"replayed {100 * self.share:3.0f} % ({self.played}/{self.total} messages)" if self.total else "live"
        resent = f", {self.resent} re-sent" if self.resent else ""
        # "+": the stages' final steps come on top (no history of them on this machine yet).
        eta = (
            f", ETA {self.eta_s:.0f} s{'' if self.eta_covers_final_steps else ' + final steps'}"
            if self.eta_s is not None
            else ""
        )
        done = sum(s in (DONE, FAILED) for s in self.stages.values())
        return (
            f"[{self.elapsed_s:6.1f} s] {played}{resent}{eta}; stages done {done}/{len(self.stages)} "
            f"({self.stage_summary()})"
        )


class ProgressLines:
    """A line every `period_s` (not a terminal)."""

    def __init__(self, log=print, period_s: float = 5.0):
        self.log, self.period_s, self._last = log, period_s, None

    def __call__(self, p: RunProgress) -> None:
        if self._last is None or time.monotonic() - self._last > self.period_s:
            self._last = time.monotonic()
            self.log(p.line())

    def close(self) -> None:
        pass


class ProgressBar:
    """rich's live bar, within 80 columns: replay share, elapsed time, the ETA of the slowest
    stage and how many stages are done (which ones: the line form, the logs)."""

    def __init__(self, description: str):
        from rich.progress import BarColumn, Progress, TaskProgressColumn, TextColumn, TimeElapsedColumn

        self._bar = Progress(
            TextColumn("{task.description}"),
            BarColumn(bar_width=16),
            TaskProgressColumn(),
            TimeElapsedColumn(),
            TextColumn("{task.fields[eta]}"),
            TextColumn("{task.fields[stages]}"),
            transient=False,
        )
        self._task = self._bar.add_task(description.split()[0], total=None, stages="", eta="")
        self._bar.start()

    def __call__(self, p: RunProgress) -> None:
        done = sum(s in (DONE, FAILED) for s in p.stages.values())
        self._bar.update(
            self._task,
            completed=p.played,
            total=p.total or None,
            eta=p.eta_text(),
            stages=f"{done}/{len(p.stages)} stages" + (f", {p.resent} re-sent" if p.resent else ""),
        )

    def close(self) -> None:
        self._bar.stop()


def console_progress(description: str, log=print):
    """The live bar on a terminal, lines otherwise."""
    return ProgressBar(description) if sys.stdout.isatty() else ProgressLines(log)
