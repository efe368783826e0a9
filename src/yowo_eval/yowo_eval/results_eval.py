"""`yowo eval`: the metric tables of docs/design.md §6 for a results directory
against the ground truth recorded in a bag."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import yaml

from yowo_bringup.results import read_camera_poses, read_floor_polygons
from yowo_common.trajectory import read_tum

from .ground_truth import GroundTruth, read_ground_truth
from .metrics import (
    ErrorSummary,
    ate,
    layout_iou,
    registration_errors,
    relative_errors_of_baseline,
    relative_pose_errors,
)

RESULT_FILES = ("cameras.yaml", "ego_trajectory.tum", "layout.json")


def evaluate(results_dir, bag, gt: GroundTruth | None = None) -> dict:
    """Metrics of a results directory (``gt``: the recording's ground truth when already
    read); ValueError naming what is missing when there is nothing to evaluate."""
    results_dir = Path(results_dir)
    if not results_dir.is_dir():
        raise ValueError(f"{results_dir}: no such results directory")
    if not any((results_dir / f).exists() for f in RESULT_FILES):
        raise ValueError(
            f"{results_dir}: holds none of {', '.join(RESULT_FILES)}; nothing to evaluate "
            "(did the run fail? see its run_log.yaml)"
        )
    gt = gt if gt is not None else read_ground_truth(bag)
    if not gt.cameras and gt.ego is None:
        raise ValueError(f"{bag}: no ground truth (/gt/...) in the recording; nothing to evaluate against")
    out: dict = {}
    cams_file = results_dir / "cameras.yaml"
    doc = yaml.safe_load(cams_file.read_text()) if cams_file.exists() else None
    if doc is not None and gt.cameras and doc.get("registered") == 0:
        # An ego-only run registers no camera by design: nothing to measure, but say so.
        out["cameras"] = {"registered": 0, "not_registered": sorted(gt.cameras), "note": doc.get("note", "")}
    elif doc is not None and gt.cameras:
        est = read_camera_poses(cams_file)
        groups: dict[str, list[str]] = {}
        for c in doc["cameras"]:
            if c.get("group") and c["name"] in est:
                groups.setdefault(c["group"], []).append(c["name"])
        if "frame" in doc:  # world-registered cameras (full run)
            errs = registration_errors(est, gt.cameras)
            out["registration"] = {
                "summary": asdict(ErrorSummary.of(errs)),
                "cameras": [asdict(e) for e in errs],
                "not_registered": sorted(set(gt.cameras) - set(est)),
            }
        rel, _ = relative_pose_errors(est, gt.cameras, groups)
        if rel:  # no group of two or more cameras: no relative pose to measure (not a table of NaN)
            out["relative"] = {"summary": asdict(ErrorSummary.of(rel)), "cameras": [asdict(e) for e in rel]}
            pct = ErrorSummary.of(relative_errors_of_baseline(rel, gt.cameras, groups))
            out["relative"]["pos_pct_of_mean_baseline"] = {k: getattr(pct, f"pos_{k}") for k in ("avg", "min", "max")}
        else:
            out["relative_note"] = "no group of two or more calibrated cameras: no relative pose to evaluate"
    traj = results_dir / "ego_trajectory.tum"
    if traj.exists() and gt.ego is not None:
        a = ate(read_tum(traj), gt.ego)
        out["ego"] = {"ate_rmse_m": a.rmse_m, "ate_mean_m": a.mean_m, "ate_max_m": a.max_m, "matched": a.matched}
    layout = results_dir / "layout.json"
    if layout.exists() and gt.floor:
        out["layout"] = {"iou": layout_iou(read_floor_polygons(layout), gt.floor)}
    if not out:
        raise ValueError(f"{results_dir}: none of its results has ground truth in {bag} to compare with")
    return out


def print_tables(metrics: dict, console) -> None:
    from rich.markup import escape
    from rich.table import Table

    for key, title in (
        ("registration", "CMC registration (world frame, no alignment)"),
        ("relative", "CMC relative pose (KU-aligned per group)"),
    ):
        if key not in metrics:
            continue
        s = metrics[key]["summary"]
        t = Table(title=title)
        for col in ("", "avg", "min", "max"):
            t.add_column(col)
        # Units in brackets are rich markup unless escaped.
        t.add_row(escape("eps_pos [m]"), *(f"{s[f'pos_{k}']:.4f}" for k in ("avg", "min", "max")))
        t.add_row(escape("eps_rot [deg]"), *(f"{s[f'rot_{k}']:.3f}" for k in ("avg", "min", "max")))
        if "pos_pct_of_mean_baseline" in metrics[key]:
            t.add_row(
                "eps_pos, % of mean baseline",
                *(f"{metrics[key]['pos_pct_of_mean_baseline'][k]:.2f}" for k in ("avg", "min", "max")),
            )
        console.print(t)
        if metrics[key].get("not_registered"):
            console.print(f"not registered: {', '.join(metrics[key]['not_registered'])}")
    if "relative_note" in metrics:
        console.print(metrics["relative_note"])
    if "cameras" in metrics:
        console.print(
            f"{metrics['cameras']['note']}; with ground truth: {', '.join(metrics['cameras']['not_registered'])}"
        )
    if "ego" in metrics:
        console.print(f"ego ATE RMSE: {metrics['ego']['ate_rmse_m']:.4f} m over {metrics['ego']['matched']} poses")
    if "layout" in metrics:
        console.print(f"layout IoU: {metrics['layout']['iou']:.3f}")


def write_metrics(metrics: dict, path: Path) -> None:
    path.write_text(json.dumps(metrics, indent=1))
