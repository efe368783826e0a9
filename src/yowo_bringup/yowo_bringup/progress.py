"""How far a run is, for the console: the share of the recording replayed, each
stage's state and the replay's ETA; as a live bar on a terminal, as a line every few
seconds otherwise (logs, CI). No ROS here: the run monitor fills RunProgress."""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field

WAITING, RUNNING, DONE, FAILED = "waiting", "running", "done", "failed"


@dataclass
class RunProgress:
    elapsed_s: float
    played: int                      # messages the replay published
    total: int                       # messages it will publish (0: unknown, a live run)
    resent: int = 0                  # sent again to restarted stages
    playing_since_s: float | None = None   # elapsed time when the first message was played
    stages: dict[str, str] = field(default_factory=dict)   # stage -> WAITING | RUNNING | DONE | FAILED

    @property
    def share(self) -> float | None:
        return min(1.0, self.played / self.total) if self.total else None

    @property
    def eta_s(self) -> float | None:
        """Seconds until the replay ends, at the pace so far (the stages finish after it)."""
        share = self.share
        if not share or self.playing_since_s is None or share >= 1.0:
            return None
        return (self.elapsed_s - self.playing_since_s) * (1.0 - share) / share

    def stage_summary(self) -> str:
        by_state: dict[str, list[str]] = {}
        for name, state in self.stages.items():
            by_state.setdefault(state, []).append(name)
        return "; ".join(f"{state}: {', '.join(names)}" for state, names in sorted(by_state.items()))

    def line(self) -> str:
        played = (f"replayed {100 * self.share:3.0f} % ({self.played}/{self.total} messages)" if self.total
                  else "live")
        resent = f", {self.resent} re-sent" if self.resent else ""
        eta = f", replay ETA {self.eta_s:.0f} s" if self.eta_s is not None else ""
        done = sum(s in (DONE, FAILED) for s in self.stages.values())
        return (f"[{self.elapsed_s:6.1f} s] {played}{resent}{eta}; stages done {done}/{len(self.stages)} "
                f"({self.stage_summary()})")


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
    """rich's live bar, within 80 columns: replay share, elapsed time, the replay's ETA and
    how many stages are done (which ones: the line form, the logs)."""

    def __init__(self, description: str):
        from rich.progress import BarColumn, Progress, TaskProgressColumn, TextColumn, TimeElapsedColumn, \
            TimeRemainingColumn

        self._bar = Progress(TextColumn("{task.description}"), BarColumn(bar_width=16), TaskProgressColumn(),
                             TimeElapsedColumn(), TextColumn("replay ETA"), TimeRemainingColumn(),
                             TextColumn("{task.fields[stages]}"), transient=False)
        self._task = self._bar.add_task(description.split()[0], total=None, stages="")
        self._bar.start()

    def __call__(self, p: RunProgress) -> None:
        done = sum(s in (DONE, FAILED) for s in p.stages.values())
        self._bar.update(self._task, completed=p.played, total=p.total or None,
                         stages=f"{done}/{len(p.stages)} stages" + (f", {p.resent} re-sent" if p.resent else ""))

    def close(self) -> None:
        self._bar.stop()


def console_progress(description: str, log=print):
    """The live bar on a terminal, lines otherwise."""
    return ProgressBar(description) if sys.stdout.isatty() else ProgressLines(log)
