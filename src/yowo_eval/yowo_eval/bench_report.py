"""results.json and BENCHMARKS.md of `yowo bench` (the tables: bench_markdown), with the
command, versions and machine; the sections other commands write into BENCHMARKS.md stay."""

from __future__ import annotations

import json
import os
import shlex
import sys
import time
from pathlib import Path

from .bench_markdown import markdown


def environment() -> dict:
    """The software (as results/params.yaml records it) and the machine of a benchmark."""
    from yowo_bringup.config import versions

    cpu = ""
    try:
        cpu = next(line.split(":", 1)[1].strip() for line in open("/proc/cpuinfo") if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return {**versions(), "cpu": cpu, "cores": os.cpu_count(), "date": time.strftime("%Y-%m-%d")}


# Sections of BENCHMARKS.md that other commands write between <!-- NAME:begin/end --> markers
# (yowo bench-graph: graph-speed; the TUM RGB-D run: tum-rgbd; real multi-camera recordings
# of people: real-multiview; yowo bench-guidance: guidance); re-rendering keeps them.
KEPT_SECTIONS = ("graph-speed", "tum-rgbd", "real-multiview", "layouts", "bystanders", "guidance", "second-walk")


def markers(name: str) -> tuple[str, str]:
    return f"<!-- {name}:begin -->", f"<!-- {name}:end -->"


def keep_sections(old_text: str, new_text: str, names=KEPT_SECTIONS) -> str:
    """`new_text` with each named section of `old_text` (those it had) at its end, in order."""
    for name in names:
        begin, end = markers(name)
        if begin in old_text and end in old_text.split(begin, 1)[1]:
            section = begin + old_text.split(begin, 1)[1].split(end, 1)[0] + end + "\n"
            new_text = new_text.rstrip("\n") + "\n\n" + section
    return new_text


def write_outputs(results: dict, out_dir: Path, markdown_path: Path | None) -> None:
    if "command" in results:  # re-rendered from an earlier run's results.json: keep its provenance
        env, command = results["environment"], results["command"]
    else:
        env = environment()
        command = "yowo " + " ".join(shlex.quote(a) for a in sys.argv[1:])  # `yowo` or `python -m yowo_bringup.cli`
        results = {**results, "environment": env, "command": command}
        (out_dir / "results.json").write_text(json.dumps(results, indent=1))
    text = markdown(results, command, env)
    (out_dir / "BENCHMARKS.md").write_text(text)
    if markdown_path is not None:  # the sections other commands wrote stay
        markdown_path.write_text(keep_sections(markdown_path.read_text() if markdown_path.exists() else "", text))
