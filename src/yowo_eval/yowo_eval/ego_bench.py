"""Ego-stage benchmark on a recording with ground truth: ego ATE RMSE per stage
(odometry only, after multiway registration, after bundle adjustment), layout
IoU, gravity error and processing speed.

- ATE: rigid (SE(3)) alignment of the trajectory to /gt/ego/pose, as evo does.
- Layout IoU: the estimated floor polygons, moved into the ground-truth frame by
  the final trajectory's ATE alignment, against /gt/layout/floor.
- Gravity error: mean over frames of the angle between the estimated and the
  true up direction, both expressed in the camera frame (independent of any
  alignment; yaw and position do not enter).
- Speed: ego frames / wall-clock seconds for decoding and the whole stage.

    python -m yowo_eval.ego_bench [--no-imu] [--no-relocalisation] BAG [BAG ...]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace

import numpy as np

from yowo_common.trajectory import Trajectory
from yowo_ego.config import EgoParams
from yowo_ego.pipeline import EgoMapResult
from yowo_ego.recording import map_bag

from .ground_truth import GroundTruth, read_ground_truth
from .metrics import associate, ate, layout_iou


def gravity_error_deg(T_est: np.ndarray, T_gt: np.ndarray) -> float:
    """Mean angle between R_est^T z and R_gt^T z (world up seen from the camera:
    the third row of R_world_cam)."""
    up_est, up_gt = T_est[:, 2, :3], T_gt[:, 2, :3]
    cos = np.clip(np.einsum("ij,ij->i", up_est, up_gt), -1.0, 1.0)
    return float(np.degrees(np.arccos(cos)).mean())


def evaluate(result: EgoMapResult, gt: GroundTruth) -> dict[str, float]:
    if gt.ego is None:
        raise ValueError("no /gt/ego/pose in the recording; the ego benchmark needs ground truth")
    ref = gt.ego
    metrics: dict[str, float] = {}
    final = None
    for stage, poses in result.trajectories.items():
        a = ate(Trajectory(result.stamps_ns, poses), ref)
        metrics[f"ate_{stage}_m"] = a.rmse_m
        final = a
    i_est, i_ref = associate(result.stamps_ns, ref.stamps_ns, 10_000_000)
    metrics["gravity_error_deg"] = gravity_error_deg(result.T_world_cam[i_est], ref.T_world_cam[i_ref])
    S = final.alignment
    est = [S.apply(np.column_stack([p, np.zeros(len(p))]))[:, :2] for p in result.layout.floor_polygons]
    metrics["layout_iou"] = layout_iou(est, gt.floor) if gt.floor else float("nan")
    return metrics


def bench_bag(bag, params: EgoParams = EgoParams()) -> dict[str, float]:
    """All ego-stage metrics for one recording (see the module docstring)."""
    t0, c0 = time.perf_counter(), time.process_time()
    result, _ = map_bag(bag, params)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    metrics = evaluate(result, read_ground_truth(bag))
    duration = (result.stamps_ns[-1] - result.stamps_ns[0]) * 1e-9
    n = len(result.stamps_ns)
    metrics.update(
        frames=n,
        duration_s=duration,
        wall_s=wall,
        cpu_s=cpu,
        fps=n / wall,
        recording_fps=(n - 1) / duration if duration > 0 else float("nan"),
        time_ratio=wall / duration if duration > 0 else float("nan"),
    )
    metrics.update({f"stat_{k}": float(v) for k, v in result.stats.items()})
    return metrics


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m yowo_eval.ego_bench", description=__doc__.split("\n\n")[0])
    parser.add_argument("bags", nargs="+")
    parser.add_argument("--json", help="write all metrics to this file")
    parser.add_argument("--no-imu", action="store_true", help="track without the recording's IMU (ablation)")
    parser.add_argument(
        "--no-relocalisation",
        action="store_true",
        help="no place recognition: segments after a break joined as before (ablation)",
    )
    args = parser.parse_args(argv)
    params = EgoParams()
    if args.no_imu:
        params = replace(params, odometry=replace(params.odometry, use_imu=False))
    if args.no_relocalisation:
        params = replace(params, loops=replace(params.loops, retrieval=replace(params.loops.retrieval, enabled=False)))
    rows = {}
    for bag in args.bags:
        m = bench_bag(bag, params)
        rows[bag] = m
        print(
            f"{bag}: ATE odometry {m['ate_odometry_m']:.3f} m, multiway {m['ate_multiway_m']:.3f} m, "
            f"BA {m.get('ate_bundle_m', float('nan')):.3f} m; breaks {m['stat_breaks']:.0f}, relocalised "
            f"{m['stat_relocalised']:.0f}, loops by appearance {m['stat_loops_retrieved']:.0f}; layout IoU {m['layout_iou']:.3f}; gravity "
            f"{m['gravity_error_deg']:.3f} deg; {m['fps']:.1f} frames/s ({m['time_ratio']:.2f} x real time, "
            f"cpu {m['cpu_s']:.0f} s)",
            flush=True,
        )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
