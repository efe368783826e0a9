"""How far a run is, for the console: the share of the recording replayed, each
stage's state and the ETA of the slowest stage; as a live bar on a terminal, as a line every few
seconds otherwise (logs, CI). No ROS here: the run monitor fills RunProgress."""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field

WAITING, RUNNING, DONE, FAILED = "waiting", "running", "done", "failed"


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

    @property
    def share(self) -> float | None:
        return min(1.0, self.played / self.total) if self.total else None

    @property
    def eta_s(self) -> float | None:
        """Seconds until every stage has taken in the whole recording, at the pace so far of
        the slowest (a stage behind the replay sets it; the stages' last steps come after)."""
        share = self.share
        if not share or self.playing_since_s is None:
            return None
        behind = min([share, *(share * c for c in self.consumed.values())])
        if behind >= 1.0 or behind <= 0.0:
            return None
        return (self.elapsed_s - self.playing_since_s) * (1.0 - behind) / behind

    def stage_summary(self) -> str:
        by_state: dict[str, list[str]] = {}
        for name, state in self.stages.items():
            by_state.setdefault(state, []).append(name)
        return "; ".join(f"{state}: {', '.join(names)}" for state, names in sorted(by_state.items()))

    def line(self) -> str:
        played = f"replayed {100 * self.share:3.0f} % ({self.played}/{self.total} messages)" if self.total else "live"
        resent = f", {self.resent} re-sent" if self.resent else ""
        eta = f", ETA {self.eta_s:.0f} s" if self.eta_s is not None else ""
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
        eta = p.eta_s
        self._bar.update(
            self._task,
            completed=p.played,
            total=p.total or None,
            eta=f"ETA {int(eta // 60)}:{int(eta % 60):02d}" if eta is not None else "",
            stages=f"{done}/{len(p.stages)} stages" + (f", {p.resent} re-sent" if p.resent else ""),
        )

    def close(self) -> None:
        self._bar.stop()


def console_progress(description: str, log=print):
    """The live bar on a terminal, lines otherwise."""
    return ProgressBar(description) if sys.stdout.isatty() else ProgressLines(log)
