"""`yowo bench`: YOWO and the baselines on the same generated recordings, written
to BENCHMARKS.md (tables + the exact command + versions + machine) and JSON."""
from __future__ import annotations

import json
import os
import platform
import shlex
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from yowo_cmc.group_sfm import SfmParams, calibrate_groups
from yowo_sim.capture import generate
from yowo_sim.detector import DetectorSpec
from yowo_sim.presets import get_preset

from .evaluation import ErrorSummary, relative_pose_errors
from .offline import read_cmc_tracks
from .results import read_ground_truth

SCENARIOS = {
    "normal": {},
    "texture_poor": {"texture": "poor"},
    "symmetric": {"texture": "symmetric"},
    "dim_light": {"light_intensity": 0.4},
    "stationary": {"long_pause_s": 60.0},
    **{f"kp_noise_{s}px": {"kp_sigma_px": s} for s in (0.5, 1.0, 2.0, 5.0)},
}

# Relative calibration methods compared in Table "relative_pose_eval".
RELATIVE_METHODS = {
    "YOWO": SfmParams(),
    # Labelled reimplementation of the idea, not the authors' code: E-matrix pair with the
    # most inliers, PnP in order of matches, one BA with one sigma, no overlap scores.
    "ECCMP-style": SfmParams(overlap_ordering=False, per_id_sigma=False),
}


def scenario_preset(preset: str, scenario: str):
    spec = SCENARIOS[scenario]
    p = get_preset(preset, cmc_images=False) if "texture" not in spec and "light_intensity" not in spec \
        else get_preset(preset)
    if "texture" in spec or "light_intensity" in spec:
        p = replace(p, scene=replace(p.scene, **{k: v for k, v in spec.items() if k in ("texture", "light_intensity")}))
    if "long_pause_s" in spec:
        p = replace(p, walk=replace(p.walk, long_pause_s=spec["long_pause_s"]))
    if "kp_sigma_px" in spec:
        s = spec["kp_sigma_px"]
        p = replace(p, detector=DetectorSpec(sigma_px={0: s, 1: 1.5 * s}, sigma_body_px=4.0 * s))
    return p


def bag_for(preset: str, scenario: str, seed: int, bags_dir: Path, log=print) -> Path:
    """The recording of a case, generated once and reused (same seed, same bag)."""
    path = bags_dir / f"{preset}_{scenario}_s{seed}"
    if not (path / "metadata.yaml").exists():
        if path.exists():
            import shutil
            shutil.rmtree(path)  # an interrupted generation
        t0 = time.perf_counter()
        summary = generate(scenario_preset(preset, scenario), seed, path)
        log(f"generated {path.name}: {summary.duration_s:.0f} s walk, {len(summary.cmcs)} CMCs "
            f"in {time.perf_counter() - t0:.0f} s")
    return path


def relative_pose_case(bag: Path) -> dict:
    gt = read_ground_truth(bag).cameras
    tracks = read_cmc_tracks(bag)
    out = {}
    for method, params in RELATIVE_METHODS.items():
        t0 = time.perf_counter()
        result = calibrate_groups(tracks, params)
        seconds = time.perf_counter() - t0
        est = {n: T for g in result.groups for n, T in g.T_local_cam.items()}
        errs, _ = relative_pose_errors(est, gt, {g.group_id: g.names for g in result.groups})
        out[method] = {"summary": asdict(ErrorSummary.of(errs)), "calibrated": len(est), "cameras": len(tracks),
                       "seconds": seconds}
    return out


def _mean(values):
    values = [v for v in values if v is not None and np.isfinite(v)]
    return float(np.mean(values)) if values else float("nan")


def run_bench(preset: str, seeds: list[int], scenarios: list[str], out_dir: Path, log=print) -> dict:
    out_dir.mkdir(parents=True, exist_ok=True)
    cases = []
    for scenario in scenarios:
        for seed in seeds:
            bag = bag_for(preset, scenario, seed, out_dir / "bags", log)
            case = {"scenario": scenario, "seed": seed, "bag": bag.name, "relative": relative_pose_case(bag)}
            cases.append(case)
            log(f"{scenario} seed {seed}: " + ", ".join(
                f"{m} {r['summary']['pos_avg']:.4f} m / {r['summary']['rot_avg']:.3f} deg"
                for m, r in case["relative"].items()))
    return {"preset": preset, "seeds": seeds, "scenarios": scenarios, "cases": cases}


def environment() -> dict:
    import cv2
    import gtsam  # noqa: F401
    import open3d

    cpu = ""
    try:
        cpu = next(line.split(":", 1)[1].strip() for line in open("/proc/cpuinfo") if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    from importlib.metadata import version
    return {"python": platform.python_version(), "numpy": np.__version__, "opencv": cv2.__version__,
            "open3d": open3d.__version__, "gtsam": version("gtsam"), "cpu": cpu, "cores": os.cpu_count(),
            "date": time.strftime("%Y-%m-%d")}


def markdown(results: dict, command: str, env: dict) -> str:
    lines = ["# BENCHMARKS", "", "Produced by:", "", "```", command, "```", "",
             f"Machine: {env['cpu']} ({env['cores']} cores); Python {env['python']}, numpy {env['numpy']}, "
             f"OpenCV {env['opencv']}, Open3D {env['open3d']}, GTSAM {env['gtsam']}; {env['date']}.", "",
             f"Preset `{results['preset']}`, seeds {results['seeds']}. Errors are averaged over seeds; "
             "each seed's value is the avg (or max) over cameras.", "",
             "## CMC relative pose (KU-aligned per group), paper Table relative_pose_eval", "",
             "| scenario | method | avg eps_pos [m] | max eps_pos [m] | avg eps_rot [deg] | max eps_rot [deg] "
             "| calibrated / cameras | time [s] |", "|---|---|---|---|---|---|---|---|"]
    by_scenario: dict[str, list] = {}
    for case in results["cases"]:
        by_scenario.setdefault(case["scenario"], []).append(case)
    for scenario, cases in by_scenario.items():
        for method in RELATIVE_METHODS:
            rs = [c["relative"][method] for c in cases]
            lines.append(
                f"| {scenario} | {method} | {_mean(r['summary']['pos_avg'] for r in rs):.4f} | "
                f"{_mean(r['summary']['pos_max'] for r in rs):.4f} | {_mean(r['summary']['rot_avg'] for r in rs):.3f} | "
                f"{_mean(r['summary']['rot_max'] for r in rs):.3f} | "
                f"{sum(r['calibrated'] for r in rs)} / {sum(r['cameras'] for r in rs)} | "
                f"{_mean(r['seconds'] for r in rs):.1f} |")
    return "\n".join(lines) + "\n"


def write_outputs(results: dict, out_dir: Path, markdown_path: Path | None) -> None:
    env = environment()
    command = "yowo " + " ".join(shlex.quote(a) for a in sys.argv[1:]) if sys.argv[0].endswith("yowo") \
        else " ".join(shlex.quote(a) for a in sys.argv)
    results = {**results, "environment": env, "command": command}
    (out_dir / "results.json").write_text(json.dumps(results, indent=1))
    text = markdown(results, command, env)
    (out_dir / "BENCHMARKS.md").write_text(text)
    if markdown_path is not None:
        markdown_path.write_text(text)
