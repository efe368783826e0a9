"""`yowo bench-layouts`: one generated recording in YOWO's layout, in each driver's layout and
with its ceiling cameras as video files, each through a plain `yowo run`: the same recording
should give the same result whatever names its topics have."""

from __future__ import annotations

import shlex
import sys
from pathlib import Path

from yowo_sim.cmc_video import write_cmc_videos
from yowo_sim.driver_layout import write_driver_layout

from .bench import bag_for
from .bench_markdown import produced_by
from .bench_report import markers
from .graph_bench import graph_case, registration_cell, write_cases

SECTION = "layouts"
BEGIN, END = markers(SECTION)
DRIVER_LAYOUTS = ("realsense", "realsense_united", "azure", "zed")
VIDEO_START_ERROR_S = 3.0


def layout_cases(preset: str, seed: int, out_dir: Path, source: str, extra: list[str], log=print) -> list[dict]:
    """Each layout of one recording through `yowo run`, with the options it needs (none but
    the video list for the videos)."""
    own = bag_for(preset, "normal", seed, out_dir / "bags", log)
    bags = {"yowo": (own, [])}
    for layout in DRIVER_LAYOUTS:
        path = out_dir / "bags" / f"{own.name}_{layout}"
        if not path.exists():
            write_driver_layout(own, path, layout)
        bags[layout] = (path, [])
    videos = out_dir / "bags" / f"{own.name}_videos"
    if not (videos / "recording").exists():
        write_cmc_videos(own, videos / "recording", videos, start_error_s=VIDEO_START_ERROR_S)
    bags["CMC videos (3 s off)"] = (videos / "recording", ["--cmc-videos", str(videos / "videos.yaml")])
    cases = []
    for layout, (bag, options) in bags.items():
        # Video frames carry no keypoints: every layout's cameras run the same source.
        case = graph_case(bag, out_dir / "runs" / f"{own.name}_{layout.split()[0]}_{source}", source, extra + options)
        case["layout"] = layout
        log(f"{layout}: exit {case['exit']}, registration {case['registration_pos_avg_m']}")
        cases.append(case)
    return cases


def layouts_markdown(cases: list[dict], command: str) -> str:
    lines = [
        BEGIN,
        "## One recording in each input layout (`yowo bench-layouts`)",
        "",
        *produced_by(command),
        "The same generated recording in YOWO's own layout, as realsense2_camera (split gyro/accelerometer "
        "streams, extrinsics on /tf_static), realsense2_camera with a united IMU, the Azure Kinect / Orbbec "
        "driver and the ZED wrapper write it (ceiling cameras under /cctv/<name>/, PNG-compressed), and with "
        "the ceiling cameras as OpenCV-written video files whose start is 3 s off; each through a plain "
        "`yowo run` (the videos with `--cmc-videos`). The drivers' layouts use the IMU with the /tf_static "
        "extrinsics and the documented default noise, YOWO's its recorded calibration.",
        "",
        "| layout | exit | registration avg [m / deg] | ego ATE [m] | processing / recording |",
        "|---|---|---|---|---|",
    ]
    for c in cases:
        reg = registration_cell(c)
        ate = f"{c['ego_ate_m']:.4f}" if c.get("ego_ate_m") is not None else "-"
        lines.append(f"| {c['layout']} | {c['exit']} | {reg} | {ate} | {c['ratio']:.2f} |")
    return "\n".join(lines + [END, ""])


def run_layout_bench(
    preset: str, seed: int, source: str, out_dir: Path, markdown_path: Path | None, extra: list[str], log=print
) -> list[dict]:
    command = "yowo " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    cases = layout_cases(preset, seed, out_dir, source, extra, log)
    write_cases(
        out_dir, ("layout_cases.json", "LAYOUTS.md"), cases, layouts_markdown(cases, command), markdown_path, SECTION
    )
    return cases
