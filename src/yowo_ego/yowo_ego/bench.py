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

    python -m yowo_ego.bench BAG [BAG ...]
"""
from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from yowo_common.ros.bag import read_messages
from yowo_common.rosconv import pose_to_matrix, stamp_to_ns

from .pipeline import EgoMapResult, EgoParams
from .recording import map_bag

GT_POSE, GT_FLOOR = "/gt/ego/pose", "/gt/layout/floor"


def read_ground_truth(bag):
    stamps, poses, floors = [], [], []
    for topic, _, msg in read_messages(bag, [GT_POSE, GT_FLOOR]):
        if topic == GT_POSE:
            stamps.append(stamp_to_ns(msg.header.stamp))
            poses.append(pose_to_matrix(msg.pose))
        else:
            floors.append(np.array([[p.x, p.y] for p in msg.polygon.points]))
    if not stamps:
        raise ValueError(f"{bag}: no {GT_POSE}; the ego benchmark needs ground truth")
    order = np.argsort(stamps)
    return np.asarray(stamps, np.int64)[order], np.array(poses)[order], floors


def gravity_error_deg(T_est: np.ndarray, T_gt: np.ndarray) -> float:
    """Mean angle between R_est^T z and R_gt^T z (world up seen from the camera:
    the third row of R_world_cam)."""
    up_est, up_gt = T_est[:, 2, :3], T_gt[:, 2, :3]
    cos = np.clip(np.einsum("ij,ij->i", up_est, up_gt), -1.0, 1.0)
    return float(np.degrees(np.arccos(cos)).mean())


def evaluate(result: EgoMapResult, gt_stamps: np.ndarray, gt_poses: np.ndarray, gt_floors: list[np.ndarray]
             ) -> dict[str, float]:
    from yowo_bringup.evaluation import Trajectory, associate, ate, layout_iou

    ref = Trajectory(gt_stamps, gt_poses)
    metrics: dict[str, float] = {}
    final = None
    for stage, poses in result.trajectories.items():
        a = ate(Trajectory(result.stamps_ns, poses), ref)
        metrics[f"ate_{stage}_m"] = a.rmse_m
        final = a
    i_est, i_ref = associate(result.stamps_ns, gt_stamps, 10_000_000)
    metrics["gravity_error_deg"] = gravity_error_deg(result.T_world_cam[i_est], gt_poses[i_ref])
    S = final.alignment
    est = [S.apply(np.column_stack([p, np.zeros(len(p))]))[:, :2] for p in result.layout.floor_polygons]
    metrics["layout_iou"] = layout_iou(est, gt_floors) if gt_floors else float("nan")
    return metrics


def bench_bag(bag, params: EgoParams = EgoParams()) -> dict[str, float]:
    """All ego-stage metrics for one recording (see the module docstring)."""
    t0, c0 = time.perf_counter(), time.process_time()
    result, _ = map_bag(bag, params)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    gt_stamps, gt_poses, gt_floors = read_ground_truth(bag)
    metrics = evaluate(result, gt_stamps, gt_poses, gt_floors)
    duration = (result.stamps_ns[-1] - result.stamps_ns[0]) * 1e-9
    n = len(result.stamps_ns)
    metrics.update(frames=n, duration_s=duration, wall_s=wall, cpu_s=cpu, fps=n / wall,
                   recording_fps=(n - 1) / duration if duration > 0 else float("nan"),
                   time_ratio=wall / duration if duration > 0 else float("nan"))
    metrics.update({f"stat_{k}": float(v) for k, v in result.stats.items()})
    return metrics


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m yowo_ego.bench", description=__doc__.split("\n\n")[0])
    parser.add_argument("bags", nargs="+")
    parser.add_argument("--json", help="write all metrics to this file")
    args = parser.parse_args(argv)
    rows = {}
    for bag in args.bags:
        m = bench_bag(bag)
        rows[bag] = m
        print(f"{bag}: ATE odometry {m['ate_odometry_m']:.3f} m, multiway {m['ate_multiway_m']:.3f} m, "
              f"BA {m.get('ate_bundle_m', float('nan')):.3f} m; layout IoU {m['layout_iou']:.3f}; gravity "
              f"{m['gravity_error_deg']:.3f} deg; {m['fps']:.1f} frames/s ({m['time_ratio']:.2f} x real time, "
              f"cpu {m['cpu_s']:.0f} s)", flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
