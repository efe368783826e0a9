"""Extensions found through Python entry points, as ros2cli finds its verbs. The
yowo_eval package, when installed, adds verbs (`eval`, `bench`) and evaluates a run
against its recording's ground truth; the runtime never imports it by name and works
without it (a robot's install has no benchmark)."""

from __future__ import annotations

from importlib.metadata import entry_points

VERBS = "yowo.verbs"  # callables taking the CLI's subparsers
EVALUATOR = "yowo.evaluator"  # a module with evaluate_run(out_dir, bag), print_tables, write_metrics


def add_verbs(subparsers) -> None:
    for ep in sorted(entry_points(group=VERBS), key=lambda e: e.name):
        ep.load()(subparsers)


def evaluator():
    """The installed evaluation plugin, or None."""
    eps = sorted(entry_points(group=EVALUATOR), key=lambda e: e.name)
    return eps[0].load() if eps else None
