"""Speed of the real graph (issue #19): `yowo run --rate 0` on generated recordings,
each node's CPU seconds, lifetime and peak memory (run_log.yaml: the supervisor samples
/proc), processing time / recording time. Its table lives in BENCHMARKS.md between
markers, so `yowo bench` re-rendering the rest keeps it."""

from __future__ import annotations

import json
import shlex
import subprocess
import sys
import time
from pathlib import Path

import yaml

from .bench import bag_for
from .bench_markdown import produced_by
from .bench_report import markers

BEGIN, END = markers("graph-speed")
NOTES_BEGIN, NOTES_END = markers("graph-speed-notes")  # hand-written notes inside, kept when rendered again


def recording_seconds(bag: Path | list[Path]) -> float:
    """How long a recording is; recordings read as one: the sum of their lengths."""
    from yowo_common.ros.bag import recording_paths, recording_span

    spans = [recording_span(p) for p in recording_paths(bag)]
    return sum(end - start for start, end in spans) / 1e9


def graph_case(bag: Path | list[Path], out: Path, source: str, extra: list[str], timeout_s: float = 7200.0) -> dict:
    """One `yowo run` of a recording (several read as one: a list) and what it measured."""
    from yowo_common.ros.bag import recording_paths

    bags = recording_paths(bag)
    cmd = [
        sys.executable,
        "-m",
        "yowo_bringup.cli",
        "run",
        *map(str, bags),
        "-o",
        str(out),
        "--replace",
        "--rate",
        "0",
        "--cmc-source",
        source,
        "--timeout",
        str(timeout_s),
        *extra,
    ]
    t0 = time.monotonic()
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s + 120)
    wall = time.monotonic() - t0
    log_file = out / "run_log.yaml"
    log = yaml.safe_load(log_file.read_text()) if log_file.exists() else {}
    recording = recording_seconds(bag)
    metrics = json.loads((out / "metrics.json").read_text()) if (out / "metrics.json").exists() else {}
    reg = metrics.get("registration", {}).get("summary", {})
    return {
        "bag": "+".join(p.name for p in bags),
        "source": source,
        "exit": r.returncode,
        "recording_s": recording,
        "wall_s": wall,
        "ratio": wall / recording if recording > 0 else float("nan"),
        "resources": log.get("resources", {}),
        "peak_memory_mb": log.get("peak_memory_mb"),
        "peak_memory_by_process_mb": log.get("peak_memory_by_process_mb", {}),
        "timing": log.get("timing", {}),
        "registration_pos_avg_m": reg.get("pos_avg"),
        "registration_rot_avg_deg": reg.get("rot_avg"),
        "ego_ate_m": metrics.get("ego", {}).get("ate_rmse_m"),
        "error": "" if r.returncode == 0 else (r.stderr or r.stdout)[-500:],
    }


def registration_cell(case: dict) -> str:
    """A graph case's average registration error, position / rotation, or - without one."""
    if case.get("registration_pos_avg_m") is None:
        return "-"
    return f"{case['registration_pos_avg_m']:.4f} / {case['registration_rot_avg_deg']:.3f}"


def _is_tracker(name: str) -> bool:
    # Trackers: one per process, or several per process on many cameras (supervisor.tracker_processes).
    return name.startswith("keypoint_tracker")


def _stage(name: str) -> str:
    return "keypoint_tracker (each process)" if _is_tracker(name) else name


def speed_markdown(cases: list[dict], command: str) -> str:
    lines = [
        BEGIN,
        "## Speed of the real graph (`yowo run --rate 0`)",
        "",
        *produced_by(command),
        "Wall time of the whole `yowo run` (start-up, replay, every stage, results) over the recording's "
        "length; per stage the CPU seconds, the process lifetime and the peak RSS (sampled from /proc once a "
        "second; trackers: the mean and the largest peak over their processes). Graph memory: the largest sum of every "
        "process's proportional set size at one sample (shared libraries counted once), the machine's memory "
        "the run held at its peak, and below it the stages that held most of it then. Registration and ATE "
        "as `yowo eval` computes them.",
        "",
        "| recording | source | processing / recording | wall [s] | recording [s] | registration avg [m / deg] "
        "| ego ATE [m] | graph memory [MB] | stage: CPU s / wall s / peak MB |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for c in cases:
        stages: dict[str, list[dict]] = {}
        for name, r in c["resources"].items():
            stages.setdefault(_stage(name), []).append(r)
        cells = []
        for name, rs in stages.items():
            cpu = sum(r["cpu_s"] for r in rs) / len(rs)
            wall = sum(r["wall_s"] for r in rs) / len(rs)
            cells.append(f"{name}: {cpu:.1f} / {wall:.0f} / {max(r['peak_rss_mb'] for r in rs):.0f}")
        reg = registration_cell(c)
        ate = f"{c['ego_ate_m']:.4f}" if c.get("ego_ate_m") is not None else "-"
        status = f"{c['ratio']:.2f}" if c["exit"] == 0 else f"failed (exit {c['exit']})"
        memory = f"{c['peak_memory_mb']:.0f}" if c.get("peak_memory_mb") is not None else "-"
        held: dict[str, float] = {}
        for name, mb in c.get("peak_memory_by_process_mb", {}).items():  # the trackers' processes summed
            stage = "keypoint_trackers" if _is_tracker(name) else name
            held[stage] = held.get(stage, 0.0) + mb
        if held:
            memory += "<br>" + "<br>".join(f"{n} {mb:.0f}" for n, mb in sorted(held.items(), key=lambda x: -x[1])[:3])
        lines.append(
            f"| {c['bag']} | {c['source']} | {status} | {c['wall_s']:.0f} | {c['recording_s']:.0f} | {reg} "
            f"| {ate} | {memory} | {'<br>'.join(cells)} |"
        )
    return "\n".join(lines + [""] + timeline_markdown(cases) + [END, ""])


def _max(values) -> float:
    return max((v for v in values if v is not None), default=float("nan"))


def _min(values) -> float:
    return min((v for v in values if v is not None), default=float("nan"))


def timeline_markdown(cases: list[dict]) -> list[str]:
    """Where each case's wall time went: per stage (trackers: the latest of any camera) when
    its process was started and had imported (node created), its earliest and latest input,
    its finalisation, the p95 of the time its inputs waited in its queue (worst topic) and the
    seconds in its input callbacks; for the replay when every stage had announced itself (its
    status: imports and discovery done), its start of playing (subscribers matched), end, and the seconds it
    was held back by flow control (unacknowledged messages: a stage behind)."""
    lines = [
        "Where the wall time goes (seconds since `yowo run` started the graph; run_log.yaml `timing`):",
        "",
        "| recording | source | stage | started / created | inputs from / to | finalize [s] | finished "
        "| queue wait p95 [ms] | in callbacks [s] |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for c in cases:
        stages: dict[str, list[dict]] = {}
        for name, t in c.get("timing", {}).items():
            stages.setdefault(_stage(name), []).append(t)
        for name, ts in stages.items():
            topics = [s for t in ts for s in t["topics"].values()]
            created = f"{_max(t.get('spawned_s') for t in ts):.1f} / {_max(t.get('created_s') for t in ts):.1f}"
            if name == "replay":
                held = sum(v for t in ts for k, v in t.get("seconds", {}).items() if k.startswith("ack_wait"))
                lines.append(
                    f"| {c['bag']} | {c['source']} | replay | {created} | stages announced "
                    f"{_max(t.get('announced_s') for t in ts):.1f}, playing {_max(t.get('playing_s') for t in ts):.1f}"
                    f" / done {_max(t.get('played_s') for t in ts):.1f} | - | - | held back {held:.1f} s | - |"
                )
                continue
            fin = _max((t.get("finalize_end_s") or 0) - (t.get("finalize_start_s") or 0) for t in ts)
            lines.append(
                f"| {c['bag']} | {c['source']} | {name} | {created} | {_min(s['first_s'] for s in topics):.1f} / "
                f"{_max(s['last_s'] for s in topics):.1f} | {fin:.1f} | {_max(t.get('finalize_end_s') for t in ts):.1f} "
                f"| {_max(s['queue_wait_ms']['p95'] for s in topics):.0f} "
                f"| {_max(sum(s['handling_s'] for s in t['topics'].values()) for t in ts):.1f} |"
            )
    return lines + [""]


def replace_section(markdown_path: Path, section: str, name: str = "graph-speed") -> None:
    """Put the named section into a markdown file, replacing an earlier one (its hand-written
    notes, between <!-- NAME-notes:begin/end -->, stay)."""
    (begin, end), (notes_begin, notes_end) = markers(name), markers(f"{name}-notes")
    text = markdown_path.read_text() if markdown_path.exists() else ""
    if begin in text and end in text:
        head, rest = text.split(begin, 1)
        old, tail = rest.split(end, 1)
        if notes_begin in old and notes_end in old:
            notes = notes_begin + old.split(notes_begin, 1)[1].split(notes_end, 1)[0] + notes_end + "\n\n"
            section = section.replace(end, notes + end)
        text = head + section.rstrip("\n") + tail
    else:
        text = text.rstrip("\n") + "\n\n" + section
    markdown_path.write_text(text)


def keep_section(old_text: str, new_text: str) -> str:
    """`new_text` with the graph-speed section of `old_text` (when it had one) at its end."""
    from .bench_report import keep_sections

    return keep_sections(old_text, new_text, ("graph-speed",))


def write_cases(
    out_dir: Path,
    files: tuple[str, str],
    cases: list[dict],
    section: str,
    markdown_path: Path | None,
    name: str = "graph-speed",
) -> None:
    """A bench's cases and its markdown section into `files` (JSON, markdown) of `out_dir`
    and, when asked, the section in place in `markdown_path`."""
    (out_dir / files[0]).write_text(json.dumps(cases, indent=1))
    (out_dir / files[1]).write_text(section)
    if markdown_path is not None:
        replace_section(markdown_path, section, name)


def run_graph_bench(
    presets: list[str],
    seeds: list[int],
    sources: list[str],
    out_dir: Path,
    markdown_path: Path | None,
    extra: list[str],
    log=print,
) -> list[dict]:
    command = "yowo " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    cases = []
    for preset in presets:
        for seed in seeds:
            for source in sources:
                bag = bag_for(preset, "normal", seed, out_dir / "bags", log)  # keypoints and images recorded
                case = graph_case(bag, out_dir / "runs" / f"{bag.name}_{source}", source, extra)
                log(
                    f"{bag.name} ({source}): {case['wall_s']:.0f} s for {case['recording_s']:.0f} s of recording "
                    f"({case['ratio']:.2f}), exit {case['exit']}"
                )
                cases.append(case)
                write_cases(
                    out_dir,
                    ("graph_cases.json", "GRAPH_SPEED.md"),
                    cases,
                    speed_markdown(cases, command),
                    markdown_path,
                )
    return cases
