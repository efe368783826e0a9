"""Evaluation metrics of the paper's "Metrics" paragraph and docs/design.md §6
(pure numpy + shapely; `yowo eval` and the benchmark call these)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation
from shapely.geometry import Polygon
from shapely.ops import unary_union

from yowo_common.geometry import Sim3, rotation_angle_deg, se3, umeyama
from yowo_common.trajectory import Trajectory


@dataclass(frozen=True)
class PoseError:
    name: str
    eps_pos_m: float
    eps_rot_deg: float


@dataclass(frozen=True, kw_only=True)
class ErrorSummary:
    """avg / min / max over cameras, as in the paper's tables."""

    count: int
    pos_avg: float
    pos_min: float
    pos_max: float
    rot_avg: float
    rot_min: float
    rot_max: float

    @staticmethod
    def of(errors: list[PoseError]) -> "ErrorSummary":
        if not errors:
            nan = float("nan")
            return ErrorSummary(count=0, pos_avg=nan, pos_min=nan, pos_max=nan, rot_avg=nan, rot_min=nan, rot_max=nan)
        p = np.array([e.eps_pos_m for e in errors])
        r = np.array([e.eps_rot_deg for e in errors])
        return ErrorSummary(
            count=len(errors),
            pos_avg=p.mean(),
            pos_min=p.min(),
            pos_max=p.max(),
            rot_avg=r.mean(),
            rot_min=r.min(),
            rot_max=r.max(),
        )


def pose_error(name: str, T_est: np.ndarray, T_gt: np.ndarray) -> PoseError:
    """eps_pos = ||X - X_gt|| (m), eps_rot = arccos((tr(R^T R_gt) - 1) / 2) (deg)."""
    return PoseError(
        name, float(np.linalg.norm(T_est[:3, 3] - T_gt[:3, 3])), rotation_angle_deg(T_est[:3, :3], T_gt[:3, :3])
    )


def registration_errors(est: dict[str, np.ndarray], gt: dict[str, np.ndarray]) -> list[PoseError]:
    """CMC registration: world-frame errors with no alignment, for cameras in both."""
    return [pose_error(n, est[n], gt[n]) for n in sorted(est) if n in gt]


def _alignment_points(poses: list[np.ndarray]) -> np.ndarray:
    """Camera centres plus a point along each camera axis at the rig's own spread,
    so two-camera groups (whose centres alone leave a rotation free) align too."""
    centres = np.array([T[:3, 3] for T in poses])
    spread = max(float(np.linalg.norm(centres - centres.mean(0), axis=1).mean()), 1e-9)
    axes = [T[:3, 3] + spread * T[:3, k] for T in poses for k in range(3)]
    return np.vstack([centres, axes])


def relative_pose_errors(
    est: dict[str, np.ndarray], gt: dict[str, np.ndarray], groups: dict[str, list[str]]
) -> tuple[list[PoseError], dict[str, Sim3]]:
    """CMC relative pose: errors after a KU (Umeyama, with scale) alignment of
    each group to ground truth. Returns the errors and each group's alignment."""
    errors, alignments = [], {}
    for group, names in sorted(groups.items()):
        names = [n for n in names if n in est and n in gt]
        if len(names) < 2:
            continue
        S = umeyama(_alignment_points([est[n] for n in names]), _alignment_points([gt[n] for n in names]))
        alignments[group] = S
        errors += [pose_error(n, S.transform_pose(est[n]), gt[n]) for n in names]
    return errors, alignments


def mean_baseline_m(poses: list[np.ndarray]) -> float:
    """Mean distance between the centres of every pair of cameras."""
    c = np.array([T[:3, 3] for T in poses])
    d = np.linalg.norm(c[:, None] - c[None], axis=2)[np.triu_indices(len(c), 1)]
    return float(d.mean()) if len(d) else float("nan")


def relative_errors_of_baseline(
    errors: list[PoseError], gt: dict[str, np.ndarray], groups: dict[str, list[str]]
) -> list[PoseError]:
    """relative_pose_errors' position errors as a percentage of the mean baseline of the
    camera's group in ground truth (the scale-free measure real recordings are compared
    by: their rigs span 2-20 m); rotations as they are."""
    group_of = {n: g for g, names in groups.items() for n in names}
    base = {g: mean_baseline_m([gt[n] for n in names if n in gt]) for g, names in groups.items()}
    return [PoseError(e.name, 100.0 * e.eps_pos_m / base[group_of[e.name]], e.eps_rot_deg) for e in errors]


def map_frame_from_first_pose(T_world_first_cam: np.ndarray) -> np.ndarray:
    """T_map_world of YOWO's map convention (yowo_ego): origin on the floor (z = 0 of
    `world`) under the first ego camera, x along that camera's viewing direction
    projected on the floor, z up. Ground truth is expressed in this frame before the
    registration metrics: the definition of the frame, no fit to the estimate."""
    forward = T_world_first_cam[:3, 2]
    yaw = float(np.arctan2(forward[1], forward[0]))
    R = Rotation.from_euler("z", -yaw).as_matrix()
    origin = np.array([T_world_first_cam[0, 3], T_world_first_cam[1, 3], 0.0])
    return se3(R, -R @ origin)


# --- trajectories ---------------------------------------------------------------
def associate(est_ns: np.ndarray, ref_ns: np.ndarray, max_diff_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (est, ref): each estimated stamp with its nearest reference
    stamp when within max_diff (evo's matching rule; ref_ns sorted)."""
    est_ns = np.asarray(est_ns, dtype=np.int64)
    ref_ns = np.asarray(ref_ns, dtype=np.int64)
    if len(est_ns) == 0 or len(ref_ns) == 0:
        return np.zeros(0, int), np.zeros(0, int)
    right = np.clip(np.searchsorted(ref_ns, est_ns), 0, len(ref_ns) - 1)
    left = np.maximum(right - 1, 0)
    nearest = np.where(np.abs(ref_ns[left] - est_ns) <= np.abs(ref_ns[right] - est_ns), left, right)
    keep = np.abs(ref_ns[nearest] - est_ns) <= max_diff_ns
    return np.flatnonzero(keep), nearest[keep]


@dataclass(frozen=True, kw_only=True)
class AteResult:
    rmse_m: float
    mean_m: float
    max_m: float
    matched: int
    alignment: Sim3


def ate(est: Trajectory, ref: Trajectory, max_diff_s: float = 0.01, align: bool = True) -> AteResult:
    """Absolute trajectory error (translation part) after a rigid SE(3) Umeyama
    alignment of est to ref, as `evo_ape tum ref est -a` computes it."""
    i_est, i_ref = associate(est.stamps_ns, ref.stamps_ns, int(max_diff_s * 1e9))
    if len(i_est) < 3:
        raise ValueError(f"ATE: only {len(i_est)} estimated poses have a ground-truth stamp within {max_diff_s} s")
    p_est, p_ref = est.positions[i_est], ref.positions[i_ref]
    S = umeyama(p_est, p_ref, with_scale=False) if align else Sim3.identity()
    err = np.linalg.norm(S.apply(p_est) - p_ref, axis=1)
    return AteResult(
        rmse_m=float(np.sqrt(np.mean(err**2))),
        mean_m=float(err.mean()),
        max_m=float(err.max()),
        matched=len(err),
        alignment=S,
    )


# --- layout ---------------------------------------------------------------------
def layout_iou(est_polygons: list[np.ndarray], gt_polygons: list[np.ndarray]) -> float:
    """Top-view floor polygon IoU (each polygon an (N, 2) array of x, y in metres)."""

    def union(polys):
        shapes = [Polygon(p).buffer(0) for p in polys if len(p) >= 3]
        return unary_union(shapes) if shapes else Polygon()

    est, gt = union(est_polygons), union(gt_polygons)
    total = est.union(gt).area
    return float(est.intersection(gt).area / total) if total > 0 else 0.0
