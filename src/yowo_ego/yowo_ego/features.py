"""Scene keypoints of the ego keyframes (paper: keypoint detection and matching;
SuperPoint/SuperGlue/LoFTR replaced by OpenCV SIFT with the ratio test and a
mutual check, which needs no network and handles the viewpoint changes of a
head-mounted camera), and the relative pose of two keyframes from matches with
depth (PnP RANSAC), used for loop closures and for re-tracking after fast turns."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from yowo_common.geometry import inv_se3
from yowo_common.pnp import sqpnp_ransac


@dataclass(frozen=True)
class FeatureParams:
    max_features: int = 1000  # SIFT keypoints per image at most [count]
    ratio: float = 0.8  # Lowe's ratio test threshold [ratio]
    depth_edge_ratio: float = 0.03  # relative depth spread around a keypoint above which it gets none (an edge) [ratio]
    pnp_px: float = 3.0  # PnP RANSAC reprojection threshold
    pnp_min_inliers: int = 25  # matches with depth, and PnP RANSAC inliers, a relative pose needs [count]


@dataclass
class KeyframeFeatures:
    """Keypoints of one image in undistorted pixels, their SIFT descriptors and depth."""

    uv: np.ndarray  # (N, 2) float
    descriptors: np.ndarray  # (N, 128) uint8: OpenCV's SIFT values are integers (4x less than float32)
    depth: np.ndarray  # (N,) metres, NaN where the depth is missing or on an edge

    def __len__(self) -> int:
        return len(self.uv)


def sample_depth(depth: np.ndarray, uv: np.ndarray, edge_ratio: float) -> np.ndarray:
    """Depth at the (sub-pixel) keypoint, interpolated bilinearly: on a floor
    seen at a grazing angle, the nearest pixel's depth is centimetres off. NaN
    when the 3x3 neighbourhood of the nearest pixel spans a depth edge (the
    keypoint may belong to either side) or holds invalid pixels."""
    h, w = depth.shape
    u = np.clip(np.round(uv[:, 0]).astype(int), 1, w - 2)
    v = np.clip(np.round(uv[:, 1]).astype(int), 1, h - 2)
    patch = np.stack([depth[v + dv, u + du] for dv in (-1, 0, 1) for du in (-1, 0, 1)], axis=1)
    # The 2x2 cell holding the keypoint lies inside that 3x3 neighbourhood.
    x = np.clip(uv[:, 0], u - 0.5, u + 0.5)
    y = np.clip(uv[:, 1], v - 0.5, v + 0.5)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    z = (
        (1 - fy) * ((1 - fx) * depth[y0, x0] + fx * depth[y0, x0 + 1])
        + fy * ((1 - fx) * depth[y0 + 1, x0] + fx * depth[y0 + 1, x0 + 1])
    ).astype(float)
    with np.errstate(invalid="ignore"):
        spread = np.ptp(patch, axis=1)
        bad = ~np.isfinite(spread) | (spread > edge_ratio * z) | ~(z > 0)
    z[bad] = np.nan
    return z


def create_sift(max_features: int):
    """SIFT with precise upscaling: OpenCV's default shifts keypoints of the upsampled
    first octave by +0.25 px in x and y, a bias the bundle adjustment would take for a
    pose error (and a mismatch against the ego landmarks' unbiased pixels)."""
    return cv2.SIFT_create(max_features, enable_precise_upscale=True)


class FeatureExtractor:
    def __init__(self, params: FeatureParams = FeatureParams()):
        self.params = params
        self._sift = create_sift(params.max_features)

    def __call__(self, gray: np.ndarray, depth: np.ndarray) -> KeyframeFeatures:
        kps, desc = self._sift.detectAndCompute(gray, None)
        if desc is None or not kps:
            return KeyframeFeatures(np.zeros((0, 2)), np.zeros((0, 128), np.uint8), np.zeros(0))
        uv = np.array([k.pt for k in kps], dtype=float)
        return KeyframeFeatures(uv, desc.astype(np.uint8), sample_depth(depth, uv, self.params.depth_edge_ratio))


def match(a: KeyframeFeatures, b: KeyframeFeatures, ratio: float = 0.8) -> np.ndarray:
    """(M, 2) index pairs (i in a, j in b): Lowe's ratio test in both directions
    and mutual nearest neighbours, from one distance matrix (a BLAS product).
    Second-nearest distances: the row (column) minimum once the nearest entry is
    masked, which is several times cheaper than a partial sort. The product is
    OpenCV's: NumPy's multi-threaded OpenBLAS spins its idle threads after
    every call, which cost more CPU than the whole product on 2 busy cores."""
    if len(a) < 2 or len(b) < 2:
        return np.zeros((0, 2), int)
    da, db = a.descriptors.astype(np.float32), b.descriptors.astype(np.float32)
    d2 = (da * da).sum(1)[:, None] + (db * db).sum(1)[None, :] - cv2.gemm(da, db, 2.0, None, 0.0, flags=cv2.GEMM_2_T)
    np.maximum(d2, 0.0, out=d2)
    i, j = np.arange(len(da)), np.arange(len(db))
    nn_ab, nn_ba = d2.argmin(axis=1), d2.argmin(axis=0)
    best_ab, best_ba = d2[i, nn_ab], d2[nn_ba, j]
    d2[i, nn_ab] = np.inf
    second_ab = d2.min(axis=1)
    d2[i, nn_ab] = best_ab
    d2[nn_ba, j] = np.inf
    second_ba = d2.min(axis=0)
    r2 = ratio * ratio
    ok = (nn_ba[nn_ab] == i) & (best_ab < r2 * second_ab) & (best_ba[nn_ab] < r2 * second_ba[nn_ab])
    return np.column_stack([i[ok], nn_ab[ok]]).astype(int)


def backproject(uv: np.ndarray, depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Undistorted pixels with z-depth -> points in the camera frame."""
    rays = np.column_stack([(uv - K[:2, 2]) / np.diag(K)[:2], np.ones(len(uv))])
    return rays * np.asarray(depth, dtype=float)[:, None]


@dataclass
class PnpResult:
    T_b_a: np.ndarray  # maps points of keyframe a into keyframe b
    inliers: np.ndarray  # indices into the matches passed in


def relative_pose(
    a: KeyframeFeatures,
    b: KeyframeFeatures,
    matches: np.ndarray,
    K: np.ndarray,
    params: FeatureParams = FeatureParams(),
) -> PnpResult | None:
    """T_b_a from a's keypoints lifted with a's depth and their matches in b (PnP
    RANSAC); None when too few inliers support it."""
    ok = np.isfinite(a.depth[matches[:, 0]]) if len(matches) else np.zeros(0, bool)
    if ok.sum() < params.pnp_min_inliers:
        return None
    idx = np.flatnonzero(ok)
    X = backproject(a.uv[matches[idx, 0]], a.depth[matches[idx, 0]], K)
    rvec, tvec, inl = sqpnp_ransac(X, b.uv[matches[idx, 1]], K, params.pnp_px, iterations=300)
    if len(inl) < params.pnp_min_inliers:
        return None
    # Polish on the inliers (SQPnP inside RANSAC sees only minimal samples).
    rvec, tvec = cv2.solvePnPRefineLM(X[inl], b.uv[matches[idx[inl], 1]], K, None, rvec, tvec)
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(rvec)[0]
    T[:3, 3] = tvec.ravel()
    return PnpResult(T, idx[inl])


def support(
    a: KeyframeFeatures, b: KeyframeFeatures, matches: np.ndarray, T_b_a: np.ndarray, K: np.ndarray, px: float = 3.0
) -> int:
    """How many matches (with depth in a) reproject within ``px`` under T_b_a."""
    if len(matches) == 0:
        return 0
    ok = np.isfinite(a.depth[matches[:, 0]])
    X = backproject(a.uv[matches[ok, 0]], a.depth[matches[ok, 0]], K) @ T_b_a[:3, :3].T + T_b_a[:3, 3]
    front = X[:, 2] > 1e-6
    uv = X[:, :2] / np.where(front, X[:, 2], 1.0)[:, None] @ K[:2, :2].T + K[:2, 2]
    return int(np.sum(front & (np.linalg.norm(uv - b.uv[matches[ok, 1]], axis=1) <= px)))


def pose_from_images(
    gray_src: np.ndarray,
    depth_src: np.ndarray,
    gray_tgt: np.ndarray,
    depth_tgt: np.ndarray,
    K: np.ndarray,
    extractor: FeatureExtractor,
) -> np.ndarray | None:
    """T_target_source of two raw images, or None."""
    fs, ft = extractor(gray_src, depth_src), extractor(gray_tgt, depth_tgt)
    r = relative_pose(ft, fs, match(ft, fs, extractor.params.ratio), K, extractor.params)
    return None if r is None else inv_se3(r.T_b_a)
