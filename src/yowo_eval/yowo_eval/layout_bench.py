"""`yowo bench-layouts`: one generated recording in YOWO's layout, in each driver's layout and
with its ceiling cameras as video files, each through a plain `yowo run`: the same recording
should give the same result whatever names its topics have."""

from __future__ import annotations

import json
import shlex
import sys
from pathlib import Path

import numpy as np
import yaml

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


def layout_cases(
    preset: str, seed: int, out_dir: Path, source: str, extra: list[str], no_camera_info=(), log=print
) -> list[dict]:
    """Each layout of one recording through `yowo run`, with the options it needs (none but
    the video list for the videos); and per camera in `no_camera_info` the realsense layout
    with that camera's CameraInfo left out (its intrinsics estimated)."""
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
    for cam in no_camera_info:
        path = out_dir / "bags" / f"{own.name}_realsense_no_info_{cam}"
        if not path.exists():
            write_driver_layout(own, path, "realsense", no_camera_info=[cam])
        bags[f"realsense, {cam} without CameraInfo"] = (path, [])
    cases = []
    for layout, (bag, options) in bags.items():
        # Video frames carry no keypoints: every layout's cameras run the same source.
        run = out_dir / "runs" / f"{own.name}_{layout.split()[0].rstrip(',')}_{source}"
        if "without CameraInfo" in layout:
            run = out_dir / "runs" / f"{bag.name}_{source}"
        case = graph_case(bag, run, source, extra + options)
        case["layout"] = layout
        if "without CameraInfo" in layout:
            case["estimated"] = estimated_intrinsics_case(run, own, layout.split()[1])
        log(f"{layout}: exit {case['exit']}, registration {case['registration_pos_avg_m']}")
        cases.append(case)
    return cases


def estimated_intrinsics_case(run: Path, own: Path, camera: str) -> dict:
    """How well a run estimated one camera's intrinsics (against the recording's CameraInfo in
    YOWO's layout) and registered it, beside the other cameras' average error."""
    from yowo_common.ros.bag import read_messages
    from yowo_common.rosconv import camera_info_to_model

    truth = next(camera_info_to_model(m) for _, _, m in read_messages(own, [f"/cmc/{camera}/camera_info"]))
    metrics = run / "metrics.json"
    cams_file = run / "cameras.yaml"
    if not metrics.exists() or not cams_file.exists():
        return {"camera": camera}
    errors = {e["name"]: e for e in json.loads(metrics.read_text())["registration"]["cameras"]}
    entry = next((c for c in yaml.safe_load(cams_file.read_text())["cameras"] if c["name"] == camera), {})
    others = [e["eps_pos_m"] for n, e in errors.items() if n != camera]
    if not entry.get("K"):  # not registered: no intrinsics to compare
        return {"camera": camera, "status": entry.get("status"), "reason": entry.get("reason", "")}
    focal = entry["K"][0][0]
    return {
        "camera": camera,
        "status": entry.get("status"),
        "estimated": entry.get("intrinsics_estimated"),
        "focal_px": focal,
        "focal_true_px": float(truth.K[0, 0]),
        "focal_error": focal / float(truth.K[0, 0]) - 1,
        "focal_sigma_px": entry.get("focal_sigma_px"),
        "k1_k2": entry.get("distortion_coefficients", [None, None])[:2],
        "k1_k2_true": [float(v) for v in truth.D[:2]],
        "pos_m": errors.get(camera, {}).get("eps_pos_m"),
        "rot_deg": errors.get(camera, {}).get("eps_rot_deg"),
        "others_pos_avg_m": float(np.mean(others)) if others else None,
    }


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
    return "\n".join(lines + _estimated_markdown(cases) + [END, ""])


def _estimated_markdown(cases: list[dict]) -> list[str]:
    """The cameras whose CameraInfo was left out: the estimated focal against the truth and
    the camera's registration against the other cameras' (issue bars: 3 %, 1.5x)."""
    rows = [c["estimated"] for c in cases if c.get("estimated", {}).get("status")]
    if not rows:
        return []
    lines = [
        "",
        "The camera without CameraInfo: its intrinsics estimated (focal with square pixels, principal point "
        "at the centre, k1, k2) against the recording's CameraInfo, and its registration against the other "
        "cameras' average.",
        "",
        "| camera | status | focal est. / true [px] | focal error | focal sigma [px] | k1, k2 est. / true "
        "| its registration [m / deg] | others' average [m] | ratio |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for e in rows:
        if e.get("pos_m") is None:
            lines.append(f"| {e['camera']} | {e['status']}: {e.get('reason', '')} | - | - | - | - | - | - | - |")
            continue
        k_est = ", ".join(f"{v:.3f}" for v in e["k1_k2"])
        k_true = ", ".join(f"{v:.3f}" for v in e["k1_k2_true"])
        lines.append(
            f"| {e['camera']} | {e['status']} | {e['focal_px']:.1f} / {e['focal_true_px']:.1f} "
            f"| {100 * e['focal_error']:+.2f} % | {e['focal_sigma_px']:.2f} | {k_est} / {k_true} "
            f"| {e['pos_m']:.4f} / {e['rot_deg']:.3f} | {e['others_pos_avg_m']:.4f} "
            f"| {e['pos_m'] / e['others_pos_avg_m']:.2f} |"
        )
    return lines


def run_layout_bench(
    preset: str,
    seed: int,
    source: str,
    out_dir: Path,
    markdown_path: Path | None,
    extra: list[str],
    no_camera_info=(),
    log=print,
) -> list[dict]:
    command = "yowo " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    cases = layout_cases(preset, seed, out_dir, source, extra, no_camera_info, log)
    write_cases(
        out_dir, ("layout_cases.json", "LAYOUTS.md"), cases, layouts_markdown(cases, command), markdown_path, SECTION
    )
    return cases
