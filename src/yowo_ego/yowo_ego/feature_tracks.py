"""Visual refinement input (paper: keypoint matches filtered by the epipolar
constraint and by depth/triangulation consistency, forming 2D-3D matches).

For a match between keyframes a and b with the multiway-registration poses:
1. epipolar check: Sampson distance to the epipolar geometry of the poses;
2. depth consistency (paper): the point triangulated from the two keypoints
   must agree with the depth back-projection of each keypoint that has depth.
   The threshold grows with the triangulation's own uncertainty along the ray
   (z^2 sigma_px / (f b_perp)), so short baselines do not reject good matches;
3. for those short baselines, where triangulation says little, the depth
   back-projection of a must also reproject onto b's keypoint (transfer check).
Surviving matches are chained into multi-view tracks (union-find); a track that
claims two keypoints of one keyframe is dropped.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from yowo_common.geometry import inv_se3, skew, transform_points

from .features import backproject


@dataclass(frozen=True)
class FilterParams:
    epipolar_px: float = 2.5  # Sampson distance to the poses' epipolar geometry above which a match is rejected
    depth_abs_m: float = 0.05  # depth-consistency threshold's constant part (depth noise and pose error)
    depth_rel: float = 0.02  # depth-consistency threshold's part proportional to the depth [share]
    keypoint_sigma_px: float = 1.0  # keypoint noise behind the triangulation's uncertainty along the ray
    triangulation_k: float = 3.0  # the triangulation's uncertainty in the depth-consistency threshold [sigmas]
    transfer_px: float = 4.0  # a keypoint's depth point reprojects at most this far from its match
    min_translation_m: float = 1e-3  # baseline below which the epipolar geometry is undefined (no epipolar check)


@dataclass
class FilterResult:
    keep: np.ndarray  # (M,) bool
    epipolar_rejected: int
    depth_rejected: int


def sampson_px(F: np.ndarray, uv_a: np.ndarray, uv_b: np.ndarray) -> np.ndarray:
    xa = np.column_stack([uv_a, np.ones(len(uv_a))])
    xb = np.column_stack([uv_b, np.ones(len(uv_b))])
    Fxa = xa @ F.T
    Ftxb = xb @ F
    num = np.einsum("ij,ij->i", xb, Fxa) ** 2
    den = Fxa[:, 0] ** 2 + Fxa[:, 1] ** 2 + Ftxb[:, 0] ** 2 + Ftxb[:, 1] ** 2
    return np.sqrt(num / np.maximum(den, 1e-30))


def filter_matches(
    uv_a: np.ndarray,
    uv_b: np.ndarray,
    depth_a: np.ndarray,
    depth_b: np.ndarray,
    T_world_a: np.ndarray,
    T_world_b: np.ndarray,
    K: np.ndarray,
    params: FilterParams = FilterParams(),
) -> FilterResult:
    """Which matches (undistorted pixels, depth NaN = none) pass the epipolar and
    depth-consistency checks for the given camera poses."""
    n = len(uv_a)
    if n == 0:
        return FilterResult(np.zeros(0, bool), 0, 0)
    T_b_a = inv_se3(T_world_b) @ T_world_a
    R, t = T_b_a[:3, :3], T_b_a[:3, 3]
    Kinv = np.linalg.inv(K)
    epi_ok = np.ones(n, bool)
    if np.linalg.norm(t) >= params.min_translation_m:
        F = Kinv.T @ skew(t) @ R @ Kinv
        epi_ok = sampson_px(F, uv_a, uv_b) <= params.epipolar_px

    # Triangulation with the poses (world -> camera projections).
    P_a = K @ inv_se3(T_world_a)[:3]
    P_b = K @ inv_se3(T_world_b)[:3]
    Xh = cv2.triangulatePoints(P_a, P_b, uv_a.T.astype(float), uv_b.T.astype(float))
    with np.errstate(divide="ignore", invalid="ignore"):
        X_tri = (Xh[:3] / Xh[3]).T
    baseline = T_world_b[:3, 3] - T_world_a[:3, 3]
    f = float(np.mean(np.diag(K)[:2]))
    depth_ok = np.ones(n, bool)
    for uv, depth, T_world_c in ((uv_a, depth_a, T_world_a), (uv_b, depth_b, T_world_b)):
        has = np.isfinite(depth)
        X_d = transform_points(T_world_c, backproject(uv, np.where(has, depth, 1.0), K))
        rays = X_d - T_world_c[:3, 3]
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        b_perp = np.linalg.norm(baseline - (rays @ baseline)[:, None] * rays, axis=1)
        z = np.where(has, depth, 0.0)
        sigma_tri = z**2 * params.keypoint_sigma_px / (f * np.maximum(b_perp, 1e-9))
        thr = params.depth_abs_m + params.depth_rel * z + params.triangulation_k * sigma_tri
        with np.errstate(invalid="ignore"):
            err = np.linalg.norm(X_tri - X_d, axis=1)
        depth_ok &= ~has | ~np.isfinite(err) | (err <= thr)
    # Transfer: a's depth point seen from b lands on b's keypoint (and vice versa).
    for uv_s, depth_s, T_ws, uv_t, T_wt in (
        (uv_a, depth_a, T_world_a, uv_b, T_world_b),
        (uv_b, depth_b, T_world_b, uv_a, T_world_a),
    ):
        has = np.isfinite(depth_s)
        X = transform_points(inv_se3(T_wt) @ T_ws, backproject(uv_s, np.where(has, depth_s, 1.0), K))
        front = X[:, 2] > 1e-6
        proj = X[:, :2] / np.where(front, X[:, 2], 1.0)[:, None] @ K[:2, :2].T + K[:2, 2]
        depth_ok &= ~has | (front & (np.linalg.norm(proj - uv_t, axis=1) <= params.transfer_px))
    keep = epi_ok & depth_ok
    return FilterResult(keep, int((~epi_ok).sum()), int((epi_ok & ~depth_ok).sum()))


@dataclass
class Tracks:
    """Multi-view tracks: observation arrays (parallel) grouped by track id."""

    keyframe: np.ndarray  # (M,) keyframe index of each observation
    feature: np.ndarray  # (M,) feature index within that keyframe
    track: np.ndarray  # (M,) track id, 0..T-1

    @property
    def count(self) -> int:
        return int(self.track.max()) + 1 if len(self.track) else 0


def build_tracks(pairs: list[tuple[int, int, np.ndarray]], num_features: list[int]) -> Tracks:
    """Union-find over accepted matches: pairs of (keyframe a, keyframe b, (M, 2)
    feature index pairs). Tracks with two keypoints in one keyframe are dropped."""
    offsets = np.concatenate([[0], np.cumsum(num_features)]).astype(int)
    n = int(offsets[-1])
    rows = [offsets[a] + m[:, 0] for a, b, m in pairs if len(m)]
    cols = [offsets[b] + m[:, 1] for a, b, m in pairs if len(m)]
    if not rows:
        return Tracks(np.zeros(0, int), np.zeros(0, int), np.zeros(0, int))
    r, c = np.concatenate(rows), np.concatenate(cols)
    graph = coo_matrix((np.ones(len(r)), (r, c)), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    used = np.zeros(n, bool)
    used[r] = used[c] = True
    nodes = np.flatnonzero(used)
    kf = np.searchsorted(offsets, nodes, side="right") - 1
    lab = label[nodes]
    # Drop tracks that see one keyframe twice (a wrong match somewhere in the chain).
    key = lab.astype(np.int64) * (len(num_features) + 1) + kf
    uniq, counts = np.unique(key, return_counts=True)
    bad_labels = np.unique(uniq[counts > 1] // (len(num_features) + 1))
    ok = ~np.isin(lab, bad_labels)
    nodes, kf, lab = nodes[ok], kf[ok], lab[ok]
    _, track = np.unique(lab, return_inverse=True)
    order = np.lexsort((kf, track))
    return Tracks(kf[order], (nodes - offsets[kf])[order], track[order])
