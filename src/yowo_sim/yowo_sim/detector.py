"""A simulated 2D agent keypoint detector: projects the ground-truth keypoints
into a CMC and corrupts them the way real detectors do."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from yowo_common.camera import CameraModel
from yowo_common.geometry import inv_se3, transform_points


@dataclass(frozen=True)
class DetectorSpec:
    # Pixel noise per keypoint id; body points (ids >= 2) are much noisier, as real pose models are.
    sigma_px: dict[int, float] = field(default_factory=lambda: {0: 1.0, 1: 1.5})
    sigma_body_px: float = 4.0
    miss_rate: float = 0.03  # a keypoint silently missing in a frame
    outlier_rate: float = 0.01  # a keypoint at a wrong place (low-ish confidence)
    outlier_px: float = 60.0
    occlusion_margin_m: float = 0.05


@dataclass(frozen=True)
class Detection:
    ids: np.ndarray  # (K,) int
    uv: np.ndarray  # (K, 2) raw (distorted) pixels
    confidence: np.ndarray  # (K,)
    uv_true: np.ndarray  # (K, 2) noise-free projections, for tests and statistics


def visible_points(
    camera: CameraModel, T_world_cam: np.ndarray, points_world: np.ndarray, static_depth: np.ndarray, margin_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """(raw pixels, mask of points in the image and not hidden behind the static scene)."""
    P_cam = transform_points(inv_se3(T_world_cam), points_world)
    uv, _ = camera.project(P_cam)
    # Not `in_front` alone: rays beyond the distortion's fold land in the image too (wide
    # corridor cameras "saw" the agent far off-axis).
    visible = camera.within_model(P_cam) & camera.in_image(uv) & np.isfinite(uv).all(axis=1)
    safe = np.where(visible[:, None], uv, 0.0)  # points behind the camera project to NaN
    cols = np.clip(np.round(safe[:, 0]).astype(int), 0, camera.width - 1)
    rows = np.clip(np.round(safe[:, 1]).astype(int), 0, camera.height - 1)
    scene_z = static_depth[rows, cols]
    return uv, visible & ~(np.isfinite(scene_z) & (scene_z < P_cam[:, 2] - margin_m))


def detect(
    camera: CameraModel,
    T_world_cam: np.ndarray,
    keypoints_world: dict[int, np.ndarray],
    static_depth: np.ndarray,
    spec: DetectorSpec,
    rng: np.random.Generator,
) -> Detection:
    """Keypoints in view and not hidden by the static scene (depth test against the
    camera's agent-free depth image), with noise, misses and outliers."""
    ids = np.array(sorted(keypoints_world), dtype=int)
    uv, visible = visible_points(
        camera, T_world_cam, np.array([keypoints_world[i] for i in ids]), static_depth, spec.occlusion_margin_m
    )
    visible &= rng.random(len(ids)) >= spec.miss_rate
    ids, uv = ids[visible], uv[visible]
    sigma = np.array([spec.sigma_px.get(int(i), spec.sigma_body_px) for i in ids])
    noisy = uv + rng.normal(size=uv.shape) * sigma[:, None]
    conf = np.clip(0.9 - 0.05 * sigma + rng.normal(0, 0.03, len(ids)), 0.05, 1.0)
    outlier = rng.random(len(ids)) < spec.outlier_rate
    noisy[outlier] += rng.uniform(-1, 1, (outlier.sum(), 2)) * spec.outlier_px
    conf[outlier] *= 0.7
    return Detection(ids, noisy, conf, uv)
