"""`yowo bench-tum`: real TUM RGB-D sequences through the real graph with no CMCs (an
ego-only `yowo run --rate 0`), their ATE beside published numbers, into BENCHMARKS.md's
tum-rgbd section (issue #18). Each sequence folder is imported once (`yowo import-tum`)."""

from __future__ import annotations

import json
import shlex
import sys
from pathlib import Path

from .bench_markdown import produced_by
from .bench_report import markers
from .graph_bench import graph_case, write_cases

SECTION = "tum-rgbd"

# Published ATE RMSE [m] of RGB-D SLAM systems on the TUM sequences (each paper's own table;
# SE(3)-aligned as TUM's evaluate_ate.py). Sequences absent from a paper's table are left out.
PUBLISHED = {
    "DVO-SLAM (Kerl et al., IROS 2013)": {
        "fr1_360": 0.083,
        "fr1_desk": 0.021,
        "fr1_desk2": 0.046,
        "fr1_room": 0.053,
        "fr1_rpy": 0.020,
        "fr1_xyz": 0.011,
        "fr2_desk": 0.017,
        "fr2_xyz": 0.018,
        "fr3_long_office_household": 0.035,
    },
    "ElasticFusion (Whelan et al., RSS 2015)": {
        "fr1_desk": 0.020,
        "fr2_xyz": 0.011,
        "fr3_long_office_household": 0.017,
        "fr3_nostructure_texture_near": 0.016,
    },
    "ORB-SLAM2 RGB-D (Mur-Artal & Tardos, T-RO 2017)": {
        "fr1_desk": 0.016,
        "fr1_desk2": 0.022,
        "fr1_room": 0.047,
        "fr2_desk": 0.009,
        "fr2_xyz": 0.004,
        "fr3_long_office_household": 0.010,
        "fr3_nostructure_texture_near": 0.019,
    },
}


def short_name(folder: Path) -> str:
    """'rgbd_dataset_freiburg1_desk' -> 'fr1_desk' (the papers' names)."""
    name = folder.name.removeprefix("rgbd_dataset_")
    return name.replace("freiburg", "fr", 1) if name.startswith("freiburg") else name


def published_cell(short: str) -> str:
    cells = [
        f"{ate:.3f} {paper.split(' (')[0]}"
        for paper, table in PUBLISHED.items()
        if (ate := table.get(short)) is not None
    ]
    return "<br>".join(cells) if cells else "-"


def tum_markdown(cases: list[dict], command: str) -> str:
    begin, end = markers(SECTION)
    lines = [
        begin,
        "## Real RGB-D sequences (TUM RGB-D), ego-only `yowo run --rate 0`",
        "",
        *produced_by(command),
        "Each sequence is imported with `yowo import-tum` (colour/depth pairs associated within 0.02 s, the TUM "
        "Kinect calibration) and run through the whole graph with no CMCs (replay and ego mapper). ATE RMSE of "
        "`ego_trajectory.tum` against the motion capture after an SE(3) alignment, as TUM's evaluate_ate.py "
        "and `yowo eval`. Published numbers are from each paper's table.",
        "",
        "| sequence | frames | recording [s] | YOWO ATE RMSE [m] | ATE max [m] | published ATE RMSE [m] "
        "| processing / recording | ego mapper: CPU s / peak MB |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for c in cases:
        ego = c["resources"].get("ego_mapper", {})
        stage = f"{ego['cpu_s']:.0f} / {ego['peak_rss_mb']:.0f}" if ego else "-"
        ate = f"{c['ego_ate_m']:.4f}" if c.get("ego_ate_m") is not None else f"- (exit {c['exit']})"
        ate_max = f"{c['ego_ate_max_m']:.4f}" if c.get("ego_ate_max_m") is not None else "-"
        lines.append(
            f"| {c['sequence']} | {c['frames']} | {c['recording_s']:.1f} | {ate} | {ate_max} "
            f"| {published_cell(c['sequence'])} | {c['ratio']:.2f} | {stage} |"
        )
    return "\n".join(lines + ["", end, ""])


def run_tum_bench(
    folders: list[Path], out_dir: Path, markdown_path: Path | None, extra: list[str], log=print
) -> list[dict]:
    from .progress import with_progress
    from .tum_import import import_tum

    command = "yowo " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    cases = []
    for folder in folders:
        bag = out_dir / "bags" / folder.name
        if not bag.exists():
            s = with_progress(lambda progress: import_tum(folder, bag, progress=progress))  # called here, now
            log(f"imported {folder} -> {bag}: {s.frames} frames over {s.duration_s:.1f} s (camera {s.camera})")
        run = out_dir / "runs" / folder.name
        case = graph_case(bag, run, "auto", extra)
        metrics = json.loads((run / "metrics.json").read_text()) if (run / "metrics.json").exists() else {}
        case.update(
            sequence=short_name(folder), ego_ate_max_m=metrics.get("ego", {}).get("ate_max_m"), frames=_frames(bag)
        )
        log(
            f"{case['sequence']}: ATE {case['ego_ate_m']} m, {case['wall_s']:.0f} s for {case['recording_s']:.0f} s "
            f"of recording, exit {case['exit']}" + (f": {case['error']}" if case["exit"] else "")
        )
        cases.append(case)
        write_cases(
            out_dir, ("tum_cases.json", "TUM_RGBD.md"), cases, tum_markdown(cases, command), markdown_path, SECTION
        )
    return cases


def _frames(bag: Path) -> int:
    from yowo_common import topics
    from yowo_common.ros.bag import list_topics

    return sum(t.count for t in list_topics(bag) if t.name == topics.EGO_COLOR[1])
