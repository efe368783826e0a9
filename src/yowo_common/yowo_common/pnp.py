"""PnP as every stage calls it: OpenCV's SQPnP (globally optimal), deterministic
RANSAC, and a point set without spread treated as "no pose" instead of a crash.

OpenCV's SQPnP asserts (`point_coordinate_variance >= POINT_VARIANCE_THRESHOLD` in
`computeOmega`) when its 3D points nearly coincide, e.g. the agent standing still for
a camera's whole view, or a RANSAC inlier set that is one repeated point. The `large`
benchmark recording stopped on it after 40 minutes.
"""

from __future__ import annotations

import cv2
import numpy as np


def _degenerate(exc: cv2.error) -> bool:
    # Only SQPnP's spread assertion means "no pose"; any other OpenCV error is a bug to surface.
    return exc.func == "computeOmega"


def sqpnp_ransac(
    points: np.ndarray,
    uv: np.ndarray,
    K: np.ndarray,
    reprojection_px: float,
    iterations: int = 2000,
    confidence: float = 0.999,
    seed: int = 0,
) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray]:
    """(rvec, tvec, inlier indices) of T_cam_world from 3D points and ideal pixels;
    no inliers when RANSAC finds no pose or the points have no spread. The seed fixes
    OpenCV's global RANSAC RNG: the same input gives the same pose."""
    cv2.setRNGSeed(seed)
    try:
        ok, rvec, tvec, inliers = cv2.solvePnPRansac(
            np.ascontiguousarray(points, np.float64),
            np.ascontiguousarray(uv, np.float64),
            K,
            None,
            iterationsCount=iterations,
            reprojectionError=reprojection_px,
            confidence=confidence,
            flags=cv2.SOLVEPNP_SQPNP,
        )
    except cv2.error as exc:
        if not _degenerate(exc):
            raise
        return None, None, np.zeros(0, np.int64)
    if not ok or inliers is None:
        return None, None, np.zeros(0, np.int64)
    return rvec, tvec, inliers.ravel().astype(np.int64)


def sqpnp_all(points: np.ndarray, uv: np.ndarray, K: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """SQPnP's solutions (rvec, tvec) of T_cam_world on every correspondence, no RANSAC;
    none when the points have no spread."""
    try:
        _, rvecs, tvecs, _ = cv2.solvePnPGeneric(
            np.ascontiguousarray(points, np.float64),
            np.ascontiguousarray(uv, np.float64),
            K,
            None,
            flags=cv2.SOLVEPNP_SQPNP,
        )
    except cv2.error as exc:
        if not _degenerate(exc):
            raise
        return []
    return list(zip(rvecs, tvecs))
