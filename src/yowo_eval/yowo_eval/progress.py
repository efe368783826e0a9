"""A transient rich progress bar around a long call that reports (done, total)."""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

T = TypeVar("T")


def with_progress(run: Callable[[Callable[[int, int], None]], T], label: str = "importing") -> T:
    from rich.progress import Progress

    with Progress(transient=True) as bar:
        task = bar.add_task(label, total=None)
        return run(lambda done, total: bar.update(task, completed=done, total=total))
