"""`yowo bench-bystanders`: the same generated walk with 0, 1 and 3 other people walking the
same rooms, each through a plain `yowo run --cmc-source pose`: the registration, and per camera
whose keypoints its tracker handed on (yowo_eval.walker_id)."""

from __future__ import annotations

import shlex
import sys
from pathlib import Path

from .bench import bag_for
from .bench_markdown import produced_by
from .bench_report import markers
from .graph_bench import graph_case, registration_cell, write_cases
from .walker_id import identify_run

SECTION = "bystanders"
BEGIN, END = markers(SECTION)


def bystander_cases(
    preset: str, seeds: list[int], counts: list[int], out_dir: Path, extra: list[str], log=print
) -> list[dict]:
    cases = []
    for seed in seeds:
        for n in counts:
            bag = bag_for(preset, f"bystanders_{n}", seed, out_dir / "bags", log)
            case = graph_case(bag, out_dir / "runs" / bag.name, "pose", extra)
            case.update(preset=preset, seed=seed, bystanders=n, cameras={})
            if case["exit"] == 0:
                for c in identify_run(out_dir / "runs" / bag.name, bag):
                    case["cameras"][c.camera] = {
                        "frames": c.frames,
                        "walker": c.walker,
                        "bystander": c.bystander,
                        "walker_in_view": c.walker_in_view,
                    }
            log(f"{bag.name}: exit {case['exit']}, registration {case['registration_pos_avg_m']}")
            cases.append(case)
    return cases


def _identification(case: dict) -> str:
    cams = case["cameras"]
    if not cams:
        return "-"
    frames = sum(c["frames"] for c in cams.values())
    walker = sum(c["walker"] for c in cams.values())
    worst = min((c["walker"] / c["frames"], n) for n, c in cams.items() if c["frames"]) if frames else (0.0, "-")
    silent = [n for n, c in cams.items() if not c["frames"]]
    out = f"{walker}/{frames} ({100 * walker / max(frames, 1):.1f} %), worst {worst[1]} {100 * worst[0]:.0f} %"
    return out + (f"; no frames: {', '.join(silent)}" if silent else "")


def bystanders_markdown(cases: list[dict], command: str) -> str:
    lines = [
        BEGIN,
        "## People in view (`yowo bench-bystanders`)",
        "",
        *produced_by(command),
        "One generated walk with 0, 1 and 3 other people on their own paths through the same rooms "
        "(other clothes and heights, pausing, some passing the walker; also in the head camera's view), "
        "ceiling cameras as images only, through `yowo run --cmc-source pose`. Identification: of the "
        "frames the trackers handed on, those whose head top and ground point are nearest the walker's "
        "true ones (ground truth, evaluation only); in view: images whose true walker is inside the "
        "image. Registration as `yowo eval` computes it.",
        "",
        "| recording | people besides the walker | exit | registration avg [m / deg] | walker frames handed on "
        "/ walker in view | identification | processing / recording |",
        "|---|---|---|---|---|---|---|",
    ]
    for c in cases:
        reg = registration_cell(c)
        cams = c["cameras"].values()
        shown = f"{sum(x['walker'] for x in cams)} / {sum(x['walker_in_view'] for x in cams)}" if cams else "-"
        lines.append(
            f"| {c['bag']} | {c['bystanders']} | {c['exit']} | {reg} | {shown} | {_identification(c)} "
            f"| {c['ratio']:.2f} |"
        )
    return "\n".join(lines + [END, ""])


def run_bystander_bench(
    preset: str,
    seeds: list[int],
    counts: list[int],
    out_dir: Path,
    markdown_path: Path | None,
    extra: list[str],
    log=print,
) -> list[dict]:
    command = "yowo " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    cases = bystander_cases(preset, seeds, counts, out_dir, extra, log)
    write_cases(
        out_dir,
        ("bystander_cases.json", "BYSTANDERS.md"),
        cases,
        bystanders_markdown(cases, command),
        markdown_path,
        SECTION,
    )
    return cases
