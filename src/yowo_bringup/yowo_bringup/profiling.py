"""Sampling profiles of the graph's node processes (`yowo run --profile DIR`): one py-spy
recording per node process (collapsed stacks, flamegraph.pl / speedscope read them) and
a summary of the functions each node spent its CPU time in. No rclpy here."""

from __future__ import annotations

import shutil
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path

# py-spy attaches only once the interpreter has started; it says so and exits meanwhile.
ATTACH_RETRY_S, ATTACH_GIVE_UP_S = 0.05, 20.0


def py_spy() -> str:
    """The py-spy executable (the venv's, else the PATH's); ValueError when absent."""
    exe = Path(sys.executable).with_name("py-spy")
    found = str(exe) if exe.exists() else shutil.which("py-spy")
    if not found:
        raise ValueError("--profile needs py-spy (pip install py-spy; it is in requirements.txt)")
    return found


class NodeProfiler:
    """py-spy recording one process into `path` (it ends when the process ends)."""

    def __init__(self, pid: int, path: Path, rate_hz: int, give_up_s: float = ATTACH_GIVE_UP_S):
        self.pid, self.path, self.rate_hz, self.give_up_s = pid, Path(path), rate_hz, give_up_s
        self.cmd = [
            py_spy(),
            "record",
            "--pid",
            str(pid),
            "--format",
            "raw",
            "-o",
            str(self.path),
            "--rate",
            str(rate_hz),
            "--nonblocking",
        ]  # never pauses the node: its timing stays
        self.error = ""
        self._proc: subprocess.Popen | None = None
        self._stopped = threading.Event()
        self._thread = threading.Thread(target=self._attach, daemon=True)
        self._thread.start()

    def _attach(self) -> None:
        give_up = time.monotonic() + self.give_up_s
        log = self.path.with_suffix(".log")
        while not self._stopped.is_set():
            with open(log, "w") as out:
                self._proc = subprocess.Popen(self.cmd, stdout=out, stderr=subprocess.STDOUT)
            if self._proc.wait() == 0 or not Path(f"/proc/{self.pid}").exists():
                return
            if time.monotonic() > give_up:  # e.g. no permission to trace (kernel.yama.ptrace_scope)
                said = log.read_text(errors="replace").strip().splitlines()
                self.error = f"py-spy could not record pid {self.pid}: {said[0] if said else 'no message'}"
                return
            time.sleep(ATTACH_RETRY_S)

    def wait(self, timeout_s: float) -> None:
        """Until the recording is written (the process has ended); then stop retrying."""
        self._thread.join(timeout_s)
        self._stopped.set()
        if self._proc is not None and self._proc.poll() is None:
            self._proc.terminate()
            self._proc.wait(5)


def read_collapsed(path: Path) -> Counter:
    """stack (tuple of 'function (file:line)' frames, outermost first) -> samples."""
    stacks: Counter = Counter()
    for line in Path(path).read_text(errors="replace").splitlines():
        stack, _, n = line.rpartition(" ")
        if stack and n.isdigit():
            stacks[tuple(stack.split(";"))] += int(n)
    return stacks


def _function(frame: str) -> str:
    """'name (package/file.py:123)' -> 'name (package/file.py)': one entry per function."""
    name, _, where = frame.partition(" (")
    return f"{name} ({where.rsplit(':', 1)[0]})" if where else name


def _phase(functions: list[str]) -> str:
    if any(f.startswith("_find_and_load ") for f in functions):
        return "imports"
    if "rclpy/" in functions[-1] or "executors.py" in functions[-1]:
        return "rclpy (executor, wait sets)"
    return "callbacks and the rest"


def top_functions(stacks: Counter, n: int = 10) -> dict:
    """samples; per phase (imports, rclpy's own, the rest); the top functions by own samples;
    the top project functions (yowo_*, module bodies left out) by samples with the function
    anywhere on the stack."""
    own, total, phases = Counter(), Counter(), Counter()
    for stack, count in stacks.items():
        functions = [_function(f) for f in stack]
        own[functions[-1]] += count
        phases[_phase(functions)] += count
        for f in {f for f in functions if "(yowo_" in f and not f.startswith("<module>")}:
            total[f] += count
    return {
        "samples": sum(stacks.values()),
        "phases": phases.most_common(),
        "own": own.most_common(n),
        "cumulative": total.most_common(n),
    }


def _share(rows: list[tuple[str, int]], samples: int) -> list[str]:
    return [f"{100 * c / samples:.0f} % `{f}`" for f, c in rows]


def summary_markdown(profile_dir: Path, rate_hz: int, n: int = 10) -> str:
    """Per node: its samples (s), the share of imports and of rclpy, and its top functions,
    own and cumulative (project functions)."""
    lines = [
        f"# Profile of the graph's nodes (py-spy, {rate_hz} Hz)",
        "",
        "Samples where the node was not idle: running, or ready to run and waiting for a core (on a "
        "loaded machine more than its CPU seconds). Shares are of these samples.",
        "",
    ]
    for path in sorted(Path(profile_dir).glob("*.txt")):
        top = top_functions(read_collapsed(path), n)
        samples = top["samples"]
        if not samples:
            continue
        lines += [
            f"## {path.stem}: {samples / rate_hz:.1f} s not idle",
            "",
            "; ".join(f"{phase} {100 * c / samples:.0f} %" for phase, c in top["phases"]),
            "",
            "| own | cumulative (yowo functions) |",
            "|---|---|",
        ]
        own, cumulative = _share(top["own"], samples), _share(top["cumulative"], samples)
        lines += [
            f"| {own[i] if i < len(own) else ''} | {cumulative[i] if i < len(cumulative) else ''} |"
            for i in range(max(len(own), len(cumulative)))
        ]
        lines.append("")
    return "\n".join(lines)
