"""A second walk that follows a run's suggestion (walk guidance, issue #48).

A run writes second_walk.yaml: waypoints in its map frame, in walking order, each with how
long to pause. The simulated walker reads that plan in the building, so the plan is put on the
building by the first run's ego trajectory against where the walker truly was (the first
recording's /gt/ego/pose): the simulator knows the world, the pipeline never sees this. The
second walk starts where the first one did, walks to the plan's start and through every
waypoint, and is recorded a silence after the first recording ends, with the same cameras and
clocks (the same preset and seed)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from yowo_common.geometry import umeyama
from yowo_common.ros.bag import read_messages, recording_span
from yowo_common.rosconv import pose_to_matrix, stamp_to_ns
from yowo_common.topics import GT_EGO_POSE
from yowo_common.trajectory import read_tum


@dataclass(frozen=True, kw_only=True)
class FollowWalk:
    waypoints_xy: list[np.ndarray]  # world frame, in walking order, the plan's start first [m]
    pauses_s: list[float]  # how long to stand at each waypoint [s]
    start_ns: int  # the second recording's first stamp (the first recording's clock)


def map_to_world(run_dir: Path, first_bag) -> tuple[np.ndarray, np.ndarray, float]:
    """(R, t, rms [m]) of the rigid transform from the first run's map to the world: its ego
    trajectory (ego_trajectory.tum) fitted to the first recording's true ego poses."""
    est = read_tum(Path(run_dir) / "ego_trajectory.tum")
    truth = {
        stamp_to_ns(m.header.stamp): pose_to_matrix(m.pose)[:3, 3]
        for _, _, m in read_messages(first_bag, [GT_EGO_POSE])
    }
    if not truth:
        raise ValueError(f"{first_bag}: no {GT_EGO_POSE}: a followed walk needs a simulated first recording")
    # The run's poses are the recording's ego frames: their stamps are the truth's.
    same = [(T[:3, 3], truth[int(ns)]) for ns, T in zip(est.stamps_ns, est.T_world_cam) if int(ns) in truth]
    src, dst = (np.array(v) for v in zip(*same))
    S = umeyama(src, dst, with_scale=False)
    rms = float(np.sqrt(np.mean(np.sum((S.apply(src) - dst) ** 2, axis=1))))
    return S.R, S.t, rms


def follow_walk(run_dir, first_bag, gap_s: float = 60.0) -> FollowWalk:
    """The walk second_walk.yaml of `run_dir` suggests, in the world of `first_bag`."""
    run_dir = Path(run_dir)
    plan_file = run_dir / "second_walk.yaml"
    if not plan_file.exists():
        raise ValueError(f"{plan_file}: missing (a full run with cameras writes it)")
    plan = yaml.safe_load(plan_file.read_text())
    if not plan.get("waypoints"):
        raise ValueError(f"{plan_file}: suggests no waypoints; there is nothing to follow")
    R, t, _ = map_to_world(run_dir, first_bag)

    def world(x, y):
        return (R @ np.array([x, y, 0.0]) + t)[:2]

    points = ([plan["start"]] if plan.get("start") else []) + plan["waypoints"]
    pauses = ([0.0] if plan.get("start") else []) + [float(w["pause_s"]) for w in plan["waypoints"]]
    return FollowWalk(
        waypoints_xy=[world(p["x_m"], p["y_m"]) for p in points],
        pauses_s=pauses,
        start_ns=recording_span(first_bag)[1] + int(gap_s * 1e9),
    )
